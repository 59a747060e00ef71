"""Hand-designed leaf RMPs of the RMPflow / RMP² family (docs/design.md §4.1, thesis §3.2.1).

Every leaf acts on a *family* of subtasks: ``x`` and ``xd`` have shape ``(n, m)`` and the result is
an :class:`~mjxrmp.core.rmp.RMP` in natural form with ``M (n, m, m)`` and ``f (n, m)``. Parameters
are frozen, validated pytree dataclasses whose defaults are the original Franka hand-designed values
(the 3-link and residual variants are built in :mod:`mjxrmp.policies`); fields a formula divides
by (length scales, epsilons, the modulation radius) are ``positive``: zero is refused.

Notation: ``σ`` is the logistic sigmoid; the smoothed norm is ``‖v‖_s = √(‖v‖² + 1e-4) − √1e-4``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mjxrmp.config import param_dataclass, positive
from mjxrmp.core.rmp import RMP

#: Smoothing constant of the point–obstacle distance norm.
SMOOTH_NORM_EPS = 1e-4


def smooth_norm(v: jax.Array, axis: int = -1) -> jax.Array:
    """Smoothed Euclidean norm ``√(‖v‖² + 1e-4) − √1e-4`` (differentiable at 0)."""
    return jnp.sqrt(jnp.sum(v * v, axis=axis) + SMOOTH_NORM_EPS) - jnp.sqrt(SMOOTH_NORM_EPS)


def safe_norm(v: jax.Array, axis: int = -1, keepdims: bool = False) -> jax.Array:
    """Euclidean norm whose gradient at ``v = 0`` is 0 instead of NaN."""
    sq = jnp.sum(v * v, axis=axis, keepdims=keepdims)
    positive = sq > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0)


def _diag_family(w: jax.Array, m: int) -> jax.Array:
    """``w[:, None, None] · I_m`` for a family of scalar weights ``w (n,)``."""
    return w[:, None, None] * jnp.eye(m, dtype=w.dtype)


# --------------------------------------------------------------------------------------------
# Target attractor
# --------------------------------------------------------------------------------------------


@param_dataclass
class TargetParams:
    """Goal attractor (end-effector position). Defaults: Franka hand-designed."""

    k_p: float = 50.0
    k_d: float = 70.0
    eps: float = positive(0.075)
    length_scale: float = positive(0.05)
    alpha_min: float = 0.03
    s_max: float = 1.0
    s_min: float = 0.5
    boost: float = 3.0
    boost_length_scale: float = positive(0.02)


def target_rmp(x: jax.Array, xd: jax.Array, goal: jax.Array, p: TargetParams) -> RMP:
    """Target attractor: ``a = k_p δ/(‖δ‖+ε) − k_d ẋ`` with ``δ = g − x`` and the directional,
    proximity-boosted metric ``M = boost·(α s_max I + (1−α) s_min δ̂δ̂ᵀ)`` (docs/design.md §4.1).

    ``goal`` broadcasts against ``x`` (shape ``(m,)`` or ``(n, m)``).
    """
    delta = goal - x
    dist = safe_norm(delta, keepdims=True)
    delta_hat = delta / jnp.maximum(dist, p.eps / 10.0)
    a = p.k_p * delta / (dist + p.eps) - p.k_d * xd
    alpha = (1.0 - p.alpha_min) * jnp.exp(-0.5 * (dist / p.length_scale) ** 2) + p.alpha_min
    m = x.shape[-1]
    eye = jnp.eye(m, dtype=x.dtype)
    outer = delta_hat[:, :, None] * delta_hat[:, None, :]
    alpha = alpha[:, :, None]
    M0 = alpha * p.s_max * eye + (1.0 - alpha) * p.s_min * outer
    e_b = jnp.exp(-0.5 * (dist / p.boost_length_scale) ** 2)
    boost = (p.boost * e_b + (1.0 - e_b))[:, :, None]
    M = boost * M0
    return RMP(M, jnp.sum(M * a[:, None, :], axis=-1))


# --------------------------------------------------------------------------------------------
# Collision avoidance (1-D distances)
# --------------------------------------------------------------------------------------------


@param_dataclass
class CollisionParams:
    """Obstacle avoidance on 1-D point–obstacle distances. Defaults: original (both robots)."""

    margin: float = 0.0
    damping_gain: float = 50.0
    damping_std: float = positive(0.04)
    damping_eps: float = positive(0.01)
    velocity_gate_length: float = positive(0.01)
    repulsion_gain: float = 800.0
    repulsion_std: float = positive(0.01)
    modulation_radius: float = positive(0.5)
    metric_scalar: float = 1.0
    metric_std: float = positive(0.02)
    metric_eps: float = positive(0.001)


def collision_rmp(x: jax.Array, xd: jax.Array, p: CollisionParams) -> RMP:
    """Collision avoidance on distances ``x (n, 1)`` (docs/design.md §4.1).

    With ``s = max(x − margin, 0)``, ``s_v = σ(ẋ/ℓ_v)`` and the gate
    ``(s/r)² − 2s/r + 1`` for ``s ≤ r`` (else 0):
    ``M = (1 − s_v)·scalar/(s/σ_e + ε_e)·gate`` and
    ``a = g_rep·exp(−s/σ_rep) − (1 − s_v)·g_damp·ẋ/(s/σ_d + ε_d)``.
    """
    s = jnp.maximum(x - p.margin, 0.0)
    r = p.modulation_radius
    gate = jnp.where(s > r, 0.0, (s / r) ** 2 - 2.0 * s / r + 1.0)
    open_gate = 1.0 - jax.nn.sigmoid(xd / p.velocity_gate_length)
    w = open_gate * p.metric_scalar / (s / p.metric_std + p.metric_eps) * gate
    a = p.repulsion_gain * jnp.exp(-s / p.repulsion_std) - open_gate * p.damping_gain * xd / (
        s / p.damping_std + p.damping_eps
    )
    return RMP(w[:, :, None], w * a)


# --------------------------------------------------------------------------------------------
# Joint limits, velocity cap, damping, configuration-space target (on q)
# --------------------------------------------------------------------------------------------


@param_dataclass
class JointLimitParams:
    """Joint-limit avoidance on the 1-D distances to each limit. Defaults: Franka."""

    metric_scalar: float = 0.1
    metric_length: float = positive(0.01)
    metric_eps: float = positive(0.001)
    velocity_gate_length: float = positive(0.01)
    damping_gain: float = 200.0
    potential_gain: float = 1.0
    potential_length: float = positive(0.1)
    potential_eps: float = positive(0.01)


def joint_limit_rmp(x: jax.Array, xd: jax.Array, p: JointLimitParams) -> RMP:
    """Joint limits on ``x = [q_upper − q, q − q_lower]`` (``(2d, 1)``, clipped ≥ 0):
    ``M = (1 − σ(ẋ/ℓ_v))·s/(x/ℓ_m + ε_m)``, ``a = g_p/((x/ℓ_p)² + ε_p) − g_d ẋ``.
    """
    s = jnp.maximum(x, 0.0)
    w = (1.0 - jax.nn.sigmoid(xd / p.velocity_gate_length)) * p.metric_scalar / (
        s / p.metric_length + p.metric_eps
    )
    a = p.potential_gain / ((s / p.potential_length) ** 2 + p.potential_eps) - p.damping_gain * xd
    return RMP(w[:, :, None], w * a)


@param_dataclass
class VelocityCapParams:
    """Joint velocity cap (per joint, 1-D). Defaults: Franka."""

    max_velocity: float = 1.7
    damping_region: float = positive(0.15)
    damping_gain: float = 5.0
    metric_weight: float = 0.05


#: Keeps the velocity-cap metric finite at the edge of the damping region.
VELOCITY_CAP_EPS = 1e-6


def velocity_cap_rmp(x: jax.Array, xd: jax.Array, p: VelocityCapParams) -> RMP:
    """Velocity cap on each joint ``(d, 1)``: inactive (``M = 0``, ``a = 0``) below
    ``v_max − region``; above, ``a = −|k(|q̇| − cutoff)|·sign(q̇)`` and
    ``M = w / (1 − (min(|q̇| − cutoff, region − 1e-6)/region)²)``.
    """
    del x
    cutoff = p.max_velocity - p.damping_region
    excess = jnp.abs(xd) - cutoff
    ratio = jnp.minimum(excess, p.damping_region - VELOCITY_CAP_EPS) / p.damping_region
    active = jnp.abs(xd) >= cutoff
    w = jnp.where(active, p.metric_weight / (1.0 - ratio**2), 0.0)
    a = jnp.where(active, -jnp.abs(p.damping_gain * excess) * jnp.sign(xd), 0.0)
    return RMP(w[:, :, None], w * a)


@param_dataclass
class DampingParams:
    """Nonlinear joint damping on ``q`` as one d-dimensional subtask. Defaults: original."""

    damping_gain: float = 30.0
    metric_scalar: float = 0.005
    inertia: float = 0.3


def damping_rmp(x: jax.Array, xd: jax.Array, p: DampingParams) -> RMP:
    """Joint damping on ``(1, d)``: ``a = −k_d‖q̇‖ q̇``, ``M = (s‖q̇‖ + inertia)·I``."""
    del x
    speed = safe_norm(xd, keepdims=True)
    a = -p.damping_gain * speed * xd
    w = p.metric_scalar * speed[:, 0] + p.inertia
    return RMP(_diag_family(w, xd.shape[-1]), w[:, None] * a)


@param_dataclass
class CSpaceTargetParams:
    """Configuration-space target (default posture) on ``x = q − q_default``. Defaults: Franka."""

    metric_scalar: float = 0.005
    k_p: float = 100.0
    k_d: float = 50.0
    robust_threshold: float = positive(0.5)
    inertia: float = 0.0001


def cspace_target_rmp(x: jax.Array, xd: jax.Array, p: CSpaceTargetParams) -> RMP:
    """Posture attractor on ``(1, d)``: ``a = −k_p x`` (``−k_p θ x̂`` when ``‖x‖ ≥ θ``) ``− k_d ẋ``;
    ``M = (s + inertia)·I``.
    """
    dist = safe_norm(x, keepdims=True)
    far = dist >= p.robust_threshold
    x_hat = x / jnp.where(far, dist, 1.0)
    a = jnp.where(far, -p.k_p * p.robust_threshold * x_hat, -p.k_p * x) - p.k_d * xd
    w = jnp.full((x.shape[0],), p.metric_scalar + p.inertia, dtype=x.dtype)
    return RMP(_diag_family(w, x.shape[-1]), w[:, None] * a)
