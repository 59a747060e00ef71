"""Reproduce thesis chapter 6: PPO with NN, NN-residual and RMP-residual policies on the 3-link
reaching setups env1/env2/env3 and the Franka, 4 seeds each; Fig 6.2 (mean episode reward),
Fig 6.3 (safe-episode %) and Fig 6.4 (Franka), mean ± 1 std over seeds.

Three stages, each resumable:

* ``train`` — for every (environment, policy) pair, a run directory ``<runs>/<env>_<policy>``
  trained by :func:`agents.run.training.run_training` (all seeds in one vmapped program); a
  finished run is skipped, an unfinished one resumed. Per-run speed (compile time, steps/s, the
  per-iteration split rollout / policy forward / update; one segment per launch) goes to
  ``<runs>/<env>_<policy>/speed.json``.
* ``baseline`` — the hand-designed RMP² policy evaluated on every setup
  (``--baseline-episodes`` deterministic episodes) into ``<runs>/hand_designed.json``.
* ``plot`` — reads every run's ``metrics.csv`` and writes ``fig6_2.png``, ``fig6_3.png``,
  ``fig6_4.png`` (the baseline dashed), ``ch6_summary.csv`` and ``ch6_summary.json`` (final
  reward, minimum and mean safe % over iterations, per policy and setup) and the study record
  ``summary.json`` / ``table.csv`` to ``--figures``. Curves and the minimum safe % use RLlib's
  reporting: each iteration averages the most recent ≥ 100 finished episodes
  (:func:`agents.run.curves.episode_window`); the per-iteration minimum is in the table too.

The stages are :func:`agents.run.ch6_study.reproduce`.

Usage::

    python scripts/reproduce_ch6.py --preset thesis                     # everything (GPU)
    python scripts/reproduce_ch6.py --preset thesis --envs three_link/env3 --policies rmp_residual
    python scripts/reproduce_ch6.py --stage baseline --runs results/ch6/runs    # CPU is fine
    python scripts/reproduce_ch6.py --stage plot --runs results/ch6/runs
    python scripts/reproduce_ch6.py --preset cpu --iterations 20        # a CPU-sized smoke run
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla  # sets the XLA:CPU flag before JAX initialises

# isort: split
from agents.run.ch6 import ENVS, LABELS, POLICIES
from agents.run.ch6_study import reproduce

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)


def main(argv: list[str] | None = None) -> int:
    """Parse the arguments and run the requested stages."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--stage", choices=("all", "train", "baseline", "plot"), default="all")
    p.add_argument("--envs", nargs="+", default=list(ENVS), choices=ENVS)
    p.add_argument("--policies", nargs="+", default=list(POLICIES), choices=list(LABELS))
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3])
    p.add_argument("--preset", default="thesis")
    p.add_argument("--iterations", type=int, default=None)
    p.add_argument("--runs", default="runs/ch6", help="directory of the run directories")
    p.add_argument("--figures", default="results/ch6", help="where figures and tables go")
    p.add_argument("--log-every", type=int, default=25)
    p.add_argument("--checkpoint-every", type=int, default=100)
    p.add_argument("--smooth", type=int, default=100,
                   help="curves average over the trailing iterations holding at least this many "
                        "episodes (RLlib's 100-episode smoothing; 1: per iteration)")
    p.add_argument("--baseline-episodes", type=int, default=1024,
                   help="episodes per setup of the hand-designed baseline")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--no-profile", action="store_true",
                   help="skip timing one iteration's phases into speed.json (it compiles them)")
    p.add_argument("--no-pack", action="store_true",
                   help="train every (setup, policy) as its own program (default: setups that "
                        "share a model, env2 and env3, × kinds that share a network, nn and "
                        "nn_residual, train packed in one program)")
    args = p.parse_args(argv)
    try:
        reproduce(args.stage, args.runs, args.figures, args.smooth, args.baseline_episodes,
                  envs=args.envs,
                  policies=args.policies, seeds=args.seeds, preset_name=args.preset,
                  iterations=args.iterations, log_every=args.log_every,
                  checkpoint_every=args.checkpoint_every, progress=not args.no_progress,
                  profile=not args.no_profile, pack=not args.no_pack)
    except FileNotFoundError as e:
        raise SystemExit(str(e)) from None
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
