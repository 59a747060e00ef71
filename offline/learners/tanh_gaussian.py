"""Tanh-squashed diagonal Gaussian policy for the offline actors (ATAC / MAHALO, thesis §7.3.3,
docs/design.md §4.5: "a tanh-Gaussian actor, MLPs 3×256 ReLU").

An action is ``a = tanh(u)`` with ``u ~ N(μ(s), diag σ(s)²)``, so actions lie in ``(−1, 1)^A``.
By the change of variables ``u = atanh(a)`` the density of ``a`` is

    log π(a|s) = Σ_i [ log N(u_i; μ_i, σ_i) − log(1 − tanh(u_i)²) ],

and the Jacobian term is evaluated without cancellation as

    log(1 − tanh(u)²) = log sech(u)² = 2 (log 2 − u − softplus(−2u)),

which is finite for every ``u`` (the naive ``log(1 − tanh(u)²)`` is ``−inf`` in float32 once
``tanh(u)`` rounds to 1, at ``|u| ≳ 9``).

* :class:`TanhGaussian` — the distribution (a NamedTuple pytree of ``mean`` and ``log_std``,
  any batch shape ``(..., A)``): :meth:`~TanhGaussian.sample` returns the action and its exact
  log-probability computed from the pre-squash sample ``u``; :meth:`~TanhGaussian.log_prob`
  scores given actions; :meth:`~TanhGaussian.mode` is the deterministic action ``tanh(μ)``;
  :meth:`~TanhGaussian.entropy` a Monte-Carlo estimate (the tanh-Gaussian entropy has no closed
  form).
* :class:`TanhGaussianPolicy` — flax module, ``policy.apply(params, obs) -> TanhGaussian``: an
  MLP (:class:`agents.ppo.networks.MLP`, 3×256 ReLU by default) outputs ``μ`` and ``log σ``; the
  log-std is clipped to ``[log_std_min, log_std_max]`` (default ``[−5, 2]``; docs/design.md §4.5
  gives no range for the thesis' actor).

``log_prob`` of given actions inverts the squashing: ``u = atanh(clip(a, −1 + ε, 1 − ε))`` with
``ε = 1e-6`` by default. The clip keeps dataset actions on the boundary (``|a| = 1``, e.g.
clipped behaviour actions) finite: they are scored as if at ``±(1 − ε)``, i.e. at
``|u| ≈ 7.25``. The clip and float32 rounding near ``|a| = 1`` mean ``log_prob(a)`` agrees with
the log-probability returned by ``sample`` only while ``|u|`` stays well below that; use the
latter for the actor's own samples (as SAC / ATAC do).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp

from agents.ppo.networks import MLP

#: Default log-std range (docs/design.md §4.5 gives none for the thesis' actor).
LOG_STD_MIN = -5.0
LOG_STD_MAX = 2.0
#: Default clip of given actions away from ±1 in :meth:`TanhGaussian.log_prob`.
ACTION_EPS = 1e-6

_LOG_2 = math.log(2.0)
_LOG_2PI = math.log(2.0 * math.pi)


def tanh_log_det_jacobian(u: jax.Array) -> jax.Array:
    """Elementwise ``log(1 − tanh(u)²) = 2 (log 2 − u − softplus(−2u))``, stable for all ``u``."""
    return 2.0 * (_LOG_2 - u - jax.nn.softplus(-2.0 * u))


def gaussian_log_prob(u: jax.Array, mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """Log-density of a diagonal Gaussian at ``u``, summed over the last axis."""
    z = (u - mean) * jnp.exp(-log_std)
    return jnp.sum(-0.5 * z * z - log_std - 0.5 * _LOG_2PI, axis=-1)


class TanhGaussian(NamedTuple):
    """``a = tanh(u)``, ``u ~ N(mean, diag exp(log_std)²)``; arrays of shape ``(..., A)``."""

    mean: jax.Array
    log_std: jax.Array

    def log_prob_pre_tanh(self, u: jax.Array) -> jax.Array:
        """``log π(tanh(u))`` from the pre-squash value ``u`` (exact; shape ``(...,)``)."""
        return (gaussian_log_prob(u, self.mean, self.log_std)
                - jnp.sum(tanh_log_det_jacobian(u), axis=-1))

    def sample_pre_tanh(self, key: jax.Array, sample_shape: Sequence[int] = ()) -> jax.Array:
        """Reparameterised ``u = mean + exp(log_std)·ε``, shape ``sample_shape + mean.shape``."""
        shape = (*tuple(sample_shape), *self.mean.shape)
        return self.pre_tanh_from_noise(jax.random.normal(key, shape, self.mean.dtype))

    def pre_tanh_from_noise(self, noise: jax.Array) -> jax.Array:
        """``u = mean + exp(log_std)·noise`` for standard-normal ``noise`` drawn elsewhere
        (``sample_pre_tanh(key)`` is this with ``noise = normal(key, mean.shape)``)."""
        return self.mean + jnp.exp(self.log_std) * noise

    def sample(self, key: jax.Array, sample_shape: Sequence[int] = ()
               ) -> tuple[jax.Array, jax.Array]:
        """``(action, log_prob)``: ``action = tanh(u)`` of shape ``sample_shape + (..., A)`` and
        its log-probability ``(sample_shape + (...,))`` by the change of variables (module doc).

        Differentiable in ``mean`` / ``log_std`` (reparameterisation).
        """
        u = self.sample_pre_tanh(key, sample_shape)
        return jnp.tanh(u), self.log_prob_pre_tanh(u)

    def sample_from_noise(self, noise: jax.Array) -> tuple[jax.Array, jax.Array]:
        """:meth:`sample` with its standard-normal ``noise`` drawn elsewhere (e.g. for many
        steps at once): ``(tanh(u), log π)``, ``u`` from :meth:`pre_tanh_from_noise`."""
        u = self.pre_tanh_from_noise(noise)
        return jnp.tanh(u), self.log_prob_pre_tanh(u)

    def log_prob(self, action: jax.Array, eps: float = ACTION_EPS) -> jax.Array:
        """Log-probability of given actions in ``(−1, 1)^A``, shape ``action.shape[:-1]``.

        ``u = atanh(clip(action, −1 + eps, 1 − eps))``; the clip keeps boundary actions finite
        (see the module docstring for what it costs near ``|a| = 1``).
        """
        a = jnp.clip(action, -1.0 + eps, 1.0 - eps)
        return self.log_prob_pre_tanh(jnp.arctanh(a))

    def mode(self) -> jax.Array:
        """The deterministic action ``tanh(mean)`` (used for evaluation)."""
        return jnp.tanh(self.mean)

    def entropy(self, key: jax.Array, num_samples: int = 16) -> jax.Array:
        """Monte-Carlo entropy estimate ``−mean_k log π(a_k)``, ``a_k ~ π``; shape ``(...,)``.

        Unbiased; differentiable through the reparameterised samples.
        """
        if num_samples < 1:
            raise ValueError(f"num_samples must be >= 1, got {num_samples!r}")
        _, logp = self.sample(key, (num_samples,))
        return -jnp.mean(logp, axis=0)


class TanhGaussianPolicy(nn.Module):
    """MLP → ``(mean, log_std)`` of a :class:`TanhGaussian` (see the module docstring).

    ``__call__(obs)`` accepts ``(O,)`` or any batch ``(..., O)``. The output layer is
    initialised with RLlib's ``normc`` at ``out_scale``; the log-std is clipped (hard clip:
    no gradient beyond the range) to ``[log_std_min, log_std_max]``.
    """

    action_size: int
    hidden_sizes: Sequence[int] = (256, 256, 256)
    activation: str = "relu"
    log_std_min: float = LOG_STD_MIN
    log_std_max: float = LOG_STD_MAX
    out_scale: float = 0.1

    @nn.compact
    def __call__(self, obs: jax.Array) -> TanhGaussian:
        if not isinstance(self.action_size, int) or self.action_size < 1:
            raise ValueError(f"action_size must be a positive integer, got "
                             f"{self.action_size!r}")
        if not self.log_std_min < self.log_std_max:
            raise ValueError(f"log_std_min={self.log_std_min!r} must be smaller than "
                             f"log_std_max={self.log_std_max!r}")
        out = MLP(self.hidden_sizes, 2 * self.action_size, self.activation, self.out_scale,
                  name="mlp")(obs)
        mean, log_std = jnp.split(out, 2, axis=-1)
        return TanhGaussian(mean, jnp.clip(log_std, self.log_std_min, self.log_std_max))


__all__ = [
    "ACTION_EPS",
    "LOG_STD_MAX",
    "LOG_STD_MIN",
    "TanhGaussian",
    "TanhGaussianPolicy",
    "gaussian_log_prob",
    "tanh_log_det_jacobian",
]
