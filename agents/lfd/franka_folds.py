"""One strategy on one Franka task: train every leave-one-out fold (with restarts), roll out,
score (thesis §5.3.2, Fig 5.7; the protocol of :mod:`agents.lfd.franka_eval`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from agents.lfd import execution, strategies, two_step
from agents.lfd.config import ExecutionParams, NominalSettings, StrategyConfig
from agents.lfd.franka_scenario import (
    FrankaEvalConfig,
    Scenario,
    clearance,
    corridor_excursions,
    hand_points_batch,
    kept_restarts,
)
from agents.lfd.policy import StrategyResult
from agents.lfd.samples import fold_weights, make_samples
from mjxrmp.data import franka_demos
from mjxrmp.geometry import make_obstacles
from mjxrmp.metrics import trajectory as traj_metrics
from mjxrmp.robots import franka

__all__ = ["evaluate_strategy", "fold_metrics", "train_restarts"]

Rollout = Callable[..., jax.Array]


def train_restarts(config: FrankaEvalConfig, cfg: StrategyConfig,
                   stacked: franka_demos.StackedDemos, folds: list[int]
                   ) -> tuple[StrategyResult, two_step.NominalFit | None, float]:
    """Train ``config.restarts`` models per fold in one program: restart 0 of fold ``f`` has the
    key ``fold_in(PRNGKey(seed), f)``, restart ``k > 0`` folds ``k`` into it. Returns the
    results stacked fold-major ``(F·K, …)``, the two-step nominal fits (else ``None``) and the
    training time (s)."""
    N, K = stacked.mask.shape[0], config.restarts
    samples = make_samples(cfg, stacked)
    train_sets = jnp.asarray([[j != f for j in range(N)] for f in folds])
    base = [jax.random.fold_in(jax.random.PRNGKey(config.seed), f) for f in folds]
    keys = jnp.stack([b if k == 0 else jax.random.fold_in(b, k) for b in base for k in range(K)])
    t0 = time.time()
    nominal = None
    if cfg.strategy == "two_step":
        result, nominal = two_step.train_folds(cfg, stacked, samples,
                                               jnp.repeat(train_sets, K, axis=0), keys)
    else:
        weights = jax.vmap(lambda tr: fold_weights(stacked.mask, tr))(train_sets)
        result = strategies.fold_trainer(cfg)(keys, samples, jnp.repeat(weights, K, axis=0))
    result = jax.block_until_ready(result)
    return result, nominal, time.time() - t0


def _rollout_fn(config: FrankaEvalConfig, cfg: StrategyConfig, horizon: int) -> Rollout:
    """``one(result, q0, goals, q_goal, q_posture, center, active, posture_weight) -> qs``: an
    execution rollout (:func:`agents.lfd.execution.rollout`) with the cylinder switched by
    ``active``."""
    hand_cfg = execution.execution_config()
    params = ExecutionParams(posture_weight=config.posture_weight, substeps=config.substeps)

    def one(res, q0_, g, qg, qp, center, act, wp):
        obs = make_obstacles(center[None], jnp.asarray([config.obstacle_radius], jnp.float32),
                             act[None])
        return execution.rollout(cfg, res, q0_, g, qg, horizon, config.exec_dt, obs, hand_cfg,
                                 params, qp, wp)[0]

    return one


def restart_misses(config: FrankaEvalConfig, one: Rollout, result: StrategyResult,
                   stacked: franka_demos.StackedDemos, folds: list[int], q_posture: np.ndarray
                   ) -> np.ndarray:
    """``(F, K)``: each model's largest distance to the goals (over starts and control points)
    when rolled out from its fold's *training* demonstrations' starts to their own goals
    (posture leaf on, no obstacle); ``inf`` where not finite."""
    N, K, F = stacked.mask.shape[0], config.restarts, len(folds)
    train_idx = np.array([[j for j in range(N) if j != f] for f in folds])     # (F, N-1)
    rep = lambda a: np.repeat(np.asarray(a)[train_idx], K, axis=0)  # noqa: E731
    train_goals = rep(stacked.goals)                                       # (F·K, N-1, 3, 3)
    check = jax.jit(jax.vmap(jax.vmap(one, in_axes=(None, 0, 0, 0, None, None, None, None)),
                             in_axes=(0, 0, 0, 0, 0, None, None, None)))
    ends = check(result, jnp.asarray(rep(stacked.q)[:, :, 0]), jnp.asarray(train_goals),
                 jnp.asarray(rep(stacked.q_goal)), jnp.asarray(np.repeat(q_posture, K, axis=0)),
                 jnp.zeros((3,), jnp.float32), jnp.float32(0.0),
                 jnp.float32(config.posture_weight))[:, :, -1]                # (F·K, N-1, 7)
    hand = np.asarray(hand_points_batch(ends.reshape(-1, 7))).reshape(train_goals.shape)
    miss = np.linalg.norm(hand - train_goals, axis=-1).max(axis=(1, 2))
    return np.nan_to_num(miss, nan=np.inf).reshape(F, K)


def evaluation_rollouts(config: FrankaEvalConfig, one: Rollout, result: StrategyResult,
                        stacked: franka_demos.StackedDemos, scenario: Scenario,
                        q_posture: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Per fold ``B = 1 + 3R`` rollouts: [held-out start, starts…, obstacle starts with the
    obstacle, starts… without the posture leaf (ablation)]. Returns ``qs (F, B, H+1, 7)``, the
    control points ``(F, B, H+1, 3, 3)`` and the rollout time (s)."""
    fold_idx = np.asarray(scenario.folds)
    F, R = scenario.starts.shape[:2]
    q0 = np.concatenate([stacked.q[fold_idx, 0][:, None], scenario.starts,
                         scenario.obstacle_starts, scenario.starts], axis=1)
    active = np.concatenate([np.zeros((F, 1 + R)), np.ones((F, R)), np.zeros((F, R))], axis=1)
    w_post = np.where(np.arange(1 + 3 * R) < 1 + 2 * R, config.posture_weight, 0.0)
    roll = jax.jit(jax.vmap(jax.vmap(one, in_axes=(None, 0, None, None, None, None, 0, 0)),
                            in_axes=(0, 0, 0, 0, 0, 0, 0, None)))
    t0 = time.time()
    qs = np.asarray(roll(result, jnp.asarray(q0), jnp.asarray(np.asarray(stacked.goals)[fold_idx]),
                         jnp.asarray(np.asarray(stacked.q_goal)[fold_idx]),
                         jnp.asarray(q_posture), jnp.asarray(scenario.centers, jnp.float32),
                         jnp.asarray(active, jnp.float32), jnp.asarray(w_post, jnp.float32)))
    roll_s = time.time() - t0
    B, H1 = qs.shape[1], qs.shape[2]
    pts = np.asarray(hand_points_batch(jnp.asarray(qs.reshape(-1, 7)))).reshape(F, B, H1, 3, 3)
    return qs, pts, roll_s


def fold_metrics(config: FrankaEvalConfig, demos: list[franka_demos.FrankaDemo], f: int,
                 qs: np.ndarray, pts: np.ndarray, goals: np.ndarray, center: np.ndarray
                 ) -> tuple[dict, np.ndarray]:
    """Scores of held-out fold ``f`` from its rollouts ``qs (B, H+1, 7)`` and control points
    ``pts (B, H+1, 3, 3)`` (:func:`evaluation_rollouts`' order) towards ``goals (3, 3)`` with the
    cylinder at ``center``: reproduction error (the held-out start, for the demonstration's
    duration, :func:`mjxrmp.metrics.trajectory.mean_error` per control point), successes, task
    successes (corridor), collisions and clearances. Returns the fold's record and the
    reproduction ``(n, 3, 3)``."""
    R = (qs.shape[0] - 1) // 3
    demo = demos[f]
    n = round((demo.length - 1) * config.dt / config.exec_dt) + 1
    rep = pts[0, :n]
    errors = [traj_metrics.mean_error(rep[:, k], demo.points[:, k]) for k in range(3)]
    finite = np.all(np.isfinite(qs), axis=(1, 2))
    within = np.all((qs >= np.asarray(franka.Q_LOWER)) & (qs <= np.asarray(franka.Q_UPPER)),
                    axis=(1, 2))
    reached = np.all(np.linalg.norm(pts[:, -1] - goals[None], axis=-1) <= config.success_radius,
                     axis=-1)
    ok = finite & within & reached
    min_clear = np.array([clearance(np.nan_to_num(qs[b]), center[:2],
                                    config.obstacle_radius).min() for b in range(1 + R, 1 + 2 * R)])
    free = min_clear > 0
    excursions = corridor_excursions(np.nan_to_num(pts[1:1 + R], nan=1e3),
                                     [d.points for j, d in enumerate(demos) if j != f])
    in_corridor = excursions <= config.corridor_tolerance
    return {
        "held_out": int(f),
        "mean_position_error": float(np.mean(errors)),
        "mean_position_error_per_point": [float(e) for e in errors],
        "final_error_held_out_start": float(np.max(np.linalg.norm(pts[0, -1] - goals, axis=-1))),
        "success": int(ok[1:1 + R].sum()),
        "task_success": int((ok[1:1 + R] & in_corridor).sum()),
        "corridor_excursions": [float(e) for e in excursions],
        "success_obstacle": int((ok[1 + R:1 + 2 * R] & free).sum()),
        "success_no_posture": int(ok[1 + 2 * R:].sum()),
        "collisions_obstacle": int((~free).sum()),
        "min_clearance_obstacle": float(min_clear.min()),
        "demo_clearance_obstacle": float(clearance(demo.q, center[:2],
                                                   config.obstacle_radius).min()),
        "joint_limit_violations": int((~within).sum()),
        "non_finite": int((~finite).sum()),
        "obstacle_center": [float(v) for v in center],
    }, rep


def _summary(config: FrankaEvalConfig, cfg: StrategyConfig, result: StrategyResult,
             per_fold: list[dict], seconds: tuple[float, float]) -> dict[str, Any]:
    """The strategy's record: settings, times, final losses and the folds' scores pooled."""
    F, R = len(per_fold), len(per_fold[0]["corridor_excursions"])
    errs = np.array([p["mean_position_error"] for p in per_fold])
    total = lambda key: sum(p[key] for p in per_fold)  # noqa: E731
    return {
        "config": {k: (list(v) if isinstance(v, tuple) else v)
                   for k, v in dataclasses.asdict(cfg).items()},
        "train_seconds": seconds[0],
        "rollout_seconds": seconds[1],
        "final_flow_loss": float(np.asarray(result.flow_losses[:, -1]).mean()),
        "final_metric_loss": (float(np.asarray(result.metric_losses[:, -1]).mean())
                              if cfg.metric_iterations else None),
        "mean_position_error": float(errs.mean()),
        "mean_position_error_std": float(errs.std()),
        "success_rate": total("success") / (F * R),
        "task_success_rate": total("task_success") / (F * R),
        "corridor_tolerance": config.corridor_tolerance,
        "median_corridor_excursion": float(np.median(
            [e for p in per_fold for e in p["corridor_excursions"]])),
        "success_rate_obstacle": total("success_obstacle") / (F * R),
        "success_rate_no_posture": total("success_no_posture") / (F * R),
        "colliding_rollouts": total("collisions_obstacle"),
        "obstacle_rollouts": F * R,
        "min_clearance_obstacle": min(p["min_clearance_obstacle"] for p in per_fold),
        "joint_limit_violations": total("joint_limit_violations"),
        "folds": per_fold,
    }


def _summary_line(out: dict) -> str:
    F_R = out["obstacle_rollouts"]
    return (f"    error {out['mean_position_error'] * 100:.2f} ± "
            f"{out['mean_position_error_std'] * 100:.2f} cm, success {out['success_rate']:.0%}, "
            f"task success (corridor) {out['task_success_rate']:.0%} (median excursion "
            f"{out['median_corridor_excursion'] * 100:.1f} cm), "
            f"with obstacle {out['success_rate_obstacle']:.0%}, without the posture leaf "
            f"{out['success_rate_no_posture']:.0%}, colliding "
            f"{out['colliding_rollouts']}/{F_R} (min clearance "
            f"{out['min_clearance_obstacle'] * 100:.1f} cm), joint-limit violations "
            f"{out['joint_limit_violations']} (rollouts {out['rollout_seconds']:.1f} s)")


def evaluate_strategy(config: FrankaEvalConfig, cfg: StrategyConfig,
                      stacked: franka_demos.StackedDemos, demos: list[franka_demos.FrankaDemo],
                      scenario: Scenario, log: Callable[[str], None] = print,
                      on_kept: Callable[[StrategyResult, np.ndarray], Any] | None = None
                      ) -> tuple[dict, list[np.ndarray]]:
    """Train every fold of ``scenario`` (:func:`train_restarts`, the restart kept by
    :func:`agents.lfd.franka_scenario.kept_restarts`), roll out and score; returns the
    strategy's record (``metrics.json``) and the held-out reproductions per fold.
    ``on_kept(result, q_posture)`` receives the kept models stacked over the folds and their
    execution postures (e.g. to save them: :func:`agents.lfd.skills.save_franka_skills`)."""
    folds, K = scenario.folds, config.restarts
    F, N = len(folds), len(demos)
    result, nominal, train_s = train_restarts(config, cfg, stacked, folds)
    # posture of the execution-time default leaf: mean final configuration of the training demos
    q_posture = np.stack([np.mean([demos[j].q[-1] for j in range(N) if j != f], axis=0)
                          for f in folds]).astype(np.float32)
    one = _rollout_fn(config, cfg, scenario.horizon)
    restart_errors = (restart_misses(config, one, result, stacked, folds, q_posture) if K > 1
                      else np.zeros((F, K)))
    choice = kept_restarts(restart_errors, config.success_radius)
    pick = lambda a: a.reshape(F, K, *a.shape[1:])[np.arange(F), choice]  # noqa: E731
    result = jax.tree.map(pick, result)
    if on_kept is not None:
        on_kept(result, q_posture)
    log(f"    trained {F} folds × {K} restarts in {train_s:.1f} s; final losses flow "
        f"{np.asarray(result.flow_losses[:, -1]).mean():.4g}"
        + (f", metric {np.asarray(result.metric_losses[:, -1]).mean():.4g}"
           if cfg.metric_iterations else "")
        + (f"; kept restarts {choice.tolist()} (largest miss from the training starts, cm: "
           f"{[f'{e * 100:.1f}' for e in restart_errors[np.arange(F), choice]]})"
           if K > 1 else ""))
    qs, pts, roll_s = evaluation_rollouts(config, one, result, stacked, scenario, q_posture)
    goals = np.asarray(stacked.goals)[np.asarray(folds)]
    per_fold, reproductions = [], []
    for i, f in enumerate(folds):
        record, rep = fold_metrics(config, demos, f, qs[i], pts[i], goals[i],
                                   scenario.centers[i])
        record.update(restart=int(choice[i]), restart_errors=[float(e) for e in
                                                               restart_errors[i]])
        per_fold.append(record)
        reproductions.append(rep)
    out = _summary(config, cfg, result, per_fold, (train_s, roll_s))
    if nominal is not None:
        out["nominal_settings"] = dataclasses.asdict(NominalSettings())
        for p, idx in zip(per_fold, np.asarray(jax.tree.map(pick, nominal).index), strict=True):
            p["nominal_per_point"] = [int(i) for i in idx]
    log(_summary_line(out))
    return out, reproductions
