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
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from mjxrmp.config import check_bool, check_choice, check_finite, check_float, check_int
from offline.data import dataset as odata
from offline.data import scenarios
from offline.learners.atac_losses import value_bounds
from offline.learners.atac_step import (
    ATACCore,
    ATACState,
    RewardModel,
    dataset_rewards,
    run_steps,
)
from offline.learners.base import (
    ObservationNormalizer,
    Trainer,
    action_scale,
    check_network,
    normalized_dataset,
    observation_normalizer,
    policy_act,
)
from offline.learners.networks import FROBENIUS_BOUND, QEnsemble, project_frobenius
from offline.learners.residual_actor import check_actor, dataset_bases, make_actor

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
    ``actor`` is the actor class (:data:`offline.learners.residual_actor.ACTORS`; default
    ``"mlp"``). ``block_steps`` and ``unroll`` set how the steps run, not what they compute
    (:func:`offline.learners.atac_step.run_steps`: the randomness of ``block_steps`` steps drawn
    at once, an inner loop unrolled ``unroll`` times); they change results only by float
    rounding.
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
    block_steps: int = 8
    unroll: int = 1

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden_sizes", tuple(self.hidden_sizes))
        n = type(self).__name__
        object.__setattr__(self, "hidden_sizes", check_network(self.hidden_sizes, None, f"{n}."))
        for name in ("num_critics", "batch_size", "num_steps", "block_steps", "unroll"):
            check_int(getattr(self, name), f"{n}.{name}")
        check_int(self.warmstart_steps, f"{n}.warmstart_steps", minimum=0)
        for name in ("critic_lr", "actor_lr", "alpha_lr", "bc_lr", "init_temperature",
                     "norm_bound"):
            check_float(getattr(self, name), f"{n}.{name}")
        check_float(self.beta, f"{n}.beta", allow_zero=True)
        for name in ("tau", "dqra_weight"):
            if check_float(getattr(self, name), f"{n}.{name}", allow_zero=True) > 1.0:
                raise ValueError(f"{n}.{name} must lie in [0, 1], got {getattr(self, name)!r}")
        if check_float(self.discount, f"{n}.discount", allow_zero=True) >= 1.0:
            raise ValueError(f"{n}.discount must lie in [0, 1), got {self.discount!r}")
        check_finite(self.target_entropy, f"{n}.target_entropy", allow_none=True)
        check_choice(self.pessimism, f"{n}.pessimism", PESSIMISM)
        for name in ("remove_terminals", "clip_v", "normalize_observations"):
            check_bool(getattr(self, name), f"{n}.{name}")
        check_actor(self.actor, self.normalize_observations)


# --------------------------------------------------------------------------------------------
# The core


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
    core = build_core(dynamics, config, reward, reward_range, norm)
    obs_size, act_size = core.ds.observation_size, core.ds.action_size

    def init(key: jax.Array, beta: Any = None) -> ATACState:
        k_actor, k_critic, k_reward, k_run = jax.random.split(key, 4)
        params = {
            "actor": core.actor.init(k_actor, jnp.zeros((1, obs_size), jnp.float32)),
            "critic": core.critic.init(k_critic, jnp.zeros((1, obs_size), jnp.float32),
                                       jnp.zeros((1, act_size), jnp.float32)),
            "log_alpha": core.log_alpha0,
            "reward": reward.init(k_reward),
        }
        params["critic"] = project_frobenius(params["critic"], config.norm_bound)
        opt_states = {"actor": core.actor_adam.init(params["actor"]),
                      "critic": core.critic_opt.init(params["critic"]),
                      "alpha": core.alpha_opt.init(core.log_alpha0),
                      "reward": core.reward_opt.init(params["reward"])}
        b = config.beta if beta is None else beta
        return ATACState(params, params["critic"], opt_states, k_run,
                         jnp.zeros((), jnp.int32), jnp.asarray(b, jnp.float32))

    def run(state: ATACState, n: int) -> tuple[ATACState, dict]:
        return run_steps(core, state, n)

    return Trainer(init=init, run=run, act=policy_act(core.actor, scale, norm),
                   num_steps=config.num_steps)


def build_core(dynamics: odata.Dataset, config: ATACConfig, reward: RewardModel,
               reward_range: tuple[float, float] | None = None,
               norm: ObservationNormalizer | None = None) -> ATACCore:
    """The prepared data, networks, optimisers and constants of :func:`make_core` (what
    :func:`offline.learners.atac_step.atac_step` takes); ``norm``: the observation normalizer
    in use (None: the identity)."""
    ds = prepare_dataset(dynamics, config.remove_terminals, norm)
    if reward_range is None and config.clip_v:
        r = np.asarray(ds.rewards)
        reward_range = (float(r.min()), float(r.max()))
    actor = make_actor(config.actor, dynamics.metadata, ds.action_size, config.hidden_sizes)
    return ATACCore(
        config=config, reward=reward, ds=ds,
        bases=dataset_bases(actor, ds.observations, ds.next_observations), actor=actor,
        critic=QEnsemble(config.num_critics, hidden_sizes=config.hidden_sizes),
        actor_adam=optax.scale_by_adam(), critic_opt=optax.adam(config.critic_lr),
        alpha_opt=optax.adam(config.alpha_lr), reward_opt=optax.adam(reward.lr),
        bounds=value_bounds(*reward_range, config.discount) if config.clip_v else None,
        target_entropy=(-float(ds.action_size) if config.target_entropy is None
                        else float(config.target_entropy)),
        log_alpha0=jnp.asarray(math.log(config.init_temperature), jnp.float32))


def check_no_reward_data(reward_data: Any, learner: str) -> None:
    """Raise the API's clear error when a learner that uses no reward data is given some."""
    if reward_data is not None:
        raise ValueError(f"{learner} uses the rewards of the dynamics data and takes no "
                         f"reward_data (use offline.learners.mahalo or "
                         f"offline.learners.plfo_baselines for PLfO)")


def make_train(dynamics: odata.Dataset, config: ATACConfig, *,
               reward_data: scenarios.RewardData | None = None,
               reward_fn: Callable[[odata.Dataset], jax.Array] | None = None,
               normalizer: ObservationNormalizer | None = None) -> Trainer:
    """ATAC (``pessimism="relative"``) or PSPI (``"absolute"``) on ``dynamics`` (thesis §7.3.3,
    docs/design.md §4.5).

    The Bellman backups use ``dynamics.rewards`` or, when given, ``reward_fn(batch) -> (B,)``
    (a fixed reward model applied to each minibatch). Dynamics data of a PLfO scenario (its
    metadata says ``rewards_visible: false``) is refused without a ``reward_fn``: its rewards
    are hidden; the Oracle baseline (:func:`offline.learners.plfo_baselines.make_train_oracle`)
    reads them on purpose. ``normalizer``: the observation statistics when
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
    "build_core",
    "check_no_reward_data",
    "dataset_rewards",
    "make_core",
    "make_train",
    "prepare_dataset",
]
