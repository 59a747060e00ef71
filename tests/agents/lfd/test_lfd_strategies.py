"""Learning RMP² policies from the Franka demonstrations (agents/lfd/strategies.py, policy.py,
execution.py, samples.py, optim.py; ch. 5).

Losses and the velocity-form resolve are checked against float64 references assembled
explicitly in NumPy from finite-difference Jacobians; one tiny joint policy is trained once per
module (two seeds in one vmapped program) for the stability and vmap checks.
"""

from __future__ import annotations

import contextlib
import os

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mjxrmp  # noqa: F401  (XLA flags first)
from agents.lfd import config as C
from agents.lfd import execution, optim, policy, strategies
from agents.lfd import samples as lfd_samples
from mjxrmp import policies
from mjxrmp.data import franka_demos as fd
from mjxrmp.geometry import make_obstacles
from mjxrmp.learned.flows import CONSTANTS
from mjxrmp.robots import franka

pytestmark = pytest.mark.skipif(not os.path.isdir(fd.DEFAULT_ROOT),
                                reason="Franka demonstrations not available")


@pytest.fixture(scope="module")
def stacked():
    return fd.stack(fd.load_task("drawer_closing", dt=0.5)[:3])


@contextlib.contextmanager
def _x64():
    jax.config.update("jax_enable_x64", True)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", False)


def _perturbed_params(config, key, scale=0.3):
    params, consts = policy.init_params(config, key)
    leaves, tree = jax.tree.flatten(params)
    keys = jax.random.split(jax.random.fold_in(key, 1), len(leaves))
    leaves = [a + scale * jax.random.normal(k, a.shape, a.dtype) for a, k in zip(leaves, keys,
                                                                                 strict=True)]
    return jax.tree.unflatten(tree, leaves), consts


def _f64(tree):
    return jax.tree.map(lambda a: np.asarray(a, np.float64) if a.dtype.kind == "f" else a, tree)


def _fd_jacobian(fn, z, h=1e-6):
    cols = [(fn(z + h * e) - fn(z - h * e)) / (2 * h) for e in np.eye(z.shape[0])]
    return np.stack(cols, axis=-1)


def _smooth_l1(e, beta):
    a = np.abs(e)
    return np.where(a < beta, 0.5 * e * e / beta, a - 0.5 * beta)


def _reference(config, params, consts):
    """``ref(q, goals, q_goal)``: float64 NumPy assembly of the strategy's pieces at one
    configuration: task coordinates ``x``, ``J_FK``, latent ``y``, ``J_ψ`` (finite differences
    through FK and the flows), the metrics and the resolved joint velocity of eq 5.1 with the
    default leaves and ``ε``. FK and the flows are only evaluated (jitted) by JAX."""
    flow, K = config.flow, config.num_leaves
    leaf = lambda tree, k: jax.tree.map(lambda a: a[k], tree)  # noqa: E731

    @jax.jit
    def task_j(qq, goals, q_goal):
        if config.strategy == "cspace":
            return (qq - q_goal)[None]
        pts = fd.hand_points(qq) - goals
        return pts[config.point:config.point + 1] if config.strategy == "single_link" else pts

    @jax.jit
    def phi_j(x):            # (K, m) -> φ_k(x_k) − φ_k(0) for every leaf
        return jnp.stack([flow.apply({"params": leaf(params["flow"], k),
                                      CONSTANTS: leaf(consts, k)}, x[k])
                          - flow.apply({"params": leaf(params["flow"], k),
                                        CONSTANTS: leaf(consts, k)}, jnp.zeros_like(x[k]))
                          for k in range(K)])

    def phi(k, z):           # leaf k's flow alone, for its Jacobian in x
        x = np.zeros((K, z.shape[0]))
        x[k] = z
        return np.asarray(phi_j(x))[k]

    def ref(q, goals, q_goal):
        task = lambda qq: np.asarray(task_j(qq, goals, q_goal))  # noqa: E731
        psi = lambda qq: np.asarray(phi_j(task_j(qq, goals, q_goal)))  # noqa: E731
        return _assemble(config, params, task, psi, phi, q)

    return ref


def _assemble(config, params, task, psi, phi, q):
    K, metric = config.num_leaves, config.metric
    leaf = lambda tree, k: jax.tree.map(lambda a: a[k], tree)  # noqa: E731
    x, y = task(q), psi(q)
    J_fk = _fd_jacobian(task, q)                       # (K, m, 7)
    J_psi = _fd_jacobian(psi, q)                       # (K, m, 7)
    J_phi = np.stack([_fd_jacobian(lambda z, k=k: phi(k, z), x[k]) for k in range(K)])
    G = np.stack([np.asarray(metric.apply({"params": leaf(params["metric"], k)},
                                          jnp.asarray(y[k]))) for k in range(K)])
    w, gam = config.default_weight, config.latent_gain
    M = sum(J_psi[k].T @ G[k] @ J_psi[k] + w * J_fk[k].T @ J_fk[k] for k in range(K))
    f = sum(J_psi[k].T @ (-gam * y[k]) - w * config.default_gain * J_fk[k].T @ x[k]
            for k in range(K))
    qd = np.linalg.solve(M + config.regularization * np.eye(7), f)
    xd_alone = np.stack([np.linalg.solve(J_phi[k], np.linalg.solve(G[k], -gam * y[k]))
                         for k in range(K)])
    return dict(x=x, J_fk=J_fk, J_psi=J_psi, G=G, M=M, f=f, qd=qd, xd_alone=xd_alone)


@pytest.mark.parametrize("strategy", ["joint", "independent"])
def test_loss_matches_float64_reference(stacked, strategy):
    """Eq 5.4 (joint) and eq 5.3 (independent). ``"cspace"`` (eq 5.2) and ``"single_link"`` are
    the same assembly with one leaf (different task coordinates); they pass too but cost 20 s
    more, so only the two multi-leaf losses run by default."""
    config = C.StrategyConfig.tiny(strategy, num_layers=2, metric_hidden=(4,))
    idx = [(0, 1), (1, 3), (2, 5)]
    with _x64():
        params, consts = _f64(_perturbed_params(config, jax.random.PRNGKey(3)))
        samples = _f64(lfd_samples.make_samples(config, stacked))
        T = stacked.mask.shape[1]
        rows = np.array([n * T + t for n, t in idx])  # samples.x/J/xd are float32 values
        samples = jax.tree.map(lambda a: a[rows], samples)._replace(w=np.array([1.0, 2.0, 0.5]))
        got = float(jax.jit(lambda p, c, sm: strategies.strategy_loss(config, p, c, sm))(
            params, consts, samples))
        reference = _reference(config, params, consts)
        tv = jax.jit(lambda x, J: policy.training_velocity(config, params, consts, x, J))
        per = []
        for (n, t) in idx:
            q = np.asarray(stacked.q[n, t], np.float64)
            ref = reference(q, np.asarray(stacked.goals[n], np.float64),
                            np.asarray(stacked.q_goal[n], np.float64))
            np.testing.assert_allclose(samples.J[len(per)], ref["J_fk"], atol=1e-6)
            np.testing.assert_allclose(samples.x[len(per)], ref["x"], atol=1e-6)
            if strategy in C.INDEPENDENT_STRATEGIES:
                k0 = config.point if strategy == "single_link" else slice(None)
                xd_demo = np.asarray(stacked.point_velocities[n, t], np.float64)[k0]
                err = ref["xd_alone"] - xd_demo.reshape(ref["xd_alone"].shape)
            else:
                qd_demo = np.asarray(stacked.qd[n, t], np.float64)
                err = np.einsum("kaq,q->ka", ref["J_fk"], ref["qd"] - qd_demo)
                np.testing.assert_allclose(tv(samples.x[len(per)], samples.J[len(per)]),
                                           ref["qd"], rtol=1e-4, atol=1e-7)
            per.append(np.mean(_smooth_l1(err, config.smooth_l1_beta)))
        want = np.sum(np.array([1.0, 2.0, 0.5]) * np.array(per)) / 3.5
    np.testing.assert_allclose(got, want, rtol=1e-4)


def test_velocity_form_resolve_is_the_pseudo_inverse(stacked):
    """With no default leaves and ``ε → 0`` eq 5.1's resolve is ``q̇ = (Σ J_kᵀG_kJ_k)⁺ Σ J_kᵀp_k``
    (the root is rank 6 < 7: three points on a rigid hand), via rmp2.pullback_velocity."""
    config = C.StrategyConfig.tiny("joint", num_layers=2, default_weight=0.0,
                                   regularization=1e-10)
    with _x64():
        params, consts = _f64(_perturbed_params(config, jax.random.PRNGKey(5)))
        result = policy.StrategyResult(params, consts, None, None)
        q = np.asarray(stacked.q[1, 4], np.float64)
        goals = np.asarray(stacked.goals[1], np.float64)
        qg = np.asarray(stacked.q_goal[1], np.float64)
        ref = _reference(config, params, consts)(q, goals, qg)
        assert np.linalg.matrix_rank(ref["M"], tol=1e-8 * np.abs(ref["M"]).max()) == 6
        pinv = np.linalg.pinv(ref["M"], rcond=1e-8) @ ref["f"]
        got = np.asarray(jax.jit(
            lambda qq: execution.policy_velocity(config, result, qq, goals, qg))(jnp.asarray(q)))
    # finite-difference Jacobians (error ~1e-9) amplified by the root's conditioning
    np.testing.assert_allclose(got, pinv, rtol=1e-4, atol=1e-6)
    # eq 5.1's optimality condition Σ J_kᵀG_k(J_k q̇ − v_k) = M q̇ − f = 0, v_k = −γG_k⁻¹y_k
    np.testing.assert_allclose(ref["M"] @ got, ref["f"], atol=1e-6 * np.abs(ref["f"]).max())


def _joint_limit_leaf_np(s, p):
    """NumPy restatement of the velocity-form joint-limit leaf (``ExecutionParams`` docstring)."""
    s = np.maximum(s, 0.0)
    act = np.maximum(1.0 - s / p.joint_limit_length, 0.0)
    m = p.joint_limit_scale * (act / (s / p.joint_limit_length + p.joint_limit_eps)) ** 2
    return m, m * p.joint_limit_speed * act


def test_execution_leaves_match_float64_reference(stacked):
    """Execution-time leaves (§5.2.3, §5.3.2) through rmp2.pullback_velocity: near two joint
    limits the root gains ``J_sᵀ diag(m(s)) J_s`` and ``J_sᵀ m(s)ṡ_d(s)`` (``J_s = [−I; I]``),
    the posture leaf ``w_c I`` and ``−w_c γ_c (q − q_p)``; an inactive obstacle adds nothing."""
    config = C.StrategyConfig.tiny("joint", num_layers=2)
    p = C.ExecutionParams(posture_weight=0.7, posture_gain=0.3)
    with _x64():
        params, consts = _f64(_perturbed_params(config, jax.random.PRNGKey(7)))
        result = policy.StrategyResult(params, consts, None, None)
        q = np.asarray(stacked.q[1, 4], np.float64).copy()
        q[3], q[5] = -0.09, 3.70          # 0.08 and 0.11 rad inside the buffered limits
        goals = np.asarray(stacked.goals[1], np.float64)
        qg = np.asarray(stacked.q_goal[1], np.float64)
        qp = qg + 0.1
        ref = _reference(config, params, consts)(q, goals, qg)
        buf = np.asarray(policies.FRANKA_JOINT_LIMIT_BUFFERS)
        s = np.concatenate([np.asarray(franka.Q_UPPER) - buf - q,
                            q - np.asarray(franka.Q_LOWER) - buf])
        m, fj = _joint_limit_leaf_np(s, p)
        assert np.count_nonzero(m) == 2
        Js = np.concatenate([-np.eye(7), np.eye(7)])
        M = ref["M"] + Js.T @ np.diag(m) @ Js + p.posture_weight * np.eye(7)
        f = ref["f"] + Js.T @ fj - p.posture_weight * p.posture_gain * (q - qp)
        want = np.linalg.solve(M + config.regularization * np.eye(7), f)
        obs = make_obstacles(jnp.zeros((1, 3)), jnp.asarray([0.05]), jnp.zeros((1,)))
        ex = execution.Execution(obs, jnp.zeros((7,)), 0.05, jnp.asarray(qp), p.posture_weight, p,
                         execution.execution_config())
        got = np.asarray(jax.jit(lambda qq: execution.policy_velocity(config, result, qq, goals, qg,
                                                              ex))(jnp.asarray(q)))
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)


# ---------------------------------------------------------------------------------------------
# One tiny trained joint policy (two seeds, one program)
# ---------------------------------------------------------------------------------------------

#: The preset of ``scripts/lfd_franka.py --quick`` (``strategies.fold_trainer`` caches its
#: program per configuration, so every test of this module with it compiles it once).
TINY = C.StrategyConfig.tiny("joint")


@pytest.fixture(scope="module")
def trained():
    stacked6 = fd.stack(fd.load_task("drawer_closing", dt=0.5))
    samples = lfd_samples.make_samples(TINY, stacked6)
    w = lfd_samples.fold_weights(stacked6.mask, jnp.arange(6) != 0)
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    both = strategies.fold_trainer(TINY)(keys, samples, jnp.stack([w, w]))
    return samples._replace(w=w), keys, both


def test_vmap_over_seeds_equals_separate_runs(trained):
    samples, keys, both = trained
    one = jax.jit(strategies.make_train(TINY))(keys[1], samples)
    for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(jax.tree.map(lambda x: x[1], both)),
                    strict=True):
        np.testing.assert_allclose(a, b, rtol=2e-4, atol=2e-6)
    assert float(both.flow_losses[0, -1]) < float(both.flow_losses[0, 0])
    assert not np.allclose(both.flow_losses[0], both.flow_losses[1])


@pytest.fixture(scope="module")
def rollout_fn(trained, stacked):
    result = jax.tree.map(lambda x: x[0], trained[2])
    goals, qg = stacked.goals[0], stacked.q_goal[0]

    @jax.jit
    def run(q0):
        qs, _ = execution.rollout(TINY, result, q0, goals, qg, 400, 0.05)
        pts = jax.vmap(fd.hand_points)(qs)
        return jnp.linalg.norm(pts - goals, axis=-1).max(axis=-1), qs

    return run


@settings(max_examples=5, deadline=None)
@given(st.lists(st.floats(-0.15, 0.15), min_size=7, max_size=7))
def test_learned_joint_policy_converges_from_perturbed_starts(rollout_fn, stacked, delta):
    """Stability of (*) for every θ: from perturbed starts the hand reaches its goals."""
    dist, qs = rollout_fn(stacked.q[0, 0] + jnp.asarray(delta, jnp.float32))
    dist = np.asarray(dist)
    assert np.all(np.isfinite(np.asarray(qs)))
    assert dist[-1] < 0.01 and dist[-1] < 0.05 * dist[0]
    # the distance keeps shrinking at the end (no limit cycle)
    assert dist[-1] <= dist[-100] + 1e-4


def test_execution_rollout_respects_joint_limits(trained, stacked):
    """With the execution-time leaves, starts inside the joint-limit buffers are pushed out of
    them and no joint ever leaves the model's limits (the barrier of ``ExecutionParams``)."""
    result = jax.tree.map(lambda x: x[0], trained[2])
    obs = make_obstacles(jnp.zeros((1, 3)), jnp.asarray([0.05]), jnp.zeros((1,)))
    q0 = np.asarray(stacked.q[0, 0]).copy()
    q0[3], q0[5] = -0.005, 3.82          # 5 mm inside the buffer of joint 4; at joint 6's limit
    qs, _ = jax.jit(lambda q: execution.rollout(TINY, result, q, stacked.goals[0],
                                                stacked.q_goal[0], 100, 0.05, obs))(
        jnp.asarray(q0, jnp.float32))
    qs = np.asarray(qs)
    s = np.asarray(jax.vmap(execution.joint_limit_distances)(jnp.asarray(qs)))[..., 0]
    assert np.all(np.isfinite(qs))
    assert np.all(qs >= np.asarray(franka.Q_LOWER)) and np.all(qs <= np.asarray(franka.Q_UPPER))
    assert s[0].min() < 0 and s[-1].min() > 0


def test_fit_early_stop_freezes_and_keeps_the_best_parameters():
    """``_fit`` with ``patience``: Adam at a large rate overshoots the minimum of
    ``(p - 3)²``; after ``patience`` steps without a lower loss the parameters freeze (the loss
    trace goes flat) and the parameters of the lowest loss are returned. Without it, the last."""
    def loss(p, _k):
        return (p - 3.0) ** 2

    tx = optax.adam(1.0)
    key = jax.random.PRNGKey(0)
    last, trace = optim.fit(loss, jnp.float32(0.0), tx, 40, key)
    best, trace_es = optim.fit(loss, jnp.float32(0.0), tx, 40, key, patience=3)
    trace, trace_es = np.asarray(trace), np.asarray(trace_es)
    first_worse = int(np.argmax(np.diff(trace) > 0)) + 1   # Adam overshoots after ~3 steps
    assert 0 < first_worse < 10
    i_best = int(np.argmin(trace_es))
    stop = i_best + 3 + 1    # patience steps without improvement, then frozen
    np.testing.assert_array_equal(trace_es[:stop], trace[:stop])
    assert np.all(trace_es[stop:] == trace_es[stop])          # frozen afterwards
    assert float(loss(best, None)) == pytest.approx(trace_es[i_best])
    assert np.ptp(trace[stop:]) > 0.01   # without patience it keeps moving
    assert float(loss(last, None)) != pytest.approx(float(loss(best, None)))
    with pytest.raises(ValueError, match="patience"):
        C.StrategyConfig(patience=0)
    ref = C.StrategyConfig.reference("joint")
    assert (ref.max_grad_norm, ref.patience, ref.num_layers) == (0.1, 250, 10)


def test_config_validation():
    with pytest.raises(ValueError, match="strategy must be one of"):
        C.StrategyConfig(strategy="bc")
    with pytest.raises(ValueError, match="regularization"):
        C.StrategyConfig(regularization=0.0)
    with pytest.raises(ValueError, match=r"StrategyConfig\.point \(a hand control point\) "
                                         r"must be one of \[0, 1, 2\]"):
        C.StrategyConfig(strategy="single_link", point=3)
    with pytest.raises(ValueError, match="metric_iterations"):
        C.StrategyConfig(metric_iterations=-1)
    with pytest.raises(ValueError, match=r"ExecutionParams\.joint_limit_length"):
        C.ExecutionParams(joint_limit_length=0.0)
    with pytest.raises(ValueError, match=r"ExecutionParams\.posture_weight"):
        C.ExecutionParams(posture_weight=-1.0)
    with pytest.raises(ValueError, match=r"ExecutionParams\.substeps"):
        C.ExecutionParams(substeps=0)


def test_train_rejects_wrong_sample_shapes(trained):
    samples = trained[0]
    with pytest.raises(ValueError, match=r"samples\.x must have shape"):
        strategies.make_train(C.StrategyConfig.tiny("cspace"))(jax.random.PRNGKey(0), samples)
