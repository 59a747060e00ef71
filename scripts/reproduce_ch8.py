"""Chapter 8 on our reaching task: offline RL with wrong rewards on data with and without
length bias (thesis §8.3–8.4.1, Figs 8.4–8.6, eq 8.3), and safety from filtered data (§8.4.2).

::

    # CPU smoke (minutes): one recipe, 2 seeds, tiny networks
    python scripts/reproduce_ch8.py
    # GPU, one H100 in one call: collect, then 3 training processes side by side, then figures
    export XLA_PYTHON_CLIENT_MEM_FRACTION=0.3
    python scripts/reproduce_ch8.py --preset gpu --stage collect
    python scripts/reproduce_ch8.py --preset gpu --stage train --learners ATAC BC > a.log 2>&1 &
    python scripts/reproduce_ch8.py --preset gpu --stage train --learners PSPI > b.log 2>&1 &
    python scripts/reproduce_ch8.py --preset gpu --stage train --learners IQL CQL > c.log 2>&1 &
    wait; python scripts/reproduce_ch8.py --preset gpu --stage figures

The GPU preset (2 recipes → 4 datasets + the filtered one; 30 k steps; 3×256 networks; 5 seeds;
64 evaluation episodes) is 4 × 4 programs of 20 runs plus 2 of 5 runs and BC: 9.9 M
seed-steps. Each training process prints ``[time]`` lines (train and evaluation seconds per
program) to tune ``--steps``; a process cut off by a time limit loses only the program in
flight (finished cells are in ``results.jsonl``; rerun the same command to continue).

Datasets (3-link ``three_link/env3``, :func:`offline.data.collect.collect_recipe` without a PPO run,
i.e. its documented fallback sources, or with ``--ppo-run RUN_DIR`` that run's snapshots): for every
recipe of ``--recipes`` (default ``mixed`` and ``medium-replay``) ``<recipe>-cut`` — episodes cut at
the first collision (a terminal): the length bias of §8.3.3 — and ``<recipe>-full`` —
``cut_at_collision=False``, every episode runs the full horizon (no length bias, like D4RL's
halfcheetah in §8.4.1). With ``--goal-deadline N``
also ``<recipe>-deadline``: the ``-cut`` data with every episode that has not reached the goal
by its ``N``-th step cut there as a terminal (:func:`offline.survival.rewards.cut_before_goal`, the
"timeout-before-goal" cut: a designed, strong length bias); it counts as length-biased in (a)
and (b). With ``--goal-deadline N`` also ``<recipe>-goal``: the same transitions with the goal
as the only absorbing state (:func:`offline.survival.rewards.absorbing_goal`): an episode that ends
within the success radius ends in a terminal, every other one (deadline cut, collision, or
horizon) in a timeout — §8.4.1's goal-oriented length bias (successes unbounded, failures
bounded), with the failures' terminals removed as in the thesis's footnote 4 on hopper and
walker2d; the ``-deadline`` data instead makes the *failures* absorbing. Length-biased in (a)
and (b) as well. And ``<recipe>-arrive``: as ``-goal``, but a successful episode ends with its
terminal at its first transition into the goal region (``absorbing_goal(..., at_arrival=True)``),
as the thesis's Meta-World data do, rather than after lingering there; also length-biased.
With ``--safety`` (on by default) also ``<safety-dataset>-filtered``:
:func:`offline.survival.filtering.filter_collision_margin` of ``--safety-dataset`` (default
``mixed-full``, whose colliding episodes run on through the obstacles) with ``--margin`` (default
the reward's δ = 0.05 m: exactly the transitions with a non-zero obstacle cost are removed, §8.4.2's
"remove all transitions with non-zero cost").

Stages (``--stage all`` runs them in order; each is resumable; :mod:`offline.survival.ch8`,
:mod:`offline.survival.ch8_train`, :mod:`offline.survival.ch8_report`):

1. **collect** — the ``-cut`` / ``-full`` datasets, cached as checksummed files in ``OUT/data``.
2. **train** — per dataset × learner: ATAC, PSPI, IQL and CQL with every data reward of
   ``--rewards`` (original / zero / random U[0,1] / negated,
   :func:`offline.survival.rewards.variant`, terminals ``--terminals keep`` or ``remove``) and
   ``--seeds`` seeds in **one** vmapped program (:func:`offline.survival.sweep.reward_batched`), and
   BC (reads no reward) once per dataset; the filtered dataset gets the original reward only, and
   only ATAC, PSPI and BC. ``--steps`` gradient steps (:class:`offline.learners.registry.Budget`),
   then the last iterate of every run is evaluated on
   ``--eval-episodes`` episodes (:mod:`offline.experiment.evaluate`: normalised score — uniform
   random 0, hand-designed expert 100 — safe %, success %). One JSON line per (dataset, learner,
   reward) cell in ``OUT/results.jsonl``; cells already there are skipped, so processes split by
   ``--datasets`` / ``--learners`` / ``--rewards`` can share ``OUT``. With ``--checkpoints
   DIR`` every program's state is also saved after each ``--chunk`` steps, and a program
   interrupted (e.g. by a time limit) continues from its last chunk when run again. With
   ``--curve`` every run is also evaluated after each chunk, the same way as its last iterate;
   the rows then carry ``curve`` (steps and per-seed results per step).
   With ``--reward-form goal`` the true reward is used in the goal-oriented form of the
   thesis's goal-oriented experiments (§7.4.2, §8.4.1;
   :func:`offline.survival.rewards.goal_oriented`): ``r − r_max ≤ 0``, so that the negated reward is
   ``r_max − r ≥ 0``. It changes the ``original`` and ``negated`` cells (their keys carry the form);
   the zero and random cells are the same data and keep their keys, so they are shared with
   ``--reward-form env``. The evaluation is unchanged (the environment's return, normalised).
   ``--beta B`` trains ATAC and PSPI at Bellman weight ``B`` instead of their config's 16 (smaller
   is more pessimistic; their cells get their own key, the other learners' keep theirs).
3. **figures** — ``fig8_4.png`` (rows datasets, columns learners, bars per reward: normalised
   score ± s.e. over seeds, BC as a dashed line), ``fig8_5.png`` (episode length vs return per
   dataset, :func:`offline.survival.rewards.length_bias_statistics`, correlation in the title),
   ``fig8_6.png`` (eq 8.3 positive-data-bias estimate per dataset and learner; ∞ drawn as a
   capped, labelled bar), ``fig8_curves.png`` (score against gradient steps, for cells trained
   with ``--curve``), ``table.md`` / ``table.csv``, ``safety.md`` / ``safety.json`` and
   ``summary.json`` with the acceptance checks computed from the results:

   (a) "well above BC": the mean over the three wrong rewards of a learner's mean score is at
       least BC's mean score + :data:`offline.survival.ch8.WELL_ABOVE` (10) points. Checked for ATAC
       and PSPI: it should hold on every ``-cut`` dataset and on no ``-full`` dataset;
   (b) the eq 8.3 estimate (from mean normalised scores, ``Ĵ* = 100``) of ATAC and PSPI is
       larger on ``<recipe>-cut`` (and the deadline modes) than on ``<recipe>-full`` (∞ >
       any finite value);
   (safety) on the filtered dataset, the collision rate (100 − safe %) of ATAC and PSPI is
       below that of BC on ``--safety-dataset`` and below their own on the unfiltered data.
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
from offline.survival import ch8, ch8_report

_xla.configure_script()  # XLA:CPU flag and compile cache (docs/design.md §5.6)

ROOT = Path(__file__).resolve().parent.parent


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command-line options (:data:`offline.survival.ch8.OPTIONS`), preset applied."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for option in ch8.OPTIONS:
        p.add_argument(*option.flags, **option.spec)
    p.add_argument("--out", type=Path, default=ROOT / "runs" / "ch8",
                   help="working folder: datasets, checkpoints, results.jsonl, figures")
    args = p.parse_args(argv)
    try:
        return ch8.check_args(args)
    except ValueError as e:
        p.error(str(e))


def main(argv: Sequence[str] | None = None) -> None:
    """Run the selected stages."""
    ch8_report.run(parse_args(argv))


if __name__ == "__main__":
    main()
