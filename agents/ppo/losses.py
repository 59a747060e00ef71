"""PPO's numerics (thesis §6.2.3): diagonal-Gaussian log-density and entropy, generalised
advantage estimation and the clipped-surrogate loss.

Truncation (time limits) in :func:`gae`
---------------------------------------
``dones`` marks the last transition of an episode, ``truncations`` the subset that ended by the
time limit (brax's ``EpisodeWrapper`` sets both). A *terminated* transition bootstraps with 0.
A *truncated* transition must bootstrap from the value of its terminal observation; the
auto-reset wrapper (:func:`envs.wrappers.wrap`) replaces that observation by the first one of the
next episode, so:

* if ``terminal_values`` is given, a truncated step uses ``r + γ·terminal_values[t]``;
* otherwise (what :func:`agents.ppo.train.make_train` does) it uses ``r + γ·values[t]``: the
  value of the last observation seen before the time limit stands in for the value of the
  terminal one (one control step apart). The bootstrap is *not* zeroed — a time limit is not a
  failure.

In both cases the GAE recursion is cut at every episode end (``dones``), so nothing leaks from
the next episode into this one.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

_LOG_2PI = math.log(2.0 * math.pi)


def gaussian_log_prob(x: jax.Array, mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """Log-density of a diagonal Gaussian, summed over the last axis."""
    log_std = jnp.broadcast_to(log_std, mean.shape)
    z = (x - mean) * jnp.exp(-log_std)
    return jnp.sum(-0.5 * z * z - log_std - 0.5 * _LOG_2PI, axis=-1)


def gaussian_entropy(log_std: jax.Array, mean: jax.Array) -> jax.Array:
    """Entropy of a diagonal Gaussian (shape ``mean.shape[:-1]``)."""
    log_std = jnp.broadcast_to(log_std, mean.shape)
    return jnp.sum(log_std + 0.5 * (_LOG_2PI + 1.0), axis=-1)


def gae(
    rewards: jax.Array,
    values: jax.Array,
    dones: jax.Array,
    truncations: jax.Array,
    last_value: jax.Array,
    gamma: float,
    lam: float,
    terminal_values: jax.Array | None = None,
) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimation over a time-major rollout; ``(advantages, returns)``.

    ``rewards, values, dones, truncations`` (and ``terminal_values``) have shape ``(T, ...)``;
    ``last_value`` ``(...)`` is the value of the observation after the last step. Flag ``t``
    refers to transition ``t`` (``s_t → s_{t+1}``); a truncated step counts as an episode end
    even if its ``dones`` flag is 0. See the module docstring for the bootstrap rule.
    """
    dones = jnp.asarray(dones, values.dtype)
    truncations = jnp.asarray(truncations, values.dtype)
    ended = jnp.maximum(dones, truncations)
    terminated = ended * (1.0 - truncations)
    if terminal_values is None:
        terminal_values = values
    next_values = jnp.concatenate([values[1:], last_value[None]], axis=0)
    bootstrap = jnp.where(truncations > 0, terminal_values, next_values)
    deltas = rewards + gamma * (1.0 - terminated) * bootstrap - values

    def body(carry, xs):
        delta, end = xs
        adv = delta + gamma * lam * (1.0 - end) * carry
        return adv, adv

    _, advantages = jax.lax.scan(body, jnp.zeros_like(last_value), (deltas, ended),
                                 reverse=True)
    return advantages, advantages + values


def ppo_loss(
    params: dict[str, Any],
    batch: dict[str, jax.Array],
    policy_apply: Callable,
    value_apply: Callable,
    clip_eps: float,
    vf_coef: float,
    ent_coef: float,
    normalize_advantages: bool = True,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Clipped-surrogate PPO loss and metrics.

    ``params = {"policy": ..., "value": ...}``; ``policy_apply(p, obs) -> (mean, log_std)``,
    ``value_apply(p, obs) -> value``. ``batch`` holds ``obs (N, O)``, ``actions (N, A)``,
    ``log_probs (N,)`` (behaviour policy), ``advantages (N,)``, ``returns (N,)``.

    ``loss = −mean(min(ρA, clip(ρ, 1−ε, 1+ε)A)) + vf_coef·½·mean((V − R)²) − ent_coef·mean(H)``
    with ``ρ = exp(log π(a|s) − log π_old(a|s))`` and ``A`` normalised to zero mean and unit
    standard deviation over the batch when ``normalize_advantages``.
    """
    obs = batch["obs"]
    mean, log_std = policy_apply(params["policy"], obs)
    log_prob = gaussian_log_prob(batch["actions"], mean, log_std)
    log_ratio = log_prob - batch["log_probs"]
    ratio = jnp.exp(log_ratio)
    adv = batch["advantages"]
    if normalize_advantages:
        adv = (adv - jnp.mean(adv)) / (jnp.std(adv) + 1e-8)
    surrogate = jnp.minimum(ratio * adv, jnp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps) * adv)
    policy_loss = -jnp.mean(surrogate)
    value = value_apply(params["value"], obs)
    value_loss = 0.5 * jnp.mean((value - batch["returns"]) ** 2)
    entropy = jnp.mean(gaussian_entropy(log_std, mean))
    loss = policy_loss + vf_coef * value_loss - ent_coef * entropy
    metrics = {
        "loss": loss,
        "policy_loss": policy_loss,
        "value_loss": value_loss,
        "entropy": entropy,
        "approx_kl": jnp.mean((ratio - 1.0) - log_ratio),
        "clip_fraction": jnp.mean((jnp.abs(ratio - 1.0) > clip_eps).astype(loss.dtype)),
    }
    return loss, metrics


__all__ = ["gae", "gaussian_entropy", "gaussian_log_prob", "ppo_loss"]
