"""Time training end to end as a user meets it: ``scripts/train.py`` as a fresh process, from
launch to exit, and a repeated one-iteration command with the compile cache cold and warm.

Writes ``results/training_speed/summary.json`` and ``table.csv`` (findings in
``docs/reports/training_speed.md``); the measurements live in :mod:`agents.bench.end_to_end`.
Meant for a GPU (the thesis preset); ``--preset cpu --iterations 2`` is a quick check here.

Examples::

    python scripts/bench_training.py --runs three_link/env3:rmp_residual franka:rmp_residual
    python scripts/bench_training.py --preset cpu --iterations 2 --out /tmp/speed
    python scripts/bench_training.py --first-iteration-only --warm-runs 3 --out /tmp/first
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla

_xla.configure_script()

import envs  # noqa: E402
from agents.bench.end_to_end import run_training_speed  # noqa: E402
from agents.ppo import KINDS  # noqa: E402
from agents.run.spec import PRESETS  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str] | None = None) -> int:
    """Parse the arguments, time the runs, write the study; the exit status."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", nargs="+", default=["three_link/env3:rmp_residual"],
                   metavar="ENV:POLICY", help="what to train")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    p.add_argument("--iterations", type=int, default=500)
    p.add_argument("--preset", default="thesis", help=f"one of {sorted(PRESETS)}")
    p.add_argument("--work", type=Path, default=ROOT / "runs" / "bench_training",
                   help="scratch folder for the run directories and the cache")
    p.add_argument("--out", type=Path, default=ROOT / "results" / "training_speed")
    p.add_argument("--no-first-iteration", dest="first", action="store_false",
                   help="time only the whole run, not the repeated one-iteration command")
    p.add_argument("--first-iteration-only", dest="full", action="store_false",
                   help="time only the repeated one-iteration command, not the whole run")
    p.add_argument("--warm-runs", type=int, default=1, metavar="N",
                   help="repeat the one-iteration command and the resumed one N times each "
                        "with the warm cache (the medians are reported)")
    args = p.parse_args(argv)
    items = [tuple(r.split(":", 1)) if ":" in r else (r, "rmp_residual") for r in args.runs]
    for env, policy in items:
        if env not in envs.ENVIRONMENTS or policy not in KINDS:
            p.error(f"--runs takes ENV:POLICY with ENV in {sorted(envs.ENVIRONMENTS)} and "
                    f"POLICY in {list(KINDS)}, got {env}:{policy}")
    if args.preset not in PRESETS:
        p.error(f"unknown --preset {args.preset!r}; valid presets are {sorted(PRESETS)}")
    if not (args.first or args.full):
        p.error("--no-first-iteration and --first-iteration-only leave nothing to time")
    if args.warm_runs < 1:
        p.error(f"--warm-runs must be a positive integer, got {args.warm_runs}")
    if args.iterations < 1:
        p.error(f"--iterations must be a positive integer, got {args.iterations}")
    command = " ".join(["python scripts/bench_training.py",
                        *(argv if argv is not None else sys.argv[1:])])
    path = run_training_speed(items, args.seeds, args.iterations, args.preset, args.work,
                              args.out, command, args.first, args.full, args.warm_runs)
    print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
