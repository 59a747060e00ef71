"""Chapter 7 on our reaching tasks: offline PLfO (Table 7.2 scenarios) with MAHALO and the
baselines, scored in the MJX environment — a Table 7.3-style table.

::

    python scripts/reproduce_ch7.py                     # CPU-sized smoke run (env3 only)
    python scripts/reproduce_ch7.py --preset gpu        # 3-link env3 and Franka, 5 seeds
    python scripts/reproduce_ch7.py --stage table       # redraw the table from the results

Stages (``--stage all`` runs them in order; each is resumable; :mod:`offline.experiment.ch7`):

1. **collect** — per environment a ``mixed`` dataset (random + noisy experts;
   :mod:`offline.data.collect`, ``--scale`` episodes per source) and an ``expert`` dataset
   (``--expert-scale`` episodes, default ``--scale``), collected in the compiled graph and
   cached as checksummed files under ``OUT/data``.
2. **train** — for every environment × scenario (``ILfO IL RLfO RL-expert RL-sample``) ×
   learner (:data:`offline.learners.registry.TABLE_LEARNERS`) that has data in that scenario
   (:func:`offline.experiment.run.applicable`): ``--seeds`` seeds vmapped in one program,
   ``--steps`` gradient steps (:class:`offline.learners.registry.Budget`), then ``--eval-episodes``
   episodes per seed in the environment (:mod:`offline.experiment.evaluate`, normalised score:
   uniform random 0, hand-designed expert 100; last iterate). One JSON line per cell in
   ``OUT/results.jsonl``; cells already there are skipped. The Oracle reads only the dynamics
   data, so it is trained once per dynamics dataset (``D_X`` in ILfO, RLfO and RL-sample;
   ``D_X ∪ D_E`` in IL and RL-expert): a scenario whose sibling's Oracle row is already there
   gets a copy of that row, marked ``shared_from``. With ``--checkpoints DIR`` every
   cell's state is also saved after each ``--chunk`` steps, and a cell interrupted (e.g. by a
   time limit) continues from its last chunk when the command is run again. With ``--curve``
   every seed is also scored after each chunk, the same way as its last iterate (the rows'
   ``curve``: steps and per-seed results per step).
3. **table** — ``OUT/table.md`` and ``OUT/table.csv`` (of the ``--envs`` cells the same
   command's train stage makes: same steps, seeds, network, data and expert-set sizes,
   terminal handling, evaluation episodes, learner settings and control rate): mean ±
   standard error over seeds per cell; in each row the entries within 90 % of the best
   non-Oracle score are bold (thesis Table 7.3's rule).
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
from offline.experiment import ch7, ch7_table

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)

ROOT = Path(__file__).resolve().parent.parent


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command-line options (:data:`offline.experiment.ch7.OPTIONS`), preset applied."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for option in ch7.OPTIONS:
        p.add_argument(*option.flags, **option.spec)
    p.add_argument("--out", type=Path, default=ROOT / "runs" / "ch7",
                   help="working folder: datasets, checkpoints, results.jsonl, table")
    args = p.parse_args(argv)
    try:
        return ch7.check_args(args)
    except ValueError as e:
        p.error(str(e))


def main(argv: Sequence[str] | None = None) -> None:
    """Run the selected stages."""
    ch7_table.run(parse_args(argv))


if __name__ == "__main__":
    main()
