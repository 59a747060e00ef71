"""MAHALO realised by ATAC (thesis §7.3, Algorithm 3; docs/design.md §4.5).

The ATAC core of :mod:`offline.learners.atac` with a **reward player**: a reward network
``g(s, s', terminal)`` (MLP, 3×256 ReLU, no action input) replaces the observed reward in the
critics' DQRA Bellman backups (eq 7.11 with ``g`` in place of ``r``; clipped and detached for
the critic) and is trained every step by Algorithm 3 line 6,

    l_reward(g) = α·E_{D_R}(g) + β·Σ_i E^w_{D_A}(π, f_i, g),

with ``E_{D_R}(g) = mean (g(s, s', d) − r)²`` on a minibatch of the reward data (eq 7.3) and
the critics detached in the Bellman term (so ``g`` moves adversarially, towards rewards that make
the pessimistic critic Bellman-consistent). The implementation minimises ``l_reward / α`` (the
same minimiser; Adam is invariant to the scale of the loss up to its ε). Defaults: β = 10,
``α = 1e5·β`` (``reward_weight=None``), the fast learning rate for ``g``. The reward network
(:class:`RewardNetConfig`, :func:`make_reward_net`) is shared with the RP baseline.

Reward labels and the clip of ``g``: with ``max_reward_label`` (expert-only reward data of IL /
ILfO, §7.2.2) every reward-data label is ``1`` (``R_max``) and ``g`` is clipped to ``[0, 1]``;
otherwise ``g`` is clipped to ``reward_range`` (default: the environment's range recorded in
the reward data's ``metadata["reward_range"]``), which also gives ``V_min`` / ``V_max`` when
``atac.clip_v``.

With ``atac.normalize_observations`` the states of ``g``'s input — dynamics minibatches and the
reward data alike — are standardised with the **dynamics** data's statistics
(:class:`offline.learners.base.ObservationNormalizer`), the normalizer of the actor and critics.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp.config import check_bool, check_float, check_int, check_parts
from offline.data import dataset as odata
from offline.data import scenarios
from offline.learners import atac
from offline.learners.base import (
    ObservationNormalizer,
    Trainer,
    check_network,
    observation_normalizer,
)
from offline.learners.networks import StateNet

#: Default weight of the reward-data loss relative to β (docs/design.md §4.5: α = 1e5·β).
REWARD_WEIGHT_PER_BETA = 1e5


@dataclasses.dataclass(frozen=True)
class RewardNetConfig:
    """The reward network ``g(s, s', terminal)`` and its data (shared by MAHALO and RP):
    ``hidden_sizes`` (3×256 ReLU), ``lr`` (the fast rate), ``batch_size`` of reward-data
    minibatches, ``max_reward_label`` and ``reward_range`` (module docstring)."""

    hidden_sizes: Sequence[int] = (256, 256, 256)
    lr: float = 5e-4
    batch_size: int = 256
    max_reward_label: bool = False
    reward_range: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        n = type(self).__name__
        object.__setattr__(self, "hidden_sizes",
                           check_network(self.hidden_sizes, "relu", f"{n}."))
        check_float(self.lr, f"{n}.lr")
        check_int(self.batch_size, f"{n}.batch_size")
        check_bool(self.max_reward_label, f"{n}.max_reward_label")
        if self.reward_range is not None:
            object.__setattr__(self, "reward_range", _check_range(self.reward_range,
                                                                  "reward_range"))


@dataclasses.dataclass(frozen=True)
class MAHALOConfig:
    """MAHALO hyperparameters: the ATAC ones (``atac``; β defaults to 10), the reward network's
    (``reward``) and the reward-data weight ``reward_weight`` α (``None``: ``1e5·β``, following
    a traced β)."""

    atac: atac.ATACConfig = dataclasses.field(default_factory=lambda: atac.ATACConfig(beta=10.0))
    reward: RewardNetConfig = dataclasses.field(default_factory=RewardNetConfig)
    reward_weight: float | None = None

    def __post_init__(self) -> None:
        check_parts(self, atac=atac.ATACConfig, reward=RewardNetConfig)
        if self.reward_weight is not None:
            check_float(self.reward_weight, "MAHALOConfig.reward_weight")


def _check_range(rng, name: str) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in rng)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (low, high), got {rng!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"{name} must be finite with low < high, got {rng!r}")
    return lo, hi


def reward_features(data: odata.Dataset | scenarios.RewardData) -> jax.Array:
    """The input of ``g(s, s', terminal)``: ``concat(s, s', terminal)`` of shape
    ``(..., 2·O + 1)`` (no action: reward data has none, §7.2.1)."""
    term = jnp.asarray(data.terminals, data.observations.dtype)[..., None]
    return jnp.concatenate([data.observations, data.next_observations, term], axis=-1)


def prepare_reward_data(reward_data: scenarios.RewardData, *, remove_terminals: bool,
                        max_reward_label: bool,
                        normalizer: ObservationNormalizer | None = None
                        ) -> scenarios.RewardData:
    """Validate, optionally turn terminals into timeouts and relabel every reward with
    ``R_max = 1`` (``max_reward_label``), cast to float32, standardise the states with
    ``normalizer`` (the dynamics data's; None: as they are) and put on the device."""
    if not isinstance(reward_data, scenarios.RewardData):
        raise ValueError(f"reward_data must be an offline.data.scenarios.RewardData, got "
                         f"{type(reward_data).__name__}")
    scenarios.validate_reward_data(reward_data)
    if reward_data.size == 0:
        raise ValueError("reward_data must contain at least one transition")
    if remove_terminals:
        reward_data = scenarios.terminals_as_timeouts(reward_data)
    r = np.asarray(reward_data.rewards, np.float32)
    if max_reward_label:
        r = np.ones_like(r)
    rd = reward_data.replace(observations=np.asarray(reward_data.observations, np.float32),
                             next_observations=np.asarray(reward_data.next_observations,
                                                          np.float32), rewards=r)
    if normalizer is not None:
        rd = normalizer.apply_states(rd)
    return jax.device_put(rd)


def resolve_reward_range(reward_data: scenarios.RewardData, reward_range: Any,
                         max_reward_label: bool
                         ) -> tuple[float, float]:
    """The clip range of ``g``: ``reward_range`` if given, ``[0, 1]`` for max-reward labels,
    else the reward data's ``metadata["reward_range"]`` (the environment's range)."""
    if reward_range is not None:
        return _check_range(reward_range, "reward_range")
    if max_reward_label:
        return 0.0, 1.0
    meta = reward_data.metadata.get("reward_range")
    if meta is None:
        raise ValueError("reward_data.metadata has no reward_range (not collected by "
                         "offline.data.collect?); pass reward_range=(r_min, r_max)")
    return _check_range(meta, "reward_data.metadata['reward_range']")


class RewardNet(NamedTuple):
    """``g`` on prepared reward data: ``init(key)``, ``predict(params, batch)`` (clipped to
    ``bounds``), ``mse(params, key)`` (eq 7.3 on a reward-data minibatch) and the clip
    ``bounds``."""

    init: Callable[[jax.Array], Any]
    predict: Callable[[Any, Any], jax.Array]
    mse: Callable[[Any, jax.Array], jax.Array]
    bounds: tuple[float, float]


def make_reward_net(reward_data: scenarios.RewardData | None, config: RewardNetConfig, *,
                    observation_size: int, remove_terminals: bool, learner: str,
                    normalizer: ObservationNormalizer | None = None) -> RewardNet:
    """The reward network ``g(s, s', terminal)`` (MLP, ``config.hidden_sizes``, one output) on
    ``reward_data`` prepared by :func:`prepare_reward_data`; errors name ``learner``.
    ``normalizer`` (the dynamics data's) standardises the reward data's states; ``predict``
    then expects minibatches standardised by it too (as the ATAC core's are)."""
    if reward_data is None:
        raise ValueError(f"{learner} needs reward_data (an offline.data.scenarios.RewardData: "
                         f"observations, rewards, next observations)")
    rd = prepare_reward_data(reward_data, remove_terminals=remove_terminals,
                             max_reward_label=config.max_reward_label, normalizer=normalizer)
    if rd.observation_size != observation_size:
        raise ValueError(f"reward_data has observation size {rd.observation_size}, dynamics "
                         f"{observation_size}; they must match")
    lo, hi = resolve_reward_range(reward_data, config.reward_range, config.max_reward_label)
    net = StateNet(1, hidden_sizes=config.hidden_sizes)

    def init(key):
        return net.init(key, jnp.zeros((1, 2 * observation_size + 1), jnp.float32))

    def predict(params, batch):
        return jnp.clip(net.apply(params, reward_features(batch)), lo, hi)

    def mse(params, key):
        b = odata.sample(rd, key, config.batch_size)
        return jnp.mean(jnp.square(net.apply(params, reward_features(b)) - b.rewards))

    return RewardNet(init, predict, mse, (lo, hi))


def make_train(dynamics: odata.Dataset, config: MAHALOConfig, *,
               reward_data: scenarios.RewardData | None = None) -> Trainer:
    """MAHALO (Algorithm 3, thesis §7.3.3) on dynamics data ``D_A`` and reward data ``D_R``.

    Never reads ``dynamics.rewards``. ``init(key, beta)`` takes β traced (vmap over β);
    α follows β when ``reward_weight`` is ``None``.
    """
    if not isinstance(config, MAHALOConfig):
        raise TypeError(f"config must be a MAHALOConfig, got {type(config).__name__}")
    norm = observation_normalizer(dynamics, config.atac.normalize_observations)
    g = make_reward_net(reward_data, config.reward, observation_size=dynamics.observation_size,
                        remove_terminals=config.atac.remove_terminals, learner="MAHALO",
                        normalizer=norm)

    def weight(beta):
        if config.reward_weight is None:
            return REWARD_WEIGHT_PER_BETA * jnp.maximum(beta, 1e-30)
        return jnp.asarray(config.reward_weight, jnp.float32)

    player = atac.RewardModel(init=g.init, predict=g.predict, fit_loss=g.mse, weight=weight,
                              lr=config.reward.lr)
    return atac.make_core(dynamics, config.atac, player, reward_range=g.bounds, normalizer=norm)


__all__ = [
    "REWARD_WEIGHT_PER_BETA",
    "MAHALOConfig",
    "RewardNet",
    "RewardNetConfig",
    "make_reward_net",
    "make_train",
    "prepare_reward_data",
    "resolve_reward_range",
    "reward_features",
]
