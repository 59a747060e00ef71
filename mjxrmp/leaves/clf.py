"""RMP²-CLF: minimally invasive subtask RMPs with a CLF guarantee (thesis §3.2.6, eqs 3.29–3.32).

Given a nominal policy for one subtask, expressed as its nominal *force* ``f₀ = M π`` (natural
form), a metric ``G(x, ẋ)``, a potential ``Φ(x)`` and a class-K function ``α``, the leaf returns
``[M, f*]`` with ``M = G + Ξ_G`` (eq 3.14) and

    f* = argmin_f ‖f − f₀‖²_P   s.t.   ẋᵀ f ≤ b := −ẋᵀ(∇Φ + ξ_G) − α(‖ẋ‖)            (3.30, 3.32)

solved in closed form as the P-weighted projection onto the half-space::

    f* = f₀ − λ P⁻¹ ẋ,      λ = max(0, (ẋᵀ f₀ − b) / (ẋᵀ P⁻¹ ẋ)).

``P = I`` (``"identity"``, used in §3.2.7) or ``P = M⁻¹`` (``"inverse_metric"``, i.e. the
objective ``‖a − π‖²_M``; then ``P⁻¹ẋ = Mẋ`` and ``M`` must be positive along ``ẋ``). At ``ẋ = 0``
both sides of the constraint vanish (footnote 18), ``λ = 0`` and ``f* = f₀``; the division is
guarded so values and gradients stay finite there.

By Proposition 3.2.1 / Theorem 3.2.2, combining such leaves with RMP² gives
``V̇ ≤ −Σ α_k(‖ẋ_k‖)`` for ``V`` of eq 3.21. If the nominal force equals ``−∇Φ`` at ``ẋ = 0``
(true for all nominals here) the system converges to ``{∇_qΦ = 0, q̇ = 0}`` (eq 3.28).

The nominal controllers of §3.2.7 are factories returning ``nominal(x, ẋ) -> f₀``:
:func:`potential_nominal` (``−∇Φ``), :func:`spiral_nominal` (``−∇Φ + ‖ẋ‖ v``,
``v = −R(π/2)∇Φ``) and :func:`sinusoidal_nominal` (``−∇Φ + sin(t/4)‖ẋ‖ v``).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from mjxrmp.core.rmp import RMP
from mjxrmp.leaves.gds import Metric, Potential, curvature_terms, potential_gradient
from mjxrmp.leaves.hand_designed import safe_norm

Nominal = Callable[[jax.Array, jax.Array], jax.Array]
ClassK = Callable[[jax.Array], jax.Array]

P_CHOICES = ("identity", "inverse_metric")
SPEEDS = ("euclidean", "metric")

__all__ = [
    "P_CHOICES",
    "SPEEDS",
    "clf_bound",
    "clf_leaf",
    "linear_alpha",
    "potential_nominal",
    "project_halfspace",
    "quadratic_alpha",
    "sinusoidal_nominal",
    "spiral_nominal",
]


def quadratic_alpha(gamma: float = 1.0) -> ClassK:
    """Class-K function ``α(s) = γ s²`` (default of :func:`clf_leaf`, ``γ = 1``).

    With ``α(‖ẋ‖) = γ‖ẋ‖²`` the CLF constraint asks for at least the dissipation of a GDS with
    damping ``B = γ I`` (Lemma 3.2.1), so the two are directly comparable.
    """
    if gamma <= 0:
        raise ValueError(f"gamma must be > 0 for a class-K function, got {gamma}")
    return lambda s: gamma * s * s


def linear_alpha(gamma: float = 1.0) -> ClassK:
    """Class-K function ``α(s) = γ s`` (a stronger decay at small speeds)."""
    if gamma <= 0:
        raise ValueError(f"gamma must be > 0 for a class-K function, got {gamma}")
    return lambda s: gamma * s


def _rot90(v: jax.Array) -> jax.Array:
    """``R(π/2) v`` for a planar vector (counter-clockwise quarter turn)."""
    if v.shape[-1] != 2:
        raise ValueError(
            "the spiral/sinusoidal nominals are planar (m = 2), "
            f"got subtask dimension {v.shape[-1]}"
        )
    return jnp.stack([-v[..., 1], v[..., 0]], axis=-1)


def potential_nominal(Phi: Potential) -> Nominal:
    """Potential-based nominal force ``M π_pt = −∇Φ`` (§3.2.7 (i))."""
    return lambda x, xd: -potential_gradient(Phi, x)


def spiral_nominal(Phi: Potential, gain: float = 1.0) -> Nominal:
    """Spiral nominal force ``M π_sp = −∇Φ + gain·‖ẋ‖ v`` with ``v = −R(π/2)∇Φ`` (§3.2.7 (ii)).

    ``v`` is the potential force turned a quarter turn counter-clockwise, so the subtask curves
    around its goal; the thesis uses ``gain = 1``. Planar subtasks (m = 2) only.
    """

    def nominal(x: jax.Array, xd: jax.Array) -> jax.Array:
        grad = potential_gradient(Phi, x)
        return -grad + gain * safe_norm(xd) * (-_rot90(grad))

    return nominal


def sinusoidal_nominal(
    Phi: Potential, t: jax.Array | float, gain: float = 1.0, period_scale: float = 4.0
) -> Nominal:
    """Sinusoidal nominal force ``M π_sn = −∇Φ + gain·sin(t/4)‖ẋ‖ v`` (§3.2.7 (iii)).

    ``t`` is the current time (a traced scalar is fine: build the leaf inside the step
    function); ``period_scale`` is the 4 in ``sin(t/4)``.
    """

    def nominal(x: jax.Array, xd: jax.Array) -> jax.Array:
        grad = potential_gradient(Phi, x)
        s = jnp.sin(jnp.asarray(t, dtype=x.dtype) / period_scale)
        return -grad + gain * s * safe_norm(xd) * (-_rot90(grad))

    return nominal


def _speed(kind: str, Gx: jax.Array, xd: jax.Array) -> jax.Array:
    if kind == "euclidean":
        return safe_norm(xd)
    sq = jnp.maximum(xd @ Gx @ xd, 0.0)
    pos = sq > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0)


def clf_bound(
    G: Metric, Phi: Potential, alpha: ClassK, x: jax.Array, xd: jax.Array,
    speed: str = "euclidean",
) -> tuple[jax.Array, jax.Array]:
    """``(M, b)``: the inertia ``M = G + Ξ_G`` and the right-hand side of eq 3.30,
    ``b = −ẋᵀ(∇Φ + ξ_G) − α(s)``, so that the constraint reads ``ẋᵀ f ≤ b``.

    ``s = ‖ẋ‖`` (``speed="euclidean"``, eq 3.30) or the Riemannian speed
    ``s = ‖ẋ‖_G = √(ẋᵀGẋ)`` (``speed="metric"``, see :func:`clf_leaf`)."""
    if speed not in SPEEDS:
        raise ValueError(f"speed must be one of {SPEEDS}, got {speed!r}")
    Xi, xi = curvature_terms(G, x, xd)
    Gx = G(x, xd)
    M = Gx + Xi
    b = -xd @ (potential_gradient(Phi, x) + xi) - alpha(_speed(speed, Gx, xd))
    return M, b


def project_halfspace(f0: jax.Array, d: jax.Array, b: jax.Array, xd: jax.Array) -> jax.Array:
    """Weighted projection of ``f0`` onto ``{f : ẋᵀ f ≤ b}`` along ``d = P⁻¹ ẋ``.

    ``f* = f0 − λ d`` with ``λ = max(0, (ẋᵀf0 − b)/(ẋᵀd))``; where ``ẋᵀd`` is not positive (e.g.
    ``ẋ = 0``, where the constraint holds trivially) ``λ = 0``. Safe for values and gradients.
    """
    denom = xd @ d
    ok = denom > jnp.finfo(denom.dtype).tiny
    violation = jnp.maximum(xd @ f0 - b, 0.0)
    lam = jnp.where(ok, violation / jnp.where(ok, denom, 1.0), 0.0)
    return f0 - lam * d


def clf_leaf(
    nominal: Nominal,
    G: Metric,
    Phi: Potential,
    alpha: ClassK | None = None,
    P: str = "identity",
    speed: str = "euclidean",
) -> Callable[[jax.Array, jax.Array], RMP]:
    """RMP²-CLF leaf ``(x (m,), ẋ (m,)) -> RMP(M = G + Ξ_G, f*)`` for one subtask (eq 3.32).

    ``nominal(x, ẋ) -> (m,)`` is the nominal force ``M π`` (see :func:`potential_nominal`,
    :func:`spiral_nominal`, :func:`sinusoidal_nominal`); ``G(x, ẋ) -> (m, m)`` and
    ``Phi(x) -> ()`` define the subtask energy of eq 3.15; ``alpha`` is a class-K function
    (default :func:`quadratic_alpha` ``(1.0)``, i.e. ``α(s) = s²``); ``P`` is ``"identity"``
    or ``"inverse_metric"``. Lift to a family with :func:`mjxrmp.leaves.gds.family`.

    ``speed`` chooses the argument of ``α``: ``"euclidean"`` is ``‖ẋ‖`` exactly as in eq 3.30;
    ``"metric"`` uses the Riemannian speed ``‖ẋ‖_G = √(ẋᵀGẋ)``, so ``α = γ s²`` demands the
    dissipation ``γ ẋᵀGẋ`` of a GDS with damping ``B = γG``. Because ``G ⪰ λ I`` with
    ``λ > 0`` for the metrics used here, ``γ‖ẋ‖²_G ≥ γλ‖ẋ‖²``: Condition 3.2.2 then holds with
    the class-K function ``s ↦ α(√λ s)`` and Theorems 3.2.1–3.2.2 apply unchanged.
    """
    if P not in P_CHOICES:
        raise ValueError(f"P must be one of {P_CHOICES}, got {P!r}")
    if speed not in SPEEDS:
        raise ValueError(f"speed must be one of {SPEEDS}, got {speed!r}")
    alpha = quadratic_alpha(1.0) if alpha is None else alpha

    def leaf(x: jax.Array, xd: jax.Array) -> RMP:
        x = jnp.asarray(x)
        xd = jnp.asarray(xd)
        if x.ndim != 1 or xd.shape != x.shape:
            raise ValueError(
                f"x and xd must be single subtask vectors of equal shape (m,), got {x.shape}, "
                f"{xd.shape}; lift to a family with mjxrmp.leaves.gds.family"
            )
        M, b = clf_bound(G, Phi, alpha, x, xd, speed)
        f0 = nominal(x, xd)
        if f0.shape != x.shape:
            raise ValueError(f"nominal(x, xd) must return a force of shape {x.shape}, "
                             f"got {f0.shape}")
        d = xd if P == "identity" else M @ xd
        return RMP(M, project_halfspace(f0, d, b, xd))

    return leaf
