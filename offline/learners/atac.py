"""ATAC and PSPI: adversarially trained actor critic (thesis §7.3.3, Algorithm 3 without the
reward player; docs/design.md §4.5), and the shared core that MAHALO and the PLfO baselines reuse.

The critic ensemble ``f_1 … f_K`` (K = 2) and the tanh-Gaussian actor ``π`` play the
Stackelberg game of eq 7.1 with the observed reward in place of ``g``:

* **Bellman term** — the DQRA loss of eq 7.11 for each critic,
  ``E^w(π, f_i) = w·E[(f_i(s,a) − y̅)²] + (1 − w)·E[(f_i(s,a) − y_i)²]`` with the target-network
  backup ``y̅ = r + γ(1 − d)·min_j f̄_j(s', a')`` (no gradient) and the residual backup
  ``y_i = r + γ(1 − d)·f_i(s', a')`` (gradient through ``f_i(s', a')`` too, the residual
  algorithm), the *same* ``a' ~ π(·|s')`` in both. ``d`` is the terminal flag (timeouts
  bootstrap). With ``clip_v`` both backups are clipped to ``[V_min, V_max]`` (docs/design.md §4.5)
  with a straight-through gradient.
* **Pessimism term** — eq 7.2 on a minibatch: relative (ATAC)
  ``L(π, f_i) = mean f_i(s, a_π) − f_i(s, a)``, or absolute (PSPI) ``mean f_i(s, a_π)``, with
  ``a_π ~ π(·|s)`` detached for the critic.
* **Combination** — :func:`combine` ``(loss, reg, w) = loss/w + reg if w > 1 else loss + w·reg``:
  critic loss ``Σ_i combine(L_i, E_i, β)`` (Algorithm 3 line 5, rescaled by ``1/β`` when
  ``β > 1``), actor loss ``combine(−mean f_1(s, a_π), −H(π), α)`` (line 9 with the SAC-style
  entropy Lagrangian: ``α`` minimises ``log α·(H − H_target)``, ``H_target = −dim A``).
* After each critic step every critic weight matrix (not the biases) is projected to Frobenius
  norm ``≤ norm_bound`` (line 7, ``Proj_F``); then the targets move by Polyak averaging
  (line 11); the temperature and then the actor step follow, the actor seeing the updated
  critic.
* **BC warm start** — during the first ``warmstart_steps`` the actor maximises the likelihood
  of the dataset actions (learning rate ``bc_lr``) and the critics minimise the Bellman term
  only (they evaluate the BC policy); the temperature is tuned throughout. At the switch the
  temperature and its optimiser are reset to their initial values and the actor's Adam state is
  rebuilt (fresh moments) at the slow rate ``actor_lr``; the target critics are kept. The switch
  happens inside the compiled scan (a ``lax.cond`` / ``where`` on the step counter), so
  ``run(run(s, a), b) == run(s, a + b)``.

Reward players (:class:`RewardModel`): the Bellman backups use ``predict(params, batch)``;
ATAC, PSPI, Oracle and UDS read the dataset's rewards, RP a frozen reward network fitted at
``init``, and MAHALO (:mod:`offline.learners.mahalo`) trains ``g`` online with Algorithm 3 line 6.

Actions are divided by :func:`offline.learners.base.action_scale` (so they lie in ``[−1, 1]``) and
``act`` multiplies the tanh mode back. With ``normalize_observations`` every state entering a
network (actor, critics, the reward player's ``g``) is standardised with the dynamics data's
statistics (:class:`offline.learners.base.ObservationNormalizer`); ``act`` takes raw observations.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from offline.data import dataset as odata
from offline.data import scenarios
from offline.learners.base import (
    ObservationNormalizer,
    Trainer,
    action_scale,
    check_bool,
    normalized_dataset,
    observation_normalizer,
    policy_act,
    scan_steps,
)
from offline.learners.networks import FROBENIUS_BOUND, QEnsemble, polyak, project_frobenius
from offline.learners.residual_actor import apply_actor, check_actor, dataset_bases, make_actor

PESSIMISM = ("relative", "absolute")


@dataclasses.dataclass(frozen=True)
class ATACConfig:
    """ATAC / PSPI hyperparameters (defaults: docs/design.md §4.5, the thesis' ATAC settings).

    ``num_steps`` counts all gradient steps, the ``warmstart_steps`` of BC warm start
    included. ``bc_lr`` is the actor's rate during warm start (the fast rate: docs/design.md §4.5
    says the actor optimiser is *rebuilt* at the slow rate at the switch). ``target_entropy``
    ``None`` means ``−dim(A)``. ``dqra_weight`` is ``w`` of eq 7.11 (weight of the
    target-network term; ``1 − w`` weighs the residual term). ``pessimism="relative"`` is ATAC,
    ``"absolute"`` PSPI. ``remove_terminals`` treats terminals as timeouts; ``clip_v`` clips
    the backups to ``[V_min, V_max]`` computed from the reward range.
    ``normalize_observations`` standardises the states (module docstring; default off).
    ``actor`` is the actor class (:data:`offline.learners.residual_actor.ACTORS`; default ``"mlp"``).
    """

    hidden_sizes: Sequence[int] = (256, 256, 256)
    num_critics: int = 2
    critic_lr: float = 5e-4
    actor_lr: float = 5e-7
    alpha_lr: float = 5e-4
    bc_lr: float = 5e-4
    init_temperature: float = 1.0
    target_entropy: float | None = None
    tau: float = 5e-3
    discount: float = 0.99
    batch_size: int = 256
    beta: float = 16.0
    warmstart_steps: int = 100_000
    num_steps: int = 1_000_000
    dqra_weight: float = 0.5
    norm_bound: float = FROBENIUS_BOUND
    pessimism: str = "relative"
    remove_terminals: bool = False
    clip_v: bool = False
    normalize_observations: bool = False
    actor: str = "mlp"

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden_sizes", tuple(self.hidden_sizes))
        if not self.hidden_sizes or any(not isinstance(h, int) or h < 1
                                        for h in self.hidden_sizes):
            raise ValueError(f"hidden_sizes must be a non-empty sequence of positive integers, "
                             f"got {self.hidden_sizes!r}")
        _check_int("num_critics", self.num_critics, 1)
        _check_int("batch_size", self.batch_size, 1)
        _check_int("warmstart_steps", self.warmstart_steps, 0)
        _check_int("num_steps", self.num_steps, 1)
        for name in ("critic_lr", "actor_lr", "alpha_lr", "bc_lr", "init_temperature",
                     "norm_bound"):
            _check_positive(name, getattr(self, name))
        if not (isinstance(self.beta, int | float) and math.isfinite(self.beta)
                and self.beta >= 0):
            raise ValueError(f"beta must be a finite number >= 0, got {self.beta!r}")
        for name in ("tau", "dqra_weight"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and 0.0 <= v <= 1.0):
                raise ValueError(f"{name} must lie in [0, 1], got {v!r}")
        if not (isinstance(self.discount, int | float) and 0.0 <= self.discount < 1.0):
            raise ValueError(f"discount must lie in [0, 1), got {self.discount!r}")
        if self.target_entropy is not None and not math.isfinite(self.target_entropy):
            raise ValueError(f"target_entropy must be finite or None, got "
                             f"{self.target_entropy!r}")
        if self.pessimism not in PESSIMISM:
            raise ValueError(f"pessimism must be one of {list(PESSIMISM)}, got "
                             f"{self.pessimism!r}")
        check_bool(self.normalize_observations, "normalize_observations")
        check_actor(self.actor, self.normalize_observations)


def _check_int(name: str, value: Any, minimum: int) -> None:
    if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")


def _check_positive(name: str, value: Any) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


# --------------------------------------------------------------------------------------------
# Loss terms (pure functions; tested against float64 NumPy references)


def combine(loss: jax.Array, reg: jax.Array, w: jax.Array | float) -> jax.Array:
    """``loss/w + reg`` if ``w > 1`` else ``loss + w·reg`` (docs/design.md §4.5; eq 7.1's weighted
    sum ``loss + w·reg`` rescaled by ``1/w`` for large ``w``). ``w`` may be traced; the unused
    branch never divides by a ``w ≤ 1``, so gradients stay finite at ``w = 0``."""
    w = jnp.asarray(w)
    big = w > 1.0
    return jnp.where(big, loss / jnp.where(big, w, 1.0) + reg, loss + w * reg)


def value_bounds(reward_min: float, reward_max: float, discount: float) -> tuple[float, float]:
    """``(V_min, V_max) = (min(−1/(1−γ), 2 r_min/(1−γ)), max(1/(1−γ), 2 r_max/(1−γ)))``
    (docs/design.md §4.5, the ``clip_v`` option)."""
    h = 1.0 / (1.0 - discount)
    return min(-h, 2.0 * reward_min * h), max(h, 2.0 * reward_max * h)


def _clip_straight_through(x: jax.Array, bounds: tuple[float, float] | None) -> jax.Array:
    if bounds is None:
        return x
    return x + jax.lax.stop_gradient(jnp.clip(x, *bounds) - x)


def dqra_loss(q: jax.Array, q_next: jax.Array, q_next_target: jax.Array, rewards: jax.Array,
              terminals: jax.Array, discount: float, w: float,
              bounds: tuple[float, float] | None = None) -> jax.Array:
    """Per-critic DQRA Bellman loss of eq 7.11, shape ``(K,)``.

    ``q = f_i(s, a)`` and ``q_next = f_i(s', a')`` are ``(B, K)``, ``q_next_target =
    min_j f̄_j(s', a')`` is ``(B,)``; ``rewards`` / ``terminals`` ``(B,)``. Returns
    ``w·mean (q − sg(y̅))² + (1 − w)·mean (q − y)²`` with ``y̅ = r + γ(1−d) q_next_target``
    (stop-gradient) and ``y = r + γ(1−d) q_next`` (gradient flows into ``q_next``: the residual
    algorithm). ``bounds`` clips both backups (straight-through gradient).
    """
    cont = discount * (1.0 - terminals.astype(q.dtype))
    y_target = _clip_straight_through(rewards + cont * q_next_target, bounds)
    y_resid = _clip_straight_through(rewards[:, None] + cont[:, None] * q_next, bounds)
    target_term = jnp.mean(jnp.square(q - jax.lax.stop_gradient(y_target)[:, None]), axis=0)
    resid_term = jnp.mean(jnp.square(q - y_resid), axis=0)
    return w * target_term + (1.0 - w) * resid_term


def pessimism_loss(q_pi: jax.Array, q_data: jax.Array, relative: bool = True) -> jax.Array:
    """Per-critic pessimism term (eq 7.2 on a minibatch), shape ``(K,)``: relative (ATAC)
    ``mean f_i(s, a_π) − f_i(s, a)`` or absolute (PSPI) ``mean f_i(s, a_π)``; inputs
    ``(B, K)`` (``a_π`` already detached by the caller)."""
    diff = q_pi - q_data if relative else q_pi
    return jnp.mean(diff, axis=0)


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


# --------------------------------------------------------------------------------------------
# The core


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


def _as_float32(x: Any) -> Any:
    """``x`` as float32: a NumPy array, or a traced array cast in the graph (e.g. rewards
    vmapped over reward variants, ``offline.survival.sweep``)."""
    if isinstance(x, jax.core.Tracer):
        return x.astype(jnp.float32)
    return np.asarray(x, np.float32)


def prepare_dataset(dataset: odata.Dataset, remove_terminals: bool,
                    normalizer: ObservationNormalizer | None = None) -> odata.Dataset:
    """Optionally turn terminals into timeouts, cast the float fields to float32, then
    :func:`offline.learners.base.normalized_dataset` (validate, divide the actions by the action
    limit, standardise the states with ``normalizer`` when it is enabled, put it on the
    device)."""
    if remove_terminals:
        dataset = scenarios.terminals_as_timeouts(odata.validate(dataset, name="dynamics"))
    f32 = {f: _as_float32(getattr(dataset, f))
           for f in ("observations", "actions", "rewards", "next_observations")}
    on = normalizer is not None and normalizer.enabled
    return normalized_dataset(dataset.replace(**f32), "dynamics", on, normalizer)[0]


def make_core(dynamics: odata.Dataset, config: ATACConfig, reward: RewardModel, *,
              reward_range: tuple[float, float] | None = None,
              normalizer: ObservationNormalizer | None = None) -> Trainer:
    """The ATAC trainer (module docstring) on ``dynamics`` with the rewards of ``reward``.

    ``reward_range`` ``(r_min, r_max)`` gives ``V_min`` / ``V_max`` when ``config.clip_v``
    (default: the range of the dataset's rewards). Algorithm 3 (thesis §7.3.3) with the reward
    player's update (line 6) when ``reward.fit_loss`` is given. With
    ``config.normalize_observations`` the states are standardised by ``normalizer`` (default:
    fitted on ``dynamics``); the reward player's ``predict`` then receives standardised
    minibatches and must have been built with the same normalizer.
    """
    if not isinstance(config, ATACConfig):
        raise TypeError(f"config must be an ATACConfig, got {type(config).__name__}")
    if reward.fit_loss is not None and reward.weight is None:
        raise ValueError("a trained reward player (fit_loss) needs a weight(beta) function")
    scale = action_scale(dynamics)
    norm = observation_normalizer(dynamics, config.normalize_observations, normalizer)
    ds = prepare_dataset(dynamics, config.remove_terminals, norm)
    obs_size, act_size = ds.observation_size, ds.action_size
    if reward_range is None and config.clip_v:
        r = np.asarray(ds.rewards)
        reward_range = (float(r.min()), float(r.max()))
    bounds = value_bounds(*reward_range, config.discount) if config.clip_v else None
    target_entropy = (-float(act_size) if config.target_entropy is None
                      else float(config.target_entropy))
    log_alpha0 = jnp.asarray(math.log(config.init_temperature), jnp.float32)
    hidden = config.hidden_sizes
    actor = make_actor(config.actor, dynamics.metadata, act_size, hidden)
    bases = dataset_bases(actor, ds.observations, ds.next_observations)
    critic = QEnsemble(config.num_critics, hidden_sizes=hidden)
    actor_adam = optax.scale_by_adam()
    critic_opt = optax.adam(config.critic_lr)
    alpha_opt = optax.adam(config.alpha_lr)
    reward_opt = optax.adam(reward.lr)
    relative = config.pessimism == "relative"
    warm = config.warmstart_steps
    gamma, w, bsz = config.discount, config.dqra_weight, config.batch_size

    def init(key: jax.Array, beta: Any = None) -> ATACState:
        k_actor, k_critic, k_reward, k_run = jax.random.split(key, 4)
        params = {
            "actor": actor.init(k_actor, jnp.zeros((1, obs_size), jnp.float32)),
            "critic": critic.init(k_critic, jnp.zeros((1, obs_size), jnp.float32),
                                  jnp.zeros((1, act_size), jnp.float32)),
            "log_alpha": log_alpha0,
            "reward": reward.init(k_reward),
        }
        params["critic"] = project_frobenius(params["critic"], config.norm_bound)
        opt_states = {"actor": actor_adam.init(params["actor"]),
                      "critic": critic_opt.init(params["critic"]),
                      "alpha": alpha_opt.init(log_alpha0),
                      "reward": reward_opt.init(params["reward"])}
        b = config.beta if beta is None else beta
        return ATACState(params, params["critic"], opt_states, k_run,
                         jnp.zeros((), jnp.int32), jnp.asarray(b, jnp.float32))

    def step(state: ATACState, key: jax.Array) -> tuple[ATACState, dict]:
        in_warm = state.step < warm
        # The warm-start switch: fresh actor Adam moments, temperature reset.
        switch = state.step == warm
        fresh = (actor_adam.init(state.params["actor"]), log_alpha0, alpha_opt.init(log_alpha0))
        current = (state.opt_states["actor"], state.params["log_alpha"],
                   state.opt_states["alpha"])
        actor_os, log_alpha, alpha_os = jax.tree.map(
            lambda f, c: jnp.where(switch, f, c), fresh, current)

        k_batch, k_next, k_pi, k_reward = jax.random.split(key, 4)
        batch, base = odata.sample_with(ds, bases, k_batch, bsz)
        p = state.params
        a_next, _ = apply_actor(actor, p["actor"], batch.next_observations,
                                base.next_observations).sample(k_next)
        a_next = jax.lax.stop_gradient(a_next)
        pi = apply_actor(actor, p["actor"], batch.observations, base.observations)
        a_pi, logp_pi = pi.sample(k_pi)
        q_next_target = jnp.min(critic.apply(state.target_critic, batch.next_observations,
                                             a_next), axis=-1)

        def bellman(critic_params, rewards):
            q = critic.apply(critic_params, batch.observations, batch.actions)
            q_next = critic.apply(critic_params, batch.next_observations, a_next)
            return dqra_loss(q, q_next, q_next_target, rewards, batch.terminals, gamma, w,
                             bounds), q

        rewards = jax.lax.stop_gradient(reward.predict(p["reward"], batch))

        def critic_loss(critic_params):
            e, q = bellman(critic_params, rewards)
            q_pi = critic.apply(critic_params, batch.observations, jax.lax.stop_gradient(a_pi))
            pess = pessimism_loss(q_pi, q, relative)
            game = jnp.sum(combine(pess, e, state.beta))
            loss = jnp.where(in_warm, jnp.sum(e), game)
            return loss, {"bellman": jnp.mean(e), "pessimism": jnp.mean(pess),
                          "q_data": jnp.mean(q), "q_pi": jnp.mean(q_pi)}

        (c_loss, metrics), c_grad = jax.value_and_grad(critic_loss, has_aux=True)(p["critic"])
        metrics["critic_loss"] = c_loss
        new_params, new_os = dict(p), dict(state.opt_states)

        if reward.fit_loss is not None:
            frozen_critic = jax.lax.stop_gradient(p["critic"])

            def reward_loss(reward_params):
                fit = reward.fit_loss(reward_params, k_reward)
                e, _ = bellman(frozen_critic, reward.predict(reward_params, batch))
                # Algorithm 3 line 6 divided by α (Adam is invariant to the loss scale).
                return fit + state.beta / reward.weight(state.beta) * jnp.sum(e), fit

            (r_loss, fit), r_grad = jax.value_and_grad(reward_loss, has_aux=True)(p["reward"])
            upd, new_os["reward"] = reward_opt.update(r_grad, state.opt_states["reward"])
            new_params["reward"] = optax.apply_updates(p["reward"], upd)
            metrics.update(reward_loss=r_loss, reward_fit=fit)

        upd, new_os["critic"] = critic_opt.update(c_grad, state.opt_states["critic"])
        new_critic = project_frobenius(optax.apply_updates(p["critic"], upd), config.norm_bound)
        new_params["critic"] = new_critic
        new_target = polyak(state.target_critic, new_critic, config.tau)

        entropy = -jnp.mean(logp_pi)
        a_grad = jax.grad(lambda la: la * (jax.lax.stop_gradient(entropy) - target_entropy))(
            log_alpha)
        upd, new_os["alpha"] = alpha_opt.update(a_grad, alpha_os)
        new_params["log_alpha"] = optax.apply_updates(log_alpha, upd)
        alpha = jnp.exp(new_params["log_alpha"])

        def actor_loss(actor_params):
            dist = apply_actor(actor, actor_params, batch.observations, base.observations)

            def bc():
                return -jnp.mean(dist.log_prob(batch.actions))

            def game():
                a, logp = dist.sample(k_pi)
                q1 = critic.apply(new_critic, batch.observations, a)[..., 0]
                return combine(-jnp.mean(q1), jnp.mean(logp), alpha)

            return jax.lax.cond(in_warm, bc, game)

        act_loss, act_grad = jax.value_and_grad(actor_loss)(p["actor"])
        upd, new_os["actor"] = actor_adam.update(act_grad, actor_os)
        lr = jnp.where(in_warm, config.bc_lr, config.actor_lr)
        new_params["actor"] = jax.tree.map(lambda x, u: x - lr * u, p["actor"], upd)
        metrics.update(actor_loss=act_loss, alpha=alpha, entropy=entropy)
        new_state = ATACState(new_params, new_target, new_os, state.key, state.step, state.beta)
        return new_state, metrics

    def run(state: ATACState, n: int) -> tuple[ATACState, dict]:
        return scan_steps(step, state, n)

    return Trainer(init=init, run=run, act=policy_act(actor, scale, norm),
                   num_steps=config.num_steps)


def check_no_reward_data(reward_data: Any, learner: str) -> None:
    """Raise the API's clear error when a learner that uses no reward data is given some."""
    if reward_data is not None:
        raise ValueError(f"{learner} uses the rewards of the dynamics data and takes no "
                         f"reward_data (use offline.learners.mahalo or offline.learners.plfo_baselines for PLfO)")


def make_train(dynamics: odata.Dataset, config: ATACConfig, *,
               reward_data: scenarios.RewardData | None = None,
               reward_fn: Callable[[odata.Dataset], jax.Array] | None = None,
               normalizer: ObservationNormalizer | None = None) -> Trainer:
    """ATAC (``pessimism="relative"``) or PSPI (``"absolute"``) on ``dynamics`` (thesis §7.3.3,
    docs/design.md §4.5).

    The Bellman backups use ``dynamics.rewards`` or, when given, ``reward_fn(batch) -> (B,)``
    (a fixed reward model applied to each minibatch). Dynamics data of a PLfO scenario (its
    metadata says ``rewards_visible: false``) is refused without a ``reward_fn``: its rewards
    are hidden; the Oracle baseline (:func:`offline.learners.plfo_baselines.make_train_oracle`) reads
    them on purpose. ``normalizer``: the observation statistics when
    ``config.normalize_observations`` (default: those of ``dynamics``; :func:`make_core`).
    ``reward_fn`` receives minibatches with standardised states when the option is on.
    """
    check_no_reward_data(reward_data, "ATAC")
    if reward_fn is None:
        if dynamics.metadata.get("rewards_visible", True) is False:
            raise ValueError("dynamics has rewards_visible=False (PLfO dynamics data): ATAC "
                             "would read hidden rewards; pass reward_fn, or use "
                             "offline.learners.plfo_baselines.make_train_oracle")
        return make_core(dynamics, config, dataset_rewards(), normalizer=normalizer)
    if not callable(reward_fn):
        raise ValueError(f"reward_fn must be callable (batch -> rewards), got {reward_fn!r}")
    return make_core(dynamics, config, RewardModel(init=lambda key: {},
                                                   predict=lambda p, batch: reward_fn(batch)),
                     normalizer=normalizer)


__all__ = [
    "PESSIMISM",
    "ATACConfig",
    "ATACState",
    "RewardModel",
    "check_no_reward_data",
    "combine",
    "dataset_rewards",
    "dqra_loss",
    "make_core",
    "make_train",
    "pessimism_loss",
    "prepare_dataset",
    "value_bounds",
]
