"""Planar 3-link reaching environments, samplers, wrappers, registry, the point robot, the
shared reward and bookkeeping, and GIF rendering.

Compiled functions are built once per module (module-level ``jax.jit`` or module fixtures) and
batches are tiny, so the file runs in well under a minute on 2 CPU cores.
"""

from __future__ import annotations

import math

import brax.envs
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.wrappers import training as brax_training
from mujoco import mjx

import envs
from envs import base, evaluate, render, samplers
from envs.three_link import ThreeLinkReach
from envs.wrappers import RMPInEnv, wrap
from mjxrmp import policies
from mjxrmp.geometry import Obstacles
from mjxrmp.robots import three_link

ENV = envs.make("three_link/env3")
POLICY = evaluate.hand_designed_policy(ENV)
N_SAMPLES = 10_000


def _rollout(env, policy, batch: int, steps: int):
    """Jitted ``key -> (final state, per-step (qpos, ee site, done, reward, obs))``."""
    ee_site = env.mj_model.site("end_effector").id

    def run(key):
        state = jax.vmap(env.reset)(jax.random.split(key, batch))

        def body(s, _):
            s = jax.vmap(env.step)(s, jax.vmap(policy)(s))
            kin = jax.vmap(lambda d: mjx.kinematics(env.mjx_model, d))(s.pipeline_state)
            return s, (s.pipeline_state.qpos, kin.site_xpos[:, ee_site], kin.site_xpos, s.done,
                       s.reward, s.obs)

        return jax.lax.scan(body, state, None, length=steps)

    return jax.jit(run)


ROLLOUT = _rollout(ENV, POLICY, batch=3, steps=40)
#: One environment's reset and step, compiled once for the tests below.
RESET, STEP = jax.jit(ENV.reset), jax.jit(ENV.step)


@pytest.fixture(scope="module")
def rollout_a():
    return jax.block_until_ready(ROLLOUT(jax.random.PRNGKey(7)))


# ------------------------------------------------------------------------- API and layout


def test_observation_sizes_and_layout():
    sizes = {"three_link/env1": 26, "three_link/env2": 26, "three_link/env3": 26, "env1/1": 16}
    for name, size in sizes.items():
        env = (envs.make("three_link/env1", num_obstacles=1) if name == "env1/1"
               else envs.make(name))
        assert env.observation_size == size
        assert env.action_size == 3 and env.backend == "mjx"
        layout = env.observation_layout()
        assert list(layout) == ["sin_q", "cos_q", "qd", "goal_minus_x", "obstacle_vectors",
                                "obstacles"]
        stops = [sl.stop for sl in layout.values()]
        starts = [sl.start for sl in layout.values()]
        assert starts == [0, *stops[:-1]] and stops[-1] == size
    residual = envs.make("three_link/env3", observation="residual_rmp")
    assert residual.observation_size == 32
    assert list(residual.observation_layout())[-3:] == ["goal", "ee_position", "ee_velocity"]
    assert ENV.dt == pytest.approx(1 / 80) and ENV.horizon == 600


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match=r"ThreeLinkReach\.obstacle_sampler"):
        envs.make("three_link/env3", obstacle_sampler="nope")
    with pytest.raises(ValueError, match=r"ThreeLinkReach\.observation"):
        envs.make("three_link/env3", observation="nope")
    with pytest.raises(ValueError, match=r"ThreeLinkReach\.num_obstacles"):
        envs.make("three_link/env2", num_obstacles=0)
    with pytest.raises(ValueError, match=r"PointRobot2D\.action_limit"):
        envs.make("point2d", action_limit=-1.0)
    with pytest.raises(ValueError, match="unknown environment"):
        envs.make("three_link/env9")


def test_bad_actions_fail_before_tracing_and_nan_never_reaches_the_state():
    state = RESET(jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match=r"action must have shape \(3,\)"):
        ENV.step(state, jnp.zeros(4))
    with pytest.raises(ValueError, match=r"jax\.vmap"):
        ENV.step(state, jnp.zeros((2, 3)))
    with pytest.raises(TypeError, match="floating-point"):
        ENV.step(state, jnp.zeros(3, jnp.int32))
    with pytest.raises(TypeError, match="array"):
        ENV.step(state, [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"\(6,\)"):
        RMPInEnv(ENV).step(state, jnp.zeros(3))
    out = STEP(state, jnp.array([jnp.nan, jnp.inf, -jnp.inf]))
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(out.pipeline_state)
               if jnp.issubdtype(x.dtype, jnp.floating))
    assert bool(jnp.all(jnp.isfinite(out.obs))) and float(out.metrics["nonfinite"]) == 0.0


def test_registry_and_brax_lookup():
    assert isinstance(envs.make("three_link/env3"), ThreeLinkReach)
    for brax_name, name in envs.BRAX_NAMES.items():
        assert brax_name.isidentifier()
        env = brax.envs.get_environment(brax_name)
        assert type(env) is type(envs.make(name))
    assert brax.envs.get_environment("three_link_env1").setup == "env1"


# ------------------------------------------------------------------------- reset / step


def test_reset_step_jit_vmap(rollout_a):
    state, (qpos, _, _, done, reward, obs) = rollout_a
    assert qpos.shape == (40, 3, 3) and obs.shape == (40, 3, 26)
    assert reward.shape == (40, 3) and done.shape == (40, 3)
    assert np.all(np.isfinite(np.asarray(obs))) and np.all(np.isfinite(np.asarray(reward)))
    assert np.all((np.asarray(reward) >= -5.0) & (np.asarray(reward) <= 1.0))
    assert state.obs.shape == (3, 26) and ENV.virtual_velocity(state).shape == (3, 3)
    for key in ("goal_distance", "success", "collision", "nonfinite", "min_obstacle_distance",
                "tracking_error"):
        assert state.metrics[key].shape == (3,)
    assert np.all(np.asarray(state.info["episode_length"]) == 40)


def test_identical_seeds_identical_rollouts(rollout_a):
    again = ROLLOUT(jax.random.PRNGKey(7))
    for a, b in zip(jax.tree.leaves(rollout_a), jax.tree.leaves(again), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    other = ROLLOUT(jax.random.PRNGKey(8))
    assert not np.allclose(np.asarray(other[0].info["goal"]), np.asarray(rollout_a[0].info["goal"]))


def test_jax_kinematics_matches_mjx_sites(rollout_a):
    _, (qpos, ee_site, sites, _, _, _) = rollout_a
    q = jnp.asarray(qpos).reshape(-1, 3)
    ee = jax.vmap(three_link.end_effector)(q)
    np.testing.assert_allclose(np.asarray(ee_site).reshape(-1, 3)[:, :2], np.asarray(ee),
                               atol=2e-5)
    joints = jax.vmap(three_link.joint_positions)(q)  # (n, 4, 2): base, joint 2, joint 3, tip
    sites = np.asarray(sites).reshape(-1, ENV.mj_model.nsite, 3)
    for i in range(3):
        np.testing.assert_allclose(sites[:, ENV.mj_model.site(f"link{i + 1}").id, :2],
                                   np.asarray(joints[:, i]), atol=2e-5)


def test_tracking_is_tight(rollout_a):
    state = rollout_a[0]
    assert float(jnp.max(state.metrics["tracking_error"])) < 0.02


def test_nonfinite_state_is_flagged_and_ends_episode():
    state = RESET(jax.random.PRNGKey(0))
    bad = state.replace(pipeline_state=state.pipeline_state.replace(
        qpos=jnp.full((3,), jnp.nan)))
    out = STEP(bad, jnp.zeros(3))
    assert float(out.done) == 1.0 and float(out.metrics["nonfinite"]) == 1.0
    assert float(out.reward) == -5.0 and bool(jnp.all(jnp.isfinite(out.obs)))


# ------------------------------------------------------------------------- collision checks


def _numpy_control_points(q: np.ndarray) -> np.ndarray:
    pts, p, angle = [], np.zeros(2), 0.0
    for qi in q:
        angle += qi
        end = p + 0.25 * np.array([math.cos(angle), math.sin(angle)])
        for k in range(1, 6):
            pts.append(p + (k / 5) * (end - p))
        p = end
    return np.array(pts)


def test_collision_detection_matches_bruteforce_numpy():
    rng = np.random.default_rng(3)
    n = 200
    qs = rng.uniform(-math.pi, math.pi, (n, 3)).astype(np.float32)
    centers = rng.uniform(-0.8, 0.8, (n, 3, 2)).astype(np.float32)
    radii = rng.uniform(0.05, 0.1, (n, 3)).astype(np.float32)

    def flags(q, c, r):
        d = ENV.distances(q, Obstacles(c, r, jnp.ones(3)))
        return jnp.min(d, axis=0), jnp.any(d < 0)

    d_min, hit = jax.jit(jax.vmap(flags))(qs, centers, radii)
    hits = 0
    for i in range(n):
        pts = _numpy_control_points(qs[i].astype(np.float64))
        dist = np.array([[np.linalg.norm(p - c) - 0.025 - r for c, r in
                          zip(centers[i], radii[i], strict=True)] for p in pts])
        np.testing.assert_allclose(np.asarray(d_min[i]), dist.min(axis=0), atol=1e-5)
        margin = np.abs(dist).min()
        if margin > 1e-5:
            assert bool(hit[i]) == bool((dist < 0).any())
        hits += int((dist < 0).any())
    assert 10 < hits < n - 10  # both outcomes are exercised


def test_step_terminates_on_collision():
    state = RESET(jax.random.PRNGKey(1))
    q = state.pipeline_state.qpos
    tip = three_link.end_effector(q)
    obstacles = Obstacles(jnp.stack([tip, tip + 5.0, tip + 6.0]), jnp.full((3,), 0.05),
                          jnp.ones(3))
    info = dict(state.info, obstacles=obstacles)
    out = STEP(state.replace(info=info), jnp.zeros(3))
    assert float(out.done) == 1.0 and float(out.metrics["collision"]) == 1.0
    assert float(out.info["episode_collided"]) == 1.0
    assert float(out.reward) < 0.0


# ------------------------------------------------------------------------- samplers


def _in_sector(p: np.ndarray, r_min, r_max, center, width) -> np.ndarray:
    r = np.linalg.norm(p, axis=-1)
    ang = np.arctan2(p[..., 1], p[..., 0])
    dang = np.abs((ang - center + np.pi) % (2 * np.pi) - np.pi)
    return (r >= r_min - 1e-5) & (r <= r_max + 1e-5) & (dang <= width / 2 + 1e-5)


@pytest.mark.parametrize(
    ("setup", "sampler"),
    [("env1", "thesis"), ("env2", "thesis"), ("env3", "thesis"), ("env3", "original")],
)
def test_three_link_sampler_rules(setup, sampler):
    env = envs.make(f"three_link/{setup}", obstacle_sampler=sampler)
    keys = jax.random.split(jax.random.PRNGKey(11), N_SAMPLES)
    q0, qd0, goal, obs, ok = jax.jit(jax.vmap(env.sample_scene))(keys)
    assert float(jnp.mean(ok)) == 1.0
    q0, qd0, goal = np.asarray(q0), np.asarray(qd0), np.asarray(goal)
    n_obs = 1 if setup == "env1" else 3  # active obstacles, the first of three slots
    assert obs.center.shape == (N_SAMPLES, 3, 2)
    assert np.all(np.asarray(obs.active) == (np.arange(3) < n_obs))
    c, r = np.asarray(obs.center)[:, :n_obs], np.asarray(obs.radius)[:, :n_obs]
    assert np.all(np.abs(q0) <= 0.1) and np.all(np.abs(qd0) <= 0.005)
    if setup == "env3":
        assert np.all(_in_sector(goal, 0.125, 0.625, np.pi, np.pi))
    else:
        assert np.all(_in_sector(goal, 0.275, 0.475, np.pi, np.pi / 2))
    assert np.all((r >= 0.05) & (r <= 0.1))
    rc = np.linalg.norm(c, axis=-1)
    lo, hi = (0.4, 0.9) if sampler == "thesis" else (0.4, 0.5)
    assert np.all((rc >= lo - 1e-5) & (rc <= hi + 1e-5))
    # Clearance ≥ 0.1: goal–obstacle and initial robot–obstacle (numpy check).
    assert np.all(np.linalg.norm(goal[:, None] - c, axis=-1) - r >= 0.1 - 1e-5)
    pts = np.asarray(jax.jit(jax.vmap(three_link.control_points))(jnp.asarray(q0)))
    d = np.linalg.norm(pts[:, :, None] - c[:, None], axis=-1) - 0.025 - r[:, None]
    assert np.all(d >= 0.1 - 1e-5)
    # Goals fill their region (not collapsed): angular spread and radial spread.
    assert np.ptp(np.linalg.norm(goal, axis=-1)) > 0.15


def test_first_valid_and_fallback():
    idx, ok = samplers.first_valid(jnp.array([False, True, True]), jnp.array([0.0, 1.0, 2.0]))
    assert int(idx) == 1 and bool(ok)
    idx, ok = samplers.first_valid(jnp.array([False, False]), jnp.array([-3.0, -1.0]))
    assert int(idx) == 1 and not bool(ok)


# ------------------------------------------------------------------------- wrappers


AUTO_ENV = wrap(ENV, episode_length=4)


@jax.jit
def _auto_rollout(key):
    state = AUTO_ENV.reset(jax.random.split(key, 2))

    def body(s, _):
        s = AUTO_ENV.step(s, jnp.zeros((2, 3)))
        return s, (s.info["goal"], s.info["obstacles"].center, s.done, s.pipeline_state.qpos,
                   s.info["steps"])

    return state, jax.lax.scan(body, state, None, length=10)


def test_auto_reset_samples_new_goal_and_obstacles():
    first, (_, (goals, centers, done, qpos, steps)) = _auto_rollout(jax.random.PRNGKey(5))
    goals, centers, done = np.asarray(goals), np.asarray(centers), np.asarray(done)
    # Episodes of 4 steps: done at steps 4 and 8 (indices 3 and 7); as in brax, the state
    # returned with done = 1 already holds the freshly reset episode.
    np.testing.assert_array_equal(done[:, 0], [0, 0, 0, 1, 0, 0, 0, 1, 0, 0])
    episodes = [goals[0], goals[3], goals[7]]
    g0 = np.asarray(first.info["goal"])
    np.testing.assert_array_equal(goals[0], g0)
    for b in range(2):
        seen = [tuple(np.round(e[b], 6)) for e in episodes]
        assert len(set(seen)) == 3, seen
        obst = [tuple(np.round(centers[i, b].ravel(), 6)) for i in (0, 3, 7)]
        assert len(set(obst)) == 3
        for i in (1, 2, 4, 5, 6, 8, 9):  # no change within an episode
            np.testing.assert_array_equal(goals[i, b], goals[i - 1, b])
    # The robot restarts near q = 0 and the step counter restarts.
    assert np.all(np.abs(np.asarray(qpos)[3]) < 0.11)
    assert np.asarray(steps)[4, 0] == 1


def test_brax_training_wrap_runs_unchanged():
    env = brax_training.wrap(envs.make("three_link/env3"), episode_length=3)
    state = jax.jit(env.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
    step = jax.jit(env.step)
    for _ in range(4):
        state = step(state, jnp.zeros((2, 3)))
    assert state.obs.shape == (2, 26)
    assert np.all(np.isfinite(np.asarray(state.obs)))
    assert "episode_metrics" in state.info


def test_rmp_in_env_zero_action_is_base_policy():
    env = envs.make("three_link/env3", observation="residual_rmp")
    wrapped = RMPInEnv(env)
    assert wrapped.action_size == 6 and wrapped.observation_size == 32
    state = jax.jit(env.reset)(jax.random.PRNGKey(2))
    acc = jax.jit(wrapped.joint_acceleration)(state, jnp.zeros(6))
    cfg = policies.default_config("three_link", "residual_rmp")
    q, qd, g, o = env.policy_inputs(state)
    ref = jax.jit(policies.acceleration, static_argnums=())(cfg, q, qd, g, o)
    np.testing.assert_allclose(np.asarray(acc), np.asarray(ref), rtol=1e-4, atol=1e-5)
    out = jax.jit(wrapped.step)(state, jnp.ones(6))
    assert bool(jnp.all(jnp.isfinite(out.obs)))
    A_r, a_r = wrapped.squash(jnp.full(6, 100.0))
    np.testing.assert_allclose(np.asarray(A_r), math.sqrt(5.0), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(a_r), 1.0, rtol=1e-6)


# ------------------------------------------------------------------------- policy


def test_hand_designed_policy_keeps_episodes_finite():
    out = evaluate.make_rollout(ENV, num_episodes=4, horizon=120)(jax.random.PRNGKey(3))
    assert float(jnp.max(out["nonfinite"])) == 0.0
    assert bool(jnp.all(jnp.isfinite(out["return"])))
    assert bool(jnp.all(jnp.isfinite(out["final_goal_distance"])))


# ------------------------------------------------------------------------- point robot


def test_point_robot():
    env = envs.make("point2d", num_obstacles=2)
    assert env.observation_size == 16 and env.action_size == 2
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    state = jax.jit(jax.vmap(env.reset))(keys)
    assert state.obs.shape == (4, 16)
    step = jax.jit(jax.vmap(env.step))
    for _ in range(3):
        state = step(state, jnp.ones((4, 2)))
    assert np.all(np.isfinite(np.asarray(state.obs)))
    x, xd = np.asarray(state.pipeline_state.x), np.asarray(state.pipeline_state.xd)
    np.testing.assert_allclose(xd, 0.03, atol=1e-6)
    d = np.linalg.norm(x[:, None] - np.asarray(state.info["obstacles"].center), axis=-1)
    assert np.all(d - np.asarray(state.info["obstacles"].radius) >= 0.09)
    # Put the point inside an obstacle: the next step collides and ends the episode.
    inside = state.replace(pipeline_state=state.pipeline_state._replace(
        x=state.info["obstacles"].center[:, 0], xd=jnp.zeros((4, 2))))
    out = step(inside, jnp.zeros((4, 2)))
    assert np.all(np.asarray(out.done) == 1.0)


# ------------------------------------------------------------------------- shared task pieces


def test_reach_reward_layout_and_episode_bookkeeping():
    p = base.RewardParams()
    d_obs = jnp.array([0.025, 1.0, -0.1])
    active = jnp.array([True, True, False])
    r = base.reach_reward(jnp.asarray(0.1), d_obs, active, jnp.array([100.0]), p)
    want = math.exp(-0.5) - 0.5 - 1e-5 * 100.0**2
    assert float(r) == pytest.approx(want, abs=1e-6)
    assert float(base.reach_reward(jnp.asarray(0.0), jnp.array([0.0]), jnp.array([True]),
                                   jnp.zeros(1), p)) == 0.0
    assert float(base.reach_reward(jnp.asarray(9.0), -jnp.ones(9), jnp.ones(9, bool),
                                   jnp.zeros(1), p)) == p.reward_min
    assert base.layout([("a", 2), ("b", 0), ("c", 3)]) == {
        "a": slice(0, 2), "b": slice(2, 2), "c": slice(2, 5)}
    info = base.episode_info(track_nonfinite=False)
    info = base.accumulate_episode(info, jnp.asarray(0.5), jnp.asarray(1.0), jnp.asarray(1.0))
    info = base.accumulate_episode(info, jnp.asarray(0.25), jnp.asarray(0.0), jnp.asarray(0.0))
    assert {k: float(v) for k, v in info.items()} == {
        "episode_return": 0.75, "episode_length": 2.0, "episode_collided": 1.0}
    np.testing.assert_array_equal(
        base.clean_action(jnp.array([jnp.nan, 3.0, -0.5]), 1.0), [0.0, 1.0, -0.5])


# ------------------------------------------------------------------------- render


def test_render_gif_of_a_three_link_trajectory(tmp_path):
    q = np.linspace(0.0, 1.0, 7)[:, None] * np.array([[1.0, -0.5, 0.25]])
    data = {"q": q, "done": np.zeros(7), "goal_distance": np.linspace(0.5, 0.1, 7),
            "goal": np.array([-0.3, 0.2]), "centers": np.array([[0.5, 0.5]]),
            "radii": np.array([0.1]), "return": 0.0}
    path = tmp_path / "three_link.gif"
    assert render.save_gif(data, "three_link", str(path), every=2, fps=5) == 4
    assert path.stat().st_size > 0
    with pytest.raises(ValueError, match="3-link and Franka"):
        render.animate(data, "point2d")
