"""Train one offline learner on one dataset or PLfO scenario, several seeds vmapped, then score it
in the MJX environment.

::

    python scripts/train_offline.py --learner MAHALO --env three_link/env3 --scenario ILfO
    python scripts/train_offline.py --learner IQL --dataset data/env3_mixed.npz --steps 100000
    python scripts/train_offline.py --learner BC --dataset minari:mjxrmp/env3-mixed-v0  # Minari
    python scripts/train_offline.py ... --resume          # continue from the last checkpoint
    python scripts/train_offline.py --learner Oracle --betas 0.25 1 4 16   # seeds × β, one program

Data: ``--dataset`` (a file written by ``scripts/collect.py``; its environment is read from the
file; or ``minari:ID_OR_FOLDER``, a local Minari dataset with Box spaces, read by
:func:`offline.data.minari.import_minari`) or, without it, a ``--recipe`` dataset of
``--scale`` episodes per source collected on ``--env`` (default ``mixed``). PLfO scenarios
(``--scenario ILfO|IL|RLfO|RL-expert|RL-sample``) also need expert data: ``--expert`` or an
``expert`` recipe collected the same way. Without a scenario the learner reads the dataset's own
rewards (``Oracle``/``PSPI``/``IQL``/``CQL``/``BC``).
Learners and what each reads: :mod:`offline.learners.registry`; the run:
:mod:`offline.experiment.single`.

Writes to ``--out``: ``metrics.csv`` (per chunk: steps, seed, every training metric),
``checkpoints/`` (orbax, every chunk; ``--resume`` continues from the newest and refuses one of
another learner, scenario or configuration, ``--normalize-observations`` and ``--actor``
included), and
``result.json`` (the configuration, wall times and the evaluation: mean return, normalised
score — random 0, expert 100 —, safe % and success % per run). A progress bar shows steps,
losses and the ETA. ``--betas`` (ATAC-type learners,
:data:`offline.learners.registry.BETA_LEARNERS`) trains every seed at every Bellman weight β in one
vmapped program (runs seed-major; ``beta`` in ``metrics.csv`` and ``result.json``) — ATAC's
per-dataset selection of β.

A run whose loss or parameters turn non-finite stops with exit status 3 and one line naming the
learner, the gradient step, the seed and the quantity (``metrics.csv`` and ``checkpoints/`` end
at the last finite chunk; no ``result.json``).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mjxrmp import _xla  # sets the XLA:CPU flag before JAX initialises

# isort: split
from mjxrmp.divergence import EXIT_DIVERGED, DivergenceError
from offline.experiment import single

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command-line options (:data:`offline.experiment.single.OPTIONS`), checked."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for option in single.OPTIONS:
        p.add_argument(*option.flags, **option.spec)
    args = p.parse_args(argv)
    try:
        return single.check_args(args)
    except ValueError as e:
        p.error(str(e))


def main(argv: Sequence[str] | None = None) -> dict:
    """Train, checkpoint, evaluate; print the scores and return the result dictionary."""
    args = parse_args(argv)
    try:
        result = single.train(args)
    except DivergenceError as err:
        print(f"error: {err}; result.json not written, only finite chunks were "
              f"checkpointed ({args.out / 'checkpoints'})", file=sys.stderr)
        sys.exit(EXIT_DIVERGED)
    print("\n".join(single.summary_lines(args, result)))
    return result


if __name__ == "__main__":
    main()
