"""PPO hyper-parameters: :class:`PPOConfig` and the thesis preset (thesis §6.2.3,
docs/design.md §4.4), validated with the shared validators of :mod:`mjxrmp.config`."""

from __future__ import annotations

import dataclasses
from typing import Any

from agents.ppo.networks import ACTIVATIONS
from mjxrmp.config import (
    check_bool,
    check_choice,
    check_finite,
    check_float,
    check_fraction,
    check_int,
    check_sizes,
)

_INTS = ("num_envs", "rollout_length", "num_minibatches", "update_epochs", "total_iterations")
_POSITIVE = ("learning_rate", "clip_eps", "adam_eps", "policy_out_scale")
_NON_NEGATIVE = ("vf_coef", "ent_coef")


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters (hashable; validated on construction).

    Batch per iteration = ``num_envs × rollout_length``; it must split into ``num_minibatches``
    equal minibatches. Each epoch shuffles the batch within ``shuffle_blocks`` equal blocks of
    environments and gives every minibatch the same number of samples from each block
    (``None``: one block per device of the mesh, so that shuffling never moves data between
    devices; one block without a mesh — a plain shuffle). ``max_grad_norm=None`` disables
    global-norm clipping. ``episode_length`` (``None``: the environment's ``horizon``) is used
    when :func:`agents.ppo.train.make_train` wraps the env.
    """

    num_envs: int = 16
    rollout_length: int = 32
    num_minibatches: int = 4
    update_epochs: int = 4
    learning_rate: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    vf_coef: float = 0.5
    ent_coef: float = 0.0
    max_grad_norm: float | None = 0.5
    total_iterations: int = 10
    normalize_advantages: bool = True
    adam_eps: float = 1e-5
    policy_hidden_sizes: tuple[int, ...] = (256, 128)
    policy_activation: str = "relu"
    policy_out_scale: float = 0.1
    log_std_init: float = -1.0
    value_hidden_sizes: tuple[int, ...] = (256, 128)
    value_activation: str = "tanh"
    episode_length: int | None = None
    normalize_observations: bool = False
    shuffle_blocks: int | None = None

    def __post_init__(self) -> None:
        def name(field: str) -> str:
            return f"PPOConfig.{field}"

        for f in _INTS:
            check_int(getattr(self, f), name(f))
        for f in _POSITIVE:
            check_float(getattr(self, f), name(f))
        for f in _NON_NEGATIVE:
            check_float(getattr(self, f), name(f), allow_zero=True)
        for f in ("gamma", "gae_lambda"):
            check_fraction(getattr(self, f), name(f), closed=True, allow_zero=True)
        for f in ("normalize_advantages", "normalize_observations"):
            check_bool(getattr(self, f), name(f))
        for f in ("policy_hidden_sizes", "value_hidden_sizes"):
            check_sizes(getattr(self, f), name(f), allow_empty=True, require_tuple=True)
        for f in ("policy_activation", "value_activation"):
            check_choice(getattr(self, f), name(f), sorted(ACTIVATIONS))
        check_finite(self.log_std_init, name("log_std_init"))
        if self.max_grad_norm is not None:
            check_float(self.max_grad_norm, name("max_grad_norm"))
        if self.episode_length is not None:
            check_int(self.episode_length, name("episode_length"))
        if self.batch_size % self.num_minibatches:
            raise ValueError(f"PPOConfig.num_minibatches={self.num_minibatches} must divide the "
                             f"batch num_envs*rollout_length={self.batch_size}")
        if self.shuffle_blocks is not None:
            b = check_int(self.shuffle_blocks, name("shuffle_blocks"))
            if self.num_envs % b or self.minibatch_size % b:
                raise ValueError(f"PPOConfig.shuffle_blocks={b} must divide num_envs="
                                 f"{self.num_envs} and the minibatch size {self.minibatch_size}")

    @property
    def batch_size(self) -> int:
        """Transitions per iteration, ``num_envs × rollout_length``."""
        return self.num_envs * self.rollout_length

    @property
    def minibatch_size(self) -> int:
        """Transitions per minibatch, ``batch_size / num_minibatches``."""
        return self.batch_size // self.num_minibatches

    @classmethod
    def thesis(cls, **overrides: Any) -> PPOConfig:
        """The thesis' RLlib settings (docs/design.md §4.4), adapted to fixed-shape batches.

        lr 5e-5, clip 0.2, GAE λ 0.99, γ 0.99, 500 iterations, Gaussian policy with log-std
        initialised at −1, policy MLP (256, 128) relu with output scale 0.1 (``NN`` on the
        planar arm; pass ``policy_hidden_sizes=(512, 256)`` for Franka), value MLP (256, 128)
        tanh. RLlib's 67,312 steps per iteration with minibatches of 4,096 does not split into
        equal minibatches; here 128 environments × 512 steps = 65,536 steps (−2.6 %) in 16
        minibatches of exactly 4,096. ``update_epochs=30``, ``vf_coef=1``, ``ent_coef=0`` and
        no gradient clipping are RLlib's PPO defaults (``num_sgd_iter``, ``vf_loss_coeff``,
        ``entropy_coeff``, ``grad_clip``), assumed because the thesis does not state them;
        RLlib's adaptive KL penalty and value clipping are not implemented.
        """
        base: dict[str, Any] = dict(
            num_envs=128,
            rollout_length=512,
            num_minibatches=16,
            update_epochs=30,
            learning_rate=5e-5,
            gamma=0.99,
            gae_lambda=0.99,
            clip_eps=0.2,
            vf_coef=1.0,
            ent_coef=0.0,
            max_grad_norm=None,
            total_iterations=500,
            normalize_advantages=True,
            policy_hidden_sizes=(256, 128),
            policy_activation="relu",
            policy_out_scale=0.1,
            log_std_init=-1.0,
            value_hidden_sizes=(256, 128),
            value_activation="tanh",
        )
        base.update(overrides)
        return cls(**base)


__all__ = ["PPOConfig"]
