"""Summarise ``scripts/lfd_franka.py`` runs that differ only in ``--seed`` (thesis §5.3.2, Fig 5.7).

Usage::

    python scripts/lfd_franka_seeds.py RUN_DIR [RUN_DIR ...] --out results/lfd_franka/seeds \\
        [--reference joint]

Each ``RUN_DIR`` holds the ``metrics.json`` of one ``lfd_franka.py`` run; the runs must agree on
every setting but the seed. The ``--reference`` strategy is compared with every other one,
paired by seed (:mod:`agents.lfd.seeds`). Writes ``seeds.json`` and ``seeds.png`` (per-seed values
with their mean, one panel per task and metric) to ``--out`` and prints the markdown tables.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

if __package__ in (None, ""):
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from agents.lfd.figures import plot_seeds
from agents.lfd.seeds import load_runs, markdown, summarise
from mjxrmp import _xla
from mjxrmp.results.summary import write_text

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)


def main(argv: list[str] | None = None) -> dict:
    """Summarise the runs; write ``seeds.json`` and ``seeds.png`` and print the markdown tables."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="+", help="output directories of scripts/lfd_franka.py runs")
    p.add_argument("--out", default="results/lfd_franka/seeds")
    p.add_argument("--reference", default="joint",
                   help="strategy compared with every other one (default: %(default)s)")
    args = p.parse_args(argv)
    summary = summarise(load_runs(args.runs), args.reference)
    os.makedirs(args.out, exist_ok=True)
    write_text(os.path.join(args.out, "seeds.json"), json.dumps(summary, indent=1))
    text = markdown(summary)
    plot_seeds(os.path.join(args.out, "seeds.png"), summary)
    print(text, end="")
    return summary


if __name__ == "__main__":
    main()
