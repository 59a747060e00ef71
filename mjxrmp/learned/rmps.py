"""Learned subtask RMPs: residual, direct, learned nominal + CLF, GDS on a nominal potential.

Thesis chapter 4 (§4.3.1–4.3.2) and chapter 6 (§6.1.2, §6.2.2). Every leaf here is a pure function
``(x (m,), ẋ (m,)) -> RMP(M (m, m), f (m,))`` for **one** subtask in natural form ``[M, f = M a]``
(§3.2.6), like :mod:`mjxrmp.leaves.gds` and :mod:`mjxrmp.leaves.clf`; lift it to a family ``(n, m)``
for :mod:`mjxrmp.core.rmp2` with :func:`mjxrmp.leaves.gds.family`. Networks are :mod:`flax.linen`
modules; bind their variables with a closure.

* **Residual RMP** (§6.1.2 "Learning Residual RMP", §6.2.2 RMP-RESIDUAL): a network outputs
  ``A_r ∈ R^{m×m}`` and ``a_r ∈ R^m``; with the hand-designed RMP ``(M_h, a_h)``::

      M = (A_r + chol(M_h)) (A_r + chol(M_h))ᵀ,      a = a_r + a_h,

  ``chol`` the lower Cholesky factor. Outputs are bounded by ``tanh``: ``A_r = √5·tanh(·)``,
  ``a_r = tanh(·)`` (docs/design.md §2.1, docs/design.md §4.4). The thesis calls this ``M`` positive
  *semi*-definite — it is singular where ``A_r + chol(M_h)`` is (e.g. ``A_r = −chol(M_h)``,
  reachable whenever ``chol(M_h)``'s entries are within ``√5``). :func:`residual_rmp` takes an
  ``eps ≥ 0`` (default 0, the thesis) and returns ``M + εI``, positive definite with
  ``λ_min ≥ ε`` for every network output when ``ε > 0``.
* **Direct RMP** (§4.3.2): ``M(x)`` by either metric parameterisation of §4.3.1
  (:class:`mjxrmp.learned.gds.CholeskyMetric` / :class:`~mjxrmp.learned.gds.GramMetric`,
  ``λ_min ≥ ε`` for every parameter value) and ``a(x, ẋ)`` by a fully connected network
  (:class:`DirectRMP`). No stability guarantee (§4.3.2), but fast.
* **Learned nominal policy + CLF** (end of §4.3.2, RMP²-CLF of §3.2.6): a network gives the
  nominal acceleration ``π_θ(x, ẋ)``; the leaf is :func:`mjxrmp.leaves.clf.clf_leaf` with nominal
  force ``M π_θ`` (``M = G + Ξ_G``, eq 3.14), i.e. the closed-form solution of the QP (3.32).
  Its force satisfies the CLF constraint (3.30) ``ẋᵀf ≤ −ẋᵀ(∇Φ + ξ_G) − α(‖ẋ‖)`` for every
  network parameter and state, by construction (:func:`learned_clf_leaf`).
* **GDS on the nominal-trajectory potential** (§4.3.1, Fig 4.8b, §5.2): a learned metric
  ``G(x)`` and the potential of :mod:`mjxrmp.learned.nominal` (eqs 4.9–4.12) in the GDS leaf of
  eq 4.6 (:func:`nominal_gds_leaf`); :func:`natural_gradient_velocity` is the velocity-form policy
  ``v = −G⁻¹∇Φ`` of Remark 5.1.1 / eq 5.1 used to learn the metric from demonstrations (§5.2.2).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_solve

from mjxrmp.config import check_choice
from mjxrmp.core.rmp import RMP
from mjxrmp.learned.flows import ACTIVATIONS
from mjxrmp.learned.gds import CholeskyMetric, GramMetric, learned_gds
from mjxrmp.learned.nominal import NominalPotential, nominal_potential, nominal_potential_gradient
from mjxrmp.leaves.clf import ClassK, clf_leaf
from mjxrmp.leaves.gds import Leaf, Metric, Potential, inertia

METRIC_KINDS = ("cholesky", "gram")

__all__ = [
    "METRIC_KINDS",
    "DirectRMP",
    "NominalPolicy",
    "ResidualRMPNet",
    "direct_leaf",
    "learned_clf_leaf",
    "natural_gradient_velocity",
    "nominal_gds_leaf",
    "position_metric",
    "residual_leaf",
    "residual_rmp",
]


def _activation(name: str) -> Callable[[jax.Array], jax.Array]:
    if name not in ACTIVATIONS:
        raise ValueError(f"unknown activation={name!r}; valid names are {sorted(ACTIVATIONS)}")
    return ACTIVATIONS[name]


class _MLP(nn.Module):
    """Dense layers ``hidden_sizes`` with ``activation``; the output layer's kernel is
    ``out_init_scale·lecun_normal`` (0: exactly zero) and its bias zero."""

    out_dim: int
    hidden_sizes: Sequence[int]
    activation: str
    out_init_scale: float
    param_dtype: Any

    @nn.compact
    def __call__(self, z: jax.Array) -> jax.Array:
        act = _activation(self.activation)
        for i, h in enumerate(self.hidden_sizes):
            z = act(nn.Dense(h, param_dtype=self.param_dtype, name=f"hidden_{i}")(z))
        if self.out_init_scale == 0.0:
            kinit = nn.initializers.zeros
        else:
            kinit = nn.initializers.variance_scaling(self.out_init_scale ** 2, "fan_in",
                                                     "truncated_normal")
        return nn.Dense(self.out_dim, kernel_init=kinit, bias_init=nn.initializers.zeros,
                        param_dtype=self.param_dtype, name="out")(z)


def _check_pair(x: jax.Array, xd: jax.Array) -> tuple[jax.Array, jax.Array]:
    x = jnp.asarray(x)
    xd = jnp.asarray(xd)
    if x.ndim != 1 or xd.shape != x.shape:
        raise ValueError(f"x and xd must be one subtask coordinate of equal shape (m,), got "
                         f"{x.shape} and {xd.shape}; lift to a family with "
                         "mjxrmp.leaves.gds.family")
    return x, xd


def _features(x: jax.Array, xd: jax.Array, context: jax.Array | None) -> jax.Array:
    parts = [x, xd] if context is None else [x, xd, jnp.asarray(context, x.dtype)]
    return jnp.concatenate(parts, axis=-1)


# ---------------------------------------------------------------------------------------------
# Residual RMP (§6.1.2, §6.2.2)
# ---------------------------------------------------------------------------------------------


def residual_rmp(hand: RMP, A_r: jax.Array, a_r: jax.Array, eps: float = 0.0) -> RMP:
    """Residual RMP of §6.2.2 around a hand-designed RMP, in natural form.

    ``hand = RMP(M_h (m, m), f_h (m,))`` is the hand-designed RMP in natural form (``M_h ≻ 0``);
    with ``a_h = M_h⁻¹ f_h`` and ``B = A_r + chol(M_h)`` the result is
    ``M = B Bᵀ + εI`` and ``f = M (a_r + a_h)``. ``eps = 0`` is the thesis' definition (positive
    semi-definite); ``eps > 0`` makes ``λ_min(M) ≥ ε`` for every ``A_r``. ``A_r = 0, a_r = 0``
    (and ``eps = 0``) gives back the hand-designed RMP.
    """
    M_h, f_h = hand
    m = f_h.shape[-1]
    if M_h.shape != (m, m) or A_r.shape != (m, m) or a_r.shape != (m,):
        raise ValueError(f"residual_rmp: expected M_h, A_r ({m}, {m}) and f_h, a_r ({m},), got "
                         f"{M_h.shape}, {A_r.shape}, {f_h.shape}, {a_r.shape}")
    L_h = jnp.linalg.cholesky(M_h)
    a_h = cho_solve((L_h, True), f_h)
    B = A_r + L_h
    exact = jax.lax.Precision.HIGHEST
    M = jnp.matmul(B, B.T, precision=exact)
    M = 0.5 * (M + M.T) + eps * jnp.eye(m, dtype=M.dtype)
    return RMP(M, jnp.matmul(M, a_r + a_h, precision=exact))


class ResidualRMPNet(nn.Module):
    """The residual network of §6.2.2: ``features → (A_r (m, m), a_r (m,))``.

    MLP ``hidden_sizes`` (default (128, 64), elu) with ``m² + m`` outputs: ``A_r`` row-major
    squashed as ``metric_scale·tanh`` (√5) and ``a_r`` as ``accel_scale·tanh`` (1). The output
    layer starts at ``out_init_scale`` (0.01; 0 makes the residual exactly zero at init). The
    thesis' features are ``[x, ẋ, g, {o_i}]``; any ``(..., k)`` input works.
    """

    dim: int
    hidden_sizes: Sequence[int] = (128, 64)
    activation: str = "elu"
    metric_scale: float = math.sqrt(5.0)
    accel_scale: float = 1.0
    out_init_scale: float = 0.01
    param_dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, features: jax.Array) -> tuple[jax.Array, jax.Array]:
        m = self.dim
        raw = _MLP(m * m + m, tuple(self.hidden_sizes), self.activation, self.out_init_scale,
                   self.param_dtype, name="mlp")(features)
        A_r = self.metric_scale * jnp.tanh(raw[..., : m * m]).reshape((*raw.shape[:-1], m, m))
        a_r = self.accel_scale * jnp.tanh(raw[..., m * m:])
        return A_r, a_r


def residual_leaf(
    hand_leaf: Leaf,
    residual: Callable[[jax.Array, jax.Array], tuple[jax.Array, jax.Array]],
    eps: float = 0.0,
) -> Leaf:
    """Leaf ``(x, ẋ) -> RMP`` of a residual RMP (§6.1.2): ``hand_leaf(x, ẋ)`` gives the
    hand-designed RMP, ``residual(x, ẋ) -> (A_r, a_r)`` the learned correction (e.g.
    :class:`ResidualRMPNet` applied to features built from ``x, ẋ`` and the goal/obstacles it
    closes over); combined by :func:`residual_rmp`."""

    def leaf(x: jax.Array, xd: jax.Array) -> RMP:
        x, xd = _check_pair(x, xd)
        A_r, a_r = residual(x, xd)
        return residual_rmp(hand_leaf(x, xd), A_r, a_r, eps)

    return leaf


# ---------------------------------------------------------------------------------------------
# Direct RMP (§4.3.2)
# ---------------------------------------------------------------------------------------------


class DirectRMP(nn.Module):
    """Directly parameterised RMP of §4.3.2: ``(x, ẋ[, context]) -> RMP(M(x), M a(x, ẋ))``.

    ``M(x)`` is :class:`~mjxrmp.learned.gds.CholeskyMetric` (``metric="cholesky"``, Fig 4.5) or
    :class:`~mjxrmp.learned.gds.GramMetric` (``"gram"``) of dimension ``dim`` (trunk
    ``metric_hidden_sizes``, relu as in Fig 4.5), identity at initialisation with
    ``λ_min ≥ eps`` for all parameters; ``a`` is an MLP on
    ``[x, ẋ, context]`` (``accel_hidden_sizes``, ``activation``), optionally bounded by
    ``accel_scale·tanh`` (``accel_scale=None``: unbounded). Works on one point or a batch
    ``(..., dim)``.
    """

    dim: int
    metric: str = "cholesky"
    metric_hidden_sizes: Sequence[int] = (128, 64)
    accel_hidden_sizes: Sequence[int] = (128, 64)
    activation: str = "elu"
    eps: float = 1e-5
    accel_scale: float | None = None
    out_init_scale: float = 0.01
    param_dtype: Any = jnp.float32

    def __post_init__(self) -> None:
        check_choice(self.metric, "DirectRMP.metric", METRIC_KINDS)
        super().__post_init__()

    @nn.compact
    def __call__(self, x: jax.Array, xd: jax.Array, context: jax.Array | None = None) -> RMP:
        x = jnp.asarray(x)
        xd = jnp.asarray(xd)
        if x.shape[-1] != self.dim or xd.shape != x.shape:
            raise ValueError(f"DirectRMP: x and xd must have shape (..., {self.dim}), got "
                             f"{x.shape} and {xd.shape}")
        kind = CholeskyMetric if self.metric == "cholesky" else GramMetric
        M = kind(dim=self.dim, hidden_sizes=tuple(self.metric_hidden_sizes),
                 activation="relu", eps=self.eps, param_dtype=self.param_dtype,
                 name="metric")(x)
        a = _MLP(self.dim, tuple(self.accel_hidden_sizes), self.activation,
                 self.out_init_scale, self.param_dtype, name="accel")(_features(x, xd, context))
        if self.accel_scale is not None:
            a = self.accel_scale * jnp.tanh(a)
        return RMP(M, jnp.einsum("...ij,...j->...i", M, a))


def direct_leaf(module: DirectRMP, variables: Any, context: jax.Array | None = None) -> Leaf:
    """The leaf ``(x, ẋ) -> RMP`` of a :class:`DirectRMP` with its variables bound."""

    def leaf(x: jax.Array, xd: jax.Array) -> RMP:
        x, xd = _check_pair(x, xd)
        return module.apply(variables, x, xd, context)

    return leaf


# ---------------------------------------------------------------------------------------------
# Learned nominal policy wrapped by the CLF leaf (§4.3.2 end, §3.2.6)
# ---------------------------------------------------------------------------------------------


class NominalPolicy(nn.Module):
    """Nominal acceleration network ``π_θ(x, ẋ[, context]) -> (..., dim)`` (§4.3.2, end).

    MLP ``hidden_sizes`` (default (128, 64), elu); output layer at ``out_init_scale``.
    """

    dim: int
    hidden_sizes: Sequence[int] = (128, 64)
    activation: str = "elu"
    out_init_scale: float = 0.01
    param_dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, xd: jax.Array, context: jax.Array | None = None
                 ) -> jax.Array:
        return _MLP(self.dim, tuple(self.hidden_sizes), self.activation, self.out_init_scale,
                    self.param_dtype, name="mlp")(_features(x, xd, context))


def position_metric(metric: Callable[[jax.Array], jax.Array]) -> Metric:
    """``G(x, ẋ) = metric(x)``: a position-only metric (e.g. a bound
    :class:`~mjxrmp.learned.gds.CholeskyMetric`) in the ``(x, ẋ)`` signature of
    :mod:`mjxrmp.leaves.gds` and :mod:`mjxrmp.leaves.clf`."""
    return lambda x, xd: metric(x)


def learned_clf_leaf(
    policy: Callable[[jax.Array, jax.Array], jax.Array],
    G: Metric,
    Phi: Potential,
    alpha: ClassK | None = None,
    P: str = "identity",
    speed: str = "euclidean",
) -> Leaf:
    """RMP²-CLF leaf around a learned nominal acceleration (§4.3.2 end, eqs 3.30–3.32).

    ``policy(x, ẋ) -> π (m,)`` is the nominal *acceleration* (e.g. a bound
    :class:`NominalPolicy`); the nominal force of the QP (3.32) is ``M π`` with
    ``M = G + Ξ_G`` (eq 3.14, :func:`mjxrmp.leaves.gds.inertia`). The leaf is
    :func:`mjxrmp.leaves.clf.clf_leaf` with that nominal: ``M`` as there and
    ``f* = argmin_f ‖f − Mπ‖²_P s.t. ẋᵀf ≤ −ẋᵀ(∇Φ + ξ_G) − α(s)`` in closed form, so the CLF
    constraint (3.30) holds for every network parameter and state. ``G(x, ẋ)``, ``Phi(x)``,
    ``alpha`` (default ``α(s) = s²``), ``P`` and ``speed`` are those of ``clf_leaf``.
    """

    def nominal(x: jax.Array, xd: jax.Array) -> jax.Array:
        pi = jnp.asarray(policy(x, xd))
        if pi.shape != x.shape:
            raise ValueError(f"policy(x, xd) must return an acceleration of shape {x.shape}, "
                             f"got {pi.shape}")
        return inertia(G, x, xd) @ pi

    return clf_leaf(nominal, G, Phi, alpha, P=P, speed=speed)


# ---------------------------------------------------------------------------------------------
# GDS on the nominal-trajectory potential (§4.3.1, Fig 4.8b; §5.2)
# ---------------------------------------------------------------------------------------------


def nominal_gds_leaf(
    metric: Callable[[jax.Array], jax.Array],
    potential: NominalPotential,
    damping: float | jax.Array,
    curvature: bool = True,
) -> Leaf:
    """GDS leaf of eq 4.6 with a learned metric ``G(x)`` and the nominal-trajectory potential.

    ``M = G(x)``, ``f = −∇Φ(x) − γ_d G(x) ẋ − ξ_G`` with ``Φ`` of eqs 4.9–4.12
    (:func:`mjxrmp.learned.nominal.nominal_potential`) and ``B = γ_d G`` (§4.3.1); this is
    :func:`mjxrmp.learned.gds.learned_gds` on that potential (the combination of Fig 4.8b).
    ``metric(x) -> (m, m)``, e.g. a bound :class:`~mjxrmp.learned.gds.CholeskyMetric`.
    """
    return learned_gds(metric, lambda x: nominal_potential(potential, x), damping, curvature)


def natural_gradient_velocity(
    metric: Callable[[jax.Array], jax.Array], potential: NominalPotential, x: jax.Array
) -> jax.Array:
    """Velocity-form policy ``v(x) = −G(x)⁻¹ ∇Φ(x)`` (Remark 5.1.1, eq 5.1; §5.2.2), one point.

    ``∇Φ`` is the closed-form gradient of the nominal potential; §5.2.2 fits the metric so that
    this velocity reproduces the demonstrations.
    """
    x = jnp.asarray(x)
    G = metric(x)
    return -jnp.linalg.solve(G, nominal_potential_gradient(potential, x))
