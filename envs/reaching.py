"""MJX reaching environments with the brax ``Env`` API: planar 3-link and Franka Panda.

Thesis §6.2–6.3, docs/design.md §2.2, docs/design.md §4.3.

**Control (acceleration actions through PD tracking).** The action is a joint acceleration,
NaNs replaced by 0 and clipped to ``±action_limit`` (1 by default). The environment keeps a
virtual joint velocity ``q̇_v`` (``state.info["qd_virtual"]``). In every physics substep
(``dt = 1/240`` s, 3 substeps per 80 Hz control step), as in the original implementation's
"velocity open loop" mode::

    q_target  = clip(q_measured + q̇_v · dt, q_lower, q_upper)
    q̇_target  = clip(q̇_v + a · dt, −q̇_max, q̇_max)     (0 where q_target sits on a limit)
    ctrl      = concat(q_target, q̇_target)              → MJX position + velocity servos
    q̇_v      ← q̇_target

Like the original, the velocity the policy and the observation see is the virtual velocity
``q̇_v`` (``measured_velocity=True`` switches the observation to MJX's ``qvel``).

**Obstacles are not in the MJX model.** Distances, collision detection, the reward's obstacle
term and the observation vectors come from analytic JAX geometry on the robot's control points
(:mod:`mjxrmp.geometry`, exact norm): 3-link obstacles are vertical cylinders (circles in the
plane), Franka obstacles are balls.

**Reward** per substep ``exp(−½‖x−g‖²/σ²) − Σ_i max(0, 1 − d_i/δ) − λ‖τ‖²`` clipped to
``[−5, 1]`` (σ 0.1, δ 0.05, λ 1e-5; ``d_i`` the smallest control-point surface distance to
obstacle ``i``; ``τ = data.qfrc_actuator``), averaged over the substeps up to and including the
first colliding one. ``done = 1`` on collision (any exact distance < 0) and on a non-finite
state (then ``metrics["nonfinite"] = 1``, the reward is −5 and the observation is zeroed where
non-finite). The episode limit (600 control steps, :attr:`ReachEnv.horizon`) is applied by the
episode wrapper (:func:`envs.wrappers.wrap`).

**Per-step metrics** (``state.metrics``, summed over an episode by brax's ``EpisodeWrapper``):
``goal_distance``, ``success`` (goal distance < 0.05 m), ``collision``, ``nonfinite``,
``min_obstacle_distance``, ``tracking_error`` (max-abs ``qvel − q̇_v`` after the step).
**Per-episode accumulators** (``state.info``, reset with each episode): ``episode_return``,
``episode_length``, ``episode_collided``, ``episode_nonfinite``; the final goal distance and
success are the last step's metrics.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
from brax.envs.base import Env, State
from mujoco import mjx

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag before JAX initialises)
from envs import samplers
from envs.checks import check_action
from mjxrmp.geometry import Obstacles
from mjxrmp.leaves.hand_designed import safe_norm
from mjxrmp.robots import Robot, get, mjcf

OBSTACLE_SAMPLERS = ("thesis", "original")
OBSERVATIONS = ("default", "residual_rmp")
THREE_LINK_SETUPS = ("env1", "env2", "env3")

#: Servo gains chosen for tight, stable velocity tracking at float32 (implicitfast integrates the
#: velocity gain implicitly). Because ``q_target − q = q̇_v·dt``, the servo is in effect a velocity
#: servo whose steady-state velocity bias is ``kp·dt/kv``; the mjcf defaults (3-link 100/10,
#: Franka 1000/50) give a 4 % / 8 % bias and tracking errors up to 0.1 / 0.06 rad/s with the
#: hand-designed policy, these give < 0.005 / 0.01 rad/s (measured on 64 / 32 rollouts).
THREE_LINK_KP = 300.0
THREE_LINK_KV = 300.0
FRANKA_KP = 1000.0
FRANKA_KV = 300.0


class ReachEnv(Env):
    """Shared machinery of the reaching environments (not registered itself).

    Subclasses provide the robot, the MJCF, the obstacle shape and :meth:`sample_scene`.
    """

    robot_name: str = ""
    obstacle_shape: str = "sphere"

    def __init__(
        self,
        *,
        xml: str,
        num_obstacles: int,
        action_limit: float = 1.0,
        substeps: int = 3,
        horizon: int = 600,
        goal_sigma: float = 0.1,
        obstacle_delta: float = 0.05,
        torque_weight: float = 1e-5,
        reward_min: float = -5.0,
        reward_max: float = 1.0,
        success_radius: float = 0.05,
        clearance: float = 0.1,
        candidates: int = 32,
        observation: str = "default",
        measured_velocity: bool = False,
    ):
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {OBSERVATIONS}, got {observation!r}")
        if num_obstacles < 1:
            raise ValueError(f"num_obstacles must be >= 1, got {num_obstacles}")
        if action_limit <= 0:
            raise ValueError(f"action_limit must be > 0, got {action_limit}")
        if substeps < 1 or horizon < 1 or candidates < 1:
            raise ValueError("substeps, horizon and candidates must be >= 1")
        self.robot: Robot = get(self.robot_name)
        self.mj_model = mujoco.MjModel.from_xml_string(xml)
        self.mjx_model = mjx.put_model(self.mj_model)
        self._data0 = mjx.make_data(self.mjx_model)
        self.num_obstacles = num_obstacles
        self.action_limit = float(action_limit)
        self.substeps = int(substeps)
        self.horizon = int(horizon)
        self.sim_dt = float(self.mj_model.opt.timestep)
        self.dt = self.sim_dt * self.substeps
        self.goal_sigma = goal_sigma
        self.obstacle_delta = obstacle_delta
        self.torque_weight = torque_weight
        self.reward_min = reward_min
        self.reward_max = reward_max
        self.success_radius = success_radius
        self.clearance = clearance
        self.candidates = int(candidates)
        self.observation_variant = observation
        self.measured_velocity = measured_velocity
        r = self.robot
        self._q_lower = jnp.asarray(r.q_lower, jnp.float32)
        self._q_upper = jnp.asarray(r.q_upper, jnp.float32)
        self._qd_max = jnp.asarray(r.qd_max, jnp.float32)
        self._radii = jnp.asarray(r.control_point_radii, jnp.float32)

    # ------------------------------------------------------------------ brax Env API
    @property
    def observation_size(self) -> int:
        return sum(sl.stop - sl.start for sl in self.observation_layout().values())

    @property
    def action_size(self) -> int:
        return self.robot.dof

    @property
    def backend(self) -> str:
        return "mjx"

    @property
    def obs_dim(self) -> int:
        """Dimension of obstacle centres and of ``v_i`` (2 for the 3-link, 3 for the Franka)."""
        return self.robot.workspace_dim

    def observation_layout(self) -> dict[str, slice]:
        """Named slices of the observation vector (thesis §6.2.2).

        ``sin_q, cos_q, qd`` (dof each), ``goal_minus_x`` (dim), ``obstacle_vectors``
        (``v_i``, obstacle → closest control-point surface, O × dim, obstacle-major),
        ``obstacles`` (``o_i`` = centre and radius, O × (dim + 1)); the ``residual_rmp``
        variant appends ``goal``, ``ee_position`` and ``ee_velocity`` (dim each).
        """
        d, w, o = self.robot.dof, self.obs_dim, self.num_obstacles
        sizes = [
            ("sin_q", d),
            ("cos_q", d),
            ("qd", d),
            ("goal_minus_x", w),
            ("obstacle_vectors", o * w),
            ("obstacles", o * (w + 1)),
        ]
        if self.observation_variant == "residual_rmp":
            sizes += [("goal", w), ("ee_position", w), ("ee_velocity", w)]
        out, start = {}, 0
        for name, n in sizes:
            out[name] = slice(start, start + n)
            start += n
        return out

    # ------------------------------------------------------------------ scene sampling
    def sample_scene(self, key: jax.Array):
        """``(q0, qd0, goal, obstacles, ok)`` for one episode.

        The initial state is drawn once; goal and obstacles are drawn as ``candidates``
        candidate pairs against it (the thesis re-samples goal and obstacles when a clearance
        rule fails), so the robot's kinematics is evaluated once per reset, not per candidate.
        """
        k_q, k_scene = jax.random.split(key)
        q0, qd0 = self._sample_q0(k_q)
        (goal, obstacles), ok = self._reject(k_scene, lambda k: self._candidate(k, q0))
        return q0, qd0, goal, obstacles, ok

    def _candidate(self, key: jax.Array, q0: jax.Array):
        """``((goal, obstacles), margin)``: one candidate and its clearance margin (≥ 0: valid)."""
        raise NotImplementedError

    def _sample_q0(self, key: jax.Array, spread: float = 0.1, qd_spread: float = 0.005):
        k_q, k_qd = jax.random.split(key)
        d = self.robot.dof
        q0 = jnp.asarray(self.robot.default_q, jnp.float32) + jax.random.uniform(
            k_q, (d,), minval=-spread, maxval=spread
        )
        lo = jnp.where(jnp.isfinite(self._q_lower), self._q_lower, -jnp.inf)
        q0 = jnp.clip(q0, lo, self._q_upper)
        qd0 = jax.random.uniform(k_qd, (d,), minval=-qd_spread, maxval=qd_spread)
        return q0, qd0

    def _robot_clearance(self, q: jax.Array, obstacles: Obstacles) -> jax.Array:
        """Smallest exact surface distance between the robot and any active obstacle."""
        d = self.distances(q, obstacles)
        return jnp.min(jnp.where(obstacles.active[None, :] > 0, d, jnp.inf))

    def _goal_clearance(self, goal: jax.Array, obstacles: Obstacles) -> jax.Array:
        diff = goal[None, :] - obstacles.center
        if self.obstacle_shape == "cylinder":
            diff = diff[:, :2]
        d = safe_norm(diff) - obstacles.radius
        return jnp.min(jnp.where(obstacles.active > 0, d, jnp.inf))

    def _reject(self, key: jax.Array, candidate: Callable[[jax.Array], tuple]):
        """Draw ``candidates`` scenes with ``candidate(key) -> (scene, margin)`` and keep the
        first whose ``margin >= 0`` (bounded rejection; ``ok`` False when none is valid)."""
        keys = jax.random.split(key, self.candidates)
        scenes, margin = jax.vmap(candidate)(keys)
        idx, ok = samplers.first_valid(margin >= 0.0, margin)
        return samplers.take(scenes, idx), ok

    # ------------------------------------------------------------------ geometry
    def distances(self, q: jax.Array, obstacles: Obstacles) -> jax.Array:
        """Exact surface distances ``(P, O)`` between control points and obstacles."""
        pts = self.robot.control_points(q)
        diff = pts[:, None, :] - obstacles.center[None, :, :]
        if self.obstacle_shape == "cylinder":
            diff = diff[..., :2]
        return safe_norm(diff) - self._radii[:, None] - obstacles.radius[None, :]

    def obstacle_vectors(self, q: jax.Array, obstacles: Obstacles) -> tuple[jax.Array, jax.Array]:
        """``v_i`` (O, dim): from obstacle ``i``'s surface to the closest control-point surface
        (``d_i`` times the unit direction obstacle centre → closest point), and ``d_i`` (O,).
        Inactive (padding) obstacles give zeros and ``+inf``."""
        pts = self.robot.control_points(q)
        diff = pts[:, None, :] - obstacles.center[None, :, :]
        if self.obstacle_shape == "cylinder":
            diff = diff.at[..., 2:].set(0.0)
        norm = safe_norm(diff)
        d = norm - self._radii[:, None] - obstacles.radius[None, :]
        idx = jnp.argmin(d, axis=0)
        cols = jnp.arange(d.shape[1])
        d_min = d[idx, cols]
        unit = diff[idx, cols] / jnp.maximum(norm[idx, cols], 1e-9)[:, None]
        active = obstacles.active > 0
        v = jnp.where(active[:, None], d_min[:, None] * unit, 0.0)
        return v, jnp.where(active, d_min, jnp.inf)

    # ------------------------------------------------------------------ observation
    def observe(self, q, qd, goal, obstacles: Obstacles) -> jax.Array:
        """The observation vector (layout: :meth:`observation_layout`)."""
        ee = self.robot.end_effector(q)
        v, _ = self.obstacle_vectors(q, obstacles)
        active = obstacles.active > 0
        centers = jnp.where(active[:, None], obstacles.center, 0.0)
        radii = jnp.where(active, obstacles.radius, -1.0)
        parts = [
            jnp.sin(q),
            jnp.cos(q),
            qd,
            goal - ee,
            v.reshape(-1),
            jnp.concatenate([centers, radii[:, None]], axis=1).reshape(-1),
        ]
        if self.observation_variant == "residual_rmp":
            ee_vel = jax.jvp(self.robot.end_effector, (q,), (qd,))[1]
            parts += [goal, ee, ee_vel]
        obs = jnp.concatenate(parts)
        return jnp.where(jnp.isfinite(obs), obs, 0.0)

    # ------------------------------------------------------------------ policy inputs
    @staticmethod
    def policy_inputs(state: State):
        """``(q, q̇, goal, obstacles)`` as an RMP² policy sees them (``q̇`` = virtual velocity)."""
        info = state.info
        return state.pipeline_state.qpos, info["qd_virtual"], info["goal"], info["obstacles"]

    # ------------------------------------------------------------------ reset / step
    def _zero_metrics(self) -> dict[str, jax.Array]:
        z = jnp.zeros((), jnp.float32)
        return {
            "goal_distance": z,
            "success": z,
            "collision": z,
            "nonfinite": z,
            "min_obstacle_distance": z,
            "tracking_error": z,
        }

    def reset(self, rng: jax.Array) -> State:
        k_scene, k_next = jax.random.split(rng)
        q0, qd0, goal, obstacles, ok = self.sample_scene(k_scene)
        data = self._data0.replace(
            qpos=q0, qvel=qd0, ctrl=jnp.concatenate([q0, qd0]).astype(self._data0.ctrl.dtype)
        )
        obs = self.observe(q0, qd0, goal, obstacles)
        metrics = self._zero_metrics()
        ee = self.robot.end_effector(q0)
        metrics["goal_distance"] = safe_norm(goal - ee)
        metrics["success"] = (metrics["goal_distance"] < self.success_radius).astype(jnp.float32)
        metrics["min_obstacle_distance"] = self._robot_clearance(q0, obstacles)
        z = jnp.zeros((), jnp.float32)
        info = {
            "rng": k_next,
            "goal": goal,
            "obstacles": obstacles,
            "qd_virtual": qd0,
            "sampler_ok": ok.astype(jnp.float32),
            "episode_return": z,
            "episode_length": z,
            "episode_collided": z,
            "episode_nonfinite": z,
        }
        return State(data, obs, z, z, metrics, info)

    def _substep(self, a: jax.Array, goal: jax.Array, obstacles: Obstacles):
        lower_finite = jnp.isfinite(self._q_lower)
        upper_finite = jnp.isfinite(self._q_upper)

        def body(carry, _):
            data, qv = carry
            q = data.qpos
            q_t = jnp.clip(q + qv * self.sim_dt, self._q_lower, self._q_upper)
            at_limit = (lower_finite & (q_t <= self._q_lower)) | (
                upper_finite & (q_t >= self._q_upper)
            )
            qd_t = jnp.where(at_limit, 0.0, qv + a * self.sim_dt)
            qd_t = jnp.clip(qd_t, -self._qd_max, self._qd_max)
            data = data.replace(ctrl=jnp.concatenate([q_t, qd_t]).astype(data.ctrl.dtype))
            data = mjx.step(self.mjx_model, data)
            q_new = data.qpos
            ee = self.robot.end_effector(q_new)
            dist_goal = safe_norm(ee - goal)
            d = self.distances(q_new, obstacles)
            d_obs = jnp.min(jnp.where(obstacles.active[None, :] > 0, d, jnp.inf), axis=0)
            active = obstacles.active > 0
            obstacle_cost = jnp.sum(
                jnp.where(active, jnp.maximum(0.0, 1.0 - d_obs / self.obstacle_delta), 0.0)
            )
            tau = data.qfrc_actuator
            r = (
                jnp.exp(-0.5 * dist_goal**2 / self.goal_sigma**2)
                - obstacle_cost
                - self.torque_weight * jnp.sum(tau * tau)
            )
            r = jnp.clip(r, self.reward_min, self.reward_max)
            collided = jnp.any(active & (d_obs < 0.0))
            return (data, qd_t), (r, collided)

        return body

    def step(self, state: State, action: jax.Array) -> State:
        check_action(action, self.action_size)
        info = dict(state.info)
        goal, obstacles = info["goal"], info["obstacles"]
        a = jnp.where(jnp.isfinite(action), action, 0.0)
        a = jnp.clip(a, -self.action_limit, self.action_limit).astype(jnp.float32)
        (data, qv), (rs, cols) = jax.lax.scan(
            self._substep(a, goal, obstacles),
            (state.pipeline_state, info["qd_virtual"]),
            None,
            length=self.substeps,
        )
        # Substeps up to and including the first collision count for the reward.
        before = jnp.concatenate([jnp.zeros((1,), bool), jnp.cumsum(cols)[:-1] > 0])
        mask = (~before).astype(jnp.float32)
        reward = jnp.sum(rs * mask) / jnp.sum(mask)
        collided = jnp.any(cols)

        q = data.qpos
        finite = (
            jnp.all(jnp.isfinite(q)) & jnp.all(jnp.isfinite(data.qvel)) & jnp.all(jnp.isfinite(qv))
        )
        qd_obs = data.qvel if self.measured_velocity else qv
        obs = self.observe(q, qd_obs, goal, obstacles)
        ee = self.robot.end_effector(q)
        goal_distance = safe_norm(goal - ee)
        reward = jnp.where(finite & jnp.isfinite(reward), reward, self.reward_min)
        nonfinite = (~finite).astype(jnp.float32)
        done = (collided | ~finite).astype(jnp.float32)
        metrics = {
            "goal_distance": goal_distance,
            "success": (goal_distance < self.success_radius).astype(jnp.float32),
            "collision": collided.astype(jnp.float32),
            "nonfinite": nonfinite,
            "min_obstacle_distance": self._robot_clearance(q, obstacles),
            "tracking_error": jnp.max(jnp.abs(data.qvel - qv)),
        }
        info["qd_virtual"] = qv
        info["episode_return"] = info["episode_return"] + reward
        info["episode_length"] = info["episode_length"] + 1.0
        info["episode_collided"] = jnp.maximum(info["episode_collided"], metrics["collision"])
        info["episode_nonfinite"] = jnp.maximum(info["episode_nonfinite"], nonfinite)
        return state.replace(
            pipeline_state=data, obs=obs, reward=reward, done=done, metrics=metrics, info=info
        )


# ---------------------------------------------------------------------- 3-link
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
    * ``env1`` has 1 obstacle (observation size 16), ``env2``/``env3`` have 3 (size 26);
    * clearance ≥ 0.1 between goal and obstacles and between the initial robot and obstacles.
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
        if setup not in THREE_LINK_SETUPS:
            raise ValueError(f"setup must be one of {THREE_LINK_SETUPS}, got {setup!r}")
        if obstacle_sampler not in OBSTACLE_SAMPLERS:
            raise ValueError(
                f"obstacle_sampler must be one of {OBSTACLE_SAMPLERS}, got {obstacle_sampler!r}"
            )
        self.setup = setup
        self.obstacle_sampler = obstacle_sampler
        if setup == "env3":
            self.goal_region = (0.125, 0.625, math.pi, math.pi)
        else:
            self.goal_region = (0.275, 0.475, math.pi, math.pi / 2)
        self.obstacle_region = (0.4, 0.9) if obstacle_sampler == "thesis" else (0.4, 0.5)
        self.obstacle_radius_range = (0.05, 0.10)
        if num_obstacles is None:
            num_obstacles = 1 if setup == "env1" else 3
        super().__init__(
            xml=mjcf.three_link_mjcf(kp=kp, kv=kv), num_obstacles=num_obstacles, **kwargs
        )

    def _candidate(self, key: jax.Array, q0: jax.Array):
        k_g, k_c, k_r = jax.random.split(key, 3)
        r_min, r_max, a_c, a_r = self.goal_region
        goal = samplers.annulus(k_g, (), r_min, r_max, a_c, a_r)
        n = self.num_obstacles
        lo, hi = self.obstacle_region
        if self.obstacle_sampler == "thesis":
            centers = samplers.annulus(k_c, (n,), lo, hi)
        else:
            centers = samplers.annulus(k_c, (n,), lo, hi, area_uniform=False)
        radius = jax.random.uniform(
            k_r, (n,), minval=self.obstacle_radius_range[0], maxval=self.obstacle_radius_range[1]
        )
        obstacles = Obstacles(centers, radius, jnp.ones((n,), jnp.float32))
        margin = jnp.minimum(
            self._robot_clearance(q0, obstacles), self._goal_clearance(goal, obstacles)
        ) - self.clearance
        return (goal, obstacles), margin


# ---------------------------------------------------------------------- Franka
class FrankaReach(ReachEnv):
    """Franka Panda reaching (thesis §6.3): 3 ball obstacles and the goal volume-uniform in the
    front half of the solid torus around the z-axis (major 0.5, minor 0.3, centre height 0.5,
    azimuth |φ| ≤ π/2, i.e. x > 0); ball radius U[0.05, 0.10]; goal ≥ 0.5 m from the initial end
    effector; clearance ≥ 0.1 between goal and balls and between the initial robot (48 control
    points) and the balls; initial ``q = default_q + U(±0.1)``, ``q̇ ~ U(±0.005)``. Observation
    size 45 (54 for the residual-RMP variant). A scene candidate is valid with probability ≈ 0.2,
    so 64 candidates are drawn per reset (failure probability ≈ 1e-6, flagged in
    ``info["sampler_ok"]``)."""

    robot_name = "franka"
    obstacle_shape = "sphere"

    def __init__(
        self,
        *,
        kp: float = FRANKA_KP,
        kv: float = FRANKA_KV,
        armature: float = mjcf.FRANKA_ARMATURE,
        num_obstacles: int = 3,
        min_goal_distance: float = 0.5,
        candidates: int = 64,
        **kwargs,
    ):
        self.torus = (0.5, 0.3, 0.5, 0.0, math.pi)  # major, minor, height, angle centre/range
        self.obstacle_radius_range = (0.05, 0.10)
        self.min_goal_distance = min_goal_distance
        super().__init__(
            xml=mjcf.franka_mjcf(kp=kp, kv=kv, armature=armature),
            num_obstacles=num_obstacles,
            candidates=candidates,
            **kwargs,
        )

    def _candidate(self, key: jax.Array, q0: jax.Array):
        k_p, k_r = jax.random.split(key)
        n = self.num_obstacles
        pts, pts_ok = samplers.half_torus_volume_uniform(k_p, (n + 1,), *self.torus)
        goal, centers = pts[0], pts[1:]
        radius = jax.random.uniform(
            k_r, (n,), minval=self.obstacle_radius_range[0], maxval=self.obstacle_radius_range[1]
        )
        obstacles = Obstacles(centers, radius, jnp.ones((n,), jnp.float32))
        ee0 = self.robot.end_effector(q0)
        margin = jnp.minimum(
            self._robot_clearance(q0, obstacles), self._goal_clearance(goal, obstacles)
        ) - self.clearance
        margin = jnp.minimum(margin, safe_norm(goal - ee0) - self.min_goal_distance)
        margin = jnp.where(jnp.all(pts_ok), margin, -jnp.inf)
        return (goal, obstacles), margin


__all__ = [
    "OBSERVATIONS",
    "OBSTACLE_SAMPLERS",
    "THREE_LINK_SETUPS",
    "FrankaReach",
    "ReachEnv",
    "ThreeLinkReach",
]
