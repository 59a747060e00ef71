"""A reaching environment's scenes simulated by MuJoCo itself (``mujoco.mj_step``), in numpy.

The MuJoCo side of sim-to-sim (:mod:`agents.run.sim2sim`; docs/design.md §2.2 for the task).
:class:`MujocoScenes` runs ``n`` scenes in lockstep, one ``mujoco.MjData`` each, on the
``MjModel`` the environment simulates (``env.mj_model``: the robot's MJCF with the
environment's constraint-stage setting, by default the constraint pipeline off; implicitfast,
``dt = 1/240`` s, float64 in MuJoCo C where MJX computes in float32). What it shares with the
MJX environment is data, not code: the model, the scene (initial ``q``/``q̇``, goal, obstacles,
sampled by the environment's own ``reset`` with the same keys: :func:`sample_scenes`), the
control constants (substeps, action and joint limits) and the observation layout. Everything
else is computed here from ``MjData``:

* kinematics: MuJoCo's forward kinematics (``mj_kinematics`` after each ``mj_step``) gives the
  site positions; control points are interpolated between sites as the robot description lists
  them (3-link: 5 per link between ``link{i}`` and the next joint or the tip; Franka:
  :data:`mjxrmp.robots.franka.CONTROL_POINT_SEGMENTS`), the end effector is the site
  ``end_effector``;
* control: the PD scheme of :mod:`envs.reaching` per physics substep (``q_target = clip(q +
  q̇_v·dt)``, ``q̇_target = clip(q̇_v + a·dt)``, 0 at a joint limit, ``ctrl = [q_target,
  q̇_target]``, ``q̇_v ← q̇_target``);
* reward (per substep, averaged up to and including the first colliding substep), collision
  (an active obstacle's exact surface distance < 0 in any substep), non-finite state, the
  observation (default layout) and the per-episode statistics of
  :func:`envs.evaluate.make_rollout` (episodes frozen once done).

:func:`run_episodes` calls a batch policy once per control step on all scenes;
:func:`view_scene` shows one scene in MuJoCo's passive viewer (needs a display).
"""

from __future__ import annotations

import itertools
import os
import sys
import time
from collections.abc import Callable
from typing import NamedTuple

import jax
import mujoco
import numpy as np
from brax.envs.base import State

from envs.reaching import ReachEnv
from mjxrmp.robots import franka, three_link

#: Batch policy: observations ``(n, obs_size)`` float32 → actions ``(n, dof)``.
BatchPolicy = Callable[[np.ndarray], np.ndarray]


def control_point_segments(robot_name: str) -> tuple[tuple[str, str, int, float], ...]:
    """``(start site, end site, points, radius)`` per control-point segment of ``robot_name``
    (points at fractions ``i/n``, ``i = 1..n``, as in :mod:`mjxrmp.robots`)."""
    if robot_name == "three_link":
        ends = [f"link{i + 1}" for i in range(three_link.NUM_LINKS)] + ["end_effector"]
        return tuple((a, b, three_link.POINTS_PER_LINK, three_link.CONTROL_POINT_RADIUS)
                     for a, b in itertools.pairwise(ends))
    if robot_name == "franka":
        return franka.CONTROL_POINT_SEGMENTS
    raise ValueError(f"robot_name must be 'three_link' or 'franka', got {robot_name!r}")


class Scenes(NamedTuple):
    """``n`` scenes as the environment's ``reset`` samples them (numpy, leading axis ``n``)."""

    q0: np.ndarray
    qd0: np.ndarray
    goal: np.ndarray
    center: np.ndarray
    radius: np.ndarray
    active: np.ndarray


def scenes_of(states: State) -> Scenes:
    """The scenes of a batch of environment states (initial ``q``/``q̇``, goal, obstacles)."""
    obstacles = states.info["obstacles"]
    return Scenes(*(np.asarray(x) for x in (
        states.pipeline_state.qpos, states.pipeline_state.qvel, states.info["goal"],
        obstacles.center, obstacles.radius, obstacles.active)))


def sample_scenes(env: ReachEnv, num_scenes: int, seed: int = 0) -> Scenes:
    """The scenes of :func:`envs.evaluate.make_rollout` ``(num_scenes, ...)(PRNGKey(seed))``:
    ``env.reset`` of the keys ``split(PRNGKey(seed), num_scenes)``."""
    keys = jax.random.split(jax.random.PRNGKey(seed), num_scenes)
    return scenes_of(jax.jit(jax.vmap(env.reset))(keys))


class MujocoScenes:
    """``n`` scenes of ``env`` in MuJoCo C, stepped in lockstep (see the module docstring)."""

    def __init__(self, env: ReachEnv, scenes: Scenes):
        if env.observation_variant != "default":
            raise ValueError(f"MujocoScenes supports the 'default' observation, got "
                             f"env.observation_variant={env.observation_variant!r}")
        self.env, self.model = env, env.mj_model
        r = env.robot
        self.dof, self.dim = r.dof, r.workspace_dim
        self.lo, self.hi = np.asarray(r.q_lower), np.asarray(r.q_upper)
        self.qd_max = np.asarray(r.qd_max)
        segs = control_point_segments(r.name)
        site = {self.model.site(i).name: i for i in range(self.model.nsite)}
        self.cp_start = np.array([site[a] for a, _, n, _ in segs for _ in range(n)])
        self.cp_end = np.array([site[b] for _, b, n, _ in segs for _ in range(n)])
        self.cp_t = np.concatenate([np.arange(1, n + 1) / n for _, _, n, _ in segs])[:, None]
        self.cp_radius = np.array([rad for _, _, n, rad in segs for _ in range(n)])
        self.ee_site = site["end_effector"]
        self.scenes = Scenes(*(np.asarray(x, np.float64) for x in scenes))
        self.active = self.scenes.active > 0
        n = self.scenes.q0.shape[0]
        self.data = [mujoco.MjData(self.model) for _ in range(n)]
        for d, q0, qd0 in zip(self.data, self.scenes.q0, self.scenes.qd0, strict=True):
            d.qpos[:], d.qvel[:], d.ctrl[:] = q0, qd0, np.concatenate([q0, qd0])
            mujoco.mj_kinematics(self.model, d)
        self.qv = self.scenes.qd0.copy()
        self.done = np.zeros(n, bool)
        self.stats = {k: np.zeros(n) for k in ("return", "length", "collided", "nonfinite")}
        self.goal_distance = self._goal_distance(self._points()[1])

    # ------------------------------------------------------------------ geometry
    def _points(self) -> tuple[np.ndarray, np.ndarray]:
        """Control points ``(n, P, dim)`` and end effector ``(n, dim)`` from the site positions."""
        sites = np.stack([d.site_xpos for d in self.data])[..., : self.dim]
        start, end = sites[:, self.cp_start], sites[:, self.cp_end]
        return start + self.cp_t * (end - start), sites[:, self.ee_site]

    def _goal_distance(self, ee: np.ndarray) -> np.ndarray:
        return np.linalg.norm(ee - self.scenes.goal, axis=-1)

    def _diff(self, cps: np.ndarray) -> np.ndarray:
        """Point → obstacle-centre differences ``(n, P, O, dim)``, z zeroed for cylinders."""
        diff = cps[:, :, None, :] - self.scenes.center[:, None, :, :]
        if self.env.obstacle_shape == "cylinder":
            diff[..., 2:] = 0.0
        return diff

    def _surface(self, diff: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        norm = np.linalg.norm(diff, axis=-1)
        return norm - self.cp_radius[None, :, None] - self.scenes.radius[:, None, :], norm

    def obstacle_distances(self, cps: np.ndarray) -> np.ndarray:
        """Smallest exact surface distance per obstacle ``(n, O)`` (``inf`` if inactive)."""
        d = self._surface(self._diff(cps))[0].min(axis=1)
        return np.where(self.active, d, np.inf)

    def observe(self) -> np.ndarray:
        """The observations ``(n, obs_size)`` float32 (layout of ``env.observation_layout``)."""
        cps, ee = self._points()
        q = np.stack([d.qpos for d in self.data])
        qd = np.stack([d.qvel for d in self.data]) if self.env.measured_velocity else self.qv
        diff = self._diff(cps)
        d, norm = self._surface(diff)
        idx = np.argmin(d, axis=1)[:, None, :]  # closest point per obstacle (n, 1, O)
        d_min = np.take_along_axis(d, idx, 1)[:, 0]
        norm_min = np.take_along_axis(norm, idx, 1)[:, 0]
        unit = np.take_along_axis(diff, idx[..., None], 1)[:, 0] / np.maximum(
            norm_min, 1e-9)[..., None]
        v = np.where(self.active[..., None], d_min[..., None] * unit, 0.0)
        centers = np.where(self.active[..., None], self.scenes.center, 0.0)
        radii = np.where(self.active, self.scenes.radius, -1.0)
        n = q.shape[0]
        obs = np.concatenate([np.sin(q), np.cos(q), qd, self.scenes.goal - ee, v.reshape(n, -1),
                              np.concatenate([centers, radii[..., None]], -1).reshape(n, -1)], 1)
        return np.where(np.isfinite(obs), obs, 0.0).astype(np.float32)

    # ------------------------------------------------------------------ stepping
    def _substep(self, a: np.ndarray, live: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One physics substep of the live scenes; ``(reward, collision)`` per scene."""
        env, dt = self.env, self.env.sim_dt
        q = np.stack([d.qpos for d in self.data])
        q_t = np.clip(q + self.qv * dt, self.lo, self.hi)
        at_limit = (np.isfinite(self.lo) & (q_t <= self.lo)) | (np.isfinite(self.hi)
                                                               & (q_t >= self.hi))
        qd_t = np.clip(np.where(at_limit, 0.0, self.qv + a * dt), -self.qd_max, self.qd_max)
        ctrl = np.concatenate([q_t, qd_t], axis=1)
        for i in np.flatnonzero(live):
            d = self.data[i]
            d.ctrl[:] = ctrl[i]
            mujoco.mj_step(self.model, d)
            mujoco.mj_kinematics(self.model, d)  # sites at the new qpos (mj_step leaves the old)
        self.qv = np.where(live[:, None], qd_t, self.qv)
        cps, ee = self._points()
        d_obs = self.obstacle_distances(cps)
        p = env.reward_params
        effort = np.stack([d.qfrc_actuator for d in self.data])
        r = (np.exp(-0.5 * self._goal_distance(ee) ** 2 / p.goal_sigma**2)
             - np.where(self.active, np.maximum(0.0, 1.0 - d_obs / p.obstacle_delta), 0.0).sum(1)
             - p.effort_weight * (effort**2).sum(1))
        return np.clip(r, p.reward_min, p.reward_max), (self.active & (d_obs < 0.0)).any(1)

    def step(self, actions: np.ndarray) -> None:
        """One control step of every scene not yet done (done scenes stay frozen)."""
        env, live = self.env, ~self.done
        a = np.asarray(actions, np.float32)
        a = np.clip(np.where(np.isfinite(a), a, 0.0), -env.action_limit, env.action_limit)
        rs, cols = zip(*(self._substep(a.astype(np.float64), live) for _ in range(env.substeps)),
                       strict=True)
        rs, cols = np.stack(rs), np.stack(cols)
        before = np.concatenate([np.zeros((1, len(live)), bool), np.cumsum(cols, 0)[:-1] > 0])
        mask = ~before
        reward = (rs * mask).sum(0) / mask.sum(0)
        collided = cols.any(0)
        state = [np.stack([getattr(d, f) for d in self.data]) for f in ("qpos", "qvel")]
        finite = np.all([np.isfinite(x).all(1) for x in (*state, self.qv)], axis=0)
        reward = np.where(finite & np.isfinite(reward), reward, env.reward_min)
        s = self.stats
        s["return"] += np.where(live, reward, 0.0)
        s["length"] += live
        s["collided"] = np.where(live, np.maximum(s["collided"], collided), s["collided"])
        s["nonfinite"] = np.where(live, np.maximum(s["nonfinite"], ~finite), s["nonfinite"])
        self.goal_distance = np.where(live, self._goal_distance(self._points()[1]),
                                      self.goal_distance)
        self.done |= live & (collided | ~finite)

    def results(self) -> dict[str, np.ndarray]:
        """Per-episode statistics, keys as :func:`envs.evaluate.make_rollout`'s."""
        s = self.stats
        safe = (s["collided"] == 0) & (s["nonfinite"] == 0)
        return {"return": s["return"].copy(), "length": s["length"].copy(),
                "safe": safe.astype(np.float64),
                "success": (safe & (self.goal_distance < self.env.success_radius)).astype(float),
                "final_goal_distance": self.goal_distance.copy(),
                "nonfinite": s["nonfinite"].copy()}


def run_episodes(env: ReachEnv, policy: BatchPolicy, scenes: Scenes, horizon: int,
                 on_step: Callable[[int], None] | None = None) -> dict[str, np.ndarray]:
    """Roll ``policy`` out on every scene for ``horizon`` control steps in MuJoCo C (one batch
    policy call per step); per-episode statistics (:meth:`MujocoScenes.results`).
    ``on_step(t)`` is called after step ``t`` (progress)."""
    sim = MujocoScenes(env, scenes)
    for t in range(horizon):
        if sim.done.all():  # every episode is frozen: nothing changes any more
            break
        sim.step(policy(sim.observe()))
        if on_step is not None:
            on_step(t + 1)
    return sim.results()


def _add_geom(scn, kind: int, size, pos, rgba) -> None:
    if scn.ngeom >= scn.maxgeom:
        return
    mujoco.mjv_initGeom(scn.geoms[scn.ngeom], kind, np.asarray(size, float),
                        np.asarray(pos, float), np.eye(3).ravel(), np.asarray(rgba, np.float32))
    scn.ngeom += 1


def decorate(scn: mujoco.MjvScene, sim: MujocoScenes) -> None:
    """Add scene 0's active obstacles (red, translucent; 3-link cylinders 0.3 m tall) and its goal
    (a green ball) to ``scn`` as decoration geoms (the obstacles are not in the model)."""
    s = sim.scenes
    for c, r, a in zip(s.center[0], s.radius[0], sim.active[0], strict=True):
        if a and sim.env.obstacle_shape == "cylinder":
            _add_geom(scn, mujoco.mjtGeom.mjGEOM_CYLINDER, (r, 0.15, 0), (*c[:2], 0.15),
                      (0.8, 0.2, 0.2, 0.6))
        elif a:
            _add_geom(scn, mujoco.mjtGeom.mjGEOM_SPHERE, (r, r, r), c, (0.8, 0.2, 0.2, 0.6))
    goal = np.zeros(3)
    goal[: sim.dim] = s.goal[0]
    _add_geom(scn, mujoco.mjtGeom.mjGEOM_SPHERE, (0.02, 0.02, 0.02), goal, (0.1, 0.8, 0.1, 1))


def require_display() -> None:
    """``RuntimeError`` on Linux when no display is set (``DISPLAY``/``WAYLAND_DISPLAY``)."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                 or os.environ.get("WAYLAND_DISPLAY")):
        raise RuntimeError("--viewer needs a display: neither DISPLAY nor WAYLAND_DISPLAY is set")


def view_scene(env: ReachEnv, policy: BatchPolicy, scenes: Scenes, horizon: int) -> None:
    """Show the first scene of ``scenes`` under ``policy`` in ``mujoco.viewer.launch_passive``
    in real time (obstacles and goal drawn as decoration geoms). ``RuntimeError`` without a
    display."""
    require_display()
    import mujoco.viewer  # lazy: opens a window (GLFW); only --viewer needs it

    sim = MujocoScenes(env, Scenes(*(x[:1] for x in scenes)))
    with mujoco.viewer.launch_passive(sim.model, sim.data[0]) as viewer:
        decorate(viewer.user_scn, sim)
        for _ in range(horizon):
            if not viewer.is_running() or sim.done[0]:
                break
            t0 = time.perf_counter()
            sim.step(policy(sim.observe()))
            viewer.sync()
            time.sleep(max(0.0, env.dt - (time.perf_counter() - t0)))


__all__ = [
    "BatchPolicy",
    "MujocoScenes",
    "Scenes",
    "control_point_segments",
    "decorate",
    "require_display",
    "run_episodes",
    "sample_scenes",
    "scenes_of",
    "view_scene",
]
