"""The naive per-subtask baseline agrees with RMP² (float64)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxrmp import RMP, policies
from mjxrmp.core import rmp2
from mjxrmp.core.naive import acceleration_naive
from mjxrmp.geometry import make_obstacles
from mjxrmp.robots import get

D = 4
_RNG = np.random.default_rng(42)
W_POINTS = _RNG.normal(size=(3, 3, D))
W_SCALARS = _RNG.normal(size=(4, D))


def small_map(q, gain):
    """Two families: 3 points in 3-D (nonlinear in q) and 4 scalars."""
    w_p, w_s = jnp.asarray(W_POINTS, q.dtype), jnp.asarray(W_SCALARS, q.dtype)
    points = jnp.sin(w_p @ q) * jnp.cos(q[1:4])[None, :] + gain * q[0] * q[2]
    scalars = (jnp.tanh(w_s @ q) + gain * jnp.sum(q**2))[:, None]
    return {"points": points, "scalars": scalars}


def small_leaves(x, xd, gain):
    """State-dependent SPD metrics and forces."""
    out = {}
    for name, xk in x.items():
        vk = xd[name]
        A = jnp.tanh(xk[:, :, None] + 0.5 * vk[:, None, :])
        M = A @ jnp.swapaxes(A, 1, 2) + (0.2 + gain) * jnp.eye(xk.shape[1])
        out[name] = RMP(M, jnp.cos(2.0 * xk) - 1.5 * vk * (1.0 + gain))
    return out


def rel_err(a, b):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300)


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


@pytest.mark.parametrize("unroll", [False, True])
def test_small_map_matches_rmp2(x64, unroll):
    ref_fn = jax.jit(lambda q, qd: rmp2.acceleration(small_map, small_leaves, q, qd, 0.3))
    naive_fn = jax.jit(
        lambda q, qd: acceleration_naive(small_map, small_leaves, q, qd, 0.3, unroll=unroll)
    )
    rng = np.random.default_rng(0)
    for _ in range(3):
        q, qd = jnp.asarray(rng.normal(size=D)), jnp.asarray(rng.normal(size=D))
        ref, out = ref_fn(q, qd), naive_fn(q, qd)
        assert out.dtype == jnp.float64
        assert rel_err(out, ref) <= 1e-5


def _policy_inputs(robot_name, n, seed):
    robot = get(robot_name)
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(robot.q_lower), robot.q_lower, -np.pi)
    hi = np.where(np.isfinite(robot.q_upper), robot.q_upper, np.pi)
    dim = robot.workspace_dim
    q = rng.uniform(lo, hi, size=(n, robot.dof))
    qd = rng.uniform(-1.0, 1.0, size=(n, robot.dof))
    if dim == 2:
        goal = rng.uniform(-0.6, 0.6, size=(n, 2))
        centers = rng.uniform(-0.7, 0.7, size=(n, 3, 2))
    else:
        goal = rng.uniform([0.3, -0.4, 0.2], [0.7, 0.4, 0.7], size=(n, 3))
        centers = rng.uniform([0.2, -0.5, 0.0], [0.8, 0.5, 0.8], size=(n, 3, 3))
    radii = rng.uniform(0.05, 0.15, size=(n, 3))
    obs = [make_obstacles(jnp.asarray(c), jnp.asarray(r)) for c, r in zip(centers, radii,
                                                                           strict=True)]
    return [(jnp.asarray(q[i]), jnp.asarray(qd[i]), jnp.asarray(goal[i]), obs[i])
            for i in range(n)]


def _compare_policy(robot_name, n, seed):
    cfg = policies.default_config(robot_name)
    naive = jax.jit(lambda q, qd, goal, obs: acceleration_naive(
        policies.task_map, policies.leaf_rmps, q, qd, goal, obs, cfg))
    ref = jax.jit(lambda q, qd, goal, obs: policies.acceleration(cfg, q, qd, goal, obs))
    for args in _policy_inputs(robot_name, n, seed):
        a, b = naive(*args), ref(*args)
        assert np.all(np.isfinite(np.asarray(b)))
        assert rel_err(a, b) <= 1e-5


def test_three_link_policy_matches_rmp2(x64):
    _compare_policy("three_link", 4, seed=1)


def test_three_link_policy_matches_rmp2_under_vmap(x64):
    cfg = policies.default_config("three_link")
    inputs = _policy_inputs("three_link", 3, seed=2)
    batch = jax.tree.map(lambda *a: jnp.stack(a), *inputs)
    naive = jax.jit(jax.vmap(lambda q, qd, goal, obs: acceleration_naive(
        policies.task_map, policies.leaf_rmps, q, qd, goal, obs, cfg)))(*batch)
    ref = jax.jit(jax.vmap(
        lambda q, qd, goal, obs: policies.acceleration(cfg, q, qd, goal, obs)))(*batch)
    assert rel_err(naive, ref) <= 1e-5


def test_franka_policy_matches_rmp2(x64):
    _compare_policy("franka", 2, seed=3)


def test_rejects_bad_input():
    q = jnp.zeros(D)
    with pytest.raises(ValueError, match="q must be a 1-D"):
        acceleration_naive(small_map, small_leaves, jnp.zeros((2, D)), jnp.zeros((2, D)), 0.3)
    with pytest.raises(ValueError, match=r"qd must have shape \(4,\)"):
        acceleration_naive(small_map, small_leaves, q, jnp.zeros(3), 0.3)
    with pytest.raises(ValueError, match=r"must have shape \(n_k, m_k\)"):
        acceleration_naive(lambda q: {"a": q}, small_leaves, q, q)
