"""The data PPO carries between steps and iterations: :class:`Transition` (one environment step
of the whole batch) and :class:`TrainState` (everything a run needs to continue exactly)."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from agents.ppo.normalization import RunningStats


class Transition(NamedTuple):
    """One step of every environment; a rollout stacks them along a leading time axis."""

    obs: jax.Array
    actions: jax.Array
    log_probs: jax.Array
    values: jax.Array
    rewards: jax.Array
    dones: jax.Array
    truncations: jax.Array
    episode_return: jax.Array  # running return including this step (read where dones)
    episode_collided: jax.Array
    success: jax.Array  # the environment's "success" metric of this step (0 if it has none)
    #: What the policy computed from the state alone (its ``precompute``; None for a policy
    #: without one), kept for the update (docs/design.md §5.7).
    policy_features: Any = None


class TrainState(NamedTuple):
    """Everything a run needs to continue exactly: what a checkpoint holds.

    ``key`` is the run's raw ``uint32 (2,)`` key; iteration ``i`` uses ``fold_in(key, i)``, so a
    run split into chunks (or resumed from a checkpoint) draws the same random numbers as an
    uninterrupted one. ``iteration`` counts the iterations done. ``hparams`` (None for an
    ordinary run) holds the run's own values of scalar hyper-parameters in a packed sweep
    (:mod:`agents.ppo.hparams`); checkpoints of a sweep's runs are written without it.
    """

    params: dict[str, Any]
    opt_state: Any
    env_state: Any
    episode_return: jax.Array
    episode_collided: jax.Array
    obs_stats: RunningStats
    key: jax.Array
    iteration: jax.Array
    hparams: dict[str, jax.Array] | None = None


def raw_key(key: jax.Array) -> jax.Array:
    """A raw ``uint32 (2,)`` key from a typed or a raw ``key``."""
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        return jax.random.key_data(key)
    return key


def raw_keys(key: jax.Array, n: int) -> jax.Array:
    """``n`` raw ``uint32 (n, 2)`` keys, for a typed or a raw ``key``."""
    return raw_key(jax.random.split(key, n))


__all__ = ["TrainState", "Transition", "raw_key", "raw_keys"]
