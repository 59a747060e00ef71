"""Learn RMP² policies from the real Franka demonstrations and compare the strategies of ch. 5.

Usage::

    python scripts/lfd_franka.py [--tasks door_reaching drawer_closing] \\
        [--strategies cspace independent joint single_link two_step] \\
        [--preset cpu|thesis|reference] [--root /work/shared/data/franka_demos] \\
        [--out results/lfd_franka/seed_0] [--figures results/lfd_franka] [--seed 0]
    python scripts/lfd_franka.py --quick --out /tmp/x --figures /tmp/x     # seconds (tests)

Leave-one-out training with restarts, reproduction error, success from new starts, task success
(the demonstrated corridor) and the cylinder obstacle, as :mod:`agents.lfd.franka_eval`
describes (settings: :class:`agents.lfd.franka_scenario.FrankaEvalConfig`, one field per flag).

Writes ``metrics.json`` (per task and strategy: per-fold errors per control point, success
counts, training time and final losses; the settings) and ``table.csv`` to ``--out``, and the
figures ``lfd_franka_<task>.png`` (demonstrated vs reproduced control-point triangles and
centre paths, 3-D, as Figs 5.1/5.4) and ``lfd_franka_errors.png`` (box plots of the errors, the
success rates and the corridor excursions per strategy, as Fig 5.7) to ``--figures``. A training
loss or parameter that turns non-finite stops the script with exit status 3 and one line naming
the strategy, the stage's iteration and the run; nothing is written.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import os
import sys
import time

if __package__ in (None, ""):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla

_xla.configure_script()

import jax  # noqa: E402

from agents.lfd.config import STRATEGIES  # noqa: E402
from agents.lfd.figures import plot_franka_errors, plot_franka_task  # noqa: E402
from agents.lfd.franka_eval import compare_strategies, table_lines  # noqa: E402
from agents.lfd.franka_scenario import FrankaEvalConfig  # noqa: E402
from mjxrmp.data import franka_demos  # noqa: E402
from mjxrmp.divergence import EXIT_DIVERGED, DivergenceError  # noqa: E402


def parse_args(argv: list[str] | None = None) -> tuple[argparse.Namespace, FrankaEvalConfig]:
    """The command line and the :class:`FrankaEvalConfig` it selects (invalid values exit)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--root", default=franka_demos.DEFAULT_ROOT,
                   help="demonstration directory (default: %(default)s)")
    p.add_argument("--tasks", nargs="+", default=list(franka_demos.TASKS),
                   choices=franka_demos.TASKS)
    p.add_argument("--strategies", nargs="+", default=list(STRATEGIES), choices=STRATEGIES)
    p.add_argument("--preset", default="cpu", choices=("cpu", "thesis", "reference", "tiny"),
                   help="StrategyConfig preset: cpu (default), thesis (full sizes, slow), "
                        "reference (thesis + the LASA code's clip 0.1 and early stop), tiny")
    p.add_argument("--flow-iterations", type=int, default=None, help="override stage 1 steps")
    p.add_argument("--metric-iterations", type=int, default=None, help="override stage 2 steps")
    p.add_argument("--dt", type=float, default=0.1, help="resampling step of the data (s)")
    p.add_argument("--exec-dt", type=float, default=0.05, help="rollout step (s)")
    p.add_argument("--folds", type=int, default=None,
                   help="hold out only the first N demonstrations (default: all)")
    p.add_argument("--num-starts", type=int, default=10, help="new initial configurations")
    p.add_argument("--perturbation", type=float, default=0.1,
                   help="std of the start perturbation per joint (rad)")
    p.add_argument("--horizon-factor", type=float, default=1.5,
                   help="success rollouts last this many longest-demonstration durations")
    p.add_argument("--success-radius", type=float, default=0.02, help="goal tolerance (m)")
    p.add_argument("--obstacle-radius", type=float, default=0.05, help="cylinder radius (m)")
    p.add_argument("--obstacle-clearance", type=float, default=-0.02,
                   help="smallest distance between the demonstrated motion and the cylinder "
                        "(m); negative: the demonstration would penetrate it by that much")
    p.add_argument("--free-margin", type=float, default=0.05,
                   help="clearance kept at the demonstration's start and goal, and at every "
                        "start of an obstacle rollout (m)")
    p.add_argument("--corridor-tolerance", type=float, default=0.05,
                   help="task success: largest excursion from the training demonstrations' "
                        "paths beyond the start's distance (m)")
    p.add_argument("--posture-weight", type=float, default=1.0,
                   help="weight of the execution-time posture leaf (0: off)")
    p.add_argument("--substeps", type=int, default=4,
                   help="Euler sub-steps per control step (agents.lfd.franka_eval)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--restarts", type=int, default=3,
                   help="models trained per fold; the first that reaches the goals from the "
                        "fold's own training starts is kept, else the closest (1: no selection)")
    p.add_argument("--matmul-precision", default="highest", choices=("highest", "default"),
                   help="float32 matrix products: highest (default) or the backend's default "
                        "(TF32 on Ampere/Hopper GPUs)")
    p.add_argument("--out", default="results/lfd_franka/seed_0")
    p.add_argument("--figures", default="results/lfd_franka")
    p.add_argument("--save-skills", default=None, metavar="DIR",
                   help="also save every kept fold model as a reloadable skill under "
                        "DIR/<task>/<strategy>/fold_<f>/ (agents.lfd.skills)")
    p.add_argument("--quick", action="store_true",
                   help="tests: tiny preset, 2 folds, 1 start, drawer task, joint strategy, "
                        "dt 0.5 s")
    args = p.parse_args(argv)
    if args.quick:
        args.preset, args.folds, args.num_starts = "tiny", 2, 1
        if args.tasks == list(franka_demos.TASKS):
            args.tasks = ["drawer_closing"]
        if args.strategies == list(STRATEGIES):
            args.strategies = ["joint"]
        args.dt, args.exec_dt, args.horizon_factor = 0.5, 0.25, 1.0
    fields = {f.name for f in dataclasses.fields(FrankaEvalConfig)}
    try:
        config = FrankaEvalConfig(**{k: v for k, v in vars(args).items() if k in fields})
    except ValueError as err:
        p.error(str(err))
    return args, config


def main(argv: list[str] | None = None) -> dict:
    """Run :func:`agents.lfd.franka_eval.compare_strategies`; write ``metrics.json``,
    ``table.csv`` and the figures; return ``{"settings", "tasks"}`` as written. Float32 matrix
    products run at ``--matmul-precision`` (``highest`` by default: on Ampere/Hopper GPUs the
    backend default is TF32, and with it the same seed's policies behaved differently on a GPU
    than on a CPU — docs/design.md §5.4)."""
    args, config = parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    os.makedirs(args.figures, exist_ok=True)
    t_start = time.time()

    def log(msg: str) -> None:
        print(f"[{time.time() - t_start:6.1f} s] {msg}", flush=True)

    with jax.default_matmul_precision(args.matmul_precision):
        try:
            result = compare_strategies(config, log, args.save_skills)
        except DivergenceError as err:
            print(f"error: {err}; nothing written to {args.out}", file=sys.stderr)
            sys.exit(EXIT_DIVERGED)
    for task in config.tasks:
        plot_franka_task(os.path.join(args.figures, f"lfd_franka_{task}.png"), task,
                         result.demos[task], result.folds[task], result.reproductions[task],
                         list(config.strategies))
    plot_franka_errors(os.path.join(args.figures, "lfd_franka_errors.png"), result.metrics)
    settings = dict(vars(args))
    settings["seconds"] = time.time() - t_start
    settings["devices"] = [str(d) for d in jax.devices()]
    with open(os.path.join(args.out, "metrics.json"), "w") as fh:
        json.dump({"settings": settings, "tasks": result.metrics}, fh, indent=1)
    with open(os.path.join(args.out, "table.csv"), "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(result.rows[0]))
        writer.writeheader()
        writer.writerows(result.rows)
    for line in table_lines(result.rows):
        log(line)
    log(f"done in {settings['seconds']:.0f} s; wrote {args.out} and {args.figures}")
    return {"settings": settings, "tasks": result.metrics}


if __name__ == "__main__":
    main()
