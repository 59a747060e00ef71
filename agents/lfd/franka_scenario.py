"""The Franka evaluation scenario: its settings, the new starts, the cylinder obstacle and the
demonstrated corridor (thesis §5.3.2, Fig 5.7c; the protocol of :mod:`agents.lfd.franka_eval`).

* **Settings** (:class:`FrankaEvalConfig`): the flags of ``scripts/lfd_franka.py``;
  :func:`make_scenario` draws one task's starts and places its obstacles.
* **New starts** (:func:`perturbed_starts`): configurations drawn around a demonstration's start,
  ``N(0, std²)`` per joint, clipped 0.05 rad inside the joint limits.
* **Obstacle** (:func:`place_obstacle`): a vertical cylinder (infinite height) placed *across*
  the held-out demonstration's path: from the midpoint of its centre path, moved perpendicular
  to the path in the horizontal plane by the smallest offset at which the demonstrated motion
  (all 48 collision spheres) comes no closer than a target clearance to it — negative by default
  (−2 cm: replaying the demonstration would cut 2 cm into the cylinder, so the policy must
  deviate from it) — while the demonstration's start and goal configurations keep a free margin
  (5 cm; the task stays solvable). A new start closer than the margin to the cylinder is
  replaced, for the obstacle rollouts only, by a fresh draw from the same distribution that is
  not (:func:`clear_starts`; a rollout that begins in the cylinder cannot avoid it: when such
  starts were kept, 4 of 600 drawer starts of a 10-seed run began inside it). **Collisions are
  counted explicitly** (:func:`clearance`): the exact smallest distance between every collision
  sphere and the cylinder along every rollout; a rollout whose minimum is ≤ 0 collides.
* **Corridor** (:func:`corridor_excursions`): the thesis counts a rollout as successful "if all
  the goals of the task are met without any collisions" in *constrained* tasks (the door task
  starts inside a cabinet and must go around its door), where "even small errors can result in
  task execution failures" (§5.3.2). The demonstrations are recorded but not the cabinet, door
  or drawer geometry, so the corridor the demonstrations went through stands in for it. The
  distance at time ``t`` is the largest over the three control points of the exact distance to
  the nearest training path of the same point
  (:func:`mjxrmp.metrics.trajectory.distance_to_paths`); the *excursion* is its maximum over
  the rollout minus its value at the start (a held-out human demonstration has 0–0.3 cm: the
  demonstrations fan in from their starts). It is a stand-in for the unmodelled scene, not the
  thesis's own protocol.
* **Restarts** (:func:`kept_restarts`): of several models trained per fold, the first whose
  largest miss from the fold's own training starts is within the success radius is kept, else
  the closest.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from agents.lfd.config import STRATEGIES, StrategyConfig
from mjxrmp.config import check_choice, check_float, check_int
from mjxrmp.data import franka_demos
from mjxrmp.geometry import make_obstacles, point_obstacle_distances
from mjxrmp.metrics import trajectory as traj_metrics
from mjxrmp.robots import franka

__all__ = [
    "FrankaEvalConfig",
    "Scenario",
    "clear_starts",
    "clearance",
    "corridor_excursions",
    "hand_points_batch",
    "kept_restarts",
    "make_scenario",
    "perturbed_starts",
    "place_obstacle",
]


_cps = jax.jit(jax.vmap(franka.control_points))
#: The three hand control points of a batch of configurations ``(B, 7) -> (B, 3, 3)``, jitted.
hand_points_batch = jax.jit(jax.vmap(franka_demos.hand_points))
#: Radii of the Franka's collision spheres.
RADII = np.asarray(franka.CONTROL_POINT_RADII, np.float32)


def clearance(qs: np.ndarray, center_xy: np.ndarray, radius: float) -> np.ndarray:
    """Exact smallest distance between the 48 collision points and a vertical cylinder, per
    configuration of ``qs (T, 7)``."""
    obs = make_obstacles(jnp.asarray([[*center_xy, 0.0]], jnp.float32),
                         jnp.asarray([radius], jnp.float32))
    d = jax.vmap(lambda p: point_obstacle_distances(p, jnp.asarray(RADII), obs, "cylinder",
                                                    smooth=False))(_cps(jnp.asarray(qs)))
    return np.asarray(jnp.min(d, axis=(1, 2)))


def place_obstacle(demo: franka_demos.FrankaDemo, radius: float, target: float,
                   free_margin: float) -> np.ndarray:
    """Cylinder centre ``(3,)`` across or beside the demonstration's centre path (module
    docstring): from the path's midpoint, moved perpendicular to it in the horizontal plane by
    the smallest offset (1 cm grid, either side) at which the demonstrated motion's smallest
    clearance is at least ``target`` (negative: it would cut that deep into the cylinder) while
    its first and last configurations keep ``free_margin``."""
    path = demo.points[:, 0, :2]
    mid = len(path) // 2
    tangent = path[min(mid + 1, len(path) - 1)] - path[max(mid - 1, 0)]
    tangent = tangent / max(np.linalg.norm(tangent), 1e-9)
    normal = np.array([-tangent[1], tangent[0]])
    ends = demo.q[[0, -1]]
    for offset in np.linspace(0.0, 0.6, 61):
        for sign in (1.0, -1.0):
            c = path[mid] + sign * offset * normal
            if clearance(demo.q, c, radius).min() >= target \
                    and clearance(ends, c, radius).min() >= free_margin:
                return np.array([c[0], c[1], 0.0])
    raise RuntimeError(f"no obstacle position within 0.6 m of {demo.source}'s path")


def corridor_excursions(points: np.ndarray, paths: list[np.ndarray]) -> np.ndarray:
    """Excursion of each rollout from the demonstrated corridor (module docstring): ``points
    (B, T, 3, 3)`` control points of ``B`` rollouts, ``paths`` the training demonstrations'
    ``(S_i, 3, 3)`` control points; returns ``max_t d_t − d_0`` per rollout, ``d_t`` the largest
    over the three points of the distance to that point's nearest training path."""
    out = []
    for rollout in points:
        d = np.max([traj_metrics.distance_to_paths(rollout[:, c], [p[:, c] for p in paths])
                    for c in range(rollout.shape[1])], axis=0)
        out.append(d.max() - d[0])
    return np.asarray(out)


def perturbed_starts(key: jax.Array, q0: np.ndarray, num: int, std: float) -> np.ndarray:
    """``num`` starts ``q0 + N(0, std²)`` clipped inside the buffered joint limits."""
    lo = np.asarray(franka.Q_LOWER) + 0.05
    hi = np.asarray(franka.Q_UPPER) - 0.05
    noise = std * np.asarray(jax.random.normal(key, (num, q0.shape[0])))
    return np.clip(q0[None] + noise, lo, hi).astype(np.float32)


def clear_starts(key: jax.Array, q0: np.ndarray, starts: np.ndarray, std: float,
                 center: np.ndarray, radius: float, margin: float,
                 max_rounds: int = 100) -> np.ndarray:
    """``starts (R, 7)`` with every one closer than ``margin`` to the cylinder at ``center``
    replaced by a fresh :func:`perturbed_starts` draw around ``q0`` that keeps ``margin`` (rounds
    of ``R`` candidates from ``key``; raises if ``max_rounds`` rounds do not suffice)."""
    out = np.array(starts, copy=True)
    bad = np.flatnonzero(clearance(out, center[:2], radius) < margin)
    for r in range(max_rounds):
        if bad.size == 0:
            return out
        cand = perturbed_starts(jax.random.fold_in(key, r), q0, len(out), std)
        cand = cand[clearance(cand, center[:2], radius) >= margin][:bad.size]
        out[bad[:len(cand)]] = cand
        bad = bad[len(cand):]
    if bad.size:
        raise RuntimeError(f"no start {margin} m clear of the cylinder at {center[:2]} in "
                           f"{max_rounds} rounds of {len(out)} draws around the held-out start")
    return out


def kept_restarts(misses: np.ndarray, radius: float) -> np.ndarray:
    """Per fold, the restart kept from ``misses (F, K)`` (each model's largest distance to the
    goals from its fold's training starts): the first within ``radius``, else the smallest."""
    ok = misses <= radius
    return np.where(ok.any(axis=1), np.argmax(ok, axis=1), np.argmin(misses, axis=1))


@dataclasses.dataclass(frozen=True)
class FrankaEvalConfig:
    """Settings of the Franka comparison (:mod:`agents.lfd.franka_eval`; the flags of
    ``scripts/lfd_franka.py`` of the same names).

    Data: ``tasks``, ``root``, resampling step ``dt`` (s). Models: ``strategies``, the
    :meth:`agents.lfd.config.StrategyConfig.preset` ``preset`` with optional
    ``flow_iterations`` / ``metric_iterations``, ``restarts`` models per fold, ``seed``.
    Evaluation: ``folds`` (hold out only the first N demonstrations; ``None``: all),
    ``num_starts`` new starts of ``perturbation`` rad per joint, rollouts of ``exec_dt`` with
    ``substeps`` Euler sub-steps lasting ``horizon_factor`` longest-demonstration durations, goal
    tolerance ``success_radius``, cylinder ``obstacle_radius`` at demonstrated clearance
    ``obstacle_clearance`` (negative: penetration; below ``free_margin``) keeping ``free_margin``
    at the demonstration's ends and every obstacle start, ``corridor_tolerance`` and the
    execution-time ``posture_weight`` (0: off).
    """

    tasks: tuple[str, ...] = franka_demos.TASKS
    strategies: tuple[str, ...] = STRATEGIES
    preset: str = "cpu"
    flow_iterations: int | None = None
    metric_iterations: int | None = None
    dt: float = 0.1
    exec_dt: float = 0.05
    folds: int | None = None
    num_starts: int = 10
    perturbation: float = 0.1
    horizon_factor: float = 1.5
    success_radius: float = 0.02
    obstacle_radius: float = 0.05
    obstacle_clearance: float = -0.02
    free_margin: float = 0.05
    corridor_tolerance: float = 0.05
    posture_weight: float = 1.0
    substeps: int = 4
    seed: int = 0
    restarts: int = 3
    root: str = franka_demos.DEFAULT_ROOT

    def __post_init__(self) -> None:
        n = "FrankaEvalConfig."
        for name, choices in (("tasks", franka_demos.TASKS), ("strategies", STRATEGIES)):
            object.__setattr__(self, name, tuple(getattr(self, name)))
            for value in getattr(self, name):
                check_choice(value, n + name, choices)
        check_choice(self.preset, n + "preset", ("cpu", "thesis", "reference", "tiny"))
        for name, minimum in (("flow_iterations", 1), ("metric_iterations", 0), ("folds", 1)):
            if getattr(self, name) is not None:
                check_int(getattr(self, name), n + name, minimum)
        for name in ("dt", "exec_dt", "perturbation", "horizon_factor", "success_radius",
                     "obstacle_radius", "free_margin", "corridor_tolerance"):
            check_float(getattr(self, name), n + name)
        c = self.obstacle_clearance
        if not (isinstance(c, int | float) and math.isfinite(c) and c < self.free_margin):
            raise ValueError(f"{n}obstacle_clearance must be finite and < free_margin "
                             f"({self.free_margin}), got {c!r}")
        check_float(self.posture_weight, n + "posture_weight", allow_zero=True)
        for name in ("num_starts", "substeps", "restarts"):
            check_int(getattr(self, name), n + name)
        check_int(self.seed, n + "seed", -(2**31))

    def strategy_config(self, strategy: str) -> StrategyConfig:
        """The :class:`agents.lfd.config.StrategyConfig` of ``strategy`` under these settings."""
        overrides = {k: getattr(self, k) for k in ("flow_iterations", "metric_iterations")
                     if getattr(self, k) is not None}
        return StrategyConfig.preset(self.preset, strategy, **overrides)


class Scenario(NamedTuple):
    """One task's evaluation scenario: the held-out ``folds``, the new ``starts (F, R, 7)``,
    the ``obstacle_starts (F, R, 7)`` (those within the free margin of the cylinder redrawn),
    the cylinder ``centers (F, 3)`` and the rollout ``horizon`` (control steps)."""

    folds: list[int]
    starts: np.ndarray
    obstacle_starts: np.ndarray
    centers: np.ndarray
    horizon: int


def make_scenario(config: FrankaEvalConfig, task_index: int,
                  demos: list[franka_demos.FrankaDemo]) -> Scenario:
    """The :class:`Scenario` of task number ``task_index`` (module docstring): starts drawn from
    ``fold_in(PRNGKey(seed + 1), task_index)``, one cylinder per held-out demonstration."""
    N = len(demos)
    folds = list(range(N if config.folds is None else min(config.folds, N)))
    key = jax.random.fold_in(jax.random.PRNGKey(config.seed + 1), task_index)
    starts = np.stack([perturbed_starts(jax.random.fold_in(key, f), demos[f].q[0],
                                        config.num_starts, config.perturbation) for f in folds])
    centers = np.stack([place_obstacle(demos[f], config.obstacle_radius,
                                       config.obstacle_clearance, config.free_margin)
                        for f in folds])
    obstacle_starts = np.stack([
        clear_starts(jax.random.fold_in(key, N + f), demos[f].q[0], starts[i],
                     config.perturbation, centers[i], config.obstacle_radius, config.free_margin)
        for i, f in enumerate(folds)])
    longest = max(d.length for d in demos)
    horizon = math.ceil(config.horizon_factor * (longest - 1) * config.dt / config.exec_dt)
    return Scenario(folds, starts, obstacle_starts, centers, horizon)
