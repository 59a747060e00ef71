"""Learn stable LASA dynamics with Euclideanizing flows (thesis §4.2, Figs 4.4 and 4.7).

Usage::

    python scripts/lfd_lasa.py --shapes Angle Sshape [--iterations N] [--seed 0] \\
        [--out results/lfd_lasa/run]
    python scripts/lfd_lasa.py --all [...]

Every requested shape is trained in one compiled program and checked as
:mod:`agents.lfd.lasa_eval` describes. Model and optimiser are
:class:`agents.lfd.config.LfdConfig`'s defaults (docs/design.md §4.6); ``--iterations``
overrides the iteration budget (default 5000, early stop after 250 iterations without
improvement), ``--tiny`` uses :meth:`LfdConfig.tiny` (tests). ``--time-epochs N`` only times
``N`` full-batch training epochs on Sshape after compilation (prints the median and the load
average) and trains nothing.

Writes to ``--out`` (one folder: ``tar czf lasa.tgz -C DIR .``):

* ``<shape>.npz`` — ``demos (7, T, 2)``, ``rollouts (7, K, 2)`` (the learned system from each
  demonstration's first sample with the demonstrations' ``dt`` for ``K − 1 = ⌈1.2·(T − 1)⌉``
  steps, i.e. over 1.2 × the demonstration's duration ``(T − 1)·dt``: 282 samples for
  ``T = 235``), ``dt`` (scalar), ``losses`` (training loss per iteration). The arrival check
  reads ``‖rollouts[:, -1]‖ < 0.01``; the first ``T`` samples are the reproduction compared with
  the demonstration at equal times;
* ``metrics.json`` — per shape the trajectory metrics (``rmse`` at equal times), the
  straight-line baseline, the arrival check, the training summary, the converged end points and
  the convergence check; ``summary``: medians over shapes with one row per shape (also printed
  as a table; :mod:`agents.lfd.lasa_summary`);
* ``<shape>_field.png`` and ``<shape>_potential.png`` (as Figs 4.4 and 4.7).

``--study DIR`` also writes the study record ``DIR/summary.json`` and ``DIR/table.csv``
(:func:`agents.lfd.lasa_summary.write_study`; ``results/lfd_lasa``, then
``python scripts/report.py``).

``--save-skills DIR`` also saves each trained field as a reloadable, exportable skill
``DIR/<shape>/`` (:func:`agents.lfd.skills.save_lasa_skills`; ``scripts/export.py --skill``).

A training loss or parameter that turns non-finite stops the script with exit status 3 and one
line naming the iteration and the shape; nothing is written.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import jax
import numpy as np

from agents.lfd.config import LATENT_POTENTIALS, LfdConfig
from agents.lfd.figures import plot_lasa, plot_lasa_overview
from agents.lfd.lasa_eval import canonical_shapes, evaluate_shapes, time_epochs
from agents.lfd.lasa_summary import write_study
from agents.lfd.skills import save_lasa_skills
from mjxrmp import _xla  # sets the XLA:CPU flag before JAX initialises
from mjxrmp.data.lasa import LASA_SHAPES
from mjxrmp.divergence import EXIT_DIVERGED, DivergenceError

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)

log = functools.partial(print, flush=True)
#: The all-shapes figure beside the study's summary.json (``--study``).
OVERVIEW = "lasa_all_fields.png"


def _check_steps(value: str) -> int | str:
    """``--check-steps``: a positive integer or ``"auto"``."""
    if value == "auto":
        return value
    try:
        steps = int(value)
    except ValueError:
        steps = 0
    if steps < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer or 'auto', got {value!r}")
    return steps


def parse_args(argv: list[str] | None) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    """The parser and the parsed command line."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = p.add_mutually_exclusive_group()
    g.add_argument("--shapes", nargs="+", metavar="SHAPE", help="LASA shape names")
    g.add_argument("--all", action="store_true", help="all 30 LASA shapes")
    p.add_argument("--iterations", type=int, default=None,
                   help="gradient steps (default: LfdConfig's 5000, with early stop)")
    p.add_argument("--time-weight", type=float, default=None,
                   help="weight of the arrival-time loss (default: LfdConfig's; 0: velocities "
                        "only)")
    p.add_argument("--latent-potential", choices=LATENT_POTENTIALS, default=None,
                   help="latent potential (default: LfdConfig's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="results/lfd_lasa/run")
    p.add_argument("--log-every", type=int, default=100, help="iterations per compiled chunk")
    p.add_argument("--tiny", action="store_true", help="LfdConfig.tiny() (tests)")
    p.add_argument("--check-starts", type=int, default=64)
    p.add_argument("--check-steps", type=_check_steps, default=None,
                   help="rollout steps of the convergence check and of the converged "
                        "demonstration rollouts: a number, or 'auto' = the guaranteed arrival "
                        "bound of every start (agents.lfd.flow_field.arrival_steps; latent "
                        "integrator); default 10·T")
    p.add_argument("--goal-radius", type=float, default=0.05,
                   help="convergence radius of the check (normalised units)")
    p.add_argument("--no-figures", action="store_true")
    p.add_argument("--study", default=None, metavar="DIR",
                   help="also write the study summary DIR/summary.json and table.csv "
                        "(e.g. results/lfd_lasa)")
    p.add_argument("--save-skills", default=None, metavar="DIR",
                   help="also save every trained shape as a reloadable skill DIR/<shape>/ "
                        "(agents.lfd.skills; default: off)")
    p.add_argument("--time-epochs", type=int, default=None, metavar="N",
                   help="only time N full-batch training epochs on Sshape (after compilation) "
                        "and print their median")
    return p, p.parse_args(argv)


def main(argv: list[str] | None = None) -> dict:
    """Train the selected shapes, roll out, check convergence, write files; return metrics."""
    # docs/design.md §5.4: GPUs default to TF32 matrix products. Their ~1e-3 relative error
    # breaks the flow's exact inverse (ψ(ψ⁻¹(y)) ≠ y), so the latent rollout's monotone ‖ψ‖ held
    # on only 2 of 30 shapes on an H100; with full float32 products it holds on all 30.
    jax.config.update("jax_default_matmul_precision", "highest")
    p, args = parse_args(argv)
    config = LfdConfig.tiny() if args.tiny else LfdConfig()
    if args.time_epochs is not None:
        if args.time_epochs < 1:
            p.error(f"--time-epochs must be >= 1, got {args.time_epochs}")
        return time_epochs(config, args.time_epochs, args.seed, log=log)
    if not (args.all or args.shapes):
        p.error("one of --shapes, --all or --time-epochs is required")
    try:
        names = list(LASA_SHAPES) if args.all else canonical_shapes(args.shapes)
    except ValueError as err:
        p.error(str(err))
    for flag in ("iterations", "log_every", "check_starts"):
        val = getattr(args, flag)
        if val is not None and val < 1:
            p.error(f"--{flag.replace('_', '-')} must be >= 1, got {val}")
    if not args.goal_radius > 0:
        p.error(f"--goal-radius must be > 0, got {args.goal_radius}")
    changes = {k: getattr(args, k) for k in ("iterations", "time_weight", "latent_potential")
               if getattr(args, k) is not None}
    try:
        config = config.replace(**changes)
    except ValueError as err:
        p.error(str(err))
    os.makedirs(args.out, exist_ok=True)

    try:
        run = evaluate_shapes(names, config, seed=args.seed, log_every=args.log_every,
                              check_starts=args.check_starts, check_steps=args.check_steps,
                              goal_radius=args.goal_radius, log=log)
    except DivergenceError as err:
        print(f"error: {err}; nothing written to {args.out}", file=sys.stderr)
        sys.exit(EXIT_DIVERGED)
    losses = np.asarray(run.result.losses)
    for i, name in enumerate(names):
        np.savez(os.path.join(args.out, f"{name}.npz"), demos=run.data["demos"][i],
                 rollouts=run.rollouts[i], dt=np.float32(run.data["dt"][i]),
                 losses=losses[i].astype(np.float32))
    with open(os.path.join(args.out, "metrics.json"), "w") as f:
        json.dump(run.record, f, indent=1)
    if not args.no_figures:
        plot_lasa(run, args.out)
    if args.study is not None:
        command = " ".join(["python", "scripts/lfd_lasa.py",
                            *(sys.argv[1:] if argv is None else argv)])
        os.makedirs(args.study, exist_ok=True)
        if not args.no_figures:
            plot_lasa_overview(run, os.path.join(args.study, OVERVIEW))
        write_study(args.study, run.record, command,
                    figures=() if args.no_figures else (OVERVIEW,))
    if args.save_skills is not None:
        save_lasa_skills(args.save_skills, names, config, run.result.variables, args.seed)
    print(f"wrote {args.out}/ ({run.record['train_seconds']:.0f} s training)")
    return run.record


if __name__ == "__main__":
    main()
