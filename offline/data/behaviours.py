"""Behaviour policies of offline data collection (:mod:`offline.data.collect`; docs/design.md
§2.4).

**Behaviour policies** (:class:`Behaviour`):

==========================  =================================================================
constructor                 action
==========================  =================================================================
:func:`expert`              hand-designed RMP² (:func:`envs.evaluate.hand_designed_policy`)
:func:`noisy_expert`        expert + ``N(0, σ²)`` per component, then clipped (σ ∈ {0.1, 0.5,
                            1.0} in the recipes: ``noisy-0.1`` …)
:func:`uniform_random`      i.i.d. ``U[−action_limit, action_limit]`` per component
:func:`ppo_policy`          a PPO checkpoint (:func:`agents.run.loading.load_run`): its
                            Gaussian mean (``stochastic=False``) or a sample
                            ``mean + exp(log_std)·ε``
                            (``stochastic=True``, as during training); the environment clips
==========================  =================================================================

"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import numpy as np

#: Noise levels of the noisy expert (thesis §7.4.2).
NOISE_LEVELS = (0.1, 0.5, 1.0)
BEHAVIOUR_KINDS = ("expert", "noisy", "random", "ppo")


@dataclasses.dataclass(frozen=True)
class Behaviour:
    """A behaviour policy (build one with :func:`expert`, :func:`noisy_expert`,
    :func:`uniform_random` or :func:`ppo_policy`)."""

    name: str
    kind: str
    sigma: float = 0.0
    run_dir: str | None = None
    step: int | None = None
    seed_index: int = 0
    stochastic: bool = False

    def __post_init__(self):
        if self.kind not in BEHAVIOUR_KINDS:
            raise ValueError(f"unknown behaviour kind={self.kind!r}; valid kinds are "
                             f"{BEHAVIOUR_KINDS}")
        if not (np.isfinite(self.sigma) and self.sigma >= 0):
            raise ValueError(f"sigma must be finite and >= 0, got {self.sigma!r}")
        if self.kind == "ppo" and self.run_dir is None:
            raise ValueError("a 'ppo' behaviour needs run_dir")

    def describe(self) -> dict[str, Any]:
        """JSON description stored in the dataset metadata."""
        d: dict[str, Any] = {"name": self.name, "kind": self.kind}
        if self.kind == "noisy":
            d["sigma"] = float(self.sigma)
        if self.kind == "ppo":
            d.update(run_dir=os.fspath(self.run_dir), step=self.step,
                     seed_index=self.seed_index, stochastic=self.stochastic)
        return d


def expert() -> Behaviour:
    """The hand-designed RMP² policy (deterministic)."""
    return Behaviour("expert", "expert")


def noisy_expert(sigma: float) -> Behaviour:
    """The expert plus i.i.d. Gaussian noise of standard deviation ``sigma`` on every action
    component, then clipped to the action box (name ``noisy-<σ>``)."""
    sigma = float(sigma)
    return Behaviour(f"noisy-{sigma!r}", "noisy", sigma=sigma)


def uniform_random() -> Behaviour:
    """Uniform random actions in the action box ``[−action_limit, action_limit]^A``."""
    return Behaviour("random", "random")


def ppo_policy(run_dir: str | os.PathLike, step: int | None = None, *, seed_index: int = 0,
               stochastic: bool = False, name: str | None = None) -> Behaviour:
    """Checkpoint ``step`` (default: newest) of training seed ``seed_index`` of the run in
    ``run_dir``: the Gaussian mean (``stochastic=False``) or a sample of the Gaussian."""
    if name is None:
        name = f"ppo-step{step if step is not None else 'latest'}"
    return Behaviour(name, "ppo", run_dir=os.fspath(run_dir), step=step,
                     seed_index=int(seed_index), stochastic=bool(stochastic))


__all__ = [
    "BEHAVIOUR_KINDS",
    "NOISE_LEVELS",
    "Behaviour",
    "expert",
    "noisy_expert",
    "ppo_policy",
    "uniform_random",
]
