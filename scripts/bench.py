"""Benchmark table: RMP² policy evaluations per second, latency and compile times.

For each robot's hand-designed RMP² policy (``mjxrmp.policies.default_config``):

* **batched** — ``jax.jit(jax.vmap(policy))`` at each batch size: evaluations/s = batch / (median
  time of one call over ``--repeats`` timed repeats, after warm-up; each repeat runs the call
  enough times to last ``--min-repeat-s`` and blocks once at the end);
* **single** — single-state latency of ``jax.jit(policy)`` on unbatched inputs: the median over
  ``--latency-calls`` calls, each blocked on its own (dispatch included);
* the same for the naive baseline (:func:`mjxrmp.core.naive.acceleration_naive`) at
  ``--naive-batches`` and the ratio RMP²/naive at the largest batch both were run at (4096 by
  default).

"compile" is the wall time of the first call of each compiled function (trace + compile + run).
Inputs are random for every state: ``q`` uniform within the joint limits (±π where a joint has
none), ``q̇ ~ U(−1, 1)``, a random goal and three random obstacles (3-link: 15 control points ×
3 circles/cylinders + velocity caps + damping + target; Franka: 48 control points × 3 balls +
joint limits + velocity caps + damping + cspace target + target). The default float32 path is
measured (no x64, default matmul precision). Two input sets alternate between calls.

Usage::

    python scripts/bench.py                       # CPU: batches up to 4096; GPU: up to 262144
    python scripts/bench.py --robots franka --batches 1 4096 65536 --repeats 7
    python -m scripts.bench --quick --json /tmp/bench.json   # smoke test
    python scripts/bench.py --peers thesis gpu    # PPO peers side by side: results/peers

Writes JSON (``--json``, default ``results/rmp2_evaluation/bench_<device>.json``) after every
row, so a run cut short still leaves its numbers. The measurements live in :mod:`agents.bench`
(docs/design.md §2.5; compile times: §5.6).
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
from agents.bench.peers import TRAINERS, run_from_settings
from agents.bench.rmp2 import ROBOTS
from agents.bench.run import (
    CPU_BATCHES,
    CPU_ENV_BATCHES,
    ENVS,
    GPU_BATCHES,
    GPU_ENV_BATCHES,
    NAIVE_BATCHES,
    fill_defaults,
    run_benchmark,
)
from offline.experiment.bench import measure as measure_offline

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)

ROOT = Path(__file__).resolve().parent.parent


def parse_args(argv: Sequence[str] | None) -> dict:
    """The settings: the arguments with the sizes defaulted for this backend."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", nargs="+", choices=ROBOTS, default=list(ROBOTS))
    p.add_argument("--batches", nargs="+", type=int, default=None,
                   help=f"RMP² batch sizes (default GPU {GPU_BATCHES}, CPU {CPU_BATCHES})")
    p.add_argument("--naive-batches", nargs="+", type=int, default=None,
                   help=f"naive-baseline batch sizes (default {NAIVE_BATCHES}; none: 0)")
    p.add_argument("--repeats", type=int, default=None, help="timed repeats (default 5)")
    p.add_argument("--latency-calls", type=int, default=None,
                   help="single-state calls for the latency median (default 1000)")
    p.add_argument("--min-repeat-s", type=float, default=None,
                   help="each timed repeat lasts at least this long (default 0.2 s)")
    p.add_argument("--full", action="store_true", help="on CPU, use the GPU batch sizes too")
    p.add_argument("--quick", action="store_true", help="tiny sizes, for a smoke test")
    p.add_argument("--json", type=Path, default=None,
                   help="output path (default results/rmp2_evaluation/bench_<device>.json)")
    p.add_argument("--envs", nargs="+", default=None,
                   help=f"environments for control-step throughput (default {ENVS}; "
                        "'none' skips; --quick skips unless given)")
    p.add_argument("--env-batches", nargs="+", type=int, default=None,
                   help=f"environment batch sizes (default GPU {GPU_ENV_BATCHES}, "
                        f"CPU {CPU_ENV_BATCHES})")
    p.add_argument("--env-steps", type=int, default=None,
                   help="control steps per timed call (default 100; CPU 20)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--async-dispatch", action="store_true",
                   help="on CPU, keep JAX's asynchronous dispatch (default: synchronous, the "
                        "low-latency setting for single-state control loops)")
    p.add_argument("--pin-cpu", type=int, default=None, metavar="CORE",
                   help="pin the process to one CPU core before JAX starts (Linux; the usual "
                        "setting for measuring single-state control-loop latency)")
    p.add_argument("--ppo", nargs="+", default=[], metavar="ENV:POLICY",
                   help="PPO training throughput rows, e.g. three_link/env3:rmp_residual")
    p.add_argument("--ppo-devices", nargs="+", type=int, default=[1],
                   help="device counts for the PPO rows (environment batch sharded)")
    p.add_argument("--ppo-iterations", type=int, default=3, help="iterations per timed chunk")
    p.add_argument("--ppo-seeds", type=int, default=4, help="vmapped seeds in the PPO rows")
    p.add_argument("--ppo-preset", default="thesis", help="PPO settings of the PPO rows")
    p.add_argument("--ppo-num-envs", type=int, default=None,
                   help="override the preset's num_envs (a larger batch for scaling runs)")
    p.add_argument("--ppo-only", action="store_true", help="only the PPO (and offline) rows")
    p.add_argument("--offline", nargs="+", default=[], metavar="LEARNER",
                   help="offline gradient-steps/s rows (offline.experiment.bench), e.g. atac")
    p.add_argument("--offline-seeds", nargs="+", type=int, default=[1, 8],
                   help="vmapped seed counts of the offline rows")
    p.add_argument("--peers", nargs="*", default=None, metavar="LAYOUT",
                   help="only PPO peers side by side (ours, brax, rejax) on three_link/env3 at "
                        "layouts thesis and/or gpu (none given: thesis); results/peers")
    p.add_argument("--peer-trainers", nargs="+", default=list(TRAINERS), choices=TRAINERS)
    p.add_argument("--peer-iterations", type=int, default=None,
                   help="PPO iterations per trainer (default 8; --quick 2)")
    p.add_argument("--peer-chunk", type=int, default=None,
                   help="iterations per timed chunk (default 2; --quick 1)")
    p.add_argument("--peer-episodes", type=int, default=None,
                   help="evaluation episodes of each final policy (default 64; --quick 4)")
    p.add_argument("--peer-set", nargs="*", default=[], metavar="FIELD=VALUE",
                   help="overrides of the thesis PPO preset for every trainer")
    args = p.parse_args(argv)
    if args.pin_cpu is not None:
        # Threads XLA creates later inherit this affinity: no hand-offs between cores.
        os.sched_setaffinity(0, {args.pin_cpu})
    settings = fill_defaults(vars(args))
    for name in ("batches", "naive_batches"):
        if any(b < 1 for b in settings[name]):
            p.error(f"--{name.replace('_', '-')} must be positive integers")
    if settings["repeats"] < 1 or settings["latency_calls"] < 1:
        p.error("--repeats and --latency-calls must be >= 1")
    return settings


def main(argv: Sequence[str] | None = None) -> dict:
    """Run the benchmark, print the table, write the JSON and return it."""
    settings = parse_args(argv)
    command = " ".join(["python scripts/bench.py", *(argv if argv is not None
                                                     else sys.argv[1:])])
    if settings["peers"] is not None:
        return {"summary": str(run_from_settings(settings, command, ROOT / "results" / "peers"))}
    return run_benchmark(settings, command, ROOT / "results" / "rmp2_evaluation",
                         offline_measure=measure_offline)


if __name__ == "__main__":
    main()
