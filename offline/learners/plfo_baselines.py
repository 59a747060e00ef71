"""Reward-based PLfO baselines of thesis §7.4 ("Baselines"; docs/design.md §4.5), all on the ATAC
core of :mod:`offline.learners.atac`:

* **RP** (reward prediction, :func:`make_train_rp`) — a reward network ``g(s, s', terminal)``
  (the same network as MAHALO's, :func:`offline.learners.mahalo.make_reward_net`) is fitted on the
  reward data by least squares (eq 7.3) in a ``lax.scan`` of ``reward_steps`` Adam steps
  inside ``init``; it is then frozen and labels the dynamics data for ATAC. Labelling is done
  per minibatch (``r = g(s, s', d)`` on each sampled batch), which is the same as labelling all
  of ``D_A`` once because ``g`` no longer changes. Comparing with MAHALO shows what the
  adversarial reward update adds (question (d) of §7.4).
* **UDS** (unlabelled data sharing, Yu et al. 2022, implemented with ATAC as in §7.4,
  :func:`make_train_uds`) — ATAC on the dynamics data relabelled host-side by
  :func:`uds_relabel`: a dynamics transition that also appears in the reward data (same
  episode id, observation and next observation) keeps the reward-data label; every other
  (unlabelled) transition gets the minimum reward ``r_min``. UDS needs to know which
  transitions are shared (§7.4), so it applies only where ``D_R`` overlaps ``D_A``. Per
  scenario (:mod:`offline.data.scenarios`): **IL** — ``D_A = D_X ∪ D_E``; the expert transitions
  get ``R_max``, all of ``D_X`` gets ``r_min``; **RL-expert** — ``D_A = D_X ∪ D_E``; expert
  transitions keep their true rewards, ``D_X`` gets ``r_min``; **RL-sample** — ``D_A = D_X``;
  the labelled fraction of episodes keeps its true rewards, the rest gets ``r_min``. Matching
  is on the raw states; with ``atac.normalize_observations`` ATAC then standardises the
  relabelled data (the dynamics data's own states, so the dynamics statistics). ILfO and
  RLfO share no transition (the expert data has no actions) and are refused (Table 7.3 has no
  UDS entry there).
* **Oracle** (:func:`make_train_oracle`) — ATAC with the true rewards of all the dynamics data
  (it reads the rewards that PLfO dynamics data hides: ``rewards_visible: false``).

AP and BC / BCO (inverse dynamics) live in their own module; AP ends in
:func:`offline.learners.atac.make_train` on an action-labelled
:class:`~offline.data.dataset.Dataset`.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import optax

from mjxrmp.config import check_finite, check_int, check_parts
from offline.data import dataset as odata
from offline.data import scenarios
from offline.learners import atac
from offline.learners.base import (
    Trainer,
    observation_normalizer,
)
from offline.learners.mahalo import RewardNetConfig, make_reward_net


@dataclasses.dataclass(frozen=True)
class RPConfig:
    """RP: the ATAC settings, the reward network's, and ``reward_steps`` regression steps."""

    atac: atac.ATACConfig = dataclasses.field(default_factory=atac.ATACConfig)
    reward: RewardNetConfig = dataclasses.field(default_factory=RewardNetConfig)
    reward_steps: int = 100_000

    def __post_init__(self) -> None:
        check_parts(self, atac=atac.ATACConfig, reward=RewardNetConfig)
        check_int(self.reward_steps, "RPConfig.reward_steps")


def make_train_rp(dynamics: odata.Dataset, config: RPConfig, *,
                  reward_data: scenarios.RewardData | None = None) -> Trainer:
    """RP (thesis §7.4): fit ``g`` on ``reward_data`` (in ``init``), then ATAC with ``g``'s
    labels. ``init(key, beta)`` returns a state whose ``params["reward"]`` is the fitted
    network (its regression is part of the compiled program, so vmap over seeds works)."""
    if not isinstance(config, RPConfig):
        raise TypeError(f"config must be an RPConfig, got {type(config).__name__}")
    norm = observation_normalizer(dynamics, config.atac.normalize_observations)
    g = make_reward_net(reward_data, config.reward, observation_size=dynamics.observation_size,
                        remove_terminals=config.atac.remove_terminals, learner="RP",
                        normalizer=norm)
    opt = optax.adam(config.reward.lr)

    def fit(key: jax.Array):
        k_init, k_steps = jax.random.split(key)
        params = g.init(k_init)

        def step(carry, t):
            p, o = carry
            grad = jax.grad(g.mse)(p, jax.random.fold_in(k_steps, t))
            upd, o = opt.update(grad, o)
            return (optax.apply_updates(p, upd), o), None

        (params, _), _ = jax.lax.scan(step, (params, opt.init(params)),
                                      np.arange(config.reward_steps))
        return params

    return atac.make_core(dynamics, config.atac, atac.RewardModel(init=fit, predict=g.predict),
                          reward_range=g.bounds, normalizer=norm)


@dataclasses.dataclass(frozen=True)
class UDSConfig:
    """UDS: the ATAC settings and ``min_reward`` given to unlabelled transitions (``None``:
    the low end of the reward data's ``metadata["reward_range"]``)."""

    atac: atac.ATACConfig = dataclasses.field(default_factory=atac.ATACConfig)
    min_reward: float | None = None

    def __post_init__(self) -> None:
        check_parts(self, atac=atac.ATACConfig)
        check_finite(self.min_reward, "UDSConfig.min_reward", allow_none=True)


def _row_keys(episode_ids, observations, next_observations) -> list[bytes]:
    ids = np.asarray(episode_ids, np.int64)
    obs = np.ascontiguousarray(observations, np.float32)
    nxt = np.ascontiguousarray(next_observations, np.float32)
    return [ids[i].tobytes() + obs[i].tobytes() + nxt[i].tobytes() for i in range(len(ids))]


def uds_relabel(dynamics: odata.Dataset, reward_data: scenarios.RewardData,
                min_reward: float) -> odata.Dataset:
    """UDS labels (host-side): a dynamics transition found in ``reward_data`` (same episode
    id, observation and next observation) gets that reward; all others get ``min_reward``.
    Raises ``ValueError`` when no transition is shared (ILfO / RLfO data)."""
    scenarios.validate_reward_data(reward_data)
    labels = dict(zip(_row_keys(reward_data.episode_ids, reward_data.observations,
                                reward_data.next_observations),
                      np.asarray(reward_data.rewards, np.float64), strict=True))
    keys = _row_keys(dynamics.episode_ids, dynamics.observations, dynamics.next_observations)
    found = np.array([k in labels for k in keys], bool)
    if not found.any():
        raise ValueError("UDS: no reward-data transition is in the dynamics data (same episode "
                         "id, observation, next observation); UDS needs shared transitions "
                         "(IL, RL-expert, RL-sample), not ILfO / RLfO")
    rewards = np.array([labels.get(k, min_reward) for k in keys],
                       np.asarray(dynamics.rewards).dtype)
    return odata.relabel_rewards(dynamics, rewards).replace(
        metadata=dynamics.metadata.updated(
            rewards_visible=True, uds={"labelled": int(found.sum()), "min_reward":
                                       float(min_reward)}))


def make_train_uds(dynamics: odata.Dataset, config: UDSConfig, *,
                   reward_data: scenarios.RewardData | None = None) -> Trainer:
    """UDS (thesis §7.4): ATAC on :func:`uds_relabel` ``(dynamics, reward_data, r_min)``."""
    if not isinstance(config, UDSConfig):
        raise TypeError(f"config must be a UDSConfig, got {type(config).__name__}")
    if reward_data is None:
        raise ValueError("UDS needs reward_data (an offline.data.scenarios.RewardData)")
    if not isinstance(reward_data, scenarios.RewardData):
        raise ValueError(f"reward_data must be an offline.data.scenarios.RewardData, got "
                         f"{type(reward_data).__name__}")
    r_min = config.min_reward
    if r_min is None:
        rng = reward_data.metadata.get("reward_range")
        if rng is None:
            raise ValueError("reward_data.metadata has no reward_range; pass "
                             "UDSConfig(min_reward=...)")
        r_min = float(rng[0])
    return atac.make_train(uds_relabel(dynamics, reward_data, r_min), config.atac)


def make_train_oracle(dynamics: odata.Dataset, config: atac.ATACConfig, *,
                      reward_data: scenarios.RewardData | None = None) -> Trainer:
    """Oracle (thesis §7.4): ATAC with the true rewards of all the dynamics data, including
    PLfO dynamics data whose rewards are hidden from the other learners."""
    atac.check_no_reward_data(reward_data, "Oracle")
    return atac.make_core(dynamics, config, atac.dataset_rewards())


__all__ = [
    "RPConfig",
    "UDSConfig",
    "make_train_oracle",
    "make_train_rp",
    "make_train_uds",
    "uds_relabel",
]
