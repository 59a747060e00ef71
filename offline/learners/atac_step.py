"""One gradient step of ATAC / PSPI / MAHALO (thesis §7.3.3, Algorithm 3; docs/design.md §4.5):
the learner state, the reward players, :func:`atac_step` and :func:`run_steps`, which
:func:`offline.learners.atac.make_core`'s ``run`` is.

The step is written for few separate operations (at batch 256 a GPU step is bound by kernel
launches, not FLOPs), with the mathematics of Algorithm 3 unchanged:

* the randomness of a step (:class:`StepDraws`: minibatch, actor noise, reward-player key) comes
  from its own key ``fold_in(state.key, step)`` as ever, but :func:`run_steps` draws it for a
  block of ``config.block_steps`` steps at once (one gather per field per block), runs the
  block's steps in an inner ``lax.scan`` (unrolled ``config.unroll`` times) and writes each
  step's metrics as one array;
* one actor forward on ``[s; s']`` gives ``a' ~ π(·|s')``, ``a_π ~ π(·|s)`` and, through its
  ``jax.vjp``, the actor's gradient later (the actor loss is differentiated with respect to the
  distribution's ``(μ, log σ)`` at ``s`` and pulled back once);
* one forward of the critic ensemble on the stacked rows ``(s, a), (s', a'), (s, a_π)`` gives
  every value the critic loss needs; its gradient is the loss's gradient with respect to those
  values pulled back once, and MAHALO's reward player reuses the same (frozen) values.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from offline.data import dataset as odata
from offline.learners.atac_losses import combine, dqra_loss, pessimism_loss
from offline.learners.networks import QEnsemble, polyak, project_frobenius
from offline.learners.residual_actor import apply_actor
from offline.learners.tanh_gaussian import TanhGaussian

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


class StepDraws(NamedTuple):
    """The randomness of one gradient step (:func:`draw`): the minibatch and its actor-base rows,
    standard-normal noise ``(B, A)`` of ``a' ~ π(·|s')`` and ``a_π ~ π(·|s)``, and the reward
    player's key."""

    batch: odata.Dataset
    base: Any
    noise_next: jax.Array
    noise_pi: jax.Array
    reward_key: jax.Array


def draw(core: ATACCore, key: jax.Array) -> StepDraws:
    """The draws of the step whose key is ``key``: ``split(key, 4)`` gives the minibatch
    (:func:`offline.data.dataset.sample_with`), the two actor noises and the reward key."""
    k_batch, k_next, k_pi, k_reward = jax.random.split(key, 4)
    batch, base = odata.sample_with(core.ds, core.bases, k_batch, core.config.batch_size)
    shape, dtype = batch.actions.shape, batch.actions.dtype
    return StepDraws(batch, base, jax.random.normal(k_next, shape, dtype),
                     jax.random.normal(k_pi, shape, dtype), k_reward)


def metric_names(core: ATACCore) -> tuple[str, ...]:
    """The metrics :func:`atac_step` reports, in the order :func:`run_steps` stacks them."""
    names = ("bellman", "pessimism", "q_data", "q_pi", "critic_loss", "actor_loss", "alpha",
             "entropy")
    return names + (("reward_loss", "reward_fit") if core.reward.fit_loss is not None else ())


def run_steps(core: ATACCore, state: ATACState, n: int) -> tuple[ATACState, dict]:
    """``n`` (static) gradient steps in blocks of ``block = config.block_steps``: one
    ``lax.scan`` over the ``n // block`` blocks (each draws its steps' randomness at once, then
    runs them in an inner ``lax.scan`` unrolled ``config.unroll`` times), then the remaining
    ``n % block`` steps. Step ``t`` draws with ``fold_in(state.key, t)``, so
    ``run_steps(run_steps(s, a), b) == run_steps(s, a + b)`` whatever the blocks. Metrics get a
    leading axis ``n``."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
        raise ValueError(f"n (number of gradient steps) must be a static integer >= 0, got {n!r}")
    block, unroll = core.config.block_steps, core.config.unroll
    full, rest = divmod(int(n), block)
    parts = []
    if full:
        state, rows = jax.lax.scan(lambda s, _: _block(core, s, block, unroll), state, None,
                                   length=full)
        parts.append(rows.reshape(full * block, *rows.shape[2:]))
    if rest or not full:
        state, rows = _block(core, state, rest, unroll)
        parts.append(rows)
    rows = parts[0] if len(parts) == 1 else jnp.concatenate(parts)
    return state, {k: rows[:, i] for i, k in enumerate(metric_names(core))}


def _block(core: ATACCore, state: ATACState, size: int, unroll: int
           ) -> tuple[ATACState, jax.Array]:
    """``size`` steps from ``state``, their draws made together, run by a ``lax.scan``
    unrolled ``unroll`` times; metrics ``(size, M)``."""
    with jax.named_scope("rng"):
        steps = state.step + jnp.arange(size, dtype=state.step.dtype)
        keys = jax.vmap(jax.random.fold_in, in_axes=(None, 0))(state.key, steps)
    with jax.named_scope("minibatch"):
        draws = jax.vmap(lambda k: draw(core, k))(keys)

    def one(s: ATACState, d: StepDraws) -> tuple[ATACState, jax.Array]:
        s, metrics = atac_step(core, s, d)
        return s._replace(step=s.step + 1), jnp.stack([metrics[k] for k in metric_names(core)])

    return jax.lax.scan(one, state, draws, unroll=max(1, min(unroll, size)))


def atac_step(core: ATACCore, state: ATACState, draws: StepDraws) -> tuple[ATACState, dict]:
    """One gradient step of Algorithm 3 with the randomness ``draws``: critics (and the reward
    player), targets, temperature, actor — BC warm start before ``config.warmstart_steps``.
    The step counter is left for the caller to advance."""
    cfg, p, batch = core.config, state.params, draws.batch
    with jax.named_scope("warm_switch"):
        in_warm = state.step < cfg.warmstart_steps
        # The warm-start switch: fresh actor Adam moments, temperature reset.
        switch = state.step == cfg.warmstart_steps
        fresh = (core.actor_adam.init(p["actor"]), core.log_alpha0,
                 core.alpha_opt.init(core.log_alpha0))
        current = (state.opt_states["actor"], p["log_alpha"], state.opt_states["alpha"])
        actor_os, log_alpha, alpha_os = jax.tree.map(
            lambda f, c: jnp.where(switch, f, c), fresh, current)
    with jax.named_scope("actor_forward"):
        dist, actor_vjp = _actor_forward(core, p["actor"], batch, draws.base)
        dist_s, dist_next = (jax.tree.map(lambda x, h=h: x[h], dist)
                             for h in (slice(0, cfg.batch_size), slice(cfg.batch_size, None)))
        a_next = jax.lax.stop_gradient(dist_next.sample_from_noise(draws.noise_next)[0])
        a_pi, logp_pi = dist_s.sample_from_noise(draws.noise_pi)
    with jax.named_scope("target_forward"):
        q_next_target = jnp.min(core.critic.apply(state.target_critic, batch.next_observations,
                                                  a_next), axis=-1)
    with jax.named_scope("critic_forward"):
        obs = jnp.concatenate([batch.observations, batch.next_observations, batch.observations])
        act = jnp.concatenate([batch.actions, a_next, jax.lax.stop_gradient(a_pi)])
        q_all, critic_vjp = jax.vjp(lambda c: core.critic.apply(c, obs, act), p["critic"])
    bellman = _bellman(core, batch, q_next_target)
    new_params, new_os = dict(p), dict(state.opt_states)
    c_grad, metrics = _critic_gradient(core, state, batch, q_all, critic_vjp, bellman, in_warm)
    if core.reward.fit_loss is not None:
        with jax.named_scope("reward_update"):
            new_params["reward"], new_os["reward"], fit_metrics = _reward_update(
                core, state, batch, jax.lax.stop_gradient(q_all), bellman, draws.reward_key)
        metrics.update(fit_metrics)
    with jax.named_scope("critic_optimizer"):
        upd, new_os["critic"] = core.critic_opt.update(c_grad, state.opt_states["critic"])
        new_critic = optax.apply_updates(p["critic"], upd)
    with jax.named_scope("projection"):
        new_critic = project_frobenius(new_critic, cfg.norm_bound)
    new_params["critic"] = new_critic
    with jax.named_scope("target_update"):
        new_target = polyak(state.target_critic, new_critic, cfg.tau)
    with jax.named_scope("temperature"):
        entropy = -jnp.mean(logp_pi)
        a_grad = jax.grad(lambda la: la * (jax.lax.stop_gradient(entropy)
                                           - core.target_entropy))(log_alpha)
        upd, new_os["alpha"] = core.alpha_opt.update(a_grad, alpha_os)
        new_params["log_alpha"] = optax.apply_updates(log_alpha, upd)
        alpha = jnp.exp(new_params["log_alpha"])
    new_params["actor"], new_os["actor"], act_loss = _actor_update(
        core, p["actor"], actor_os, batch, dist_s, actor_vjp, new_critic, alpha,
        draws.noise_pi, in_warm)
    metrics.update(actor_loss=act_loss, alpha=alpha, entropy=entropy)
    return ATACState(new_params, new_target, new_os, state.key, state.step, state.beta), metrics


def _actor_forward(core: ATACCore, actor_params: Any, batch: odata.Dataset, base: Any
                   ) -> tuple[TanhGaussian, Callable]:
    """The actor's distribution at the rows ``[s; s']`` (one forward) and its ``vjp`` with
    respect to the actor's parameters."""
    obs = jnp.concatenate([batch.observations, batch.next_observations])
    rows = (None if base.observations is None
            else jnp.concatenate([base.observations, base.next_observations]))
    return jax.vjp(lambda a: apply_actor(core.actor, a, obs, rows), actor_params)


def _bellman(core: ATACCore, batch: odata.Dataset, q_next_target: jax.Array) -> Callable:
    """``bellman(q_all, rewards) -> (E_i (K,), f_i(s, a) (B, K))``: the DQRA term of eq 7.11 from
    the critic values ``q_all`` of the stacked rows ``(s, a), (s', a'), (s, a_π)``."""
    cfg = core.config

    def bellman(q_all: jax.Array, rewards: jax.Array) -> tuple[jax.Array, jax.Array]:
        q, q_next, _ = jnp.split(q_all, 3)
        return dqra_loss(q, q_next, q_next_target, rewards, batch.terminals, cfg.discount,
                         cfg.dqra_weight, core.bounds), q

    return bellman


def _critic_gradient(core: ATACCore, state: ATACState, batch: odata.Dataset,
                     q_all: jax.Array, critic_vjp: Callable, bellman: Callable,
                     in_warm: jax.Array) -> tuple[Any, dict]:
    """Gradient of the critic loss ``Σ_i combine(L_i, E_i, β)`` (the Bellman term alone during
    warm start) with respect to the critic values ``q_all``, pulled back through the critics'
    forward (``critic_vjp``); and its metrics."""
    rewards = jax.lax.stop_gradient(core.reward.predict(state.params["reward"], batch))

    def critic_loss(q_all):
        with jax.named_scope("critic_loss"):
            e, q = bellman(q_all, rewards)
        with jax.named_scope("pessimism"):
            q_pi = jnp.split(q_all, 3)[2]
            pess = pessimism_loss(q_pi, q, core.config.pessimism == "relative")
            game = jnp.sum(combine(pess, e, state.beta))
        loss = jnp.where(in_warm, jnp.sum(e), game)
        return loss, {"bellman": jnp.mean(e), "pessimism": jnp.mean(pess),
                      "q_data": jnp.mean(q), "q_pi": jnp.mean(q_pi)}

    (c_loss, metrics), q_grad = jax.value_and_grad(critic_loss, has_aux=True)(q_all)
    with jax.named_scope("critic_backward"):
        (c_grad,) = critic_vjp(q_grad)
    metrics["critic_loss"] = c_loss
    return c_grad, metrics


def _reward_update(core: ATACCore, state: ATACState, batch: odata.Dataset, q_all: jax.Array,
                   bellman: Callable, key: jax.Array) -> tuple[Any, Any, dict]:
    """Algorithm 3 line 6 for a reward player trained online: ``(params, opt_state, metrics)``
    after one step on ``fit_loss + β/α · Bellman term`` (the critics frozen: their values
    ``q_all`` are the critic step's, detached)."""
    reward, p = core.reward, state.params

    def reward_loss(reward_params):
        fit = reward.fit_loss(reward_params, key)
        e, _ = bellman(q_all, reward.predict(reward_params, batch))
        # Algorithm 3 line 6 divided by α (Adam is invariant to the loss scale).
        return fit + state.beta / reward.weight(state.beta) * jnp.sum(e), fit

    (r_loss, fit), r_grad = jax.value_and_grad(reward_loss, has_aux=True)(p["reward"])
    upd, opt_state = core.reward_opt.update(r_grad, state.opt_states["reward"])
    return (optax.apply_updates(p["reward"], upd), opt_state,
            {"reward_loss": r_loss, "reward_fit": fit})


def _actor_update(core: ATACCore, actor_params: Any, actor_os: Any, batch: odata.Dataset,
                  dist: TanhGaussian, actor_vjp: Callable, critic_params: Any, alpha: jax.Array,
                  noise: jax.Array, in_warm: jax.Array) -> tuple[Any, Any, jax.Array]:
    """``(params, opt_state, loss)`` after one actor step: BC during warm start (rate
    ``bc_lr``), else ``combine(−mean f_1(s, a_π), −H(π), α)`` against the updated critic (rate
    ``actor_lr``). The loss is differentiated with respect to ``dist`` (the actor's
    distribution at ``s``, the first rows of its forward) and pulled back by ``actor_vjp``."""

    def actor_loss(dist):
        with jax.named_scope("actor_loss"):
            def bc():
                return -jnp.mean(dist.log_prob(batch.actions))

            def game():
                a, logp = dist.sample_from_noise(noise)
                # Only f_1 enters the actor's loss: evaluate that member alone (leading axis).
                first = jax.tree.map(lambda x: x[:1], critic_params)
                q1 = core.critic.clone(num_critics=1).apply(first, batch.observations, a)[..., 0]
                return combine(-jnp.mean(q1), jnp.mean(logp), alpha)

            return jax.lax.cond(in_warm, bc, game)

    loss, d_grad = jax.value_and_grad(actor_loss)(dist)
    with jax.named_scope("actor_backward"):
        pad = lambda g: jnp.concatenate([g, jnp.zeros_like(g)])  # noqa: E731  (s' rows: no loss)
        (grad,) = actor_vjp(jax.tree.map(pad, d_grad))
    with jax.named_scope("actor_optimizer"):
        upd, actor_os = core.actor_adam.update(grad, actor_os)
        lr = jnp.where(in_warm, core.config.bc_lr, core.config.actor_lr)
        new = jax.tree.map(lambda x, u: x - lr * u, actor_params, upd)
    return new, actor_os, loss


__all__ = [
    "ATACCore",
    "ATACState",
    "RewardModel",
    "StepDraws",
    "atac_step",
    "dataset_rewards",
    "draw",
    "metric_names",
    "run_steps",
]
