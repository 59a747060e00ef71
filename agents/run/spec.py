"""What a training run is: :class:`RunSpec` (environment, policy kind, seeds, PPO settings,
logging cadence) and the named PPO presets (docs/design.md §4.4)."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from typing import Any

from agents.ppo import KINDS, PPOConfig
from mjxrmp.config import check_choice, check_int, parse_assignments


def cpu_preset(**overrides: Any) -> PPOConfig:
    """The main job's CPU-sized PPO settings: 64 environments × 128 steps, 4 minibatches of
    2,048, 4 epochs, 400 iterations (3.3 M environment steps; about 5 minutes on 2 CPU cores
    for ``rmp_residual`` on ``three_link/env3``)."""
    base: dict[str, Any] = dict(num_envs=64, rollout_length=128, num_minibatches=4,
                                update_epochs=4, learning_rate=3e-4, gamma=0.99,
                                gae_lambda=0.95, max_grad_norm=0.5, total_iterations=400)
    base.update(overrides)
    return PPOConfig(**base)


PRESETS: dict[str, Callable[..., PPOConfig]] = {"cpu": cpu_preset, "thesis": PPOConfig.thesis}


def preset(name: str, **overrides: Any) -> PPOConfig:
    """The PPO settings called ``name`` (:data:`PRESETS`) with ``overrides``. Network sizes per
    robot and policy kind come from :func:`agents.ppo.policies.make_policy`, not from the preset."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset={name!r}; valid presets are {sorted(PRESETS)}")
    return PRESETS[name](**overrides)


def parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    """``["learning_rate=1e-4", "policy_hidden_sizes=64,64"]`` → :class:`PPOConfig` overrides,
    each parsed by the field's declared type (:func:`mjxrmp.config.parse_field`: ``none`` for
    None, strict ``true``/``false``/``1``/``0`` for booleans, comma-separated tuples); an error
    names the ``--set`` item, the field and the expected type."""
    return parse_assignments(PPOConfig, items, option="--set")


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """What to train: environment, policy kind, seeds and PPO settings, and how to log."""

    env: str = "three_link/env3"
    policy: str = "rmp_residual"
    seeds: tuple[int, ...] = (0,)
    ppo: PPOConfig = dataclasses.field(default_factory=cpu_preset)
    log_every: int = 5
    checkpoint_every: int = 25
    #: How many of the newest checkpoints to keep; ``None`` keeps every one (what an offline
    #: ``medium-replay`` dataset of the run's snapshots needs, :mod:`offline.data.collect`).
    keep_checkpoints: int | None = 3

    def __post_init__(self) -> None:
        check_choice(self.policy, "RunSpec.policy", KINDS)
        if not (isinstance(self.seeds, tuple) and self.seeds):
            raise ValueError(f"RunSpec.seeds must be a non-empty tuple of integers >= 0, got "
                             f"{self.seeds!r}")
        for i, s in enumerate(self.seeds):
            check_int(s, f"RunSpec.seeds[{i}]", minimum=0)
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"RunSpec.seeds must be distinct, got {self.seeds!r}")
        check_int(self.log_every, "RunSpec.log_every")
        check_int(self.checkpoint_every, "RunSpec.checkpoint_every")
        if self.keep_checkpoints is not None:
            check_int(self.keep_checkpoints, "RunSpec.keep_checkpoints (None keeps all)")
        if self.checkpoint_every % self.log_every:
            raise ValueError(f"RunSpec.checkpoint_every={self.checkpoint_every} must be a "
                             f"multiple of log_every={self.log_every}")

    def identity(self) -> dict[str, Any]:
        """What a checkpoint must match to be resumed by this run (everything but the length
        of the run and the logging cadence)."""
        ppo = dataclasses.asdict(self.ppo)
        ppo.pop("total_iterations")
        return {"env": self.env, "policy": self.policy, "seeds": list(self.seeds),
                "ppo": json.loads(json.dumps(ppo))}

    def to_json(self) -> dict[str, Any]:
        """The spec as JSON-compatible data (``run.json``; read back by
        :func:`agents.run.loading.spec_from_json`)."""
        return json.loads(json.dumps(dataclasses.asdict(self)))


__all__ = ["PRESETS", "RunSpec", "cpu_preset", "parse_overrides", "preset"]
