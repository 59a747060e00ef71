"""Chapter 8 on our reaching task, the datasets and cells of ``scripts/reproduce_ch8.py`` (thesis
§8.3–8.4, docs/design.md §2.4): dataset names and files (``<recipe>-cut`` / ``-full`` /
``-deadline`` / ``-goal`` / ``-arrive`` / ``<safety-dataset>-filtered``), the collect stage,
loading a dataset as its mode says, and the cell keys of the results. The script's command
line is :data:`OPTIONS` (checked by :func:`check_args`); the train stage is
:mod:`offline.survival.ch8_train`, the figures stage :mod:`offline.survival.ch8_report`.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from offline.data import dataset as odata
from offline.data.collect import RECIPES
from offline.data.rollouts import make_env
from offline.experiment.programs import collect_cached
from offline.experiment.settings import (
    CHECKPOINT_OPTION,
    LEARNER_OPTIONS,
    SUBSTEPS_OPTION,
    Option,
    apply_preset,
    control_rate_kwargs,
    setting_key,
    substeps_tag,
)
from offline.survival.filtering import filter_collision_margin
from offline.survival.rewards import (
    FORM_DEPENDENT,
    REWARD_FORMS,
    REWARD_VARIANTS,
    TERMINAL_MODES,
    absorbing_goal,
    cut_before_goal,
)

#: The environment of the chapter-8 experiments.
ENV = "three_link/env3"
#: Learners of the sweep.
LEARNERS = ("ATAC", "PSPI", "IQL", "CQL", "BC")
#: Learners the acceptance checks are about (provably pessimistic, thesis §8.4.1).
PESSIMISTIC = ("ATAC", "PSPI")
#: Learners trained on the collision-filtered dataset (thesis §8.4.2 uses ATAC and PSPI).
SAFETY_LEARNERS = ("ATAC", "PSPI", "BC")
#: Points above BC that count as "well above" (acceptance check (a)).
WELL_ABOVE = 10.0
#: What the table says of each ``--reward-form``.
REWARD_FORM_TEXT = {
    "env": "the environment's reward r; negated = -r",
    "goal": "goal-oriented, r - r_max <= 0 (thesis 7.4.2, 8.4.1); negated = r_max - r >= 0",
}
PRESETS = {
    "cpu": dict(recipes=["mixed"], scale=2, steps=200, hidden=[32, 32], seeds=2, batch=64,
                eval_episodes=8, reference_episodes=32, chunk=100),
    "gpu": dict(recipes=["mixed", "medium-replay"], scale=100, steps=30_000,
                hidden=[256, 256, 256], seeds=5, batch=256, eval_episodes=64,
                reference_episodes=256, chunk=10_000),
}


#: Arguments a preset fills that must be positive.
_POSITIVE = ("seeds", "steps", "scale", "eval_episodes", "chunk", "batch", "reference_episodes")

#: The command line of ``scripts/reproduce_ch8.py`` (``--out`` is the script's own).
OPTIONS = (
    Option(("--preset",), dict(choices=sorted(PRESETS), default="cpu")),
    Option(("--stage",), dict(choices=("all", "collect", "train", "figures"), default="all")),
    Option(("--recipes",), dict(nargs="+", default=None, choices=RECIPES)),
    Option(("--datasets",), dict(
        nargs="+", default=None,
        help="train only these datasets (e.g. mixed-cut mixed-full-filtered)")),
    Option(("--learners",), dict(nargs="+", default=list(LEARNERS), choices=LEARNERS)),
    Option(("--rewards",), dict(nargs="+", default=list(REWARD_VARIANTS),
                                choices=REWARD_VARIANTS)),
    *LEARNER_OPTIONS,
    Option(("--terminals",), dict(default="keep", choices=TERMINAL_MODES)),
    Option(("--reward-form",), dict(
        default="env", choices=REWARD_FORMS,
        help="the true reward as the environment gives it, or 'goal': shifted by its maximum "
             "to be non-positive, as in the thesis's goal-oriented experiments, so the negated "
             "reward is non-negative")),
    Option(("--beta",), dict(
        type=float, default=None,
        help="Bellman weight β of ATAC and PSPI (default: the config's 16; smaller is more "
             "pessimistic; their cells get their own key)")),
    Option(("--seeds",), dict(type=int, default=None, help="seeds per cell (vmapped)")),
    Option(("--steps",), dict(type=int, default=None, help="gradient steps per run")),
    Option(("--hidden",), dict(type=int, nargs="+", default=None, help="MLP hidden sizes")),
    Option(("--batch",), dict(type=int, default=None, help="minibatch size")),
    Option(("--scale",), dict(type=int, default=None, help="episodes per dataset source")),
    Option(("--eval-episodes",), dict(type=int, default=None)),
    Option(("--reference-episodes",), dict(
        type=int, default=None, help="episodes of the expert / random reference returns")),
    Option(("--chunk",), dict(type=int, default=None, help="gradient steps per compiled call")),
    Option(("--curve",), dict(
        action="store_true",
        help="also evaluate every run after each --chunk steps: learning curves in the result "
             "rows (`curve`) and fig8_curves.png (evaluation only, the training and the final "
             "scores are unchanged)")),
    CHECKPOINT_OPTION,
    Option(("--safety",), dict(action=argparse.BooleanOptionalAction, default=True,
                               help="also train on the collision-filtered dataset (§8.4.2)")),
    Option(("--safety-dataset",), dict(default="mixed-full")),
    Option(("--goal-deadline",), dict(
        type=int, default=None, metavar="STEPS",
        help="also train on <recipe>-deadline: the collision-cut data with every episode that "
             "has not reached the goal by this many steps cut there (a terminal; "
             "offline.survival.rewards.cut_before_goal): a designed length bias")),
    Option(("--margin",), dict(
        type=float, default=None,
        help="filter clearance in metres (default: the reward's obstacle delta)")),
    Option(("--data-seed",), dict(type=int, default=0)),
    Option(("--ppo-run",), dict(
        type=Path, default=None, metavar="RUN_DIR",
        help="collect the recipes' PPO sources from this training run (scripts/train.py; "
             "medium-replay is its checkpoints up to --ppo-step, so train it with "
             "--keep-checkpoints 0); default: the scripted fallback sources of "
             "offline.data.collect")),
    Option(("--ppo-step",), dict(
        type=int, default=None,
        help="the run's checkpoint that counts as 'medium' (default: its newest)")),
    SUBSTEPS_OPTION,
)


def check_args(args: Any) -> Any:
    """Fill ``args`` from its preset, default ``--margin`` and ``--datasets``, and check it
    (``ValueError`` with the message for the command line); returns ``args``."""
    apply_preset(args, PRESETS[args.preset], _POSITIVE)
    if args.beta is not None and not (math.isfinite(args.beta) and args.beta >= 0):
        raise ValueError(f"--beta must be a finite number >= 0, got {args.beta}")
    if args.goal_deadline is not None and args.goal_deadline < 1:
        raise ValueError("--goal-deadline must be a positive number of steps")
    if args.ppo_step is not None and args.ppo_run is None:
        raise ValueError("--ppo-step needs --ppo-run")
    env_kwargs(args)
    if args.margin is None:
        args.margin = float(make_env(ENV).obstacle_delta)
    base = base_datasets(args.recipes, args.goal_deadline)
    if args.safety and args.safety_dataset not in base:
        raise ValueError(f"--safety-dataset {args.safety_dataset!r} is not one of {base}")
    every = base + ([filtered_name(args)] if args.safety else [])
    if args.datasets is None:
        args.datasets = every
    bad = [d for d in args.datasets if d not in every]
    if bad:
        raise ValueError(f"unknown --datasets {bad}; with these --recipes they are {every}")
    return args


#: Dataset modes derived from the collision-cut data with a goal deadline (``--goal-deadline``).
DEADLINE_MODES = ("deadline", "goal", "arrive")


def base_datasets(recipes: Sequence[str], goal_deadline: int | None = None) -> list[str]:
    """``<recipe>-cut`` and ``<recipe>-full`` for every recipe, and ``<recipe>-deadline``,
    ``<recipe>-goal`` and ``<recipe>-arrive`` when ``goal_deadline`` is given."""
    modes = ("cut", "full") + (DEADLINE_MODES if goal_deadline else ())
    return [f"{r}-{mode}" for r in recipes for mode in modes]


def filtered_name(args: Any) -> str:
    """The name of the collision-filtered dataset (``<safety-dataset>-filtered``)."""
    return f"{args.safety_dataset}-filtered"


def mode_of(name: str) -> str:
    """The mode of a dataset name: ``cut``, ``full`` or one of :data:`DEADLINE_MODES`."""
    return name.removesuffix("-filtered").rsplit("-", 1)[-1]


def split_name(name: str) -> tuple[str, bool, bool]:
    """``(recipe, cut_at_collision, filtered)`` of a dataset name (the :data:`DEADLINE_MODES`
    datasets are derived from the collision-cut one)."""
    recipe = name.removesuffix("-filtered").rsplit("-", 1)[0]
    return recipe, mode_of(name) in ("cut", *DEADLINE_MODES), name.endswith("-filtered")


def is_deadline(name: str) -> bool:
    """Whether ``name`` is cut at a goal deadline (one of :data:`DEADLINE_MODES`)."""
    return mode_of(name) in DEADLINE_MODES


def ppo_tag(args: Any) -> list:
    """What identifies the PPO sources of the data (``[]`` for the scripted fallback)."""
    if args.ppo_run is None:
        return []
    return ["ppo", args.ppo_run.name, "latest" if args.ppo_step is None else args.ppo_step]


def env_kwargs(args: Any) -> dict[str, int] | None:
    """The environment's constructor arguments for ``--substeps``
    (:func:`offline.experiment.settings.control_rate_kwargs`; None: its defaults)."""
    return control_rate_kwargs(ENV, args.substeps)


def data_path(args: Any, recipe: str, cut: bool) -> Path:
    """The cached file of the ``-cut`` (``cut``) or ``-full`` data of ``recipe``."""
    mode = "cut" if cut else "full"
    tag = "".join(f"_{part}" for part in ppo_tag(args) + substeps_tag(args.substeps))
    return (args.out / "data" /
            f"{ENV.replace('/', '-')}_{recipe}_{mode}_x{args.scale}_s{args.data_seed}{tag}.npz")


def collect_stage(args: Any) -> None:
    """Collect (or find cached) the cut and full datasets of every recipe that ``--datasets``
    uses (both of every recipe by default; a filtered or deadline dataset uses its base)."""
    used = {split_name(name)[:2] for name in args.datasets}
    for name in base_datasets(args.recipes):
        recipe, cut, _ = split_name(name)
        if (recipe, cut) not in used:
            continue
        collect_cached(data_path(args, recipe, cut), ENV, recipe, args.scale, args.data_seed,
                       name, cut_at_collision=cut, ppo_run=args.ppo_run, ppo_step=args.ppo_step,
                       env_kwargs=env_kwargs(args))


def load_dataset(args: Any, name: str) -> odata.Dataset:
    """The dataset ``name`` (loaded, checked against the environment; filtered if asked)."""

    recipe, cut, filtered = split_name(name)
    path = data_path(args, recipe, cut)
    if not path.exists():
        raise SystemExit(f"no dataset at {path}: run --stage collect first")
    env = make_env(ENV, env_kwargs(args))
    ds = odata.check_environment(odata.load(path), env, name=name)
    mode, radius = mode_of(name), float(env.success_radius)
    if mode in DEADLINE_MODES:
        ds = cut_before_goal(ds, args.goal_deadline, radius=radius)
    if mode in ("goal", "arrive"):
        ds = absorbing_goal(ds, radius=radius, at_arrival=mode == "arrive")
    return filter_collision_margin(ds, ENV, args.margin) if filtered else ds



def cell_key(dataset: str, learner: str, reward: str, args: Any) -> str:
    """The results key of one (dataset, learner, data reward) cell at the settings ``args``."""
    margin = args.margin if split_name(dataset)[2] else None
    key = [dataset, learner, reward, args.terminals, args.steps, list(args.hidden), args.seeds,
           args.batch, args.scale, args.eval_episodes, margin]
    deadline = ["goal_deadline", args.goal_deadline] if is_deadline(dataset) else []
    return json.dumps(key + deadline + ppo_tag(args) + substeps_tag(args.substeps)
                      + setting_key(args) + _form_tag(reward, args) + _beta_tag(learner, args))


def beta_of(learner: str, args: Any) -> float | None:
    """``--beta`` for a learner with ATAC's Bellman weight (None: the config's β, or none)."""
    return args.beta if learner in PESSIMISTIC else None


def _beta_tag(learner: str, args: Any) -> list:
    """Cell-key entries of ``--beta`` (none without it, so earlier results keep their keys)."""
    beta = beta_of(learner, args)
    return [] if beta is None else ["beta", beta]


def _form_tag(reward: str, args: Any) -> list:
    """Cell-key entries of ``--reward-form`` for a data reward that depends on it (none for
    the environment's own form, so earlier results keep their keys)."""
    return ["reward_form", args.reward_form] if form_of(reward, args) == "goal" else []


def form_of(reward: str, args: Any) -> str | None:
    """The true reward's form behind the data reward ``reward`` (None: it does not use it)."""
    return args.reward_form if reward in FORM_DEPENDENT else None


__all__ = [
    "DEADLINE_MODES",
    "ENV",
    "LEARNERS",
    "OPTIONS",
    "PESSIMISTIC",
    "PRESETS",
    "REWARD_FORM_TEXT",
    "SAFETY_LEARNERS",
    "WELL_ABOVE",
    "base_datasets",
    "beta_of",
    "cell_key",
    "check_args",
    "collect_stage",
    "data_path",
    "env_kwargs",
    "filtered_name",
    "form_of",
    "is_deadline",
    "load_dataset",
    "mode_of",
    "ppo_tag",
    "split_name",
]
