"""Learned subtask RMPs (thesis §4.3.1–4.3.2, §6.2.2): residual, direct, learned nominal + CLF,
GDS on the nominal-trajectory potential.

Networks are small and every check goes through one jitted function per variant, built once,
so hypothesis only re-runs compiled code.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mjxrmp  # noqa: F401  (XLA flags first)
from mjxrmp.core.rmp import RMP
from mjxrmp.learned.gds import CholeskyMetric
from mjxrmp.learned.nominal import NominalPotential, nominal_potential, nominal_potential_gradient
from mjxrmp.learned.rmps import (
    DirectRMP,
    NominalPolicy,
    ResidualRMPNet,
    direct_leaf,
    learned_clf_leaf,
    natural_gradient_velocity,
    nominal_gds_leaf,
    position_metric,
    residual_leaf,
    residual_rmp,
)
from mjxrmp.leaves.hand_designed import TargetParams, target_rmp


@pytest.fixture(autouse=True, scope="module")
def _x64():
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", False)


def randomize(variables, seed, scale):
    """Every parameter replaced by ``scale·N(0, 1)`` (arbitrary network parameters)."""
    rng = np.random.default_rng(seed)
    return jax.tree.map(lambda p: jnp.asarray(scale * rng.standard_normal(p.shape)), variables)


def potential():
    """A hand-made nominal-trajectory potential (eq 4.9) on a bent 8-point trajectory."""
    s = np.linspace(0.0, 1.0, 8)
    centers = np.stack([1.0 - s, 0.5 * np.sin(np.pi * s)], axis=1)
    return NominalPotential(jnp.asarray(centers), jnp.asarray(np.linspace(0.8, 0.0, 8)),
                            jnp.asarray(0.2), jnp.asarray(5.0), jnp.asarray(0.0))


METRIC = CholeskyMetric(dim=2, hidden_sizes=(16, 16), param_dtype=jnp.float64)
POLICY = NominalPolicy(dim=2, hidden_sizes=(16, 16), param_dtype=jnp.float64)


def _xi_reference(metric_vars, x, xd):
    """``ξ_G = Ġ_x ẋ − ½∇_x(ẋᵀGẋ)`` (eq 3.13) for a position-only metric, from ``∂G/∂x``."""
    dG = jax.jacfwd(lambda y: METRIC.apply(metric_vars, y))(x)       # [i, j, k] = ∂G_ij/∂x_k
    return jnp.einsum("ijk,k,j->i", dG, xd, xd) - 0.5 * jnp.einsum("i,ijk,j->k", xd, dG, xd)


@functools.cache
def clf(P):
    """Jitted CLF check for ``P``; built lazily so its constants are float64 (x64 on)."""
    pot = potential()

    @jax.jit
    def evaluate(policy_vars, metric_vars, x, xd):
        G = position_metric(lambda y: METRIC.apply(metric_vars, y))
        Phi = lambda y: nominal_potential(pot, y)  # noqa: E731
        leaf = learned_clf_leaf(lambda y, yd: POLICY.apply(policy_vars, y, yd), G, Phi, P=P)
        M, f = leaf(x, xd)
        # independent right-hand side of eq 3.30 with α(s) = s² (clf_leaf's default)
        b = -xd @ (nominal_potential_gradient(pot, x) + _xi_reference(metric_vars, x, xd)) \
            - xd @ xd
        nominal = METRIC.apply(metric_vars, x) @ POLICY.apply(policy_vars, x, xd)
        return M, f, b, nominal

    return evaluate



@functools.cache
def init(name):
    """Variable shapes (tests replace every value), from ``jax.eval_shape`` under x64."""
    if name == "policy":
        return jax.eval_shape(POLICY.init, jax.random.key(0), jnp.zeros(2), jnp.zeros(2))
    if name == "metric":
        return jax.eval_shape(METRIC.init, jax.random.key(1), jnp.zeros(2))
    if name == "net":
        return jax.eval_shape(NET.init, jax.random.key(4), jnp.zeros(6))
    return jax.eval_shape(DIRECT[name].init, jax.random.key(2), jnp.zeros(3), jnp.zeros(3))


coord = st.floats(-1.5, 1.5, allow_nan=False, allow_subnormal=False)
vec2 = st.tuples(coord, coord).map(np.array)


@settings(max_examples=40, deadline=None)
@given(P=st.sampled_from(["identity", "inverse_metric"]), seed=st.integers(0, 2**31 - 1),
       scale=st.floats(0.05, 3.0), x=vec2,
       xd=st.one_of(vec2, st.just(np.zeros(2))))
def test_learned_nominal_with_clf_satisfies_3_30(P, seed, scale, x, xd):
    """For arbitrary network parameters and states, ``ẋᵀf ≤ −ẋᵀ(∇Φ + ξ_G) − α(‖ẋ‖)``; the
    nominal ``Mπ_θ`` is kept where it already satisfies it (minimal invasiveness)."""
    policy_vars = randomize(init("policy"), seed, scale)
    metric_vars = randomize(init("metric"), seed + 1, scale)
    M, f, b, nominal = (np.asarray(a) for a in clf(P)(policy_vars, metric_vars, x, xd))
    assert np.all(np.isfinite(f)) and np.all(np.isfinite(M))
    tol = 1e-9 * (1 + abs(float(b)) + np.linalg.norm(xd) * (np.linalg.norm(f)
                                                             + np.linalg.norm(nominal)))
    assert xd @ f <= b + tol
    if xd @ nominal <= b - tol:
        np.testing.assert_allclose(f, nominal, rtol=1e-12, atol=1e-12)


# --- direct RMP (§4.3.2) -----------------------------------------------------------------------


DIRECT = {kind: DirectRMP(dim=3, metric=kind, metric_hidden_sizes=(16, 16),
                          accel_hidden_sizes=(16, 16), eps=1e-3, param_dtype=jnp.float64)
          for kind in ("cholesky", "gram")}


def _make_direct(kind):
    module = DIRECT[kind]

    @jax.jit
    def evaluate(variables, x, xd):
        M, f = direct_leaf(module, variables)(x, xd)
        return M, f, jnp.linalg.eigvalsh(M)

    return evaluate


DIRECT_EVAL = {k: _make_direct(k) for k in DIRECT}
vec3 = st.tuples(coord, coord, coord).map(np.array)


@settings(max_examples=40, deadline=None)
@given(kind=st.sampled_from(sorted(DIRECT)), seed=st.integers(0, 2**31 - 1),
       scale=st.floats(0.01, 5.0), x=vec3, xd=vec3)
def test_direct_rmp_metric_positive_definite(kind, seed, scale, x, xd):
    variables = randomize(init(kind), seed, scale)
    M, f, eig = (np.asarray(a) for a in DIRECT_EVAL[kind](variables, x, xd))
    np.testing.assert_allclose(M, M.T, rtol=0, atol=1e-12 * (1 + np.abs(M).max()))
    assert eig.min() >= 1e-3 * (1 - 1e-9) - 1e-13 * eig.max()
    assert np.all(np.isfinite(f))


def test_direct_rmp_identity_metric_at_init_and_batches():
    module = DIRECT["cholesky"]
    v = jax.jit(module.init)(jax.random.key(2), jnp.zeros(3), jnp.zeros(3))
    x = jnp.asarray(np.random.default_rng(3).normal(size=(5, 3)))
    (M, f), (_, f1) = jax.jit(lambda x_: (module.apply(v, x_, -x_),
                                          direct_leaf(module, v)(x_[2], -x_[2])))(x)
    np.testing.assert_allclose(np.asarray(M), np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.asarray(f1), np.asarray(f[2]), rtol=1e-12)


# --- residual RMP (§6.2.2) ---------------------------------------------------------------------


NET = ResidualRMPNet(dim=2, hidden_sizes=(16, 16), param_dtype=jnp.float64)


@jax.jit
def _residual(net_vars, features, hand_M, hand_f, eps):
    A_r, a_r = NET.apply(net_vars, features)
    M, f = residual_rmp(RMP(hand_M, hand_f), A_r, a_r, eps)
    return A_r, a_r, M, f, jnp.linalg.eigvalsh(M), jnp.linalg.solve(M, f)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), scale=st.floats(0.01, 10.0),
       eps=st.sampled_from([0.0, 1e-4, 0.1]))
def test_residual_rmp_metric(seed, scale, eps):
    """``M = (A_r + chol M_h)(A_r + chol M_h)ᵀ + εI``: PSD always (the thesis, ε = 0), PD with
    ``λ_min ≥ ε`` for ε > 0, for any parameters; outputs bounded by √5 and 1; ``a = a_r + a_h``."""
    rng = np.random.default_rng(seed)
    R = rng.normal(size=(2, 2))
    hand_M = R @ R.T + 0.05 * np.eye(2)
    hand_f = rng.normal(size=2)
    features = rng.normal(size=6) * 3
    A_r, a_r, M, f, eig, a = (np.asarray(v) for v in _residual(
        randomize(init("net"), seed, scale), features, hand_M, hand_f, eps))
    assert np.abs(A_r).max() <= math.sqrt(5.0) and np.abs(a_r).max() <= 1.0
    np.testing.assert_allclose(M, M.T, atol=1e-12 * (1 + np.abs(M).max()))
    B = A_r + np.linalg.cholesky(hand_M)
    np.testing.assert_allclose(M, B @ B.T + eps * np.eye(2), rtol=1e-12, atol=1e-12)
    assert eig.min() >= eps * (1 - 1e-9) - 1e-12 * eig.max()
    np.testing.assert_allclose(f, M @ (a_r + np.linalg.solve(hand_M, hand_f)), rtol=1e-9,
                               atol=1e-9 * (1 + np.abs(M).max()))
    if eig.min() > 1e-6 * eig.max():
        np.testing.assert_allclose(a, a_r + np.linalg.solve(hand_M, hand_f), rtol=1e-6,
                                   atol=1e-6)


def test_residual_rmp_zero_residual_and_thesis_semidefiniteness():
    hand_M = np.array([[2.0, 0.3], [0.3, 1.0]])
    hand = RMP(jnp.asarray(hand_M), jnp.asarray([0.4, -1.0]))
    M, f = residual_rmp(hand, jnp.zeros((2, 2)), jnp.zeros(2))
    np.testing.assert_allclose(np.asarray(M), hand_M, rtol=1e-14)
    np.testing.assert_allclose(np.asarray(f), [0.4, -1.0], rtol=1e-14)
    # A_r = −chol(M_h) (entries within √5) makes the thesis' metric vanish; ε restores λ ≥ ε
    A_r = -jnp.linalg.cholesky(hand.M)
    np.testing.assert_allclose(np.asarray(residual_rmp(hand, A_r, jnp.zeros(2)).M), 0.0,
                               atol=1e-15)
    np.testing.assert_allclose(np.asarray(residual_rmp(hand, A_r, jnp.zeros(2), 0.01).M),
                               0.01 * np.eye(2), atol=1e-15)


def test_residual_leaf_around_the_target_attractor():
    """At zero residual (``out_init_scale=0``) the leaf is the hand-designed target RMP."""
    goal = jnp.asarray([0.3, -0.2])
    params = TargetParams()

    def hand_leaf(x, xd):
        M, f = target_rmp(x[None], xd[None], goal, params)
        return RMP(M[0], f[0])

    net = ResidualRMPNet(dim=2, hidden_sizes=(8,), out_init_scale=0.0, param_dtype=jnp.float64)
    net_vars = jax.jit(net.init)(jax.random.key(5), jnp.zeros(6))
    leaf = residual_leaf(hand_leaf, lambda x, xd: net.apply(
        net_vars, jnp.concatenate([x, xd, goal])))
    x, xd = jnp.asarray([0.5, 0.1]), jnp.asarray([-0.2, 0.3])
    (M, f), (M_h, f_h) = jax.jit(lambda a, b: (leaf(a, b), hand_leaf(a, b)))(x, xd)
    np.testing.assert_allclose(np.asarray(M), np.asarray(M_h), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(f), np.asarray(f_h), rtol=1e-10)


# --- GDS on the nominal potential (§4.3.1, Fig 4.8b; §5.2) -------------------------------------


def test_nominal_gds_leaf_and_velocity_form():
    pot = potential()
    metric_vars = randomize(init("metric"), 7, 0.5)
    metric = lambda y: METRIC.apply(metric_vars, y)  # noqa: E731
    gamma = 1.7

    @jax.jit
    def evaluate(x, xd):
        M, f = nominal_gds_leaf(metric, pot, gamma)(x, xd)
        ref = -nominal_potential_gradient(pot, x) - gamma * metric(x) @ xd \
            - _xi_reference(metric_vars, x, xd)
        grad = nominal_potential_gradient(pot, x)
        return M, f, ref, natural_gradient_velocity(metric, pot, x), metric(x), grad

    x, xd = jnp.asarray([0.4, 0.2]), jnp.asarray([0.3, -0.5])
    M, f, ref, v, G, grad = (np.asarray(a) for a in evaluate(x, xd))
    np.testing.assert_allclose(M, G, rtol=1e-12)
    np.testing.assert_allclose(f, ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(M @ v, -grad, rtol=1e-10, atol=1e-12)
