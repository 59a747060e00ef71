"""Leave-one-out comparison of the chapter-5 strategies on the real Franka demonstrations
(thesis §5.3.2, Figs 5.1, 5.4, 5.7; ``scripts/lfd_franka.py``).

For each task (door reaching, drawer closing; 6 demonstrations each, §5.2.3) and each strategy
of :mod:`agents.lfd.strategies` (configuration-space regression, independent per-subtask
learning, joint learning through the velocity-form RMP², single-link learning, and the two-step
strategy of §5.2 — nominal-demonstration potential, then a metric by eq 5.6 — of
:mod:`agents.lfd.two_step`, whose potentials are fitted per fold on the host before the folds'
metrics train in one program; its "flow" loss is eq 4.12's objective, and its folds record the
nominal demonstration of each control point), :func:`compare_strategies` measures
(settings :class:`agents.lfd.franka_scenario.FrankaEvalConfig`, scenario
:mod:`agents.lfd.franka_scenario`, one strategy :mod:`agents.lfd.franka_folds`):

* **leave-one-out**: for every demonstration ``f`` a policy is trained on the other five. All
  folds are one compiled program (``vmap`` over the folds' sample weights and keys
  ``fold_in(PRNGKey(seed), f)``).
* **restarts** (``restarts``, 3): each fold is trained from that many keys in the same
  program. Each model is rolled out from the fold's own *training* demonstrations' starts (each
  to its own goals; posture leaf on, no obstacle); the first restart whose largest miss (over
  starts and control points) is within ``success_radius`` is kept, or, if none is, the one
  with the smallest miss. So restart 0 (the key of ``restarts=1``) is kept whenever it passes
  this check. The held-out demonstration is not used. (In a 10-seed run with one model per
  fold, 4 of 60 door models of the joint strategy had a stationary point 23–55 cm from the
  goal.)
* **reproduction error** (§5.3.2, Fig 5.7a): the policy is rolled out from the held-out
  demonstration's start toward its goals for the demonstration's duration; the mean position
  error of each of the three hand control points against the held-out demonstration (time
  aligned: :func:`mjxrmp.metrics.trajectory.mean_error`), averaged over the three points.
* **success from new starts** (§5.3.2, Fig 5.7c): ``num_starts`` configurations drawn around
  the held-out start, rolled out for ``horizon_factor`` × the longest demonstration's duration.
  Success = all three control points within ``success_radius`` (2 cm) of their goals at the
  end, no joint outside the model's limits at any time, finite.
* **task success** (the corridor test): a successful rollout from a new start must also never
  stray more than ``corridor_tolerance`` (5 cm) farther from the fold's *training*
  demonstrations' paths than it started. The excursions themselves (threshold-free) are
  reported and drawn as box plots. This test was added after the goal-only test gave 100 % for
  every strategy.
* **obstacle**: the same starts are run again with the cylinder placed across the held-out
  demonstration's path, avoided through the hand-designed collision RMP (§5.2.3). Success then
  also requires no collision. ``colliding_rollouts`` / ``obstacle_rollouts`` and the smallest
  clearance are reported per strategy, with the demonstration's own clearance per fold.

Every rollout runs the execution policy of :mod:`agents.lfd.execution` (learned leaves, the
default straight-line leaves of §5.3.2, and the execution-time leaves of
:class:`agents.lfd.config.ExecutionParams`: velocity-form joint limits, a posture leaf of
weight ``posture_weight`` towards the mean final configuration of the fold's *training*
demonstrations, the collision leaves in their velocity-form lift; the obstacle is switched off
by its ``active`` flag when absent) with step ``exec_dt`` and ``substeps`` Euler sub-steps
(4 by default: with one Euler step of 0.05 s the lifted collision leaf chattered at the
cylinder — clearance alternating 2.9/3.9 cm — and in some models the hand then sank through
it, 9 cm deep within five steps; at 0.0125 s the same model and start stay 1.6 cm clear).
The new starts are also run without the posture leaf (``success_rate_no_posture``, an
ablation): the posture target carries the demonstrations' final hand orientation, which helps
every strategy (single-link learning included), so that column shows what the learned leaves
achieve on their own.

Settings were chosen without the held-out demonstrations: the CPU preset's weight decay and the
posture weight were picked from rollouts of the door joint policies started at the *training*
demonstrations' starts (exact and perturbed) of every fold. The default (CPU preset, 2 tasks ×
5 strategies × 6 folds × 3 restarts, 4 sub-steps) takes about 13 minutes on 2 CPU cores (757 s
measured; 5–8 minutes with ``restarts=1, substeps=1``; the two-step strategy alone about 1
minute); the ``thesis`` preset uses the full model sizes and iteration counts (hours on a CPU;
387 s for 2 tasks × 4 strategies as 8 processes side by side on one H100, and worse results
than the CPU preset); ``reference`` adds the LASA reference code's gradient clip 0.1 and
250-iteration early stop to it (362 s the same way; no better).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from agents.lfd.franka_folds import evaluate_strategy
from agents.lfd.franka_scenario import FrankaEvalConfig, make_scenario
from agents.lfd.skills import save_franka_skills
from mjxrmp.data import franka_demos

__all__ = ["LABELS", "Comparison", "compare_strategies", "table_lines", "table_row"]

#: Display names of the strategies (tables and figures).
LABELS = {"cspace": "C-space", "independent": "Independent", "joint": "Joint (RMP²)",
          "single_link": "Single link", "two_step": "Two-step (§5.2)"}


class Comparison(NamedTuple):
    """What :func:`compare_strategies` returns, per task: ``metrics[task][strategy]`` (the
    records of ``metrics.json``), the table ``rows`` (:func:`table_row`, ``table.csv``), and for
    the figures the loaded ``demos[task]``, the held-out ``folds[task]`` and the
    ``reproductions[task][strategy]`` (one ``(n, 3, 3)`` array per fold)."""

    metrics: dict[str, dict[str, dict]]
    rows: list[dict[str, Any]]
    demos: dict[str, list[franka_demos.FrankaDemo]]
    folds: dict[str, list[int]]
    reproductions: dict[str, dict[str, list[np.ndarray]]]


def table_row(task: str, strategy: str, m: dict) -> dict[str, Any]:
    """One row of ``table.csv`` from a strategy's record ``m`` (lengths in cm, rates rounded)."""
    return {"task": task, "strategy": strategy,
            "mean_position_error_cm": round(m["mean_position_error"] * 100, 3),
            "std_cm": round(m["mean_position_error_std"] * 100, 3),
            "success_rate": round(m["success_rate"], 3),
            "task_success_rate": round(m["task_success_rate"], 3),
            "median_corridor_excursion_cm": round(m["median_corridor_excursion"] * 100, 2),
            "success_rate_obstacle": round(m["success_rate_obstacle"], 3),
            "success_rate_no_posture": round(m["success_rate_no_posture"], 3),
            "colliding_rollouts": m["colliding_rollouts"],
            "obstacle_rollouts": m["obstacle_rollouts"],
            "min_clearance_cm": round(m["min_clearance_obstacle"] * 100, 2),
            "joint_limit_violations": m["joint_limit_violations"],
            "train_seconds": round(m["train_seconds"], 1)}


def table_lines(rows: list[dict[str, Any]]) -> list[str]:
    """The comparison table as text lines (a header, then one line per row)."""
    lines = ["task             strategy      error (cm)      success  task (corridor)  obstacle  "
             "no posture  colliding"]
    for r in rows:
        lines.append(
            f"{r['task']:16s} {r['strategy']:12s} {r['mean_position_error_cm']:6.2f} ± "
            f"{r['std_cm']:5.2f}   {r['success_rate']:6.0%}   {r['task_success_rate']:9.0%}      "
            f"   {r['success_rate_obstacle']:6.0%}    {r['success_rate_no_posture']:6.0%}     "
            f"{r['colliding_rollouts']}/{r['obstacle_rollouts']}")
    return lines


def _saver(out: str | os.PathLike | None, config: FrankaEvalConfig, task: str, strategy: str,
           folds: list[int], stacked: franka_demos.StackedDemos) -> Callable | None:
    """The ``on_kept`` of :func:`evaluate_strategy` that saves the kept models as skills, or
    None without ``out``."""
    if out is None:
        return None
    idx = np.asarray(folds)
    goals, q_goal = np.asarray(stacked.goals)[idx], np.asarray(stacked.q_goal)[idx]
    return lambda result, q_posture: save_franka_skills(out, config, task, strategy, folds,
                                                        result, goals, q_goal, q_posture)


def compare_strategies(config: FrankaEvalConfig, log: Callable[[str], None] = print,
                       save_skills: str | os.PathLike | None = None) -> Comparison:
    """Run the comparison of the module docstring for every task and strategy of ``config``,
    with progress lines through ``log``; with ``save_skills`` every kept fold model is saved as
    a skill under ``save_skills/<task>/<strategy>/fold_<f>/``
    (:func:`agents.lfd.skills.save_franka_skills`)."""
    out = Comparison({}, [], {}, {}, {})
    for ti, task in enumerate(config.tasks):
        demos = franka_demos.load_task(task, config.root, dt=config.dt)
        stacked = franka_demos.stack(demos)
        scenario = make_scenario(config, ti, demos)
        log(f"{task}: {len(demos)} demonstrations, lengths {[d.length for d in demos]} at "
            f"dt={config.dt}; {len(scenario.folds)} folds, horizon {scenario.horizon} steps of "
            f"{config.exec_dt} s")
        out.metrics[task], out.reproductions[task] = {}, {}
        out.demos[task], out.folds[task] = demos, scenario.folds
        for s in config.strategies:
            log(f"  {s}")
            m, out.reproductions[task][s] = evaluate_strategy(
                config, config.strategy_config(s), stacked, demos, scenario, log,
                _saver(save_skills, config, task, s, scenario.folds, stacked))
            out.metrics[task][s] = m
            out.rows.append(table_row(task, s, m))
    return out
