"""Conservative Q-learning, CQL(H) on soft actor-critic (Kumar, Zhou, Tucker and Levine,
"Conservative Q-Learning for Offline Reinforcement Learning", NeurIPS 2020, arXiv:2006.04779),
one of the offline RL algorithms of thesis §8.4 (Figs 8.4 and 8.7).

Per gradient step, on one minibatch ``(s, a, r, s', d)`` (actions divided by the action limit):

* **critics** ``Q_i`` (twin, with Polyak targets ``Q̄_i``): the TD loss
  ``E[(Q_i(s, a) − y)²]``, ``y = r + γ(1 − d)·min_j Q̄_j(s', a')``, ``a' ∼ π(·|s')`` (no entropy
  term in the backup unless ``backup_entropy``), plus the CQL(H) penalty (CQL eq. 4) times
  ``min_q_weight`` α:

      α·( T·E_s log Σ_k exp((Q_i(s, a_k) − log μ(a_k)) / T) − E_{(s,a)∼D} Q_i(s, a) ),

  the log-sum-exp estimated by importance sampling as in the authors' code: ``num_samples``
  actions from each of the uniform distribution on ``[−1, 1]^A`` (``log μ = −A log 2``), the
  current policy at ``s`` and the current policy at ``s'`` (each with its log-density), all
  scored by ``Q_i`` at ``s`` (:func:`conservative_penalty`). As in the authors' code the
  ``log(3·num_samples)`` normaliser of the estimate is left out (a constant);
* **actor** (SAC): ``E[α_ent·log π(a_π|s) − min_i Q_i(s, a_π)]``, ``a_π ∼ π(·|s)`` reparameterised;
* **entropy temperature** ``α_ent = exp(log α)`` tuned automatically towards the target
  entropy ``−dim(A)``: loss ``−E[log α·(log π(a_π|s) + target_entropy)]``;
* **targets** ``Q̄ ← (1 − τ)Q̄ + τQ``.

All losses are evaluated with the parameters before the step, then every network takes one Adam
step. Defaults: the CQL(H) MuJoCo settings of the authors' code (``min_q_weight`` 5, 10 sampled
actions, temperature 1, critic lr 3e-4, policy lr 1e-4 — also used for ``log α`` — γ 0.99, τ 5e-3,
batch 256, no Lagrange variant) with 3×256 ReLU networks (docs/design.md §4.5 sizes) and the
tanh-Gaussian actor of the offline learners.

``beta`` of the learner API is the conservative weight α (``CQLConfig.min_q_weight`` when None),
a traced scalar in the state so ``jax.vmap`` over it works. CQL reads the dynamics data's rewards
and takes no reward data.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from mjxrmp.config import check_bool, check_finite, check_float, check_fraction, check_int
from offline.data import dataset as odata
from offline.data.scenarios import RewardData
from offline.learners.base import (
    Trainer,
    adam_step,
    check_network,
    normalized_dataset,
    policy_act,
    scan_steps,
)
from offline.learners.networks import QEnsemble, polyak
from offline.learners.residual_actor import (
    NO_BASES,
    ActorBases,
    apply_actor,
    check_actor,
    dataset_bases,
    make_actor,
)


@dataclasses.dataclass(frozen=True)
class CQLConfig:
    """CQL(H) hyper-parameters (module docstring); ``target_entropy`` None means ``−dim(A)``;
    ``normalize_observations`` standardises every network's states with the dataset's
    statistics (:class:`offline.learners.base.ObservationNormalizer`; default off); ``actor`` is the
    actor class (:data:`offline.learners.residual_actor.ACTORS`; default ``"mlp"``)."""

    hidden_sizes: tuple[int, ...] = (256, 256, 256)
    activation: str = "relu"
    actor_lr: float = 1e-4
    critic_lr: float = 3e-4
    alpha_lr: float = 1e-4
    batch_size: int = 256
    num_steps: int = 1_000_000
    discount: float = 0.99
    tau: float = 5e-3
    min_q_weight: float = 5.0
    num_samples: int = 10
    temperature: float = 1.0
    target_entropy: float | None = None
    backup_entropy: bool = False
    num_critics: int = 2
    normalize_observations: bool = False
    actor: str = "mlp"

    def __post_init__(self) -> None:
        n = type(self).__name__
        object.__setattr__(self, "hidden_sizes", check_network(self.hidden_sizes,
                                                               self.activation, f"{n}."))
        for name in ("actor_lr", "critic_lr", "alpha_lr", "min_q_weight", "temperature"):
            check_float(getattr(self, name), f"{n}.{name}")
        for name in ("batch_size", "num_steps", "num_samples", "num_critics"):
            check_int(getattr(self, name), f"{n}.{name}")
        check_fraction(self.discount, f"{n}.discount")
        check_bool(self.normalize_observations, f"{n}.normalize_observations")
        check_actor(self.actor, self.normalize_observations)
        check_fraction(self.tau, f"{n}.tau", closed=True)
        check_finite(self.target_entropy, f"{n}.target_entropy", allow_none=True)
        check_bool(self.backup_entropy, f"{n}.backup_entropy")


class CQLState(NamedTuple):
    params: dict  # {"actor", "critic", "log_alpha"}
    target: dict  # {"critic"}
    opt_state: dict  # per network
    key: jax.Array
    step: jax.Array
    beta: jax.Array  # conservative weight α (min_q_weight)


def penalty_actions(policy: nn.Module, actor_params: Any, obs: jax.Array,
                    next_obs: jax.Array, key: jax.Array, num_samples: int,
                    base: ActorBases = NO_BASES) -> tuple[jax.Array, jax.Array]:
    """The importance samples of the CQL(H) log-sum-exp: ``(actions (3K, B, A), log_density
    (3K, B))`` — ``K`` uniform actions on ``[−1, 1]^A``, ``K`` from ``π(·|s)`` and ``K`` from
    ``π(·|s')``, with their log-densities; no gradient flows through them. ``base``: the
    residual actor's precomputed RMP² base at ``obs`` / ``next_obs`` (default: evaluated here)."""
    k_unif, k_cur, k_next = jax.random.split(key, 3)
    batch = obs.shape[0]
    action_size = policy.action_size
    uniform = jax.random.uniform(k_unif, (num_samples, batch, action_size), obs.dtype, -1.0, 1.0)
    log_uniform = jnp.full((num_samples, batch), -action_size * math.log(2.0), obs.dtype)
    a_cur, logp_cur = apply_actor(policy, actor_params, obs, base.observations).sample(
        k_cur, (num_samples,))
    a_next, logp_next = apply_actor(policy, actor_params, next_obs, base.next_observations
                                    ).sample(k_next, (num_samples,))
    actions = jnp.concatenate([uniform, a_cur, a_next])
    log_density = jnp.concatenate([log_uniform, logp_cur, logp_next])
    return jax.lax.stop_gradient(actions), jax.lax.stop_gradient(log_density)


def sampled_q(critic: QEnsemble, critic_params: Any, obs: jax.Array,
              actions: jax.Array) -> jax.Array:
    """``Q_i(s_b, a_kb)`` for sampled actions ``(K, B, A)`` at states ``(B, O)``: ``(K, B, C)``."""
    obs_k = jnp.broadcast_to(obs, (*actions.shape[:2], obs.shape[-1]))
    return critic.apply(critic_params, obs_k, actions)


def conservative_penalty(q_sampled: jax.Array, log_density: jax.Array, q_data: jax.Array,
                         temperature: float = 1.0) -> jax.Array:
    """Per-critic CQL(H) penalty ``T·mean_b logsumexp_k((Q_ik − log μ_k)/T) − mean_b Q_i(s, a)``
    (CQL eq. 4, importance-sampled): ``q_sampled`` ``(K, B, C)``, ``log_density`` ``(K, B)``,
    ``q_data`` ``(B, C)``; returns ``(C,)``."""
    z = (q_sampled - log_density[..., None]) / temperature
    return temperature * jnp.mean(jax.nn.logsumexp(z, axis=0), axis=0) - jnp.mean(q_data, axis=0)


def _check_inputs(config: Any, reward_data: Any) -> None:
    """Refuse a config that is not a :class:`CQLConfig` and any reward data."""
    if not isinstance(config, CQLConfig):
        raise ValueError(f"config must be a CQLConfig, got {type(config).__name__}")
    if reward_data is not None:
        raise ValueError("CQL takes no reward_data: it learns from the rewards of the dynamics "
                         "data (label them first, e.g. offline.data.dataset.relabel_rewards)")


def make_train(dynamics: odata.Dataset, config: CQLConfig = CQLConfig(), *,
               reward_data: RewardData | None = None) -> Trainer:
    """The learner API (:mod:`offline.learners.base`) for CQL(H) on ``dynamics`` (with its rewards).

    Metrics per step: ``critic_loss`` (TD + penalty, summed over critics), ``td_loss``,
    ``cql_penalty`` (mean over critics, before the weight), ``actor_loss``, ``alpha`` (entropy
    temperature), ``entropy`` (``−mean log π``), ``mean_q``.
    """
    _check_inputs(config, reward_data)
    data, scale, norm = normalized_dataset(dynamics, "dynamics", config.normalize_observations)
    c = config
    action_size = dynamics.action_size
    target_entropy = -float(action_size) if c.target_entropy is None else c.target_entropy
    policy = make_actor(c.actor, dynamics.metadata, action_size, c.hidden_sizes, c.activation)
    bases = dataset_bases(policy, data.observations, data.next_observations)
    critic = QEnsemble(c.num_critics, c.hidden_sizes, c.activation)
    opts = {"actor": optax.adam(c.actor_lr), "critic": optax.adam(c.critic_lr),
            "log_alpha": optax.adam(c.alpha_lr)}

    def init(key: jax.Array, beta: Any = None) -> CQLState:
        k_actor, k_critic, k_run = jax.random.split(key, 3)
        obs, act = data.observations[:1], data.actions[:1]
        params = {"actor": policy.init(k_actor, obs), "critic": critic.init(k_critic, obs, act),
                  "log_alpha": jnp.zeros((), jnp.float32)}
        opt_state = {name: opts[name].init(params[name]) for name in opts}
        beta = c.min_q_weight if beta is None else beta
        return CQLState(params, {"critic": params["critic"]}, opt_state, k_run,
                        jnp.zeros((), jnp.int32), jnp.asarray(beta, jnp.float32))

    def update(state: CQLState, key: jax.Array):
        k_batch, k_pi, k_next, k_pen = jax.random.split(key, 4)
        b, base = odata.sample_with(data, bases, k_batch, c.batch_size)
        p = state.params
        alpha = jnp.exp(p["log_alpha"])

        # Bellman target
        a_next, logp_next = apply_actor(policy, p["actor"], b.next_observations,
                                        base.next_observations).sample(k_next)
        q_next = jnp.min(critic.apply(state.target["critic"], b.next_observations, a_next), -1)
        if c.backup_entropy:
            q_next = q_next - alpha * logp_next
        y = jax.lax.stop_gradient(b.rewards + c.discount * (1.0 - b.terminals) * q_next)
        sampled, log_density = penalty_actions(policy, p["actor"], b.observations,
                                               b.next_observations, k_pen, c.num_samples, base)

        def critic_loss(cp):
            q = critic.apply(cp, b.observations, b.actions)  # (B, C)
            td = jnp.mean(jnp.square(q - y[:, None]), axis=0)  # (C,)
            penalty = conservative_penalty(sampled_q(critic, cp, b.observations, sampled),
                                           log_density, q, c.temperature)
            loss = jnp.sum(td + state.beta * penalty)
            return loss, (jnp.sum(td), jnp.mean(penalty), jnp.mean(q))

        def actor_loss(ap):
            a_pi, logp = apply_actor(policy, ap, b.observations, base.observations).sample(k_pi)
            q_pi = jnp.min(critic.apply(p["critic"], b.observations, a_pi), -1)
            return jnp.mean(alpha * logp - q_pi), logp

        def alpha_loss(log_alpha, logp):
            return -jnp.mean(log_alpha * jax.lax.stop_gradient(logp + target_entropy))

        (l_critic, (td, pen, mean_q)), g_critic = jax.value_and_grad(
            critic_loss, has_aux=True)(p["critic"])
        (l_actor, logp), g_actor = jax.value_and_grad(actor_loss, has_aux=True)(p["actor"])
        g_alpha = jax.grad(alpha_loss)(p["log_alpha"], logp)
        new_p, opt_state = {}, {}
        for name, g in (("critic", g_critic), ("actor", g_actor), ("log_alpha", g_alpha)):
            new_p[name], opt_state[name] = adam_step(opts[name], p[name],
                                                     state.opt_state[name], g)
        target = {"critic": polyak(state.target["critic"], new_p["critic"], c.tau)}
        metrics = {"critic_loss": l_critic, "td_loss": td, "cql_penalty": pen,
                   "actor_loss": l_actor, "alpha": alpha, "entropy": -jnp.mean(logp),
                   "mean_q": mean_q}
        return state._replace(params=new_p, target=target, opt_state=opt_state), metrics

    def run(state: CQLState, n: int):
        return scan_steps(update, state, n)

    return Trainer(init, run, policy_act(policy, scale, norm), c.num_steps)


__all__ = ["CQLConfig", "CQLState", "conservative_penalty", "make_train", "penalty_actions",
           "sampled_q"]
