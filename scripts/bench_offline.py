"""Offline-learner throughput: gradient steps per second and the wall time of whole vmapped runs.

::

    python scripts/bench_offline.py                       # ATAC, CPU-sized: 10 k steps × 1 seed
    python scripts/bench_offline.py --learners atac --seeds 1 8 --full-steps 1000000 --full-seeds 8
    # the same run in 100 k-step compiled chunks, progress written to the JSON after each
    python scripts/bench_offline.py --learners atac --seeds 8 --chunk 2000 \
        --full-steps 1000000 --full-seeds 8 --full-chunk 100000
    # operations per compiled gradient step by part of the step (on a GPU: a kernel trace too)
    python scripts/bench_offline.py --learners atac --seeds 8 --no-rate --structure

For each learner (``atac``, ``pspi``, ``mahalo``, ``bc``, ``iql``, ``cql``) at the thesis sizes
(docs/design.md §4.5: batch 256, 3×256 MLPs; :mod:`offline.experiment.bench`):

* **steps/s** — a compiled ``run(state, chunk)`` vmapped over ``S`` seeds (``--seeds``), timed
  after a warm-up call; reported per seed-step (``gradient steps/s`` of one seed) and in total;
* **structure** (``--structure``) — the operations one gradient step of the compiled, vmapped
  ``run`` executes, by opcode and by part of the step, and on a GPU the kernels one call runs
  per step, their busy and span µs, matrix products and reductions apart
  (:func:`offline.experiment.bench.structure`);
* **full run** — ``jax.jit(jax.vmap(trainer.train))(keys)`` for ``--full-steps`` gradient steps
  × ``--full-seeds`` seeds, wall time including compilation (compile time reported apart); with
  ``--full-chunk`` in compiled chunks (how ``scripts/train_offline.py`` runs), the progress
  (steps done, wall so far) written to the JSON after each chunk, so a run cut short by a time
  limit still leaves its rate.

The data are a ``mixed`` dataset of ``three_link/env3`` collected in the compiled graph
(:func:`offline.data.collect.collect_recipe`; its size does not change the cost of a step) and, for
MAHALO, the ILfO scenario built from it and an ``expert`` dataset. ``--block-steps`` and
``--unroll`` set how ATAC, PSPI and MAHALO run their steps (``ATACConfig``: speed only).
Writes JSON (default ``results/offline/bench_offline_<device>.json``) and prints a table.
:func:`offline.experiment.bench.measure` is what ``scripts/bench.py --offline`` calls.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla  # sets the XLA:CPU flag before JAX initialises

# isort: split
import jax

from offline.experiment.bench import LEARNERS, device_slug, run_benchmark

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)

ROOT = Path(__file__).resolve().parent.parent


def main(argv: Sequence[str] | None = None) -> dict:
    """Parse arguments, run the benchmark (:func:`offline.experiment.bench.run_benchmark`),
    print and write the JSON."""
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
    p.add_argument("--structure", action="store_true",
                   help="also count the operations of one compiled gradient step, by part")
    p.add_argument("--block-steps", type=int, default=None,
                   help="ATAC-family steps drawn at once (ATACConfig.block_steps)")
    p.add_argument("--unroll", type=int, default=None,
                   help="ATAC-family inner-loop unroll (ATACConfig.unroll)")
    p.add_argument("--scale", type=int, default=8, help="episodes per source of the dataset")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    if any(n < 1 for n in args.seeds):
        p.error("--seeds must be positive integers")
    if args.full_steps < 0 or args.full_seeds < 1 or args.scale < 1 or args.full_chunk < 0:
        p.error("--full-steps and --full-chunk must be >= 0, --full-seeds and --scale >= 1")
    options = {k: v for k, v in (("block_steps", args.block_steps), ("unroll", args.unroll))
               if v is not None}
    if any(v < 1 for v in options.values()):
        p.error("--block-steps and --unroll must be >= 1")
    print(f"device: {jax.devices()[0].device_kind} ({jax.default_backend()}); jax "
          f"{jax.__version__}", flush=True)
    path = args.json or ROOT / "results" / "offline" / f"bench_offline_{device_slug()}.json"
    command = " ".join(["python scripts/bench_offline.py",
                        *(argv if argv is not None else sys.argv[1:])])
    result = run_benchmark(args.learners, path, command, seeds=args.seeds, chunk=args.chunk,
                           full_steps=args.full_steps, full_seeds=args.full_seeds,
                           full_chunk=args.full_chunk, rates=not args.no_rate,
                           scale=args.scale, seed=args.seed, steps_structure=args.structure,
                           atac_options=options)
    print(f"JSON: {path}", flush=True)
    return result


if __name__ == "__main__":
    main()
