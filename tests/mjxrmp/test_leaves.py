"""Hand-designed leaf RMPs: metric properties, formulas against NumPy, parameter validation."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mjxrmp import policies
from mjxrmp.leaves import hand_designed as leaves

N = 6
floats = st.floats(-3.0, 3.0, allow_nan=False, width=32)


def family(m):
    return arrays(np.float32, (N, m), elements=floats)


def assert_symmetric_psd(M):
    M = np.asarray(M, np.float64)
    assert np.all(np.isfinite(M))
    np.testing.assert_allclose(M, np.swapaxes(M, -1, -2), rtol=1e-6, atol=1e-6)
    for Mi in M:
        eig = np.linalg.eigvalsh(Mi)
        assert eig.min() >= -1e-5 * max(1.0, np.abs(eig).max())


_target = jax.jit(leaves.target_rmp)
_collision = jax.jit(leaves.collision_rmp)
_joint_limit = jax.jit(leaves.joint_limit_rmp)
_cap = jax.jit(leaves.velocity_cap_rmp)
_damping = jax.jit(leaves.damping_rmp)
_cspace = jax.jit(leaves.cspace_target_rmp)

ALL_PARAMS = [policies.three_link_config(v) for v in policies.VARIANTS] + [
    policies.franka_config(v) for v in policies.VARIANTS
]


@settings(max_examples=40, deadline=None)
@given(x=family(3), xd=family(3), goal=arrays(np.float32, (3,), elements=floats))
def test_target_metric_symmetric_psd(x, xd, goal):
    for cfg in ALL_PARAMS:
        assert_symmetric_psd(_target(x, xd, goal, cfg.target).M)


@settings(max_examples=40, deadline=None)
@given(x=family(1), xd=family(1))
def test_scalar_metrics_nonnegative(x, xd):
    for cfg in ALL_PARAMS:
        for fn, p in ((_collision, cfg.collision), (_cap, cfg.velocity_cap)):
            assert_symmetric_psd(fn(x, xd, p).M)
        if cfg.joint_limit is not None:
            assert_symmetric_psd(_joint_limit(x, xd, cfg.joint_limit).M)


@settings(max_examples=40, deadline=None)
@given(x=family(7), xd=family(7))
def test_joint_space_metrics_symmetric_psd(x, xd):
    for cfg in ALL_PARAMS:
        assert_symmetric_psd(_damping(x, xd, cfg.damping).M)
        if cfg.cspace_target is not None:
            assert_symmetric_psd(_cspace(x, xd, cfg.cspace_target).M)


# ---------------------------------------------------------------------------------------------
# Formulas written out in NumPy scalars (docs/design.md §4.1) as the independent reference.
# ---------------------------------------------------------------------------------------------


def np_target(x, xd, g, p):
    delta = g - x
    dist = np.linalg.norm(delta)
    a = p.k_p * delta / (dist + p.eps) - p.k_d * xd
    alpha = (1 - p.alpha_min) * math.exp(-0.5 * (dist / p.length_scale) ** 2) + p.alpha_min
    dh = delta / max(dist, p.eps / 10)
    M0 = alpha * p.s_max * np.eye(len(x)) + (1 - alpha) * p.s_min * np.outer(dh, dh)
    eb = math.exp(-0.5 * (dist / p.boost_length_scale) ** 2)
    M = (p.boost * eb + 1 - eb) * M0
    return M, M @ a


def np_collision(x, xd, p):
    s = max(x - p.margin, 0.0)
    gate = (s / p.modulation_radius) ** 2 - 2 * s / p.modulation_radius + 1
    gate = gate if s <= p.modulation_radius else 0.0
    sv = 1 / (1 + math.exp(-xd / p.velocity_gate_length))
    w = (1 - sv) * p.metric_scalar / (s / p.metric_std + p.metric_eps) * gate
    a = p.repulsion_gain * math.exp(-s / p.repulsion_std) - (1 - sv) * p.damping_gain * xd / (
        s / p.damping_std + p.damping_eps
    )
    return w, w * a


def np_velocity_cap(xd, p):
    cutoff = p.max_velocity - p.damping_region
    if abs(xd) < cutoff:
        return 0.0, 0.0
    ratio = min(abs(xd) - cutoff, p.damping_region - 1e-6) / p.damping_region
    w = p.metric_weight / (1 - ratio**2)
    return w, w * -abs(p.damping_gain * (abs(xd) - cutoff)) * np.sign(xd)


def test_leaf_formulas_match_numpy_reference():
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        for cfg in (policies.franka_config(), policies.three_link_config()):
            for _ in range(20):
                x, xd, g = rng.normal(size=(3, 3)) * 0.3
                M, f = leaves.target_rmp(jnp.asarray(x[None]), jnp.asarray(xd[None]),
                                         jnp.asarray(g), cfg.target)
                M_ref, f_ref = np_target(x, xd, g, cfg.target)
                np.testing.assert_allclose(M[0], M_ref, rtol=1e-12)
                np.testing.assert_allclose(f[0], f_ref, rtol=1e-12, atol=1e-12)
            d = rng.uniform(-0.05, 0.7, size=50)
            dd = rng.normal(size=50)
            M, f = leaves.collision_rmp(jnp.asarray(d[:, None]), jnp.asarray(dd[:, None]),
                                        cfg.collision)
            ref = np.array([np_collision(a, b, cfg.collision) for a, b in zip(d, dd, strict=True)])
            np.testing.assert_allclose(M[:, 0, 0], ref[:, 0], rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(f[:, 0], ref[:, 1], rtol=1e-10, atol=1e-12)
            v = rng.uniform(-2.0, 2.0, size=50)
            M, f = leaves.velocity_cap_rmp(jnp.zeros((50, 1)), jnp.asarray(v[:, None]),
                                           cfg.velocity_cap)
            ref = np.array([np_velocity_cap(b, cfg.velocity_cap) for b in v])
            np.testing.assert_allclose(M[:, 0, 0], ref[:, 0], rtol=1e-10)
            np.testing.assert_allclose(f[:, 0], ref[:, 1], rtol=1e-10, atol=1e-12)


def test_damping_and_cspace_closed_forms():
    with jax.enable_x64(True):
        p = leaves.DampingParams()
        xd = jnp.array([[0.3, -0.4, 0.0, 0.0, 0.0, 0.0, 1.2]])
        M, f = leaves.damping_rmp(jnp.zeros_like(xd), xd, p)
        speed = 1.3
        np.testing.assert_allclose(M[0], (0.005 * speed + 0.3) * np.eye(7))
        np.testing.assert_allclose(f[0], (0.005 * speed + 0.3) * -30 * speed * np.asarray(xd[0]))
        c = leaves.CSpaceTargetParams()
        near = jnp.full((1, 7), 0.1)  # ‖x‖ = 0.26 < θ = 0.5
        far = jnp.full((1, 7), 0.3)  # ‖x‖ = 0.79 ≥ θ
        w = 0.005 + 0.0001
        np.testing.assert_allclose(leaves.cspace_target_rmp(near, 0 * near, c).f[0],
                                   w * -100 * np.asarray(near[0]))
        x_hat = np.asarray(far[0]) / np.linalg.norm(far[0])
        np.testing.assert_allclose(leaves.cspace_target_rmp(far, 0 * far, c).f[0],
                                   w * -100 * 0.5 * x_hat)


def test_leaves_are_nan_free_at_singular_points():
    zero3 = jnp.zeros((1, 3))
    for fn, args in (
        (leaves.target_rmp, (zero3, zero3, jnp.zeros(3), leaves.TargetParams())),
        (leaves.damping_rmp, (zero3, zero3, leaves.DampingParams())),
        (leaves.cspace_target_rmp, (zero3, zero3, leaves.CSpaceTargetParams())),
        (leaves.collision_rmp, (jnp.zeros((1, 1)), jnp.zeros((1, 1)), leaves.CollisionParams())),
    ):
        out, grads = jax.value_and_grad(lambda *a, fn=fn: jnp.sum(fn(*a).f) + jnp.sum(fn(*a).M),
                                        argnums=(0, 1))(*args)
        assert np.isfinite(out)
        assert all(np.all(np.isfinite(g)) for g in grads)


def test_presets_reproduce_original_values():
    f = policies.franka_config()
    assert (f.cspace_target.k_p, f.cspace_target.k_d) == (100.0, 50.0)
    assert f.joint_limit.damping_gain == 200.0 and f.velocity_cap.max_velocity == 1.7
    assert f.target.boost == 3.0 and f.collision.repulsion_gain == 800.0
    assert f.joint_limit_buffers == (0.01, 0.03, 0.01, 0.01, 0.01, 0.01, 0.01)
    r = policies.franka_config("residual_base")
    assert (r.cspace_target.k_p, r.target.k_p, r.target.boost, r.damping.damping_gain) == (
        1.0, 0.5, 1.0, 1.0)
    t = policies.three_link_config()
    assert t.cspace_target is None and t.joint_limit is None
    assert (t.target.boost, t.velocity_cap.max_velocity) == (20.0, 1.0)
    assert t.damping.damping_gain == 30.0
    # The one documented departure: the 3-link collision metric length scale (every variant)
    # (original 0.02, 0.1 for the ±1 rad/s² action clip); everything else is the original.
    assert t.collision == leaves.CollisionParams(metric_std=0.1)
    assert leaves.CollisionParams().metric_std == 0.02
    tr = policies.three_link_config("residual_rmp")
    assert (tr.target.k_p, tr.target.k_d, tr.target.boost) == (5.0, 10.0, 5.0)
    assert tr.velocity_cap.damping_region == 0.1 and tr.damping.damping_gain == 5.0
    for variant in ("residual_base", "residual_rmp"):
        assert policies.three_link_config(variant).collision == leaves.CollisionParams(
            metric_std=0.1)
    assert f.collision == leaves.CollisionParams()


@pytest.mark.parametrize("cls", [leaves.TargetParams, leaves.CollisionParams,
                                 leaves.JointLimitParams, leaves.VelocityCapParams,
                                 leaves.DampingParams, leaves.CSpaceTargetParams])
def test_negative_parameter_is_refused_by_name(cls):
    name = dataclasses.fields(cls)[1].name
    with pytest.raises(ValueError, match=rf"{cls.__name__}\.{name} must be >= 0"):
        cls(**{name: -1.0})


def test_params_are_hashable_frozen_pytrees():
    p = leaves.TargetParams()
    assert hash(p) == hash(leaves.TargetParams())
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.k_p = 3.0
    doubled = jax.tree.map(lambda v: 2 * v, p)
    assert isinstance(doubled, leaves.TargetParams) and doubled.k_p == 100.0
