"""The MJX reaching environment shared by the robots: :class:`ReachEnv` (brax ``Env`` API).

Thesis §6.2–6.3, docs/design.md §2.2 and §4.3. The robots subclass it:
:class:`envs.three_link.ThreeLinkReach` and :class:`envs.franka.FrankaReach`.

**Control (acceleration actions through PD tracking).** The action is a joint acceleration,
NaNs replaced by 0 and clipped to ``±action_limit`` (1 by default). The environment keeps a
virtual joint velocity ``q̇_v`` (:meth:`ReachEnv.virtual_velocity`). In every physics substep
(``dt = 1/240`` s, 3 substeps per 80 Hz control step), as in the original implementation's
"velocity open loop" mode::

    q_target  = clip(q_measured + q̇_v · dt, q_lower, q_upper)
    q̇_target  = clip(q̇_v + a · dt, −q̇_max, q̇_max)     (0 where q_target sits on a limit)
    ctrl      = concat(q_target, q̇_target)              → MJX position + velocity servos
    q̇_v      ← q̇_target

Like the original, the velocity the policy and the observation see is the virtual velocity
``q̇_v`` (``measured_velocity=True`` switches the observation to MJX's ``qvel``).

**All control state lives in the physics state.** ``q̇_v`` is not stored separately: after a
reset (``ctrl = concat(q0, q̇0)``) and after every step (the last substep's ``ctrl``) it equals
the velocity half ``pipeline_state.ctrl[dof:]`` bit for bit (``ctrl`` is float32), so
:meth:`ReachEnv.virtual_velocity` reads it there. brax's ``AutoResetWrapper``, which restores
only ``pipeline_state`` and ``obs``, therefore restarts an episode with the matching ``q̇_v``;
goal and obstacles (``state.info``) never change within an episode, so they match the restored
first state too (docs/design.md §5.3).

**Obstacles are not in the MJX model.** Distances, collision detection, the reward's obstacle
term and the observation vectors come from analytic JAX geometry on the robot's control points
(:mod:`mjxrmp.geometry`, exact norm): 3-link obstacles are vertical cylinders (circles in the
plane), Franka obstacles are balls.

**MuJoCo's constraint pipeline is off** (``constraint_stages=False``, docs/design.md §5.8):
the models have no contacts or equality constraints and the position targets are clipped to the
joint ranges, so the solver has nothing to do that changes the motion, but under MJX it costs up
to a third of a control step. ``constraint_stages=True`` simulates the MJCF as generated
(joint-limit constraints included). On a GPU the substeps of a control step are written out
rather than looped (``unroll_substeps``, §5.9) and MJX's mass-matrix factorisations and solves
are written out (``written_out_solves``, §5.10); both default to on a GPU only.

**Reward** per substep :func:`envs.base.reach_reward` with ``τ = data.qfrc_actuator`` as the
effort (``exp(−½‖x−g‖²/σ²) − Σ_i max(0, 1 − d_i/δ) − λ‖τ‖²`` clipped to ``[−5, 1]``; ``d_i`` the
smallest control-point surface distance to obstacle ``i``), averaged over the substeps up to
and including the first colliding one. ``done = 1`` on collision (any exact distance < 0) and
on a non-finite state (then ``metrics["nonfinite"] = 1``, the reward is −5 and the observation
is zeroed where non-finite). The episode limit (600 control steps, :attr:`ReachEnv.horizon`) is
applied by the episode wrapper (:func:`envs.wrappers.wrap`).

**Per-step metrics** (``state.metrics``, summed over an episode by brax's ``EpisodeWrapper``):
``goal_distance``, ``success`` (goal distance < 0.05 m), ``collision``, ``nonfinite``,
``min_obstacle_distance``, ``tracking_error`` (max-abs ``qvel − q̇_v`` after the step).
``step`` keeps any other metric a wrapper added (brax's ``EvalWrapper`` adds ``reward``).
**Per-episode accumulators** (``state.info``, reset with each episode, also by brax's
auto-reset: :func:`envs.base.accumulate_episode`): ``episode_return``, ``episode_length``,
``episode_collided``, ``episode_nonfinite``; the final goal distance and success are the last
step's metrics.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
from brax.envs.base import Env, State
from mujoco import mjx

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag before JAX initialises)
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
from envs.physics import gpu_default, set_constraint_stages, substep_unroll, written_out_mass_solves
from mjxrmp.config import check_bool, check_choice, check_float, check_int
from mjxrmp.geometry import Obstacles
from mjxrmp.leaves.hand_designed import safe_norm
from mjxrmp.robots import Robot, get

OBSERVATIONS = ("default", "residual_rmp")

__all__ = ["OBSERVATIONS", "ReachEnv"]


class ReachEnv(Env):
    """Shared machinery of the reaching environments (not registered itself).

    Subclasses provide the robot, the MJCF, the obstacle shape and :meth:`_candidate` (one
    goal-and-obstacles candidate for :meth:`sample_scene`).
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
        constraint_stages: bool = False,
        unroll_substeps: bool | None = None,
        written_out_solves: bool | None = None,
    ):
        settings = {k: v for k, v in locals().items() if k != "self"}  # the arguments only
        name = type(self).__name__
        #: What shapes the environment besides its scene (:meth:`shares_model`): the arguments
        #: and a subclass's own settings (set before it calls this constructor).
        self.model_settings = {**getattr(self, "model_settings", {}), **settings}
        self.observation_variant = check_choice(observation, f"{name}.observation", OBSERVATIONS)
        self.num_obstacles = check_int(num_obstacles, f"{name}.num_obstacles")
        self.action_limit = check_float(action_limit, f"{name}.action_limit")
        self.substeps = check_int(substeps, f"{name}.substeps")
        self.horizon = check_int(horizon, f"{name}.horizon")
        self.candidates = check_int(candidates, f"{name}.candidates")
        self.measured_velocity = check_bool(measured_velocity, f"{name}.measured_velocity")
        self.robot: Robot = get(self.robot_name)
        self.constraint_stages = check_bool(constraint_stages, f"{name}.constraint_stages")
        self.substep_unroll = substep_unroll(self.substeps, check_bool(
            unroll_substeps, f"{name}.unroll_substeps", allow_none=True))
        self.written_out_solves = gpu_default(check_bool(
            written_out_solves, f"{name}.written_out_solves", allow_none=True))
        self.mj_model = set_constraint_stages(mujoco.MjModel.from_xml_string(xml),
                                              self.constraint_stages)
        # this process's first device: in a multi-process run jax.devices()[0] is process 0's
        self.mjx_model = mjx.put_model(self.mj_model, device=jax.local_devices()[0])
        self._data0 = mjx.make_data(self.mjx_model, device=jax.local_devices()[0])
        self.sim_dt = float(self.mj_model.opt.timestep)
        self.dt = self.sim_dt * self.substeps
        self.goal_sigma = goal_sigma
        self.obstacle_delta = obstacle_delta
        self.torque_weight = torque_weight
        self.reward_min = reward_min
        self.reward_max = reward_max
        self.success_radius = success_radius
        self.clearance = clearance
        r = self.robot
        self._q_lower = jnp.asarray(r.q_lower, jnp.float32)
        self._q_upper = jnp.asarray(r.q_upper, jnp.float32)
        self._qd_max = jnp.asarray(r.qd_max, jnp.float32)
        self._radii = jnp.asarray(r.control_point_radii, jnp.float32)

    # ------------------------------------------------------------------ brax Env API
    @property
    def observation_size(self) -> int:
        """Length of the observation vector (:meth:`observation_layout`)."""
        return sum(sl.stop - sl.start for sl in self.observation_layout().values())

    @property
    def action_size(self) -> int:
        """One joint acceleration per degree of freedom."""
        return self.robot.dof

    @property
    def backend(self) -> str:
        """``"mjx"``."""
        return "mjx"

    @property
    def obs_dim(self) -> int:
        """Dimension of obstacle centres and of ``v_i`` (2 for the 3-link, 3 for the Franka)."""
        return self.robot.workspace_dim

    @property
    def reward_params(self) -> RewardParams:
        """The reward constants (σ, δ, λ and the clipping range) as :class:`RewardParams`."""
        return RewardParams(self.goal_sigma, self.obstacle_delta, self.torque_weight,
                            self.reward_min, self.reward_max)

    def observation_layout(self) -> dict[str, slice]:
        """Named slices of the observation vector (thesis §6.2.2).

        ``sin_q, cos_q, qd`` (dof each), ``goal_minus_x`` (dim), ``obstacle_vectors``
        (``v_i``, obstacle → closest control-point surface, O × dim, obstacle-major),
        ``obstacles`` (``o_i`` = centre and radius, O × (dim + 1)); the ``residual_rmp``
        variant appends ``goal``, ``ee_position`` and ``ee_velocity`` (dim each).
        """
        d, w, o = self.robot.dof, self.obs_dim, self.num_obstacles
        sizes = [("sin_q", d), ("cos_q", d), ("qd", d), ("goal_minus_x", w),
                 ("obstacle_vectors", o * w), ("obstacles", o * (w + 1))]
        if self.observation_variant == "residual_rmp":
            sizes += [("goal", w), ("ee_position", w), ("ee_velocity", w)]
        return layout(sizes)

    # ------------------------------------------------------------------ scene sampling
    def default_scene(self) -> dict[str, jax.Array]:
        """The scene sampler's parameters (goal region, obstacle region and radii) as float32
        arrays: :meth:`reset`'s default scene (docs/design.md §2.2)."""
        raise NotImplementedError

    def shares_model(self, other: Env) -> bool:
        """Whether ``other`` differs from this environment at most in its scene parameters
        (:meth:`default_scene`): same class, MJCF and settings, so one compiled program runs
        both, each environment row with its own scene."""
        return type(other) is type(self) and other.model_settings == self.model_settings

    def sample_scene(self, key: jax.Array, scene: dict[str, jax.Array] | None = None):
        """``(q0, qd0, goal, obstacles, ok)`` for one episode of ``scene`` (default: its own).

        The initial state is drawn once; goal and obstacles are drawn as ``candidates``
        candidate pairs against it (the thesis re-samples goal and obstacles when a clearance
        rule fails), so the robot's kinematics is evaluated once per reset, not per candidate.
        """
        scene = self.default_scene() if scene is None else scene
        k_q, k_scene = jax.random.split(key)
        q0, qd0 = self._sample_q0(k_q)
        (goal, obstacles), ok = sample_first_valid(k_scene, self.candidates,
                                                   lambda k: self._candidate(k, q0, scene))
        return q0, qd0, goal, obstacles, ok

    def _candidate(self, key: jax.Array, q0: jax.Array, scene: dict[str, jax.Array]):
        """``((goal, obstacles), margin)``: one candidate of ``scene``, its margin ≥ 0 if valid."""
        raise NotImplementedError

    def _scene_margin(self, q0: jax.Array, goal: jax.Array, obstacles: Obstacles) -> jax.Array:
        """Clearance margin of a scene: the smaller of the robot's and the goal's clearance to
        the obstacles, minus :attr:`clearance` (≥ 0: valid)."""
        return jnp.minimum(self._robot_clearance(q0, obstacles),
                           self._goal_clearance(goal, obstacles)) - self.clearance

    def _sample_q0(self, key: jax.Array, spread: float = 0.1, qd_spread: float = 0.005):
        k_q, k_qd = jax.random.split(key)
        d = self.robot.dof
        q0 = jnp.asarray(self.robot.default_q, jnp.float32) + jax.random.uniform(
            k_q, (d,), minval=-spread, maxval=spread)
        lo = jnp.where(jnp.isfinite(self._q_lower), self._q_lower, -jnp.inf)
        q0 = jnp.clip(q0, lo, self._q_upper)
        qd0 = jax.random.uniform(k_qd, (d,), minval=-qd_spread, maxval=qd_spread)
        return q0, qd0

    # ------------------------------------------------------------------ geometry
    def _planar(self, diff: jax.Array) -> jax.Array:
        """Centre differences as the obstacle shape measures them (cylinders: x-y only)."""
        return diff[..., :2] if self.obstacle_shape == "cylinder" else diff

    def distances(self, q: jax.Array, obstacles: Obstacles) -> jax.Array:
        """Exact surface distances ``(P, O)`` between control points and obstacles."""
        pts = self.robot.control_points(q)
        diff = self._planar(pts[:, None, :] - obstacles.center[None, :, :])
        return safe_norm(diff) - self._radii[:, None] - obstacles.radius[None, :]

    def _robot_clearance(self, q: jax.Array, obstacles: Obstacles) -> jax.Array:
        """Smallest exact surface distance between the robot and any active obstacle."""
        d = self.distances(q, obstacles)
        return jnp.min(jnp.where(obstacles.active[None, :] > 0, d, jnp.inf))

    def _goal_clearance(self, goal: jax.Array, obstacles: Obstacles) -> jax.Array:
        d = safe_norm(self._planar(goal[None, :] - obstacles.center)) - obstacles.radius
        return jnp.min(jnp.where(obstacles.active > 0, d, jnp.inf))

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

    def virtual_velocity(self, state: State) -> jax.Array:
        """The virtual joint velocity ``q̇_v`` (module docstring): the velocity-servo half of
        ``pipeline_state.ctrl`` (leading batch axes allowed)."""
        return state.pipeline_state.ctrl[..., self.robot.dof:]

    def policy_inputs(self, state: State):
        """``(q, q̇, goal, obstacles)`` as an RMP² policy sees them (``q̇`` = virtual velocity)."""
        info = state.info
        return (state.pipeline_state.qpos, self.virtual_velocity(state), info["goal"],
                info["obstacles"])

    # ------------------------------------------------------------------ reset / step
    def _goal_metrics(self, q: jax.Array, goal: jax.Array) -> dict[str, jax.Array]:
        goal_distance = safe_norm(goal - self.robot.end_effector(q))
        return {"goal_distance": goal_distance,
                "success": (goal_distance < self.success_radius).astype(jnp.float32)}

    def reset(self, rng: jax.Array, scene: dict[str, jax.Array] | None = None) -> State:
        """A new episode of ``scene`` (default :meth:`default_scene`; kept in ``info["scene"]``
        for the auto-reset) from :meth:`sample_scene`, servos holding the initial state."""
        scene = self.default_scene() if scene is None else scene
        k_scene, k_next = jax.random.split(rng)
        q0, qd0, goal, obstacles, ok = self.sample_scene(k_scene, scene)
        data = self._data0.replace(
            qpos=q0, qvel=qd0, ctrl=jnp.concatenate([q0, qd0]).astype(self._data0.ctrl.dtype)
        )
        obs = self.observe(q0, qd0, goal, obstacles)
        z = jnp.zeros((), jnp.float32)
        metrics = {**self._goal_metrics(q0, goal), "collision": z, "nonfinite": z,
                   "min_obstacle_distance": self._robot_clearance(q0, obstacles),
                   "tracking_error": z}
        info = {"rng": k_next, "goal": goal, "obstacles": obstacles, "scene": scene,
                "sampler_ok": ok.astype(jnp.float32), **episode_info()}
        return State(data, obs, z, z, metrics, info)

    def _substep(self, a: jax.Array, goal: jax.Array, obstacles: Obstacles):
        """``scan`` body of one physics substep: PD targets from ``q̇_v`` (module docstring),
        ``mjx.step``, and the substep's reward and collision flag."""
        lower_finite = jnp.isfinite(self._q_lower)
        upper_finite = jnp.isfinite(self._q_upper)
        active = obstacles.active > 0
        params = self.reward_params

        def body(carry, _):
            data, qv = carry
            q_t = jnp.clip(data.qpos + qv * self.sim_dt, self._q_lower, self._q_upper)
            at_limit = ((lower_finite & (q_t <= self._q_lower))
                        | (upper_finite & (q_t >= self._q_upper)))
            qd_t = jnp.where(at_limit, 0.0, qv + a * self.sim_dt)
            qd_t = jnp.clip(qd_t, -self._qd_max, self._qd_max)
            data = data.replace(ctrl=jnp.concatenate([q_t, qd_t]).astype(data.ctrl.dtype))
            with written_out_mass_solves(self.written_out_solves):
                data = mjx.step(self.mjx_model, data)
            dist_goal = safe_norm(self.robot.end_effector(data.qpos) - goal)
            d = self.distances(data.qpos, obstacles)
            d_obs = jnp.min(jnp.where(obstacles.active[None, :] > 0, d, jnp.inf), axis=0)
            r = reach_reward(dist_goal, d_obs, active, data.qfrc_actuator, params)
            return (data, qd_t), (r, jnp.any(active & (d_obs < 0.0)))

        return body

    def step(self, state: State, action: jax.Array) -> State:
        """One control step: ``substeps`` physics substeps of the PD scheme (module docstring)."""
        check_action(action, self.action_size)
        goal, obstacles = state.info["goal"], state.info["obstacles"]
        a = clean_action(action, self.action_limit).astype(jnp.float32)
        (data, qv), (rs, cols) = jax.lax.scan(
            self._substep(a, goal, obstacles),
            (state.pipeline_state, self.virtual_velocity(state)),
            None,
            length=self.substeps,
            unroll=self.substep_unroll,
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
        obs = self.observe(q, data.qvel if self.measured_velocity else qv, goal, obstacles)
        reward = jnp.where(finite & jnp.isfinite(reward), reward, self.reward_min)
        nonfinite = (~finite).astype(jnp.float32)
        metrics = {**state.metrics, **self._goal_metrics(q, goal),
                   "collision": collided.astype(jnp.float32), "nonfinite": nonfinite,
                   "min_obstacle_distance": self._robot_clearance(q, obstacles),
                   "tracking_error": jnp.max(jnp.abs(data.qvel - qv))}
        info = accumulate_episode(state.info, reward, metrics["collision"], nonfinite)
        return state.replace(pipeline_state=data, obs=obs, reward=reward,
                             done=(collided | ~finite).astype(jnp.float32), metrics=metrics,
                             info=info)
