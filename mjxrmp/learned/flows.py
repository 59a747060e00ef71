"""Euclideanizing flow: a diffeomorphism built from affine coupling layers (thesis §4.2.2).

The flow ``φ_θ = φ_M ∘ … ∘ φ_1 : ℝⁿ → ℝⁿ`` composes ``M`` coupling layers (eq 4.4)::

    y_m = [y_{m−1}^a ;  y_{m−1}^b ⊙ exp(s_m(y_{m−1}^a)) + t_m(y_{m−1}^a)]        (4.4)

where ``a`` are the *conditioning* coordinates (passed through) and ``b`` the transformed ones.
The split alternates by index parity and the pattern is reversed after every layer (layer ``k``
passes through the coordinates ``i`` with ``(i + k)`` odd, as in the original implementation's
``mask = arange(n) % 2`` flipped after each block), so any ``n ≥ 2`` works, odd ``n`` included.

Scale and translation functions (eq 4.5) are either

* ``net="rff"`` (the thesis, default): ``g(z) = φ(z)ᵀ w`` with ``N`` *fixed* random Fourier
  features ``φ(z) = c·cos(αᵢᵀ z + βᵢ)``, ``αᵢ ~ N(0, l⁻² I)``, ``βᵢ ~ U[0, 2π)``, and a learnable,
  bias-free read-out ``w`` initialised at zero. The thesis writes ``c = √(2/N)``; the original
  implementation uses ``c = 1``, and its training settings (docs/design.md §4.6: Adam, lr 1e-4) were
  tuned for that. Both span the same function class (``w ↦ c·w``); ``normalize_features=False``
  (default) is the original's ``c = 1``, ``True`` gives eq 4.5's ``√(2/N)``.
* ``net="mlp"``: a fully connected network (hidden ``(100, 100)``, ``elu``; the original
  implementation's ``fcnn`` variant) whose last layer (weights and bias) is initialised at zero.

Defaults are the values of the thesis and docs/design.md §4.6: ``M = 10`` layers, ``N = 200``
features, length-scale ``l = 0.45``. Every zero-initialised read-out gives ``s ≡ t ≡ 0``, so the
flow is **exactly the identity at initialisation**. The inverse is exact (up to rounding): the
conditioning coordinates pass through unchanged, so ``s`` and ``t`` are recomputed from the output
and ``y^b = (y_m^b − t) ⊙ exp(−s)``. The Jacobian of one layer is triangular up to a permutation, so
``log|det J_φ| = Σ_m Σ_b s_m`` comes for free with the forward pass.

The networks are :mod:`flax.linen` modules (as elsewhere in the project: a frozen dataclass
configuration, ``apply`` a pure function of a variables pytree). The fixed random features live in
the ``"constants"`` collection, the learnable read-outs in ``"params"``::

    flow = EuclideanizingFlow(dim=2)
    variables = flow.init(key, jnp.zeros(2))        # {"params": ..., "constants": ...}
    y = flow.apply(variables, x)                    # x (..., n): one point or a batch
    x = flow.apply(variables, y, method="inverse")
    y, log_det = flow.apply(variables, x, method="forward_and_log_det")
    J = jacobian(flow, variables, x)                # (..., n, n)

Train with gradients of ``variables["params"]`` only (keep ``"constants"`` fixed). The subtask
map of §4.2, ``ψ = (φ_θ − φ_θ(0)) ∘ (FK − g)``, is :func:`subtask_map` applied to ``FK(q)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from mjxrmp.config import check_choice, check_float, check_int

#: Flax collection holding the fixed (not learned) random Fourier features.
CONSTANTS = "constants"

NETS = ("rff", "mlp")

ACTIVATIONS: dict[str, Callable[[jax.Array], jax.Array]] = {
    "elu": jax.nn.elu,
    "tanh": jnp.tanh,
    "relu": jax.nn.relu,
    "softplus": jax.nn.softplus,
    "swish": jax.nn.swish,
    "gelu": jax.nn.gelu,
}

__all__ = [
    "ACTIVATIONS",
    "CONSTANTS",
    "NETS",
    "AffineCoupling",
    "EuclideanizingFlow",
    "RandomFourierFeatures",
    "ZeroInitMLP",
    "coupling_mask",
    "jacobian",
    "subtask_map",
]


def _activation(name: str) -> Callable[[jax.Array], jax.Array]:
    if name not in ACTIVATIONS:
        raise ValueError(f"unknown activation={name!r}; valid names are {sorted(ACTIVATIONS)}")
    return ACTIVATIONS[name]


def coupling_mask(dim: int, layer: int) -> tuple[bool, ...]:
    """Conditioning coordinates of coupling layer ``layer``: ``True`` where ``(i + layer)`` is odd.

    Layer 0 passes the odd indices through and transforms the even ones; the pattern flips after
    every layer (eq 4.4, footnote 5). Both parts are non-empty for ``dim ≥ 2``.
    """
    return tuple(bool((i + layer) % 2) for i in range(dim))


class RandomFourierFeatures(nn.Module):
    """``g(z) = φ(z)ᵀ w``: fixed random Fourier features, zero-initialised linear read-out (eq 4.5).

    ``φ(z) = c·cos(zα + β)`` with ``α (d_in, N) ~ N(0, l⁻²)`` and ``β (N,) ~ U[0, 2π)`` drawn at
    ``init`` from the ``"params"`` key and stored in :data:`CONSTANTS`; ``c = √(2/N)`` if
    ``normalize`` else 1. The read-out ``w (N, out_dim)`` has no bias. Works on ``z (..., d_in)``.
    """

    out_dim: int
    num_features: int = 200
    length_scale: float = 0.45
    normalize: bool = False
    param_dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, z: jax.Array) -> jax.Array:
        d_in, n = z.shape[-1], self.num_features
        alpha = self.variable(
            CONSTANTS, "alpha",
            lambda: jax.random.normal(self.make_rng("params"), (d_in, n), self.param_dtype)
            / self.length_scale,
        ).value
        beta = self.variable(
            CONSTANTS, "beta",
            lambda: jax.random.uniform(self.make_rng("params"), (n,), self.param_dtype,
                                       0.0, 2.0 * math.pi),
        ).value
        features = jnp.cos(z @ alpha + beta)
        if self.normalize:
            features = features * math.sqrt(2.0 / n)
        w = self.param("w", nn.initializers.zeros, (n, self.out_dim), self.param_dtype)
        return features @ w


class ZeroInitMLP(nn.Module):
    """MLP ``hidden_sizes`` with ``activation``, then a linear layer initialised at zero."""

    out_dim: int
    hidden_sizes: Sequence[int] = (100, 100)
    activation: str = "elu"
    param_dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, z: jax.Array) -> jax.Array:
        act = _activation(self.activation)
        for i, h in enumerate(self.hidden_sizes):
            z = act(nn.Dense(h, param_dtype=self.param_dtype, name=f"hidden_{i}")(z))
        return nn.Dense(self.out_dim, kernel_init=nn.initializers.zeros,
                        bias_init=nn.initializers.zeros, param_dtype=self.param_dtype,
                        name="out")(z)


class AffineCoupling(nn.Module):
    """One affine coupling layer ``φ_m`` of eq 4.4 with conditioning ``mask`` (``True``: pass).

    ``s`` and ``t`` read the input with the transformed coordinates zeroed (so they depend on
    ``y^a`` only) and are zeroed on the conditioning coordinates. Calls return
    ``(output, log|det J|)`` with ``log|det J| = Σ_b s_b`` of shape ``(...)``.
    """

    mask: tuple[bool, ...]
    net: str = "rff"
    num_features: int = 200
    length_scale: float = 0.45
    normalize_features: bool = False
    hidden_sizes: Sequence[int] = (100, 100)
    activation: str = "elu"
    param_dtype: Any = jnp.float32

    def setup(self) -> None:
        """The scale and translation networks of the layer (flax hook)."""
        d = len(self.mask)
        if self.net == "rff":
            make = lambda name: RandomFourierFeatures(  # noqa: E731
                d, self.num_features, self.length_scale, self.normalize_features,
                self.param_dtype, name=name)
        else:
            make = lambda name: ZeroInitMLP(  # noqa: E731
                d, tuple(self.hidden_sizes), self.activation, self.param_dtype, name=name)
        self.scale_net = make("scale")
        self.translate_net = make("translate")

    def _scale_translate(self, y: jax.Array) -> tuple[jax.Array, jax.Array]:
        keep = jnp.asarray(self.mask)
        z = jnp.where(keep, y, 0.0)
        s = jnp.where(keep, 0.0, self.scale_net(z))
        t = jnp.where(keep, 0.0, self.translate_net(z))
        return s, t

    def __call__(self, y: jax.Array) -> tuple[jax.Array, jax.Array]:
        s, t = self._scale_translate(y)
        return y * jnp.exp(s) + t, jnp.sum(s, axis=-1)

    def inverse(self, y: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(x, log|det ∂x/∂y|)``: the exact inverse of the layer and its log-determinant."""
        s, t = self._scale_translate(y)
        return (y - t) * jnp.exp(-s), -jnp.sum(s, axis=-1)


class EuclideanizingFlow(nn.Module):
    """Euclideanizing flow ``φ_θ = φ_M ∘ … ∘ φ_1`` on ``ℝ^dim`` (thesis §4.2.2, eqs 4.4–4.5).

    See the module docstring. Methods (all on ``x (..., dim)``, a point or any batch):
    ``__call__`` → ``φ(x)``; ``forward_and_log_det`` → ``(φ(x), log|det J_φ(x)|)``;
    ``inverse`` → ``φ⁻¹(y)``; ``inverse_and_log_det`` → ``(φ⁻¹(y), log|det J_{φ⁻¹}(y)|)``.
    """

    dim: int
    num_layers: int = 10
    num_features: int = 200
    length_scale: float = 0.45
    net: str = "rff"
    normalize_features: bool = False
    hidden_sizes: Sequence[int] = (100, 100)
    activation: str = "elu"
    param_dtype: Any = jnp.float32

    def __post_init__(self) -> None:
        check_int(self.dim, "EuclideanizingFlow.dim", minimum=2)  # a coupling needs two parts
        check_int(self.num_layers, "EuclideanizingFlow.num_layers")
        check_choice(self.net, "EuclideanizingFlow.net", NETS)
        if self.net == "rff":
            check_int(self.num_features, "EuclideanizingFlow.num_features")
            check_float(self.length_scale, "EuclideanizingFlow.length_scale")
        else:
            check_choice(self.activation, "EuclideanizingFlow.activation", sorted(ACTIVATIONS))
            for i, h in enumerate(self.hidden_sizes):
                check_int(h, f"EuclideanizingFlow.hidden_sizes[{i}]")
        super().__post_init__()

    def setup(self) -> None:
        """The ``num_layers`` coupling layers, conditioning parts alternating (flax hook)."""
        self.layers = [
            AffineCoupling(coupling_mask(self.dim, k), self.net, self.num_features,
                           self.length_scale, self.normalize_features, tuple(self.hidden_sizes),
                           self.activation, self.param_dtype, name=f"coupling_{k}")
            for k in range(self.num_layers)
        ]

    def _check(self, x: jax.Array, name: str) -> jax.Array:
        x = jnp.asarray(x)
        if x.ndim < 1 or x.shape[-1] != self.dim:
            raise ValueError(f"{name} must have shape (..., {self.dim}), got {x.shape}")
        return x

    def forward_and_log_det(self, x: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(φ(x), log|det J_φ(x)|)``: the log-determinant is ``Σ_m Σ_b s_m`` (eq 4.4)."""
        y = self._check(x, "x")
        log_det = jnp.zeros(y.shape[:-1], jnp.result_type(y.dtype, self.param_dtype))
        for layer in self.layers:
            y, ld = layer(y)
            log_det = log_det + ld
        return y, log_det

    def __call__(self, x: jax.Array) -> jax.Array:
        """``φ(x)`` for ``x (..., dim)``."""
        return self.forward_and_log_det(x)[0]

    def inverse_and_log_det(self, y: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(φ⁻¹(y), log|det J_{φ⁻¹}(y)|)``: the layers undone in reverse order."""
        x = self._check(y, "y")
        log_det = jnp.zeros(x.shape[:-1], jnp.result_type(x.dtype, self.param_dtype))
        for layer in reversed(self.layers):
            x, ld = layer.inverse(x)
            log_det = log_det + ld
        return x, log_det

    def inverse(self, y: jax.Array) -> jax.Array:
        """``φ⁻¹(y)`` for ``y (..., dim)`` (exact inverse of :meth:`__call__`)."""
        return self.inverse_and_log_det(y)[0]


def jacobian(flow: EuclideanizingFlow, variables: Any, x: jax.Array,
             inverse: bool = False) -> jax.Array:
    """Jacobian ``J_φ(x) = ∂φ/∂x`` (or ``∂φ⁻¹/∂y`` if ``inverse``), shape ``(..., dim, dim)``.

    Forward-mode autodiff per point (``dim`` is small), ``vmap``-ed over any leading axes. Call
    it inside ``jax.jit`` (``flow`` is static): run eagerly it dispatches op by op.
    """
    x = jnp.asarray(x)
    method = "inverse" if inverse else None
    one = jax.jacfwd(lambda p: flow.apply(variables, p, method=method))
    if x.ndim == 1:
        return one(x)
    flat = x.reshape((-1, x.shape[-1]))
    return jax.vmap(one)(flat).reshape((*x.shape, x.shape[-1]))


def subtask_map(flow: EuclideanizingFlow, variables: Any, x: jax.Array,
                goal: jax.Array | None = None) -> jax.Array:
    """``ψ(x) = φ_θ(x − g) − φ_θ(0)`` (§4.2): the goal maps to the origin for any ``θ``.

    With ``x = FK(q)`` this is the thesis' subtask map ``(φ_θ − φ_θ(0)) ∘ (FK − g)``. ``goal``
    (``None`` → 0) broadcasts against ``x (..., dim)``.
    """
    x = jnp.asarray(x)
    if goal is not None:
        x = x - goal
    origin = flow.apply(variables, jnp.zeros((flow.dim,), x.dtype))
    return flow.apply(variables, x) - origin
