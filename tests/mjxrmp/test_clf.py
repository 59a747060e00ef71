"""RMP²-CLF leaves (thesis eqs 3.29–3.32): the CLF constraint, minimal invasiveness, nominals."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mjxrmp  # noqa: F401  (XLA flags first)
from mjxrmp.core import rmp2
from mjxrmp.leaves.clf import (
    clf_leaf,
    linear_alpha,
    potential_nominal,
    quadratic_alpha,
    sinusoidal_nominal,
    spiral_nominal,
)
from mjxrmp.leaves.gds import curvature_terms, family, subtask_energy
from mjxrmp.leaves.point_robot import (
    CollisionParams,
    GoalAttractorParams,
    collision_avoidance,
    collision_metric,
    collision_potential,
    goal_metric,
    goal_potential,
    goal_weight,
    obstacle_distance,
)


@pytest.fixture(autouse=True, scope="module")
def _x64():
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", False)


GOAL = GoalAttractorParams()
ALPHA_GAMMA = 1.5


def _vel_metric(x, xd):
    """A velocity-dependent metric: G = (1 + ‖ẋ‖²)(I + ½ x xᵀ)."""
    return (1.0 + xd @ xd) * (jnp.eye(2, dtype=x.dtype) + 0.5 * jnp.outer(x, x))


def _quad_potential(x):
    return 0.5 * (2.0 * x[0] ** 2 + x[1] ** 2) + jnp.sin(x[0] * x[1])


SUBTASKS = {"goal": (goal_metric(GOAL), goal_potential(GOAL)),
            "velocity": (_vel_metric, _quad_potential)}


def _bound_reference(kind, x, xd, speed):
    """Right-hand side of eq 3.30, ``b = −ẋᵀ(∇Φ + ξ_G) − α(s)``, computed independently."""
    alpha = quadratic_alpha(ALPHA_GAMMA)
    if kind == "goal":  # published closed forms (RMPflow)
        r = jnp.linalg.norm(x)
        w = goal_weight(GOAL, x)
        grad_phi = GOAL.gain * w * jnp.tanh(GOAL.alpha * r) / r * x
        grad_w = -(w - GOAL.w_l) / GOAL.sigma**2 * x
        xi = (xd @ grad_w) * xd - 0.5 * (xd @ xd) * grad_w
        G = w * jnp.eye(2)
    else:
        G_fn, Phi = SUBTASKS[kind]
        grad_phi = jax.grad(Phi)(x)
        _, xi = curvature_terms(G_fn, x, xd)
        G = G_fn(x, xd)
    s = jnp.sqrt(xd @ xd) if speed == "euclidean" else jnp.sqrt(xd @ G @ xd)
    return -xd @ (grad_phi + xi) - alpha(s)


def _make_eval(kind, P, speed):
    G, Phi = SUBTASKS[kind]

    @jax.jit
    def evaluate(x, xd, f0):
        leaf = clf_leaf(lambda x_, xd_: f0, G, Phi, quadratic_alpha(ALPHA_GAMMA), P=P,
                        speed=speed)
        M, f = leaf(x, xd)
        return M, f, _bound_reference(kind, x, xd, speed)

    return evaluate


EVALS = {(k, P, s): _make_eval(k, P, s) for k in SUBTASKS
         for P in ("identity", "inverse_metric") for s in ("euclidean", "metric")}

coord = st.floats(-3.0, 3.0, allow_nan=False, allow_subnormal=False)
vel = st.one_of(st.floats(-3.0, 3.0, allow_nan=False, allow_subnormal=False),
                st.sampled_from([0.0, 1e-9, -1e-6]))
force = st.floats(-50.0, 50.0, allow_nan=False, allow_subnormal=False)
vec = lambda s: st.tuples(s, s).map(np.array)  # noqa: E731
kinds = st.sampled_from(sorted(EVALS))


def _offset_from_goal(x):
    # the attractor's potential gradient uses x/‖x‖ (smooth at 0 anyway); keep away from it
    return x if np.linalg.norm(x) > 1e-3 else x + 0.5


@settings(max_examples=300, deadline=None)
@given(key=kinds, x=vec(coord), xd=vec(vel), f0=vec(force))
def test_clf_leaf_satisfies_constraint_3_30(key, x, xd, f0):
    _, P, _ = key
    x = _offset_from_goal(x)
    M, f, b = (np.asarray(a) for a in EVALS[key](x, xd, f0))
    assert np.all(np.isfinite(M)) and np.all(np.isfinite(f))
    scale = 1.0 + abs(float(b)) + np.linalg.norm(xd) * (np.linalg.norm(f0) + np.linalg.norm(f))
    assert xd @ f <= b + 1e-9 * scale
    # minimally invasive (KKT of eq 3.32): f* − f0 = −λ P⁻¹ẋ with λ ≥ 0, active if λ > 0
    d = xd if P == "identity" else M @ xd
    delta = f - f0
    assert abs(delta[0] * d[1] - delta[1] * d[0]) <= 1e-9 * (1 + np.linalg.norm(delta)) * (
        1 + np.linalg.norm(d))
    assert delta @ d <= 1e-12 * scale
    if np.linalg.norm(delta) > 1e-9 * scale:
        assert abs(xd @ f - b) <= 1e-8 * scale


@settings(max_examples=200, deadline=None)
@given(key=kinds, x=vec(coord), xd=vec(st.floats(-3.0, 3.0).filter(lambda v: abs(v) > 1e-3)),
       g=vec(force), margin=st.floats(0.0, 5.0))
def test_clf_leaf_keeps_a_nominal_that_satisfies_the_constraint(key, x, xd, g, margin):
    x = _offset_from_goal(x)
    _, _, b = EVALS[key](x, xd, jnp.asarray(g))
    # make f0 = g − c ẋ satisfy ẋᵀf0 ≤ b strictly
    c = max(0.0, (xd @ g - float(b)) / (xd @ xd)) + margin + 1e-6
    f0 = g - c * xd
    _, f, _ = EVALS[key](x, xd, jnp.asarray(f0))
    np.testing.assert_array_equal(np.asarray(f), f0)


_COLLISION_GDS = jax.jit(collision_avoidance())
_COLLISION_CLF = jax.jit(clf_leaf(lambda a, b: jnp.zeros(1), collision_metric(CollisionParams()),
                                  collision_potential(CollisionParams())))


@settings(max_examples=100, deadline=None)
@given(x=vec(coord), xd=vec(vel), s=st.floats(-2.0, 5.0), sd=st.floats(-3.0, 3.0))
def test_inertia_symmetric_psd(x, xd, s, sd):
    x = _offset_from_goal(x)
    M, _, _ = EVALS[("goal", "identity", "euclidean")](x, xd, jnp.zeros(2))
    M = np.asarray(M)
    np.testing.assert_allclose(M, M.T, atol=0)
    assert np.linalg.eigvalsh(M).min() >= 0.0
    # the RMPflow collision metric: M = w(ε + 2 min(0, ẋ)ẋ) ≥ 0 (1×1); through a CLF leaf too
    Mc, _ = _COLLISION_GDS(jnp.array([s]), jnp.array([sd]))
    assert float(Mc[0, 0]) >= 0.0
    Mc2, _ = _COLLISION_CLF(jnp.array([abs(s) + 0.1]), jnp.array([sd]))
    assert float(Mc2[0, 0]) >= 0.0


@pytest.mark.parametrize("P", ["identity", "inverse_metric"])
def test_zero_velocity_is_trivial_and_differentiable(P):
    G, Phi = goal_metric(GOAL), goal_potential(GOAL)
    leaf = clf_leaf(spiral_nominal(Phi), G, Phi, quadratic_alpha(2.0), P=P)
    x = jnp.array([0.8, -0.4])

    @jax.jit
    def check(x, v):
        return (leaf(x, v).f, jax.jacfwd(lambda v_: leaf(x, v_).f)(v),
                jax.jacfwd(lambda y: leaf(y, v).f)(x),
                jax.grad(lambda v_: jnp.sum(leaf(x, v_).f ** 2))(v))

    f, jac, jac_x, grad = check(x, jnp.zeros(2))
    np.testing.assert_allclose(f, -jax.grad(Phi)(x), rtol=1e-14)
    assert np.all(np.isfinite(jac)) and np.all(np.isfinite(jac_x)) and np.all(np.isfinite(grad))


def test_nominal_controllers_match_section_3_2_7():
    Phi = goal_potential(GOAL)
    x = jnp.array([1.2, 0.5])
    xd = jnp.array([0.3, -0.4])  # ‖ẋ‖ = 0.5
    grad = jax.grad(Phi)(x)
    v = -jnp.array([-grad[1], grad[0]])  # −R(π/2)∇Φ
    np.testing.assert_allclose(potential_nominal(Phi)(x, xd), -grad, rtol=1e-14)
    np.testing.assert_allclose(spiral_nominal(Phi)(x, xd), -grad + 0.5 * v, rtol=1e-14)
    np.testing.assert_allclose(spiral_nominal(Phi)(x, jnp.zeros(2)), -grad, rtol=1e-14)
    assert abs(float(v @ grad)) < 1e-12  # quarter turn
    # counter-clockwise: v = R(π/2)(−∇Φ) has a positive cross product with −∇Φ
    assert float(-grad[0] * v[1] + grad[1] * v[0]) > 0
    np.testing.assert_allclose(sinusoidal_nominal(Phi, 0.0)(x, xd), -grad, rtol=1e-14)
    np.testing.assert_allclose(sinusoidal_nominal(Phi, 2 * jnp.pi)(x, xd),
                               spiral_nominal(Phi)(x, xd), rtol=1e-12)
    np.testing.assert_allclose(sinusoidal_nominal(Phi, 1.0)(x, xd),
                               -grad + np.sin(0.25) * 0.5 * v, rtol=1e-12)


def test_bad_arguments_raise():
    G, Phi = goal_metric(GOAL), goal_potential(GOAL)
    with pytest.raises(ValueError, match="P must be"):
        clf_leaf(potential_nominal(Phi), G, Phi, P="cholesky")
    with pytest.raises(ValueError, match="speed"):
        clf_leaf(potential_nominal(Phi), G, Phi, speed="fast")
    with pytest.raises(ValueError, match="gamma"):
        quadratic_alpha(0.0)
    with pytest.raises(ValueError, match="gamma"):
        linear_alpha(-1.0)
    leaf = clf_leaf(lambda x, xd: jnp.zeros(3), G, Phi)
    with pytest.raises(ValueError, match="nominal"):
        leaf(jnp.ones(2), jnp.ones(2))


@pytest.mark.parametrize("nominal", ["spiral", "sinusoidal"])
def test_clf_closed_loop_energy_decreases(nominal):
    """Proposition 3.2.1 with RMP²-CLF goal leaf + GDS obstacle leaf: V̇ ≤ −α(‖ẋ‖) ≤ 0."""
    G, Phi = goal_metric(GOAL), goal_potential(GOAL)
    coll = CollisionParams(epsilon=0.2)
    goal, center = jnp.array([-3.0, 3.0]), jnp.array([0.0, 0.0])
    gamma = 2.0

    def task_map(q, t):
        Y = q.reshape(1, 2)
        return {"goal": Y - goal, "obstacle": obstacle_distance(Y, center, 1.0)}

    def leaf_fn(x, xd, t):
        nom = spiral_nominal(Phi) if nominal == "spiral" else sinusoidal_nominal(Phi, t)
        g = family(clf_leaf(nom, G, Phi, quadratic_alpha(gamma)))
        return {"goal": g(x["goal"], xd["goal"]),
                "obstacle": family(collision_avoidance(coll))(x["obstacle"], xd["obstacle"])}

    def accel(q, qd, t):
        M, f = rmp2.pullback(task_map, leaf_fn, q, qd, t)
        return jnp.linalg.solve(M, f)  # exact M⁻¹f (no resolve regularisation)

    def V(q, qd):
        xg, xo = q - goal, obstacle_distance(q[None], center, 1.0)[0]
        vo = jax.jvp(lambda y: obstacle_distance(y[None], center, 1.0)[0], (q,), (qd,))[1]
        return (subtask_energy(G, Phi, xg, qd)
                + subtask_energy(collision_metric(coll), collision_potential(coll), xo, vo))

    dt, steps = 0.005, 5000

    def step(s, k):
        q, qd, t = s
        # RK4 on the time-varying closed loop
        def deriv(q_, qd_, t_):
            return qd_, accel(q_, qd_, t_)
        k1 = deriv(q, qd, t)
        k2 = deriv(q + 0.5 * dt * k1[0], qd + 0.5 * dt * k1[1], t + 0.5 * dt)
        k3 = deriv(q + 0.5 * dt * k2[0], qd + 0.5 * dt * k2[1], t + 0.5 * dt)
        k4 = deriv(q + dt * k3[0], qd + dt * k3[1], t + dt)
        q = q + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        qd = qd + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        return (q, qd, t + dt), (q, qd)

    q0, qd0 = jnp.array([2.5, -3.2]), jnp.array([-1.0, 1.0])

    @jax.jit
    def run():
        _, (qs, qds) = jax.lax.scan(step, (q0, qd0, jnp.zeros(())), jnp.arange(steps))
        qs = jnp.concatenate([q0[None], qs])
        qds = jnp.concatenate([qd0[None], qds])
        return qs, qds, jax.vmap(V)(qs, qds)

    qs, qds, Vs = (np.asarray(a) for a in run())
    assert np.all(np.isfinite(Vs))
    assert np.diff(Vs).max() <= 1e-7 * Vs[0]
    # the energy drop is at least the integral of α(‖ẋ‖) (eq 3.23), up to integration error
    dissipated = np.sum(gamma * np.sum(qds[:-1] ** 2, axis=1)) * dt
    assert Vs[0] - Vs[-1] >= 0.98 * dissipated
    # with α(‖ẋ‖) = γ‖ẋ‖² the final approach is slow (quadratic dissipation); it gets close
    assert Vs[-1] < 0.05 * Vs[0]
    assert np.linalg.norm(qs[-1] - np.asarray(goal)) < 0.5
    assert np.min(np.linalg.norm(qs, axis=1)) > 1.0  # never inside the obstacle
