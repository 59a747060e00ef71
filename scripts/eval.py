"""Evaluate training checkpoints: many checkpoints × setups × training seeds × episodes at once.

::

    python scripts/eval.py RUN_DIR [RUN_DIR ...] [--steps all|latest|N ...]
        [--setups three_link/env1 three_link/env2 three_link/env3 | franka]
        [--episodes 256] [--eval-seed 0] [--horizon H] [--json out.json] [--gif out.gif]

Every checkpoint (``--steps``, default ``latest``, of every run directory written by
``scripts/train.py``) acts with each training seed's deterministic policy for ``--episodes``
episodes of ``--horizon`` control steps (default: the environment's 600) on each setup (default:
the run's own environment). Checkpoints of the same environment and policy kind run as one
compiled call; every parameter set sees the same episodes (scenes from ``--eval-seed``). A
policy runs only on setups whose observations it can read (every 3-link setup has size 26, so
a 3-link policy runs on all three; the Franka's has 45). See :mod:`agents.run.evaluation` and
:mod:`agents.run.eval_report`.

**Output.** A table (run, iteration, setup, mean episode return ± std over training seeds,
success %, safe %, final goal distance) and, with ``--json``, every number: per training seed
and aggregated, the groups with their compile and run seconds. ``--gif`` renders episode 0 of
the best row (highest mean return; its best seed).

**Refusals.** ``latest``/``all`` skip corrupt checkpoints with a one-line warning naming them; a
corrupt checkpoint named by iteration, or one whose parameters hold NaN/inf (a diverged run),
ends the script with a one-line error and exit status 2: a diverged policy is never reported.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla

_xla.configure_script()

from agents.run.checkpoint import IncompatibleCheckpointError  # noqa: E402
from agents.run.eval_report import evaluate_runs, format_table  # noqa: E402
from agents.run.evaluation import SETUPS  # noqa: E402
from mjxrmp.results.summary import write_text  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    """CLI entry point (see the module docstring); returns the exit status."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run directories (train.py)")
    p.add_argument("--steps", nargs="+", default=["latest"],
                   help="checkpoints of every run: all, latest or iteration numbers")
    p.add_argument("--setups", nargs="+", default=None, choices=SETUPS,
                   help="setups to evaluate on (default: each run's own environment)")
    p.add_argument("--episodes", type=int, default=256, help="episodes per parameter set")
    p.add_argument("--eval-seed", type=int, default=0, help="seed of the evaluation scenes")
    p.add_argument("--horizon", type=int, default=None,
                   help="control steps per episode (default: the environment's, 600)")
    p.add_argument("--json", default=None, help="write every number to this JSON file")
    p.add_argument("--per-episode", action="store_true",
                   help="include the per-episode arrays in the JSON")
    p.add_argument("--gif", default=None, help="render episode 0 of the best checkpoint")
    args = p.parse_args(argv)
    if args.episodes < 1:
        p.error(f"--episodes must be >= 1, got {args.episodes}")
    if args.horizon is not None and args.horizon < 1:
        p.error(f"--horizon must be >= 1, got {args.horizon}")

    try:
        report = evaluate_runs(args.runs, args.steps, args.setups, args.episodes,
                               args.eval_seed, args.horizon, args.per_episode, args.gif,
                               stream=sys.stderr)
    except (FileNotFoundError, ValueError, IncompatibleCheckpointError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(format_table(report["rows"]))
    print(f"compile {report['compile_seconds']:.1f} s, run {report['run_seconds']:.1f} s "
          f"({len(report['groups'])} compiled call(s), {args.episodes} episodes per parameter "
          f"set, device {report['device']})")
    if report["gif"] is not None:
        b, g = report["best"], report["gif"]
        print(f"wrote {g['path']}: {os.path.basename(os.path.normpath(b['run']))} iteration "
              f"{b['iteration']} seed {g['seed']} on {g['setup']}, episode 0, return "
              f"{g['return']:.2f}")
    if args.json:
        write_text(args.json, json.dumps(report, indent=1, allow_nan=False))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
