"""Running observation statistics for PPO's observation normalisation (docs/design.md §2.3).

Only the *learned* parts of a policy (MLPs, the value network) read normalised observations;
RMP² always decodes the raw observation (see :mod:`agents.ppo.policies`). Statistics start at
mean 0 / variance 1 (normalisation is then the identity) and are merged batch by batch with
Chan et al.'s parallel update, so the result does not depend on how the data was chunked.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp


class RunningStats(NamedTuple):
    """Count, mean and (population) variance of the observations seen so far."""

    count: jax.Array  # scalar float32
    mean: jax.Array  # (obs_size,)
    var: jax.Array  # (obs_size,)


def init_stats(obs_size: int) -> RunningStats:
    """Empty statistics: count 0, mean 0, variance 1 (normalisation is the identity)."""
    if not isinstance(obs_size, int) or obs_size < 1:
        raise ValueError(f"obs_size must be a positive integer, got {obs_size!r}")
    return RunningStats(jnp.zeros((), jnp.float32), jnp.zeros((obs_size,), jnp.float32),
                        jnp.ones((obs_size,), jnp.float32))


def update_stats(stats: RunningStats, batch: jax.Array) -> RunningStats:
    """Merge the observations ``batch (..., obs_size)`` into ``stats`` (parallel update).

    With ``n_a, μ_a, σ²_a`` the old and ``n_b, μ_b, σ²_b`` the batch moments:
    ``μ = μ_a + δ·n_b/n``, ``σ² = (n_a σ²_a + n_b σ²_b + δ² n_a n_b / n) / n``, ``δ = μ_b − μ_a``.
    The first update replaces the initial variance 1 (its count is 0).
    """
    x = batch.reshape((-1, batch.shape[-1])).astype(jnp.float32)
    n_b = jnp.asarray(x.shape[0], jnp.float32)
    mean_b = jnp.mean(x, axis=0)
    var_b = jnp.mean(jnp.square(x - mean_b), axis=0)
    n = stats.count + n_b
    delta = mean_b - stats.mean
    mean = stats.mean + delta * (n_b / n)
    m2 = stats.count * stats.var + n_b * var_b + jnp.square(delta) * stats.count * n_b / n
    return RunningStats(n, mean, m2 / n)


def normalize(stats: RunningStats | None, obs: jax.Array, clip: float = 10.0,
              eps: float = 1e-8) -> jax.Array:
    """``clip((obs − μ)/√(σ² + eps), ±clip)``; ``obs`` unchanged when ``stats`` is None."""
    if stats is None:
        return obs
    z = (obs - stats.mean) / jnp.sqrt(stats.var + eps)
    return jnp.clip(z, -clip, clip)


__all__ = ["RunningStats", "init_stats", "normalize", "update_stats"]
