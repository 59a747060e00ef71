"""Learned GDS components: metric networks, the diffeomorphic potential, a learned GDS leaf.

Thesis §4.3.1 ("Parameterizing GDSs"). A GDS with a position-dependent metric (eq 3.18),

    G(x) ẍ + C_G(x, ẋ) ẋ = −∇Φ(x) − B(x, ẋ) ẋ,

is the RMP (eq 4.6)

    M = G(x),     a = G(x)⁻¹ (−∇Φ(x) − B ẋ − C_G ẋ),     i.e.  f = M a = −∇Φ − B ẋ − ξ_G,   (4.6)

with the damping fixed to ``B = γ_d G(x)`` so that the damping acceleration ``γ_d ẋ`` does not
depend on the learned metric (§4.3.1), and ``ξ_G = C_G ẋ = Ġ_x ẋ − ½ ∇_x(ẋᵀ G ẋ)`` (eq 3.13;
``Ξ_G = 0`` since ``G`` does not depend on ``ẋ``). Stability (Lemma 3.2.1) needs ``G ≻ 0``
everywhere and a potential whose only stationary point is the goal; the parameterisations here
guarantee both for *every* parameter value:

* :class:`CholeskyMetric` — ``G = L Lᵀ + εI``, ``L`` lower-triangular with strictly positive
  diagonal (Fig 4.5): ``x → 128 → 64`` (relu) → a diagonal head and a strictly-lower head, both
  initialised at zero (docs/design.md §4.6); ``L_ii = |h_i + c| + ε_L`` (the thesis' absolute value,
  ``ε_L = 1e-5``) or ``softplus(h_i + c) + ε_L``.
* :class:`GramMetric` — ``G = Aᵀ A + εI`` (Gram parameterisation), ``A = mat(h) + c I``.

  In both, ``c`` is chosen so that ``G = I`` *exactly* at initialisation (``L = A = √(1 − ε) I``).
  docs/design.md §4.6 writes ``L_ii = |h_i + 1| + 1e-5`` with no ``εI`` term; with ``eps=0`` the
  offset here is ``c = 1 − ε_L``, i.e. that form up to ``1e-5`` at initialisation. The extra floor
  ``εI`` makes ``λ_min(G) ≥ ε`` (a triangular ``L`` with diagonal ``≥ ε_L`` alone only gives
  ``G ≻ 0``, without a bound).
* :func:`diffeomorphic_potential` — ``Φ = Φ̄ ∘ ψ`` (eq 4.7) with ``ψ(x) = φ_θ(x − g) − φ_θ(0)``
  the Euclideanizing-flow subtask map of §4.2 and ``Φ̄(y) = ½‖y‖²`` by default; its gradient
  ``∇Φ = J_ψᵀ ∇Φ̄(ψ(x))`` (eq 4.7) is :func:`diffeomorphic_potential_gradient`. Because ``φ_θ``
  is a diffeomorphism, ``Φ ≥ 0`` vanishes and is stationary only at ``x = g``.
* :func:`learned_gds` — the GDS leaf ``(x (m,), ẋ (m,)) -> RMP(M, f)`` of eq 4.6 from any metric
  ``x -> G(x)`` and potential ``x -> Φ(x)`` (e.g. the networks above with their variables closed
  over); lift it to a family ``(n, m)`` with :func:`mjxrmp.leaves.gds.family` for RMP²::

      metric = CholeskyMetric(dim=2)
      mvars = metric.init(key, jnp.zeros(2))
      flow = EuclideanizingFlow(dim=2)
      fvars = flow.init(key, jnp.zeros(2))
      leaf = learned_gds(lambda x: metric.apply(mvars, x),
                         lambda x: diffeomorphic_potential(flow, fvars, x, goal),
                         damping=2.0)
      rmp = leaf(x, xd)                           # RMP(M (2, 2), f (2,))

The networks are :mod:`flax.linen` modules working on ``x (..., dim)`` (one point or a batch),
returning ``(..., dim, dim)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp.config import check_choice, check_float, check_fraction, check_int
from mjxrmp.core.rmp import RMP
from mjxrmp.learned.flows import ACTIVATIONS, EuclideanizingFlow, subtask_map
from mjxrmp.leaves.gds import Leaf

DIAGONALS = ("abs", "softplus")

__all__ = [
    "DIAGONALS",
    "CholeskyMetric",
    "GramMetric",
    "diffeomorphic_potential",
    "diffeomorphic_potential_gradient",
    "learned_gds",
    "lower_triangular",
    "quadratic_potential",
    "smooth_norm_potential",
]


def _activation(name: str) -> Callable[[jax.Array], jax.Array]:
    if name not in ACTIVATIONS:
        raise ValueError(f"unknown activation={name!r}; valid names are {sorted(ACTIVATIONS)}")
    return ACTIVATIONS[name]


def _symmetrize(G: jax.Array) -> jax.Array:
    return 0.5 * (G + jnp.swapaxes(G, -1, -2))


def lower_triangular(diag: jax.Array, off: jax.Array) -> jax.Array:
    """Lower-triangular ``L (..., m, m)`` from its diagonal ``(..., m)`` and the strictly-lower
    entries ``(..., m(m−1)/2)`` in row-major order (``l_d``, ``l_o`` of §4.3.1)."""
    m = diag.shape[-1]
    if off.shape[-1] != m * (m - 1) // 2 or off.shape[:-1] != diag.shape[:-1]:
        raise ValueError(f"off must have shape {(*diag.shape[:-1], m * (m - 1) // 2)}, "
                         f"got {off.shape}")
    rows, cols = np.tril_indices(m, -1)
    L = jnp.zeros((*diag.shape, m), jnp.result_type(diag, off))
    L = L.at[..., rows, cols].set(off)
    return L + diag[..., :, None] * jnp.eye(m, dtype=L.dtype)


def _hidden(x: jax.Array, sizes: Sequence[int], activation: str, param_dtype: Any) -> jax.Array:
    act = _activation(activation)
    for i, h in enumerate(sizes):
        x = act(nn.Dense(h, param_dtype=param_dtype, name=f"hidden_{i}")(x))
    return x


def _zero_dense(n: int, name: str, param_dtype: Any) -> nn.Dense:
    return nn.Dense(n, kernel_init=nn.initializers.zeros, bias_init=nn.initializers.zeros,
                    param_dtype=param_dtype, name=name)


def _check_metric_fields(obj: Any) -> None:
    name = type(obj).__name__
    check_int(obj.dim, f"{name}.dim")
    check_fraction(obj.eps, f"{name}.eps", allow_zero=True)
    for i, h in enumerate(obj.hidden_sizes):
        check_int(h, f"{name}.hidden_sizes[{i}]")
    check_choice(obj.activation, f"{name}.activation", sorted(ACTIVATIONS))


def _check_input(x: jax.Array, dim: int, name: str) -> jax.Array:
    x = jnp.asarray(x)
    if x.ndim < 1 or x.shape[-1] != dim:
        raise ValueError(f"{name}: x must have shape (..., {dim}), got {x.shape}")
    return x


class CholeskyMetric(nn.Module):
    """``G(x) = L(x) L(x)ᵀ + εI`` (§4.3.1, Fig 4.5), ``G = I`` at initialisation.

    ``x → hidden_sizes`` (``activation``) → heads ``h_d (m)`` and ``h_o (m(m−1)/2)`` initialised
    at zero; ``L_ii = |h_i + c| + diag_eps`` (``diagonal="abs"``, the thesis) or
    ``softplus(h_i + c) + diag_eps`` (``"softplus"``), ``L_ij = h_o`` below the diagonal, with
    ``c`` such that ``L_ii = √(1 − eps)`` at ``h = 0``. ``λ_min(G) ≥ eps`` for all parameters.
    Defaults: hidden ``(128, 64)`` relu, ``diag_eps = 1e-5`` (docs/design.md §4.6), ``eps = 1e-5``.
    """

    dim: int
    hidden_sizes: Sequence[int] = (128, 64)
    activation: str = "relu"
    eps: float = 1e-5
    diag_eps: float = 1e-5
    diagonal: str = "abs"
    param_dtype: Any = jnp.float32

    def __post_init__(self) -> None:
        _check_metric_fields(self)
        check_choice(self.diagonal, "CholeskyMetric.diagonal", DIAGONALS)
        if check_float(self.diag_eps, "CholeskyMetric.diag_eps") >= math.sqrt(1.0 - self.eps):
            raise ValueError(f"CholeskyMetric.diag_eps must be in (0, √(1 − eps)), "
                             f"got {self.diag_eps!r}")
        super().__post_init__()

    def diagonal_offset(self) -> float:
        """``c`` with ``L_ii(h = 0) = √(1 − eps)`` (so ``G = I`` at initialisation)."""
        target = math.sqrt(1.0 - self.eps) - self.diag_eps
        if self.diagonal == "abs":
            return target
        return math.log(math.expm1(target))  # softplus⁻¹

    @nn.compact
    def factor(self, x: jax.Array) -> jax.Array:
        """The Cholesky factor ``L(x) (..., m, m)`` (lower-triangular, positive diagonal)."""
        x = _check_input(x, self.dim, "CholeskyMetric")
        m = self.dim
        h = _hidden(x, self.hidden_sizes, self.activation, self.param_dtype)
        h_d = _zero_dense(m, "diag", self.param_dtype)(h)
        h_o = _zero_dense(m * (m - 1) // 2, "off_diag", self.param_dtype)(h)
        c = self.diagonal_offset()
        if self.diagonal == "abs":
            l_d = jnp.abs(h_d + c) + self.diag_eps
        else:
            l_d = jax.nn.softplus(h_d + c) + self.diag_eps
        return lower_triangular(l_d, h_o)

    def __call__(self, x: jax.Array) -> jax.Array:
        """``G(x) (..., m, m)``, symmetric with ``λ_min ≥ eps``."""
        L = self.factor(x)
        G = L @ jnp.swapaxes(L, -1, -2)
        return _symmetrize(G) + self.eps * jnp.eye(self.dim, dtype=G.dtype)


class GramMetric(nn.Module):
    """``G(x) = A(x)ᵀ A(x) + εI`` (§4.3.1, Gram parameterisation), ``G = I`` at initialisation.

    ``x → hidden_sizes`` (``activation``) → a head of ``m²`` outputs initialised at zero,
    reshaped row-major to ``H``; ``A = H + √(1 − eps) I``. ``λ_min(G) ≥ eps`` for all parameters.
    Hidden sizes and activation default to the Cholesky network's (the thesis: "similar to Fig
    4.5").
    """

    dim: int
    hidden_sizes: Sequence[int] = (128, 64)
    activation: str = "relu"
    eps: float = 1e-5
    param_dtype: Any = jnp.float32

    def __post_init__(self) -> None:
        _check_metric_fields(self)
        super().__post_init__()

    @nn.compact
    def factor(self, x: jax.Array) -> jax.Array:
        """``A(x) (..., m, m)``."""
        x = _check_input(x, self.dim, "GramMetric")
        m = self.dim
        h = _hidden(x, self.hidden_sizes, self.activation, self.param_dtype)
        H = _zero_dense(m * m, "gram", self.param_dtype)(h).reshape((*h.shape[:-1], m, m))
        return H + math.sqrt(1.0 - self.eps) * jnp.eye(m, dtype=H.dtype)

    def __call__(self, x: jax.Array) -> jax.Array:
        """``G(x) (..., m, m)``, symmetric with ``λ_min ≥ eps``."""
        A = self.factor(x)
        G = jnp.swapaxes(A, -1, -2) @ A
        return _symmetrize(G) + self.eps * jnp.eye(self.dim, dtype=G.dtype)


# ---------------------------------------------------------------------------------------------
# Potentials
# ---------------------------------------------------------------------------------------------


def quadratic_potential(y: jax.Array) -> jax.Array:
    """``Φ̄(y) = ½‖y‖²`` over the last axis (the thesis' example below eq 4.7)."""
    return 0.5 * jnp.sum(y * y, axis=-1)


def smooth_norm_potential(y: jax.Array, eps: float = 1e-2) -> jax.Array:
    """``Φ̄(y) = √(‖y‖² + ε²) − ε``: a smoothed ``‖y‖``, whose negative gradient is (nearly) the
    unit latent velocity ``ẏ = −y/‖y‖`` of the original implementation (docs/design.md §4.6).
    Its only stationary point is the origin."""
    return jnp.sqrt(jnp.sum(y * y, axis=-1) + eps * eps) - eps


LatentPotential = Callable[[jax.Array], jax.Array]


def diffeomorphic_potential(
    flow: EuclideanizingFlow,
    variables: Any,
    x: jax.Array,
    goal: jax.Array | None = None,
    latent_potential: LatentPotential = quadratic_potential,
) -> jax.Array:
    """``Φ(x) = Φ̄(ψ(x))``, ``ψ(x) = φ_θ(x − g) − φ_θ(0)`` (eq 4.7 with the map of §4.2).

    ``x (..., dim)`` → ``(...)``. ``Φ(g) = 0`` exactly and ``Φ > 0`` elsewhere (``ψ`` is a
    bijection with ``ψ(g) = 0``) when ``Φ̄ ≥ 0`` vanishes only at the origin; ``goal`` (``None`` →
    0) broadcasts against ``x``.
    """
    return latent_potential(subtask_map(flow, variables, x, goal))


def diffeomorphic_potential_gradient(
    flow: EuclideanizingFlow,
    variables: Any,
    x: jax.Array,
    goal: jax.Array | None = None,
    latent_potential: LatentPotential = quadratic_potential,
) -> jax.Array:
    """``∇_x Φ = J_ψ(x)ᵀ ∇_y Φ̄(ψ(x))`` (eq 4.7), by one reverse-mode pass; ``x (..., dim)``.

    ``J_ψ = J_φ(x − g)`` is non-singular everywhere, so ``∇Φ = 0`` only where ``∇Φ̄ = 0``, i.e. at
    ``x = g``.
    """
    x = jnp.asarray(x)
    y, pullback = jax.vjp(lambda p: subtask_map(flow, variables, p, goal), x)
    # Points of a batch are independent, so the gradient of the sum is the per-point gradient.
    dPhi_bar = jax.grad(lambda v: jnp.sum(latent_potential(v)))(y)
    return pullback(dPhi_bar)[0]


# ---------------------------------------------------------------------------------------------
# Learned GDS leaf
# ---------------------------------------------------------------------------------------------


def learned_gds(
    metric: Callable[[jax.Array], jax.Array],
    potential: Callable[[jax.Array], jax.Array],
    damping: float | jax.Array,
    curvature: bool = True,
) -> Leaf:
    """GDS leaf ``(x (m,), ẋ (m,)) -> RMP(M = G(x), f = −∇Φ(x) − γ_d G(x) ẋ − ξ_G)`` (eq 4.6).

    ``metric(x) -> (m, m)`` a position-only Riemannian metric (e.g. :class:`CholeskyMetric`
    applied with its variables), ``potential(x) -> ()`` (e.g. :func:`diffeomorphic_potential`),
    ``damping = γ_d ≥ 0`` with ``B = γ_d G`` (§4.3.1). ``ξ_G = Ġ_x ẋ − ½∇_x(ẋᵀGẋ)`` (eq 3.13) is
    computed from one forward-mode Jacobian of ``metric``. ``curvature=False`` drops it: cheaper,
    but then no longer a GDS, so Lemma 3.2.1's ``V̇ = −ẋᵀBẋ`` does not hold (the velocity-based
    systems of Remark 5.1.1 avoid curvature terms altogether). With curvature the result equals
    :func:`mjxrmp.leaves.gds.gds` with ``G(x, ẋ) = metric(x)`` and ``B = γ_d G``. Lift to a
    family with :func:`mjxrmp.leaves.gds.family`.
    """
    if isinstance(damping, (int, float)) and not (damping >= 0 and math.isfinite(damping)):
        raise ValueError(f"damping must be finite and >= 0, got {damping!r}")

    def leaf(x: jax.Array, xd: jax.Array) -> RMP:
        x = jnp.asarray(x)
        xd = jnp.asarray(xd)
        if x.ndim != 1 or xd.shape != x.shape:
            raise ValueError(
                f"x and xd must be one subtask coordinate of equal shape (m,), got {x.shape} "
                f"and {xd.shape}; lift to a family (n, m) with mjxrmp.leaves.gds.family (jax.vmap)")
        m = x.shape[0]
        if jax.eval_shape(potential, x).shape != ():
            raise ValueError("potential(x) must return a scalar, got shape "
                             f"{jax.eval_shape(potential, x).shape}")
        grad_Phi = jax.grad(potential)(x)
        if curvature:
            # dG[i, j, k] = ∂G_ij/∂x_k from one linearisation of the metric.
            G, dG = _value_and_jacfwd(metric, x)
            if G.shape != (m, m):
                raise ValueError(f"metric(x) must return an ({m}, {m}) matrix, got {G.shape}")
            Gdot_xd = jnp.einsum("ijk,k,j->i", dG, xd, xd)            # Ġ_x ẋ
            grad_kinetic = jnp.einsum("i,ijk,j->k", xd, dG, xd)       # ∇_x(ẋᵀGẋ)
            xi = Gdot_xd - 0.5 * grad_kinetic
        else:
            G = metric(x)
            if G.shape != (m, m):
                raise ValueError(f"metric(x) must return an ({m}, {m}) matrix, got {G.shape}")
            xi = jnp.zeros_like(grad_Phi)
        f = -grad_Phi - damping * (G @ xd) - xi
        return RMP(G, f)

    return leaf


def _value_and_jacfwd(fn: Callable[[jax.Array], jax.Array], x: jax.Array
                      ) -> tuple[jax.Array, jax.Array]:
    """``(fn(x), ∂fn/∂x)`` with the Jacobian's input axis last, from one ``jax.linearize``."""
    value, lin = jax.linearize(fn, x)
    jac = jax.vmap(lin, out_axes=-1)(jnp.eye(x.shape[0], dtype=x.dtype))
    return value, jac
