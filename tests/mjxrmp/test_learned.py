"""Learned GDS components (thesis §4.3.1): metric networks, diffeomorphic potential (eq 4.7), leaf.

As in test_flows.py, every network is evaluated through one cached, jitted function per
configuration so that compile time stays small on CPU.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mjxrmp  # noqa: F401  (XLA flags first)
from mjxrmp.learned.flows import CONSTANTS, EuclideanizingFlow, jacobian, subtask_map
from mjxrmp.learned.gds import (
    CholeskyMetric,
    GramMetric,
    diffeomorphic_potential,
    diffeomorphic_potential_gradient,
    learned_gds,
    lower_triangular,
    smooth_norm_potential,
)
from mjxrmp.leaves import gds


@pytest.fixture
def x64():
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", False)


def noisy(variables, seed, scale):
    """``variables`` with every ``"params"`` leaf moved by ``scale·N(0, 1)`` (host RNG)."""
    rng = np.random.default_rng(seed)
    out = dict(variables)
    out["params"] = jax.tree.map(
        lambda p: p + jnp.asarray(scale * rng.standard_normal(p.shape), p.dtype),
        variables["params"])
    return out


METRICS = {
    "cholesky_abs": lambda dt, **kw: CholeskyMetric(dim=3, param_dtype=dt, **kw),
    "cholesky_softplus": lambda dt, **kw: CholeskyMetric(dim=3, diagonal="softplus",
                                                         param_dtype=dt, **kw),
    "gram": lambda dt, **kw: GramMetric(dim=3, param_dtype=dt, **kw),
}


@functools.cache
def metric_fn(metric):
    """Jitted ``(variables, x (B, m)) -> (G, factor, G by vmap over points)``."""

    def fn(variables, x):
        G = metric.apply(variables, x)
        factor = metric.apply(variables, x, method="factor")
        G_vmap = jax.vmap(lambda p: metric.apply(variables, p))(x)
        return G, factor, G_vmap

    return jax.jit(fn)


@functools.cache
def _metric_init(metric):
    return metric.init(jax.random.key(0), jnp.zeros((metric.dim,), metric.param_dtype))


# ---------------------------------------------------------------------------------------------
# Metrics
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", sorted(METRICS))
def test_metric_architecture_and_identity_at_init(x64, kind):
    metric = METRICS[kind](jnp.float64, eps=1e-3)  # the module of the SPD test (one compile)
    variables = _metric_init(metric)
    shapes = jax.tree.map(lambda a: a.shape, variables["params"])
    assert shapes["hidden_0"]["kernel"] == (3, 128) and shapes["hidden_1"]["kernel"] == (128, 64)
    heads = {"diag": (64, 3), "off_diag": (64, 3)} if kind != "gram" else {"gram": (64, 9)}
    for name, shape in heads.items():
        assert shapes[name]["kernel"] == shape
        assert np.all(np.asarray(variables["params"][name]["kernel"]) == 0)
        assert np.all(np.asarray(variables["params"][name]["bias"]) == 0)
    x = np.random.default_rng(0).uniform(-2, 2, (32, 3))
    G, factor, G_vmap = metric_fn(metric)(variables, x)
    assert G.shape == (32, 3, 3) and G.dtype == jnp.float64
    np.testing.assert_allclose(G, np.broadcast_to(np.eye(3), G.shape), atol=1e-14)
    np.testing.assert_allclose(factor, np.broadcast_to(np.sqrt(1 - metric.eps) * np.eye(3),
                                                       G.shape), atol=1e-14)
    np.testing.assert_allclose(G_vmap, G, atol=1e-14)  # batch == vmap over points


@pytest.mark.parametrize("kind", sorted(METRICS))
@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**16), scale=st.sampled_from([0.1, 0.5, 1.0]))
def test_metric_spd_for_any_parameters(kind, seed, scale):
    """G symmetric, λ_min(G) ≥ ε for arbitrary (far from initial) parameters and points."""
    jax.config.update("jax_enable_x64", True)
    try:
        metric = METRICS[kind](jnp.float64, eps=1e-3)
        variables = noisy(_metric_init(metric), seed, scale)
        x = np.random.default_rng(seed + 1).uniform(-3, 3, (32, 3))
        G, factor, G_vmap = (np.asarray(a) for a in metric_fn(metric)(variables, x))
        np.testing.assert_array_equal(G, np.swapaxes(G, -1, -2))
        norm = np.linalg.norm(G, 2, axis=(-2, -1))
        lam_min = np.linalg.eigvalsh(G)[:, 0]
        assert np.all(lam_min >= metric.eps - 1e-12 * np.maximum(norm, 1.0)), lam_min.min()
        np.testing.assert_allclose(G_vmap, G, rtol=1e-12, atol=1e-12)
        if kind.startswith("cholesky"):
            np.testing.assert_array_equal(np.triu(factor, 1), 0.0)  # lower-triangular
            assert np.all(np.diagonal(factor, axis1=-2, axis2=-1) >= metric.diag_eps)
    finally:
        jax.config.update("jax_enable_x64", False)


@pytest.mark.parametrize("kind", ["cholesky_abs", "cholesky_softplus", "gram"])
def test_metric_floor_is_tight_for_degenerate_parameters(x64, kind):
    """Driving the factor to (near) singular leaves λ_min(G) at the floor ε, never below."""
    metric = METRICS[kind](jnp.float64, eps=1e-3)
    variables = noisy(_metric_init(metric), 3, 0.3)
    params = dict(variables["params"])
    if kind == "gram":  # A = 0 exactly: G = εI
        params["gram"] = {"kernel": np.zeros((64, 9)),
                          "bias": -np.sqrt(1 - metric.eps) * np.eye(3).ravel()}
    elif kind == "cholesky_abs":  # L_ii = ε_L with large off-diagonal entries
        params["diag"] = {"kernel": np.zeros((64, 3)),
                          "bias": -metric.diagonal_offset() * np.ones(3)}
    else:  # softplus(very negative) → L_ii ≈ ε_L
        params["diag"] = {"kernel": np.zeros((64, 3)), "bias": -50.0 * np.ones(3)}
    variables = {"params": params}
    x = np.random.default_rng(0).uniform(-1, 1, (16, 3))
    G = np.asarray(metric_fn(metric)(variables, x)[0])
    lam_min = np.linalg.eigvalsh(G)[:, 0]
    assert np.all(lam_min >= metric.eps - 1e-12 * np.linalg.norm(G, 2, axis=(-2, -1)))
    assert np.all(lam_min <= 1.01 * metric.eps + 1e-6), lam_min  # the floor is what remains


def test_metric_float32_identity_at_init_and_spd():
    metric = METRICS["cholesky_abs"](jnp.float32)  # defaults: eps = diag_eps = 1e-5
    x = np.random.default_rng(7).uniform(-3, 3, (64, 3)).astype(np.float32)
    G0 = metric_fn(metric)(_metric_init(metric), x)[0]
    assert G0.dtype == jnp.float32
    np.testing.assert_allclose(G0, np.broadcast_to(np.eye(3), G0.shape), atol=1e-6)
    variables = noisy(_metric_init(metric), 7, 0.3)
    G = np.asarray(metric_fn(metric)(variables, x)[0], np.float64)
    np.testing.assert_array_equal(G, np.swapaxes(G, -1, -2))
    tol = 1e-6 * np.maximum(np.linalg.norm(G, 2, axis=(-2, -1)), 1.0)  # float32 rounding
    assert np.all(np.linalg.eigvalsh(G)[:, 0] >= metric.eps - tol)


def test_lower_triangular_layout():
    L = np.asarray(lower_triangular(jnp.array([1.0, 2.0, 3.0]), jnp.array([4.0, 5.0, 6.0])))
    np.testing.assert_array_equal(L, [[1, 0, 0], [4, 2, 0], [5, 6, 3]])


# ---------------------------------------------------------------------------------------------
# Diffeomorphic potential (eq 4.7)
# ---------------------------------------------------------------------------------------------

FLOW = EuclideanizingFlow(dim=2, num_layers=2, num_features=16, param_dtype=jnp.float64)


@functools.cache
def _flow_init():
    return FLOW.init(jax.random.key(0), jnp.zeros(2, jnp.float64))


def flow_variables(seed, scale=0.05):
    base = _flow_init()
    return {"params": noisy(base, seed, scale)["params"], CONSTANTS: base[CONSTANTS]}


@jax.jit
def potential_fn(variables, x, goal):
    """Φ, ∇Φ by autodiff, ∇Φ by eq 4.7, J_φ(x − g), ψ(x), Φ at the goal, smooth-norm Φ."""
    Phi = diffeomorphic_potential(FLOW, variables, x, goal)
    grad = jax.vmap(jax.grad(lambda p: diffeomorphic_potential(FLOW, variables, p, goal)))(x)
    grad_47 = diffeomorphic_potential_gradient(FLOW, variables, x, goal)
    J = jacobian(FLOW, variables, x - goal)
    psi = subtask_map(FLOW, variables, x, goal)
    at_goal = diffeomorphic_potential(FLOW, variables, goal, goal)
    grad_at_goal = jax.grad(lambda p: diffeomorphic_potential(FLOW, variables, p, goal))(goal)
    Phi_norm = diffeomorphic_potential(FLOW, variables, x, goal, smooth_norm_potential)
    return dict(Phi=Phi, grad=grad, grad_47=grad_47, J=J, psi=psi, at_goal=at_goal,
                grad_at_goal=grad_at_goal, Phi_norm=Phi_norm)


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_potential_nonnegative_zero_and_stationary_only_at_goal(seed):
    jax.config.update("jax_enable_x64", True)
    try:
        rng = np.random.default_rng(seed)
        variables = flow_variables(seed)
        goal = rng.uniform(-0.5, 0.5, 2)
        x = goal + rng.uniform(-1.5, 1.5, (32, 2))
        x[0] = goal + 1e-3  # close to the goal, not at it
        out = jax.tree.map(np.asarray, potential_fn(variables, x, goal))
        assert out["at_goal"] == 0.0
        np.testing.assert_array_equal(out["grad_at_goal"], 0.0)
        assert np.all(out["Phi"] > 0.0) and np.all(out["Phi_norm"] > 0.0)
        assert np.all(np.linalg.norm(out["grad"], axis=-1) > 0.0)
        # Φ = ½‖ψ‖², ψ a bijection: Φ ≥ ½ σ_min² ‖x − g‖² locally; here just consistency.
        np.testing.assert_allclose(out["Phi"], 0.5 * np.sum(out["psi"] ** 2, -1), rtol=1e-12)
    finally:
        jax.config.update("jax_enable_x64", False)


def test_potential_gradient_matches_eq_4_7_and_finite_differences(x64):
    variables = flow_variables(21)
    goal = np.array([0.2, -0.1])
    x = np.random.default_rng(21).uniform(-1, 1, (8, 2))
    out = jax.tree.map(np.asarray, potential_fn(variables, x, goal))
    # Eq 4.7: ∇Φ = J_φᵀ ∇Φ̄(ψ) with ∇Φ̄(ψ) = ψ for Φ̄ = ½‖·‖².
    eq_47 = np.einsum("bij,bi->bj", out["J"], out["psi"])
    np.testing.assert_allclose(out["grad"], eq_47, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(out["grad_47"], eq_47, rtol=1e-10, atol=1e-12)
    h = 1e-6
    for k in range(2):
        e = np.zeros(2)
        e[k] = h
        fd = (np.asarray(potential_fn(variables, x + e, goal)["Phi"])
              - np.asarray(potential_fn(variables, x - e, goal)["Phi"])) / (2 * h)
        np.testing.assert_allclose(out["grad"][:, k], fd, rtol=1e-6, atol=1e-8)


# ---------------------------------------------------------------------------------------------
# Learned GDS leaf (eq 4.6)
# ---------------------------------------------------------------------------------------------

METRIC2 = CholeskyMetric(dim=2, param_dtype=jnp.float64)
DAMPING = 1.5


@jax.jit
def gds_fn(mvars, fvars, x, xd, goal):
    metric = lambda p: METRIC2.apply(mvars, p)  # noqa: E731
    potential = lambda p: diffeomorphic_potential(FLOW, fvars, p, goal)  # noqa: E731
    leaf = learned_gds(metric, potential, DAMPING)
    reference = gds.gds(lambda p, v: metric(p), potential, lambda p, v: DAMPING * metric(p))
    no_curv = learned_gds(metric, potential, DAMPING, curvature=False)
    rmp = gds.family(leaf)(x, xd)
    ref = gds.family(reference)(x, xd)
    nc = gds.family(no_curv)(x, xd)
    G, Gdot = jax.vmap(lambda p, v: jax.jvp(metric, (p,), (v,)))(x, xd)
    grad = jax.vmap(jax.grad(potential))(x)
    return dict(M=rmp.M, f=rmp.f, M_ref=ref.M, f_ref=ref.f, f_nc=nc.f, G=G, Gdot=Gdot, grad=grad)


def test_learned_gds_leaf_matches_gds_and_dissipates(x64):
    """f = −∇Φ − γ_d G ẋ − ξ_G (eq 4.6, B = γ_d G); V̇ = −γ_d ẋᵀGẋ (Lemma 3.2.1)."""
    rng = np.random.default_rng(5)
    mvars = noisy(METRIC2.init(jax.random.key(1), jnp.zeros(2)), 5, 0.3)
    fvars = flow_variables(6)
    goal = np.array([0.1, 0.3])
    x, xd = rng.uniform(-1, 1, (16, 2)), rng.uniform(-1, 1, (16, 2))
    out = jax.tree.map(np.asarray, gds_fn(mvars, fvars, x, xd, goal))
    assert out["M"].shape == (16, 2, 2) and out["f"].shape == (16, 2)
    np.testing.assert_allclose(out["M"], out["G"], rtol=1e-14)  # Ξ_G = 0: position-only metric
    np.testing.assert_allclose(out["M"], out["M_ref"], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(out["f"], out["f_ref"], rtol=1e-9, atol=1e-10)
    f_nc = -out["grad"] - DAMPING * np.einsum("bij,bj->bi", out["G"], xd)
    np.testing.assert_allclose(out["f_nc"], f_nc, rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(out["f"] - out["f_nc"])) > 1e-6  # the curvature term is really there
    # Along ẍ = M⁻¹f, V = ½ẋᵀGẋ + Φ changes at V̇ = ẋᵀGẍ + ½ẋᵀĠẋ + ∇Φᵀẋ = −γ_d ẋᵀGẋ.
    xdd = np.linalg.solve(out["M"], out["f"][..., None])[..., 0]
    Vdot = (np.einsum("bi,bij,bj->b", xd, out["G"], xdd)
            + 0.5 * np.einsum("bi,bij,bj->b", xd, out["Gdot"], xd)
            + np.sum(out["grad"] * xd, -1))
    dissipation = -DAMPING * np.einsum("bi,bij,bj->b", xd, out["G"], xd)
    np.testing.assert_allclose(Vdot, dissipation, rtol=1e-8, atol=1e-10)


# ---------------------------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------------------------


def test_bad_configuration_and_inputs_raise():
    with pytest.raises(ValueError, match="eps"):
        CholeskyMetric(dim=2, eps=1.0)
    with pytest.raises(ValueError, match="diag_eps"):
        CholeskyMetric(dim=2, diag_eps=0.0)
    with pytest.raises(ValueError, match="diagonal"):
        CholeskyMetric(dim=2, diagonal="exp")
    with pytest.raises(ValueError, match="dim"):
        GramMetric(dim=0)
    with pytest.raises(ValueError, match="activation"):
        GramMetric(dim=2, activation="nope")
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2\)"):
        jax.eval_shape(lambda x: METRIC2.init(jax.random.key(0), x), jnp.zeros(3))
    with pytest.raises(ValueError, match="damping"):
        learned_gds(lambda x: jnp.eye(2), lambda x: jnp.sum(x * x), -1.0)
    leaf = learned_gds(lambda x: jnp.eye(2), lambda x: jnp.sum(x * x), 1.0)
    with pytest.raises(ValueError, match="family"):
        jax.eval_shape(leaf, jnp.zeros((3, 2)), jnp.zeros((3, 2)))
    bad = learned_gds(lambda x: jnp.eye(3), lambda x: jnp.sum(x * x), 1.0)
    with pytest.raises(ValueError, match=r"\(2, 2\) matrix"):
        jax.eval_shape(bad, jnp.zeros(2), jnp.zeros(2))
    scalar = learned_gds(lambda x: jnp.eye(2), lambda x: x, 1.0)
    with pytest.raises(ValueError, match="scalar"):
        jax.eval_shape(scalar, jnp.zeros(2), jnp.zeros(2))
