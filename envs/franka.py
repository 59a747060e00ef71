"""Franka Panda reaching (thesis §6.3, docs/design.md §4.3): :class:`FrankaReach`."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from envs.reaching import ReachEnv
from envs.samplers import half_torus_volume_uniform
from mjxrmp.geometry import Obstacles
from mjxrmp.leaves.hand_designed import safe_norm
from mjxrmp.robots.mjcf import FRANKA_ARMATURE, franka_mjcf

#: Servo gains (see :data:`envs.three_link.THREE_LINK_KP` for the choice): a velocity bias of
#: ``kp·dt/kv`` and tracking errors below 0.01 rad/s with the hand-designed policy.
FRANKA_KP = 1000.0
FRANKA_KV = 300.0

__all__ = ["FRANKA_KP", "FRANKA_KV", "FrankaReach"]


class FrankaReach(ReachEnv):
    """Franka Panda reaching (thesis §6.3): 3 ball obstacles and the goal volume-uniform in the
    front half of the solid torus around the z-axis (major 0.5, minor 0.3, centre height 0.5,
    azimuth |φ| ≤ π/2, i.e. x > 0); ball radius U[0.05, 0.10]; goal ≥ 0.5 m from the initial end
    effector; clearance ≥ 0.1 between goal and balls and between the initial robot (48 control
    points) and the balls; initial ``q = default_q + U(±0.1)``, ``q̇ ~ U(±0.005)``. Observation
    size 45 (54 for the residual-RMP variant). A scene candidate is valid with probability ≈ 0.2,
    so 64 candidates are drawn per reset (failure probability ≈ 1e-6, flagged in
    ``info["sampler_ok"]``). Build it with ``envs.make("franka", ...)``."""

    robot_name = "franka"
    obstacle_shape = "sphere"

    def __init__(
        self,
        *,
        kp: float = FRANKA_KP,
        kv: float = FRANKA_KV,
        armature: float = FRANKA_ARMATURE,
        num_obstacles: int = 3,
        min_goal_distance: float = 0.5,
        candidates: int = 64,
        **kwargs,
    ):
        self.torus = (0.5, 0.3, 0.5, 0.0, math.pi)  # major, minor, height, angle centre/range
        self.obstacle_radius_range = (0.05, 0.10)
        self.min_goal_distance = min_goal_distance
        self.model_settings = {"min_goal_distance": min_goal_distance}
        super().__init__(
            xml=franka_mjcf(kp=kp, kv=kv, armature=armature),
            num_obstacles=num_obstacles,
            candidates=candidates,
            **kwargs,
        )

    def default_scene(self) -> dict[str, jax.Array]:
        """``torus`` (major, minor, centre height, angle centre, angle range: the region of the
        goal and the ball centres) and ``obstacle_radius`` (min, max) as float32 arrays."""
        return {"torus": jnp.asarray(self.torus, jnp.float32),
                "obstacle_radius": jnp.asarray(self.obstacle_radius_range, jnp.float32)}

    def _candidate(self, key: jax.Array, q0: jax.Array, scene: dict[str, jax.Array]):
        k_p, k_r = jax.random.split(key)
        n = self.num_obstacles
        pts, pts_ok = half_torus_volume_uniform(k_p, (n + 1,), *scene["torus"])
        goal, centers = pts[0], pts[1:]
        r_lo, r_hi = scene["obstacle_radius"]
        radius = jax.random.uniform(k_r, (n,), minval=r_lo, maxval=r_hi)
        obstacles = Obstacles(centers, radius, jnp.ones((n,), jnp.float32))
        ee0 = self.robot.end_effector(q0)
        margin = self._scene_margin(q0, goal, obstacles)
        margin = jnp.minimum(margin, safe_norm(goal - ee0) - self.min_goal_distance)
        margin = jnp.where(jnp.all(pts_ok), margin, -jnp.inf)
        return (goal, obstacles), margin
