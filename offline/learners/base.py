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
  i.e. multiplied by :func:`action_scale`; ``obs`` is ``(O,)`` or ``(..., O)``, a *raw*
  environment observation (a learner that standardises observations does so inside ``act``).
* ``num_steps`` — the config's default total number of gradient steps;
  ``train(key, beta=None)`` runs them from ``init`` (``jax.jit(jax.vmap(trainer.train))(keys)``
  trains several seeds in one program).

Learners divide the dataset's actions by :func:`action_scale` so that they lie in ``[−1, 1]``,
the tanh-Gaussian's range.

Shared plumbing of the learners: :func:`scan_steps` (``run``: ``n`` steps in one ``lax.scan``,
step ``t``'s key ``fold_in(state.key, state.step)``, so ``run(run(s, a), b) == run(s, a + b)``),
:func:`normalized_dataset` (validated, on the device, actions divided by the action limit,
observations optionally standardised), :func:`policy_act` (deterministic tanh-Gaussian action in
environment units), :func:`adam_step` and :func:`check_network` (the configs validate their other
fields with :mod:`mjxrmp.config`'s validators: bad input → ``ValueError`` naming the field).

**Observation standardisation** (every learner's ``normalize_observations`` option, default
off): :class:`ObservationNormalizer` ``(s − μ) / σ`` with the per-feature mean ``μ`` and standard
deviation ``σ`` (floored at :data:`STD_FLOOR`) of the **dynamics data's** ``observations`` (its
``next_observations`` are left out of the statistics: they repeat the observations shifted by
one step). Every state that enters a network — actor, critics, value, reward network (on the
reward data too), inverse-dynamics model — is standardised with the same statistics, and
``act`` standardises the raw environment observation itself. Off, the normalizer is the
identity and nothing is computed: results are bit-identical to a learner without the option.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import numpy as np
import optax

from agents.ppo.networks import activation_fn
from mjxrmp.config import check_bool, check_sizes
from offline.data import dataset as odata
from offline.data.dataset import Dataset

#: Floor of the standard deviation used by :class:`ObservationNormalizer` (constant features).
STD_FLOOR = 1e-3


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
# Network settings


def check_network(hidden_sizes: Any, activation: Any, prefix: str = "") -> tuple[int, ...]:
    """Validated hidden sizes (a non-empty sequence of positive ints) and activation name
    (``None``: the network has no activation setting); names start with ``prefix``."""
    sizes = check_sizes(hidden_sizes, f"{prefix}hidden_sizes")
    if activation is not None:
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


class ObservationNormalizer(NamedTuple):
    """Per-feature standardisation ``(s − mean) / std`` of observations (module docstring).

    ``mean`` / ``std`` are float32 NumPy arrays ``(O,)``, or both ``None`` for the identity
    (the option off): then :meth:`apply` returns its input unchanged (the same object). A
    pytree (a NamedTuple), so it can be closed over or carried inside jitted / vmapped code.
    """

    mean: np.ndarray | None = None
    std: np.ndarray | None = None

    @classmethod
    def fit(cls, data: odata.TransitionTable) -> ObservationNormalizer:
        """Mean and standard deviation (floored at :data:`STD_FLOOR`) of ``data.observations``
        (a :class:`~offline.data.dataset.Dataset` or reward data), computed host-side in float64 and
        stored as float32. The observations must be concrete (not traced), finite and at
        least one row."""
        obs = data.observations
        if isinstance(obs, jax.core.Tracer):
            raise ValueError("observation statistics need concrete observations, got traced "
                             "ones (only rewards may be traced)")
        obs = np.asarray(obs, np.float64)
        if obs.ndim != 2 or obs.shape[0] == 0 or not np.isfinite(obs).all():
            raise ValueError(f"observations must be a finite (N >= 1, O) array to standardise, "
                             f"got shape {obs.shape}")
        std = np.maximum(obs.std(axis=0), STD_FLOOR)
        return cls(obs.mean(axis=0).astype(np.float32), std.astype(np.float32))

    @property
    def enabled(self) -> bool:
        """Whether this normalizer standardises (False for the identity)."""
        return self.mean is not None

    def apply(self, obs: Any) -> Any:
        """``(obs − mean) / std`` over the last axis (``obs`` itself for the identity); NumPy in,
        NumPy out (host-side data), JAX in, JAX out (inside traced code)."""
        if not self.enabled:
            return obs
        return (obs - self.mean) / self.std

    def apply_states(self, data: odata.TransitionTable) -> odata.TransitionTable:
        """``data`` (a dataset or reward data) with ``observations`` and ``next_observations``
        standardised (``data`` itself for the identity)."""
        if not self.enabled:
            return data
        return data.replace(observations=self.apply(data.observations),
                            next_observations=self.apply(data.next_observations))


def observation_normalizer(data: odata.TransitionTable, normalize_observations: bool,
                           normalizer: ObservationNormalizer | None = None
                           ) -> ObservationNormalizer:
    """The normalizer a learner uses on ``data`` (its dynamics data): off, the identity
    (``normalizer`` must then be None or the identity); on, ``normalizer`` if given (the
    statistics of the dynamics data that ``data`` was derived from, e.g. AP's labelled reward
    data), else :meth:`ObservationNormalizer.fit` on ``data``."""
    if not check_bool(normalize_observations, "normalize_observations"):
        if normalizer is not None and normalizer.enabled:
            raise ValueError("normalizer is given but normalize_observations is False")
        return ObservationNormalizer()
    if normalizer is None:
        return ObservationNormalizer.fit(data)
    if not isinstance(normalizer, ObservationNormalizer) or not normalizer.enabled or (
            np.shape(normalizer.mean) != (data.observation_size,)):
        raise ValueError(f"normalizer must be an enabled ObservationNormalizer of "
                         f"{data.observation_size} features, got {normalizer!r}")
    return normalizer


def normalized_dataset(dataset: odata.Dataset, name: str = "dynamics",
                       normalize_observations: bool = False,
                       normalizer: ObservationNormalizer | None = None
                       ) -> tuple[odata.Dataset, float, ObservationNormalizer]:
    """``(dataset on the device with actions / action_limit, action_limit, normalizer)`` after
    :func:`offline.data.dataset.validate`; an empty dataset is refused. With
    ``normalize_observations`` its ``observations`` and ``next_observations`` are standardised
    by :func:`observation_normalizer` ``(dataset, True, normalizer)``; off, the normalizer is
    the identity and the observations are untouched.
    """
    odata.validate(dataset, name=name)
    if dataset.size == 0:
        raise ValueError(f"{name} is empty (0 transitions)")
    normalizer = observation_normalizer(dataset, normalize_observations, normalizer)
    scale = action_scale(dataset)
    actions = np.asarray(dataset.actions) / np.asarray(scale, np.asarray(dataset.actions).dtype)
    data = normalizer.apply_states(dataset.replace(actions=actions))
    # leaf by leaf: where the rewards are traced (offline.survival.sweep.reward_batched) the other
    # fields stay concrete arrays instead of joining one staged transfer
    return jax.tree.map(jax.device_put, data), scale, normalizer


def policy_act(policy: nn.Module, scale: float,
               normalizer: ObservationNormalizer | None = None
               ) -> Callable[[Any, jax.Array], jax.Array]:
    """The learner API's ``act(actor_params, obs)``: ``action_limit · tanh(μ(obs))``, the raw
    environment observation ``obs`` first standardised by ``normalizer`` (None: as is)."""
    norm = ObservationNormalizer() if normalizer is None else normalizer

    def act(params: Any, obs: jax.Array) -> jax.Array:
        return scale * policy.apply(params, norm.apply(obs)).mode()

    return act


def adam_step(optimizer: optax.GradientTransformation, params: Any, opt_state: Any,
              grads: Any) -> tuple[Any, Any]:
    """One optimiser step: ``(new_params, new_opt_state)``."""
    updates, opt_state = optimizer.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state


__all__ = [
    "STD_FLOOR",
    "ObservationNormalizer",
    "Trainer",
    "action_scale",
    "actor_params",
    "adam_step",
    "check_network",
    "normalized_dataset",
    "observation_normalizer",
    "policy_act",
    "scan_steps",
]
