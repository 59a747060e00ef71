"""The interface shared by every offline learner (thesis chapter 7; ATAC, PSPI, MAHALO, IQL, …).

A learner module ``offline/<name>.py`` exposes a frozen, validated ``<Name>Config`` and
``make_train(dynamics, config, *, reward_data=None) -> Trainer``. A :class:`Trainer` bundles pure
functions over a learner-specific state (a NamedTuple whose ``params`` dict holds ``"actor"``):

* ``init(key, beta=None) -> state`` — ``beta`` is the learner's trade-off coefficient (ATAC's
  Bellman weight β, MAHALO's β, …) passed as a traced scalar so ``jax.vmap`` over β works;
  ``None`` means the config's value; learners without one accept and ignore it.
* ``run(state, n) -> (state, metrics)`` — ``n`` (static) gradient steps in one ``lax.scan``;
  every metric has leading axis ``n``. The randomness of step ``t`` is derived from the state's
  key and its step counter, so ``run(run(s, a)[0], b)`` equals ``run(s, a + b)``.
* ``act(params, obs) -> action`` — the deterministic action (tanh mode) in *environment* units,
  i.e. multiplied by :func:`action_scale`; ``obs`` is ``(O,)`` or ``(..., O)``.
* ``num_steps`` — the config's default total number of gradient steps;
  ``train(key, beta=None)`` runs them from ``init`` (``jax.jit(jax.vmap(trainer.train))(keys)``
  trains several seeds in one program).

Learners divide the dataset's actions by :func:`action_scale` so that they lie in ``[−1, 1]``,
the tanh-Gaussian's range.

Shared plumbing of the learners: :func:`scan_steps` (``run``: ``n`` steps in one ``lax.scan``,
step ``t``'s key ``fold_in(state.key, state.step)``, so ``run(run(s, a), b) == run(s, a + b)``),
:func:`normalized_dataset` (validated, on the device, actions divided by the action limit),
:func:`policy_act` (deterministic tanh-Gaussian action in environment units), :func:`adam_step`
and the config validators (bad input → ``ValueError`` naming the argument).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import numpy as np
import optax

from agents.networks import activation_fn
from offline import data as odata
from offline.data import Dataset
from offline.tanh_gaussian import TanhGaussianPolicy


class Trainer(NamedTuple):
    """Pure training functions of one offline learner (see the module docstring)."""

    init: Callable[..., Any]
    run: Callable[[Any, int], tuple[Any, dict]]
    act: Callable[[Any, jax.Array], jax.Array]
    num_steps: int

    def train(self, key: jax.Array, beta: Any = None) -> tuple[Any, dict]:
        """``run(init(key, beta), num_steps)``: a full training run from scratch."""
        return self.run(self.init(key, beta), self.num_steps)


def actor_params(state: Any) -> Any:
    """The actor's parameters of a learner state (``state.params["actor"]``), as ``act`` takes."""
    return state.params["actor"]


def action_scale(dataset: Dataset) -> float:
    """The environment's action limit recorded in the dataset (``metadata["action_limit"]``,
    default 1): dataset actions divided by it lie in ``[−1, 1]``."""
    scale = float(dataset.metadata.get("action_limit", 1.0))
    if not scale > 0.0:
        raise ValueError(f"dataset.metadata['action_limit'] must be positive, got {scale!r}")
    return scale


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



__all__ = [
    "Trainer",
    "action_scale",
    "actor_params",
    "adam_step",
    "check_fraction",
    "check_network",
    "check_positive_float",
    "check_positive_int",
    "normalized_dataset",
    "policy_act",
    "scan_steps",
]
