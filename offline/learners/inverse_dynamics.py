"""Inverse-dynamics model ``a ≈ f(s, s')`` for learning from observations (thesis §7.4
"Baselines": BCO [Torabi et al., 2018] and action prediction AP; docs/design.md §4.5).

**Model.** ``f(s, s') = action_limit · tanh(MLP([s, s' − s]))`` — an MLP (3×256 ReLU by
default, :class:`agents.ppo.networks.MLP`) on the state and the state change, bounded by ``tanh`` to
the action box. Feeding ``s' − s`` rather than ``s'`` is our choice (the thesis and the original
implementation give no architecture): for control-affine dynamics such as ``s' = s + B a`` the
target is then a function of the input's second half alone. It is trained by least squares on the
dynamics data's actions divided by the action limit (so targets lie in ``[−1, 1]``), in one
``lax.scan`` of Adam steps (:func:`make_inverse_dynamics`); training is jittable and vmappable over
seeds. With ``normalize_observations`` both ``s`` and ``s'`` are standardised with the training
(dynamics) data's statistics (:class:`offline.learners.base.ObservationNormalizer`) before the
network — the trained :class:`InverseModel` carries that normalizer and takes raw states, so
labelling reward data standardises its states with the dynamics statistics.

**Labelling.** :func:`label_actions` gives reward data (:class:`offline.data.scenarios.RewardData`,
no actions) the model's predicted actions and returns an :class:`offline.data.dataset.Dataset` — the
input of BCO (:mod:`offline.learners.bc`) and of AP (labelled expert data appended to the dynamics
data with :func:`offline.data.dataset.concatenate`, then ATAC)::

    inv = make_inverse_dynamics(dynamics, InverseDynamicsConfig())
    state, _ = jax.jit(inv.train)(key)
    labelled = label_actions(inv.model(state), reward_data)
    ap_data = offline.data.dataset.concatenate(dynamics, labelled)   # host-side
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from agents.ppo.networks import MLP
from mjxrmp.config import check_bool, check_float, check_int
from offline.data import dataset as odata
from offline.data.scenarios import RewardData
from offline.learners.base import (
    ObservationNormalizer,
    adam_step,
    check_network,
    normalized_dataset,
    scan_steps,
)

# --------------------------------------------------------------------------------------------
# Inverse dynamics


@dataclasses.dataclass(frozen=True)
class InverseDynamicsConfig:
    """Inverse-dynamics regression (our defaults; the thesis gives none): 3×256 ReLU, Adam
    lr 3e-4, batch 256, 100k steps (as long as ATAC's BC warm start, docs/design.md §4.5);
    ``normalize_observations`` standardises the states (module docstring; default off)."""

    hidden_sizes: tuple[int, ...] = (256, 256, 256)
    activation: str = "relu"
    learning_rate: float = 3e-4
    batch_size: int = 256
    num_steps: int = 100_000
    normalize_observations: bool = False

    def __post_init__(self) -> None:
        n = type(self).__name__
        object.__setattr__(self, "hidden_sizes", check_network(self.hidden_sizes,
                                                               self.activation, f"{n}."))
        check_float(self.learning_rate, f"{n}.learning_rate")
        check_int(self.batch_size, f"{n}.batch_size")
        check_int(self.num_steps, f"{n}.num_steps")
        check_bool(self.normalize_observations, f"{n}.normalize_observations")


class InverseDynamicsNet(nn.Module):
    """``tanh(MLP([s, s' − s]))`` in ``[−1, 1]^A`` (normalised actions)."""

    action_size: int
    hidden_sizes: Sequence[int] = (256, 256, 256)
    activation: str = "relu"

    @nn.compact
    def __call__(self, obs: jax.Array, next_obs: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs, next_obs - obs], axis=-1)
        return jnp.tanh(MLP(tuple(self.hidden_sizes), self.action_size, self.activation, 1.0,
                            name="mlp")(x))


@dataclasses.dataclass(frozen=True)
class InverseModel:
    """A trained inverse-dynamics model: a pytree whose leaves are ``params`` and the arrays of
    its observation ``normalizer`` (none when it is the identity), so it can be vmapped over
    seeds; ``model(obs, next_obs)`` predicts actions in environment units from raw states."""

    params: Any
    config: InverseDynamicsConfig
    action_size: int
    action_scale: float
    normalizer: ObservationNormalizer

    def normalized(self, obs: jax.Array, next_obs: jax.Array) -> jax.Array:
        """Predicted actions divided by the action limit, in ``[−1, 1]^A`` (raw states in)."""
        net = InverseDynamicsNet(self.action_size, self.config.hidden_sizes,
                                 self.config.activation)
        norm = self.normalizer
        return net.apply(self.params, norm.apply(obs), norm.apply(next_obs))

    def __call__(self, obs: jax.Array, next_obs: jax.Array) -> jax.Array:
        return self.action_scale * self.normalized(obs, next_obs)


jax.tree_util.register_dataclass(InverseModel, data_fields=["params", "normalizer"],
                                 meta_fields=["config", "action_size", "action_scale"])


class InverseDynamicsState(NamedTuple):
    params: dict
    opt_state: Any
    key: jax.Array
    step: jax.Array


class InverseDynamicsTrainer(NamedTuple):
    """``init(key) -> state``; ``run(state, n) -> (state, metrics)``; ``model(state) ->``
    :class:`InverseModel`; ``num_steps`` the config's; ``train(key)`` runs them."""

    init: Callable[[jax.Array], InverseDynamicsState]
    run: Callable[[InverseDynamicsState, int], tuple[InverseDynamicsState, dict]]
    model: Callable[[InverseDynamicsState], InverseModel]
    num_steps: int

    def train(self, key: jax.Array) -> tuple[InverseDynamicsState, dict]:
        return self.run(self.init(key), self.num_steps)


def make_inverse_dynamics(dynamics: odata.Dataset,
                          config: InverseDynamicsConfig = InverseDynamicsConfig()
                          ) -> InverseDynamicsTrainer:
    """Least-squares regression of the normalised dataset actions on ``(s, s')`` (standardised
    when ``config.normalize_observations``): loss ``mean ‖f(s, s') − a/action_limit‖²`` over
    minibatches drawn with :func:`offline.data.dataset.sample`; metric ``loss`` per step.
    ``dynamics`` is closed over as device arrays."""
    if not isinstance(config, InverseDynamicsConfig):
        raise ValueError(f"config must be an InverseDynamicsConfig, got "
                         f"{type(config).__name__}")
    data, scale, norm = normalized_dataset(dynamics, "dynamics", config.normalize_observations)
    if dynamics.action_size == 0:
        raise ValueError("dynamics has no action dimensions (action_size 0)")
    net = InverseDynamicsNet(dynamics.action_size, config.hidden_sizes, config.activation)
    optimizer = optax.adam(config.learning_rate)

    def init(key: jax.Array) -> InverseDynamicsState:
        k_init, k_run = jax.random.split(key)
        obs = data.observations[:1]
        params = {"inverse": net.init(k_init, obs, obs)}
        return InverseDynamicsState(params, optimizer.init(params), k_run,
                                    jnp.zeros((), jnp.int32))

    def update(state: InverseDynamicsState, key: jax.Array):
        batch = odata.sample(data, key, config.batch_size)

        def loss_fn(params):
            pred = net.apply(params["inverse"], batch.observations, batch.next_observations)
            return jnp.mean(jnp.sum(jnp.square(pred - batch.actions), axis=-1))

        loss, grads = jax.value_and_grad(loss_fn)(state.params)
        params, opt_state = adam_step(optimizer, state.params, state.opt_state, grads)
        return state._replace(params=params, opt_state=opt_state), {"loss": loss}

    def run(state: InverseDynamicsState, n: int):
        return scan_steps(update, state, n)

    def model(state: InverseDynamicsState) -> InverseModel:
        return InverseModel(state.params["inverse"], config, dynamics.action_size, scale, norm)

    return InverseDynamicsTrainer(init, run, model, config.num_steps)


def label_actions(model: InverseModel, reward_data: RewardData) -> odata.Dataset:
    """Reward data with the actions ``model(s, s')`` predicts (environment units): a
    :class:`~offline.data.dataset.Dataset` with the reward data's states, rewards, flags and episode
    ids, ``metadata["action_labels"] = "inverse_dynamics"`` and the model's
    ``action_limit``. Jittable and vmappable over ``model`` (seeds)."""
    if not isinstance(model, InverseModel):
        raise ValueError(f"model must be an InverseModel, got {type(model).__name__}")
    if not isinstance(reward_data, RewardData):
        raise ValueError(f"reward_data must be an offline.data.scenarios.RewardData, got "
                         f"{type(reward_data).__name__}")
    actions = model(reward_data.observations, reward_data.next_observations)
    meta = reward_data.metadata.updated(action_labels="inverse_dynamics",
                                        action_limit=float(model.action_scale))
    return odata.Dataset(reward_data.observations, actions, reward_data.rewards,
                         reward_data.next_observations, reward_data.terminals,
                         reward_data.timeouts, reward_data.episode_ids, meta)


__all__ = [
    "InverseDynamicsConfig",
    "InverseDynamicsNet",
    "InverseDynamicsState",
    "InverseDynamicsTrainer",
    "InverseModel",
    "label_actions",
    "make_inverse_dynamics",
]
