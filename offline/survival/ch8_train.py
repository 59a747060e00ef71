"""The train stage of ``scripts/reproduce_ch8.py`` (thesis §8.4.1–8.4.2; docs/design.md §2.4):
per dataset × learner, ATAC, PSPI, IQL and CQL with every data reward of ``--rewards`` and
``--seeds`` seeds in **one** vmapped program (:func:`offline.survival.sweep.reward_batched`), and
BC (reads no reward) once per dataset; the filtered dataset gets the original reward only, and
only :data:`offline.survival.ch8.SAFETY_LEARNERS`. The last iterate of every run is evaluated
(:mod:`offline.experiment.evaluate`) and one JSON line per (dataset, learner, reward) cell is
appended to ``OUT/results.jsonl``; cells already there are skipped.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from offline.data import dataset as odata
from offline.experiment import evaluate
from offline.experiment.programs import (
    LearningCurve,
    curve_path,
    done_cells,
    program_checkpoint_dir,
    progress_printer,
    remove_program_checkpoints,
    train_program,
)
from offline.experiment.run import seed_keys
from offline.experiment.settings import setting_fields
from offline.learners.registry import Budget
from offline.survival import sweep
from offline.survival.ch8 import (
    ENV,
    SAFETY_LEARNERS,
    beta_of,
    cell_key,
    env_kwargs,
    form_of,
    load_dataset,
    split_name,
)
from offline.survival.rewards import goal_oriented


def standard_error(x: Any) -> float:
    """Standard error of the mean of ``x`` (sample standard deviation; 0 for one value)."""
    x = np.asarray(x, np.float64)
    return float(x.std(ddof=1) / math.sqrt(len(x))) if len(x) > 1 else 0.0


class Evaluation:
    """One evaluator and one compiled evaluation program (batch of ``seeds`` policies) per
    process: every learner's actor is a tanh-Gaussian MLP of the same sizes, so their ``act``
    functions agree; a probe checks that before reusing the first one."""

    def __init__(self, args: Any, probe: np.ndarray):
        self.evaluator = evaluate.make_evaluator(ENV, args.eval_episodes,
                                                 reference_episodes=args.reference_episodes,
                                                 env_kwargs=env_kwargs(args))
        self.probe = probe
        self.programs: list = []  # (act, jitted program)

    def _program(self, act: Callable, params: Any) -> Callable:
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

    def __call__(self, act: Callable, params: Any, seeds: int) -> list[dict[str, list[float]]]:
        """Per group of ``seeds`` consecutive runs: the per-seed evaluation lists."""
        runs = jax.tree.leaves(params)[0].shape[0]
        program = self._program(act, params)
        out = []
        for g in range(0, runs, seeds):
            ev = program(jax.tree.map(lambda x, _g=g: x[_g:_g + seeds], params))
            out.append({k: np.asarray(v, np.float64).tolist() for k, v in ev.items()})
        return out


def _todo(name: str, rewards: Sequence[str], filtered: bool, done: set[str], args: Any
          ) -> dict[str, list[str]]:
    """Per learner, the data rewards of dataset ``name`` whose cells are not done yet."""
    learners = [lrn for lrn in args.learners if not filtered or lrn in SAFETY_LEARNERS]
    todo = {lrn: [r for r in (["none"] if lrn == "BC" else rewards)
                  if cell_key(name, lrn, r, args) not in done]
            for lrn in learners}
    return {lrn: rs for lrn, rs in todo.items() if rs}


def train_stage(args: Any) -> None:
    """Train and evaluate every missing cell; append one JSON line per cell."""
    results = args.out / "results.jsonl"
    done = done_cells(results)
    budget = Budget(steps=args.steps, hidden=tuple(args.hidden), batch=args.batch,
                    **setting_fields(args))
    evaluation = None
    for name in args.datasets:
        filtered = split_name(name)[2]
        rewards = ["original"] if filtered else list(args.rewards)
        todo = _todo(name, rewards, filtered, done, args)
        if not todo:
            continue
        ds = load_dataset(args, name)
        if args.reward_form == "goal":
            ds = goal_oriented(ds)
        base, rows = sweep.reward_rows(ds, rewards, args.terminals,
                                       sweep.reward_key(args.data_seed, name))
        evaluation = evaluation or Evaluation(args, np.asarray(ds.observations[:16]))
        for learner, cell_rewards in todo.items():
            cell_rows = rows[[rewards.index(r) for r in cell_rewards]]
            _train_program(args, name, learner, cell_rewards, base, cell_rows, budget,
                           evaluation, results, int(ds.size))


def _train_program(args: Any, name: str, learner: str, cell_rewards: Sequence[str],
                   base: odata.Dataset, rows: np.ndarray, budget: Budget,
                   evaluation: Evaluation, results: Path, transitions: int) -> None:
    """Train one learner on dataset ``name`` with the data rewards ``rows`` (every seed in one
    program), evaluate the last iterates and append one row per reward."""
    t0 = time.perf_counter()
    if learner == "BC":
        trainer = sweep.build_plain("BC", base, budget)
        keys = seed_keys(range(args.seeds))
    else:
        trainer = sweep.reward_batched(learner, base, budget)
        keys = sweep.reward_seed_keys(rows, range(args.seeds))
    runs = keys[0].shape[0] if isinstance(keys, tuple) else keys.shape[0]
    progress = progress_printer(f"{name} {learner} ({runs} runs)", args.steps, t0)
    program = json.dumps([cell_key(name, learner, r, args) for r in cell_rewards])
    ckpt = program_checkpoint_dir(args.checkpoints, program)
    curve = LearningCurve(
        lambda st: evaluation(trainer.act, sweep.run_actor_params(st), args.seeds),
        curve_path(ckpt)) if args.curve else None
    on_chunk = progress if curve is None else curve.after(progress)
    beta = beta_of(learner, args)
    state = train_program(trainer, keys, args.chunk, on_chunk, ckpt, {"program": program},
                          None if beta is None else [beta] * runs, name=f"{name} {learner}")
    jax.block_until_ready(state)
    train_s = time.perf_counter() - t0
    groups = evaluation(trainer.act, sweep.run_actor_params(state), args.seeds)
    eval_s = time.perf_counter() - t0 - train_s
    if curve is not None and curve.steps:  # none when resumed at the last chunk
        groups = [{**ev, "curve": c} for ev, c in zip(groups, curve.groups(), strict=True)]
        train_s, eval_s = train_s - curve.seconds, eval_s + curve.seconds
    timing = {"runs_in_program": runs, "program_train_s": train_s, "program_eval_s": eval_s}
    _write_rows(args, results, name, learner, cell_rewards, groups, timing, evaluation,
                transitions)
    remove_program_checkpoints(ckpt)
    print(f"[time] {name} {learner}: {runs} runs × {args.steps} steps in one program, "
          f"train {train_s:.1f} s, eval {eval_s:.1f} s", flush=True)


def _write_rows(args: Any, results: Path, name: str, learner: str,
                cell_rewards: Sequence[str], groups: list[dict], timing: dict[str, Any],
                evaluation: Evaluation, transitions: int) -> None:
    """Append the result row of every reward of one program and print its score."""
    _, cut, filtered = split_name(name)
    results.parent.mkdir(parents=True, exist_ok=True)
    for reward, ev in zip(cell_rewards, groups, strict=True):
        row = {"cell": cell_key(name, learner, reward, args), "dataset": name,
               "recipe": split_name(name)[0], "cut": cut, "filtered": filtered,
               "margin": args.margin if filtered else None, "learner": learner,
               "reward": reward, "reward_form": form_of(reward, args),
               "beta": beta_of(learner, args),
               "terminals": args.terminals, "seeds": args.seeds,
               "steps": args.steps, "hidden": list(args.hidden), "batch": args.batch,
               **timing, "device": jax.devices()[0].device_kind,
               "transitions": transitions, "substeps": args.substeps,
               **setting_fields(args),
               "reference": evaluation.evaluator.reference, **ev}
        with open(results, "a") as f:
            f.write(json.dumps(row) + "\n")
        score = np.asarray(ev["normalized_score"])
        print(f"[train] {name:22s} {learner:4s} {reward:8s}: score "
              f"{score.mean():7.1f} ± {standard_error(score):5.1f}  safe "
              f"{np.mean(ev['safe_pct']):5.1f} %  success "
              f"{np.mean(ev['success_pct']):5.1f} %", flush=True)


__all__ = ["Evaluation", "standard_error", "train_stage"]
