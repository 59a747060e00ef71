"""The evaluation report of ``scripts/eval.py``: per (checkpoint, setup) statistics over
training seeds, the best row, the screen table and the GIF of the best row's first episode
(sweeps: :mod:`agents.run.evaluation`).

:func:`evaluate_runs` is what the script calls: load the checkpoints, evaluate every group in
one compiled call each (:func:`evaluate`) and render the GIF. The report holds, per training seed
and aggregated over seeds, mean return, success %, safe %, final goal distance, episode length
and non-finite %, and the groups with their compile and run seconds.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import IO, Any

import jax
import numpy as np

from agents.run.evaluation import (
    STATS,
    Sweep,
    group_checkpoints,
    resolve_steps,
    run_sweep,
    setup_env,
)
from agents.run.loading import LoadedRun, env_policy, load_run, mean_action_fn, policy_params
from envs.evaluate import summarize

_SEED_KEYS = ("mean_return", "success_pct", "safe_pct", "mean_final_goal_distance",
              "mean_length", "nonfinite_pct")


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(float(x)) else None


def seed_summary(per_episode: dict[str, np.ndarray]) -> dict[str, float]:
    """Mean return, success %, safe %, final goal distance, length and non-finite % over one
    member's episodes (arrays ``(num_episodes,)``; :func:`envs.evaluate.summarize`)."""
    summary = summarize({**per_episode, "sampler_ok": np.ones_like(per_episode["return"])})
    return {k: summary[k] for k in _SEED_KEYS}


def _row(sweep: Sweep, ci: int, setup: str, per_episode: bool) -> dict[str, Any]:
    """The row of checkpoint ``ci`` on ``setup`` (see :func:`summarize_sweep`)."""
    c = sweep.checkpoints[ci]
    idx = [m for m, (cj, _) in enumerate(sweep.members) if cj == ci]
    eps = sweep.episodes[setup]
    per_seed = [seed_summary({k: eps[k][m] for k in STATS}) for m in idx]
    row: dict[str, Any] = {
        "run": c.run_dir, "name": os.path.basename(os.path.normpath(c.run_dir)),
        "env": c.spec.env, "policy": c.spec.policy, "step": c.step,
        "iteration": c.iteration, "setup": setup, "seeds": list(c.seeds),
        "episodes": int(eps["return"].shape[1]), "horizon": sweep.horizons[setup],
        "per_seed": {k: [_num(p[k]) for p in per_seed] for k in _SEED_KEYS},
    }
    for k in _SEED_KEYS:
        v = np.array([p[k] for p in per_seed])
        row[k] = _num(np.mean(v))
        row[k + "_std"] = _num(np.std(v))
    if per_episode:
        row["per_episode"] = {k: eps[k][idx].tolist() for k in STATS}
    return row


def summarize_sweep(sweep: Sweep, per_episode: bool = False) -> list[dict[str, Any]]:
    """One row per (checkpoint, setup): per-seed statistics (:func:`seed_summary`) and their
    mean and standard deviation over training seeds (population std, 0 for one seed);
    ``per_episode`` adds the raw per-episode arrays."""
    return [_row(sweep, ci, s, per_episode)
            for ci in range(len(sweep.checkpoints)) for s in sweep.setups]


def best_row(rows: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """The row of the highest mean return (ties: success %), with ``best_seed`` (the training
    seed of the highest mean return in it) added; None if no row has a finite return."""
    finite = [r for r in rows if r["mean_return"] is not None]
    if not finite:
        return None
    best = dict(max(finite, key=lambda r: (r["mean_return"], r["success_pct"] or 0.0)))
    returns = [-math.inf if x is None else x for x in best["per_seed"]["mean_return"]]
    best["best_seed"] = best["seeds"][int(np.argmax(returns))]
    return best


def _group_entry(group: list[LoadedRun], sweep: Sweep) -> dict[str, Any]:
    return {"env": group[0].spec.env, "policy": group[0].spec.policy,
            "checkpoints": [{"run": c.run_dir, "step": c.step} for c in group],
            "setups": list(sweep.setups), "members": len(sweep.members),
            "horizons": sweep.horizons,
            "compile_seconds": sweep.compile_seconds, "run_seconds": sweep.run_seconds}


def evaluate(checkpoints: Sequence[LoadedRun], setups: Sequence[str] | None = None,
             num_episodes: int = 256, eval_seed: int = 0, horizon: int | None = None,
             per_episode: bool = False, stream: IO[str] | None = None) -> dict[str, Any]:
    """Group the checkpoints (:func:`agents.run.evaluation.group_checkpoints`), run one
    :func:`agents.run.evaluation.run_sweep` per group and return the JSON report: ``rows``
    (:func:`summarize_sweep`), ``groups`` (what each compiled call held, its compile and run
    seconds), totals, ``best`` and the evaluation settings. Setups are checked for every group
    before anything compiles."""
    groups = group_checkpoints(checkpoints)
    for g in groups:
        for s in (setups or (g[0].spec.env,)):
            setup_env(g[0], s)
    if len(groups) > 1 and stream is not None:
        print(f"{len(groups)} groups of different environments/policy kinds: one compiled call "
              "per group", file=stream)
    report: dict[str, Any] = {
        "episodes": num_episodes, "eval_seed": eval_seed, "horizon": horizon,
        "device": jax.devices()[0].platform, "groups": [], "rows": [],
    }
    for g in groups:
        sweep = run_sweep(g, setups, num_episodes, eval_seed, horizon)
        report["groups"].append(_group_entry(g, sweep))
        report["rows"].extend(summarize_sweep(sweep, per_episode))
        if stream is not None:
            print(f"group {g[0].spec.policy} on {g[0].spec.env}: {len(g)} checkpoint(s), "
                  f"{len(sweep.members)} parameter sets × {len(sweep.setups)} setup(s) × "
                  f"{num_episodes} episodes: compile {sweep.compile_seconds:.1f} s, run "
                  f"{sweep.run_seconds:.1f} s", file=stream)
    report["compile_seconds"] = sum(g["compile_seconds"] for g in report["groups"])
    report["run_seconds"] = sum(g["run_seconds"] for g in report["groups"])
    best = best_row(report["rows"])
    report["best"] = None if best is None else {k: best[k] for k in (
        "run", "step", "iteration", "setup", "mean_return", "success_pct", "best_seed")}
    return report


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """The screen table: run, iteration, setup, return mean ± std over seeds, success %, safe %,
    final goal distance (success/safe/distance: mean over seeds)."""
    def pm(r, k, spec):
        m, s = r[k], r[k + "_std"]
        return "n/a" if m is None else f"{m:{spec}} ± {s:.2g}"

    head = ("run", "iter", "setup", "seeds", "return (± std)", "success %", "safe %",
            "final dist")
    body = [(r["name"], str(r["iteration"]), r["setup"], str(len(r["seeds"])),
             pm(r, "mean_return", ".4g"), pm(r, "success_pct", ".1f"),
             pm(r, "safe_pct", ".1f"),
             "n/a" if r["mean_final_goal_distance"] is None
             else f"{r['mean_final_goal_distance']:.3f}") for r in rows]
    widths = [max(len(x) for x in col) for col in zip(head, *body, strict=True)]
    lines = ["  ".join(x.ljust(w) if i in (0, 2) else x.rjust(w)
                       for i, (x, w) in enumerate(zip(line, widths, strict=True)))
             for line in (head, *body)]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def render_gif(loaded: LoadedRun, seed: int, setup: str, path: str, eval_seed: int = 0,
               num_episodes: int = 256, horizon: int | None = None, every: int = 3,
               fps: int = 20) -> dict[str, Any]:
    """Write a GIF of episode 0 of the evaluation (same scene: key ``split(PRNGKey(eval_seed),
    num_episodes)[0]``) played by training seed ``seed`` of ``loaded`` on ``setup``, drawn with
    :func:`envs.render.save_gif`; returns the trajectory (:func:`envs.render.trajectory`)."""
    from envs.render import save_gif, trajectory  # lazy: optional dependency (matplotlib)

    env = setup_env(loaded, setup)
    steps = int(env.horizon if horizon is None else horizon)
    apply_fn, params = mean_action_fn(loaded), policy_params(loaded, loaded.seeds.index(seed))
    key = jax.random.split(jax.random.PRNGKey(eval_seed), num_episodes)[0]
    data = trajectory(env, env_policy(apply_fn, params), key, steps)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    save_gif(data, env.unwrapped.robot_name, path, every=every, fps=fps)
    return data


def evaluate_runs(runs: Sequence[str], steps: Sequence[str] = ("latest",),
                  setups: Sequence[str] | None = None, num_episodes: int = 256,
                  eval_seed: int = 0, horizon: int | None = None, per_episode: bool = False,
                  gif: str | None = None, stream: IO[str] | None = None) -> dict[str, Any]:
    """The report of :func:`evaluate` for checkpoints ``steps``
    (:func:`agents.run.evaluation.resolve_steps`) of every run directory in ``runs``; with
    ``gif``, episode 0 of the best row's best seed is rendered there (:func:`render_gif`) and
    described under the report's ``gif`` key (None otherwise)."""
    checkpoints = [load_run(r, step) for r in runs for step in resolve_steps(r, steps)]
    report = evaluate(checkpoints, setups, num_episodes, eval_seed, horizon, per_episode,
                      stream)
    report["gif"] = None
    if gif and report["best"] is not None:
        b = report["best"]
        loaded = next(c for c in checkpoints if c.run_dir == b["run"] and c.step == b["step"])
        data = render_gif(loaded, b["best_seed"], b["setup"], gif, eval_seed, num_episodes,
                          horizon)
        report["gif"] = {"path": gif, "run": b["run"], "step": b["step"],
                         "seed": b["best_seed"], "setup": b["setup"], "episode": 0,
                         "return": data["return"]}
    return report


__all__ = ["best_row", "evaluate", "evaluate_runs", "format_table", "render_gif",
           "seed_summary", "summarize_sweep"]
