"""GDS leaves of the 2-D point-robot examples of RMPflow (thesis §3.2.7, Figs 3.2 and 3.3).

Two geometric dynamical systems, in the forms published with RMPflow (Cheng et al. 2018,
"RMPflow: A computational graph for automatic motion policy generation", appendix on the 2-D
examples) and with the same default constants as the public companion code of the multi-robot
RMP paper (Li et al. 2019, "Multi-objective policy generation for multi-robot systems using
Riemannian motion policies"):

**Goal attractor** on ``x = y − g`` (m = 2), :class:`GoalAttractorParams`:

* metric ``G(x) = w(x) I`` with ``w(x) = (w_u − w_l) exp(−‖x‖²/2σ²) + w_l``
  (``w_u = 10``, ``w_l = 1``, ``σ = 1``): heavier (more important) near the goal;
* potential with the soft-normalised gradient ``∇Φ(x) = gain · w(x) · tanh(α‖x‖) x/‖x‖``
  (``α = 1``, ``gain = 1``), i.e. the radial potential
  ``Φ(r) = gain·[w_l log cosh(α r)/α + (w_u − w_l) ∫₀ʳ exp(−ρ²/2σ²) tanh(αρ) dρ]``;
  the first part is closed form (the ``α⁻¹ log cosh`` soft norm), the second is a fixed
  Gauss–Legendre quadrature (its integrand is negligible beyond ``10σ``), and the gradient is
  the exact published expression (a ``custom_jvp``), smooth at ``x = 0`` (the companion code
  zeroes it within 0.005 of the goal; the smooth form needs no such switch);
* damping ``B(x) = η w(x) I`` (``η = 2``).

**Collision avoidance** on the 1-D distance ``x = ‖y − c‖/R − 1`` (zero on the obstacle
boundary; also used between two robots with ``y − c`` the robot–robot offset),
:class:`CollisionParams`:

* velocity-dependent metric ``G(x, ẋ) = w(x) u(ẋ)`` with ``w(x) = 1/x⁴`` and
  ``u(ẋ) = ε + min(0, ẋ) ẋ`` — important only when close *and* approaching;
* barrier potential ``Φ(x) = ½ α w(x)²`` (``α = 1e-5``); damping ``B = η G`` (``η = 0``);
* ``ε = 0.2`` for the single-robot obstacle example, ``ε = 1e-8`` between robots;
* numerical guards of the original: ``w`` capped at ``1e10`` (here: ``x`` floored at
  ``1e10^(−1/4)``, so inside or at the boundary ``w = 1e10`` with zero slope), ``M`` clipped to
  ``±1e5`` and ``f`` to ``±1e10``.

Both leaves are built with :func:`mjxrmp.leaves.gds.gds`, so ``M = G + Ξ_G`` and ``ξ_G`` come from
autodiff (for the collision metric ``Ξ_G = w min(0, ẋ) ẋ`` and ``ξ_G = ½ ẋ² u w'``; for the
attractor ``ξ_G = (ẋ·∇w) ẋ − ½‖ẋ‖² ∇w``, matching the hand-derived published forms).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp.config import param_dataclass, positive
from mjxrmp.core.rmp import RMP
from mjxrmp.leaves.gds import Damping, Leaf, Metric, Potential, gds

__all__ = [
    "CollisionParams",
    "GoalAttractorParams",
    "collision_avoidance",
    "collision_damping",
    "collision_metric",
    "collision_potential",
    "goal_attractor",
    "goal_damping",
    "goal_metric",
    "goal_offsets",
    "goal_potential",
    "goal_weight",
    "obstacle_distance",
    "pair_indices",
    "pairwise_distances",
]

_QUAD_NODES, _QUAD_WEIGHTS = np.polynomial.legendre.leggauss(48)
#: The Gaussian part of the attractor potential is integrated up to ``_CUTOFF · σ``.
_CUTOFF = 10.0


@param_dataclass
class GoalAttractorParams:
    """RMPflow goal attractor GDS (Cheng et al. 2018; defaults of Li et al. 2019's code)."""

    w_u: float = 10.0  #: metric weight at the goal
    w_l: float = 1.0  #: metric weight far from the goal
    sigma: float = positive(1.0)  #: length scale of the metric's transition
    alpha: float = positive(1.0)  #: soft-normalisation sharpness of ``tanh(α‖x‖)``
    eta: float = 2.0  #: damping gain, ``B = η w(x) I``
    gain: float = 1.0  #: potential gain


@param_dataclass
class CollisionParams:
    """RMPflow collision-avoidance GDS on ``x = d/R − 1`` (Cheng et al. 2018)."""

    epsilon: float = 0.2  #: metric floor in ``u(ẋ) = ε + min(0, ẋ)ẋ`` (1e-8 between robots)
    alpha: float = 1e-5  #: barrier potential gain, ``Φ = ½ α w²``
    eta: float = 0.0  #: damping gain, ``B = η G``
    w_max: float = positive(1e10)  #: cap on ``w(x) = 1/x⁴``
    m_max: float = 1e5  #: clip on the inertia
    f_max: float = 1e10  #: clip on the force


# ---------------------------------------------------------------------------------------------
# Goal attractor
# ---------------------------------------------------------------------------------------------


def _norm(x: jax.Array) -> jax.Array:
    sq = jnp.sum(x * x, axis=-1)
    pos = sq > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0)


def _tanhc(z: jax.Array) -> jax.Array:
    """``tanh(z)/z``, smooth at 0."""
    small = jnp.abs(z) < 1e-4
    zs = jnp.where(small, 1.0, z)
    return jnp.where(small, 1.0 - z * z / 3.0, jnp.tanh(zs) / zs)


def _logcosh(z: jax.Array) -> jax.Array:
    a = jnp.abs(z)
    return a + jnp.log1p(jnp.exp(-2.0 * a)) - jnp.log(2.0)


def goal_weight(p: GoalAttractorParams, x: jax.Array) -> jax.Array:
    """``w(x) = (w_u − w_l) exp(−‖x‖²/2σ²) + w_l``."""
    sq = jnp.sum(x * x, axis=-1)
    return (p.w_u - p.w_l) * jnp.exp(-sq / (2.0 * p.sigma**2)) + p.w_l


def _goal_potential_value(x: jax.Array, p: GoalAttractorParams) -> jax.Array:
    r = _norm(x)
    base = p.w_l * _logcosh(p.alpha * r) / p.alpha
    rc = jnp.minimum(r, _CUTOFF * p.sigma)
    nodes = jnp.asarray(_QUAD_NODES, dtype=x.dtype)
    weights = jnp.asarray(_QUAD_WEIGHTS, dtype=x.dtype)
    rho = 0.5 * rc * (nodes + 1.0)
    integrand = jnp.exp(-rho * rho / (2.0 * p.sigma**2)) * jnp.tanh(p.alpha * rho)
    bump = 0.5 * rc * jnp.sum(weights * integrand)
    return p.gain * (base + (p.w_u - p.w_l) * bump)


def _goal_potential_grad(x: jax.Array, p: GoalAttractorParams) -> jax.Array:
    """Published gradient ``gain · w(x) · tanh(α‖x‖) x/‖x‖`` (smooth at the goal)."""
    r = _norm(x)
    return p.gain * goal_weight(p, x) * p.alpha * _tanhc(p.alpha * r) * x


@jax.custom_jvp
def _goal_potential(x: jax.Array, p: GoalAttractorParams) -> jax.Array:
    return _goal_potential_value(x, p)


@_goal_potential.defjvp
def _goal_potential_jvp(primals, tangents):
    x, p = primals
    dx, dp = tangents
    value, dvalue_p = jax.jvp(lambda p_: _goal_potential_value(x, p_), (p,), (dp,))
    return value, dvalue_p + _goal_potential_grad(x, p) @ dx


def goal_metric(p: GoalAttractorParams) -> Metric:
    """``G(x, ẋ) = w(x) I`` (position only, so ``M = G``)."""
    return lambda x, xd: goal_weight(p, x) * jnp.eye(x.shape[-1], dtype=x.dtype)


def goal_potential(p: GoalAttractorParams) -> Potential:
    """``Φ(x)`` with ``∇Φ = gain·w(x)·tanh(α‖x‖) x/‖x‖`` (exact gradient, quadrature value)."""
    return lambda x: _goal_potential(x, p)


def goal_damping(p: GoalAttractorParams) -> Damping:
    """``B(x, ẋ) = η w(x) I``."""
    return lambda x, xd: p.eta * goal_weight(p, x) * jnp.eye(x.shape[-1], dtype=x.dtype)


def goal_attractor(p: GoalAttractorParams | None = None) -> Leaf:
    """The RMPflow goal-attractor GDS leaf ``(x = y − g (m,), ẋ) -> RMP`` (lift with ``family``)."""
    p = GoalAttractorParams() if p is None else p
    return gds(goal_metric(p), goal_potential(p), goal_damping(p))


# ---------------------------------------------------------------------------------------------
# Collision avoidance
# ---------------------------------------------------------------------------------------------


def _collision_w(p: CollisionParams, x: jax.Array) -> jax.Array:
    xc = jnp.maximum(x, p.w_max ** (-0.25))
    return 1.0 / xc**4


def collision_metric(p: CollisionParams) -> Metric:
    """``G(x, ẋ) = w(x) u(ẋ)`` with ``w = 1/x⁴``, ``u = ε + min(0, ẋ) ẋ`` (1×1)."""

    def G(x, xd):
        u = p.epsilon + jnp.minimum(0.0, xd) * xd
        return (_collision_w(p, x) * u).reshape(1, 1)

    return G


def collision_potential(p: CollisionParams) -> Potential:
    """Barrier ``Φ(x) = ½ α w(x)²``."""
    return lambda x: 0.5 * p.alpha * _collision_w(p, x[0]) ** 2


def collision_damping(p: CollisionParams) -> Damping:
    """``B(x, ẋ) = η G(x, ẋ)``."""
    G = collision_metric(p)
    return lambda x, xd: p.eta * G(x, xd)


def collision_avoidance(p: CollisionParams | None = None) -> Leaf:
    """The RMPflow collision-avoidance GDS leaf on ``x = d/R − 1`` (m = 1), with the clips."""
    p = CollisionParams() if p is None else p
    base = gds(collision_metric(p), collision_potential(p), collision_damping(p))

    def leaf(x: jax.Array, xd: jax.Array) -> RMP:
        M, f = base(x, xd)
        return RMP(jnp.clip(M, -p.m_max, p.m_max), jnp.clip(f, -p.f_max, p.f_max))

    return leaf


# ---------------------------------------------------------------------------------------------
# Task-map helpers for point robots
# ---------------------------------------------------------------------------------------------


def goal_offsets(Y: jax.Array, goals: jax.Array) -> jax.Array:
    """Attractor coordinates ``x_i = y_i − g_i`` for robots ``Y (N, 2)``: shape ``(N, 2)``."""
    return Y - goals


def obstacle_distance(Y: jax.Array, center: jax.Array, radius: float) -> jax.Array:
    """``x_i = ‖y_i − c‖/R − 1`` for points ``Y (N, 2)`` and one disc obstacle: ``(N, 1)``."""
    return (_norm(Y - center) / radius - 1.0)[:, None]


def pair_indices(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Index arrays ``(i, j)`` of all robot pairs ``i < j`` (static numpy)."""
    i, j = np.triu_indices(n, k=1)
    return i, j


def pairwise_distances(Y: jax.Array, radius: float) -> jax.Array:
    """``x_ij = ‖y_i − y_j‖/R − 1`` for all pairs ``i < j`` of ``Y (N, 2)``: ``(N(N−1)/2, 1)``."""
    i, j = pair_indices(Y.shape[0])
    return (_norm(Y[i] - Y[j]) / radius - 1.0)[:, None]
