"""Chapter 7 on our reaching tasks: offline PLfO (Table 7.2 scenarios) with MAHALO and the
baselines, scored in the MJX environment — a Table 7.3-style table.

::

    python scripts/reproduce_ch7.py                     # CPU-sized smoke run (env3 only)
    python scripts/reproduce_ch7.py --preset gpu        # 3-link env3 and Franka, 5 seeds
    python scripts/reproduce_ch7.py --stage table       # redraw the table from the results

Stages (``--stage all`` runs them in order; each is resumable):

1. **collect** — per environment a ``mixed`` dataset (random + noisy experts; :mod:`offline.
   collect`, ``--scale`` episodes per source) and an ``expert`` dataset (``--expert-scale``
   episodes, default ``--scale``),
   collected in the compiled graph and cached as checksummed files under ``OUT/data``.
2. **train** — for every environment × scenario (``ILfO IL RLfO RL-expert RL-sample``) ×
   learner (:data:`offline.experiment.run.TABLE_LEARNERS`) that has data in that scenario
   (:func:`offline.experiment.run.applicable`): ``--seeds`` seeds vmapped in one program,
   ``--steps`` gradient steps (:class:`offline.experiment.run.Budget`), then ``--eval-episodes``
   episodes per seed in the environment (:mod:`offline.experiment.evaluate`, normalised score: uniform
   random 0, hand-designed expert 100; last iterate). One JSON line per cell in
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
import json
import math
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

ROOT = Path(__file__).resolve().parent.parent
SCENARIO_ORDER = ("ILfO", "IL", "RLfO", "RL-expert", "RL-sample")
PRESETS = {
    "cpu": dict(envs=["three_link/env3"], scale=4, steps=2000, hidden=[64, 64], seeds=5,
                eval_episodes=16, chunk=1000),
    "gpu": dict(envs=["three_link/env3", "franka"], scale=100, steps=100_000,
                hidden=[256, 256, 256], seeds=5, eval_episodes=64, chunk=25_000),
}


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    from offline.experiment.run import TABLE_LEARNERS
    from offline.survival.sweep import (
        add_checkpoint_option,
        add_learner_options,
        add_substeps_option,
        apply_preset,
        control_rate_kwargs,
    )

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", choices=sorted(PRESETS), default="cpu")
    p.add_argument("--stage", choices=("all", "collect", "train", "table"), default="all")
    p.add_argument("--envs", nargs="+", default=None)
    p.add_argument("--scenarios", nargs="+", default=list(SCENARIO_ORDER),
                   choices=SCENARIO_ORDER)
    p.add_argument("--learners", nargs="+", default=list(TABLE_LEARNERS),
                   choices=TABLE_LEARNERS)
    p.add_argument("--seeds", type=int, default=None, help="seeds per cell (vmapped)")
    p.add_argument("--steps", type=int, default=None, help="gradient steps per run")
    p.add_argument("--hidden", type=int, nargs="+", default=None, help="MLP hidden sizes")
    p.add_argument("--scale", type=int, default=None, help="episodes per dataset source")
    p.add_argument("--expert-scale", type=int, default=None, metavar="EPISODES",
                   help="episodes of the expert dataset (default: --scale, as §7.4.2's "
                        "Meta-World protocol; §7.4.1's D4RL protocol gives a small expert set; "
                        "cells get their own key)")
    p.add_argument("--eval-episodes", type=int, default=None)
    p.add_argument("--chunk", type=int, default=None, help="gradient steps per compiled call")
    p.add_argument("--curve", action="store_true",
                   help="also evaluate every seed after each --chunk steps: learning curves in "
                        "the result rows (`curve`; evaluation only, training is unchanged)")
    add_checkpoint_option(p)
    add_learner_options(p)
    p.add_argument("--remove-terminals", action="store_true",
                   help="treat terminals (collisions) as timeouts in both datasets")
    p.add_argument("--data-seed", type=int, default=0)
    add_substeps_option(p)
    p.add_argument("--out", type=Path, default=ROOT / "results" / "ch7")
    args = p.parse_args(argv)
    args = apply_preset(p, args, PRESETS[args.preset],
                        ("seeds", "steps", "scale", "eval_episodes", "chunk"))
    if args.expert_scale is not None and args.expert_scale < 1:
        p.error(f"--expert-scale must be >= 1 episode, got {args.expert_scale}")
    if args.expert_scale == args.scale:
        args.expert_scale = None  # the default: same data, same cell keys
    if args.substeps is not None:
        try:
            for env in args.envs:
                control_rate_kwargs(env, args.substeps)
        except ValueError as e:
            p.error(str(e))
    return args


def recipe_scale(args, recipe: str) -> int:
    """Episodes per source of ``recipe``'s dataset: ``--expert-scale`` for the expert set."""
    return args.expert_scale if recipe == "expert" and args.expert_scale else args.scale


def data_path(out: Path, env: str, recipe: str, scale: int, seed: int,
              substeps: int | None = None) -> Path:
    from offline.survival.sweep import substeps_tag

    tag = "".join(f"_{part}" for part in substeps_tag(substeps))
    return out / "data" / f"{env.replace('/', '-')}_{recipe}_x{scale}_s{seed}{tag}.npz"


def collect_stage(args) -> None:
    """Collect (or find cached) the mixed and expert datasets of every environment."""
    from offline.survival.sweep import collect_cached, control_rate_kwargs

    for env in args.envs:
        for recipe in ("mixed", "expert"):
            n = recipe_scale(args, recipe)
            collect_cached(data_path(args.out, env, recipe, n, args.data_seed, args.substeps),
                           env, recipe, n, args.data_seed, f"{env} {recipe}",
                           env_kwargs=control_rate_kwargs(env, args.substeps))


def _cell_key(env: str, scenario: str, learner: str, args) -> str:
    from offline.survival.sweep import setting_key, substeps_tag

    key = [env, scenario, learner, args.steps, list(args.hidden), args.seeds, args.scale,
           args.remove_terminals, args.eval_episodes]
    n = _expert_scale(scenario, args)
    return json.dumps(key + setting_key(args) + ([] if n is None else ["expert_scale", n])
                      + substeps_tag(args.substeps))


def _expert_scale(scenario: str, args) -> int | None:
    """``--expert-scale`` in scenarios that read the expert set; None for the default and for
    RL-sample, whose cells are the same computation for every expert set."""
    from offline.data.scenarios import EXPERT_FREE

    return None if scenario in EXPERT_FREE else args.expert_scale


def train_stage(args) -> None:
    """Train and evaluate every missing cell; append one JSON line per cell."""
    from offline.data import collect, scenarios
    from offline.data import dataset as odata
    from offline.experiment import evaluate
    from offline.experiment import run as experiment
    from offline.learners.base import actor_params
    from offline.survival.sweep import (
        LearningCurve,
        control_rate_kwargs,
        curve_path,
        done_cells,
        program_checkpoint_dir,
        progress_printer,
        remove_program_checkpoints,
        setting_fields,
        train_program,
    )

    results = args.out / "results.jsonl"
    done = done_cells(results)
    budget = experiment.Budget(steps=args.steps, hidden=tuple(args.hidden),
                               **setting_fields(args))
    keys = experiment.seed_keys(range(args.seeds))
    for env in args.envs:
        env_kwargs = control_rate_kwargs(env, args.substeps)
        env_obj = collect.make_env(env, env_kwargs)
        mixed, expert = (odata.check_environment(
            odata.load(data_path(args.out, env, recipe, recipe_scale(args, recipe),
                                 args.data_seed, args.substeps)), env_obj,
            name=recipe) for recipe in ("mixed", "expert"))
        evaluator = None
        for scenario in args.scenarios:
            dyn, rd = scenarios.make(scenario, mixed, expert,
                                     key=jax.random.PRNGKey(args.data_seed),
                                     keep_terminals=not args.remove_terminals)
            for learner in args.learners:
                cell = _cell_key(env, scenario, learner, args)
                if cell in done or not experiment.applicable(learner, scenario):
                    continue
                if learner in experiment.DYNAMICS_ONLY and _share_run(
                        results, cell, env, scenario, learner, args, int(rd.size)):
                    done.add(cell)
                    continue
                evaluator = evaluator or evaluate.make_evaluator(env, args.eval_episodes,
                                                                 env_kwargs=env_kwargs)
                t0 = time.perf_counter()
                trainer = experiment.build(learner, dyn, rd, budget, scenario)

                progress = progress_printer(f"{env} {scenario} {learner}", args.steps, t0)

                def score(st, _t=trainer, _e=evaluator) -> list[dict[str, list[float]]]:
                    ev = jax.vmap(lambda p: _e.evaluate(_t.act, p, jax.random.PRNGKey(10_000)))(
                        actor_params(st))
                    return [{k: np.asarray(v, np.float64).tolist() for k, v in ev.items()}]

                ckpt = program_checkpoint_dir(args.checkpoints, cell)
                curve = LearningCurve(score, curve_path(ckpt)) if args.curve else None
                state = train_program(trainer, keys, args.chunk,
                                      progress if curve is None else curve.after(progress),
                                      ckpt, {"program": cell})
                train_s = time.perf_counter() - t0
                ev = score(state)[0]
                eval_s = time.perf_counter() - t0 - train_s
                if curve is not None and curve.steps:  # none when resumed at the last chunk
                    ev["curve"] = curve.groups()[0]
                    train_s, eval_s = train_s - curve.seconds, eval_s + curve.seconds
                row = {"cell": cell, "env": env, "substeps": args.substeps,
                       "scenario": scenario, "learner": learner,
                       "seeds": args.seeds, "steps": args.steps, "hidden": list(args.hidden),
                       "train_s": train_s, "eval_s": eval_s,
                       "device": jax.devices()[0].device_kind,
                       "dynamics_transitions": int(dyn.size),
                       "reward_transitions": int(rd.size),
                       "expert_scale": _expert_scale(scenario, args),
                       **setting_fields(args),
                       "reference": evaluator.reference, **ev}
                results.parent.mkdir(parents=True, exist_ok=True)
                with open(results, "a") as f:
                    f.write(json.dumps(row) + "\n")
                remove_program_checkpoints(ckpt)
                score = np.asarray(ev["normalized_score"])
                print(f"[train] {env} {scenario:9s} {learner:6s}: score {score.mean():7.1f} ± "
                      f"{score.std(ddof=1) / math.sqrt(len(score)):5.1f}  safe "
                      f"{np.mean(ev['safe_pct']):5.1f} %  ({train_s:.0f} s train)", flush=True)


def _share_run(results: Path, cell: str, env: str, scenario: str, learner: str, args,
               reward_transitions: int) -> bool:
    """Append ``cell``'s row as a copy of a finished run of ``learner`` (one of
    :data:`offline.experiment.run.DYNAMICS_ONLY`) in a scenario with the same dynamics data
    (:func:`offline.data.scenarios.same_dynamics`), if there is one: the same computation, so the
    Oracle is trained once per dynamics dataset, as thesis Table 7.3 reports one Oracle score for
    RLfO and RL-expert. The row records ``shared_from``. Returns whether it did."""
    from offline.data.scenarios import same_dynamics
    from offline.survival.sweep import result_rows

    rows = {r["cell"]: r for r in result_rows(results)}  # read afresh: other processes append
    for other in same_dynamics(scenario):
        source = rows.get(_cell_key(env, other, learner, args))
        if source is not None and other != scenario:
            row = {**source, "cell": cell, "scenario": scenario, "train_s": 0.0, "eval_s": 0.0,
                   "expert_scale": _expert_scale(scenario, args),
                   "reward_transitions": reward_transitions,
                   "shared_from": source.get("shared_from", source["cell"])}
            with open(results, "a") as f:
                f.write(json.dumps(row) + "\n")
            print(f"[train] {env} {scenario:9s} {learner:6s}: the run of {other} (same dynamics "
                  f"data)", flush=True)
            return True
    return False


def _fmt(mean: float, se: float, bold: bool) -> str:
    s = f"{mean:.1f} ± {se:.1f}"
    return f"**{s}**" if bold else s


def table_stage(args) -> dict:
    """Write and print the Table 7.3-style table; return the per-cell summary."""
    from offline.experiment.run import TABLE_LEARNERS
    from offline.survival.sweep import result_rows, setting_fields

    path = args.out / "results.jsonl"
    if not path.exists():
        raise SystemExit(f"no results at {path}: run --stage train first")
    rows = result_rows(path)
    # The cells of ``--envs`` with the key ``args`` gives them: run budget (steps, seeds,
    # network, data scale, terminals, evaluation episodes), learner setting, expert-set size and
    # control rate (RL-sample keys do not depend on the expert set).
    rows = [r for r in rows if r["env"] in args.envs
            and r["cell"] == _cell_key(r["env"], r["scenario"], r["learner"], args)]
    if not rows:
        settings = ", ".join(f"{k}={v}" for k, v in {
            "steps": args.steps, "seeds": args.seeds, "scale": args.scale,
            **setting_fields(args), "expert_scale": args.expert_scale,
            "substeps": args.substeps}.items())
        raise SystemExit(f"no results with {settings} in {path}")
    cells: dict = {}
    for r in rows:
        s = np.asarray(r["normalized_score"], np.float64)
        cells[(r["env"], r["scenario"], r["learner"])] = (
            float(s.mean()), float(s.std(ddof=1) / math.sqrt(len(s))) if len(s) > 1 else 0.0,
            float(np.mean(r["safe_pct"])), len(s))
    envs = list(dict.fromkeys(r["env"] for r in rows))
    header = ["scenario", "dataset", *TABLE_LEARNERS]
    md = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    csv = [",".join(["scenario", "dataset", "learner", "mean", "se", "safe_pct", "seeds",
                     "bold"])]
    summary = {"cells": 0, "mahalo_within_90": 0, "mahalo_beats_bc_bco_ilfo": {}}
    for scenario in SCENARIO_ORDER:
        for env in envs:
            here = {lrn: cells[(env, scenario, lrn)] for lrn in TABLE_LEARNERS
                    if (env, scenario, lrn) in cells}
            if not here:
                continue
            # Bold: within 90 % of the best non-Oracle score (none bold in an Oracle-only row).
            best = max((v[0] for k, v in here.items() if k != "Oracle"), default=None)
            thresh = math.inf if best is None else best - 0.1 * abs(best)
            entries = []
            for lrn in TABLE_LEARNERS:
                if lrn not in here:
                    entries.append("–")
                    continue
                mean, se, safe, n = here[lrn]
                bold = lrn != "Oracle" and mean >= thresh
                entries.append(_fmt(mean, se, bold))
                csv.append(f"{scenario},{env},{lrn},{mean:.3f},{se:.3f},{safe:.2f},{n},"
                           f"{int(bold)}")
            md.append(f"| {scenario} | {env} | " + " | ".join(entries) + " |")
            summary["cells"] += 1
            if "MAHALO" in here and here["MAHALO"][0] >= thresh:
                summary["mahalo_within_90"] += 1
            if scenario == "ILfO" and "MAHALO" in here:  # None: BC or BCO not run
                summary["mahalo_beats_bc_bco_ilfo"][env] = (
                    bool(all(here["MAHALO"][0] > here[b][0] for b in ("BC", "BCO")))
                    if all(b in here for b in ("BC", "BCO")) else None)
    text = "\n".join(md)
    note = (f"\nMAHALO within 90 % of the best non-Oracle score in "
            f"{summary['mahalo_within_90']} of {summary['cells']} scenario × dataset cells; "
            f"MAHALO > BC and BCO in ILfO: {summary['mahalo_beats_bc_bco_ilfo']}\n")
    (args.out / "table.md").write_text(text + "\n" + note)
    (args.out / "table.csv").write_text("\n".join(csv) + "\n")
    print(text + "\n" + note, flush=True)
    return summary


def main(argv: Sequence[str] | None = None) -> None:
    """Run the selected stages."""
    from offline.survival.sweep import run_stages

    args = parse_args(argv)
    run_stages(args, {"collect": collect_stage, "train": train_stage, "table": table_stage},
               f"device {jax.devices()[0].device_kind}; preset {args.preset}: envs {args.envs}, "
               f"{args.seeds} seeds × {args.steps} steps, hidden {args.hidden}, "
               f"scale {args.scale}, normalize observations {args.normalize_observations}, "
               f"actor {args.actor}")

if __name__ == "__main__":
    main()
