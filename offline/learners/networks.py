"""Networks and parameter utilities shared by the offline learners (thesis ch. 7, docs/design.md
§4.5).

* :class:`QEnsemble` — ``num_critics`` independent Q-networks ``Q_i(s, a)`` (MLPs, 3×256 ReLU by
  default) evaluated in one call through ``nn.vmap``: ``__call__(obs, act) -> (..., num_critics)``.
  Kernels carry a leading ensemble axis ``(num_critics, fan_in, fan_out)``.
* :class:`StateNet` — an MLP on the state alone with ``out_size`` outputs (state values ``V(s)``
  for IQL, or any other ``s ↦ ℝ^k`` map), squeezed to ``(...,)`` when ``out_size == 1``.
* :func:`project_frobenius` — ATAC's projection after each critic step: every weight matrix
  (not the biases) rescaled to Frobenius norm ≤ ``max_norm`` (per ensemble member).
* :func:`polyak` — target-network update ``θ̄ ← (1 − τ) θ̄ + τ θ``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from agents.ppo.networks import MLP

#: ATAC's bound on each critic weight matrix's Frobenius norm (docs/design.md §4.5).
FROBENIUS_BOUND = 100.0


class QEnsemble(nn.Module):
    """``num_critics`` Q-networks on ``concat(obs, act)``; returns ``(..., num_critics)``."""

    num_critics: int = 2
    hidden_sizes: Sequence[int] = (256, 256, 256)
    activation: str = "relu"

    @nn.compact
    def __call__(self, obs: jax.Array, act: jax.Array) -> jax.Array:
        if obs.shape[:-1] != act.shape[:-1]:
            raise ValueError(f"obs and act must share their batch shape, got {obs.shape} and "
                             f"{act.shape}")
        ensemble = nn.vmap(MLP, variable_axes={"params": 0}, split_rngs={"params": True},
                           in_axes=None, out_axes=-1, axis_size=self.num_critics)
        q = ensemble(tuple(self.hidden_sizes), 1, self.activation, 1.0, name="critics")(
            jnp.concatenate([obs, act], axis=-1))
        return q[..., 0, :]


class StateNet(nn.Module):
    """MLP on the state alone: ``(..., out_size)``, or ``(...,)`` for ``out_size == 1``."""

    out_size: int = 1
    hidden_sizes: Sequence[int] = (256, 256, 256)
    activation: str = "relu"

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        out = MLP(tuple(self.hidden_sizes), self.out_size, self.activation, 1.0, name="mlp")(obs)
        return out[..., 0] if self.out_size == 1 else out


def project_frobenius(params: Any, max_norm: float = FROBENIUS_BOUND) -> Any:
    """Rescale every Dense ``kernel`` so that its Frobenius norm is at most ``max_norm``.

    Biases are left alone. A kernel with a leading ensemble axis (``ndim == 3``, as in
    :class:`QEnsemble`) is projected per member. Kernels already inside the ball are unchanged.
    """

    def one(path, x):
        if getattr(path[-1], "key", None) != "kernel":
            return x
        sq = jnp.sum(jnp.square(x), axis=(-2, -1), keepdims=True)
        scale = jnp.minimum(1.0, max_norm / jnp.sqrt(jnp.maximum(sq, 1e-30)))
        return x * scale

    return jax.tree_util.tree_map_with_path(one, params)


def polyak(target: Any, online: Any, tau: float | jax.Array) -> Any:
    """Soft target update ``θ̄ ← (1 − τ)·θ̄ + τ·θ`` leaf by leaf."""
    return jax.tree.map(lambda t, o: (1.0 - tau) * t + tau * o, target, online)


__all__ = ["FROBENIUS_BOUND", "QEnsemble", "StateNet", "polyak", "project_frobenius"]
