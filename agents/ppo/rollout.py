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

from agents.ppo.losses import gaussian_log_prob
from agents.ppo.networks import PPONetworks
from agents.ppo.state import TrainState, Transition


def make_rollout(env: Env, nets: PPONetworks, num_steps: int, constrain: Callable[..., Any]
                 ) -> Callable[[TrainState, jax.Array], tuple[TrainState, Transition]]:
    """``rollout(ts, key) -> (ts, transitions)``: ``num_steps`` steps of the batched,
    auto-resetting ``env`` with actions sampled from the policy; ``transitions`` is time-major
    ``(num_steps, num_envs, ...)``. ``constrain`` places the environment batch on the mesh
    (:func:`agents.ppo.sharding.batch_axis_sharding`)."""

    def env_step(carry, key):
        params, stats, state, ep_ret, ep_col = carry
        obs = state.obs
        mean, log_std = nets.policy_apply(params["policy"], obs, stats)
        action = mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape, mean.dtype)
        value = nets.value_apply(params["value"], obs, stats)
        state = constrain(env.step(state, action))
        reward = state.reward.astype(jnp.float32)
        done = state.done.astype(jnp.float32)
        collision = state.metrics.get("collision", jnp.zeros_like(reward))
        success = state.metrics.get("success", jnp.zeros_like(reward)).astype(jnp.float32)
        ep_ret = ep_ret + reward
        ep_col = jnp.maximum(ep_col, collision.astype(jnp.float32))
        tr = Transition(obs, action, gaussian_log_prob(action, mean, log_std), value, reward,
                        done, state.info["truncation"].astype(jnp.float32), ep_ret, ep_col,
                        success)
        ep_ret = jnp.where(done > 0, 0.0, ep_ret)
        ep_col = jnp.where(done > 0, 0.0, ep_col)
        return (params, stats, state, ep_ret, ep_col), tr

    def rollout(ts, key):
        carry = (ts.params, ts.obs_stats, ts.env_state, ts.episode_return, ts.episode_collided)
        (_, _, state, ep_ret, ep_col), tr = jax.lax.scan(
            env_step, carry, jax.random.split(key, num_steps))
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


__all__ = ["episode_metrics", "make_rollout"]
