"""Reproduce thesis chapter 6: PPO with NN, NN-residual and RMP-residual policies on the 3-link
reaching setups env1/env2/env3 and the Franka, 4 seeds each; Fig 6.2 (mean episode reward),
Fig 6.3 (safe-episode %) and Fig 6.4 (Franka), mean ± 1 std over seeds.

Two stages, each resumable:

* ``train`` — for every (environment, policy) pair, a run directory ``<runs>/<env>_<policy>``
  trained by :func:`agents.run.training.run_training` (all seeds in one vmapped program); a finished
  run is skipped, an unfinished one resumed. Per-run speed (compile time, steps/s, the
  per-iteration split rollout / policy forward / update) goes to ``<runs>/<env>_<policy>/
  speed.json``.
* ``plot`` — reads every run's ``metrics.csv`` and writes ``fig6_2.png``, ``fig6_3.png``,
  ``fig6_4.png``, ``ch6_summary.csv`` and ``ch6_summary.json`` (final reward, minimum and mean
  safe % over iterations, per policy and setup) to ``--figures``. Curves and the minimum safe %
  use RLlib's reporting: each iteration averages the most recent ≥ 100 finished episodes
  (:func:`episode_window`); the per-iteration minimum is in the table too.

Usage::

    python scripts/reproduce_ch6.py --preset thesis                     # everything (GPU)
    python scripts/reproduce_ch6.py --preset thesis --envs three_link/env3 --policies rmp_residual
    python scripts/reproduce_ch6.py --stage plot --runs results/ch6/runs
    python scripts/reproduce_ch6.py --preset cpu --iterations 20        # a CPU-sized smoke run
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time
import warnings

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag before JAX initialises)

# isort: split
import numpy as np

from agents.run import checkpoint
from agents.run.training import (
    RunSpec,
    build,
    episode_window,
    nanmean,
    preset,
    profile_iteration,
    read_csv,
    run_training,
)

THREE_LINK = ("three_link/env1", "three_link/env2", "three_link/env3")
ENVS = (*THREE_LINK, "franka")
POLICIES = ("nn", "nn_residual", "rmp_residual")
LABELS = {"nn": "NN", "nn_residual": "NN-RESIDUAL", "rmp_residual": "RMP-RESIDUAL",
          "rmp_residual_env": "RMP-RESIDUAL (in env)", "hand_designed": "HAND-DESIGNED"}
COLORS = {"nn": "0.35", "nn_residual": "tab:red", "rmp_residual": "tab:blue",
          "rmp_residual_env": "tab:green", "hand_designed": "tab:orange"}


def run_dir(runs: str, env: str, policy: str) -> str:
    """``<runs>/<env with / → ->_<policy>``."""
    return os.path.join(runs, f"{env.replace('/', '-')}_{policy}")


def train_all(args) -> None:
    """The ``train`` stage (see the module docstring)."""
    overrides = {} if args.iterations is None else {"total_iterations": args.iterations}
    for env in args.envs:
        for policy in args.policies:
            spec = RunSpec(env=env, policy=policy, seeds=tuple(args.seeds),
                           ppo=preset(args.preset, **overrides), log_every=args.log_every,
                           checkpoint_every=args.checkpoint_every)
            out = run_dir(args.runs, env, policy)
            step = checkpoint.latest_step(os.path.join(out, "checkpoints"))
            if step is not None and step >= spec.ppo.total_iterations:
                print(f"{out}: finished ({step} iterations), skipped", file=sys.stderr)
                continue
            print(f"== {policy} on {env}: {len(spec.seeds)} seeds × "
                  f"{spec.ppo.total_iterations} iterations × {spec.ppo.batch_size} steps",
                  file=sys.stderr)
            t0 = time.perf_counter()
            result = run_training(spec, out, resume=step is not None,
                                  progress=not args.no_progress)
            wall = time.perf_counter() - t0
            split = profile_iteration(build(spec), result.state)
            speed = {
                "env": env, "policy": policy, "seeds": list(spec.seeds),
                "iterations": int(result.history["mean_reward"].shape[1]),
                "env_steps": result.env_steps, "compile_s": result.compile_seconds,
                "train_s": result.train_seconds, "wall_s": wall,
                "steps_per_s": result.env_steps / max(result.train_seconds, 1e-9),
                "iteration_split_s": split,
                "device": str(__import__("jax").devices()[0].device_kind),
                "date": time.strftime("%Y-%m-%d"),
            }
            with open(os.path.join(out, "speed.json"), "w") as f:
                json.dump(speed, f, indent=1)
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


def _panel(ax, runs, env, key, scale, smooth, ylabel):
    for policy in LABELS:
        if (env, policy) not in runs:
            continue
        v = episode_window(runs[(env, policy)], key, smooth) * scale
        it = np.arange(1, v.shape[1] + 1)
        mean = nanmean(v, axis=0)
        std = np.sqrt(np.maximum(nanmean((v - mean) ** 2, axis=0), 0.0))
        ax.plot(it, mean, color=COLORS[policy], label=LABELS[policy], lw=1.4)
        ax.fill_between(it, mean - std, mean + std, color=COLORS[policy], alpha=0.2, lw=0)
    ax.set_xlabel("iteration")
    ax.set_ylabel(ylabel)
    if scale == 100.0:
        ax.set_ylim(-2, 102)
    ax.grid(alpha=0.3)


def plot_all(runs_dir: str, figures: str, smooth: int) -> dict:
    """The ``plot`` stage: figures and summary tables; returns the summary."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = load_runs(runs_dir)
    if not runs:
        raise SystemExit(f"no runs with metrics.csv under {runs_dir}")
    os.makedirs(figures, exist_ok=True)
    figs = (("fig6_2.png", "mean_episode_return", 1.0, "mean episode reward"),
            ("fig6_3.png", "safe_fraction", 100.0, "safe episodes (%)"))
    for name, key, scale, ylabel in figs:
        fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
        for ax, env in zip(axes, THREE_LINK, strict=True):
            _panel(ax, runs, env, key, scale, smooth, ylabel)
            ax.set_title(env.split("/")[1])
        axes[0].legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(os.path.join(figures, name), dpi=120)
        plt.close(fig)
    if any(env == "franka" for env, _ in runs):
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
        for ax, (key, scale, ylabel) in zip(axes, (("mean_episode_return", 1.0,
                                                     "mean episode reward"),
                                                    ("safe_fraction", 100.0,
                                                     "safe episodes (%)")), strict=True):
            _panel(ax, runs, "franka", key, scale, smooth, ylabel)
        axes[0].legend(fontsize=8)
        fig.suptitle("Franka reaching")
        fig.tight_layout()
        fig.savefig(os.path.join(figures, "fig6_4.png"), dpi=120)
        plt.close(fig)

    rows = []
    warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices: iterations without episodes
    for (env, policy), h in sorted(runs.items()):
        ret, safe = h["mean_episode_return"], h["safe_fraction"]
        n = ret.shape[1]
        k = max(1, n // 20)  # final reward: mean over the last 5% of iterations and the seeds
        collided = np.nansum((1.0 - safe) * h["episodes"])
        early = slice(0, max(1, n // 5))
        safe_w = episode_window(h, "safe_fraction")
        rows.append({
            "env": env, "policy": policy, "seeds": ret.shape[0], "iterations": n,
            "final_reward": float(nanmean(ret[:, -k:])),
            "final_reward_std": float(np.nanstd(nanmean(ret[:, -k:], axis=1))),
            "min_safe_pct_100ep": float(100 * np.nanmin(nanmean(safe_w, axis=0))),
            "min_safe_pct_100ep_any_seed": float(100 * np.nanmin(safe_w)),
            "min_safe_pct_per_iteration_any_seed": float(100 * np.nanmin(safe)),
            "mean_safe_pct": float(100 * nanmean(safe)),
            "early_safe_pct": float(100 * nanmean(safe[:, early])),
            "collisions": round(float(collided)),
            "episodes": int(np.nansum(h["episodes"])),
        })
    with open(os.path.join(figures, "ch6_summary.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    summary = {"rows": rows}
    by = {(r["env"], r["policy"]): r for r in rows}
    e3 = ("three_link/env3", "rmp_residual"), ("three_link/env3", "nn")
    if all(k in by for k in e3):
        summary["env3_rmp_residual_over_nn"] = (by[e3[0]]["final_reward"]
                                                / max(by[e3[1]]["final_reward"], 1e-9))
    with open(os.path.join(figures, "ch6_summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    for r in rows:
        print(f"{r['env']:16s} {r['policy']:14s} {r['iterations']:3d} it. | final reward "
              f"{r['final_reward']:7.1f} ± {r['final_reward_std']:5.1f} | safe % (100-episode "
              f"window) min {r['min_safe_pct_100ep']:5.1f}, any seed "
              f"{r['min_safe_pct_100ep_any_seed']:5.1f} | mean {r['mean_safe_pct']:5.1f} early "
              f"{r['early_safe_pct']:5.1f} | collisions {r['collisions']}/{r['episodes']}")
    if "env3_rmp_residual_over_nn" in summary:
        print(f"env3 final reward rmp_residual / nn = {summary['env3_rmp_residual_over_nn']:.2f}")
    return summary


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--stage", choices=("all", "train", "plot"), default="all")
    p.add_argument("--envs", nargs="+", default=list(ENVS), choices=ENVS)
    p.add_argument("--policies", nargs="+", default=list(POLICIES), choices=list(LABELS))
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3])
    p.add_argument("--preset", default="thesis")
    p.add_argument("--iterations", type=int, default=None)
    p.add_argument("--runs", default="runs/ch6", help="directory of the run directories")
    p.add_argument("--figures", default="results/ch6", help="where figures and tables go")
    p.add_argument("--log-every", type=int, default=25)
    p.add_argument("--checkpoint-every", type=int, default=100)
    p.add_argument("--smooth", type=int, default=100,
                   help="curves average over the trailing iterations holding at least this many "
                        "episodes (RLlib's 100-episode smoothing; 1: per iteration)")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    if args.stage in ("all", "train"):
        train_all(args)
    if args.stage in ("all", "plot"):
        plot_all(args.runs, args.figures, args.smooth)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
