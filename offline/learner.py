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
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax

from offline.data import Dataset


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


__all__ = ["Trainer", "action_scale", "actor_params"]
