"""rejax's PPO on our reaching environments (a peer of :mod:`agents.bench.peers`).

:class:`GymnaxReach` gives a reaching environment the gymnax ``Environment`` interface that
rejax trains on: ``reset(key, params) -> (obs, state)``, ``step(key, state, action, params) ->
(obs, state, reward, done, info)`` with gymnax's auto-reset (a finished episode restarts from
``reset`` with the step's fresh key, so every episode samples a new scene, as in our trainer),
``observation_space``/``action_space`` boxes and ``default_params``. It is written against
that interface rather than subclassing ``gymnax.environments.environment.Environment``, so this
module imports without the optional ``peers`` extra; ``done`` is the environment's own
termination (collision, non-finite state) or the episode limit (``horizon``, 600 control steps).

:func:`train_rejax` builds rejax's ``PPO`` at the settings of a :class:`agents.ppo.PPOConfig`
and times chunks of ``train_iteration`` (rejax's own iteration: rollout, GAE, epochs of
minibatches) in one ``lax.scan``; rejax's periodic evaluation is left out of the timing.
rejax and gymnax come from the ``peers`` extra (``pip install -e .[peers]``).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import State
from flax import struct

import envs
from agents.bench.peer_common import PeerRun, timed_chunks
from agents.ppo import PPOConfig
from agents.ppo.networks import activation_fn


@dataclasses.dataclass(frozen=True)
class Box:
    """A gymnax ``Box`` space: bounds and shape."""

    low: float
    high: float
    shape: tuple[int, ...]
    dtype: Any = jnp.float32


@struct.dataclass
class ReachParams:
    """gymnax environment parameters: the episode limit."""

    max_steps_in_episode: int


@struct.dataclass
class ReachState:
    """gymnax environment state: the brax state and the control steps taken in the episode."""

    env_state: State
    time: jax.Array


class GymnaxReach:
    """A reaching environment (``envs.make(env_name)``) behind gymnax's interface (module
    docstring)."""

    def __init__(self, env_name: str):
        self.env = envs.make(env_name)
        self.horizon = int(self.env.horizon)

    @property
    def default_params(self) -> ReachParams:
        """The episode limit of the environment (its ``horizon``)."""
        return ReachParams(self.horizon)

    def observation_space(self, params: ReachParams) -> Box:
        """Unbounded observations of the environment's size."""
        return Box(-np.inf, np.inf, (int(self.env.observation_size),))

    def action_space(self, params: ReachParams) -> Box:
        """Joint accelerations within ``±action_limit``."""
        limit = float(self.env.action_limit)
        return Box(-limit, limit, (int(self.env.action_size),))

    def reset(self, key: jax.Array, params: ReachParams | None = None
              ) -> tuple[jax.Array, ReachState]:
        """A new episode from ``key``."""
        state = self.env.reset(key)
        return state.obs, ReachState(state, jnp.zeros((), jnp.int32))

    def step(self, key: jax.Array, state: ReachState, action: jax.Array,
             params: ReachParams | None = None
             ) -> tuple[jax.Array, ReachState, jax.Array, jax.Array, dict]:
        """One control step; a finished episode restarts from ``reset(key)`` (gymnax's
        auto-reset)."""
        params = self.default_params if params is None else params
        nxt = self.env.step(state.env_state, action)
        t = state.time + 1
        done = (nxt.done > 0) | (t >= params.max_steps_in_episode)
        obs_re, state_re = self.reset(key, params)
        new = jax.tree.map(lambda a, b: jnp.where(done, a, b), state_re, ReachState(nxt, t))
        return jnp.where(done, obs_re, nxt.obs), new, nxt.reward, done, {}


def make_ppo(env_name: str, config: PPOConfig, policy_hidden: tuple[int, ...],
             policy_activation: str) -> Any:
    """rejax's ``PPO`` on :class:`GymnaxReach` at ``config``'s settings: environments,
    unroll, minibatches, epochs, learning rate, γ, λ, clip ε, value and entropy coefficients,
    gradient clipping (``None``: none), observation normalisation, the value MLP of ``config``
    and the policy MLP ``policy_hidden`` with ``policy_activation``."""
    from rejax import PPO  # lazy: optional extra (pip install -e .[peers])
    from rejax.networks import GaussianPolicy, VNetwork  # lazy: optional extra

    env = GymnaxReach(env_name)
    algo = PPO.create(
        env=env, env_params=env.default_params, num_envs=config.num_envs,
        num_steps=config.rollout_length, num_minibatches=config.num_minibatches,
        num_epochs=config.update_epochs, learning_rate=config.learning_rate, gamma=config.gamma,
        gae_lambda=config.gae_lambda, clip_eps=config.clip_eps, vf_coef=config.vf_coef,
        ent_coef=config.ent_coef, normalize_observations=config.normalize_observations,
        max_grad_norm=np.inf if config.max_grad_norm is None else config.max_grad_norm,
        skip_initial_evaluation=True)
    space = env.action_space(env.default_params)
    actor = GaussianPolicy(space.shape[0], (space.low, space.high), policy_hidden,
                           activation_fn(policy_activation))
    critic = VNetwork(config.value_hidden_sizes, activation_fn(config.value_activation))
    return algo.replace(actor=actor, critic=critic)


def deterministic_act(algo: Any, ts: Any) -> Any:
    """``act(obs) -> action``: the mean of rejax's Gaussian policy in ``ts``, clipped to the
    action space (observations normalised as in training where rejax normalises them)."""
    params, space = ts.actor_ts.params, algo.action_space

    def act(obs):
        if algo.normalize_observations:
            obs = algo.normalize_obs(ts.obs_rms_state, obs)
        mean = algo.actor.apply(params, obs[None], method=lambda m, o: m.action_mean(m.features(o)))
        return jnp.clip(mean[0], space.low, space.high)

    return act


def train_rejax(env_name: str, config: PPOConfig, iterations: int, chunk: int, seed: int,
                policy_hidden: tuple[int, ...], policy_activation: str,
                log_std_init: float) -> PeerRun:
    """Train rejax's PPO (:func:`make_ppo`) for ``iterations`` iterations in chunks of
    ``chunk``, timed (:func:`agents.bench.peer_common.timed_chunks`); the policy's log standard
    deviation starts at ``log_std_init`` as ours does (rejax's default is 0)."""
    t0 = time.perf_counter()
    algo = make_ppo(env_name, config, policy_hidden, policy_activation)
    ts = algo.init_state(jax.random.PRNGKey(seed))
    params = ts.actor_ts.params
    log_std = params["params"]["action_log_std"]
    params = {**params, "params": {**params["params"],
                                   "action_log_std": jnp.full_like(log_std, log_std_init)}}
    # Strong types throughout (rejax starts e.g. ``global_step`` as a Python int), so that the
    # chunk compiles once rather than again on its second call.
    ts = jax.tree.map(lambda x: jnp.asarray(x).astype(jnp.asarray(x).dtype),
                      ts.replace(actor_ts=ts.actor_ts.replace(params=params)))

    @jax.jit
    def run_chunk(ts):
        return jax.lax.scan(lambda s, _: (algo.train_iteration(s), None), ts, None,
                            length=chunk)[0]

    ts, times = timed_chunks(run_chunk, ts, iterations // chunk)
    steps = iterations * config.batch_size
    return PeerRun(deterministic_act(algo, ts), times, time.perf_counter() - t0, steps)


__all__ = ["Box", "GymnaxReach", "ReachParams", "ReachState", "deterministic_act", "make_ppo",
           "train_rejax"]
