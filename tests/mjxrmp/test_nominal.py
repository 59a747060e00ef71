"""Nominal-trajectory potential (thesis eqs 4.9–4.11), its fit (eq 4.12, exact NNLS/LSEI) and
the DTW nominal demonstration (§5.2.1).

The bias fit is checked against independent SciPy solvers on a design matrix rebuilt here in
NumPy from the closed-form gradient of eq 4.9; every fit uses the same trajectory length so the
jitted solver compiles once per variant.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize
from scipy.optimize import nnls as scipy_nnls

import mjxrmp  # noqa: F401  (XLA flags first)
from mjxrmp.learned import lsq, nominal_fit
from mjxrmp.learned import nominal as nm


@pytest.fixture(autouse=True, scope="module")
def _x64():
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", False)


T = 24
DT = 0.05
SIGMA, ETA, LAM = 0.06, 10.0, 1e-3


def line():
    s = np.linspace(0.0, 1.0, T)
    return np.stack([0.8 * (1.0 - s), 0.4 * (1.0 - s)], axis=1)


def arc():
    th = np.linspace(np.pi, 0.0, T)
    pts = 0.4 * np.stack([np.cos(th), np.sin(th)], axis=1)
    return pts - pts[-1]


@functools.cache
def fitter(goal_constraint):
    return jax.jit(functools.partial(nominal_fit.fit_nominal_potential, sigma=SIGMA, eta=ETA,
                                     lam=LAM, goal_constraint=goal_constraint))


@functools.cache
def fitted(kind, goal_constraint="auto"):
    traj = line() if kind == "line" else arc()
    return (traj, *fitter(goal_constraint)(jnp.asarray(traj), DT))


# --- independent NumPy reference of eqs 4.9–4.12 ----------------------------------------------


def np_design(centers, x, sigma=SIGMA, eta=ETA):
    """``∇Φ(x; φ⁰) = A φ⁰ + b`` from the textbook formulas, one point ``x (m,)``."""
    diff = x - centers
    r = np.linalg.norm(diff, axis=1)
    k = np.exp(-(r**2) / (2 * sigma**2))
    w = k / k.sum()
    grad_w = (w[:, None] * (-diff + (w[:, None] * diff).sum(0))) / sigma**2      # (T, m)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = np.where(r[:, None] > 0, diff / r[:, None], 0.0)
    elem = np.log(np.exp(eta * r) + np.exp(-eta * r)) / eta
    b = (w[:, None] * np.tanh(eta * r)[:, None] * unit).sum(0) + (elem[:, None] * grad_w).sum(0)
    return grad_w.T, b


def np_problem(traj):
    vel = np.gradient(traj, DT, axis=0)
    A = np.stack([np_design(traj, z)[0] for z in traj])      # (T, m, T)
    b = np.stack([np_design(traj, z)[1] for z in traj])      # (T, m)
    C = np.concatenate([A.reshape(-1, T), np.sqrt(LAM) * np.eye(T)]) / np.sqrt(T)
    d = np.concatenate([-(vel + b).ravel(), np.zeros(T)]) / np.sqrt(T)
    return A, b, C, d


def np_potential(traj, biases, x, sigma=SIGMA, eta=ETA):
    r = np.linalg.norm(x - traj, axis=1)
    k = np.exp(-(r**2) / (2 * sigma**2))
    return (k * (np.log(np.exp(eta * r) + np.exp(-eta * r)) / eta + biases)).sum() / k.sum()


def assert_monotone(phi):
    phi = np.asarray(phi)
    assert np.all(phi >= 0.0)
    assert np.all(np.diff(phi) <= 0.0)      # exact: 0 ≤ φ_T ≤ φ_{t+1} ≤ φ_t


# --- solver ------------------------------------------------------------------------------------


def test_nnls_matches_scipy():
    rng = np.random.default_rng(0)
    solve = jax.jit(lsq.nnls)
    for _ in range(5):
        A = rng.standard_normal((15, 10))
        b = rng.standard_normal(15)
        x, r, status = solve(A, b)
        x_ref, r_ref = scipy_nnls(A, b)
        assert int(status) == 0
        np.testing.assert_allclose(np.asarray(x), x_ref, atol=1e-12)
        np.testing.assert_allclose(float(r), r_ref, rtol=1e-12)


def test_fit_without_goal_constraint_matches_scipy_nnls():
    """Eq 4.12 without the equality, by LSI/LDP here and by SciPy's NNLS on the increments
    ``β_t = φ_t − φ_{t+1} ≥ 0`` (φ = Uβ) of an independently built design matrix."""
    traj, p, info = fitted("arc", "none")
    _, _, C, d = np_problem(traj)
    U = np.triu(np.ones((T, T)))
    beta, _ = scipy_nnls(C @ U, d)
    phi_ref = U @ beta
    np.testing.assert_allclose(np.asarray(p.biases), phi_ref, rtol=1e-8, atol=1e-10)
    assert float(info.objective) == pytest.approx(np.sum((C @ phi_ref - d) ** 2), rel=1e-10)
    assert not bool(info.exact) and int(info.status) == 0
    assert_monotone(p.biases)


def test_fit_with_goal_constraint_matches_slsqp_and_kkt():
    """Straight line: eq 4.12 is feasible, the goal becomes stationary, and the solution agrees
    with SciPy's SLSQP and satisfies the KKT conditions checked here from scratch."""
    traj, p, info = fitted("line")
    A, b, C, d = np_problem(traj)
    phi = np.asarray(p.biases)
    assert bool(info.exact) and bool(info.feasible) and int(info.status) == 0
    assert_monotone(phi)
    E, e = A[-1], -b[-1]
    np.testing.assert_allclose(E @ phi, e, atol=1e-10)
    assert float(info.goal_gradient) < 1e-10
    # On a straight line both rows of E are parallel: give SLSQP the one independent row.
    row = int(np.argmax(np.linalg.norm(E, axis=1)))
    D = np.eye(T) - np.eye(T, k=1)
    res = minimize(lambda z: np.sum((C @ z - d) ** 2), np.linspace(1, 0, T),
                   jac=lambda z: 2 * C.T @ (C @ z - d), method="SLSQP",
                   constraints=[{"type": "ineq", "fun": lambda z: D @ z, "jac": lambda z: D},
                                {"type": "eq", "fun": lambda z: E[row] @ z - e[row],
                                 "jac": lambda z: E[row][None]}],
                   options={"ftol": 1e-15, "maxiter": 500})
    assert res.success
    assert float(info.objective) <= res.fun * (1 + 1e-9)
    np.testing.assert_allclose(phi, res.x, atol=1e-5)
    # KKT: ∇J = Dᵀμ + Eᵀν with μ ≥ 0 on the active monotone constraints only.
    grad = 2 * C.T @ (C @ phi - d)
    active = D @ phi <= 1e-10
    K = np.concatenate([D[active].T, E[row][:, None]], axis=1)
    mult, *_ = np.linalg.lstsq(K, grad, rcond=None)
    assert np.linalg.norm(K @ mult - grad) <= 1e-7 * (1 + np.linalg.norm(grad))
    assert np.all(mult[:-1] >= -1e-7)


def test_infeasible_goal_constraint_reported_and_penalised():
    """A circular arc curving into its goal leaves a sideways goal gradient no monotone biases
    can cancel: eq 4.12 is infeasible, which is reported; the biases then solve the penalised
    problem ``J + μ‖∇Φ(ζ_T)‖²`` (checked with SciPy's NNLS) and stay monotone."""
    traj, p, info = fitted("arc")
    A, b, C, d = np_problem(traj)
    E, e = A[-1], -b[-1]
    V = np.cumsum(E, axis=1)
    V[:, -1] = 0.0                         # Σ_t ∇w_t = 0 (round-off removed)
    _, gap = scipy_nnls(V, e)
    assert gap > 1e-3                      # independent infeasibility certificate
    assert not bool(info.feasible) and not bool(info.exact) and int(info.status) == 0
    assert_monotone(p.biases)
    U = np.triu(np.ones((T, T)))
    mu = 1e4
    beta, _ = scipy_nnls(np.concatenate([C @ U, np.sqrt(mu) * V]),
                         np.concatenate([d, np.sqrt(mu) * e]))
    np.testing.assert_allclose(np.asarray(p.biases), U @ beta, rtol=1e-6, atol=1e-8)
    assert float(info.goal_gradient) == pytest.approx(np.linalg.norm(E @ (U @ beta) - e),
                                                      rel=1e-6)
    assert float(info.goal_gradient) < 0.05


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), mode=st.sampled_from(["auto", "none"]))
def test_fitted_biases_monotone_for_random_curves(seed, mode):
    rng = np.random.default_rng(seed)
    # a random smooth planar curve ending at the origin
    s = np.linspace(0.0, 1.0, T)[:, None]
    coef = rng.normal(size=(3, 2)) * np.array([[0.6], [0.3], [0.15]])
    traj = sum(c * np.sin((k + 1) * np.pi * (1 - s) / 2) for k, c in enumerate(coef))
    p, info = fitter(mode)(jnp.asarray(traj), DT)
    assert int(info.status) == 0
    assert_monotone(p.biases)
    assert np.all(np.isfinite(np.asarray(p.biases)))


# --- the potential -----------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["line", "arc"])
def test_potential_nonnegative_zero_at_goal_and_decreasing(kind):
    traj, p, _ = fitted(kind)
    V = jax.jit(nm.nominal_potential)
    assert abs(float(V(p, traj[-1]))) < 1e-14
    g = np.linspace(-1.0, 1.2, 89)
    grid = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    assert float(jnp.min(V(p, grid))) >= -1e-12
    # along the nominal trajectory the potential decreases strictly towards the goal …
    along = np.asarray(V(p, traj))
    assert np.all(np.diff(along) < 0)
    # … and −∇Φ points along the demonstrated motion (eq 4.12's fit), except at the goal
    grad = np.asarray(jax.jit(nm.nominal_potential_gradient)(p, traj))[:-1]
    vel = np.gradient(traj, DT, axis=0)[:-1]
    cos = np.sum(-grad * vel, 1) / np.linalg.norm(grad, axis=1) / np.linalg.norm(vel, axis=1)
    assert np.all(cos > 0.95)
    # eq 4.9 in NumPy (before the offset) agrees
    x = np.array([0.3, -0.2])
    ref = np_potential(traj, np.asarray(p.biases), x) - float(p.offset)
    assert float(V(p, x)) == pytest.approx(ref, rel=1e-12)


coord = st.floats(-1.0, 1.0, allow_nan=False, allow_subnormal=False)


@settings(max_examples=40, deadline=None)
@given(kind=st.sampled_from(["line", "arc"]), x=st.tuples(coord, coord).map(np.array))
def test_gradient_matches_finite_differences(kind, x):
    traj, p, _ = fitted(kind)
    grad = np.asarray(_grad(p, x))
    h = 1e-6
    fd = np.array([(np_potential(traj, np.asarray(p.biases), x + h * e)
                    - np_potential(traj, np.asarray(p.biases), x - h * e)) / (2 * h)
                   for e in np.eye(2)])
    np.testing.assert_allclose(grad, fd, atol=1e-7 * (1 + np.abs(fd).max()))
    np.testing.assert_allclose(np.asarray(_autodiff(p, x)), grad, atol=1e-12)
    perp, par = _parts(p, x)
    np.testing.assert_allclose(np.asarray(perp + par), grad, atol=1e-14)


_grad = jax.jit(nm.nominal_potential_gradient)
_autodiff = jax.jit(jax.grad(nm.nominal_potential, argnums=1))
_parts = jax.jit(nm.nominal_potential_gradient_parts)


def test_goal_is_stationary_and_gradient_is_finite_on_the_centres():
    traj, p, _ = fitted("line")
    np.testing.assert_allclose(np.asarray(_grad(p, traj[-1])), 0.0, atol=1e-10)
    assert np.all(np.isfinite(np.asarray(_autodiff(p, traj[5]))))


def test_vmap_over_points_and_potentials():
    _, p_line, _ = fitted("line")
    _, p_arc, _ = fitted("arc")
    pts = jnp.asarray(np.random.default_rng(1).uniform(-1, 1, (7, 2)))
    over_points = jax.jit(jax.vmap(nm.nominal_potential, in_axes=(None, 0)))
    np.testing.assert_allclose(np.asarray(over_points(p_line, pts)),
                               [np_potential(line(), np.asarray(p_line.biases), x)
                                - float(p_line.offset) for x in np.asarray(pts)], rtol=1e-12)
    both = jax.tree.map(lambda a, b: jnp.stack([jnp.asarray(a), jnp.asarray(b)]), p_line, p_arc)
    over_potentials = jax.jit(jax.vmap(nm.nominal_potential_gradient, in_axes=(0, None)))
    out = over_potentials(both, pts[0])
    np.testing.assert_allclose(np.asarray(out[1]), np.asarray(_grad(p_arc, pts[0])), rtol=1e-12)


# --- DTW nominal (§5.2.1) ----------------------------------------------------------------------


def test_select_nominal_by_mean_dtw():
    """Parallel copies of a segment shifted by ``c_i δ`` across it: on equal sampling the DTW
    distance is ``T|c_i − c_j|δ`` (the diagonal path), so the mean is least at the median
    shift, here demonstration 3."""
    n = 20
    s = np.linspace(0, 1, n)
    base = np.stack([s, np.zeros(n)], axis=1)
    shifts = np.array([-1.0, 6.0, -2.0, 0.5, 1.0])
    delta = 0.01
    demos = [base + np.array([0.0, c * delta]) for c in shifts]
    index, mean = nominal_fit.select_nominal(demos)
    assert index == 3
    expect = n * delta * np.abs(shifts[:, None] - shifts[None]).sum(1) / (len(shifts) - 1)
    np.testing.assert_allclose(mean, expect, rtol=1e-12)
    j_index, j_mean = jax.jit(nominal_fit.select_nominal_jax)(jnp.asarray(np.stack(demos)))
    assert int(j_index) == 3
    np.testing.assert_allclose(np.asarray(j_mean), expect, rtol=1e-10)
    # unequal lengths (NumPy version): a longer, resampled outlier changes nothing
    demos[1] = np.stack([np.linspace(0, 1, 31), np.full(31, 6.0 * delta)], axis=1)
    assert nominal_fit.select_nominal(demos)[0] == 3
    assert nominal_fit.select_nominal(demos[:1])[0] == 0
