"""Offline-learner throughput: gradient steps per second and the wall time of whole vmapped runs
(docs/design.md §4.5 sizes: batch 256, 3×256 MLPs).

* :func:`measure` — a compiled ``run(state, chunk)`` vmapped over ``S`` seeds, timed after a
  warm-up call; reported per seed-step (gradient steps/s of one seed) and in total;
* :func:`measure_full` — a whole run of ``num_steps`` gradient steps × ``num_seeds`` seeds,
  wall time including compilation (compile time reported apart), as one program or in compiled
  chunks (how ``scripts/train_offline.py`` runs), with progress after each chunk;
* :func:`structure` — how many operations (GPU kernels, roughly) one compiled gradient step
  executes, by part of the step (:mod:`offline.experiment.step_profile`);
* :func:`run_benchmark` — these for several learners, the JSON rewritten after every result (what
  ``scripts/bench_offline.py`` runs; ``scripts/bench.py --offline`` calls :func:`measure`).

The data are a ``mixed`` dataset of ``three_link/env3`` collected in the compiled graph
(:func:`offline.data.collect.collect_recipe`; its size does not change the cost of a step) and,
for MAHALO, the ILfO scenario built from it and an ``expert`` dataset.
"""

from __future__ import annotations

import datetime
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from mjxrmp.atomic import atomic_write
from mjxrmp.results.summary import run_record, slug
from offline.data import collect, scenarios
from offline.experiment import step_profile
from offline.experiment.run import train_chunked
from offline.learners import atac, bc, cql, iql, mahalo

LEARNERS = ("atac", "pspi", "mahalo", "bc", "iql", "cql")


def datasets(scale: int, seed: int) -> tuple[Any, Any, Any]:
    """``(mixed, expert, ilfo_scenario)`` of ``three_link/env3`` with ``scale`` episodes per
    source."""
    mixed = collect.collect_recipe("three_link/env3", "mixed", scale, seed=seed)
    expert = collect.collect_recipe("three_link/env3", "expert", scale, seed=seed)
    return mixed, expert, scenarios.make("ILfO", mixed, expert)


def make_trainer(name: str, mixed: Any, scenario: Any, num_steps: int,
                 atac_options: dict | None = None) -> Any:
    """The learner ``name`` at its default (thesis) sizes with ``num_steps`` gradient steps;
    ``atac_options`` (e.g. ``block_steps``, ``unroll``) go to the ATAC config of ATAC, PSPI and
    MAHALO."""
    warm = min(100_000, num_steps // 10)
    opts = dict(atac_options or {})
    if name in ("atac", "pspi"):
        cfg = atac.ATACConfig(num_steps=num_steps, warmstart_steps=warm,
                              pessimism="relative" if name == "atac" else "absolute", **opts)
        return atac.make_train(mixed, cfg)
    if name == "mahalo":
        dyn, rew = scenario
        cfg = mahalo.MAHALOConfig(atac=atac.ATACConfig(beta=10.0, num_steps=num_steps,
                                                       warmstart_steps=warm, **opts))
        return mahalo.make_train(dyn, cfg, reward_data=rew)
    if name == "bc":
        return bc.make_train(mixed, bc.BCConfig(num_steps=num_steps))
    if name == "iql":
        return iql.make_train(mixed, iql.IQLConfig(num_steps=num_steps))
    if name == "cql":
        return cql.make_train(mixed, cql.CQLConfig(num_steps=num_steps))
    raise ValueError(f"unknown learner {name!r}; valid names are {list(LEARNERS)}")


def measure(learner: str, seeds: Sequence[int] = (1,), chunk: int = 1000, scale: int = 8,
            seed: int = 0, data: Any = None, num_steps: int | None = None,
            atac_options: dict | None = None) -> dict:
    """Gradient steps/s of ``learner``: ``chunk`` steps timed after a warm-up call, for each
    seed count in ``seeds`` (vmapped)."""
    mixed, _, scenario = data if data is not None else datasets(scale, seed)
    row: dict = {"learner": learner, "batch_size": 256, "hidden": [256, 256, 256],
                 "transitions": int(mixed.size), "chunk": chunk, "rates": []}
    trainer = make_trainer(learner, mixed, scenario, max(num_steps or chunk, chunk),
                           atac_options)
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


def measure_full(learner: str, num_steps: int, num_seeds: int, seed: int = 0, data: Any = None,
                 scale: int = 8, chunk: int = 0,
                 on_chunk: Callable[[dict], None] | None = None,
                 atac_options: dict | None = None) -> dict:
    """Wall time of a whole run of ``num_steps`` steps for ``num_seeds`` seeds vmapped,
    compilation included (reported apart too): one ``jax.jit(jax.vmap(train))`` program
    (``chunk = 0``), or ``chunk``-step compiled calls of ``run`` after a compiled ``init``
    (:func:`offline.experiment.run.train_chunked`'s way of running), with ``on_chunk(partial
    result)`` after each — so a run cut short still leaves its progress and rate."""
    mixed, _, scenario = data if data is not None else datasets(scale, seed)
    trainer = make_trainer(learner, mixed, scenario, num_steps, atac_options)
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


def structure(learner: str, seeds: int = 8, chunk: int = 64, seed: int = 0, data: Any = None,
              scale: int = 8, atac_options: dict | None = None) -> dict:
    """The operations one gradient step of ``learner`` executes in its compiled, vmapped
    ``run`` (:func:`offline.experiment.step_profile.step_structure`): per step in total, by
    opcode and by part of the step."""
    mixed, _, scenario = data if data is not None else datasets(scale, seed)
    trainer = make_trainer(learner, mixed, scenario, chunk, atac_options)
    row = step_profile.step_structure(trainer, seeds, chunk, seed)
    print(f"{learner}: {row['ops_per_step']} operations per gradient step ({seeds} seeds "
          f"vmapped, {row['backend']}), {row['fusions_per_step']} of them fusions; by part "
          f"{row['by_part']}", flush=True)
    if row["gpu_kernels"] is not None:
        k = row["gpu_kernels"]
        kinds = ", ".join(f"{kind} {v['kernels_per_step']:.0f} kernels / "
                          f"{v['busy_us_per_step']:.0f} µs" for kind, v in k["by_kind"].items())
        print(f"{learner}: on the GPU {k['kernels_per_step']:.0f} kernels per gradient step, "
              f"{k['busy_us_per_step']:.0f} µs busy in {k['span_us_per_step']:.0f} µs ({kinds})",
              flush=True)
    return row


def device_slug() -> str:
    """``cpu`` or the first device's kind, lower-case alphanumerics and ``_`` (file names)."""
    if jax.default_backend() == "cpu":
        return "cpu"
    return slug(jax.devices()[0].device_kind)


def run_benchmark(learners: Sequence[str], path: Path, command: str,
                  seeds: Sequence[int] = (1,), chunk: int | None = None, full_steps: int = 0,
                  full_seeds: int = 8, full_chunk: int = 0, rates: bool = True,
                  scale: int = 8, seed: int = 0, steps_structure: bool = False,
                  atac_options: dict | None = None) -> dict:
    """:func:`measure` (unless not ``rates``), with ``steps_structure`` :func:`structure` (at
    the largest seed count) and, with ``full_steps > 0``, :func:`measure_full` for every learner
    on one shared dataset, ATAC-family configs with ``atac_options``; the result (``date``,
    ``command``, ``device``, ``rows``) is rewritten to the JSON ``path`` after every
    measurement, so a run cut short keeps what it measured. ``chunk`` defaults to 10,000 steps
    on CPU, 20,000 on GPU."""
    chunk = chunk or (10_000 if jax.default_backend() == "cpu" else 20_000)
    data = datasets(scale, seed)
    result = {**run_record(command, jax.devices()[0].device_kind),
              "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
              "atac_options": dict(atac_options or {}), "rows": []}
    path.parent.mkdir(parents=True, exist_ok=True)

    def write() -> None:
        atomic_write(path, (json.dumps(result, indent=2) + "\n").encode())

    for learner in learners:
        row = (measure(learner, seeds, chunk, seed=seed, data=data, atac_options=atac_options)
               if rates else {"learner": learner})
        result["rows"].append(row)
        if steps_structure:
            row["structure"] = structure(learner, max(seeds), seed=seed, data=data,
                                         atac_options=atac_options)
        write()  # kept if the full run is cut
        if full_steps > 0:
            def partial(progress, _row=row):
                _row["full_progress"] = progress
                print(f"  {progress['steps_done']:,}/{full_steps:,} steps, "
                      f"{progress['wall_s']:.0f} s", flush=True)
                write()

            row["full"] = measure_full(learner, full_steps, full_seeds, seed=seed, data=data,
                                       chunk=full_chunk, on_chunk=partial,
                                       atac_options=atac_options)
            write()
    return result


__all__ = ["LEARNERS", "datasets", "device_slug", "make_trainer", "measure", "measure_full",
           "run_benchmark", "structure"]
