"""Acting: ``rollout_length`` steps of every auto-resetting environment under the current
Gaussian policy (one ``lax.scan``), and the episode statistics of a rollout.

Episode returns and collision flags are accumulated here (sum of rewards; max of
``state.metrics["collision"]`` when the environment has that metric, else 0) because the
auto-reset wrapper clears the environment's own accumulators on the terminal step.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import Env

from agents.ppo.hparams import base_weight
from agents.ppo.losses import gaussian_log_prob
from agents.ppo.networks import PPONetworks
from agents.ppo.state import TrainState, Transition
from envs.wrappers import AutoResetWrapper

#: Environment steps between two reset pools of the pooled rollout (a divisor of the rollout
#: length is used) and the episode starts each pool holds per environment.
POOL_BLOCK = 64
POOL_DEPTH = 2


def pool_block(num_steps: int, block: int = POOL_BLOCK) -> int | None:
    """The largest divisor of ``num_steps`` not above ``block``, or None when it is below 8
    (too short a block for a pool to pay off)."""
    size = max(d for d in range(1, min(block, num_steps) + 1) if num_steps % d == 0)
    return size if size >= 8 else None


def make_rollout(env: Env, nets: PPONetworks, num_steps: int, constrain: Callable[..., Any],
                 seed_axis: str | None = None, reset_pools: bool = False
                 ) -> Callable[[TrainState, jax.Array], tuple[TrainState, Transition]]:
    """``rollout(ts, key) -> (ts, transitions)``: ``num_steps`` steps of the batched,
    auto-resetting ``env`` with actions sampled from the policy; ``transitions`` is time-major
    ``(num_steps, num_envs, ...)``. ``constrain`` places the environment batch on the mesh
    (:func:`agents.ppo.sharding.batch_axis_sharding`).

    ``seed_axis`` is the ``axis_name`` of the ``vmap`` over seeds around the trainer (None when
    there is none). With an :class:`envs.wrappers.AutoResetWrapper` environment a step computes
    the reset only when an episode ended in some environment of some seed: the axis name lets
    every seed take the same branch, so it is a real conditional (docs/design.md §5.7). With
    ``reset_pools`` as well, the steps run in blocks of :func:`pool_block` steps, each
    restarting finished episodes from a :class:`~envs.wrappers.ResetPool` of
    :data:`POOL_DEPTH` starts made at the block's beginning; a block in which some environment
    (of any seed) finishes more episodes than that is run again step by step. All give the
    same transitions.
    """
    auto_reset = isinstance(env, AutoResetWrapper)
    block = pool_block(num_steps) if seed_axis is not None and reset_pools else None
    pooled = block is not None and auto_reset
    axis = {"axis_name": seed_axis} if auto_reset and seed_axis is not None else {}

    def act(carry, key, advance):
        params, stats, state, ep_ret, ep_col, weight = carry
        obs = state.obs
        features = nets.policy_features(obs, weight)
        mean, log_std = nets.policy_apply(params["policy"], obs, stats, features)
        action = mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape, mean.dtype)
        value = nets.value_apply(params["value"], obs, stats)
        state, extra = advance(state, action)
        state = constrain(state)
        reward = state.reward.astype(jnp.float32)
        done = state.done.astype(jnp.float32)
        collision = state.metrics.get("collision", jnp.zeros_like(reward))
        success = state.metrics.get("success", jnp.zeros_like(reward)).astype(jnp.float32)
        ep_ret = ep_ret + reward
        ep_col = jnp.maximum(ep_col, collision.astype(jnp.float32))
        tr = Transition(obs, action, gaussian_log_prob(action, mean, log_std), value, reward,
                        done, state.info["truncation"].astype(jnp.float32), ep_ret, ep_col,
                        success, features)
        ep_ret = jnp.where(done > 0, 0.0, ep_ret)
        ep_col = jnp.where(done > 0, 0.0, ep_col)
        return (params, stats, state, ep_ret, ep_col, weight), tr, extra

    def plain(carry, keys):
        def body(c, key):
            c, tr, _ = act(c, key, lambda s, a: (env.step(s, a, **axis), None))
            return c, tr
        return jax.lax.scan(body, carry, keys)

    def from_pool(carry, keys):
        def body(c, key):
            c, pool = c
            c, tr, pool = act(c, key, lambda s, a: env.step_from_pool(s, a, pool))
            return (c, pool), tr
        pool = env.reset_pool(carry[2], POOL_DEPTH)
        (carry_out, pool), tr = jax.lax.scan(body, (carry, pool), keys)
        redo = jax.lax.pmax(pool.overflow, seed_axis)
        return jax.lax.cond(redo, plain, lambda c, k: (carry_out, tr), carry, keys)

    def rollout(ts, key):
        carry = (ts.params, ts.obs_stats, ts.env_state, ts.episode_return, ts.episode_collided,
                 base_weight(ts.hparams))
        keys = jax.random.split(key, num_steps)
        if pooled:
            blocks = keys.reshape((num_steps // block, block, *keys.shape[1:]))
            carry, tr = jax.lax.scan(from_pool, carry, blocks)
            tr = jax.tree.map(lambda x: x.reshape((num_steps, *x.shape[2:])), tr)
        else:
            carry, tr = plain(carry, keys)
        _, _, state, ep_ret, ep_col, _ = carry
        ts = ts._replace(env_state=state, episode_return=ep_ret, episode_collided=ep_col)
        return ts, constrain(tr, 1)

    return rollout


def episode_metrics(tr: Transition) -> dict[str, jax.Array]:
    """``mean_reward`` over all transitions, ``episodes`` (how many finished), and over the
    finished episodes (NaN when none finished) ``mean_episode_return``, ``safe_fraction``
    (``1 − collided``) and ``success_fraction`` (``success`` of the terminal step)."""
    n_done = jnp.sum(tr.dones)
    denom = jnp.maximum(n_done, 1.0)
    nan = jnp.asarray(jnp.nan, jnp.float32)

    def over_episodes(x):
        return jnp.where(n_done > 0, jnp.sum(tr.dones * x) / denom, nan)

    return {
        "mean_reward": jnp.mean(tr.rewards),
        "episodes": n_done,
        "mean_episode_return": over_episodes(tr.episode_return),
        "safe_fraction": over_episodes(1.0 - tr.episode_collided),
        "success_fraction": over_episodes(tr.success),
    }


__all__ = ["POOL_BLOCK", "POOL_DEPTH", "episode_metrics", "make_rollout", "pool_block"]
