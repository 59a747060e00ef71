"""The two-step strategy of thesis §5.2 (agents/lfd/two_step.py; executed by execution.py).

A hand-made set of five 3-D demonstrations (parallel bumps of known offsets) checks the DTW
nominal against a brute-force float64 DTW and the padded float32 potential against the float64
fit; a synthetic set whose velocities come from a known constant metric checks the eq 5.6 fit;
one tiny policy trained once per module on three real drawer demonstrations checks the stability
identity ``q̇ = (M + εI)⁻¹(−∇V)`` (so ``V̇ ≤ 0``) against a float64 NumPy resolve, and a rollout
with the execution leaves from a held-out start.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjxrmp  # noqa: F401  (XLA flags first)
from agents.lfd import config as C
from agents.lfd import execution, strategies
from agents.lfd import samples as lfd_samples
from agents.lfd import two_step as T2
from mjxrmp.data import franka_demos as fd
from mjxrmp.data.franka_demos import StackedDemos
from mjxrmp.geometry import make_obstacles
from mjxrmp.learned import nominal as nom
from mjxrmp.robots import franka

DT = 0.1
# Offsets of the five demonstrations' bumps, per control point: the DTW medoid is the middle
# offset (index 2, 3 and 1 for the three points).
OFFSETS = np.array([[0.0, 1.0, 2.0, 3.0, 5.0], [5.0, 0.0, 1.0, 2.0, 3.0],
                    [1.0, 2.0, 3.0, 5.0, 0.0]]).T                       # (N, K)
LENGTHS = (12, 12, 12, 11, 12)
# The potential and its gradient compiled once per dtype and shape (op by op they dominated).
POTENTIAL = jax.jit(nom.nominal_potential)
GRADIENT = jax.jit(nom.nominal_potential_gradient)


def _hand_made() -> StackedDemos:
    """Five demonstrations of three control points: ``x(s) = (1 − s)·a + c·sin(πs)·b`` ending
    at their goals, padded like :func:`mjxrmp.data.franka_demos.stack`."""
    N, T, K = len(LENGTHS), max(LENGTHS), 3
    a, b = np.array([0.3, 0.2, 0.1]), np.array([0.0, -0.02, 0.04])
    goals = np.array([[0.5, 0.0, 0.4], [0.5, 0.04, 0.5], [0.5, -0.04, 0.5]])
    points = np.zeros((N, T, K, 3))
    vel = np.zeros_like(points)
    mask = np.zeros((N, T))
    for i, n in enumerate(LENGTHS):
        s = np.linspace(0.0, 1.0, n)[:, None]
        for k in range(K):
            x = (1 - s) * a + OFFSETS[i, k] * np.sin(np.pi * s) * b + goals[k]
            points[i, :n, k] = x
            points[i, n:, k] = x[-1]
            vel[i, :n - 1, k] = np.diff(x, axis=0) / DT
        mask[i, :n] = 1.0
    f32 = lambda z: jnp.asarray(z, jnp.float32)  # noqa: E731
    zq = jnp.zeros((N, T, 7), jnp.float32)
    return StackedDemos(zq, zq, f32(points), f32(vel), f32(np.repeat(goals[None], N, 0)),
                        jnp.zeros((N, 7), jnp.float32), f32(mask), jnp.asarray(LENGTHS))


def _dtw(a: np.ndarray, b: np.ndarray) -> float:
    """Brute-force float64 DTW with Euclidean cost (the §5.2.1 dissimilarity)."""
    D = np.full((len(a) + 1, len(b) + 1), np.inf)
    D[0, 0] = 0.0
    for i in range(1, len(a) + 1):
        for j in range(1, len(b) + 1):
            D[i, j] = np.linalg.norm(a[i - 1] - b[j - 1]) + min(D[i - 1, j - 1], D[i - 1, j],
                                                                  D[i, j - 1])
    return float(D[-1, -1])


@pytest.fixture(scope="module")
def hand_made():
    return _hand_made()


@pytest.fixture(scope="module")
def hand_fit(hand_made):
    return T2.fit_nominal(hand_made, np.ones(5, bool))


@pytest.mark.parametrize("train", [(1, 1, 1, 1, 1), (1, 0, 0, 1, 1)])
def test_nominal_is_the_dtw_medoid(hand_made, train):
    train = np.asarray(train, bool)
    fit = T2.fit_nominal(hand_made, train)
    pts = np.asarray(hand_made.points, np.float64)
    members = np.flatnonzero(train)
    for k in range(3):
        trajs = [pts[i, :LENGTHS[i], k] for i in members]
        D = np.array([[_dtw(p, q) for q in trajs] for p in trajs])
        want = members[np.argmin(D.sum(axis=1))]
        assert int(fit.index[k]) == want
        # the middle offset among the training demonstrations
        offs = OFFSETS[members, k]
        assert want == members[np.argsort(offs)[len(offs) // 2]]
    assert np.asarray(fit.index).tolist() == ([2, 3, 1] if train.all() else [3, 4, 0])


def test_padded_float32_potential_equals_the_float64_fit(hand_made, hand_fit):
    pts = np.asarray(hand_made.points, np.float64)
    vel = np.asarray(hand_made.point_velocities, np.float64)
    rng = np.random.default_rng(0)
    for k in range(3):
        i = int(hand_fit.index[k])
        zeta = pts[i, :LENGTHS[i], k] - pts[i, LENGTHS[i] - 1, k]
        sigma = 2.0 * np.mean(np.linalg.norm(np.diff(zeta, axis=0), axis=1))
        with jax.enable_x64(True):
            # the library fit (its jitted wrapper in the module, to share the compilation)
            ref, _ = T2._fit_potential(jnp.asarray(zeta),
                                       velocities=jnp.asarray(vel[i, :LENGTHS[i], k]),
                                       sigma=sigma, eta=10.0, lam=1e-3)
            x = zeta[rng.integers(0, len(zeta), 32)] + 0.05 * rng.standard_normal((32, 3))
            g_ref = np.asarray(GRADIENT(ref, jnp.asarray(x)))
            v_ref = np.asarray(POTENTIAL(ref, jnp.asarray(x)))
        p = jax.tree.map(lambda a, k=k: a[k], hand_fit.potential)
        assert p.centers.shape == (12, 3) and p.centers.dtype == jnp.float32
        xf = jnp.asarray(x, jnp.float32)
        np.testing.assert_allclose(GRADIENT(p, xf), g_ref, rtol=1e-4, atol=1e-5)
        np.testing.assert_allclose(POTENTIAL(p, xf), v_ref, rtol=1e-4, atol=1e-5)
        # the goal is a zero of the potential (offset), padding included
        assert abs(float(POTENTIAL(p, jnp.zeros(3)))) < 1e-5


def test_metric_fit_by_eq_5_6_reduces_the_loss(hand_made, hand_fit):
    """Velocities ``ẋ = −G*⁻¹∇Φ(x)`` of a known constant metric ``G* = diag(4, 1, 0.25)`` at the
    demonstrations' samples: the loss at ``G = I`` matches a float64 NumPy evaluation, and 300
    Adam steps cut it by at least 100× (measured: ~2e4×). With zero iterations ``G = I``
    exactly and the leaf's velocity is ``−∇Φ``."""
    N, T = hand_made.mask.shape
    x = (hand_made.points - hand_made.goals[:, None]).reshape(N * T, 3, 3)
    grad = jax.jit(jax.vmap(nom.nominal_potential_gradient, in_axes=(0, 1), out_axes=1))(
        hand_fit.potential, x)
    G_star = np.diag([4.0, 1.0, 0.25])
    xd = -np.einsum("ab,skb->ska", np.linalg.inv(G_star), np.asarray(grad, np.float64))
    w = hand_made.mask.reshape(-1)
    z = jnp.zeros((N * T, 7))
    samples = lfd_samples.Samples(x, jnp.zeros((N * T, 3, 3, 7)), jnp.asarray(xd, jnp.float32),
                                  z, w)
    cfg = C.StrategyConfig.tiny("two_step", metric_hidden=(16, 16), metric_iterations=300,
                                metric_learning_rate=1e-2)
    res = jax.jit(T2.make_train(cfg))(jax.random.PRNGKey(0), samples, hand_fit)
    losses = np.asarray(res.metric_losses)
    e = -np.asarray(grad, np.float64) - xd                      # prediction error at G = I
    b = cfg.smooth_l1_beta
    sl1 = np.where(np.abs(e) < b, 0.5 * e * e / b, np.abs(e) - 0.5 * b).mean(axis=-1)  # (S, K)
    ref0 = (np.asarray(w)[:, None] * sl1).sum(0) / np.asarray(w).sum()
    np.testing.assert_allclose(losses[0], ref0.mean(), rtol=1e-4)
    assert losses[-1] < losses[0] / 100.0
    assert res.flow_losses.shape == (1,)
    np.testing.assert_allclose(res.flow_losses[0], np.mean(hand_fit.objective), rtol=1e-6)

    # a trained metric stays positive definite; at initialisation it is I and v = −∇Φ
    xs = jax.random.normal(jax.random.PRNGKey(1), (64, 3, 3)) * 0.3
    leaf_rmps = jax.jit(jax.vmap(lambda r, xx: T2.leaf_rmps(cfg, r, xx), in_axes=(None, 0)))
    G = leaf_rmps(res, xs).M
    assert float(jnp.min(jnp.linalg.eigvalsh(G))) > 0.0
    # importance normalisation: c_k = weighted mean of tr G_k/3 over the samples, and the leaf's
    # own velocity (eq 5.6's fit) is unchanged by it
    raw = np.asarray(jax.jit(jax.vmap(lambda mp, xk: cfg.metric.apply({"params": mp}, xk),
                                      in_axes=(0, 1), out_axes=1))(res.params["metric"],
                                                                   samples.x),
                     np.float64)                                            # (S, K, 3, 3)
    c_ref = (np.asarray(w)[:, None] * np.trace(raw, axis1=-2, axis2=-1) / 3).sum(0) / np.sum(w)
    np.testing.assert_allclose(res.params["scale"], c_ref, rtol=1e-5)
    assert np.all(np.asarray(res.params["scale"]) > 1.5)   # fitted G ≈ diag(4, 1, 0.25)·…
    rmp = leaf_rmps(res, samples.x[:16])
    v = np.linalg.solve(np.asarray(rmp.M, np.float64), np.asarray(rmp.f, np.float64)[..., None])
    v_raw = np.linalg.solve(raw[:16], -np.asarray(grad, np.float64)[:16, ..., None])
    np.testing.assert_allclose(v[..., 0], v_raw[..., 0], rtol=1e-4, atol=1e-6)
    res0 = jax.jit(T2.make_train(cfg.replace(metric_iterations=0)))(jax.random.PRNGKey(0),
                                                                    samples, hand_fit)
    rmp = leaf_rmps(res0, xs)
    np.testing.assert_allclose(rmp.M, np.broadcast_to(np.eye(3), rmp.M.shape), atol=1e-6)
    v = jnp.linalg.solve(rmp.M, rmp.f[..., None])[..., 0]
    autodiff = jax.jit(jax.vmap(jax.vmap(jax.grad(nom.nominal_potential, argnums=1)),
                                in_axes=(None, 0)))(hand_fit.potential, xs)
    np.testing.assert_allclose(v, -autodiff, rtol=1e-4, atol=1e-5)


# ---------------------------------------------------------------------------------------------
# Real demonstrations: one tiny policy per module
# ---------------------------------------------------------------------------------------------

needs_data = pytest.mark.skipif(not os.path.isdir(fd.DEFAULT_ROOT),
                                reason="Franka demonstrations not available")


@pytest.fixture(scope="module")
def trained():
    stacked = fd.stack(fd.load_task("drawer_closing", dt=0.5)[:3])
    cfg = C.StrategyConfig.tiny("two_step", metric_hidden=(16, 16), metric_iterations=100)
    samples = lfd_samples.make_samples(cfg, stacked)
    train_sets = np.array([[True, True, False], [True, False, True]])
    keys = jnp.stack([jax.random.PRNGKey(0), jax.random.PRNGKey(1)])
    res, nominal = T2.train_folds(cfg, stacked, samples, train_sets, keys)
    first = jax.tree.map(lambda a: a[0], res)
    return cfg, stacked, first, res, nominal


@needs_data
def test_folds_match_separate_runs_and_make_train_refuses(trained):
    cfg, stacked, _, res, nominal = trained
    assert res.metric_losses.shape == (2, 100)
    assert np.all(np.asarray(res.metric_losses[:, -1]) < np.asarray(res.metric_losses[:, 0]))
    samples = lfd_samples.make_samples(cfg, stacked)
    one = T2.make_train(cfg)(jax.random.PRNGKey(0),
                             samples._replace(w=lfd_samples.fold_weights(stacked.mask, [1, 1, 0])),
                             jax.tree.map(lambda a: a[0], nominal))
    np.testing.assert_allclose(one.metric_losses, res.metric_losses[0], rtol=1e-4, atol=1e-6)
    with pytest.raises(ValueError, match="two_step"):
        strategies.make_train(cfg)
    with pytest.raises(ValueError, match="strategy='two_step'"):
        T2.make_train(C.StrategyConfig.tiny("joint"))
    with pytest.raises(ValueError, match="sigma_spacings"):
        C.NominalSettings(sigma_spacings=0.0)
    with pytest.raises(ValueError, match="train"):
        T2.fit_nominal(stacked, np.zeros(3, bool))


@needs_data
def test_policy_descends_the_lyapunov_function(trained):
    """``q̇ = (M + εI)⁻¹(−∇V)`` with ``M = Σ_k J_kᵀ(G_k + wI)J_k`` assembled in float64 NumPy, so
    ``V̇ = ∇Vᵀq̇ ≤ 0``, at 24 seeded random configurations."""
    cfg, stacked, res, _, _ = trained
    goals, q_goal = stacked.goals[2], stacked.q_goal[2]
    q0 = np.asarray(franka.DEFAULT_Q)
    qs = q0 + 0.4 * np.random.default_rng(3).standard_normal((24, 7))
    qd = jax.jit(jax.vmap(lambda q: execution.policy_velocity(cfg, res, q, goals, q_goal)))(qs)
    dV = jax.jit(jax.vmap(jax.grad(lambda q: T2.lyapunov(cfg, res, q, goals))))(qs)
    J = np.asarray(jax.jit(jax.vmap(jax.jacfwd(fd.hand_points)))(qs), np.float64)  # (B,K,3,7)
    x = np.asarray(jax.jit(jax.vmap(fd.hand_points))(qs)) - np.asarray(goals)
    G = np.asarray(jax.jit(jax.vmap(lambda xx: T2.leaf_rmps(cfg, res, xx).M))(jnp.asarray(x)),
                   np.float64)
    M = np.einsum("bkaq,bkac,bkcr->bqr", J, G + cfg.default_weight * np.eye(3), J)
    dV = np.asarray(dV, np.float64)
    ref = np.linalg.solve(M + cfg.regularization * np.eye(7), -dV[..., None])[..., 0]
    np.testing.assert_allclose(qd, ref, rtol=2e-3, atol=2e-4 * np.abs(ref).max())
    vdot = np.einsum("bq,bq->b", dV, np.asarray(qd, np.float64))
    assert np.all(vdot < 0.0)


@needs_data
def test_rollout_with_execution_leaves_converges_to_the_goals(trained):
    cfg, stacked, res, _, _ = trained
    goals, q_goal = stacked.goals[2], stacked.q_goal[2]
    obs = make_obstacles(jnp.asarray([[2.0, 2.0, 0.0]]), jnp.asarray([0.05]), jnp.asarray([0.0]))
    roll = jax.jit(lambda q0: execution.rollout(cfg, res, q0, goals, q_goal, 40, 0.25, obs,
                                        q_posture=stacked.q_goal[0])[0])
    qs = np.asarray(roll(stacked.q[2, 0]))
    pts = np.asarray(jax.vmap(fd.hand_points)(jnp.asarray(qs)))
    dist = np.linalg.norm(pts - np.asarray(goals), axis=-1).max(axis=-1)
    assert np.all(np.isfinite(qs))
    assert np.all((qs >= franka.Q_LOWER) & (qs <= franka.Q_UPPER))
    assert dist[-1] < 0.2 * dist[0] and dist[-1] < 0.05
