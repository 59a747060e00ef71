"""2-D point robot (double integrator) with a goal and circular obstacles — pure JAX, no MJX.

For RMP²-CLF studies (thesis §3.2.6–3.2.7) and fast learner tests. brax ``Env`` API; the
``pipeline_state`` is a :class:`PointState` ``(x, xd)``.

* dynamics: semi-implicit Euler, ``ẋ ← ẋ + a·dt``, ``x ← x + ẋ·dt`` (``dt = 0.01`` s), action =
  acceleration (NaNs → 0) clipped to ``±action_limit`` per axis (default 1);
* reset: start and goal uniform in ``[−1, 1]²`` at least ``min_goal_distance`` (0.5) apart;
  ``num_obstacles`` circles with centres uniform in ``[−1, 1]²`` and radius
  U[0.1, 0.2]; clearance ≥ 0.1 between each circle and both start and goal (bounded rejection);
* reward :func:`envs.base.reach_reward` with the acceleration as the effort
  (``exp(−½‖x−g‖²/σ²) − Σ_i max(0, 1 − d_i/δ) − λ‖a‖²`` clipped to [−5, 1], σ 0.1, δ 0.05,
  λ 1e-5); done on collision (``d_i < 0``, point radius 0) or a non-finite state;
* ``step`` keeps any metric a wrapper added (brax's ``EvalWrapper`` adds ``reward``); all state
  lives in ``pipeline_state`` or stays fixed within an episode (goal, obstacles), so brax's own
  ``AutoResetWrapper`` restarts an episode correctly (the accumulators restart as
  :func:`envs.base.accumulate_episode` describes);
* observation ``[x, ẋ, g − x, {v_i}, {o_i}]`` (``v_i`` from the circle's surface to the point,
  ``o_i`` = centre and radius): ``6 + 5·num_obstacles`` entries.

Build it with ``envs.make("point2d", num_obstacles=...)``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State

from envs.base import (
    RewardParams,
    accumulate_episode,
    check_action,
    clean_action,
    episode_info,
    layout,
    reach_reward,
    sample_first_valid,
)
from mjxrmp.config import check_float, check_int
from mjxrmp.geometry import Obstacles
from mjxrmp.leaves.hand_designed import safe_norm

__all__ = ["PointRobot2D", "PointState"]


class PointState(NamedTuple):
    """Position and velocity of the point robot."""

    x: jax.Array
    xd: jax.Array


class PointRobot2D(Env):
    """Double-integrator point robot reaching a goal among circles (see module docstring)."""

    def __init__(
        self,
        num_obstacles: int = 1,
        *,
        dt: float = 0.01,
        horizon: int = 600,
        action_limit: float = 1.0,
        obstacle_radius_range: tuple[float, float] = (0.1, 0.2),
        clearance: float = 0.1,
        min_goal_distance: float = 0.5,
        success_radius: float = 0.05,
        candidates: int = 32,
    ):
        self.num_obstacles = check_int(num_obstacles, "PointRobot2D.num_obstacles")
        self.dt = check_float(dt, "PointRobot2D.dt")
        self.horizon = check_int(horizon, "PointRobot2D.horizon")
        self.action_limit = check_float(action_limit, "PointRobot2D.action_limit")
        self.obstacle_radius_range = obstacle_radius_range
        self.clearance = clearance
        self.min_goal_distance = min_goal_distance
        self.success_radius = success_radius
        self.candidates = check_int(candidates, "PointRobot2D.candidates")
        self.reward_params = RewardParams()

    @property
    def observation_size(self) -> int:
        """``6 + 5·num_obstacles`` (:meth:`observation_layout`)."""
        return 6 + 5 * self.num_obstacles

    @property
    def action_size(self) -> int:
        """A 2-D acceleration."""
        return 2

    @property
    def backend(self) -> str:
        """``"jax"`` (no physics engine)."""
        return "jax"

    def observation_layout(self) -> dict[str, slice]:
        """Named slices: ``x``, ``xd``, ``goal_minus_x``, ``obstacle_vectors``, ``obstacles``."""
        n = self.num_obstacles
        return layout([("x", 2), ("xd", 2), ("goal_minus_x", 2), ("obstacle_vectors", 2 * n),
                       ("obstacles", 3 * n)])

    def distances(self, x: jax.Array, obstacles: Obstacles) -> jax.Array:
        """Exact distances ``(O,)`` from the point to each circle's surface."""
        return safe_norm(x[None, :] - obstacles.center) - obstacles.radius

    def _candidate(self, key: jax.Array):
        k_s, k_g, k_c, k_r = jax.random.split(key, 4)
        n = self.num_obstacles
        start = jax.random.uniform(k_s, (2,), minval=-1.0, maxval=1.0)
        goal = jax.random.uniform(k_g, (2,), minval=-1.0, maxval=1.0)
        centers = jax.random.uniform(k_c, (n, 2), minval=-1.0, maxval=1.0)
        lo, hi = self.obstacle_radius_range
        radius = jax.random.uniform(k_r, (n,), minval=lo, maxval=hi)
        obstacles = Obstacles(centers, radius, jnp.ones((n,), jnp.float32))
        margin = jnp.minimum(
            jnp.min(self.distances(start, obstacles)), jnp.min(self.distances(goal, obstacles))
        ) - self.clearance
        margin = jnp.minimum(margin, safe_norm(goal - start) - self.min_goal_distance)
        return (start, goal, obstacles), margin

    def sample_scene(self, key: jax.Array):
        """``(start, goal, obstacles, ok)`` by bounded rejection."""
        (start, goal, obstacles), ok = sample_first_valid(key, self.candidates, self._candidate)
        return start, goal, obstacles, ok

    def observe(self, x, xd, goal, obstacles: Obstacles) -> jax.Array:
        """The observation vector (layout: :meth:`observation_layout`)."""
        diff = x[None, :] - obstacles.center
        norm = safe_norm(diff)
        d = norm - obstacles.radius
        v = d[:, None] * diff / jnp.maximum(norm, 1e-9)[:, None]
        o = jnp.concatenate([obstacles.center, obstacles.radius[:, None]], axis=1)
        obs = jnp.concatenate([x, xd, goal - x, v.reshape(-1), o.reshape(-1)])
        return jnp.where(jnp.isfinite(obs), obs, 0.0)

    def _goal_metrics(self, x: jax.Array, goal: jax.Array) -> dict[str, jax.Array]:
        dist = safe_norm(goal - x)
        return {"goal_distance": dist, "success": (dist < self.success_radius).astype(jnp.float32)}

    def reset(self, rng: jax.Array) -> State:
        """A new episode at rest at the sampled start."""
        k_scene, k_next = jax.random.split(rng)
        start, goal, obstacles, ok = self.sample_scene(k_scene)
        xd = jnp.zeros(2, jnp.float32)
        z = jnp.zeros((), jnp.float32)
        metrics = {**self._goal_metrics(start, goal), "collision": z, "nonfinite": z}
        info = {"rng": k_next, "goal": goal, "obstacles": obstacles,
                "sampler_ok": ok.astype(jnp.float32), **episode_info(track_nonfinite=False)}
        obs = self.observe(start, xd, goal, obstacles)
        return State(PointState(start, xd), obs, z, z, metrics, info)

    def step(self, state: State, action: jax.Array) -> State:
        """One semi-implicit Euler step of the double integrator."""
        check_action(action, self.action_size)
        goal, obstacles = state.info["goal"], state.info["obstacles"]
        a = clean_action(action, self.action_limit)
        xd = state.pipeline_state.xd + a * self.dt
        x = state.pipeline_state.x + xd * self.dt
        d = self.distances(x, obstacles)
        metrics = {**state.metrics, **self._goal_metrics(x, goal)}  # keeps wrappers' metrics
        reward = reach_reward(metrics["goal_distance"], d, obstacles.active > 0, a,
                              self.reward_params)
        finite = jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(xd))
        collided = jnp.any(d < 0.0)
        reward = jnp.where(finite, reward, self.reward_params.reward_min)
        metrics.update(collision=collided.astype(jnp.float32),
                       nonfinite=(~finite).astype(jnp.float32))
        info = accumulate_episode(state.info, reward, metrics["collision"], metrics["nonfinite"])
        return state.replace(
            pipeline_state=PointState(x, xd),
            obs=self.observe(x, xd, goal, obstacles),
            reward=reward,
            done=(collided | ~finite).astype(jnp.float32),
            metrics=metrics,
            info=info,
        )
