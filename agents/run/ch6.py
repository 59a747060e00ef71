"""Thesis chapter 6: PPO with NN, NN-residual and RMP-residual policies on the 3-link reaching
setups env1/env2/env3 and the Franka, several seeds each; Fig 6.2 (mean episode reward), Fig 6.3
(safe-episode %) and Fig 6.4 (Franka), mean ± 1 std over seeds. ``scripts/reproduce_ch6.py``
calls :func:`agents.run.ch6_study.reproduce`, which adds the hand-designed baseline and the
study record. Two stages live here, each resumable:

* ``train`` (:func:`train_all`) — for every (environment, policy) pair, a run directory
  ``<runs>/<env>_<policy>`` trained by :func:`agents.run.training.run_training` (all seeds in one
  vmapped program) or, for setups that share a model (env2 and env3) and policy kinds that
  share a network (``nn`` and ``nn_residual``), by one packed sweep
  (:func:`agents.run.sweep.run_sweep`: the setups × the kinds × all seeds in one program;
  :func:`packed_cells`); a finished run is skipped, an unfinished one resumed. Per-run speed
  (compile time, steps/s, the per-iteration split rollout / policy forward / update) goes to
  ``<runs>/<env>_<policy>/speed.json``.
* ``plot`` (:func:`plot_all`) — reads every run's ``metrics.csv`` and writes ``fig6_2.png``,
  ``fig6_3.png``, ``fig6_4.png``, ``ch6_summary.csv`` and ``ch6_summary.json`` (final reward,
  minimum and mean safe % over iterations, per policy and setup). Curves and the minimum safe %
  use RLlib's reporting: each iteration averages the most recent ≥ 100 finished episodes
  (:func:`agents.run.curves.episode_window`); the per-iteration minimum is in the table too.
"""

from __future__ import annotations

import csv
import json
import os
import sys
import time
import warnings
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from agents.ppo.policies import policy_groups
from agents.run import checkpoint
from agents.run.curves import episode_window
from agents.run.logs import nanmean, read_csv
from agents.run.program import build, profile_iteration
from agents.run.spec import RunSpec, preset
from agents.run.sweep import run_sweep
from agents.run.sweep_spec import SweepSpec, model_groups
from agents.run.training import run_training
from mjxrmp.results.summary import package_versions, write_text

THREE_LINK = ("three_link/env1", "three_link/env2", "three_link/env3")
ENVS = (*THREE_LINK, "franka")
POLICIES = ("nn", "nn_residual", "rmp_residual")
LABELS = {"nn": "NN", "nn_residual": "NN-RESIDUAL", "rmp_residual": "RMP-RESIDUAL",
          "rmp_residual_env": "RMP-RESIDUAL (in env)", "hand_designed": "HAND-DESIGNED"}
COLORS = {"nn": "0.35", "nn_residual": "tab:red", "rmp_residual": "tab:blue",
          "rmp_residual_env": "tab:green", "hand_designed": "tab:orange"}


def run_name(env: str, policy: str) -> str:
    """``<env with / → ->_<policy>``: a cell's run directory name and study run key."""
    return f"{env.replace('/', '-')}_{policy}"


def run_dir(runs: str, env: str, policy: str) -> str:
    """``<runs>/<run_name(env, policy)>``."""
    return os.path.join(runs, run_name(env, policy))


def _segment(start: int | None, wall: float, **fields: Any) -> dict[str, Any]:
    return {"from_iteration": int(start or 0), "wall_s": wall,
            "device": str(jax.devices()[0].device_kind), "date": time.strftime("%Y-%m-%d"),
            "versions": package_versions(), **fields}


def packed_groups(names: Sequence[str]) -> list[tuple[str, ...]]:
    """``names`` grouped by the model they share (:func:`agents.run.sweep_spec.model_groups`), in
    order of first appearance; a group trains as one packed program."""
    return [tuple(group) for group in model_groups(names)]


def packed_cells(envs: Sequence[str], policies: Sequence[str]) -> list[list[tuple[str, str]]]:
    """The ``(env, policy)`` cells grouped into programs: setups that share a model
    (:func:`packed_groups`) × policy kinds that share a network
    (:func:`agents.ppo.policies.policy_groups`), each group environment-major (a sweep's point
    order)."""
    return [[(env, kind) for env in setups for kind in kinds]
            for setups in packed_groups(envs) for kinds in policy_groups(policies)]


def _distinct(values: Sequence[str]) -> tuple[str, ...]:
    """``values`` without repeats, in order; empty when there is only one (no sweep axis)."""
    out = tuple(dict.fromkeys(values))
    return out if len(out) > 1 else ()


def _train_group(specs: list[RunSpec], outs: list[str], sweep_dir: str, resume: bool,
                 progress: bool, profile: bool = True) -> list[dict[str, Any]]:
    """Train (or resume) one run, or several cells packed in one program (a sweep over their
    setups × kinds into ``sweep_dir`` with the run directories ``outs``); each run's speed record
    (also written to ``out/speed.json``). Every launch that trains, an interrupted one
    included, adds a segment to the record's ``segments``; ``wall_s`` and ``compile_s`` sum
    them (a packed run counts its share, ``program_wall_s / len(packed_with)``, so the records
    of a grid add up to its GPU time), ``steps_per_s`` is the program's in the last segment.
    ``profile``: also time one iteration's phases (``iteration_split_s``; compiles them anew)."""
    n = len(specs)
    paths = [os.path.join(out, "speed.json") for out in outs]
    segments: list[list[dict[str, Any]]] = [[] for _ in outs]
    for seg, path in zip(segments, paths, strict=True):
        if resume and os.path.exists(path):
            with open(path) as f:
                seg.extend(json.load(f).get("segments", []))
    ckpts = os.path.join(outs[0], "checkpoints")
    start = checkpoint.latest_step(ckpts) if resume else None
    packed = {"packed_with": [os.path.basename(out) for out in outs]} if n > 1 else {}
    sweep = SweepSpec(specs[0], envs=_distinct([s.env for s in specs]),
                      policies=_distinct([s.policy for s in specs])) if n > 1 else None
    t0 = time.perf_counter()
    try:
        result = run_training(specs[0], outs[0], resume=resume, progress=progress) \
            if sweep is None else run_sweep(sweep, sweep_dir, resume=resume, progress=progress,
                                            point_dirs=outs)
    except KeyboardInterrupt:
        wall = time.perf_counter() - t0
        for spec, seg, path in zip(specs, segments, paths, strict=True):
            seg.append(_segment(start, wall / n, interrupted=True, program_wall_s=wall,
                                to_iteration=int(checkpoint.latest_step(ckpts) or 0), **packed))
            write_text(path, json.dumps({"env": spec.env, "policy": spec.policy,
                                         "segments": seg}, indent=1))
        raise
    wall = time.perf_counter() - t0
    done = int(result.history["mean_reward"].shape[1])
    split = profile_iteration(build(specs[0] if sweep is None else sweep.program_spec()),
                              result.state) if profile else None
    records = []
    for spec, seg, path in zip(specs, segments, paths, strict=True):
        seg.append(_segment(start, wall / n, to_iteration=done, program_wall_s=wall,
                            compile_s=result.compile_seconds / n,
                            train_s=result.train_seconds / n, **packed))
        steps = (done - seg[-1]["from_iteration"]) * spec.ppo.batch_size * len(spec.seeds) * n
        records.append({
            "env": spec.env, "policy": spec.policy, "seeds": list(spec.seeds),
            "iterations": done, "env_steps": result.env_steps // n,
            "wall_s": sum(s["wall_s"] for s in seg),
            "compile_s": sum(s.get("compile_s", 0.0) for s in seg),
            "steps_per_s": steps / max(result.train_seconds, 1e-9), "iteration_split_s": split,
            "device": seg[-1]["device"], "date": seg[-1]["date"], "segments": seg, **packed})
        write_text(path, json.dumps(records[-1], indent=1))
    return records


def train_all(runs: str, envs: Sequence[str] = ENVS, policies: Sequence[str] = POLICIES,
              seeds: Sequence[int] = (0, 1, 2, 3), preset_name: str = "thesis",
              iterations: int | None = None, log_every: int = 25, checkpoint_every: int = 100,
              progress: bool = True, profile: bool = True, pack: bool = True,
              **overrides: Any) -> None:
    """The ``train`` stage (see the module docstring); ``profile=False`` skips the per-phase
    timing of one iteration in ``speed.json``; ``pack`` trains each group of
    :func:`packed_cells` in one program (a sweep written to ``<runs>/sweep_<runs>``, the runs in
    their usual directories) when none of its runs or all of them stopped at the same
    iteration; ``overrides`` go to the preset."""
    if iterations is not None:
        overrides["total_iterations"] = iterations
    units = packed_cells(envs, policies) if pack else [[(e, p)] for e in envs for p in policies]
    for cells in units:
        specs = [RunSpec(env=env, policy=kind, seeds=tuple(seeds),
                         ppo=preset(preset_name, **overrides), log_every=log_every,
                         checkpoint_every=checkpoint_every) for env, kind in cells]
        outs = [run_dir(runs, env, kind) for env, kind in cells]
        steps = [checkpoint.latest_step(os.path.join(o, "checkpoints")) for o in outs]
        total = specs[0].ppo.total_iterations
        todo = [i for i, step in enumerate(steps) if step is None or step < total]
        for i in sorted(set(range(len(cells))) - set(todo)):
            print(f"{outs[i]}: finished ({steps[i]} iterations), skipped", file=sys.stderr)
        # one program when the unfinished runs stopped at the same iteration (or are new) and
        # are every setup × kind of theirs
        left = [cells[i] for i in todo]
        grid = len(left) == len({e for e, _ in left}) * len({k for _, k in left})
        parts = [todo] if grid and len({steps[i] for i in todo}) == 1 else [[i] for i in todo]
        for part in parts:
            kinds, setups = (" + ".join(dict.fromkeys(cells[i][c] for i in part)) for c in (1, 0))
            print(f"== {kinds} on {setups}: {len(seeds)} seeds × {total} iterations × "
                  f"{specs[0].ppo.batch_size} steps", file=sys.stderr)
            sweep_dir = os.path.join(runs, "sweep_" + "+".join(
                os.path.basename(outs[i]) for i in part))
            for speed in _train_group([specs[i] for i in part], [outs[i] for i in part],
                                      sweep_dir, steps[part[0]] is not None, progress,
                                      profile):
                print(json.dumps(speed), file=sys.stderr)


def load_runs(runs: str) -> dict[tuple[str, str], dict[str, np.ndarray]]:
    """``{(env, policy): history}`` for every run directory under ``runs`` with a metrics.csv."""
    out = {}
    for env in ENVS:
        for policy in LABELS:
            path = os.path.join(run_dir(runs, env, policy), "metrics.csv")
            if os.path.exists(path):
                out[(env, policy)] = read_csv(path)[0]
    return out


def _panel(ax: Any, runs: dict, env: str, key: str, scale: float, smooth: int,
           ylabel: str, baseline: float | None = None) -> None:
    for policy in LABELS:
        if (env, policy) not in runs:
            continue
        v = episode_window(runs[(env, policy)], key, smooth) * scale
        it = np.arange(1, v.shape[1] + 1)
        mean = nanmean(v, axis=0)
        std = np.sqrt(np.maximum(nanmean((v - mean) ** 2, axis=0), 0.0))
        ax.plot(it, mean, color=COLORS[policy], label=LABELS[policy], lw=1.4)
        ax.fill_between(it, mean - std, mean + std, color=COLORS[policy], alpha=0.2, lw=0)
    if baseline is not None:
        ax.axhline(baseline, color=COLORS["hand_designed"], ls="--", lw=1.2,
                   label=LABELS["hand_designed"])
    ax.set_xlabel("iteration")
    ax.set_ylabel(ylabel)
    if scale == 100.0:
        ax.set_ylim(-2, 102)
    ax.grid(alpha=0.3)


def plot_figures(runs: dict, figures: str, smooth: int,
                 baselines: dict[str, Any] | None = None) -> None:
    """``fig6_2.png`` (reward) and ``fig6_3.png`` (safe %) over the 3-link setups and, when a
    Franka run exists, ``fig6_4.png``; ``baselines`` (``{env: {"mean_return", "safe_pct"}}``,
    the hand-designed policy) are drawn as dashed lines."""
    baselines = baselines or {}

    def level(env: str, key: str) -> float | None:
        b = baselines.get(env)
        if b is None:
            return None
        return b["mean_return"] if key == "mean_episode_return" else b["safe_pct"]

    import matplotlib  # lazy: optional dependency (the "plots" extra)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: optional dependency (after the backend is set)

    reward = ("mean_episode_return", 1.0, "mean episode reward")
    safe = ("safe_fraction", 100.0, "safe episodes (%)")
    for name, (key, scale, ylabel) in (("fig6_2.png", reward), ("fig6_3.png", safe)):
        fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
        for ax, env in zip(axes, THREE_LINK, strict=True):
            _panel(ax, runs, env, key, scale, smooth, ylabel, level(env, key))
            ax.set_title(env.split("/")[1])
        axes[0].legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(os.path.join(figures, name), dpi=120)
        plt.close(fig)
    if any(env == "franka" for env, _ in runs):
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
        for ax, (key, scale, ylabel) in zip(axes, (reward, safe), strict=True):
            _panel(ax, runs, "franka", key, scale, smooth, ylabel, level("franka", key))
        axes[0].legend(fontsize=8)
        fig.suptitle("Franka reaching")
        fig.tight_layout()
        fig.savefig(os.path.join(figures, "fig6_4.png"), dpi=120)
        plt.close(fig)


def summary_row(env: str, policy: str, h: dict[str, np.ndarray]) -> dict[str, Any]:
    """Final reward (mean over the last 5 % of iterations and the seeds, ± std over seeds),
    minimum safe % (100-episode window: seed mean and any seed; per iteration: any seed), mean
    and early (first 20 %) safe %, collisions and episodes of one run's history."""
    ret, safe = h["mean_episode_return"], h["safe_fraction"]
    n = ret.shape[1]
    k = max(1, n // 20)
    early = slice(0, max(1, n // 5))
    with warnings.catch_warnings():  # all-NaN slices: iterations without episodes
        warnings.simplefilter("ignore", RuntimeWarning)
        safe_w = episode_window(h, "safe_fraction")
        return {
            "env": env, "policy": policy, "seeds": ret.shape[0], "iterations": n,
            "final_reward": float(nanmean(ret[:, -k:])),
            "final_reward_std": float(np.nanstd(nanmean(ret[:, -k:], axis=1))),
            "min_safe_pct_100ep": float(100 * np.nanmin(nanmean(safe_w, axis=0))),
            "min_safe_pct_100ep_any_seed": float(100 * np.nanmin(safe_w)),
            "min_safe_pct_per_iteration_any_seed": float(100 * np.nanmin(safe)),
            "mean_safe_pct": float(100 * nanmean(safe)),
            "early_safe_pct": float(100 * nanmean(safe[:, early])),
            "collisions": round(float(np.nansum((1.0 - safe) * h["episodes"]))),
            "episodes": int(np.nansum(h["episodes"])),
        }


def _print_rows(summary: dict[str, Any]) -> None:
    for r in summary["rows"]:
        print(f"{r['env']:16s} {r['policy']:14s} {r['iterations']:3d} it. | final reward "
              f"{r['final_reward']:7.1f} ± {r['final_reward_std']:5.1f} | safe % (100-episode "
              f"window) min {r['min_safe_pct_100ep']:5.1f}, any seed "
              f"{r['min_safe_pct_100ep_any_seed']:5.1f} | mean {r['mean_safe_pct']:5.1f} early "
              f"{r['early_safe_pct']:5.1f} | collisions {r['collisions']}/{r['episodes']}")
    if "env3_rmp_residual_over_nn" in summary:
        print(f"env3 final reward rmp_residual / nn = {summary['env3_rmp_residual_over_nn']:.2f}")


def plot_all(runs_dir: str, figures: str, smooth: int,
             baselines: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``plot`` stage: figures (with the hand-designed ``baselines`` where given),
    ``ch6_summary.csv``/``.json`` and the printed table; returns the summary. Raises
    ``FileNotFoundError`` when no run has a metrics.csv."""
    runs = load_runs(runs_dir)
    if not runs:
        raise FileNotFoundError(f"no runs with metrics.csv under {runs_dir}")
    os.makedirs(figures, exist_ok=True)
    plot_figures(runs, figures, smooth, baselines)
    rows = [summary_row(env, policy, h) for (env, policy), h in sorted(runs.items())]
    with open(os.path.join(figures, "ch6_summary.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    summary: dict[str, Any] = {"rows": rows}
    by = {(r["env"], r["policy"]): r for r in rows}
    e3 = ("three_link/env3", "rmp_residual"), ("three_link/env3", "nn")
    if all(k in by for k in e3):
        summary["env3_rmp_residual_over_nn"] = (by[e3[0]]["final_reward"]
                                                / max(by[e3[1]]["final_reward"], 1e-9))
    with open(os.path.join(figures, "ch6_summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    _print_rows(summary)
    return summary


__all__ = ["COLORS", "ENVS", "LABELS", "POLICIES", "THREE_LINK", "load_runs", "packed_cells",
           "packed_groups", "plot_all", "plot_figures", "run_dir", "run_name", "summary_row",
           "train_all"]
