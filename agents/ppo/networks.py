"""Flax networks for PPO (docs/design.md §2.3, docs/design.md §4.4).

* :class:`GaussianPolicy` — MLP mean (hidden sizes and activation configurable, output layer
  initialised with RLlib's ``normc`` scheme at scale 0.1) and a state-independent log standard
  deviation initialised at −1. ``__call__(obs, norm=None) -> (mean, log_std)``, the MLP reading
  the observation normalised by the running statistics ``norm`` (:mod:`agents.ppo.normalization`);
  ``log_std`` has shape ``(action_size,)`` and broadcasts against ``mean``.
* :class:`ValueMLP` — MLP (256, 128) tanh by default, scalar output: ``__call__(obs) -> (...,)``.
* :class:`PPONetworks` — the policy and value modules of one PPO program and how each reads the
  observation (normalised or raw).

Both work on a single observation ``(obs_size,)`` or on any leading batch shape.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from agents.ppo.normalization import RunningStats, normalize

#: Activations accepted by name (``PPOConfig.policy_activation`` / ``value_activation``).
ACTIVATIONS: dict[str, Callable[[jax.Array], jax.Array]] = {
    "tanh": jnp.tanh,
    "relu": jax.nn.relu,
    "elu": jax.nn.elu,
    "gelu": jax.nn.gelu,
    "swish": jax.nn.swish,
}


def normc(scale: float = 1.0) -> Callable[..., jax.Array]:
    """RLlib's ``normc_initializer``: Gaussian columns rescaled to Euclidean norm ``scale``.

    For a Dense kernel ``(fan_in, fan_out)`` every output unit's weight vector has norm
    ``scale``.
    """

    def init(key, shape, dtype=jnp.float32):
        w = jax.random.normal(key, shape, dtype)
        norm = jnp.sqrt(jnp.sum(w * w, axis=0, keepdims=True))
        return (scale * w / norm).astype(dtype)

    return init


def activation_fn(name: str) -> Callable[[jax.Array], jax.Array]:
    """The activation called ``name`` (clear error for unknown names)."""
    if name not in ACTIVATIONS:
        raise ValueError(f"unknown activation={name!r}; valid names are {sorted(ACTIVATIONS)}")
    return ACTIVATIONS[name]


class MLP(nn.Module):
    """Hidden layers with ``activation``, then a linear output layer of ``out_size`` units."""

    hidden_sizes: Sequence[int]
    out_size: int
    activation: str = "tanh"
    out_scale: float = 1.0

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        act = activation_fn(self.activation)
        for i, h in enumerate(self.hidden_sizes):
            x = act(nn.Dense(h, kernel_init=normc(1.0), name=f"hidden_{i}")(x))
        return nn.Dense(self.out_size, kernel_init=normc(self.out_scale), name="out")(x)


class GaussianPolicy(nn.Module):
    """Diagonal Gaussian policy: MLP mean, state-independent ``log_std`` (see module doc)."""

    action_size: int
    hidden_sizes: Sequence[int] = (256, 128)
    activation: str = "relu"
    out_scale: float = 0.1
    log_std_init: float = -1.0

    @nn.compact
    def __call__(self, obs: jax.Array, norm: RunningStats | None = None
                 ) -> tuple[jax.Array, jax.Array]:
        mean = MLP(self.hidden_sizes, self.action_size, self.activation, self.out_scale,
                   name="mean")(normalize(norm, obs))
        log_std = self.param(
            "log_std", nn.initializers.constant(self.log_std_init), (self.action_size,)
        )
        return mean, log_std


class ValueMLP(nn.Module):
    """State-value network, MLP (256, 128) tanh by default; returns shape ``obs.shape[:-1]``."""

    hidden_sizes: Sequence[int] = (256, 128)
    activation: str = "tanh"
    out_scale: float = 1.0

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        return MLP(self.hidden_sizes, 1, self.activation, self.out_scale, name="mlp")(obs)[..., 0]


@dataclasses.dataclass(frozen=True)
class PPONetworks:
    """The policy module (``apply(p, obs, norm) -> (mean, log_std)``) and value module of a PPO
    program. With ``normalize_observations`` both read the running statistics passed to
    :meth:`policy_apply` and :meth:`value_apply`; otherwise the statistics are ignored."""

    policy: nn.Module
    value: nn.Module
    normalize_observations: bool = False

    def norm(self, stats: RunningStats) -> RunningStats | None:
        """The statistics the networks read: ``stats``, or None without normalisation."""
        return stats if self.normalize_observations else None

    def policy_apply(self, params: Any, obs: jax.Array, stats: RunningStats,
                     features: Any = None) -> tuple[jax.Array, jax.Array]:
        """``(mean, log_std)`` of the policy at ``obs`` (with the policy's precomputed
        ``features`` of ``obs`` where it has them: :meth:`policy_features`)."""
        if features is None:
            return self.policy.apply(params, obs, self.norm(stats))
        return self.policy.apply(params, obs, self.norm(stats), features)

    def policy_features(self, obs: jax.Array, base_weight: Any = None) -> Any:
        """The parameter-free part of the policy at ``obs`` (its ``precompute(obs)``), or None
        for a policy without one; what :meth:`policy_apply` then needs no longer compute.
        ``base_weight`` (a packed sweep's per-run value, :mod:`agents.ppo.hparams`) scales it:
        only for a policy whose part is an added base acceleration (``weighted_base``)."""
        if base_weight is not None and not getattr(self.policy, "weighted_base", False):
            raise ValueError(f"base_weight needs a policy whose precomputed part is an added "
                             f"base acceleration (NNResidualPolicy), got "
                             f"{type(self.policy).__name__}")
        precompute = getattr(self.policy, "precompute", None)
        if precompute is None:
            return None
        features = precompute(obs)
        if base_weight is None:
            return features
        # weight 0 gives exactly 0, as the nn policy has no base, even where the base is not finite
        return jnp.where(base_weight != 0, base_weight * features, 0.0)

    def value_apply(self, params: Any, obs: jax.Array, stats: RunningStats) -> jax.Array:
        """State value at ``obs`` (normalised first when the networks normalise)."""
        return self.value.apply(params, normalize(self.norm(stats), obs))


__all__ = ["ACTIVATIONS", "MLP", "GaussianPolicy", "PPONetworks", "ValueMLP", "activation_fn",
           "normc"]
