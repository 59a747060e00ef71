"""Behaviour cloning (BC) and behaviour cloning from observation (BCO), the imitation
baselines of thesis §7.4 ("Baselines": BC for IL, BCO [Torabi et al., 2018] for ILfO; Tables
7.3-7.4) and §8.4 (the BC reference policy of Figs 8.4 and 8.7); docs/design.md §4.5.

**BC** maximises the tanh-Gaussian likelihood of the dataset actions,

    L(θ) = −E_{(s, a)∼D} log π_θ(a / action_limit | s),

with the actor of the offline learners (:class:`offline.learners.tanh_gaussian.TanhGaussianPolicy`,
3×256 ReLU, docs/design.md §4.5) and Adam. ``BCConfig.data`` chooses ``D``: ``"all"`` (the dynamics
data) or ``"reward_episodes"`` — only the dynamics episodes that also appear in the reward data
(same episode ids, :mod:`offline.data.scenarios`), i.e. the expert demonstrations of IL / RL-expert.

**BCO** clones actions the data does not have: an inverse-dynamics model
(:mod:`offline.learners.inverse_dynamics`) is trained on the dynamics data, labels the reward data's
transitions ``(s, s')`` with actions, and BC runs on the labelled reward data. Both stages are
one compiled program: ``init(key)`` trains the inverse model (its own ``lax.scan``) and labels
the data; ``run`` performs the BC steps. (Torabi et al. alternate the two stages with fresh
environment interaction — BCO(α); offline there is none, so this is BCO(0).)

With ``normalize_observations`` (of ``BCConfig``; BCO's inverse model has its own flag in
``InverseDynamicsConfig``) the actor sees states standardised with the statistics of the
**dynamics** data passed to ``make_train`` — also when it clones only the reward episodes or
BCO's labelled reward data (:class:`offline.learners.base.ObservationNormalizer`); ``act`` takes raw
observations.

``beta`` (the learner API's trade-off coefficient) is accepted and ignored: BC has none.
Defaults (our choice; the thesis gives none for BC): Adam lr 3e-4, batch 256, 100k steps (the
length of ATAC's BC warm start, docs/design.md §4.5).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from mjxrmp.config import check_bool, check_choice, check_float, check_int, check_parts
from offline.data import dataset as odata
from offline.data.scenarios import RewardData, validate_reward_data
from offline.learners.base import (
    Trainer,
    action_scale,
    adam_step,
    check_network,
    normalized_dataset,
    observation_normalizer,
    policy_act,
    scan_steps,
)
from offline.learners.inverse_dynamics import InverseDynamicsConfig, make_inverse_dynamics
from offline.learners.residual_actor import (
    ActorBases,
    apply_actor,
    check_actor,
    dataset_bases,
    make_actor,
)

#: Values of :attr:`BCConfig.data`.
BC_DATA = ("all", "reward_episodes")


@dataclasses.dataclass(frozen=True)
class BCConfig:
    """BC (module docstring). ``data``: ``"all"`` or ``"reward_episodes"`` (needs reward
    data); ``normalize_observations`` standardises the actor's states (default off);
    ``actor`` is the actor class (:data:`offline.learners.residual_actor.ACTORS`; default
    ``"mlp"``)."""

    hidden_sizes: tuple[int, ...] = (256, 256, 256)
    activation: str = "relu"
    learning_rate: float = 3e-4
    batch_size: int = 256
    num_steps: int = 100_000
    data: str = "all"
    normalize_observations: bool = False
    actor: str = "mlp"

    def __post_init__(self) -> None:
        n = type(self).__name__
        object.__setattr__(self, "hidden_sizes", check_network(self.hidden_sizes,
                                                               self.activation, f"{n}."))
        check_float(self.learning_rate, f"{n}.learning_rate")
        check_int(self.batch_size, f"{n}.batch_size")
        check_int(self.num_steps, f"{n}.num_steps")
        check_choice(self.data, f"{n}.data", BC_DATA)
        check_bool(self.normalize_observations, f"{n}.normalize_observations")
        check_actor(self.actor, self.normalize_observations)


@dataclasses.dataclass(frozen=True)
class BCOConfig:
    """BCO: ``bc`` for the cloning stage (its ``data`` must be ``"all"``: the labelled reward
    data is cloned) and ``inverse`` for the inverse-dynamics model."""

    bc: BCConfig = dataclasses.field(default_factory=BCConfig)
    inverse: InverseDynamicsConfig = dataclasses.field(default_factory=InverseDynamicsConfig)

    def __post_init__(self) -> None:
        check_parts(self, bc=BCConfig, inverse=InverseDynamicsConfig)
        if self.bc.data != "all":
            raise ValueError(f"bc.data must be 'all' for BCO (it clones the labelled reward "
                             f"data), got {self.bc.data!r}")


class BCState(NamedTuple):
    params: dict  # {"actor"}
    opt_state: Any
    key: jax.Array
    step: jax.Array


class BCOState(NamedTuple):
    params: dict  # {"actor", "inverse"}
    opt_state: Any
    key: jax.Array
    step: jax.Array
    labels: jax.Array  # (N_R, A) normalised actions the inverse model gave the reward data


def bc_loss(policy: nn.Module, actor_params: Any, observations: jax.Array,
            actions: jax.Array, base: jax.Array | None = None) -> tuple[jax.Array, dict]:
    """``(−mean log π(a|s), metrics)`` for normalised actions ``a`` in ``[−1, 1]`` (module
    docstring); metrics ``bc_loss`` and ``action_mse`` (mode vs data, normalised units).
    ``base``: the residual actor's precomputed RMP² base at ``observations``
    (:func:`offline.learners.residual_actor.dataset_bases`)."""
    dist = apply_actor(policy, actor_params, observations, base)
    loss = -jnp.mean(dist.log_prob(actions))
    mse = jnp.mean(jnp.sum(jnp.square(dist.mode() - actions), axis=-1))
    return loss, {"bc_loss": loss, "action_mse": mse}


def _bc_update(policy: nn.Module, optimizer: optax.GradientTransformation,
               batch_size: int, data_of: Callable[[Any], odata.Dataset], bases: ActorBases):
    """One BC step on a minibatch of ``data_of(state)`` (normalised actions; its observations
    are the same in every state, and ``bases`` holds the actor's base at them)."""

    def update(state, key):
        batch, base = odata.sample_with(data_of(state), bases, key, batch_size)

        def loss_fn(actor):
            return bc_loss(policy, actor, batch.observations, batch.actions, base.observations)

        (_, metrics), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params["actor"])
        actor, opt_state = adam_step(optimizer, state.params["actor"], state.opt_state, grads)
        return state._replace(params={**state.params, "actor": actor},
                              opt_state=opt_state), metrics

    return update


def reward_episodes(dynamics: odata.Dataset, reward_data: RewardData) -> odata.Dataset:
    """The dynamics episodes whose ids appear in the reward data (host-side)."""
    ids = np.unique(np.asarray(reward_data.episode_ids))
    per, _ = odata.episode_statistics(dynamics)
    keep = np.isin(per.episode_ids, ids)
    if not keep.any():
        raise ValueError("BCConfig.data='reward_episodes' but no dynamics episode id appears in "
                         "reward_data (the scenario's reward data does not overlap the dynamics "
                         "data: use BCO, or data='all')")
    return odata.filter_episodes(dynamics, keep)


def _make_bc(dynamics: odata.Dataset, config: BCConfig,
             reward_data: RewardData | None) -> Trainer:
    norm = observation_normalizer(dynamics, config.normalize_observations)
    if config.data == "reward_episodes":
        if reward_data is None:
            raise ValueError("BCConfig.data='reward_episodes' needs reward_data")
        dynamics = reward_episodes(odata.validate(dynamics, name="dynamics"),
                                    validate_reward_data(reward_data))
    elif reward_data is not None:
        raise ValueError("BC with data='all' uses no reward data; pass reward_data=None (or "
                         "BCConfig(data='reward_episodes') to clone only the reward episodes)")
    data, scale, _ = normalized_dataset(dynamics, "dynamics", config.normalize_observations, norm)
    policy = make_actor(config.actor, dynamics.metadata, dynamics.action_size,
                        config.hidden_sizes, config.activation)
    optimizer = optax.adam(config.learning_rate)

    def init(key: jax.Array, beta: Any = None) -> BCState:
        del beta  # BC has no trade-off coefficient
        k_init, k_run = jax.random.split(key)
        params = {"actor": policy.init(k_init, data.observations[:1])}
        return BCState(params, optimizer.init(params["actor"]), k_run,
                       jnp.zeros((), jnp.int32))

    update = _bc_update(policy, optimizer, config.batch_size, lambda state: data,
                        dataset_bases(policy, data.observations))

    def run(state: BCState, n: int):
        return scan_steps(update, state, n)

    return Trainer(init, run, policy_act(policy, scale, norm), config.num_steps)


def _make_bco(dynamics: odata.Dataset, config: BCOConfig,
              reward_data: RewardData | None) -> Trainer:
    if reward_data is None:
        raise ValueError("BCO needs reward_data (the observation-only data it clones)")
    validate_reward_data(reward_data)
    if reward_data.size == 0:
        raise ValueError("reward_data is empty (0 transitions)")
    if reward_data.observation_size != dynamics.observation_size:
        raise ValueError(f"reward_data observations have size {reward_data.observation_size}, "
                         f"dynamics {dynamics.observation_size}; they must match")
    inverse = make_inverse_dynamics(dynamics, config.inverse)
    rd = jax.device_put(reward_data)
    action_size = dynamics.action_size
    norm = observation_normalizer(dynamics, config.bc.normalize_observations)
    # The labelled reward data (states standardised for the actor); its actions are replaced by
    # the state's labels in each step.
    template = norm.apply_states(odata.Dataset(
        rd.observations, jnp.zeros((rd.size, action_size), jnp.float32), rd.rewards,
        rd.next_observations, rd.terminals, rd.timeouts, rd.episode_ids, rd.metadata))
    bc = config.bc
    policy = make_actor(bc.actor, dynamics.metadata, action_size, bc.hidden_sizes,
                        bc.activation)
    optimizer = optax.adam(bc.learning_rate)

    def init(key: jax.Array, beta: Any = None) -> BCOState:
        del beta  # BCO has no trade-off coefficient
        k_inv, k_init, k_run = jax.random.split(key, 3)
        model = inverse.model(inverse.train(k_inv)[0])
        labels = model.normalized(rd.observations, rd.next_observations)
        params = {"actor": policy.init(k_init, template.observations[:1]),
                  "inverse": model.params}
        return BCOState(params, optimizer.init(params["actor"]), k_run,
                        jnp.zeros((), jnp.int32), labels)

    update = _bc_update(policy, optimizer, bc.batch_size,
                        lambda state: template.replace(actions=state.labels),
                        dataset_bases(policy, template.observations))

    def run(state: BCOState, n: int):
        return scan_steps(update, state, n)

    return Trainer(init, run, policy_act(policy, action_scale(dynamics), norm), bc.num_steps)


def make_train(dynamics: odata.Dataset, config: BCConfig | BCOConfig = BCConfig(), *,
               reward_data: RewardData | None = None) -> Trainer:
    """The learner API (:mod:`offline.learners.base`) for BC (``BCConfig``) or BCO (``BCOConfig``).

    BC reads only ``dynamics`` (``reward_data`` must be None) unless
    ``config.data == "reward_episodes"``; BCO needs ``reward_data``. States hold
    ``params["actor"]``; metrics per step: ``bc_loss``, ``action_mse``.
    """
    if isinstance(config, BCOConfig):
        return _make_bco(dynamics, config, reward_data)
    if isinstance(config, BCConfig):
        return _make_bc(dynamics, config, reward_data)
    raise ValueError(f"config must be a BCConfig or a BCOConfig, got {type(config).__name__}")


__all__ = ["BC_DATA", "BCConfig", "BCOConfig", "BCOState", "BCState", "bc_loss", "make_train",
           "reward_episodes"]
