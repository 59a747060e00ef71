"""RMP² (pullback, resolve, acceleration, velocity) against an independent float64 formulation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from rmp_reference import (
    reference_pullback,
    reference_pullback_velocity,
    reference_resolve,
    rel_err,
)

from mjxrmp import RMP
from mjxrmp.core import rmp2

D = 4
RNG = np.random.default_rng(0)
W1 = RNG.normal(size=(3, D))
W2 = RNG.normal(size=(3, D))
W3 = RNG.normal(size=(5, D))


def hand_map(q, scale):
    """A nonlinear task map with two families: 2 points in 3-D and 5 scalars."""
    w1, w2, w3 = (jnp.asarray(w, q.dtype) for w in (W1, W2, W3))
    points = jnp.stack([jnp.tanh(w1 @ q), jnp.sin(w2 @ q) * q[0]])
    scalars = (jnp.cos(w3 @ q) + scale * (q @ q))[:, None]
    return {"points": points, "scalars": scalars}


def hand_leaves(x, xd, scale):
    """Nonlinear, state-dependent leaf RMPs with SPD metrics."""
    out = {}
    for name, xk in x.items():
        vk = xd[name]
        A = jnp.tanh(xk[:, :, None] * vk[:, None, :] + xk[:, None, :])
        M = A @ jnp.swapaxes(A, 1, 2) + (0.1 + scale) * jnp.eye(xk.shape[1])
        f = jnp.sin(3.0 * xk) - 2.0 * vk + scale
        out[name] = RMP(M, f)
    return out


def hand_velocity_leaves(x, scale):
    out = {}
    for name, xk in x.items():
        A = jnp.tanh(xk[:, :, None] + xk[:, None, :])
        M = A @ jnp.swapaxes(A, 1, 2) + (0.1 + scale) * jnp.eye(xk.shape[1])
        out[name] = RMP(M, jnp.einsum("nij,nj->ni", M, -jnp.sin(xk)))
    return out


#: ``rmp2.pullback`` compiled (the task map and leaves static): one program per shape and dtype
#: instead of every operation compiled on its own.
PULLBACK = jax.jit(rmp2.pullback, static_argnums=(0, 1))


def random_states(n, d=D, seed=1):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, d)), rng.normal(size=(n, d))


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


@pytest.mark.parametrize("seed", range(5))
def test_pullback_matches_finite_difference_reference(x64, seed):
    q, qd = (a[0] for a in random_states(1, seed=seed))
    M, f = PULLBACK(hand_map, hand_leaves, jnp.asarray(q), jnp.asarray(qd), 0.3)
    M_ref, f_ref = reference_pullback(hand_map, hand_leaves, q, qd, 0.3)
    assert M.dtype == jnp.float64
    assert rel_err(M, M_ref) <= 1e-6
    assert rel_err(f, f_ref) <= 1e-6


def test_resolve_matches_original_numerics(x64):
    rng = np.random.default_rng(3)
    for scale in (0.5, 10.0, 1e4):  # below and above the max(1, 0.01·max|M|) switch
        A = rng.normal(size=(D, D))
        M = scale * (A @ A.T + 0.1 * np.eye(D))
        f = rng.normal(size=D)
        qdd = rmp2.resolve(RMP(jnp.asarray(M), jnp.asarray(f)))
        assert rel_err(qdd, reference_resolve(M, f)) <= 1e-10


def test_acceleration_is_resolve_of_pullback_and_solves_least_squares(x64):
    q, qd = (a[0] for a in random_states(1, seed=7))
    qdd = rmp2.acceleration(hand_map, hand_leaves, jnp.asarray(q), jnp.asarray(qd), 0.3)
    M_ref, f_ref = reference_pullback(hand_map, hand_leaves, q, qd, 0.3)
    assert rel_err(qdd, reference_resolve(M_ref, f_ref)) <= 1e-6
    # The unregularised root solves the least-squares problem (3.9): closed form (3.10).
    exact = np.linalg.pinv(M_ref) @ f_ref
    root = rmp2.pullback(hand_map, hand_leaves, jnp.asarray(q), jnp.asarray(qd), 0.3)
    assert rel_err(np.linalg.solve(np.asarray(root.M), np.asarray(root.f)), exact) <= 1e-6


@pytest.mark.parametrize("seed", range(3))
def test_velocity_form_matches_reference(x64, seed):
    q = random_states(1, seed=seed)[0][0]
    qdot = rmp2.velocity(hand_map, hand_velocity_leaves, jnp.asarray(q), 0.2)
    M_ref, p_ref = reference_pullback_velocity(hand_map, hand_velocity_leaves, q, 0.2)
    root = rmp2.pullback_velocity(hand_map, hand_velocity_leaves, jnp.asarray(q), 0.2)
    assert rel_err(root.M, M_ref) <= 1e-6
    assert rel_err(root.f, p_ref) <= 1e-6
    assert rel_err(qdot, reference_resolve(M_ref, p_ref)) <= 1e-6


def test_float32_agrees_with_float64():
    qs, qds = random_states(8, seed=11)
    f32 = jax.jit(jax.vmap(lambda q, qd: rmp2.acceleration(hand_map, hand_leaves, q, qd, 0.3)))
    out32 = f32(jnp.asarray(qs, jnp.float32), jnp.asarray(qds, jnp.float32))
    assert out32.dtype == jnp.float32
    with jax.enable_x64(True):
        out64 = jax.jit(jax.vmap(lambda q, qd: rmp2.acceleration(hand_map, hand_leaves, q, qd,
                                                                 0.3)))(
            jnp.asarray(qs), jnp.asarray(qds)
        )
    for a, b in zip(out32, out64, strict=True):
        assert rel_err(a, b) <= 1e-4


def test_jit_and_vmap_match_single_evaluations(x64):
    qs, qds = random_states(6, seed=5)
    batched = jax.jit(jax.vmap(lambda q, qd: rmp2.acceleration(hand_map, hand_leaves, q, qd, 0.3)))
    out = batched(jnp.asarray(qs), jnp.asarray(qds))
    for i in range(len(qs)):
        single = rmp2.acceleration(hand_map, hand_leaves, jnp.asarray(qs[i]), jnp.asarray(qds[i]),
                                   0.3)
        np.testing.assert_allclose(out[i], single, rtol=1e-10, atol=1e-12)


def test_gradient_wrt_leaf_parameter_matches_finite_difference(x64):
    q, qd = (jnp.asarray(a[0]) for a in random_states(1, seed=9))

    def loss(scale):
        qdd = rmp2.acceleration(hand_map, hand_leaves, q, qd, scale)
        return jnp.sum(qdd**2)

    g = jax.jit(jax.grad(loss))(0.3)
    h = 1e-6
    loss = jax.jit(loss)
    fd = (loss(0.3 + h) - loss(0.3 - h)) / (2 * h)
    assert np.isfinite(g)
    assert abs(g - fd) <= 1e-6 * max(1.0, abs(fd))


# ---------------------------------------------------------------------------------------------
# Bad input
# ---------------------------------------------------------------------------------------------

Q = jnp.zeros(D)


def test_rejects_batched_or_mismatched_states():
    with pytest.raises(ValueError, match="q must be a 1-D"):
        rmp2.acceleration(hand_map, hand_leaves, jnp.zeros((2, D)), jnp.zeros((2, D)), 0.3)
    with pytest.raises(ValueError, match=r"qd must have shape \(4,\)"):
        rmp2.acceleration(hand_map, hand_leaves, Q, jnp.zeros(3), 0.3)
    with pytest.raises(TypeError, match="q must be a floating-point"):
        rmp2.acceleration(hand_map, hand_leaves, jnp.zeros(D, jnp.int32), Q, 0.3)


def test_rejects_task_map_leaf_with_wrong_rank():
    with pytest.raises(ValueError, match=r"task_map leaf \['a'\] must have shape \(n_k, m_k\)"):
        rmp2.pullback(lambda q: {"a": q}, hand_leaves, Q, Q)


def test_rejects_non_rmp_leaf_output():
    def tuple_leaves(x, xd, scale):
        return {k: (v.M, v.f) for k, v in hand_leaves(x, xd, scale).items()}

    with pytest.raises((TypeError, ValueError), match="leaf_fn must return"):
        rmp2.pullback(hand_map, tuple_leaves, Q, Q, 0.3)
    with pytest.raises((TypeError, ValueError), match="leaf_fn must return"):
        rmp2.pullback(hand_map, lambda x, xd, s: "not a pytree of RMPs", Q, Q, 0.3)


def test_rejects_mismatched_leaf_structure():
    def missing_family(x, xd, scale):
        out = hand_leaves(x, xd, scale)
        del out["scalars"]
        return out

    with pytest.raises(ValueError, match="same structure as task_map"):
        rmp2.pullback(hand_map, missing_family, Q, Q, 0.3)


def test_rejects_wrong_leaf_shapes():
    def bad_metric(x, xd, scale):
        out = hand_leaves(x, xd, scale)
        out["points"] = RMP(out["points"].M[:, :2, :2], out["points"].f)
        return out

    with pytest.raises(ValueError, match=r"leaf_fn RMP at \['points'\]: M must have shape"):
        rmp2.pullback(hand_map, bad_metric, Q, Q, 0.3)


def test_rejects_bad_root():
    with pytest.raises(ValueError, match=r"root\.f must have shape"):
        rmp2.resolve(RMP(jnp.eye(3), jnp.zeros(2)))


def test_debug_mode_reports_first_non_finite_value():
    def nan_leaves(x, xd, scale):
        out = hand_leaves(x, xd, scale)
        out["scalars"] = RMP(out["scalars"].M, out["scalars"].f * jnp.sqrt(scale - 1.0))
        return out

    q, qd = (jnp.asarray(a[0], jnp.float32) for a in random_states(1, seed=2))
    # the plain (non-debug) calls compiled; debug mode raises here, before returning
    plain = jax.jit(rmp2.acceleration, static_argnums=(0, 1))
    assert not np.all(np.isfinite(plain(hand_map, nan_leaves, q, qd, 0.3)))
    # A NaN produced by a traced operation is reported at the primitive that produced it ...
    with pytest.raises(Exception, match="nan generated by primitive: sqrt"):
        rmp2.acceleration(hand_map, nan_leaves, q, qd, 0.3, debug=True)

    # ... and a non-finite input is named before anything runs.
    with pytest.raises(ValueError, match=r"qd contains non-finite values at \[1\]"):
        rmp2.acceleration(hand_map, hand_leaves, q, qd.at[1].set(jnp.nan), 0.3, debug=True)
    # Valid inputs pass through debug mode unchanged.
    np.testing.assert_allclose(
        rmp2.acceleration(hand_map, hand_leaves, q, qd, 0.3, debug=True),
        plain(hand_map, hand_leaves, q, qd, 0.3),
        rtol=1e-5,  # two compiled programs; float32 rounding
    )
