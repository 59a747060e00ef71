"""PPO (thesis §6.2.3, docs/design.md §2.3): GAE, clipped surrogate, value MLP, Adam, one compiled graph.

``train = make_train(env, policy, config)``; ``train(key)`` is jittable end to end —
initialisation, a ``lax.scan`` over iterations, inside each a ``lax.scan`` rollout of
``rollout_length`` steps of ``num_envs`` auto-resetting environments, GAE, and
``update_epochs × num_minibatches`` Adam steps (``lax.scan``) — and ``jax.vmap(train)(keys)``
trains several seeds in one program. :func:`make_trainer` exposes the pieces (``init``,
``rollout``, ``update``, ``run`` of a :class:`TrainState`) for chunked runs with checkpoints
(:mod:`agents.run.checkpoint`), timing splits and data-parallel sharding over a device mesh.

Truncation (time limits) in :func:`gae`
---------------------------------------
``dones`` marks the last transition of an episode, ``truncations`` the subset that ended by the
time limit (brax's ``EpisodeWrapper`` sets both). A *terminated* transition bootstraps with 0.
A *truncated* transition must bootstrap from the value of its terminal observation; the
auto-reset wrapper (:func:`envs.wrappers.wrap`) replaces that observation by the first one of the
next episode, so:

* if ``terminal_values`` is given, a truncated step uses ``r + γ·terminal_values[t]``;
* otherwise (what :func:`make_train` does) it uses ``r + γ·values[t]``: the value of the last
  observation seen before the time limit stands in for the value of the terminal one (one
  control step apart). The bootstrap is *not* zeroed — a time limit is not a failure.

In both cases the GAE recursion is cut at every episode end (``dones``), so nothing leaks from
the next episode into this one.

Metrics per iteration (arrays of length ``total_iterations``; a leading seed axis under vmap):
``mean_reward`` (over all ``num_envs × rollout_length`` transitions), ``episodes`` (number of
episodes that finished in the rollout), ``mean_episode_return``, ``safe_fraction``
(``1 − collided``) and ``success_fraction`` (the environment's ``success`` metric on the
terminal step), averaged over the finished episodes (NaN when none finished), and the means
over all minibatch updates of ``loss``, ``policy_loss``, ``value_loss``, ``entropy``,
``approx_kl``, ``clip_fraction``. Episode returns and collision flags are accumulated by the
trainer itself (sum of rewards; max of ``state.metrics["collision"]`` when the environment has
that metric, else 0) because the auto-reset wrapper clears the environment's own accumulators on
the terminal step.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from brax.envs.base import Env
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from agents.ppo.networks import ACTIVATIONS, GaussianPolicy, ValueMLP
from agents.ppo.normalization import RunningStats, init_stats, normalize, update_stats
from envs.wrappers import AutoResetWrapper, wrap

_LOG_2PI = math.log(2.0 * math.pi)


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters (hashable; validated on construction).

    Batch per iteration = ``num_envs × rollout_length``; it must split into ``num_minibatches``
    equal minibatches. Each epoch shuffles the batch within ``shuffle_blocks`` equal blocks of
    environments and gives every minibatch the same number of samples from each block
    (``None``: one block per device of the mesh, so that shuffling never moves data between
    devices; one block without a mesh — a plain shuffle). ``max_grad_norm=None`` disables
    global-norm clipping. ``episode_length`` (``None``: the environment's ``horizon``) is used
    when :func:`make_train` wraps the env.
    """

    num_envs: int = 16
    rollout_length: int = 32
    num_minibatches: int = 4
    update_epochs: int = 4
    learning_rate: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    vf_coef: float = 0.5
    ent_coef: float = 0.0
    max_grad_norm: float | None = 0.5
    total_iterations: int = 10
    normalize_advantages: bool = True
    adam_eps: float = 1e-5
    policy_hidden_sizes: tuple[int, ...] = (256, 128)
    policy_activation: str = "relu"
    policy_out_scale: float = 0.1
    log_std_init: float = -1.0
    value_hidden_sizes: tuple[int, ...] = (256, 128)
    value_activation: str = "tanh"
    episode_length: int | None = None
    normalize_observations: bool = False
    shuffle_blocks: int | None = None

    def __post_init__(self):
        def bad(name, why):
            raise ValueError(f"PPOConfig.{name}={getattr(self, name)!r}: {why}")

        for name in ("num_envs", "rollout_length", "num_minibatches", "update_epochs",
                     "total_iterations"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                bad(name, "must be a positive integer")
        for name in ("learning_rate", "clip_eps", "adam_eps", "policy_out_scale"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                bad(name, "must be a finite number > 0")
        for name in ("gamma", "gae_lambda"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and 0.0 <= v <= 1.0):
                bad(name, "must lie in [0, 1]")
        for name in ("vf_coef", "ent_coef"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                bad(name, "must be a finite number >= 0")
        if not (isinstance(self.log_std_init, int | float) and math.isfinite(self.log_std_init)):
            bad("log_std_init", "must be finite")
        if self.max_grad_norm is not None and not (
            isinstance(self.max_grad_norm, int | float) and self.max_grad_norm > 0
        ):
            bad("max_grad_norm", "must be None or a number > 0")
        if self.episode_length is not None and not (
            isinstance(self.episode_length, int) and self.episode_length >= 1
        ):
            bad("episode_length", "must be None or a positive integer")
        for name in ("policy_hidden_sizes", "value_hidden_sizes"):
            v = getattr(self, name)
            if not (isinstance(v, tuple) and all(isinstance(h, int) and h >= 1 for h in v)):
                bad(name, "must be a tuple of positive integers")
        for name in ("policy_activation", "value_activation"):
            if getattr(self, name) not in ACTIVATIONS:
                bad(name, f"unknown activation; valid names are {sorted(ACTIVATIONS)}")
        if self.batch_size % self.num_minibatches:
            bad("num_minibatches",
                f"must divide the batch num_envs*rollout_length={self.batch_size}")
        if self.shuffle_blocks is not None:
            b = self.shuffle_blocks
            if not (isinstance(b, int) and not isinstance(b, bool) and b >= 1
                    and self.num_envs % b == 0 and self.minibatch_size % b == 0):
                bad("shuffle_blocks", f"must be None or a positive integer dividing num_envs="
                                      f"{self.num_envs} and the minibatch size "
                                      f"{self.minibatch_size}")

    @property
    def batch_size(self) -> int:
        """Transitions per iteration, ``num_envs × rollout_length``."""
        return self.num_envs * self.rollout_length

    @property
    def minibatch_size(self) -> int:
        return self.batch_size // self.num_minibatches

    @classmethod
    def thesis(cls, **overrides) -> PPOConfig:
        """The thesis' RLlib settings (docs/design.md §4.4), adapted to fixed-shape batches.

        lr 5e-5, clip 0.2, GAE λ 0.99, γ 0.99, 500 iterations, Gaussian policy with log-std
        initialised at −1, policy MLP (256, 128) relu with output scale 0.1 (``NN`` on the
        planar arm; pass ``policy_hidden_sizes=(512, 256)`` for Franka), value MLP (256, 128)
        tanh. RLlib's 67,312 steps per iteration with minibatches of 4,096 does not split into
        equal minibatches; here 128 environments × 512 steps = 65,536 steps (−2.6 %) in 16
        minibatches of exactly 4,096. ``update_epochs=30``, ``vf_coef=1``, ``ent_coef=0`` and
        no gradient clipping are RLlib's PPO defaults (``num_sgd_iter``, ``vf_loss_coeff``,
        ``entropy_coeff``, ``grad_clip``), assumed because the thesis does not state them;
        RLlib's adaptive KL penalty and value clipping are not implemented.
        """
        base = dict(
            num_envs=128,
            rollout_length=512,
            num_minibatches=16,
            update_epochs=30,
            learning_rate=5e-5,
            gamma=0.99,
            gae_lambda=0.99,
            clip_eps=0.2,
            vf_coef=1.0,
            ent_coef=0.0,
            max_grad_norm=None,
            total_iterations=500,
            normalize_advantages=True,
            policy_hidden_sizes=(256, 128),
            policy_activation="relu",
            policy_out_scale=0.1,
            log_std_init=-1.0,
            value_hidden_sizes=(256, 128),
            value_activation="tanh",
        )
        base.update(overrides)
        return cls(**base)


# ---------------------------------------------------------------------------------------------
# numerics


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


# ---------------------------------------------------------------------------------------------
# training


class Transition(NamedTuple):
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


class TrainState(NamedTuple):
    """Everything a run needs to continue exactly: what a checkpoint holds.

    ``key`` is the run's raw ``uint32 (2,)`` key; iteration ``i`` uses ``fold_in(key, i)``, so a
    run split into chunks (or resumed from a checkpoint) draws the same random numbers as an
    uninterrupted one. ``iteration`` counts the iterations done.
    """

    params: dict[str, Any]
    opt_state: Any
    env_state: Any
    episode_return: jax.Array
    episode_collided: jax.Array
    obs_stats: RunningStats
    key: jax.Array
    iteration: jax.Array


def _raw_key(key: jax.Array) -> jax.Array:
    """A raw ``uint32 (2,)`` key from a typed or a raw ``key``."""
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        return jax.random.key_data(key)
    return key


def _raw_keys(key: jax.Array, n: int) -> jax.Array:
    """``n`` raw ``uint32 (n, 2)`` keys, for a typed or a raw ``key``."""
    return _raw_key(jax.random.split(key, n))


def batch_axis_sharding(mesh: Mesh | None, num_envs: int):
    """``constrain(tree, axis)``: shard every leaf whose dimension ``axis`` is the environment
    batch (size ``num_envs``) over the mesh's first axis, replicate the others (identity when
    ``mesh`` is None)."""
    if mesh is None:
        return lambda tree, axis=0: tree
    name = mesh.axis_names[0]

    def constrain(tree, axis=0):
        def one(x):
            if x.ndim > axis and x.shape[axis] == num_envs:
                spec = PartitionSpec(*([None] * axis), name)
            else:
                spec = PartitionSpec()
            return jax.lax.with_sharding_constraint(x, NamedSharding(mesh, spec))

        return jax.tree.map(one, tree)

    return constrain


@dataclasses.dataclass(frozen=True)
class Trainer:
    """The pieces of one PPO program (see :func:`make_trainer`); every function is jittable.

    * ``init(key) -> TrainState``;
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
    init: Callable[[jax.Array], TrainState]
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


def make_trainer(
    env: Env,
    policy: nn.Module | None = None,
    config: PPOConfig | None = None,
    mesh: Mesh | None = None,
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
    merged with each iteration's rollout after its update, so an iteration's rollout and update
    see the same statistics); RMP² always reads the raw observation.

    ``mesh`` (a :class:`jax.sharding.Mesh`) shards the environment batch, the rollout and every
    minibatch over the mesh's first axis and replicates the parameters (data parallelism: XLA
    all-reduces the gradients). ``num_envs`` and the minibatch size must be divisible by the
    mesh size. The same code runs on one CPU, several GPUs or several hosts (after
    ``jax.distributed.initialize``) and computes the same numbers up to summation order.
    """
    if isinstance(policy, PPOConfig):
        raise TypeError("make_trainer(env, policy, config): pass the PPOConfig as config=")
    config = PPOConfig() if config is None else config
    if not isinstance(config, PPOConfig):
        raise TypeError(f"config must be a PPOConfig, got {type(config).__name__}")
    if policy is not None and not isinstance(policy, nn.Module):
        raise TypeError(f"policy must be a flax.linen Module, got {type(policy).__name__}")
    if mesh is not None:
        if not isinstance(mesh, Mesh):
            raise TypeError(f"mesh must be a jax.sharding.Mesh or None, got {type(mesh)}")
        for name, n in (("num_envs", config.num_envs), ("minibatch_size", config.minibatch_size)):
            if n % mesh.size:
                raise ValueError(f"PPOConfig {name}={n} must be divisible by the mesh size "
                                 f"{mesh.size} to shard the environment batch")
        if config.shuffle_blocks is not None and config.shuffle_blocks % mesh.size:
            raise ValueError(f"PPOConfig shuffle_blocks={config.shuffle_blocks} must be a "
                             f"multiple of the mesh size {mesh.size}")
    obs_size = int(env.observation_size)
    action_size = int(env.action_size)
    batched = env if isinstance(env, AutoResetWrapper) else wrap(env, config.episode_length)
    if policy is None:
        policy = GaussianPolicy(
            action_size,
            hidden_sizes=config.policy_hidden_sizes,
            activation=config.policy_activation,
            out_scale=config.policy_out_scale,
            log_std_init=config.log_std_init,
        )
    value_net = ValueMLP(config.value_hidden_sizes, config.value_activation)
    tx = optax.adam(config.learning_rate, eps=config.adam_eps)
    if config.max_grad_norm is not None:
        tx = optax.chain(optax.clip_by_global_norm(config.max_grad_norm), tx)
    n_envs, n_mb, mb_size = config.num_envs, config.num_minibatches, config.minibatch_size
    blocks = config.shuffle_blocks or (1 if mesh is None else mesh.size)
    block_len = config.batch_size // blocks
    constrain_blocks = batch_axis_sharding(mesh, blocks)
    constrain = batch_axis_sharding(mesh, n_envs)
    constrain_mb = batch_axis_sharding(mesh, mb_size)
    use_norm = config.normalize_observations

    def norm_of(stats):
        return stats if use_norm else None

    def policy_apply(p, obs, stats):
        return policy.apply(p, obs, norm_of(stats))

    def value_apply(p, obs, stats):
        return value_net.apply(p, normalize(norm_of(stats), obs))

    def loss(p, b, stats):
        return ppo_loss(p, b, lambda pp, o: policy_apply(pp, o, stats),
                        lambda pp, o: value_apply(pp, o, stats), config.clip_eps,
                        config.vf_coef, config.ent_coef, config.normalize_advantages)

    loss_grad = jax.value_and_grad(loss, has_aux=True)

    def init(key):
        key = _raw_key(key)
        k_pol, k_val, k_env = jax.random.split(key, 3)
        dummy = jnp.zeros((obs_size,), jnp.float32)
        params = {"policy": policy.init(k_pol, dummy), "value": value_net.init(k_val, dummy)}
        state = constrain(batched.reset(_raw_keys(k_env, n_envs)))
        stats = init_stats(obs_size)
        if use_norm:
            stats = update_stats(stats, state.obs)
        zeros = constrain(jnp.zeros((n_envs,), jnp.float32))
        return TrainState(params, tx.init(params), state, zeros, zeros, stats,
                          jax.random.fold_in(key, 1), jnp.zeros((), jnp.int32))

    def env_step(carry, key):
        params, stats, state, ep_ret, ep_col = carry
        obs = state.obs
        mean, log_std = policy_apply(params["policy"], obs, stats)
        noise = jax.random.normal(key, mean.shape, mean.dtype)
        action = mean + jnp.exp(log_std) * noise
        log_prob = gaussian_log_prob(action, mean, log_std)
        value = value_apply(params["value"], obs, stats)
        state = constrain(batched.step(state, action))
        reward = state.reward.astype(jnp.float32)
        done = state.done.astype(jnp.float32)
        trunc = state.info["truncation"].astype(jnp.float32)
        collision = state.metrics.get("collision", jnp.zeros_like(reward))
        success = state.metrics.get("success", jnp.zeros_like(reward)).astype(jnp.float32)
        ep_ret = ep_ret + reward
        ep_col = jnp.maximum(ep_col, collision.astype(jnp.float32))
        tr = Transition(obs, action, log_prob, value, reward, done, trunc, ep_ret, ep_col,
                        success)
        ep_ret = jnp.where(done > 0, 0.0, ep_ret)
        ep_col = jnp.where(done > 0, 0.0, ep_col)
        return (params, stats, state, ep_ret, ep_col), tr

    def rollout(ts, key):
        carry = (ts.params, ts.obs_stats, ts.env_state, ts.episode_return, ts.episode_collided)
        (_, _, state, ep_ret, ep_col), tr = jax.lax.scan(
            env_step, carry, jax.random.split(key, config.rollout_length))
        ts = ts._replace(env_state=state, episode_return=ep_ret, episode_collided=ep_col)
        return ts, constrain(tr, 1)

    def update_minibatch(carry, mb):
        params, opt_state, stats = carry
        (_, metrics), grads = loss_grad(params, constrain_mb(mb), stats)
        updates, opt_state = tx.update(grads, opt_state, params)
        params = optax.apply_updates(params, updates)
        return (params, opt_state, stats), metrics

    def minibatches(x, perm):
        # x: (blocks, block_len, ...) -> (n_mb, mb_size, ...), block-major inside a minibatch
        x = jax.vmap(lambda xb, pb: xb[pb])(x, perm)
        x = x.reshape((blocks, n_mb, mb_size // blocks, *x.shape[2:]))
        return jnp.swapaxes(x, 0, 1).reshape((n_mb, mb_size, *x.shape[3:]))

    def update_epoch(carry, key):
        params, opt_state, stats, flat = carry
        perm = jax.vmap(lambda k: jax.random.permutation(k, block_len))(
            jax.random.split(key, blocks))
        mbs = constrain_mb(jax.tree.map(lambda x: minibatches(x, perm), flat), 1)
        (params, opt_state, _), metrics = jax.lax.scan(
            update_minibatch, (params, opt_state, stats), mbs)
        return (params, opt_state, stats, flat), metrics

    def update(ts, tr, key):
        stats = ts.obs_stats
        last_value = value_apply(ts.params["value"], ts.env_state.obs, stats)
        adv, ret = gae(tr.rewards, tr.values, tr.dones, tr.truncations, last_value,
                       config.gamma, config.gae_lambda)
        flat = {"obs": tr.obs, "actions": tr.actions, "log_probs": tr.log_probs,
                "advantages": adv, "returns": ret}
        # (T, N, ...) -> (blocks, N/blocks·T, ...): environment-major, so that each block
        # holds whole environments and stays on the device that stepped them
        flat = constrain_blocks(jax.tree.map(
            lambda x: jnp.swapaxes(x, 0, 1).reshape((blocks, block_len, *x.shape[2:])), flat))
        (params, opt_state, _, _), upd = jax.lax.scan(
            update_epoch, (ts.params, ts.opt_state, stats, flat),
            jax.random.split(key, config.update_epochs),
        )
        if use_norm:
            stats = update_stats(stats, tr.obs)
        n_done = jnp.sum(tr.dones)
        denom = jnp.maximum(n_done, 1.0)
        nan = jnp.asarray(jnp.nan, jnp.float32)
        metrics = {k: jnp.mean(v) for k, v in upd.items()}
        metrics.update(
            mean_reward=jnp.mean(tr.rewards),
            episodes=n_done,
            mean_episode_return=jnp.where(
                n_done > 0, jnp.sum(tr.dones * tr.episode_return) / denom, nan),
            safe_fraction=jnp.where(
                n_done > 0, jnp.sum(tr.dones * (1.0 - tr.episode_collided)) / denom, nan),
            success_fraction=jnp.where(
                n_done > 0, jnp.sum(tr.dones * tr.success) / denom, nan),
        )
        ts = ts._replace(params=params, opt_state=opt_state, obs_stats=stats,
                         iteration=ts.iteration + 1)
        return ts, metrics

    def iteration(ts, _):
        k_roll, k_upd = jax.random.split(jax.random.fold_in(ts.key, ts.iteration))
        ts, tr = rollout(ts, k_roll)
        return update(ts, tr, k_upd)

    def run(ts, num_iterations):
        return jax.lax.scan(iteration, ts, None, length=num_iterations)

    return Trainer(config, policy, value_net, batched, init, rollout, update, run)


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


__all__ = [
    "PPOConfig",
    "TrainState",
    "Trainer",
    "Transition",
    "batch_axis_sharding",
    "gae",
    "gaussian_entropy",
    "gaussian_log_prob",
    "make_train",
    "make_trainer",
    "ppo_loss",
]
