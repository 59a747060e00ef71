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

Datasets (3-link ``three_link/env3``, :func:`offline.data.collect.collect_recipe` without a PPO run, i.e.
its documented fallback sources, or with ``--ppo-run RUN_DIR`` that run's snapshots): for every
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
:func:`offline.survival.filtering.filter_collision_margin` of ``--safety-dataset`` (default ``mixed-full``,
whose colliding episodes run on through the obstacles) with ``--margin`` (default the reward's δ =
0.05 m: exactly the transitions with a non-zero obstacle cost are removed, §8.4.2's "remove all
transitions with non-zero cost").

Stages (``--stage all`` runs them in order; each is resumable):

1. **collect** — the ``-cut`` / ``-full`` datasets, cached as checksummed files in ``OUT/data``.
2. **train** — per dataset × learner: ATAC, PSPI, IQL and CQL with every data reward of
   ``--rewards`` (original / zero / random U[0,1] / negated, :func:`offline.survival.rewards.variant`,
   terminals ``--terminals keep`` or ``remove``) and ``--seeds`` seeds in **one** vmapped program
   (:func:`offline.survival.sweep.reward_batched`), and BC (reads no reward) once per dataset; the
   filtered dataset gets the original reward only, and only ATAC, PSPI and BC. ``--steps``
   gradient steps (:class:`offline.experiment.run.Budget`), then the last iterate of every run is
   evaluated on
   ``--eval-episodes`` episodes (:mod:`offline.experiment.evaluate`: normalised score — uniform random 0,
   hand-designed expert 100 — safe %, success %). One JSON line per (dataset, learner, reward)
   cell in ``OUT/results.jsonl``; cells already there are skipped, so processes split by
   ``--datasets`` / ``--learners`` / ``--rewards`` can share ``OUT``. With ``--checkpoints
   DIR`` every program's state is also saved after each ``--chunk`` steps, and a program
   interrupted (e.g. by a time limit) continues from its last chunk when run again. With
   ``--curve`` every run is also evaluated after each chunk, the same way as its last iterate;
   the rows then carry ``curve`` (steps and per-seed results per step).
   With ``--reward-form goal`` the true reward is used in the goal-oriented form of the
   thesis's goal-oriented experiments (§7.4.2, §8.4.1; :func:`offline.survival.rewards.goal_oriented`):
   ``r − r_max ≤ 0``, so that the negated reward is ``r_max − r ≥ 0``. It changes the
   ``original`` and ``negated`` cells (their keys carry the form); the zero and random cells
   are the same data and keep their keys, so they are shared with ``--reward-form env``. The
   evaluation is unchanged (the environment's return, normalised). ``--beta B`` trains ATAC and
   PSPI at Bellman weight ``B`` instead of their config's 16 (smaller is more pessimistic; their
   cells get their own key, the other learners' keep theirs).
3. **figures** — ``fig8_4.png`` (rows datasets, columns learners, bars per reward: normalised
   score ± s.e. over seeds, BC as a dashed line), ``fig8_5.png`` (episode length vs return per
   dataset, :func:`offline.survival.rewards.length_bias_statistics`, correlation in the title),
   ``fig8_6.png`` (eq 8.3 positive-data-bias estimate per dataset and learner; ∞ drawn as a
   capped, labelled bar), ``fig8_curves.png`` (score against gradient steps, for cells trained
   with ``--curve``), ``table.md`` / ``table.csv``, ``safety.md`` / ``safety.json`` and
   ``summary.json`` with the acceptance checks computed from the results:

   (a) "well above BC": the mean over the three wrong rewards of a learner's mean score is at
       least BC's mean score + :data:`WELL_ABOVE` (10) points. Checked for ATAC and PSPI: it
       should hold on every ``-cut`` dataset and on no ``-full`` dataset;
   (b) the eq 8.3 estimate (from mean normalised scores, ``Ĵ* = 100``) of ATAC and PSPI is
       larger on ``<recipe>-cut`` (and the deadline modes) than on ``<recipe>-full`` (∞ >
       any finite value);
   (safety) on the filtered dataset, the collision rate (100 − safe %) of ATAC and PSPI is
       below that of BC on ``--safety-dataset`` and below their own on the unfiltered data.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag before JAX initialises)

# isort: split
import jax
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
ENV = "three_link/env3"
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


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    from offline.data.collect import RECIPES
    from offline.survival.rewards import REWARD_FORMS, REWARD_VARIANTS, TERMINAL_MODES
    from offline.survival.sweep import (
        add_checkpoint_option,
        add_learner_options,
        add_substeps_option,
        apply_preset,
    )

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", choices=sorted(PRESETS), default="cpu")
    p.add_argument("--stage", choices=("all", "collect", "train", "figures"), default="all")
    p.add_argument("--recipes", nargs="+", default=None, choices=RECIPES)
    p.add_argument("--datasets", nargs="+", default=None,
                   help="train only these datasets (e.g. mixed-cut mixed-full-filtered)")
    p.add_argument("--learners", nargs="+", default=list(LEARNERS), choices=LEARNERS)
    p.add_argument("--rewards", nargs="+", default=list(REWARD_VARIANTS),
                   choices=REWARD_VARIANTS)
    add_learner_options(p)
    p.add_argument("--terminals", default="keep", choices=TERMINAL_MODES)
    p.add_argument("--reward-form", default="env", choices=REWARD_FORMS,
                   help="the true reward as the environment gives it, or 'goal': shifted by "
                        "its maximum to be non-positive, as in the thesis's goal-oriented "
                        "experiments, so the negated reward is non-negative")
    p.add_argument("--beta", type=float, default=None,
                   help="Bellman weight β of ATAC and PSPI (default: the config's 16; smaller "
                        "is more pessimistic; their cells get their own key)")
    p.add_argument("--seeds", type=int, default=None, help="seeds per cell (vmapped)")
    p.add_argument("--steps", type=int, default=None, help="gradient steps per run")
    p.add_argument("--hidden", type=int, nargs="+", default=None, help="MLP hidden sizes")
    p.add_argument("--batch", type=int, default=None, help="minibatch size")
    p.add_argument("--scale", type=int, default=None, help="episodes per dataset source")
    p.add_argument("--eval-episodes", type=int, default=None)
    p.add_argument("--reference-episodes", type=int, default=None,
                   help="episodes of the expert / random reference returns")
    p.add_argument("--chunk", type=int, default=None, help="gradient steps per compiled call")
    p.add_argument("--curve", action="store_true",
                   help="also evaluate every run after each --chunk steps: learning curves in "
                        "the result rows (`curve`) and fig8_curves.png (evaluation only, the "
                        "training and the final scores are unchanged)")
    add_checkpoint_option(p)
    p.add_argument("--safety", action=argparse.BooleanOptionalAction, default=True,
                   help="also train on the collision-filtered dataset (§8.4.2)")
    p.add_argument("--safety-dataset", default="mixed-full")
    p.add_argument("--goal-deadline", type=int, default=None, metavar="STEPS",
                   help="also train on <recipe>-deadline: the collision-cut data with every "
                        "episode that has not reached the goal by this many steps cut there "
                        "(a terminal; offline.survival.rewards.cut_before_goal): a designed length bias")
    p.add_argument("--margin", type=float, default=None,
                   help="filter clearance in metres (default: the reward's obstacle delta)")
    p.add_argument("--data-seed", type=int, default=0)
    p.add_argument("--ppo-run", type=Path, default=None, metavar="RUN_DIR",
                   help="collect the recipes' PPO sources from this training run (scripts/"
                        "train.py; medium-replay is its checkpoints up to --ppo-step, so "
                        "train it with --keep-checkpoints 0); default: the scripted fallback "
                        "sources of offline.data.collect")
    p.add_argument("--ppo-step", type=int, default=None,
                   help="the run's checkpoint that counts as 'medium' (default: its newest)")
    add_substeps_option(p)
    p.add_argument("--out", type=Path, default=ROOT / "results" / "ch8")
    args = p.parse_args(argv)
    args = apply_preset(p, args, PRESETS[args.preset],
                        ("seeds", "steps", "scale", "eval_episodes", "chunk", "batch",
                         "reference_episodes"))
    if args.beta is not None and not (math.isfinite(args.beta) and args.beta >= 0):
        p.error(f"--beta must be a finite number >= 0, got {args.beta}")
    if args.goal_deadline is not None and args.goal_deadline < 1:
        p.error("--goal-deadline must be a positive number of steps")
    if args.ppo_step is not None and args.ppo_run is None:
        p.error("--ppo-step needs --ppo-run")
    if args.substeps is not None:
        try:
            env_kwargs(args)
        except ValueError as e:
            p.error(str(e))
    if args.margin is None:
        from offline.data.collect import make_env

        args.margin = float(make_env(ENV).obstacle_delta)
    base = base_datasets(args.recipes, args.goal_deadline)
    if args.safety and args.safety_dataset not in base:
        p.error(f"--safety-dataset {args.safety_dataset!r} is not one of {base}")
    every = base + ([filtered_name(args)] if args.safety else [])
    if args.datasets is None:
        args.datasets = every
    bad = [d for d in args.datasets if d not in every]
    if bad:
        p.error(f"unknown --datasets {bad}; with these --recipes they are {every}")
    return args


# --------------------------------------------------------------------------------------------
# Datasets


#: Dataset modes derived from the collision-cut data with a goal deadline (``--goal-deadline``).
DEADLINE_MODES = ("deadline", "goal", "arrive")


def base_datasets(recipes: Sequence[str], goal_deadline: int | None = None) -> list[str]:
    """``<recipe>-cut`` and ``<recipe>-full`` for every recipe, and ``<recipe>-deadline``,
    ``<recipe>-goal`` and ``<recipe>-arrive`` when ``goal_deadline`` is given."""
    modes = ("cut", "full") + (DEADLINE_MODES if goal_deadline else ())
    return [f"{r}-{mode}" for r in recipes for mode in modes]


def filtered_name(args) -> str:
    return f"{args.safety_dataset}-filtered"


def _mode(name: str) -> str:
    """The mode of a dataset name: ``cut``, ``full`` or one of :data:`DEADLINE_MODES`."""
    return name.removesuffix("-filtered").rsplit("-", 1)[-1]


def split_name(name: str) -> tuple[str, bool, bool]:
    """``(recipe, cut_at_collision, filtered)`` of a dataset name (the :data:`DEADLINE_MODES`
    datasets are derived from the collision-cut one)."""
    recipe = name.removesuffix("-filtered").rsplit("-", 1)[0]
    return recipe, _mode(name) in ("cut", *DEADLINE_MODES), name.endswith("-filtered")


def is_deadline(name: str) -> bool:
    """Whether ``name`` is cut at a goal deadline (one of :data:`DEADLINE_MODES`)."""
    return _mode(name) in DEADLINE_MODES


def _ppo_tag(args) -> list:
    """What identifies the PPO sources of the data (``[]`` for the scripted fallback)."""
    if args.ppo_run is None:
        return []
    return ["ppo", args.ppo_run.name, "latest" if args.ppo_step is None else args.ppo_step]


def env_kwargs(args) -> dict[str, int] | None:
    """The environment's constructor arguments for ``--substeps``
    (:func:`offline.survival.sweep.control_rate_kwargs`; None: its defaults)."""
    from offline.survival.sweep import control_rate_kwargs

    return control_rate_kwargs(ENV, args.substeps)


def data_path(args, recipe: str, cut: bool) -> Path:
    from offline.survival.sweep import substeps_tag

    mode = "cut" if cut else "full"
    tag = "".join(f"_{part}" for part in _ppo_tag(args) + substeps_tag(args.substeps))
    return (args.out / "data" /
            f"{ENV.replace('/', '-')}_{recipe}_{mode}_x{args.scale}_s{args.data_seed}{tag}.npz")


def collect_stage(args) -> None:
    """Collect (or find cached) the cut and full datasets of every recipe."""
    from offline.survival.sweep import collect_cached

    for name in base_datasets(args.recipes):
        recipe, cut, _ = split_name(name)
        collect_cached(data_path(args, recipe, cut), ENV, recipe, args.scale, args.data_seed,
                       name, cut_at_collision=cut, ppo_run=args.ppo_run, ppo_step=args.ppo_step,
                       env_kwargs=env_kwargs(args))


def load_dataset(args, name: str):
    """The dataset ``name`` (loaded, checked against the environment; filtered if asked)."""
    from offline.data import collect
    from offline.data import dataset as odata
    from offline.survival.filtering import filter_collision_margin
    from offline.survival.rewards import absorbing_goal, cut_before_goal

    recipe, cut, filtered = split_name(name)
    path = data_path(args, recipe, cut)
    if not path.exists():
        raise SystemExit(f"no dataset at {path}: run --stage collect first")
    env = collect.make_env(ENV, env_kwargs(args))
    ds = odata.check_environment(odata.load(path), env, name=name)
    mode, radius = _mode(name), float(env.success_radius)
    if mode in DEADLINE_MODES:
        ds = cut_before_goal(ds, args.goal_deadline, radius=radius)
    if mode in ("goal", "arrive"):
        ds = absorbing_goal(ds, radius=radius, at_arrival=mode == "arrive")
    return filter_collision_margin(ds, ENV, args.margin) if filtered else ds


# --------------------------------------------------------------------------------------------
# Training


def _cell_key(dataset: str, learner: str, reward: str, args) -> str:
    margin = args.margin if split_name(dataset)[2] else None
    key = [dataset, learner, reward, args.terminals, args.steps, list(args.hidden), args.seeds,
           args.batch, args.scale, args.eval_episodes, margin]
    from offline.survival.sweep import setting_key, substeps_tag

    deadline = ["goal_deadline", args.goal_deadline] if is_deadline(dataset) else []
    return json.dumps(key + deadline + _ppo_tag(args) + substeps_tag(args.substeps)
                      + setting_key(args) + _form_tag(reward, args) + _beta_tag(learner, args))


def _beta(learner: str, args) -> float | None:
    """``--beta`` for a learner with ATAC's Bellman weight (None: the config's β, or none)."""
    return args.beta if learner in PESSIMISTIC else None


def _beta_tag(learner: str, args) -> list:
    """Cell-key entries of ``--beta`` (none without it, so earlier results keep their keys)."""
    beta = _beta(learner, args)
    return [] if beta is None else ["beta", beta]


def _form_tag(reward: str, args) -> list:
    """Cell-key entries of ``--reward-form`` for a data reward that depends on it (none for
    the environment's own form, so earlier results keep their keys)."""
    return ["reward_form", args.reward_form] if _form(reward, args) == "goal" else []


def _form(reward: str, args) -> str | None:
    """The true reward's form behind the data reward ``reward`` (None: it does not use it)."""
    from offline.survival.rewards import FORM_DEPENDENT

    return args.reward_form if reward in FORM_DEPENDENT else None


class _Evaluation:
    """One evaluator and one compiled evaluation program (batch of ``seeds`` policies) per
    process: every learner's actor is a tanh-Gaussian MLP of the same sizes, so their ``act``
    functions agree; a probe checks that before reusing the first one."""

    def __init__(self, args, probe: np.ndarray):
        from offline.experiment import evaluate

        self.evaluator = evaluate.make_evaluator(ENV, args.eval_episodes,
                                                 reference_episodes=args.reference_episodes,
                                                 env_kwargs=env_kwargs(args))
        self.probe = probe
        self.programs: list = []  # (act, jitted program)

    def _program(self, act, params):
        first = jax.tree.map(lambda x: x[0], params)
        for known, program in self.programs:
            try:
                same = np.allclose(np.asarray(known(first, self.probe)),
                                   np.asarray(act(first, self.probe)), rtol=0, atol=0)
            except (TypeError, ValueError, KeyError):
                same = False
            if same:
                return program
        ev = self.evaluator
        program = jax.jit(jax.vmap(lambda p: ev.evaluate(act, p, jax.random.PRNGKey(10_000))))
        self.programs.append((act, program))
        return program

    def __call__(self, act, params, seeds: int) -> list[dict[str, list[float]]]:
        """Per group of ``seeds`` consecutive runs: the per-seed evaluation lists."""
        runs = jax.tree.leaves(params)[0].shape[0]
        program = self._program(act, params)
        out = []
        for g in range(0, runs, seeds):
            ev = program(jax.tree.map(lambda x, _g=g: x[_g:_g + seeds], params))
            out.append({k: np.asarray(v, np.float64).tolist() for k, v in ev.items()})
        return out


def train_stage(args) -> None:
    """Train and evaluate every missing cell; append one JSON line per cell."""
    from offline.experiment import run as experiment
    from offline.survival import sweep
    from offline.survival.rewards import goal_oriented

    results = args.out / "results.jsonl"
    done = sweep.done_cells(results)
    budget = experiment.Budget(steps=args.steps, hidden=tuple(args.hidden), batch=args.batch,
                               **sweep.setting_fields(args))
    evaluation = None
    for name in args.datasets:
        _, cut, filtered = split_name(name)
        rewards = ["original"] if filtered else list(args.rewards)
        learners = [lrn for lrn in args.learners if not filtered or lrn in SAFETY_LEARNERS]
        todo = {lrn: [r for r in (["none"] if lrn == "BC" else rewards)
                      if _cell_key(name, lrn, r, args) not in done]
                for lrn in learners}
        todo = {lrn: rs for lrn, rs in todo.items() if rs}
        if not todo:
            continue
        ds = load_dataset(args, name)
        if args.reward_form == "goal":
            ds = goal_oriented(ds)
        base, rows = sweep.reward_rows(ds, rewards, args.terminals,
                                       sweep.reward_key(args.data_seed, name))
        evaluation = evaluation or _Evaluation(args, np.asarray(ds.observations[:16]))
        for learner, cell_rewards in todo.items():
            t0 = time.perf_counter()
            if learner == "BC":
                trainer = sweep.build_plain("BC", base, budget)
                keys = experiment.seed_keys(range(args.seeds))
            else:
                trainer = sweep.reward_batched(learner, base, budget)
                keys = sweep.reward_seed_keys(rows[[rewards.index(r) for r in cell_rewards]],
                                              range(args.seeds))
            runs = keys[0].shape[0] if isinstance(keys, tuple) else keys.shape[0]

            progress = sweep.progress_printer(f"{name} {learner} ({runs} runs)", args.steps, t0)
            program = json.dumps([_cell_key(name, learner, r, args) for r in cell_rewards])
            ckpt = sweep.program_checkpoint_dir(args.checkpoints, program)
            curve = sweep.LearningCurve(
                lambda st, _act=trainer.act, _ev=evaluation: _ev(
                    _act, sweep.run_actor_params(st), args.seeds),
                sweep.curve_path(ckpt)) if args.curve else None
            on_chunk = progress if curve is None else curve.after(progress)
            beta = _beta(learner, args)
            state = sweep.train_program(trainer, keys, args.chunk, on_chunk, ckpt,
                                        {"program": program},
                                        None if beta is None else [beta] * runs)
            jax.block_until_ready(state)
            train_s = time.perf_counter() - t0
            groups = evaluation(trainer.act, sweep.run_actor_params(state), args.seeds)
            eval_s = time.perf_counter() - t0 - train_s
            if curve is not None and curve.steps:  # none when resumed at the last chunk
                groups = [{**ev, "curve": c} for ev, c in zip(groups, curve.groups(), strict=True)]
                train_s, eval_s = train_s - curve.seconds, eval_s + curve.seconds
            results.parent.mkdir(parents=True, exist_ok=True)
            for reward, ev in zip(cell_rewards, groups, strict=True):
                row = {"cell": _cell_key(name, learner, reward, args), "dataset": name,
                       "recipe": split_name(name)[0], "cut": cut, "filtered": filtered,
                       "margin": args.margin if filtered else None, "learner": learner,
                       "reward": reward, "reward_form": _form(reward, args),
                       "beta": _beta(learner, args),
                       "terminals": args.terminals, "seeds": args.seeds,
                       "steps": args.steps, "hidden": list(args.hidden), "batch": args.batch,
                       "runs_in_program": runs, "program_train_s": train_s,
                       "program_eval_s": eval_s, "device": jax.devices()[0].device_kind,
                       "transitions": int(ds.size), "substeps": args.substeps,
                       **sweep.setting_fields(args),
                       "reference": evaluation.evaluator.reference, **ev}
                with open(results, "a") as f:
                    f.write(json.dumps(row) + "\n")
                score = np.asarray(ev["normalized_score"])
                print(f"[train] {name:22s} {learner:4s} {reward:8s}: score "
                      f"{score.mean():7.1f} ± {_se(score):5.1f}  safe "
                      f"{np.mean(ev['safe_pct']):5.1f} %  success "
                      f"{np.mean(ev['success_pct']):5.1f} %", flush=True)
            sweep.remove_program_checkpoints(ckpt)
            print(f"[time] {name} {learner}: {runs} runs × {args.steps} steps in one program, "
                  f"train {train_s:.1f} s, eval {eval_s:.1f} s", flush=True)


def _se(x) -> float:
    x = np.asarray(x, np.float64)
    return float(x.std(ddof=1) / math.sqrt(len(x))) if len(x) > 1 else 0.0


# --------------------------------------------------------------------------------------------
# Figures, tables and acceptance checks


def load_cells(args) -> dict[tuple[str, str, str], dict]:
    """``(dataset, learner, reward) -> {mean, se, safe, success, n, scores}`` of the rows of
    ``OUT/results.jsonl`` made with the current settings (its cell keys)."""
    path = args.out / "results.jsonl"
    if not path.exists():
        raise SystemExit(f"no results at {path}: run --stage train first")
    from offline.survival.sweep import result_rows

    cells = {}
    for r in result_rows(path):
        if r["cell"] != _cell_key(r["dataset"], r["learner"], r["reward"], args):
            continue
        s = np.asarray(r["normalized_score"], np.float64)
        cell = cells[(r["dataset"], r["learner"], r["reward"])] = {
            "mean": float(s.mean()), "se": _se(s), "safe": float(np.mean(r["safe_pct"])),
            "success": float(np.mean(r["success_pct"])), "n": len(s), "scores": s.tolist()}
        if "curve" in r:  # --curve: steps × seeds
            points = np.asarray(r["curve"]["normalized_score"], np.float64)
            cell["curve"] = {"steps": list(r["curve"]["steps"]),
                             "mean": points.mean(axis=1).tolist(),
                             "se": [_se(p) for p in points]}
    return cells


def _json_float(x: float) -> float | str | None:
    """JSON-safe float: ``"inf"`` for ∞, None for NaN."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return None
    return "inf" if math.isinf(x) else float(x)


def bias_estimates(cells: dict) -> dict[tuple[str, str], float]:
    """Eq 8.3 per (dataset, learner) with all three wrong-reward scores (means, Ĵ* = 100)."""
    from offline.survival.rewards import WRONG_REWARDS, positive_data_bias

    out = {}
    for d, lrn in {(d, lrn) for d, lrn, _ in cells}:
        if all((d, lrn, r) in cells for r in WRONG_REWARDS):
            out[(d, lrn)] = positive_data_bias({r: cells[(d, lrn, r)]["mean"]
                                                for r in WRONG_REWARDS})
    return out


def acceptance(args, cells: dict, bias: dict, lengths: dict) -> dict:
    """The acceptance checks of the module docstring, computed from ``cells``."""
    from offline.survival.rewards import WRONG_REWARDS

    base = base_datasets(args.recipes, args.goal_deadline)
    well_above, wrong_mean = {}, {}
    for d in base:
        bc = cells.get((d, "BC", "none"))
        for lrn in PESSIMISTIC:
            if bc is None or not all((d, lrn, r) in cells for r in WRONG_REWARDS):
                continue
            m = float(np.mean([cells[(d, lrn, r)]["mean"] for r in WRONG_REWARDS]))
            wrong_mean[f"{d}/{lrn}"] = m
            well_above[f"{d}/{lrn}"] = bool(m >= bc["mean"] + WELL_ABOVE)
    biased = [v for k, v in well_above.items() if split_name(k.split("/")[0])[1]]
    unbiased = [v for k, v in well_above.items() if not split_name(k.split("/")[0])[1]]
    larger = {}
    for recipe in args.recipes:
        for lrn in PESSIMISTIC:
            full = bias.get((f"{recipe}-full", lrn))
            for mode in ("cut", *DEADLINE_MODES):
                name = recipe if mode == "cut" else f"{recipe}-{mode}"
                biased_bias = bias.get((f"{recipe}-{mode}", lrn))
                if biased_bias is not None and full is not None:
                    larger[f"{name}/{lrn}"] = bool(biased_bias > full)
    summary = {
        "reward_form": args.reward_form,
        "rule_a": f"'well above BC': mean over the wrong rewards {list(WRONG_REWARDS)} of the "
                  f"mean normalised score >= BC's mean + {WELL_ABOVE:g}; checked for "
                  f"{list(PESSIMISTIC)}",
        "wrong_reward_mean": wrong_mean,
        "bc_mean": {d: cells[(d, "BC", "none")]["mean"] for d in base
                    if (d, "BC", "none") in cells},
        "well_above_bc": well_above,
        "a_length_biased_well_above_bc": bool(all(biased)) if biased else None,
        "a_unbiased_not_well_above_bc": (not any(unbiased)) if unbiased else None,
        "rule_b": "eq 8.3 estimate (mean normalised scores, J* = 100) on <recipe>-cut (and "
                  "<recipe>-deadline, -goal, -arrive) > on <recipe>-full (inf > any finite value)",
        "bias_estimate": {f"{d}/{lrn}": _json_float(v) for (d, lrn), v in sorted(bias.items())},
        "bias_larger_on_length_biased": larger,
        "b_bias_larger_on_length_biased": bool(all(larger.values())) if larger else None,
        "length_return_correlation": {d: _json_float(v["length_return_correlation"])
                                      for d, v in lengths.items()},
        "cut_fraction": {d: _json_float(v["cut_fraction"]) for d, v in lengths.items()},
    }
    parts = [summary["a_length_biased_well_above_bc"], summary["a_unbiased_not_well_above_bc"]]
    summary["a"] = bool(all(parts)) if None not in parts else None
    summary["b"] = summary["b_bias_larger_on_length_biased"]
    return summary


def safety_summary(args, cells: dict) -> dict:
    """Return and collision rate (100 − safe %) on filtered vs unfiltered data, and BC's."""
    f, u = filtered_name(args), args.safety_dataset
    out = {"filtered_dataset": f, "unfiltered_dataset": u, "margin_m": args.margin,
           "rule": "collision rate (100 - safe %) of the learner on the filtered data < BC's "
                   "on the unfiltered data and < the learner's own on the unfiltered data",
           "rows": {}, "checks": {}}
    bc = cells.get((u, "BC", "none"))
    for name, key in (("BC", (u, "BC", "none")), ("BC (filtered)", (f, "BC", "none")),
                      *[(f"{lrn} ({tag})", (d, lrn, "original")) for lrn in PESSIMISTIC
                        for tag, d in (("unfiltered", u), ("filtered", f))]):
        if key in cells:
            c = cells[key]
            out["rows"][name] = {"score": c["mean"], "score_se": c["se"],
                                 "collision_pct": 100.0 - c["safe"], "success_pct": c["success"]}
    for lrn in PESSIMISTIC:
        fil, unf = cells.get((f, lrn, "original")), cells.get((u, lrn, "original"))
        if fil is None or unf is None or bc is None:
            continue
        out["checks"][lrn] = bool(100.0 - fil["safe"] < 100.0 - bc["safe"]
                                  and 100.0 - fil["safe"] < 100.0 - unf["safe"])
    out["all"] = bool(all(out["checks"].values())) if out["checks"] else None
    return out


def _plot_lengths(args, lengths: dict, plt: Any) -> None:
    """Fig 8.5: episode length vs true return, one panel per dataset."""
    fig, axes = plt.subplots(1, len(lengths), figsize=(3.4 * len(lengths), 3), squeeze=False)
    for ax, (d, st) in zip(axes[0], lengths.items(), strict=True):
        ax.scatter(st["lengths"], st["returns"], s=6, alpha=0.6)
        corr = st["length_return_correlation"]
        ax.set_title(f"{d}: corr " + ("undefined" if math.isnan(corr) else f"{corr:.2f}"),
                     fontsize=8)
        ax.set_xlabel("episode length")
        ax.set_ylabel("return (true reward)")
    fig.tight_layout()
    fig.savefig(args.out / "fig8_5.png", dpi=110)
    plt.close(fig)


def _plot(args, cells: dict, bias: dict, lengths: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from offline.survival.rewards import REWARD_VARIANTS

    # Rows and columns with results only (a sweep may train part of the grid).
    trained = {(d, lrn) for d, lrn, _ in cells}
    base = [d for d in base_datasets(args.recipes, args.goal_deadline)
            if any((d, lrn) in trained for lrn in LEARNERS)]
    learners = [lrn for lrn in LEARNERS if lrn != "BC" and any((d, lrn) in trained for d in base)]
    if not base or not learners:
        print("[figures] no trained cells: Figs 8.4 and 8.6 are left out", flush=True)
        return
    colours = dict(zip(REWARD_VARIANTS, ("tab:green", "tab:grey", "tab:orange", "tab:red"),
                       strict=True))
    fig, axes = plt.subplots(len(base), len(learners), figsize=(3.2 * len(learners),
                                                                 2.6 * len(base)),
                             squeeze=False, sharey=True)
    for i, d in enumerate(base):
        for j, lrn in enumerate(learners):
            ax = axes[i][j]
            for k, r in enumerate(REWARD_VARIANTS):
                c = cells.get((d, lrn, r))
                if c is not None:
                    ax.bar(k, c["mean"], yerr=c["se"], color=colours[r], capsize=3)
            if (d, "BC", "none") in cells:
                ax.axhline(cells[(d, "BC", "none")]["mean"], ls="--", c="k", lw=1, label="BC")
            ax.set_xticks(range(len(REWARD_VARIANTS)), REWARD_VARIANTS, fontsize=7)
            ax.set_title(f"{d} — {lrn}", fontsize=8)
            if j == 0:
                ax.set_ylabel("normalised score")
    sep = "\n" if len(learners) < 3 else " "  # one or two columns are too narrow for one line
    fig.suptitle(f"Fig 8.4 (env3): last-iterate normalised score ± s.e.{sep}per data reward; "
                 "dashed: BC", fontsize=9)
    fig.tight_layout()
    fig.savefig(args.out / "fig8_4.png", dpi=110)
    plt.close(fig)

    if lengths:
        _plot_lengths(args, lengths, plt)

    finite = [v for v in bias.values() if math.isfinite(v)]
    cap = 1.5 * max([*finite, 2.0])
    fig, ax = plt.subplots(figsize=(1.2 + 1.6 * len(base), 3.2))
    width = 0.8 / len(learners)
    for j, lrn in enumerate(learners):
        for i, d in enumerate(base):
            v = bias.get((d, lrn))
            if v is None:
                continue
            x = i + (j - (len(learners) - 1) / 2) * width
            ax.bar(x, min(v, cap), width, color=f"C{j}", hatch="//" if math.isinf(v) else None,
                   label=lrn if i == 0 else None)
            if math.isinf(v):
                ax.text(x, cap, "∞", ha="center", va="bottom")
    ax.set_xticks(range(len(base)), base, fontsize=8)
    ax.set_ylabel("estimated positive data bias (eq 8.3)")
    if ax.get_legend_handles_labels()[0]:  # no estimate without all three wrong rewards
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out / "fig8_6.png", dpi=110)
    plt.close(fig)


def _plot_curves(args, cells: dict) -> None:
    """``fig8_curves.png``: normalised score ± s.e. against gradient steps per dataset, one line
    per learner and reward (cells trained with ``--curve``); BC's final score dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    datasets = list(dict.fromkeys(d for (d, _, _), c in cells.items() if "curve" in c))
    if not datasets:
        return
    fig, axes = plt.subplots(1, len(datasets), figsize=(4.2 * len(datasets), 3.2),
                             squeeze=False, sharey=True)
    # one colour per (learner, reward) in every panel, in a fixed order
    lines = sorted({(lrn, r) for (_, lrn, r), c in cells.items() if "curve" in c})
    colour = {line: f"C{i % 10}" for i, line in enumerate(lines)}
    for ax, d in zip(axes[0], datasets, strict=True):
        for line in lines:
            c = cells.get((d, *line))
            if c is None or "curve" not in c:
                continue
            x, m, e = (np.asarray(c["curve"][k], np.float64) for k in ("steps", "mean", "se"))
            ax.plot(x, m, marker=".", c=colour[line], label=" ".join(line))
            ax.fill_between(x, m - e, m + e, color=colour[line], alpha=0.2)
        if (d, "BC", "none") in cells:
            ax.axhline(cells[(d, "BC", "none")]["mean"], ls="--", c="k", lw=1,
                       label="BC (final)")
        ax.set_title(d, fontsize=9)
        ax.set_xlabel("gradient steps")
        ax.xaxis.set_major_formatter(lambda v, _: f"{v / 1000:g}k")
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel("normalised score")
    fig.tight_layout()
    fig.savefig(args.out / "fig8_curves.png", dpi=110)
    plt.close(fig)


def length_statistics(args, statistics: Callable[[Any], dict]) -> dict[str, dict]:
    """Fig 8.5's per-dataset length/return statistics (``statistics`` is
    :func:`offline.survival.rewards.length_bias_statistics`), computed from the datasets in
    ``OUT/data`` and cached in ``OUT/length_bias.json``, so the figures can be redrawn where
    only the results were copied (the datasets are large); cached entries fill in datasets
    that are missing."""
    cache = args.out / "length_bias.json"
    stats = json.loads(cache.read_text()) if cache.exists() else {}
    for d in base_datasets(args.recipes, args.goal_deadline):
        if data_path(args, *split_name(d)[:2]).exists():
            stats[d] = statistics(load_dataset(args, d))
    stats = {d: stats[d] for d in base_datasets(args.recipes, args.goal_deadline) if d in stats}
    if stats:
        cache.write_text(json.dumps(stats))
    else:
        print(f"[figures] no datasets in {args.out / 'data'} and no {cache}: Fig 8.5 and the "
              f"length statistics are left out (run --stage collect first)", flush=True)
    return stats


def figures_stage(args) -> dict:
    """Write the figures, tables, safety report and acceptance summary; return the summary."""
    from offline.survival.rewards import REWARD_VARIANTS, length_bias_statistics

    cells = load_cells(args)
    bias = bias_estimates(cells)
    lengths = length_statistics(args, length_bias_statistics)
    datasets = list(dict.fromkeys(d for d, _, _ in cells))
    header = ["dataset", "learner", *REWARD_VARIANTS, "BC", "bias (eq 8.3)"]
    md = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    csv = ["dataset,learner,reward,mean,se,safe_pct,success_pct,seeds,bias"]
    for d in datasets:
        bc = cells.get((d, "BC", "none"))
        for lrn in LEARNERS:
            rewards = ["none"] if lrn == "BC" else list(REWARD_VARIANTS)
            here = {r: cells[(d, lrn, r)] for r in rewards if (d, lrn, r) in cells}
            if not here:
                continue
            b = bias.get((d, lrn))
            for r, c in here.items():
                csv.append(f"{d},{lrn},{r},{c['mean']:.3f},{c['se']:.3f},{c['safe']:.2f},"
                           f"{c['success']:.2f},{c['n']},{'' if b is None else b}")
            if lrn == "BC":
                continue
            entries = [f"{here[r]['mean']:.1f} ± {here[r]['se']:.1f}" if r in here else "–"
                       for r in REWARD_VARIANTS]
            bc_text = "–" if bc is None else f"{bc['mean']:.1f}"
            b_text = "–" if b is None else ("∞" if math.isinf(b) else f"{b:.2f}")
            md.append(f"| {d} | {lrn} | " + " | ".join(entries) + f" | {bc_text} | {b_text} |")
    summary = acceptance(args, cells, bias, lengths)
    safety = safety_summary(args, cells)
    summary["safety"] = safety["all"] if args.safety else None
    note = (f"\n(a) ATAC/PSPI with wrong rewards well above BC on every length-biased dataset: "
            f"{summary['a_length_biased_well_above_bc']}; on no unbiased dataset: "
            f"{summary['a_unbiased_not_well_above_bc']}  ({summary['rule_a']})\n"
            f"(b) bias estimate larger with length bias: {summary['b']} "
            f"{summary['bias_larger_on_length_biased']}\n"
            f"True reward's form: {args.reward_form} ({REWARD_FORM_TEXT[args.reward_form]})\n")
    (args.out / "table.md").write_text("\n".join(md) + "\n" + note)
    (args.out / "table.csv").write_text("\n".join(csv) + "\n")
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1))
    _plot(args, cells, bias, lengths)
    _plot_curves(args, cells)
    print("\n".join(md) + "\n" + note, flush=True)
    if not args.safety or not safety["rows"]:
        print("[figures] --no-safety, or no filtered-data or safety-dataset cells: safety.md "
              "is left out", flush=True)
        return summary
    srows = ["| policy | score | collision % | success % |", "|---|---|---|---|"]
    srows += [f"| {k} | {v['score']:.1f} ± {v['score_se']:.1f} | {v['collision_pct']:.1f} | "
              f"{v['success_pct']:.1f} |" for k, v in safety["rows"].items()]
    (args.out / "safety.md").write_text(
        f"Safety from filtered data (thesis §8.4.2): {safety['filtered_dataset']} = "
        f"{safety['unfiltered_dataset']} without transitions of clearance < "
        f"{safety['margin_m']} m.\n\n" + "\n".join(srows) +
        f"\n\nRule: {safety['rule']}. Checks: {safety['checks']} → {safety['all']}\n")
    (args.out / "safety.json").write_text(json.dumps(safety, indent=1))
    print((args.out / "safety.md").read_text(), flush=True)
    return summary


def main(argv: Sequence[str] | None = None) -> None:
    """Run the selected stages."""
    from offline.survival.sweep import run_stages

    args = parse_args(argv)
    run_stages(
        args, {"collect": collect_stage, "train": train_stage, "figures": figures_stage},
        f"device {jax.devices()[0].device_kind}; preset {args.preset}: datasets "
        f"{args.datasets}, learners {args.learners}, rewards {args.rewards}, {args.seeds} "
        f"seeds × {args.steps} steps, hidden {args.hidden}, scale {args.scale}, normalize "
        f"observations {args.normalize_observations}, actor {args.actor}, reward form "
        f"{args.reward_form}")

if __name__ == "__main__":
    main()
