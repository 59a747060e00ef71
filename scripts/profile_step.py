"""Profile the reaching environments' control step: each phase timed alone against the physics
floor, GPU kernels per control step, and the joint-limit checks of dropping MuJoCo's
constraint stages (the hand-designed policy and, with ``--trained``, a trained one).

Writes ``results/performance/summary.json`` and ``table.csv`` (the ``performance`` study of
``BENCHMARKS.md``; findings in ``docs/reports/performance.md``), keeping the environments of an
earlier study there that this command does not profile, each with its own command. The
measurements live in :mod:`agents.bench.profile`. Meant for a GPU; on a CPU the kernel counts
are left out.

Examples::

    python scripts/profile_step.py                                  # both robots, 512 envs
    python scripts/profile_step.py --envs franka --batch 4096 --episodes 0
    python scripts/profile_step.py --trained franka=runs/franka_rmp_residual
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
from agents.bench.profile import run_profile  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str] | None = None) -> int:
    """Parse the arguments, profile, write the study; the exit status."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--envs", nargs="+", default=["three_link/env3", "franka"],
                   help=f"environments; any of {sorted(envs.ENVIRONMENTS)}")
    p.add_argument("--batch", type=int, default=512, help="environments per batch")
    p.add_argument("--steps", type=int, default=128, help="control steps per timed call")
    p.add_argument("--repeats", type=int, default=7, help="timed calls (median reported)")
    p.add_argument("--episodes", type=int, default=1024,
                   help="episodes of the joint-limit check (0 skips it)")
    p.add_argument("--horizon", type=int, default=600, help="control steps per episode")
    p.add_argument("--trained", action="append", default=[], metavar="ENV=RUN_DIR",
                   help="also limit-check the policy of this training run (repeatable)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=ROOT / "results" / "performance")
    args = p.parse_args(argv)
    bad = [e for e in args.envs if e not in envs.ENVIRONMENTS]
    if bad:
        p.error(f"unknown --envs {bad}; valid names are {sorted(envs.ENVIRONMENTS)}")
    for name in ("batch", "steps", "repeats", "horizon"):
        if getattr(args, name) < 1:
            p.error(f"--{name} must be a positive integer, got {getattr(args, name)}")
    if args.episodes < 0:
        p.error(f"--episodes must be >= 0, got {args.episodes}")
    trained = dict(item.split("=", 1) for item in args.trained if "=" in item)
    if len(trained) != len(args.trained) or not set(trained) <= set(args.envs):
        p.error(f"--trained takes ENV=RUN_DIR with ENV among --envs {args.envs}, got "
                f"{args.trained}")
    command = " ".join(["python scripts/profile_step.py", *(argv if argv is not None
                                                            else sys.argv[1:])])
    path = run_profile(args.envs, args.batch, args.steps, args.repeats, args.episodes,
                       args.horizon, args.seed, args.out, command, trained)
    print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
