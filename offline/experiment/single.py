"""One offline learner on one dataset or PLfO scenario, several seeds (and β values) vmapped in
one program, then scored in the MJX environment — ``scripts/train_offline.py`` (thesis §7.4;
docs/design.md §2.4).

Data: ``--dataset`` (a file written by ``scripts/collect.py``; its environment is read from the
file) or, without it, a ``--recipe`` dataset of ``--scale`` episodes per source collected on
``--env``. PLfO scenarios also need expert data: ``--expert`` or an ``expert`` recipe collected
the same way. Without a scenario the learner reads the dataset's own rewards.

:func:`train` writes to ``--out``: ``metrics.csv`` (per chunk: steps, seed, every training
metric), ``checkpoints/`` (orbax, every chunk; ``--resume`` continues from the newest and refuses
one of another learner, scenario or configuration) and ``result.json`` (the configuration, wall
times and the evaluation per run). ``--betas`` trains every seed at every Bellman weight β in
one program (runs seed-major).
"""

from __future__ import annotations

import csv
import json
import time
import warnings
from pathlib import Path
from typing import Any

import jax
import numpy as np

from agents.run import checkpoint
from agents.run.training import ProgressBar
from offline.data import collect, scenarios
from offline.data import dataset as odata
from offline.data.rollouts import make_env
from offline.experiment import evaluate
from offline.experiment.programs import train_program
from offline.experiment.run import build, seed_beta_runs, seed_keys
from offline.experiment.settings import LEARNER_OPTIONS, Option, setting_changes, setting_fields
from offline.learners.base import actor_params
from offline.learners.registry import BETA_LEARNERS, LEARNERS, Budget

#: The command line of ``scripts/train_offline.py``.
#: The environment trained on when neither ``--env`` nor a dataset names one.
DEFAULT_ENV = "three_link/env3"

#: Prefix of a ``--dataset`` / ``--expert`` value naming a Minari dataset id or folder.
MINARI_PREFIX = "minari:"

OPTIONS = (
    Option(("--learner",), dict(required=True, choices=LEARNERS)),
    Option(("--scenario",), dict(default=None, choices=scenarios.SCENARIOS)),
    Option(("--dataset",), dict(type=Path, default=None, help=(
        f"dataset file (scripts/collect.py) or {MINARI_PREFIX}ID_OR_FOLDER (a local Minari "
        "dataset, offline.data.minari)"))),
    Option(("--expert",), dict(type=Path, default=None,
                               help="expert dataset file or Minari dataset (scenarios)")),
    Option(("--env",), dict(default=None, help=(
        "environment to train on; default: the --dataset's recorded environment, else "
        f"{DEFAULT_ENV} (collected on when no --dataset is given)"))),
    Option(("--recipe",), dict(default="mixed", help="recipe collected without --dataset")),
    Option(("--scale",), dict(type=int, default=8, help="episodes per source when collecting")),
    Option(("--seeds",), dict(type=int, nargs="+", default=[0, 1])),
    Option(("--betas",), dict(
        type=float, nargs="+", default=None,
        help="Bellman weights β to train at, every seed at every β in one program (ATAC-type "
             "learners; default: each learner's own β)")),
    Option(("--steps",), dict(type=int, default=2000, help="gradient steps")),
    Option(("--hidden",), dict(type=int, nargs="+", default=[256, 256, 256])),
    Option(("--batch",), dict(type=int, default=256)),
    Option(("--chunk",), dict(type=int, default=500,
                              help="steps per compiled call/checkpoint")),
    Option(("--eval-episodes",), dict(type=int, default=32)),
    Option(("--reference-episodes",), dict(
        type=int, default=evaluate.REFERENCE_EPISODES,
        help="episodes of the expert and random reference returns of the normalised score "
             "(default %(default)s; fewer only for quick checks)")),
    Option(("--remove-terminals",), dict(action="store_true")),
    *LEARNER_OPTIONS,
    Option(("--data-seed",), dict(type=int, default=0)),
    Option(("--out",), dict(type=Path, default=Path("runs/offline"))),
    Option(("--resume",), dict(action="store_true")),
    Option(("--no-progress",), dict(action="store_true")),
)


def check_args(args: Any) -> Any:
    """Check the parsed :data:`OPTIONS` (``ValueError`` with the message for the command
    line); returns ``args``."""
    for name in ("scale", "steps", "batch", "chunk", "eval_episodes", "reference_episodes"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be a positive integer")
    for flag, path in (("--dataset", args.dataset), ("--expert", args.expert)):
        if path is not None and str(path).startswith(MINARI_PREFIX):
            from offline.data import minari as ominari  # lazy: the optional `minari` extra
            try:
                ominari.locate(str(path)[len(MINARI_PREFIX):])
            except FileNotFoundError as e:
                raise ValueError(f"{flag}: {e}") from None
        elif path is not None and not path.exists():
            raise ValueError(f"dataset file {path} does not exist")
    if args.expert is not None and args.scenario is None:
        raise ValueError("--expert is only used with --scenario")
    if args.betas is not None:
        if args.learner not in BETA_LEARNERS:
            raise ValueError(f"--betas needs a learner with ATAC's Bellman weight "
                             f"{list(BETA_LEARNERS)}, got {args.learner}")
        if any(not (np.isfinite(b) and b >= 0) for b in args.betas):
            raise ValueError(f"--betas must be finite numbers >= 0, got {args.betas}")
    return args


def read_dataset(path: Path) -> odata.Dataset:
    """The dataset of a ``--dataset`` / ``--expert`` value: a dataset file
    (:func:`offline.data.dataset.load`) or ``minari:ID_OR_FOLDER``, a local Minari dataset
    (:func:`offline.data.minari.import_minari`)."""
    spec = str(path)
    if spec.startswith(MINARI_PREFIX):
        from offline.data import minari as ominari  # lazy: the optional `minari` extra
        return ominari.import_minari(spec[len(MINARI_PREFIX):])
    return odata.load(path)


def load_data(args: Any) -> tuple[str, odata.Dataset, scenarios.RewardData | None]:
    """``(env_name, dynamics, reward_data)``: the dataset (or scenario pair) of the run."""

    def get(path: Path | None, recipe: str) -> odata.Dataset:
        if path is not None:
            return read_dataset(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # the documented no-PPO fallback
            return collect.collect_recipe(args.env or DEFAULT_ENV, recipe, args.scale,
                                          seed=args.data_seed)

    data = get(args.dataset, args.recipe)
    # an explicit --env is the learner's environment: check_environment refuses a dataset
    # recorded on another one (naming both)
    env = args.env or data.metadata.get("env", DEFAULT_ENV)
    odata.check_environment(data, make_env(env), name=str(args.dataset or "dataset"))
    if args.scenario is None:
        if args.remove_terminals:
            data = scenarios.terminals_as_timeouts(data)
        return env, data, None
    expert = odata.check_environment(get(args.expert, "expert"), make_env(env),
                                     name=str(args.expert or "expert"))
    dyn, rd = scenarios.make(args.scenario, data, expert,
                             key=jax.random.PRNGKey(args.data_seed),
                             keep_terminals=not args.remove_terminals)
    return env, dyn, rd


def _metrics_writer(path: Path, runs: list[tuple[int, float | None]], labels: list[str],
                    bar: ProgressBar | None) -> Any:
    """An ``on_chunk`` callback appending every run's chunk means to ``metrics.csv`` (header
    first) and updating the progress bar."""

    def on_chunk(st: Any, means: dict, done: int) -> None:
        new = not path.exists()
        with open(path, "a", newline="") as f:
            w = csv.writer(f)
            if new:
                w.writerow(["steps", *labels, *means])
            for i, run in enumerate(runs):
                w.writerow([done, *run[:len(labels)],
                            *(f"{float(v[i]):.6g}" for v in means.values())])
        if bar is not None:
            losses = [f"{k} {float(np.mean(v)):.3g}" for k, v in means.items() if "loss" in k]
            bar.update(done, " ".join(losses[:3]))

    return on_chunk


def train(args: Any) -> dict[str, Any]:
    """Train (checkpointed, resumable), evaluate and write ``result.json``; return the result
    (the run's configuration, wall times, device, reference returns and per-run evaluation).
    A run whose loss or parameters turn non-finite raises
    :class:`mjxrmp.divergence.DivergenceError` (learner, gradient step, seed and quantity):
    ``metrics.csv`` and ``checkpoints/`` end at the last finite chunk, nothing is evaluated and
    ``result.json`` is not written."""
    t_start = time.perf_counter()
    env, dyn, rd = load_data(args)
    budget = Budget(steps=args.steps, hidden=tuple(args.hidden), batch=args.batch,
                    **setting_fields(args))
    trainer = build(args.learner, dyn, rd, budget, args.scenario)
    run_seeds, run_betas = seed_beta_runs(args.seeds, args.betas)
    meta = {"learner": args.learner, "scenario": args.scenario, "env": env,
            "seeds": list(args.seeds), "steps": args.steps, "hidden": list(args.hidden),
            "batch": args.batch, "remove_terminals": args.remove_terminals,
            "dynamics_transitions": int(dyn.size)}
    meta.update(setting_changes(args))  # only changed settings: old checkpoints resume
    if run_betas is not None:  # one entry per run, seed-major
        meta["run_seeds"], meta["betas"] = run_seeds, run_betas
    ckpt_dir = args.out / "checkpoints"
    resuming = checkpoint.latest_step(ckpt_dir) is not None
    if resuming and not args.resume:
        raise SystemExit(f"{args.out} already holds a run; pass --resume or another --out")
    args.out.mkdir(parents=True, exist_ok=True)
    bar = None if args.no_progress else ProgressBar(args.steps)
    csv_path = args.out / "metrics.csv"
    if not resuming and csv_path.exists():
        csv_path.unlink()
    t_train = time.perf_counter()
    labels = ["seed"] + (["beta"] if run_betas else [])
    runs = list(zip(run_seeds, run_betas or [None] * len(run_seeds), strict=True))
    try:
        state = train_program(trainer, seed_keys(run_seeds), args.chunk,
                              _metrics_writer(csv_path, runs, labels, bar), ckpt_dir, meta,
                              run_betas, name=args.learner, runs=[
                                  f"seed {s}" + ("" if b is None else f", β {b:g}")
                                  for s, b in runs])
    except checkpoint.IncompatibleCheckpointError as err:
        raise SystemExit(f"--resume: {err}") from None
    finally:
        if bar is not None:
            bar.close()
    train_s = time.perf_counter() - t_train
    evaluator = evaluate.make_evaluator(env, args.eval_episodes,
                                        reference_episodes=args.reference_episodes)
    ev = jax.vmap(lambda p: evaluator.evaluate(trainer.act, p, jax.random.PRNGKey(10_000)))(
        actor_params(state))
    result = {**meta, "train_s": train_s, "wall_s": time.perf_counter() - t_start,
              "device": jax.devices()[0].device_kind, "reference": evaluator.reference,
              **{k: np.asarray(v, np.float64).tolist() for k, v in ev.items()}}
    tmp = args.out / "result.json.tmp"
    tmp.write_text(json.dumps(result, indent=1) + "\n")
    tmp.replace(args.out / "result.json")
    return result


def summary_lines(args: Any, result: dict[str, Any]) -> list[str]:
    """The lines ``scripts/train_offline.py`` prints: per β, the mean normalised score, per-seed
    scores, safe % and success %; then the training time and the output folder."""
    score = np.asarray(result["normalized_score"])
    runs = result.get("betas") or [None] * len(score)
    lines = []
    for beta in args.betas or [None]:
        pick = [i for i, b in enumerate(runs) if b == beta]
        at = "" if beta is None else f" at β {beta:g}"
        lines.append(
            f"{args.learner} on {result['env']} ({args.scenario or 'dataset rewards'}), seeds "
            f"{args.seeds}{at}: normalised score {score[pick].mean():.1f} (per seed "
            f"{np.round(score[pick], 1).tolist()}), safe "
            f"{np.mean(np.asarray(result['safe_pct'])[pick]):.1f} %, success "
            f"{np.mean(np.asarray(result['success_pct'])[pick]):.1f} %")
    lines.append(f"train {result['train_s']:.0f} s → {args.out}")
    return lines


__all__ = ["MINARI_PREFIX", "OPTIONS", "check_args", "load_data", "read_dataset", "summary_lines",
           "train"]
