"""One gradient step of ATAC / PSPI / MAHALO (thesis §7.3.3, Algorithm 3; docs/design.md §4.5):
the learner state, the reward players and :func:`atac_step`, which
:func:`offline.learners.atac.make_core` scans."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from offline.data import dataset as odata
from offline.learners.atac_losses import combine, dqra_loss, pessimism_loss
from offline.learners.networks import QEnsemble, polyak, project_frobenius
from offline.learners.residual_actor import apply_actor

# --------------------------------------------------------------------------------------------
# Reward players

class RewardModel(NamedTuple):
    """Where the Bellman backups' rewards come from.

    ``init(key) -> params`` (a pytree, ``{}`` when there are none; RP fits its frozen network
    here); ``predict(params, batch) -> (B,)`` rewards for a dynamics minibatch (detached by the
    core); ``fit_loss(params, key) -> scalar`` the reward-data loss of a reward player trained
    online (MAHALO's ``E_{D_R}(g)``, eq 7.3), or ``None`` for a fixed reward;
    ``weight(beta) -> α`` the weight of ``fit_loss`` in Algorithm 3 line 6.
    """

    init: Callable[[jax.Array], Any]
    predict: Callable[[Any, odata.Dataset], jax.Array]
    fit_loss: Callable[[Any, jax.Array], jax.Array] | None = None
    weight: Callable[[jax.Array], jax.Array] | None = None
    lr: float = 5e-4


def dataset_rewards() -> RewardModel:
    """The reward player that reads the minibatch's ``rewards`` (ATAC / PSPI / Oracle / UDS)."""
    return RewardModel(init=lambda key: {}, predict=lambda params, batch: batch.rewards)

class ATACState(NamedTuple):
    """Learner state: ``params`` {"actor", "critic", "log_alpha", "reward"}, the target
    critics, the optimiser states {"actor", "critic", "alpha", "reward"}, the PRNG key (step
    ``t`` uses ``fold_in(key, t)``), the step counter and β (traced, so vmap over β works)."""

    params: dict
    target_critic: Any
    opt_states: dict
    key: jax.Array
    step: jax.Array
    beta: jax.Array


class ATACCore(NamedTuple):
    """What one ATAC gradient step needs besides the state: the prepared data, its actor bases,
    the networks, the optimisers and the constants (built once by
    :func:`offline.learners.atac.make_core`)."""

    config: Any  # offline.learners.atac.ATACConfig
    reward: RewardModel
    ds: odata.Dataset
    bases: Any
    actor: Any
    critic: QEnsemble
    actor_adam: optax.GradientTransformation
    critic_opt: optax.GradientTransformation
    alpha_opt: optax.GradientTransformation
    reward_opt: optax.GradientTransformation
    bounds: tuple[float, float] | None
    target_entropy: float
    log_alpha0: jax.Array


def atac_step(core: ATACCore, state: ATACState, key: jax.Array) -> tuple[ATACState, dict]:
    """One gradient step of Algorithm 3: critics (and the reward player), targets, temperature,
    actor — BC warm start before ``config.warmstart_steps``."""
    cfg = core.config
    in_warm = state.step < cfg.warmstart_steps
    # The warm-start switch: fresh actor Adam moments, temperature reset.
    switch = state.step == cfg.warmstart_steps
    fresh = (core.actor_adam.init(state.params["actor"]), core.log_alpha0,
             core.alpha_opt.init(core.log_alpha0))
    current = (state.opt_states["actor"], state.params["log_alpha"], state.opt_states["alpha"])
    actor_os, log_alpha, alpha_os = jax.tree.map(
        lambda f, c: jnp.where(switch, f, c), fresh, current)

    k_batch, k_next, k_pi, k_reward = jax.random.split(key, 4)
    batch, base = odata.sample_with(core.ds, core.bases, k_batch, cfg.batch_size)
    p = state.params
    a_next, _ = apply_actor(core.actor, p["actor"], batch.next_observations,
                            base.next_observations).sample(k_next)
    a_next = jax.lax.stop_gradient(a_next)
    a_pi, logp_pi = apply_actor(core.actor, p["actor"], batch.observations,
                                base.observations).sample(k_pi)
    q_next_target = jnp.min(core.critic.apply(state.target_critic, batch.next_observations,
                                              a_next), axis=-1)

    def bellman(critic_params, rewards):
        q = core.critic.apply(critic_params, batch.observations, batch.actions)
        q_next = core.critic.apply(critic_params, batch.next_observations, a_next)
        return dqra_loss(q, q_next, q_next_target, rewards, batch.terminals, cfg.discount,
                         cfg.dqra_weight, core.bounds), q

    new_params, new_os = dict(p), dict(state.opt_states)
    c_grad, metrics = _critic_gradient(core, state, batch, a_pi, bellman, in_warm)
    if core.reward.fit_loss is not None:
        new_params["reward"], new_os["reward"], fit_metrics = _reward_update(
            core, state, batch, bellman, k_reward)
        metrics.update(fit_metrics)
    upd, new_os["critic"] = core.critic_opt.update(c_grad, state.opt_states["critic"])
    new_critic = project_frobenius(optax.apply_updates(p["critic"], upd), cfg.norm_bound)
    new_params["critic"] = new_critic
    new_target = polyak(state.target_critic, new_critic, cfg.tau)

    entropy = -jnp.mean(logp_pi)
    a_grad = jax.grad(lambda la: la * (jax.lax.stop_gradient(entropy) - core.target_entropy))(
        log_alpha)
    upd, new_os["alpha"] = core.alpha_opt.update(a_grad, alpha_os)
    new_params["log_alpha"] = optax.apply_updates(log_alpha, upd)
    alpha = jnp.exp(new_params["log_alpha"])
    new_params["actor"], new_os["actor"], act_loss = _actor_update(
        core, p["actor"], actor_os, batch, base, new_critic, alpha, k_pi, in_warm)
    metrics.update(actor_loss=act_loss, alpha=alpha, entropy=entropy)
    return ATACState(new_params, new_target, new_os, state.key, state.step, state.beta), metrics


def _critic_gradient(core: ATACCore, state: ATACState, batch: odata.Dataset, a_pi: jax.Array,
                     bellman: Callable, in_warm: jax.Array) -> tuple[Any, dict]:
    """Gradient of the critic loss ``Σ_i combine(L_i, E_i, β)`` (the Bellman term alone during
    warm start) and its metrics."""
    p = state.params
    rewards = jax.lax.stop_gradient(core.reward.predict(p["reward"], batch))

    def critic_loss(critic_params):
        e, q = bellman(critic_params, rewards)
        q_pi = core.critic.apply(critic_params, batch.observations, jax.lax.stop_gradient(a_pi))
        pess = pessimism_loss(q_pi, q, core.config.pessimism == "relative")
        game = jnp.sum(combine(pess, e, state.beta))
        loss = jnp.where(in_warm, jnp.sum(e), game)
        return loss, {"bellman": jnp.mean(e), "pessimism": jnp.mean(pess),
                      "q_data": jnp.mean(q), "q_pi": jnp.mean(q_pi)}

    (c_loss, metrics), c_grad = jax.value_and_grad(critic_loss, has_aux=True)(p["critic"])
    metrics["critic_loss"] = c_loss
    return c_grad, metrics


def _reward_update(core: ATACCore, state: ATACState, batch: odata.Dataset, bellman: Callable,
                   key: jax.Array) -> tuple[Any, Any, dict]:
    """Algorithm 3 line 6 for a reward player trained online: ``(params, opt_state, metrics)``
    after one step on ``fit_loss + β/α · Bellman term`` (the critics frozen)."""
    reward, p = core.reward, state.params
    frozen_critic = jax.lax.stop_gradient(p["critic"])

    def reward_loss(reward_params):
        fit = reward.fit_loss(reward_params, key)
        e, _ = bellman(frozen_critic, reward.predict(reward_params, batch))
        # Algorithm 3 line 6 divided by α (Adam is invariant to the loss scale).
        return fit + state.beta / reward.weight(state.beta) * jnp.sum(e), fit

    (r_loss, fit), r_grad = jax.value_and_grad(reward_loss, has_aux=True)(p["reward"])
    upd, opt_state = core.reward_opt.update(r_grad, state.opt_states["reward"])
    return (optax.apply_updates(p["reward"], upd), opt_state,
            {"reward_loss": r_loss, "reward_fit": fit})


def _actor_update(core: ATACCore, actor_params: Any, actor_os: Any, batch: odata.Dataset,
                  base: odata.Dataset, critic_params: Any, alpha: jax.Array, key: jax.Array,
                  in_warm: jax.Array) -> tuple[Any, Any, jax.Array]:
    """``(params, opt_state, loss)`` after one actor step: BC during warm start (rate
    ``bc_lr``), else ``combine(−mean f_1(s, a_π), −H(π), α)`` against the updated critic (rate
    ``actor_lr``)."""

    def actor_loss(params):
        dist = apply_actor(core.actor, params, batch.observations, base.observations)

        def bc():
            return -jnp.mean(dist.log_prob(batch.actions))

        def game():
            a, logp = dist.sample(key)
            q1 = core.critic.apply(critic_params, batch.observations, a)[..., 0]
            return combine(-jnp.mean(q1), jnp.mean(logp), alpha)

        return jax.lax.cond(in_warm, bc, game)

    loss, grad = jax.value_and_grad(actor_loss)(actor_params)
    upd, actor_os = core.actor_adam.update(grad, actor_os)
    lr = jnp.where(in_warm, core.config.bc_lr, core.config.actor_lr)
    return jax.tree.map(lambda x, u: x - lr * u, actor_params, upd), actor_os, loss


__all__ = ["ATACCore", "ATACState", "RewardModel", "atac_step", "dataset_rewards"]
