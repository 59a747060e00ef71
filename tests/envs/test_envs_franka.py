"""Franka reaching environment: sizes, sampler rules, MJX/JAX kinematics, brax wrap, policy.

One compiled rollout (batch 2, 30 steps, hand-designed policy) is shared by several tests.
"""

from __future__ import annotations

import brax.envs
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.wrappers import training as brax_training
from mujoco import mjx

import envs
from envs import evaluate, samplers
from envs.franka import FrankaReach
from mjxrmp.geometry import Obstacles
from mjxrmp.robots import franka, mjcf

ENV = envs.make("franka")
POLICY = evaluate.hand_designed_policy(ENV)
SITES = mjcf.site_names("franka")
SITE_ID = {name: ENV.mj_model.site(name).id for name in SITES}


@jax.jit
def _rollout(key):
    state = jax.vmap(ENV.reset)(jax.random.split(key, 2))

    def body(s, _):
        s = jax.vmap(ENV.step)(s, jax.vmap(POLICY)(s))
        kin = jax.vmap(lambda d: mjx.kinematics(ENV.mjx_model, d))(s.pipeline_state)
        return s, (s.pipeline_state.qpos, kin.site_xpos, s.obs, s.reward, s.done)

    return jax.lax.scan(body, state, None, length=30)


@pytest.fixture(scope="module")
def rollout():
    return jax.block_until_ready(_rollout(jax.random.PRNGKey(0)))


def test_sizes_and_lookup():
    assert ENV.observation_size == 45 and ENV.action_size == 7
    assert envs.make("franka", observation="residual_rmp").observation_size == 54
    assert isinstance(brax.envs.get_environment("franka_reach"), FrankaReach)
    layout = ENV.observation_layout()
    assert layout["obstacle_vectors"] == slice(24, 33) and layout["obstacles"] == slice(33, 45)


def test_policy_rollout_is_finite_and_tracks(rollout):
    state, (_, _, obs, reward, _done) = rollout
    assert np.all(np.isfinite(np.asarray(obs))) and np.all(np.isfinite(np.asarray(reward)))
    assert float(jnp.max(state.metrics["nonfinite"])) == 0.0
    assert float(jnp.max(state.metrics["tracking_error"])) < 0.05
    assert obs.shape == (30, 2, 45)


def test_jax_kinematics_matches_mjx_sites(rollout):
    _, (qpos, site_xpos, *_) = rollout
    q = jnp.asarray(qpos).reshape(-1, 7)
    sites = np.asarray(site_xpos).reshape(q.shape[0], ENV.mj_model.nsite, 3)
    ee = np.asarray(jax.vmap(franka.end_effector)(q))
    np.testing.assert_allclose(sites[:, SITE_ID["end_effector"]], ee, atol=5e-5)
    frames = jax.vmap(franka.link_frames)(q)
    for name in ("link3", "link5", "link8", "left_fingertip"):
        np.testing.assert_allclose(sites[:, SITE_ID[name]], np.asarray(frames[name][1]),
                                   atol=5e-5)


def test_sampler_rules():
    # 2,000 scenes: the rules hold for every one (10,000 took 25 CPU s of rejection sampling)
    keys = jax.random.split(jax.random.PRNGKey(1), 2_000)
    q0, qd0, goal, obs, ok = jax.jit(jax.vmap(ENV.sample_scene))(keys)
    assert float(jnp.mean(ok)) == 1.0
    default = np.asarray(franka.DEFAULT_Q)
    assert np.all(np.abs(np.asarray(q0) - default) <= 0.1 + 1e-6)
    assert np.all(np.abs(np.asarray(qd0)) <= 0.005)
    c, r, goal = np.asarray(obs.center), np.asarray(obs.radius), np.asarray(goal)
    assert c.shape == (2_000, 3, 3)
    for p in (goal, c.reshape(-1, 3)):
        rho = np.hypot(p[:, 0], p[:, 1])
        assert np.all((rho - 0.5) ** 2 + (p[:, 2] - 0.5) ** 2 <= 0.09 + 1e-5)
        assert np.all(p[:, 0] >= -1e-6)  # front half
    assert np.all((r >= 0.05) & (r <= 0.1))
    assert np.all(np.linalg.norm(goal[:, None] - c, axis=-1) - r >= 0.1 - 1e-5)
    ee0 = np.asarray(jax.jit(jax.vmap(franka.end_effector))(q0))
    assert np.all(np.linalg.norm(goal - ee0, axis=-1) >= 0.5 - 1e-5)
    pts = np.asarray(jax.jit(jax.vmap(franka.control_points))(q0))
    radii = np.asarray(franka.CONTROL_POINT_RADII)
    d = np.linalg.norm(pts[:, :, None] - c[:, None], axis=-1) - radii[None, :, None] - r[:, None]
    assert np.all(d >= 0.1 - 1e-5)


def test_half_torus_sampler_is_volume_uniform():
    pts, ok = jax.jit(lambda k: samplers.half_torus_volume_uniform(k, (20_000,), 0.5, 0.3, 0.5))(
        jax.random.PRNGKey(2))
    assert float(jnp.mean(ok)) > 0.999
    p = np.asarray(pts)[np.asarray(ok)]
    assert bool(np.all(np.asarray(samplers.in_half_torus(jnp.asarray(p), 0.5, 0.3, 0.5))))
    rho = np.hypot(p[:, 0], p[:, 1])
    # Volume-uniform: the mean distance from the axis is R + r²/(4R) = 0.545 (Pappus), not R.
    assert abs(rho.mean() - 0.545) < 0.005


def test_collision_distances_match_bruteforce_numpy():
    rng = np.random.default_rng(0)
    qs = rng.uniform(franka.Q_LOWER, franka.Q_UPPER, (50, 7)).astype(np.float32)
    c = rng.uniform([-0.2, -0.5, 0.0], [0.8, 0.5, 1.0], (50, 3, 3)).astype(np.float32)
    r = rng.uniform(0.05, 0.1, (50, 3)).astype(np.float32)
    d = jax.jit(jax.vmap(lambda q, c_, r_: ENV.distances(q, Obstacles(c_, r_, jnp.ones(3)))))(
        qs, c, r)
    pts = np.asarray(jax.jit(jax.vmap(franka.control_points))(qs)).astype(np.float64)
    radii = np.asarray(franka.CONTROL_POINT_RADII)
    hits = 0
    for i in range(50):
        ref = np.empty((48, 3))
        for p in range(48):
            for o in range(3):
                ref[p, o] = np.sqrt(np.sum((pts[i, p] - c[i, o]) ** 2)) - radii[p] - r[i, o]
        np.testing.assert_allclose(np.asarray(d[i]), ref, atol=1e-5)
        hits += int((ref < 0).any())
    assert 0 < hits < 50


@pytest.mark.slow(reason="brax's training wrap is robot-independent: "
                  "tests/envs/test_envs.py::test_brax_training_wrap_runs_unchanged makes the "
                  "same checks on the 3-link; the Franka reset and step run in the shared rollout")
def test_brax_training_wrap_runs_unchanged():
    env = brax_training.wrap(envs.make("franka"), episode_length=3)
    state = jax.jit(env.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
    step = jax.jit(env.step)
    for _ in range(4):
        state = step(state, jnp.zeros((2, 7)))
    assert state.obs.shape == (2, 45) and np.all(np.isfinite(np.asarray(state.obs)))
