"""Train one offline learner on one dataset or PLfO scenario, several seeds vmapped, then score it
in the MJX environment.

::

    python scripts/train_offline.py --learner MAHALO --env three_link/env3 --scenario ILfO
    python scripts/train_offline.py --learner IQL --dataset data/env3_mixed.npz --steps 100000
    python scripts/train_offline.py ... --resume          # continue from the last checkpoint
    python scripts/train_offline.py --learner Oracle --betas 0.25 1 4 16   # seeds × β, one program

Data: ``--dataset`` (a file written by ``scripts/collect.py``; its environment is read from the
file) or, without it, a ``--recipe`` dataset of ``--scale`` episodes per source collected on
``--env`` (default ``mixed``). PLfO scenarios (``--scenario ILfO|IL|RLfO|RL-expert|RL-sample``)
also need expert data: ``--expert`` or an ``expert`` recipe collected the same way. Without a
scenario the learner reads the dataset's own rewards (``Oracle``/``PSPI``/``IQL``/``CQL``/``BC``).
Learners and what each reads: :mod:`offline.experiment.run`.

Writes to ``--out``: ``metrics.csv`` (per chunk: steps, seed, every training metric),
``checkpoints/`` (orbax, every chunk; ``--resume`` continues from the newest and refuses one of
another learner, scenario or configuration, ``--normalize-observations`` and ``--actor``
included), and
``result.json`` (the configuration, wall times and the evaluation: mean return, normalised
score — random 0, expert 100 —, safe % and success % per run). A progress bar shows steps,
losses and the ETA. ``--betas`` (ATAC-type learners, :data:`offline.experiment.run.BETA_LEARNERS`)
trains every seed at every Bellman weight β in one vmapped program (runs seed-major; ``beta`` in
``metrics.csv`` and ``result.json``) — ATAC's per-dataset selection of β.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag before JAX initialises)

# isort: split
import jax
import numpy as np


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    from offline.data.scenarios import SCENARIOS
    from offline.experiment.run import LEARNERS
    from offline.survival.sweep import add_learner_options

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--learner", required=True, choices=LEARNERS)
    p.add_argument("--scenario", default=None, choices=SCENARIOS)
    p.add_argument("--dataset", type=Path, default=None, help="dataset file (scripts/collect.py)")
    p.add_argument("--expert", type=Path, default=None, help="expert dataset file (scenarios)")
    p.add_argument("--env", default="three_link/env3",
                   help="environment to collect on when no --dataset is given")
    p.add_argument("--recipe", default="mixed", help="recipe collected without --dataset")
    p.add_argument("--scale", type=int, default=8, help="episodes per source when collecting")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    p.add_argument("--betas", type=float, nargs="+", default=None,
                   help="Bellman weights β to train at, every seed at every β in one program "
                        "(ATAC-type learners; default: each learner's own β)")
    p.add_argument("--steps", type=int, default=2000, help="gradient steps")
    p.add_argument("--hidden", type=int, nargs="+", default=[256, 256, 256])
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--chunk", type=int, default=500, help="steps per compiled call/checkpoint")
    p.add_argument("--eval-episodes", type=int, default=32)
    p.add_argument("--remove-terminals", action="store_true")
    add_learner_options(p)
    p.add_argument("--data-seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path("runs/offline"))
    p.add_argument("--resume", action="store_true")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    for name in ("scale", "steps", "batch", "chunk", "eval_episodes"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be a positive integer")
    for path in (args.dataset, args.expert):
        if path is not None and not path.exists():
            p.error(f"dataset file {path} does not exist")
    if args.expert is not None and args.scenario is None:
        p.error("--expert is only used with --scenario")
    if args.betas is not None:
        from offline.experiment.run import BETA_LEARNERS

        if args.learner not in BETA_LEARNERS:
            p.error(f"--betas needs a learner with ATAC's Bellman weight {list(BETA_LEARNERS)}, "
                    f"got {args.learner}")
        if any(not (np.isfinite(b) and b >= 0) for b in args.betas):
            p.error(f"--betas must be finite numbers >= 0, got {args.betas}")
    return args


def load_data(args):
    """``(env_name, dynamics, reward_data)``: the dataset (or scenario pair) of the run."""
    import warnings

    from offline.data import collect, scenarios
    from offline.data import dataset as odata

    def get(path, recipe):
        if path is not None:
            return odata.load(path)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # the documented no-PPO fallback
            return collect.collect_recipe(args.env, recipe, args.scale, seed=args.data_seed)

    data = get(args.dataset, args.recipe)
    env = data.metadata.get("env", args.env)
    odata.check_environment(data, collect.make_env(env), name=str(args.dataset or "dataset"))
    if args.scenario is None:
        if args.remove_terminals:
            data = scenarios.terminals_as_timeouts(data)
        return env, data, None
    expert = odata.check_environment(get(args.expert, "expert"), collect.make_env(env),
                                     name=str(args.expert or "expert"))
    if expert.metadata.get("env", env) != env:
        raise SystemExit(f"--expert was collected on {expert.metadata.get('env')!r}, the "
                         f"dataset on {env!r}")
    dyn, rd = scenarios.make(args.scenario, data, expert,
                             key=jax.random.PRNGKey(args.data_seed),
                             keep_terminals=not args.remove_terminals)
    return env, dyn, rd


def main(argv: Sequence[str] | None = None) -> dict:
    """Train, checkpoint, evaluate; return the result dictionary."""
    from agents.run import checkpoint
    from agents.run.training import ProgressBar
    from offline.experiment import evaluate
    from offline.experiment import run as experiment
    from offline.learners.base import actor_params
    from offline.survival.sweep import setting_changes, setting_fields, train_program

    args = parse_args(argv)
    t_start = time.perf_counter()
    env, dyn, rd = load_data(args)
    budget = experiment.Budget(steps=args.steps, hidden=tuple(args.hidden), batch=args.batch,
                               **setting_fields(args))
    trainer = experiment.build(args.learner, dyn, rd, budget, args.scenario)
    run_seeds, run_betas = experiment.seed_beta_runs(args.seeds, args.betas)
    keys = experiment.seed_keys(run_seeds)
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

    def on_chunk(st, means, done):
        new = not csv_path.exists()
        with open(csv_path, "a", newline="") as f:
            w = csv.writer(f)
            if new:
                w.writerow(["steps", *labels, *means])
            for i, run in enumerate(runs):
                w.writerow([done, *run[:len(labels)],
                            *(f"{float(v[i]):.6g}" for v in means.values())])
        if bar is not None:
            losses = [f"{k} {float(np.mean(v)):.3g}" for k, v in means.items() if "loss" in k]
            bar.update(done, " ".join(losses[:3]))

    try:
        state = train_program(trainer, keys, args.chunk, on_chunk, ckpt_dir, meta, run_betas)
    except checkpoint.IncompatibleCheckpointError as err:
        raise SystemExit(f"--resume: {err}") from None
    if bar is not None:
        bar.close()
    train_s = time.perf_counter() - t_train
    evaluator = evaluate.make_evaluator(env, args.eval_episodes)
    ev = jax.vmap(lambda p: evaluator.evaluate(trainer.act, p, jax.random.PRNGKey(10_000)))(
        actor_params(state))
    result = {**meta, "train_s": train_s, "wall_s": time.perf_counter() - t_start,
              "device": jax.devices()[0].device_kind, "reference": evaluator.reference,
              **{k: np.asarray(v, np.float64).tolist() for k, v in ev.items()}}
    tmp = args.out / "result.json.tmp"
    tmp.write_text(json.dumps(result, indent=1) + "\n")
    tmp.replace(args.out / "result.json")
    score = np.asarray(result["normalized_score"])
    for beta in args.betas or [None]:
        pick = [i for i, run in enumerate(runs) if run[1] == beta]
        at = "" if beta is None else f" at β {beta:g}"
        print(f"{args.learner} on {env} ({args.scenario or 'dataset rewards'}), seeds "
              f"{args.seeds}{at}: normalised score {score[pick].mean():.1f} (per seed "
              f"{np.round(score[pick], 1).tolist()}), safe "
              f"{np.mean(np.asarray(result['safe_pct'])[pick]):.1f} %, success "
              f"{np.mean(np.asarray(result['success_pct'])[pick]):.1f} %")
    print(f"train {train_s:.0f} s → {args.out}")
    return result


if __name__ == "__main__":
    main()
