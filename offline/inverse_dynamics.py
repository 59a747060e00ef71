"""Inverse-dynamics model ``a ≈ f(s, s')`` for learning from observations (thesis §7.4
"Baselines": BCO [Torabi et al., 2018] and action prediction AP; ANCHOR_FACTS §5), and the
gradient-step plumbing shared by this package's baselines (BC, BCO, IQL, CQL).

**Model.** ``f(s, s') = action_limit · tanh(MLP([s, s' − s]))`` — an MLP (3×256 ReLU by
default, :class:`agents.networks.MLP`) on the state and the state change, bounded by ``tanh`` to
the action box. Feeding ``s' − s`` rather than ``s'`` is our choice (the thesis and ANCHOR_FACTS
give no architecture): for control-affine dynamics such as ``s' = s + B a`` the target is then a
function of the input's second half alone. It is trained by least squares on the dynamics data's
actions divided by the action limit (so targets lie in ``[−1, 1]``), in one ``lax.scan`` of
Adam steps (:func:`make_inverse_dynamics`); training is jittable and vmappable over seeds.

**Labelling.** :func:`label_actions` gives reward data (:class:`offline.scenarios.RewardData`,
no actions) the model's predicted actions and returns an :class:`offline.data.Dataset` — the
input of BCO (:mod:`offline.bc`) and of AP (labelled expert data appended to the dynamics data
with :func:`offline.data.concatenate`, then ATAC)::

    inv = make_inverse_dynamics(dynamics, InverseDynamicsConfig())
    state, _ = jax.jit(inv.train)(key)
    labelled = label_actions(inv.model(state), reward_data)
    ap_data = offline.data.concatenate(dynamics, labelled)   # host-side

**Shared plumbing** (used by :mod:`offline.bc`, :mod:`offline.iql`, :mod:`offline.cql`):
:func:`scan_steps` (the learner API's ``run``: ``n`` steps in one ``lax.scan``, step ``t``'s key
``fold_in(state.key, state.step)``, so ``run(run(s, a), b) == run(s, a + b)``),
:func:`normalized_dataset` (validated, on the device, actions divided by the action limit),
:func:`policy_act` (deterministic tanh-Gaussian action in environment units) and the config
validators.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from agents.networks import MLP, activation_fn
from offline import data as odata
from offline.learner import action_scale
from offline.scenarios import RewardData
from offline.tanh_gaussian import TanhGaussianPolicy

# --------------------------------------------------------------------------------------------
# Config validators (bad input -> ValueError naming the argument)


def check_positive_int(value: Any, name: str) -> int:
    """``value`` as an ``int`` if it is a positive integer (not a bool), else ``ValueError``."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def check_positive_float(value: Any, name: str) -> float:
    """``value`` as a ``float`` if it is a finite number > 0, else ``ValueError``."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.number) or not (
            np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return float(value)


def check_fraction(value: Any, name: str, *, closed: bool = False) -> float:
    """``value`` as a ``float`` if it lies in ``(0, 1)`` (``(0, 1]`` when ``closed``)."""
    ok = (not isinstance(value, bool) and isinstance(value, int | float | np.number)
          and value > 0.0 and (value <= 1.0 if closed else value < 1.0))
    if not ok:
        raise ValueError(f"{name} must lie in (0, 1{']' if closed else ')'}, got {value!r}")
    return float(value)


def check_network(hidden_sizes: Any, activation: Any, prefix: str = "") -> tuple[int, ...]:
    """Validated hidden sizes (a non-empty sequence of positive ints) and activation name."""
    name = f"{prefix}hidden_sizes"
    if isinstance(hidden_sizes, str | bytes) or not isinstance(hidden_sizes, Sequence) or (
            len(hidden_sizes) == 0):
        raise ValueError(f"{name} must be a non-empty sequence of positive integers, got "
                         f"{hidden_sizes!r}")
    sizes = tuple(check_positive_int(h, f"{name}[{i}]") for i, h in enumerate(hidden_sizes))
    activation_fn(activation)
    return sizes


# --------------------------------------------------------------------------------------------
# Shared training plumbing


def scan_steps(update: Callable[[Any, jax.Array], tuple[Any, dict]], state: Any,
               n: int) -> tuple[Any, dict]:
    """``n`` (static) applications of ``update(state, key_t) -> (state, metrics)`` in one
    ``lax.scan``, with ``key_t = fold_in(state.key, state.step)`` and ``state.step`` incremented
    after each; metrics get a leading axis ``n``. ``state`` is a NamedTuple with ``key`` and
    ``step`` fields. Splitting ``n`` over several calls gives the same result."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
        raise ValueError(f"n (number of gradient steps) must be a static integer >= 0, got {n!r}")

    def body(s, _):
        s, metrics = update(s, jax.random.fold_in(s.key, s.step))
        return s._replace(step=s.step + 1), metrics

    return jax.lax.scan(body, state, None, length=int(n))


def normalized_dataset(dataset: odata.Dataset, name: str = "dynamics"
                       ) -> tuple[odata.Dataset, float]:
    """``(dataset on the device with actions / action_limit, action_limit)`` after
    :func:`offline.data.validate`; an empty dataset is refused."""
    odata.validate(dataset, name=name)
    if dataset.size == 0:
        raise ValueError(f"{name} is empty (0 transitions)")
    scale = action_scale(dataset)
    actions = np.asarray(dataset.actions) / np.asarray(scale, np.asarray(dataset.actions).dtype)
    return jax.device_put(dataset.replace(actions=actions)), scale


def policy_act(policy: TanhGaussianPolicy, scale: float) -> Callable[[Any, jax.Array], jax.Array]:
    """The learner API's ``act(actor_params, obs)``: ``action_limit · tanh(μ(obs))``."""

    def act(params: Any, obs: jax.Array) -> jax.Array:
        return scale * policy.apply(params, obs).mode()

    return act


def adam_step(optimizer: optax.GradientTransformation, params: Any, opt_state: Any,
              grads: Any) -> tuple[Any, Any]:
    """One optimiser step: ``(new_params, new_opt_state)``."""
    updates, opt_state = optimizer.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state


# --------------------------------------------------------------------------------------------
# Inverse dynamics


@dataclasses.dataclass(frozen=True)
class InverseDynamicsConfig:
    """Inverse-dynamics regression (our defaults; the thesis gives none): 3×256 ReLU, Adam
    lr 3e-4, batch 256, 100k steps (as long as ATAC's BC warm start, ANCHOR_FACTS §5)."""

    hidden_sizes: tuple[int, ...] = (256, 256, 256)
    activation: str = "relu"
    learning_rate: float = 3e-4
    batch_size: int = 256
    num_steps: int = 100_000

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden_sizes", check_network(self.hidden_sizes,
                                                               self.activation))
        check_positive_float(self.learning_rate, "learning_rate")
        check_positive_int(self.batch_size, "batch_size")
        check_positive_int(self.num_steps, "num_steps")


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
    """A trained inverse-dynamics model: a pytree whose only leaves are ``params`` (so it can
    be vmapped over seeds); ``model(obs, next_obs)`` predicts actions in environment units."""

    params: Any
    config: InverseDynamicsConfig
    action_size: int
    action_scale: float

    def normalized(self, obs: jax.Array, next_obs: jax.Array) -> jax.Array:
        """Predicted actions divided by the action limit, in ``[−1, 1]^A``."""
        net = InverseDynamicsNet(self.action_size, self.config.hidden_sizes,
                                 self.config.activation)
        return net.apply(self.params, obs, next_obs)

    def __call__(self, obs: jax.Array, next_obs: jax.Array) -> jax.Array:
        return self.action_scale * self.normalized(obs, next_obs)


jax.tree_util.register_dataclass(InverseModel, data_fields=["params"],
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
    """Least-squares regression of the normalised dataset actions on ``(s, s')``:
    loss ``mean ‖f(s, s') − a/action_limit‖²`` over minibatches drawn with
    :func:`offline.data.sample`; metric ``loss`` per step. ``dynamics`` is closed over as
    device arrays."""
    if not isinstance(config, InverseDynamicsConfig):
        raise ValueError(f"config must be an InverseDynamicsConfig, got "
                         f"{type(config).__name__}")
    data, scale = normalized_dataset(dynamics)
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
        return InverseModel(state.params["inverse"], config, dynamics.action_size, scale)

    return InverseDynamicsTrainer(init, run, model, config.num_steps)


def label_actions(model: InverseModel, reward_data: RewardData) -> odata.Dataset:
    """Reward data with the actions ``model(s, s')`` predicts (environment units): a
    :class:`~offline.data.Dataset` with the reward data's states, rewards, flags and episode
    ids, ``metadata["action_labels"] = "inverse_dynamics"`` and the model's
    ``action_limit``. Jittable and vmappable over ``model`` (seeds)."""
    if not isinstance(model, InverseModel):
        raise ValueError(f"model must be an InverseModel, got {type(model).__name__}")
    if not isinstance(reward_data, RewardData):
        raise ValueError(f"reward_data must be an offline.scenarios.RewardData, got "
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
    "adam_step",
    "check_fraction",
    "check_network",
    "check_positive_float",
    "check_positive_int",
    "label_actions",
    "make_inverse_dynamics",
    "normalized_dataset",
    "policy_act",
    "scan_steps",
]
