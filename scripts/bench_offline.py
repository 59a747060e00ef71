"""Offline-learner throughput: gradient steps per second and the wall time of whole vmapped runs.

::

    python scripts/bench_offline.py                       # ATAC, CPU-sized: 10 k steps × 1 seed
    python scripts/bench_offline.py --learners atac --seeds 1 8 --full-steps 1000000 --full-seeds 8
    # the same run in 100 k-step compiled chunks, progress written to the JSON after each
    python scripts/bench_offline.py --learners atac --seeds 8 --chunk 2000 \
        --full-steps 1000000 --full-seeds 8 --full-chunk 100000

For each learner (``atac``, ``pspi``, ``mahalo``, ``bc``, ``iql``, ``cql``) at the thesis sizes
(docs/design.md §4.5: batch 256, 3×256 MLPs):

* **steps/s** — a compiled ``run(state, chunk)`` vmapped over ``S`` seeds (``--seeds``), timed
  after a warm-up call; reported per seed-step (``gradient steps/s`` of one seed) and in total;
* **full run** — ``jax.jit(jax.vmap(trainer.train))(keys)`` for ``--full-steps`` gradient steps
  × ``--full-seeds`` seeds, wall time including compilation (compile time reported apart); with
  ``--full-chunk`` in compiled chunks (how ``scripts/train_offline.py`` runs), the progress
  (steps done, wall so far) written to the JSON after each chunk, so a run cut short by a time
  limit still leaves its rate.

The data are a ``mixed`` dataset of ``three_link/env3`` collected in the compiled graph
(:func:`offline.data.collect.collect_recipe`; its size does not change the cost of a step) and, for
MAHALO, the ILfO scenario built from it and an ``expert`` dataset. Writes JSON (default
``results/bench_offline_<device>.json``) and prints a table. :func:`measure` is what
``scripts/bench.py --offline`` calls.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag before JAX initialises)

# isort: split
import jax
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
LEARNERS = ("atac", "pspi", "mahalo", "bc", "iql", "cql")


def _datasets(scale: int, seed: int):
    from offline.data import collect, scenarios

    mixed = collect.collect_recipe("three_link/env3", "mixed", scale, seed=seed)
    expert = collect.collect_recipe("three_link/env3", "expert", scale, seed=seed)
    return mixed, expert, scenarios.make("ILfO", mixed, expert)


def _trainer(name: str, mixed, scenario, num_steps: int):
    """The learner ``name`` at its default (thesis) sizes with ``num_steps`` gradient steps."""
    from offline.learners import atac, bc, cql, iql, mahalo

    warm = min(100_000, num_steps // 10)
    if name in ("atac", "pspi"):
        cfg = atac.ATACConfig(num_steps=num_steps, warmstart_steps=warm,
                              pessimism="relative" if name == "atac" else "absolute")
        return atac.make_train(mixed, cfg)
    if name == "mahalo":
        dyn, rew = scenario
        cfg = mahalo.MAHALOConfig(atac=atac.ATACConfig(beta=10.0, num_steps=num_steps,
                                                       warmstart_steps=warm))
        return mahalo.make_train(dyn, cfg, reward_data=rew)
    if name == "bc":
        return bc.make_train(mixed, bc.BCConfig(num_steps=num_steps))
    if name == "iql":
        return iql.make_train(mixed, iql.IQLConfig(num_steps=num_steps))
    if name == "cql":
        return cql.make_train(mixed, cql.CQLConfig(num_steps=num_steps))
    raise ValueError(f"unknown learner {name!r}; valid names are {list(LEARNERS)}")


def measure(learner: str, seeds: Sequence[int] = (1,), chunk: int = 1000, scale: int = 8,
            seed: int = 0, data=None, num_steps: int | None = None) -> dict:
    """Gradient steps/s of ``learner``: ``chunk`` steps timed after a warm-up call, for each
    seed count in ``seeds`` (vmapped)."""
    mixed, _, scenario = data if data is not None else _datasets(scale, seed)
    row: dict = {"learner": learner, "batch_size": 256, "hidden": [256, 256, 256],
                 "transitions": int(mixed.size), "chunk": chunk, "rates": []}
    trainer = _trainer(learner, mixed, scenario, max(num_steps or chunk, chunk))
    run = jax.jit(jax.vmap(trainer.run, in_axes=(0, None)), static_argnums=1)
    for n in seeds:
        keys = jax.random.split(jax.random.key(seed), n)
        state = jax.block_until_ready(jax.jit(jax.vmap(trainer.init))(keys))
        t0 = time.perf_counter()
        exe = run.lower(state, chunk).compile()
        compile_s = time.perf_counter() - t0
        state, _ = jax.block_until_ready(exe(state))
        t0 = time.perf_counter()
        jax.block_until_ready(exe(state))
        dt = time.perf_counter() - t0
        row["rates"].append({"seeds": n, "compile_s": compile_s, "seconds": dt,
                             "steps_per_s_per_seed": chunk / dt,
                             "seed_steps_per_s": n * chunk / dt})
        print(f"{learner}: {n} seed(s) vmapped, {chunk} steps in {dt:.2f} s → "
              f"{chunk / dt:,.0f} gradient steps/s per seed ({n * chunk / dt:,.0f} in total), "
              f"compile {compile_s:.1f} s", flush=True)
    return row


def measure_full(learner: str, num_steps: int, num_seeds: int, seed: int = 0, data=None,
                 scale: int = 8, chunk: int = 0,
                 on_chunk: Callable[[dict], None] | None = None) -> dict:
    """Wall time of a whole run of ``num_steps`` steps for ``num_seeds`` seeds vmapped,
    compilation included (reported apart too): one ``jax.jit(jax.vmap(train))`` program
    (``chunk = 0``), or ``chunk``-step compiled calls of ``run`` after a compiled ``init``
    (:func:`offline.experiment.run.train_chunked`'s way of running), with ``on_chunk(partial
    result)`` after each — so a run cut short still leaves its progress and rate."""
    from offline.experiment.run import train_chunked

    mixed, _, scenario = data if data is not None else _datasets(scale, seed)
    trainer = _trainer(learner, mixed, scenario, num_steps)
    keys = jax.random.split(jax.random.key(seed + 1), num_seeds)
    t_start = time.perf_counter()
    if chunk:
        state = jax.block_until_ready(jax.jit(jax.vmap(trainer.init))(keys))
        compile_s = time.perf_counter() - t_start   # init only; each chunk size compiles once

        def progress(state, means, done):
            if on_chunk is not None:
                on_chunk({"steps_done": done, "seeds": num_seeds,
                          "wall_s": time.perf_counter() - t_start})

        _, metrics = train_chunked(trainer, keys, chunk, progress, state=state)
    else:
        train = jax.jit(jax.vmap(trainer.train)).lower(keys).compile()
        compile_s = time.perf_counter() - t_start
        _, metrics = jax.block_until_ready(train(keys))
    wall = time.perf_counter() - t_start
    finite = bool(all(np.all(np.isfinite(v)) for v in jax.tree.leaves(metrics)))
    print(f"{learner}: {num_steps:,} steps × {num_seeds} seeds vmapped: {wall:.1f} s wall "
          f"including {compile_s:.1f} s compile{' (init; chunks compile inside)' if chunk else ''}"
          f" (metrics finite: {finite})", flush=True)
    return {"steps": num_steps, "seeds": num_seeds, "compile_s": compile_s, "wall_s": wall,
            "chunk": chunk, "steps_per_s_per_seed": num_steps / (wall - compile_s),
            "metrics_finite": finite}


def main(argv: Sequence[str] | None = None) -> dict:
    """Parse arguments, run :func:`measure` per learner, print and write the JSON."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--learners", nargs="+", default=["atac"], choices=LEARNERS)
    p.add_argument("--seeds", nargs="+", type=int, default=[1],
                   help="seed counts vmapped in the steps/s rows")
    p.add_argument("--chunk", type=int, default=None,
                   help="timed gradient steps (default 10,000 on CPU, 20,000 on GPU)")
    p.add_argument("--full-steps", type=int, default=0,
                   help="also time a whole run of this many steps (0: skip)")
    p.add_argument("--full-seeds", type=int, default=8)
    p.add_argument("--no-rate", action="store_true",
                   help="skip the per-seed-count rate measurement (only the --full-steps run)")
    p.add_argument("--full-chunk", type=int, default=0,
                   help="run the whole run in compiled chunks of this many steps, writing "
                        "progress to the JSON after each (0: one program)")
    p.add_argument("--scale", type=int, default=8, help="episodes per source of the dataset")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    for name in ("seeds",):
        if any(n < 1 for n in getattr(args, name)):
            p.error(f"--{name} must be positive integers")
    if args.full_steps < 0 or args.full_seeds < 1 or args.scale < 1 or args.full_chunk < 0:
        p.error("--full-steps and --full-chunk must be >= 0, --full-seeds and --scale >= 1")
    on_cpu = jax.default_backend() == "cpu"
    chunk = args.chunk or (10_000 if on_cpu else 20_000)
    device = jax.devices()[0].device_kind
    print(f"device: {device} ({jax.default_backend()}); jax {jax.__version__}", flush=True)
    data = _datasets(args.scale, args.seed)
    result = {"date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
              "command": " ".join(["python scripts/bench_offline.py",
                                   *(argv if argv is not None else sys.argv[1:])]),
              "device": device, "rows": []}
    slug = "cpu" if on_cpu else "".join(c if c.isalnum() else "_" for c in device.lower())
    path = args.json or ROOT / "results" / f"bench_offline_{slug}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    for learner in args.learners:
        row = ({"learner": learner} if args.no_rate
               else measure(learner, args.seeds, chunk, seed=args.seed, data=data))
        result["rows"].append(row)
        path.write_text(json.dumps(result, indent=2) + "\n")  # kept if the full run is cut
        if args.full_steps > 0:
            def partial(progress, _row=row):
                _row["full_progress"] = progress
                print(f"  {progress['steps_done']:,}/{args.full_steps:,} steps, "
                      f"{progress['wall_s']:.0f} s", flush=True)
                path.write_text(json.dumps(result, indent=2) + "\n")

            row["full"] = measure_full(learner, args.full_steps, args.full_seeds,
                                       seed=args.seed, data=data, chunk=args.full_chunk,
                                       on_chunk=partial)
            path.write_text(json.dumps(result, indent=2) + "\n")
    print(f"JSON: {path}", flush=True)
    return result


if __name__ == "__main__":
    main()
