"""Reproduce thesis Figs 3.2 and 3.3: RMP²-CLF vs RMPflow-GDS on 2-D point robots (§3.2.7).

The simulations, metrics and figures are :mod:`mjxrmp.studies.ch3` and
:mod:`mjxrmp.studies.ch3_figures`. Writes ``fig3_2.png``, ``fig3_3.png`` and ``fig3_3.json``
to ``--out`` and prints the goal errors and times to goal.

Usage: ``python scripts/reproduce_ch3.py [--out results/ch3] [--steps 6000]``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla
from mjxrmp.studies import ch3
from mjxrmp.studies.ch3_figures import SAVE_KWARGS, figures

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)


def main(argv: list[str] | None = None) -> dict:
    """Parse the arguments, run both figures, write the outputs; returns the JSON record."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results/ch3", help="output directory")
    parser.add_argument("--steps", type=int, default=6000,
                        help="integration steps (dt = 0.01) for Fig 3.3; Fig 3.2 uses 2/3 of it")
    parser.add_argument("--robots", type=int, default=ch3.SWAP_ROBOTS)
    parser.add_argument("--tol", type=float, default=0.05, help="goal tolerance for Fig 3.3")
    parser.add_argument("--seeds", type=int, default=4,
                        help="start-noise seeds for Fig 3.3 (the first is plotted)")
    args = parser.parse_args(argv)

    result = ch3.reproduce(steps=args.steps, robots=args.robots, tol=args.tol, seeds=args.seeds)
    os.makedirs(args.out, exist_ok=True)
    for name, fig in figures(result).items():
        fig.savefig(os.path.join(args.out, name), **SAVE_KWARGS)
    with open(os.path.join(args.out, "fig3_3.json"), "w") as fh:
        json.dump(result.record, fh, indent=2)
    print("\n".join(ch3.summary_lines(result)))
    return result.record


if __name__ == "__main__":
    main()
