"""Chapter 7 on our reaching tasks (thesis §7.4, Tables 7.2–7.3; docs/design.md §2.4): offline
PLfO with MAHALO and the baselines, scored in the MJX environment — the stages of
``scripts/reproduce_ch7.py``.

Stages (``--stage all`` runs them in order; each is resumable):

1. **collect** (:func:`collect_stage`) — per environment a ``mixed`` dataset (random + noisy
   experts; :mod:`offline.data.collect`, ``--scale`` episodes per source) and an ``expert``
   dataset (``--expert-scale`` episodes, default ``--scale``), collected in the compiled graph
   and cached as checksummed files under ``OUT/data``.
2. **train** (:func:`train_stage`) — for every environment × scenario (``ILfO IL RLfO RL-expert
   RL-sample``) × learner (:data:`offline.learners.registry.TABLE_LEARNERS`) that has data in
   that scenario (:func:`offline.experiment.run.applicable`): ``--seeds`` seeds vmapped in one
   program, ``--steps`` gradient steps (:class:`offline.learners.registry.Budget`), then
   ``--eval-episodes`` episodes per seed in the environment (:mod:`offline.experiment.evaluate`,
   normalised score: uniform random 0, hand-designed expert 100; last iterate). One JSON line
   per cell in ``OUT/results.jsonl``; cells already there are skipped. The Oracle reads only
   the dynamics data, so it is trained once per dynamics dataset (``D_X`` in ILfO, RLfO and
   RL-sample; ``D_X ∪ D_E`` in IL and RL-expert): a scenario whose sibling's Oracle row is
   already there gets a copy of that row, marked ``shared_from``. With ``--checkpoints DIR``
   every cell's state is also saved after each ``--chunk`` steps, and a cell interrupted (e.g.
   by a time limit) continues from its last chunk when the command is run again. With
   ``--curve`` every seed is also scored after each chunk, the same way as its last iterate
   (the rows' ``curve``: steps and per-seed results per step).
3. **table** (:func:`offline.experiment.ch7_table.table_stage`) — ``OUT/table.md`` and
   ``OUT/table.csv``.

The functions take the script's parsed arguments (:data:`OPTIONS`, checked by
:func:`check_args`).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from offline.data import dataset as odata
from offline.data import scenarios
from offline.data.rollouts import make_env
from offline.experiment import evaluate
from offline.experiment.programs import (
    LearningCurve,
    collect_cached,
    curve_path,
    done_cells,
    program_checkpoint_dir,
    progress_printer,
    remove_program_checkpoints,
    result_rows,
    train_program,
)
from offline.experiment.run import applicable, build, seed_keys
from offline.experiment.settings import (
    CHECKPOINT_OPTION,
    LEARNER_OPTIONS,
    SUBSTEPS_OPTION,
    Option,
    apply_preset,
    control_rate_kwargs,
    setting_fields,
    setting_key,
    substeps_tag,
)
from offline.learners.base import Trainer, actor_params
from offline.learners.registry import DYNAMICS_ONLY, TABLE_LEARNERS, Budget

#: Scenarios in table order (thesis Table 7.2).
SCENARIO_ORDER = ("ILfO", "IL", "RLfO", "RL-expert", "RL-sample")
PRESETS = {
    "cpu": dict(envs=["three_link/env3"], scale=4, steps=2000, hidden=[64, 64], seeds=5,
                eval_episodes=16, chunk=1000),
    "gpu": dict(envs=["three_link/env3", "franka"], scale=100, steps=100_000,
                hidden=[256, 256, 256], seeds=5, eval_episodes=64, chunk=25_000),
}
#: Arguments a preset fills that must be positive.
_POSITIVE = ("seeds", "steps", "scale", "eval_episodes", "chunk", "reference_episodes")

#: The command line of ``scripts/reproduce_ch7.py`` (``--out`` is the script's own).
OPTIONS = (
    Option(("--preset",), dict(choices=sorted(PRESETS), default="cpu")),
    Option(("--stage",), dict(choices=("all", "collect", "train", "table"), default="all")),
    Option(("--envs",), dict(nargs="+", default=None)),
    Option(("--scenarios",), dict(nargs="+", default=list(SCENARIO_ORDER),
                                  choices=SCENARIO_ORDER)),
    Option(("--learners",), dict(nargs="+", default=list(TABLE_LEARNERS),
                                 choices=TABLE_LEARNERS)),
    Option(("--seeds",), dict(type=int, default=None, help="seeds per cell (vmapped)")),
    Option(("--steps",), dict(type=int, default=None, help="gradient steps per run")),
    Option(("--hidden",), dict(type=int, nargs="+", default=None, help="MLP hidden sizes")),
    Option(("--scale",), dict(type=int, default=None, help="episodes per dataset source")),
    Option(("--expert-scale",), dict(
        type=int, default=None, metavar="EPISODES",
        help="episodes of the expert dataset (default: --scale, as §7.4.2's Meta-World "
             "protocol; §7.4.1's D4RL protocol gives a small expert set; cells get their own "
             "key)")),
    Option(("--eval-episodes",), dict(type=int, default=None)),
    Option(("--reference-episodes",), dict(
        type=int, default=evaluate.REFERENCE_EPISODES,
        help="episodes of the expert / random reference returns (default %(default)s; fewer "
             "only for quick checks)")),
    Option(("--chunk",), dict(type=int, default=None, help="gradient steps per compiled call")),
    Option(("--curve",), dict(
        action="store_true",
        help="also evaluate every seed after each --chunk steps: learning curves in the result "
             "rows (`curve`; evaluation only, training is unchanged)")),
    CHECKPOINT_OPTION,
    *LEARNER_OPTIONS,
    Option(("--remove-terminals",), dict(
        action="store_true", help="treat terminals (collisions) as timeouts in both datasets")),
    Option(("--data-seed",), dict(type=int, default=0)),
    SUBSTEPS_OPTION,
)


def check_args(args: Any) -> Any:
    """Fill ``args`` from its preset and check it (``ValueError`` with the message for the
    command line); returns ``args``."""
    apply_preset(args, PRESETS[args.preset], _POSITIVE)
    if args.expert_scale is not None and args.expert_scale < 1:
        raise ValueError(f"--expert-scale must be >= 1 episode, got {args.expert_scale}")
    if args.expert_scale == args.scale:
        args.expert_scale = None  # the default: same data, same cell keys
    for env in args.envs:
        control_rate_kwargs(env, args.substeps)
    return args


def recipe_scale(args: Any, recipe: str) -> int:
    """Episodes per source of ``recipe``'s dataset: ``--expert-scale`` for the expert set."""
    return args.expert_scale if recipe == "expert" and args.expert_scale else args.scale


def data_path(out: Path, env: str, recipe: str, scale: int, seed: int,
              substeps: int | None = None) -> Path:
    """The cached dataset file of ``recipe`` on ``env`` under ``out/data``."""
    tag = "".join(f"_{part}" for part in substeps_tag(substeps))
    return out / "data" / f"{env.replace('/', '-')}_{recipe}_x{scale}_s{seed}{tag}.npz"


def collect_stage(args: Any) -> None:
    """Collect (or find cached) the mixed and expert datasets of every environment."""
    for env in args.envs:
        for recipe in ("mixed", "expert"):
            n = recipe_scale(args, recipe)
            collect_cached(data_path(args.out, env, recipe, n, args.data_seed, args.substeps),
                           env, recipe, n, args.data_seed, f"{env} {recipe}",
                           env_kwargs=control_rate_kwargs(env, args.substeps))


def cell_key(env: str, scenario: str, learner: str, args: Any) -> str:
    """The results key of one (environment, scenario, learner) cell at the settings ``args``."""
    key = [env, scenario, learner, args.steps, list(args.hidden), args.seeds, args.scale,
           args.remove_terminals, args.eval_episodes]
    n = expert_scale(scenario, args)
    return json.dumps(key + setting_key(args) + ([] if n is None else ["expert_scale", n])
                      + substeps_tag(args.substeps))


def expert_scale(scenario: str, args: Any) -> int | None:
    """``--expert-scale`` in scenarios that read the expert set; None for the default and for
    RL-sample, whose cells are the same computation for every expert set."""
    return None if scenario in scenarios.EXPERT_FREE else args.expert_scale


def _load_pair(args: Any, env: str) -> tuple[odata.Dataset, odata.Dataset]:
    """The ``mixed`` and ``expert`` datasets of ``env``, checked against the environment."""
    env_obj = make_env(env, control_rate_kwargs(env, args.substeps))
    return tuple(odata.check_environment(
        odata.load(data_path(args.out, env, recipe, recipe_scale(args, recipe), args.data_seed,
                             args.substeps)), env_obj, name=recipe)
        for recipe in ("mixed", "expert"))


def train_stage(args: Any) -> None:
    """Train and evaluate every missing cell; append one JSON line per cell."""
    results = args.out / "results.jsonl"
    done = done_cells(results)
    budget = Budget(steps=args.steps, hidden=tuple(args.hidden), **setting_fields(args))
    for env in args.envs:
        mixed, expert = _load_pair(args, env)
        evaluator = None
        for scenario in args.scenarios:
            dyn, rd = scenarios.make(scenario, mixed, expert,
                                     key=jax.random.PRNGKey(args.data_seed),
                                     keep_terminals=not args.remove_terminals)
            for learner in args.learners:
                cell = cell_key(env, scenario, learner, args)
                if cell in done or not applicable(learner, scenario):
                    continue
                if learner in DYNAMICS_ONLY and share_run(
                        results, cell, env, scenario, learner, args, int(rd.size)):
                    done.add(cell)
                    continue
                evaluator = evaluator or evaluate.make_evaluator(
                    env, args.eval_episodes, env_kwargs=control_rate_kwargs(env, args.substeps),
                    reference_episodes=args.reference_episodes)
                trainer = build(learner, dyn, rd, budget, scenario)
                ev, train_s, eval_s, ckpt = _train_cell(
                    args, cell, f"{env} {scenario} {learner}", trainer, evaluator)
                _append(results, {
                    "cell": cell, "env": env, "substeps": args.substeps, "scenario": scenario,
                    "learner": learner, "seeds": args.seeds, "steps": args.steps,
                    "hidden": list(args.hidden), "train_s": train_s, "eval_s": eval_s,
                    "device": jax.devices()[0].device_kind,
                    "dynamics_transitions": int(dyn.size), "reward_transitions": int(rd.size),
                    "expert_scale": expert_scale(scenario, args), **setting_fields(args),
                    "reference": evaluator.reference, **ev})
                remove_program_checkpoints(ckpt)
                score = np.asarray(ev["normalized_score"])
                print(f"[train] {env} {scenario:9s} {learner:6s}: score {score.mean():7.1f} ± "
                      f"{score.std(ddof=1) / math.sqrt(len(score)):5.1f}  safe "
                      f"{np.mean(ev['safe_pct']):5.1f} %  ({train_s:.0f} s train)", flush=True)


def _train_cell(args: Any, cell: str, name: str, trainer: Trainer,
                evaluator: evaluate.Evaluator) -> tuple[dict[str, Any], float, float, Any]:
    """Train one cell's seeds (checkpointed, with a learning curve if asked) and evaluate the
    last iterate: ``(per-seed evaluation, train seconds, evaluation seconds, checkpoint
    folder)``; the caller removes the folder once the row is written. A diverging seed raises
    :class:`mjxrmp.divergence.DivergenceError` (no row is written for the cell)."""
    t0 = time.perf_counter()
    progress = progress_printer(name, args.steps, t0)

    def score(st: Any) -> list[dict[str, list[float]]]:
        ev = jax.vmap(lambda p: evaluator.evaluate(trainer.act, p, jax.random.PRNGKey(10_000)))(
            actor_params(st))
        return [{k: np.asarray(v, np.float64).tolist() for k, v in ev.items()}]

    ckpt = program_checkpoint_dir(args.checkpoints, cell)
    curve = LearningCurve(score, curve_path(ckpt)) if args.curve else None
    state = train_program(trainer, seed_keys(range(args.seeds)), args.chunk,
                          progress if curve is None else curve.after(progress), ckpt,
                          {"program": cell}, name=name,
                          runs=[f"seed {s}" for s in range(args.seeds)])
    train_s = time.perf_counter() - t0
    ev = score(state)[0]
    eval_s = time.perf_counter() - t0 - train_s
    if curve is not None and curve.steps:  # none when resumed at the last chunk
        ev["curve"] = curve.groups()[0]
        train_s, eval_s = train_s - curve.seconds, eval_s + curve.seconds
    return ev, train_s, eval_s, ckpt


def _append(results: Path, row: dict[str, Any]) -> None:
    """Append one JSON line to ``results``."""
    results.parent.mkdir(parents=True, exist_ok=True)
    with open(results, "a") as f:
        f.write(json.dumps(row) + "\n")


def share_run(results: Path, cell: str, env: str, scenario: str, learner: str, args: Any,
              reward_transitions: int) -> bool:
    """Append ``cell``'s row as a copy of a finished run of ``learner`` (one of
    :data:`offline.learners.registry.DYNAMICS_ONLY`) in a scenario with the same dynamics data
    (:func:`offline.data.scenarios.same_dynamics`), if there is one: the same computation, so
    the Oracle is trained once per dynamics dataset, as thesis Table 7.3 reports one Oracle
    score for RLfO and RL-expert. The row records ``shared_from``. Returns whether it did."""
    rows = {r["cell"]: r for r in result_rows(results)}  # read afresh: other processes append
    for other in scenarios.same_dynamics(scenario):
        source = rows.get(cell_key(env, other, learner, args))
        if source is not None and other != scenario:
            _append(results, {**source, "cell": cell, "scenario": scenario, "train_s": 0.0,
                              "eval_s": 0.0, "expert_scale": expert_scale(scenario, args),
                              "reward_transitions": reward_transitions,
                              "shared_from": source.get("shared_from", source["cell"])})
            print(f"[train] {env} {scenario:9s} {learner:6s}: the run of {other} (same dynamics "
                  f"data)", flush=True)
            return True
    return False


__all__ = [
    "OPTIONS",
    "PRESETS",
    "SCENARIO_ORDER",
    "cell_key",
    "check_args",
    "collect_stage",
    "data_path",
    "expert_scale",
    "recipe_scale",
    "share_run",
    "train_stage",
]
