"""Scalar PPO hyper-parameters as data (docs/design.md §2.3): what lets one compiled program
train several runs that differ only in these values (:mod:`agents.run.sweep`).

A :class:`agents.ppo.state.TrainState` may carry ``hparams``, a dict from some of
:data:`SWEEPABLE` to float32 scalars (one per run under the ``vmap`` over runs); the update reads
each value from there and every other value from the :class:`~agents.ppo.config.PPOConfig`
(:func:`resolve`). A state without ``hparams`` (``None``, every ordinary run) computes exactly
what it computed before: the values are then the config's Python floats, constants of the
program.

One value belongs to the policy, not to PPO: ``base_weight`` (:data:`POLICY_VALUES`), the weight
of the hand-designed acceleration added to the network's output by
:class:`agents.ppo.policies.NNResidualPolicy` — 1 is the ``nn_residual`` policy, 0 the ``nn``
policy (the same network), so a sweep trains both kinds in one program
(:func:`agents.ppo.policies.packed_kind`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from agents.ppo.config import PPOConfig

#: The :class:`PPOConfig` fields a packed sweep may vary per run: the Adam step size, the
#: clipped-surrogate loss's coefficients (thesis §6.2.3) and the return's discounting (GAE).
SWEEPABLE = ("learning_rate", "ent_coef", "clip_eps", "vf_coef", "gamma", "gae_lambda")
#: Per-run values of the policy a packed sweep may carry besides :data:`SWEEPABLE`.
POLICY_VALUES = ("base_weight",)


@dataclasses.dataclass(frozen=True)
class Values:
    """The values the update uses (Python floats or traced float32 scalars)."""

    learning_rate: Any
    ent_coef: Any
    clip_eps: Any
    vf_coef: Any
    gamma: Any
    gae_lambda: Any


def resolve(config: PPOConfig, hparams: dict[str, Any] | None) -> Values:
    """The update's values: ``hparams[name]`` where given, else ``config.name``."""
    given = hparams or {}
    unknown = sorted(set(given) - set(SWEEPABLE) - set(POLICY_VALUES))
    if unknown:
        raise ValueError(f"TrainState.hparams has unknown names {unknown}; sweepable names are "
                         f"{list(SWEEPABLE)} (and the policy's {list(POLICY_VALUES)})")
    return Values(**{k: given.get(k, getattr(config, k)) for k in SWEEPABLE})


def base_weight(hparams: dict[str, Any] | None) -> Any:
    """The run's ``base_weight`` (a traced scalar), or None when the state carries none."""
    return (hparams or {}).get("base_weight")


__all__ = ["POLICY_VALUES", "SWEEPABLE", "Values", "base_weight", "resolve"]
