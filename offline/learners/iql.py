"""Implicit Q-learning (IQL; Kostrikov, Nair and Levine, "Offline Reinforcement Learning with
Implicit Q-Learning", ICLR 2022, arXiv:2110.06169), one of the offline RL algorithms of thesis
§8.4 (Figs 8.4 and 8.7, the wrong-reward studies) — the "not explicitly pessimistic" one.

Per gradient step, on one minibatch ``(s, a, r, s', d)`` of the dynamics data (actions divided by
the action limit), in the order of the authors' implementation:

1. **value** by expectile regression on the target critics (IQL eq. 5):
   ``L_V = E[L₂^τ(min_i Q̄_i(s, a) − V(s))]``, ``L₂^τ(u) = |τ − 1(u < 0)|·u²``;
2. **actor** by advantage-weighted regression (IQL eq. 7) with the new value:
   ``L_π = −E[w · log π(a|s)]``, ``w = min(exp(β·(min_i Q̄_i(s, a) − V(s))), w_max)``;
3. **critics** by the SARSA-free TD loss (IQL eq. 6): ``L_Q = E[Σ_i (Q_i(s, a) − y)²]``,
   ``y = r + γ(1 − d)·V(s')`` with the new value (``d`` = terminal; timeouts bootstrap);
4. **targets** ``Q̄ ← (1 − τ_p)Q̄ + τ_p Q`` (:func:`offline.learners.networks.polyak`).

Defaults are the paper's D4RL locomotion settings (its appendix B and the authors'
``configs/mujoco_config.py``): expectile τ = 0.7, inverse temperature β = 3.0, weights clipped
at 100, γ = 0.99, Adam lr 3e-4 for all three networks, batch 256, τ_p = 5e-3, 1M steps; networks
3×256 ReLU here (docs/design.md §4.5 sizes; the paper uses 2×256). Not reproduced: the paper's
cosine decay of the actor learning rate and its locomotion reward rescaling by
``1000/(max return − min return)`` (rewards are used as given). The actor is the tanh-Gaussian of
the other offline learners (:class:`offline.learners.tanh_gaussian.TanhGaussianPolicy`).

``beta`` of the learner API is the AWR inverse temperature β (``IQLConfig.temperature`` when
None), a traced scalar in the state so ``jax.vmap`` over β works. IQL reads the dynamics data's
rewards and takes no reward data.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from mjxrmp.config import check_bool, check_float, check_fraction, check_int
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
from offline.learners.networks import QEnsemble, StateNet, polyak
from offline.learners.residual_actor import apply_actor, check_actor, dataset_bases, make_actor


@dataclasses.dataclass(frozen=True)
class IQLConfig:
    """IQL hyper-parameters (module docstring for their sources); ``normalize_observations``
    standardises every network's states with the dataset's statistics
    (:class:`offline.learners.base.ObservationNormalizer`; default off); ``actor`` is the actor
    class (:data:`offline.learners.residual_actor.ACTORS`; default ``"mlp"``)."""

    hidden_sizes: tuple[int, ...] = (256, 256, 256)
    activation: str = "relu"
    actor_lr: float = 3e-4
    critic_lr: float = 3e-4
    value_lr: float = 3e-4
    batch_size: int = 256
    num_steps: int = 1_000_000
    discount: float = 0.99
    expectile: float = 0.7
    temperature: float = 3.0
    max_weight: float = 100.0
    tau: float = 5e-3
    num_critics: int = 2
    normalize_observations: bool = False
    actor: str = "mlp"

    def __post_init__(self) -> None:
        n = type(self).__name__
        object.__setattr__(self, "hidden_sizes", check_network(self.hidden_sizes,
                                                               self.activation, f"{n}."))
        for name in ("actor_lr", "critic_lr", "value_lr", "temperature", "max_weight"):
            check_float(getattr(self, name), f"{n}.{name}")
        for name in ("batch_size", "num_steps", "num_critics"):
            check_int(getattr(self, name), f"{n}.{name}")
        check_fraction(self.discount, f"{n}.discount")
        check_bool(self.normalize_observations, f"{n}.normalize_observations")
        check_actor(self.actor, self.normalize_observations)
        check_fraction(self.expectile, f"{n}.expectile")
        check_fraction(self.tau, f"{n}.tau", closed=True)


class IQLState(NamedTuple):
    params: dict  # {"actor", "critic", "value"}
    target: dict  # {"critic"}
    opt_state: dict  # per network
    key: jax.Array
    step: jax.Array
    beta: jax.Array  # AWR inverse temperature


def expectile_loss(diff: jax.Array, expectile: float | jax.Array) -> jax.Array:
    """``mean |τ − 1(u < 0)|·u²`` over ``u = diff`` (IQL eq. 5, asymmetric least squares)."""
    weight = jnp.where(diff < 0, 1.0 - expectile, expectile)
    return jnp.mean(weight * jnp.square(diff))


def awr_weights(advantage: jax.Array, temperature: float | jax.Array,
                max_weight: float) -> jax.Array:
    """``min(exp(β·A), w_max)`` (IQL eq. 7 with the authors' clip), computed without overflow."""
    return jnp.exp(jnp.minimum(temperature * advantage, jnp.log(max_weight)))


def make_train(dynamics: odata.Dataset, config: IQLConfig = IQLConfig(), *,
               reward_data: RewardData | None = None) -> Trainer:
    """The learner API (:mod:`offline.learners.base`) for IQL on ``dynamics`` (with its rewards).

    Metrics per step: ``value_loss``, ``actor_loss``, ``critic_loss``, ``mean_q``, ``mean_v``,
    ``mean_weight`` (mean AWR weight).
    """
    if not isinstance(config, IQLConfig):
        raise ValueError(f"config must be an IQLConfig, got {type(config).__name__}")
    if reward_data is not None:
        raise ValueError("IQL takes no reward_data: it learns from the rewards of the dynamics "
                         "data (label them first, e.g. offline.data.dataset.relabel_rewards)")
    data, scale, norm = normalized_dataset(dynamics, "dynamics", config.normalize_observations)
    c = config
    policy = make_actor(c.actor, dynamics.metadata, dynamics.action_size, c.hidden_sizes,
                        c.activation)
    bases = dataset_bases(policy, data.observations)
    critic = QEnsemble(c.num_critics, c.hidden_sizes, c.activation)
    value = StateNet(1, c.hidden_sizes, c.activation)
    opts = {"actor": optax.adam(c.actor_lr), "critic": optax.adam(c.critic_lr),
            "value": optax.adam(c.value_lr)}

    def init(key: jax.Array, beta: Any = None) -> IQLState:
        k_actor, k_critic, k_value, k_run = jax.random.split(key, 4)
        obs, act = data.observations[:1], data.actions[:1]
        params = {"actor": policy.init(k_actor, obs), "critic": critic.init(k_critic, obs, act),
                  "value": value.init(k_value, obs)}
        opt_state = {name: opts[name].init(params[name]) for name in opts}
        beta = c.temperature if beta is None else beta
        return IQLState(params, {"critic": params["critic"]}, opt_state, k_run,
                        jnp.zeros((), jnp.int32), jnp.asarray(beta, jnp.float32))

    def update(state: IQLState, key: jax.Array):
        b, base = odata.sample_with(data, bases, key, c.batch_size)
        p, opt_state = dict(state.params), dict(state.opt_state)
        q_target = jnp.min(critic.apply(state.target["critic"], b.observations, b.actions), -1)

        def value_loss(vp):
            v = value.apply(vp, b.observations)
            return expectile_loss(q_target - v, c.expectile), v

        (l_value, v), grads = jax.value_and_grad(value_loss, has_aux=True)(p["value"])
        p["value"], opt_state["value"] = adam_step(opts["value"], p["value"],
                                                   opt_state["value"], grads)

        weights = awr_weights(q_target - value.apply(p["value"], b.observations), state.beta,
                              c.max_weight)

        def actor_loss(ap):
            logp = apply_actor(policy, ap, b.observations, base.observations).log_prob(b.actions)
            return -jnp.mean(weights * logp)

        l_actor, grads = jax.value_and_grad(actor_loss)(p["actor"])
        p["actor"], opt_state["actor"] = adam_step(opts["actor"], p["actor"],
                                                   opt_state["actor"], grads)

        y = b.rewards + c.discount * (1.0 - b.terminals) * value.apply(p["value"],
                                                                         b.next_observations)

        def critic_loss(cp):
            q = critic.apply(cp, b.observations, b.actions)
            return jnp.mean(jnp.sum(jnp.square(q - y[:, None]), -1)), q

        (l_critic, q), grads = jax.value_and_grad(critic_loss, has_aux=True)(p["critic"])
        p["critic"], opt_state["critic"] = adam_step(opts["critic"], p["critic"],
                                                     opt_state["critic"], grads)
        target = {"critic": polyak(state.target["critic"], p["critic"], c.tau)}
        metrics = {"value_loss": l_value, "actor_loss": l_actor, "critic_loss": l_critic,
                   "mean_q": jnp.mean(q), "mean_v": jnp.mean(v),
                   "mean_weight": jnp.mean(weights)}
        return state._replace(params=p, target=target, opt_state=opt_state), metrics

    def run(state: IQLState, n: int):
        return scan_steps(update, state, n)

    return Trainer(init, run, policy_act(policy, scale, norm), c.num_steps)


__all__ = ["IQLConfig", "IQLState", "awr_weights", "expectile_loss", "make_train"]
