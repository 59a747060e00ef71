"""PPO (thesis §6.2.3, docs/design.md §2.3): one compiled graph from initialisation to the last
update.

``train = make_train(env, policy, config)``; ``train(key)`` is jittable end to end: initialise
the policy, the value network (:mod:`agents.ppo.networks`), Adam and ``num_envs`` environments,
then ``lax.scan`` over iterations, each

1. a rollout of ``rollout_length`` steps of the auto-resetting environments
   (:func:`agents.ppo.rollout.make_rollout`);
2. GAE and ``update_epochs × num_minibatches`` Adam steps on the clipped surrogate
   (:func:`agents.ppo.update.make_update`, :mod:`agents.ppo.losses`).

``jax.vmap(train)(keys)`` trains several seeds in one program. :func:`make_trainer` exposes the
pieces (``init``, ``rollout``, ``update``, ``run`` of a :class:`agents.ppo.state.TrainState`)
for chunked runs with checkpoints (:mod:`agents.run.checkpoint`), timing splits and
data-parallel sharding over a device mesh (:mod:`agents.ppo.sharding`).

Metrics per iteration (arrays of length ``total_iterations``; a leading seed axis under vmap):
``mean_reward`` (over all ``num_envs × rollout_length`` transitions), ``episodes`` (number of
episodes that finished in the rollout), ``mean_episode_return``, ``safe_fraction``
(``1 − collided``) and ``success_fraction`` (the environment's ``success`` metric on the
terminal step), averaged over the finished episodes (NaN when none finished), and the means
over all minibatch updates of ``loss``, ``policy_loss``, ``value_loss``, ``entropy``,
``approx_kl``, ``clip_fraction``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from brax.envs.base import Env
from jax.sharding import Mesh

from agents.ppo.config import PPOConfig
from agents.ppo.networks import GaussianPolicy, PPONetworks, ValueMLP
from agents.ppo.normalization import RunningStats, init_stats, update_stats
from agents.ppo.rollout import make_rollout
from agents.ppo.sharding import batch_axis_sharding, check_mesh
from agents.ppo.state import TrainState, Transition, raw_key, raw_keys
from agents.ppo.update import make_optimizer, make_update
from envs.wrappers import AutoResetWrapper, wrap


@dataclasses.dataclass(frozen=True)
class Trainer:
    """The pieces of one PPO program (see :func:`make_trainer`); every function is jittable.

    * ``init(key, scene=None) -> TrainState`` (``scene``: the environments' scene
      parameters, default the environment's own);
    * ``rollout(ts, key) -> (ts, Transition)``: ``rollout_length`` steps of every environment;
    * ``update(ts, transitions, key) -> (ts, metrics)``: GAE, the SGD epochs, statistics;
    * ``run(ts, num_iterations) -> (ts, metrics)``: ``num_iterations`` (static) iterations in a
      ``lax.scan``, metrics stacked along a leading axis;
    * ``train(key) -> (params, metrics)``: ``run(init(key), config.total_iterations)``.
    """

    config: PPOConfig
    policy: nn.Module
    value_net: nn.Module
    env: Env
    init: Callable[..., TrainState]
    rollout: Callable[[TrainState, jax.Array], tuple[TrainState, Transition]]
    update: Callable[[TrainState, Transition, jax.Array], tuple[TrainState, dict]]
    run: Callable[[TrainState, int], tuple[TrainState, dict]]

    def train(self, key: jax.Array) -> tuple[dict[str, Any], dict[str, jax.Array]]:
        """Initialise and run ``config.total_iterations`` iterations; ``(params, metrics)``."""
        ts, metrics = self.run(self.init(key), self.config.total_iterations)
        return ts.params, metrics

    def policy_norm(self, ts: TrainState) -> RunningStats | None:
        """The statistics the policy's networks read (None without observation normalisation)."""
        return ts.obs_stats if self.config.normalize_observations else None


def _check_arguments(policy: Any, config: Any, mesh: Any) -> PPOConfig:
    """``config`` (default :class:`PPOConfig`) after checking the argument types and ``mesh``."""
    if isinstance(policy, PPOConfig):
        raise TypeError("make_trainer(env, policy, config): pass the PPOConfig as config=")
    config = PPOConfig() if config is None else config
    if not isinstance(config, PPOConfig):
        raise TypeError(f"config must be a PPOConfig, got {type(config).__name__}")
    if policy is not None and not isinstance(policy, nn.Module):
        raise TypeError(f"policy must be a flax.linen Module, got {type(policy).__name__}")
    check_mesh(config, mesh)
    return config


def make_networks(config: PPOConfig, action_size: int,
                  policy: nn.Module | None = None) -> PPONetworks:
    """The policy (``policy``, default a :class:`agents.ppo.networks.GaussianPolicy` from
    ``config``) and the value MLP of ``config``."""
    if policy is None:
        policy = GaussianPolicy(action_size, hidden_sizes=config.policy_hidden_sizes,
                                activation=config.policy_activation,
                                out_scale=config.policy_out_scale,
                                log_std_init=config.log_std_init)
    value = ValueMLP(config.value_hidden_sizes, config.value_activation)
    return PPONetworks(policy, value, config.normalize_observations)


def _make_init(env: Env, nets: PPONetworks, tx: optax.GradientTransformation,
               config: PPOConfig, obs_size: int, constrain: Callable[..., Any]
               ) -> Callable[[jax.Array], TrainState]:
    """``init(key, scene=None) -> TrainState``: network parameters, optimiser state,
    ``num_envs`` reset environments (of ``scene``, the environment's scene parameters, for
    all of them, where given: :meth:`envs.reaching.ReachEnv.default_scene`) and the
    observation statistics (from the first observations when used)."""

    def init(key, scene=None):
        key = raw_key(key)
        k_pol, k_val, k_env = jax.random.split(key, 3)
        dummy = jnp.zeros((obs_size,), jnp.float32)
        params = {"policy": nets.policy.init(k_pol, dummy), "value": nets.value.init(k_val, dummy)}
        keys = raw_keys(k_env, config.num_envs)
        if scene is None:
            state = constrain(env.reset(keys))
        else:
            scene = jax.tree.map(lambda x: jnp.broadcast_to(x, (config.num_envs, *x.shape)),
                                 scene)
            state = constrain(env.reset(keys, scene))
        stats = init_stats(obs_size)
        if config.normalize_observations:
            stats = update_stats(stats, state.obs)
        zeros = constrain(jnp.zeros((config.num_envs,), jnp.float32))
        return TrainState(params, tx.init(params), state, zeros, zeros, stats,
                          jax.random.fold_in(key, 1), jnp.zeros((), jnp.int32))

    return init


def make_trainer(
    env: Env,
    policy: nn.Module | None = None,
    config: PPOConfig | None = None,
    mesh: Mesh | None = None,
    seed_axis: str | None = None,
    reset_pools: bool = False,
) -> Trainer:
    """The PPO program for a single (un-batched) brax environment; see :class:`Trainer`.

    ``env`` is wrapped with :func:`envs.wrappers.wrap` (vmap → episode limit ``config.
    episode_length`` → auto-reset with a new scene) unless it already is an
    :class:`envs.wrappers.AutoResetWrapper` around a batched env. ``policy`` is a flax module
    with ``__call__(obs, norm=None) -> (mean, log_std)`` (:mod:`agents.ppo.policies`); default
    :class:`agents.ppo.networks.GaussianPolicy` built from ``config`` (default :class:`PPOConfig`).
    ``params = {"policy": ..., "value": ...}``; metrics: see the module docstring.

    With ``config.normalize_observations`` the policy's networks and the value network read
    observations normalised by running statistics (initialised from the first observations,
    merged with each iteration's rollout after its update); RMP² always reads the raw
    observation.

    ``mesh`` (a :class:`jax.sharding.Mesh`) shards the environment batch, the rollout and every
    minibatch over the mesh's first axis and replicates the parameters (data parallelism: XLA
    all-reduces the gradients). ``num_envs`` and the minibatch size must be divisible by the
    mesh size. The same code runs on one CPU, several GPUs or several hosts and computes the
    same numbers up to summation order.

    ``seed_axis``: the ``axis_name`` of a ``jax.vmap`` over seeds that the caller puts around
    ``init``/``run``/``rollout`` (e.g. ``jax.vmap(trainer.run, axis_name=seed_axis)``); with it
    a rollout step computes the auto-reset only when some seed's episode ended, and with
    ``reset_pools`` the rollout restarts finished episodes from reset pools computed once per
    block of steps (:func:`agents.ppo.rollout.make_rollout`; same transitions). Leave it None
    when the trainer is not vmapped under that name.
    """
    config = _check_arguments(policy, config, mesh)
    batched = env if isinstance(env, AutoResetWrapper) else wrap(env, config.episode_length)
    nets = make_networks(config, int(env.action_size), policy)
    tx = make_optimizer(config)
    constrain = batch_axis_sharding(mesh, config.num_envs)
    init = _make_init(batched, nets, tx, config, int(env.observation_size), constrain)
    rollout = make_rollout(batched, nets, config.rollout_length, constrain, seed_axis,
                           reset_pools)
    update = make_update(nets, tx, config, mesh)

    def iteration(ts, _):
        k_roll, k_upd = jax.random.split(jax.random.fold_in(ts.key, ts.iteration))
        ts, tr = rollout(ts, k_roll)
        return update(ts, tr, k_upd)

    def run(ts, num_iterations):
        return jax.lax.scan(iteration, ts, None, length=num_iterations)

    return Trainer(config, nets.policy, nets.value, batched, init, rollout, update, run)


def make_train(
    env: Env,
    policy: nn.Module | None = None,
    config: PPOConfig | None = None,
    mesh: Mesh | None = None,
) -> Callable[[jax.Array], tuple[dict[str, Any], dict[str, jax.Array]]]:
    """``train(key) -> (params, metrics)``: :meth:`Trainer.train` of :func:`make_trainer`.

    Jittable end to end; ``jax.vmap(train)(keys)`` trains several seeds in one program. ``key``
    may be a typed key or a raw ``uint32 (2,)`` key.
    """
    return make_trainer(env, policy, config, mesh).train


__all__ = ["Trainer", "make_networks", "make_train", "make_trainer"]
