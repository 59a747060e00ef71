"""Planar 3-link reaching (thesis §6.2, docs/design.md §4.3): :class:`ThreeLinkReach`."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from envs.reaching import ReachEnv
from envs.samplers import annulus
from mjxrmp.config import check_choice, check_int
from mjxrmp.geometry import Obstacles
from mjxrmp.robots.mjcf import three_link_mjcf

OBSTACLE_SAMPLERS = ("thesis", "original")
THREE_LINK_SETUPS = ("env1", "env2", "env3")

#: Servo gains chosen for tight, stable velocity tracking at float32 (implicitfast integrates the
#: velocity gain implicitly). Because ``q_target − q = q̇_v·dt``, the servo is in effect a velocity
#: servo whose steady-state velocity bias is ``kp·dt/kv``; the mjcf defaults (3-link 100/10,
#: Franka 1000/50) give a 4 % / 8 % bias and tracking errors up to 0.1 / 0.06 rad/s with the
#: hand-designed policy, these give < 0.005 / 0.01 rad/s (measured on 64 / 32 rollouts).
THREE_LINK_KP = 300.0
THREE_LINK_KV = 300.0

__all__ = ["OBSTACLE_SAMPLERS", "THREE_LINK_KP", "THREE_LINK_KV", "THREE_LINK_SETUPS",
           "ThreeLinkReach"]


class ThreeLinkReach(ReachEnv):
    """Planar 3-link reaching (thesis §6.2), setups ``env1``/``env2``/``env3``.

    * initial ``q ~ U(±0.1)``, ``q̇ ~ U(±0.005)``;
    * goals (area-uniform): ``env1``/``env2`` in the π/2 sector centred on the −x axis (angles
      3π/4 … 5π/4, opposite the initial arm — the original training script's
      ``goal_torus_angle_center = π``) ∩ annulus r ∈ [0.275, 0.475]; ``env3`` in the left
      half-disk (angles π/2 … 3π/2) ∩ annulus r ∈ [0.125, 0.625];
    * obstacles: vertical cylinders (circles in the plane), radius U[0.05, 0.10]; centres
      ``obstacle_sampler="thesis"`` (default): area-uniform in the annulus r ∈ [0.4, 0.9]
      (thesis text); ``"original"``: radius U[0.4, 0.5], angle U[0, 2π) (the original code's
      2-D torus sampler with major 0.65, minor 0.25);
    * ``env1`` has 1 obstacle, ``env2``/``env3`` have 3. Every setup has ``num_obstacles = 3``
      obstacle slots (observation size 26); env1's other two are inactive padding (zero
      vectors, radius −1 in the observation; ignored by the reward, the collision check, the
      clearance rule and the RMP² policies). The count is a scene parameter
      (``obstacle_count``), so the three setups share one model (docs/design.md §2.2);
      ``num_obstacles=1`` gives env1 the thesis's unpadded observation (size 16);
    * clearance ≥ 0.1 between goal and obstacles and between the initial robot and obstacles.

    Build it with ``envs.make("three_link/env3", ...)``; other keyword arguments go to
    :class:`~envs.reaching.ReachEnv`.
    """

    robot_name = "three_link"
    obstacle_shape = "cylinder"

    def __init__(
        self,
        setup: str = "env3",
        *,
        obstacle_sampler: str = "thesis",
        kp: float = THREE_LINK_KP,
        kv: float = THREE_LINK_KV,
        num_obstacles: int | None = None,
        **kwargs,
    ):
        self.setup = check_choice(setup, "ThreeLinkReach.setup", THREE_LINK_SETUPS)
        self.obstacle_sampler = check_choice(
            obstacle_sampler, "ThreeLinkReach.obstacle_sampler", OBSTACLE_SAMPLERS)
        if setup == "env3":
            self.goal_region = (0.125, 0.625, math.pi, math.pi)
        else:
            self.goal_region = (0.275, 0.475, math.pi, math.pi / 2)
        self.obstacle_region = (0.4, 0.9) if obstacle_sampler == "thesis" else (0.4, 0.5)
        self.obstacle_radius_range = (0.05, 0.10)
        n = 3 if num_obstacles is None else check_int(num_obstacles, "ThreeLinkReach.num_obstacles")
        #: Active obstacles of the setup's scenes (at most the slots): env1 1, env2/env3 3.
        self.obstacle_count = min(1 if setup == "env1" else 3, n)
        self.model_settings = {"obstacle_sampler": obstacle_sampler}
        super().__init__(xml=three_link_mjcf(kp=kp, kv=kv), num_obstacles=n, **kwargs)

    def default_scene(self) -> dict[str, jax.Array]:
        """``goal_region`` (r_min, r_max, angle centre, angle range), ``obstacle_region``
        (r_min, r_max of the centres), ``obstacle_radius`` (min, max) and ``obstacle_count``
        (the active obstacles, the first slots) as float32 arrays."""
        return {"goal_region": jnp.asarray(self.goal_region, jnp.float32),
                "obstacle_region": jnp.asarray(self.obstacle_region, jnp.float32),
                "obstacle_radius": jnp.asarray(self.obstacle_radius_range, jnp.float32),
                "obstacle_count": jnp.asarray(self.obstacle_count, jnp.float32)}

    def _candidate(self, key: jax.Array, q0: jax.Array, scene: dict[str, jax.Array]):
        k_g, k_c, k_r = jax.random.split(key, 3)
        goal = annulus(k_g, (), *scene["goal_region"])
        n = self.num_obstacles
        lo, hi = scene["obstacle_region"]
        centers = annulus(k_c, (n,), lo, hi, area_uniform=self.obstacle_sampler == "thesis")
        r_lo, r_hi = scene["obstacle_radius"]
        radius = jax.random.uniform(k_r, (n,), minval=r_lo, maxval=r_hi)
        active = (jnp.arange(n) < scene["obstacle_count"]).astype(jnp.float32)
        obstacles = Obstacles(centers, radius, active)
        return (goal, obstacles), self._scene_margin(q0, goal, obstacles)
