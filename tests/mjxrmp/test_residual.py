"""The residual RMP policy split into state-only parts and the learned leaf (mjxrmp.residual):
in float64 it equals the whole-tree formulation (mjxrmp.policies.residual_rmp_acceleration)
for random states, obstacles and network outputs, on both robots; the PPO policy module gives
the same mean and the same parameter gradient with precomputed parts as without."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import envs
from agents.ppo.policies import make_policy
from mjxrmp import policies
from mjxrmp.geometry import Obstacles
from mjxrmp.residual import ResidualParts, residual_from_parts, residual_parts
from mjxrmp.robots import get


def _case(robot: str, seed: int):
    r = get(robot)
    d, m = r.dof, r.workspace_dim
    k = jax.random.split(jax.random.PRNGKey(seed), 6)
    q = 0.5 * jax.random.uniform(k[0], (d,), jnp.float64, -1.0, 1.0)
    qd = 0.5 * jax.random.normal(k[1], (d,), jnp.float64)
    goal = r.end_effector(q) + 0.3 * jax.random.normal(k[2], (m,), jnp.float64)
    obstacles = Obstacles(1.0 + jax.random.normal(k[3], (3, m), jnp.float64),
                          jnp.full((3,), 0.1, jnp.float64), jnp.array([1.0, 1.0, 0.0]))
    A_r = jnp.sqrt(5.0) * jnp.tanh(jax.random.normal(k[4], (m, m), jnp.float64))
    a_r = jnp.tanh(jax.random.normal(k[5], (m,), jnp.float64))
    return q, qd, goal, obstacles, A_r, a_r


def _reset_obs(env, seed: int, n: int) -> jax.Array:
    """Observations of ``n`` fresh episodes (the reset compiled once, not run op by op)."""
    return jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(seed), n)).obs


@jax.jit
def _both(cfg, q, qd, goal, obstacles, A_r, a_r):
    ref = policies.residual_rmp_acceleration(cfg, q, qd, goal, obstacles, A_r, a_r)
    return ref, residual_from_parts(residual_parts(cfg, q, qd, goal, obstacles), A_r, a_r)


@settings(max_examples=12, deadline=None)
@given(robot=st.sampled_from(["three_link", "franka"]), seed=st.integers(0, 2**16))
def test_parts_plus_learned_leaf_equal_the_whole_tree_in_float64(robot, seed):
    with jax.enable_x64(True):
        cfg = policies.default_config(robot, "residual_rmp")
        q, qd, goal, obstacles, A_r, a_r = _case(robot, seed)
        ref, got = _both(cfg, q, qd, goal, obstacles, A_r, a_r)
        assert got.dtype == jnp.float64
        np.testing.assert_allclose(got, ref, rtol=1e-10,
                                   atol=1e-10 * float(jnp.max(jnp.abs(ref))))


def test_parts_need_a_target_leaf():
    cfg = policies.default_config("three_link", "hand_designed")
    q, qd, goal, obstacles, _, _ = _case("three_link", 0)
    with pytest.raises(ValueError, match="target leaf"):
        residual_parts(cfg.__class__(**{**cfg.__dict__, "target": None}), q, qd, goal,
                       obstacles)


@pytest.mark.parametrize("env_name", ["three_link/env3"])
def test_policy_with_precomputed_parts_matches_and_differentiates_alike(env_name):
    """RMPResidualPolicy: mean and the gradient of a loss in the parameters agree (float32)
    with and without precomputed parts, for a batch of real observations."""
    env = envs.make(env_name)
    module = make_policy("rmp_residual", env)
    obs = _reset_obs(env, 0, 6)
    params = jax.jit(module.init)(jax.random.PRNGKey(1), obs)
    params = jax.tree.map(lambda p: p + 0.1 * jnp.ones_like(p), params)  # leave the init
    feats = jax.jit(module.precompute)(obs)

    def loss(p, f):
        mean, _ = module.apply(p, obs, None, f)
        return jnp.sum(jnp.sin(mean))

    # each path jitted on its own (op by op, the RMP² tree took 20 s to dispatch)
    np.testing.assert_allclose(jax.jit(lambda p, f: module.apply(p, obs, None, f)[0])(
        params, feats), jax.jit(lambda p: module.apply(p, obs)[0])(params), rtol=1e-5, atol=1e-5)
    g_with = jax.jit(jax.grad(loss))(params, feats)
    g_without = jax.jit(jax.grad(lambda p: loss(p, None)))(params)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5),
                 g_with, g_without)


def test_a_batch_axis_of_one_leaves_the_gradient_unchanged():
    """The learned leaf's gradient over 1,024 states, in a program with a leading batch axis of
    size 1 (a one-seed run's seeds axis), equals the gradient without that axis and, for the
    first state, central differences in float64. With jaxlib 0.10's YNNPACK reduction fusions
    (mjxrmp._xla.YNN_FLAG) the batched gradient was off by up to its own size."""
    n, m, d = 1024, 2, 3
    k = jax.random.split(jax.random.PRNGKey(0), 8)
    L = jax.random.normal(k[0], (n, d, d))
    parts = ResidualParts(L @ jnp.swapaxes(L, 1, 2) + jnp.eye(d), jax.random.normal(k[1], (n, d)),
                          jax.random.normal(k[2], (n, m, d)), jax.random.normal(k[3], (n, m)),
                          jnp.tril(jax.random.normal(k[4], (n, m, m))),
                          jax.random.normal(k[5], (n, m)))
    A_r, a_r = 0.3 * jax.random.normal(k[6], (n, m, m)), jax.random.normal(k[7], (n, m))

    def loss(A, a):
        return jnp.sum(jnp.sin(jax.vmap(residual_from_parts)(parts, A, a)))

    plain = jax.jit(jax.grad(loss, (0, 1)))(A_r, a_r)
    batched = jax.jit(jax.vmap(jax.grad(loss, (0, 1))))(A_r[None], a_r[None])
    for b, p in zip(batched, plain, strict=True):
        np.testing.assert_allclose(b[0], p, rtol=1e-4, atol=1e-4)
    i = 0
    one = jax.tree.map(lambda x: np.asarray(x[i], np.float64), parts)
    f = lambda A: float(jnp.sum(jnp.sin(residual_from_parts(one, A, a_r[i]))))  # noqa: E731
    eps, A0 = 1e-3, np.asarray(A_r[i], np.float64)
    with jax.enable_x64(True):
        central = np.array([(f(A0 + e) - f(A0 - e)) / (2 * eps)
                            for e in eps * np.eye(m * m).reshape(m * m, m, m)]).reshape(m, m)
    np.testing.assert_allclose(batched[0][0, i], central, rtol=1e-3, atol=1e-3)


@pytest.mark.parametrize("kind", ["nn_residual", "hand_designed"])
def test_other_policies_with_a_precomputed_base_match(kind):
    """The policies whose hand-designed part is an additive acceleration precompute it too
    (the same arithmetic in two programs: XLA may contract the resolve's products differently,
    so float32 rounding, not bits)."""
    env = envs.make("three_link/env3")
    module = make_policy(kind, env)
    obs = _reset_obs(env, 2, 5)
    params = jax.jit(module.init)(jax.random.PRNGKey(3), obs)
    base = jax.jit(module.precompute)(obs)
    np.testing.assert_allclose(jax.jit(lambda p, b: module.apply(p, obs, None, b)[0])(
        params, base), jax.jit(lambda p: module.apply(p, obs)[0])(params), rtol=1e-6, atol=1e-6)

