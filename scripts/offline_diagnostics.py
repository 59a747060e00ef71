"""Offline diagnostics behind the claims of ``results/offline`` and ``results/ch7``
(:mod:`offline.experiment.diagnostics`).

::

    # one control step's effect on the expert's discounted return (64 scenes, gamma 0.99)
    python scripts/offline_diagnostics.py action-gap --t0 0 --env three_link/env3 --substeps 24
    # ATAC (true reward) vs BC on `mixed`, scored after every chunk; also --program bc|topbc
    python scripts/offline_diagnostics.py atac-vs-bc --program atac --actor-lr 5e-6 \\
        --betas 1 16 --steps 80000 --warm 8000 --chunk 16000
    # BC on each source of the chapter-7 `mixed` data (reproduce_ch7.py --stage collect)
    python scripts/offline_diagnostics.py bc-sources DATA_DIR franka --steps 50000
    # BC of N expert episodes
    python scripts/offline_diagnostics.py bc-scale --steps 20000 --episodes 400 4000

Each run appends one JSON line (its flags under ``"args"``) to ``--out`` (default
``runs/offline_diagnostics/<subcommand>.jsonl``). ``atac-vs-bc`` collects its ``mixed`` dataset
once into ``--data`` (default under ``runs/offline_diagnostics/data/``) and reuses it.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla  # sets the XLA:CPU flag before JAX initialises

# isort: split
from offline.experiment import diagnostics

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)

OUT_DIR = os.path.join("runs", "offline_diagnostics")
SUBSTEPS_HELP = ("physics substeps per control step (default: the environment's own); the "
                 "horizon keeps the episode's length in seconds")


def _add_action_gap(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("action-gap", help="the expert's one-step action gap")
    p.add_argument("--t0", type=int, default=0, help="expert steps before the branching step")
    p.add_argument("--env", default="three_link/env3")
    p.add_argument("--substeps", type=int, default=None, help=SUBSTEPS_HELP)
    p.add_argument("--scenes", type=int, default=64)
    p.add_argument("--seed", type=int, default=3)
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--horizon", type=int, default=400, help="expert steps after the branch")


def _add_atac_vs_bc(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("atac-vs-bc", help="ATAC (true reward) vs BC learning curves on mixed")
    p.add_argument("--program", choices=diagnostics.CURVE_PROGRAMS, required=True)
    p.add_argument("--env", default="three_link/env3")
    p.add_argument("--scale", type=int, default=100, help="episodes per source of mixed")
    p.add_argument("--data", default=None, help="cached mixed dataset (.npz)")
    p.add_argument("--steps", type=int, default=100_000)
    p.add_argument("--warm", type=int, default=10_000, help="ATAC's BC warm-start steps")
    p.add_argument("--chunk", type=int, default=20_000, help="steps between curve points")
    p.add_argument("--actor-lr", type=float, default=5e-7)
    p.add_argument("--betas", type=float, nargs="+", default=[16.0])
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--top", type=float, default=0.5, help="topbc: fraction of episodes kept")
    p.add_argument("--actor", default="nn_residual")
    p.add_argument("--hidden", type=int, nargs="+", default=[256, 256, 256])
    p.add_argument("--eval-episodes", type=int, default=64)
    p.add_argument("--substeps", type=int, default=None, help=SUBSTEPS_HELP)


def _add_bc(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bc-sources", help="BC on each source of the chapter-7 mixed data")
    p.add_argument("data", help="data folder of reproduce_ch7.py --stage collect")
    p.add_argument("env")
    p.add_argument("--steps", type=int, default=50_000)
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--substeps", type=int, default=24, help=SUBSTEPS_HELP)
    p.add_argument("--actor", default="nn_residual")
    p.add_argument("--eval-episodes", type=int, default=64)
    p = sub.add_parser("bc-scale", help="BC of N expert episodes")
    p.add_argument("--steps", type=int, required=True)
    p.add_argument("--episodes", type=int, nargs="+", required=True)
    p.add_argument("--env", default="three_link/env3")
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--substeps", type=int, default=None, help=SUBSTEPS_HELP)
    p.add_argument("--actor", default="mlp")
    p.add_argument("--eval-episodes", type=int, default=64)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The subcommand and its flags; default ``--out`` (and ``--data`` of ``atac-vs-bc``)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    for add in (_add_action_gap, _add_atac_vs_bc, _add_bc):
        add(sub)
    for parser in sub.choices.values():
        parser.add_argument("--out", default=None, help="JSON-lines file to append to")
    args = p.parse_args(argv)
    if args.out is None:
        args.out = os.path.join(OUT_DIR, f"{args.command}.jsonl")
    if args.command == "atac-vs-bc" and args.data is None:
        tag = "" if args.substeps is None else f"_substeps_{args.substeps}"
        args.data = os.path.join(OUT_DIR, "data", f"{args.env.replace('/', '-')}_mixed_"
                                 f"x{args.scale}_s0{tag}.npz")
    return args


def main(argv: Sequence[str] | None = None) -> dict:
    """Run the subcommand and append its result to ``--out``."""
    args = parse_args(argv)
    result = diagnostics.run_command(args)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "a") as f:
        f.write(json.dumps(result) + "\n")
    print(f"→ {args.out}", flush=True)
    return result


if __name__ == "__main__":
    main()
