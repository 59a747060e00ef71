"""Offline PLfO scenarios (thesis §7.2 and §7.4, Table 7.2; docs/design.md §4.5): a dynamics
dataset ``D_A = {(s, a, s')}`` and a reward dataset ``D_R = {(s, r, s')}`` built from a
mixed-quality dataset ``D_X`` (e.g. :func:`offline.data.collect.collect_recipe` ``"mixed"``) and
expert trajectories ``D_E`` (recipe ``"expert"``).

Reward data has **no actions**: it is a :class:`RewardData` pytree (observations, rewards,
next observations, terminal/timeout flags, episode ids, metadata) — a separate type rather than
a :class:`~offline.data.dataset.Dataset` with NaN or dummy actions, so a learner cannot read an
action that is not there. (MAHALO's reward network ``g(s, s', terminal)`` reads exactly these
fields.) ``offline.data.dataset.sample`` works on it unchanged (it only needs a ``rewards`` leaf);
:func:`save_reward_data` / :func:`load_reward_data` store it as a dataset file with
zero-width actions ``(N, 0)``.

=============  ======================================  ======================================
scenario       dynamics data ``D_A`` (with actions)    reward data ``D_R`` (no actions)
=============  ======================================  ======================================
``ILfO``       ``D_X``                                 ``D_E`` states, reward ``R_max``
``IL``         ``D_X ∪ D_E``                           ``D_E`` states, reward ``R_max``
``RLfO``       ``D_X``                                 ``D_E`` states, true rewards
``RL-expert``  ``D_X ∪ D_E``                           ``D_E`` states, true rewards
``RL-sample``  ``D_X``                                 a random ``fraction`` of ``D_X``'s
                                                       episodes, true rewards
=============  ======================================  ======================================

Sources in the thesis:

* Table 7.2 (what each scenario gives the learner) and §7.4 "Scenarios": ILfO = expert
  state-only trajectories + mixed dynamics data; IL = ILfO plus the expert actions; RLfO =
  ILfO plus the rewards along the expert trajectories; RL-expert = RLfO plus the expert actions;
  RL-sample = the mixed data with a subset of its trajectories labelled with reward.
* §7.2.2 "Offline IL" / "Offline ILfO": expert demonstrations act as reward data labelled with
  the **maximum reward** ``R_max`` (``D_R = {(s_E, R_max, s'_E)}``); for IL the dynamics data
  contains the expert demonstrations *and* ``D_X``, for ILfO only ``D_X``. The same holds for
  RL-expert (expert actions appended to the dynamics data, docs/design.md §4.5).
* ``R_max`` defaults to the environment's maximum per-step reward recorded by the collector
  (``metadata["reward_range"][1]``, 1 for the reaching tasks — docs/design.md §4.5: "labelled with
  the maximum reward 1").
* RL-sample's labelled fraction: §7.4.2 (Meta-World, the setting closest to these reaching
  tasks: noisy scripted policies) labels 50 % of the trajectories — the default
  ``fraction=0.5``; §7.4.1 (D4RL) labels 1 % of the transitions.

**Rewards in the dynamics data.** ``D_A`` is a :class:`~offline.data.dataset.Dataset` and keeps the
true rewards in its ``rewards`` field: the Oracle baseline (ATAC with true rewards everywhere)
and diagnostics read them. A PLfO learner (MAHALO, RP, AP, UDS) must not: its metadata says
``"plfo_role": "dynamics"`` and ``"rewards_visible": false``.

**Terminals.** ``keep_terminals=False`` turns every terminal into a timeout in both datasets
(the option of docs/design.md §4.5 that treats collisions as non-absorbing; report both settings).

**Episode ids.** Reward-data episode ids are those the episodes have in
``offline.data.dataset.concatenate(D_X, D_E)`` (``D_X``'s ``0 … K−1``, then ``D_E``'s ``K …``), so
an id names the same episode in ``D_A`` and ``D_R`` whenever it is in both;
``metadata["overlap_with_dynamics"]`` says whether ``D_R``'s episodes are also in ``D_A``
(IL, RL-expert, RL-sample) or not (ILfO, RLfO).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from typing import Any

import jax
import numpy as np

from offline.data import dataset as odata

#: Scenario names (thesis Table 7.2).
SCENARIOS = ("ILfO", "IL", "RLfO", "RL-expert", "RL-sample")
#: The fields of :class:`RewardData` in pytree order.
REWARD_FIELDS = ("observations", "rewards", "next_observations", "terminals", "timeouts",
                 "episode_ids")
#: Scenarios whose data does not depend on the expert dataset (reward data from ``D_X``).
EXPERT_FREE = ("RL-sample",)
#: Scenarios whose dynamics data holds the expert's transitions with actions (``D_X ∪ D_E``).
WITH_EXPERT_ACTIONS = ("IL", "RL-expert")
#: Default labelled fraction of RL-sample's episodes (thesis §7.4.2).
RL_SAMPLE_FRACTION = 0.5


@dataclasses.dataclass(frozen=True)
class RewardData(odata.TransitionTable):
    """Reward data ``D_R = {(s, r, s')}`` of PLfO: no actions.

    ``observations`` / ``next_observations`` ``(N, O)``, ``rewards`` ``(N,)``, ``terminals`` /
    ``timeouts`` ``(N,)`` bool, ``episode_ids`` ``(N,)`` int32 and static JSON ``metadata``.
    """

    observations: Any
    rewards: Any
    next_observations: Any
    terminals: Any
    timeouts: Any
    episode_ids: Any
    metadata: odata.Metadata = dataclasses.field(default_factory=odata.Metadata)

    def as_dataset(self) -> odata.Dataset:
        """A :class:`~offline.data.dataset.Dataset` with zero-width actions ``(N, 0)`` (for
        files)."""
        n = self.size
        acts = np.zeros((n, 0), np.asarray(self.observations).dtype)
        return odata.Dataset(self.observations, acts, self.rewards, self.next_observations,
                             self.terminals, self.timeouts, self.episode_ids,
                             self.metadata.updated(reward_data=True))


jax.tree_util.register_dataclass(RewardData, data_fields=list(REWARD_FIELDS),
                                 meta_fields=["metadata"])


def validate_reward_data(rd: RewardData) -> RewardData:
    """Check ``rd`` with the rules of :func:`offline.data.dataset.validate`; return it unchanged."""
    if not isinstance(rd, RewardData):
        raise TypeError(f"expected RewardData, got {type(rd).__name__}")
    odata.validate(rd.as_dataset(), name="reward data")
    return rd


def reward_data(dataset: odata.Dataset, *, reward: float | None = None,
                metadata: Mapping[str, Any] | None = None) -> RewardData:
    """The :class:`RewardData` of ``dataset`` (its actions dropped), with every reward replaced
    by ``reward`` when given (e.g. ``R_max`` for expert demonstrations); ``metadata`` entries
    are added to the dataset's."""
    rewards = np.asarray(dataset.rewards)
    meta = dataset.metadata.to_dict()
    meta.pop("reward_data", None)
    if reward is not None:
        if not np.isfinite(reward):
            raise ValueError(f"reward must be finite, got {reward!r}")
        rewards = np.full_like(rewards, reward)
        meta["reward_label"] = {"constant": float(reward)}
    else:
        meta["reward_label"] = "true"
    meta.update(metadata or {})
    return validate_reward_data(RewardData(
        np.asarray(dataset.observations), rewards, np.asarray(dataset.next_observations),
        np.asarray(dataset.terminals), np.asarray(dataset.timeouts),
        np.asarray(dataset.episode_ids), odata.Metadata(meta)))


def save_reward_data(rd: RewardData, path: str | os.PathLike) -> str:
    """Write ``rd`` with :func:`offline.data.dataset.save` (actions of width 0)."""
    return odata.save(validate_reward_data(rd).as_dataset(), path)


def load_reward_data(path: str | os.PathLike) -> RewardData:
    """Read a file written by :func:`save_reward_data`."""
    ds = odata.load(path)
    if ds.action_size != 0 or not ds.metadata.get("reward_data", False):
        raise odata.DatasetFileError(f"dataset file {os.fspath(path)!r} holds a dataset with "
                                     f"actions, not reward data")
    meta = ds.metadata.to_dict()
    meta.pop("reward_data")
    return RewardData(ds.observations, ds.rewards, ds.next_observations, ds.terminals,
                      ds.timeouts, ds.episode_ids, odata.Metadata(meta))


def terminals_as_timeouts(data: odata.Dataset | RewardData) -> odata.Dataset | RewardData:
    """``data`` with every terminal turned into a timeout (collisions not absorbing)."""
    term = np.asarray(data.terminals)
    return data.replace(terminals=np.zeros_like(term),
                        timeouts=np.asarray(data.timeouts) | term,
                        metadata=data.metadata.updated(terminals_as_timeouts=True))


def _max_reward(expert: odata.Dataset, max_reward: float | None) -> float:
    if max_reward is not None:
        return float(max_reward)
    rng = expert.metadata.get("reward_range")
    if not (isinstance(rng, list) and len(rng) == 2):
        raise ValueError("the expert dataset's metadata has no reward_range (not collected by "
                         "offline.data.collect?); pass max_reward=R_max")
    return float(rng[1])


def _num_episodes(ds: odata.Dataset) -> int:
    return int(odata.episode_statistics(ds)[1]["num_episodes"])


#: Environment facts a dataset records (:func:`offline.data.rollouts.environment_metadata`) that the
#: scenario's dynamics data carries at its top level when its parts agree on them.
ENVIRONMENT_KEYS = ("env", "env_kwargs", "horizon", "action_limit", "reward_range",
                    "observation_layout")


def _shared_environment(parts: list[odata.Dataset]) -> dict:
    """The :data:`ENVIRONMENT_KEYS` entries of the parts' metadata (keys no part records are
    left out); parts that disagree on one are refused — mixing environments or action limits
    would silently mis-scale actions (learners read ``metadata["action_limit"]``)."""
    metas = [p.metadata.to_dict() for p in parts]
    out = {}
    for key in ENVIRONMENT_KEYS:
        values = [m.get(key) for m in metas]
        present = [v for v in values if v is not None]
        if not present:
            continue
        if len(present) != len(values) or any(v != present[0] for v in present):
            raise ValueError(f"the scenario's dynamics parts disagree on metadata[{key!r}]: "
                             f"{values}; collect them from the same environment")
        out[key] = present[0]
    return out


def make(name: str, mixed: odata.Dataset, expert: odata.Dataset | None = None, *,
         key: jax.Array | None = None, fraction: float = RL_SAMPLE_FRACTION,
         max_reward: float | None = None,
         keep_terminals: bool = True) -> tuple[odata.Dataset, RewardData]:
    """``(dynamics_data, reward_data)`` of PLfO scenario ``name`` (module docstring table).

    ``mixed`` is ``D_X``, ``expert`` ``D_E`` (not needed for RL-sample); ``key`` and
    ``fraction`` choose RL-sample's labelled episodes
    (:func:`offline.data.dataset.split_by_episode`); ``max_reward`` is ``R_max`` for ILfO/IL
    (default: the expert metadata's reward range).
    """
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario name={name!r}; valid scenarios are "
                         f"{list(SCENARIOS)}")
    odata.validate(mixed, name="mixed")
    mixed = odata.renumber_episodes(mixed)
    k = _num_episodes(mixed)
    base = {"plfo_scenario": name, "keep_terminals": bool(keep_terminals),
            "thesis": "Table 7.2, sections 7.2.2 and 7.4"}
    if name == "RL-sample":
        if key is None:
            raise ValueError("RL-sample needs a PRNG key (key=...) to choose the labelled "
                             "episodes")
        labelled, _ = odata.split_by_episode(mixed, fraction, key)
        dyn_parts = [mixed]
        rd = reward_data(labelled, metadata={
            **base, "plfo_role": "reward", "source": "mixed", "labelled_fraction":
            float(fraction), "overlap_with_dynamics": True})
    else:
        if expert is None:
            raise ValueError(f"scenario {name!r} needs expert data (expert=...)")
        odata.validate(expert, name="expert")
        expert = odata.renumber_episodes(expert)
        # Ids as in concatenate(mixed, expert): the expert's episodes follow the mixed ones.
        expert = expert.replace(episode_ids=(np.asarray(expert.episode_ids) + k
                                             ).astype(np.int32))
        with_actions = name in WITH_EXPERT_ACTIONS
        dyn_parts = [mixed, expert] if with_actions else [mixed]
        label = _max_reward(expert, max_reward) if name in ("ILfO", "IL") else None
        rd = reward_data(expert, reward=label, metadata={
            **base, "plfo_role": "reward", "source": "expert",
            "overlap_with_dynamics": with_actions})
    meta = {**base, **_shared_environment(dyn_parts), "plfo_role": "dynamics",
            "rewards_visible": False, "parts": [p.metadata.to_dict() for p in dyn_parts],
            "part_names": ["mixed", "expert"][:len(dyn_parts)]}
    dynamics = odata.concatenate(*dyn_parts, metadata=meta)
    if not keep_terminals:
        dynamics = terminals_as_timeouts(dynamics)
        rd = terminals_as_timeouts(rd)
    return dynamics, rd


def same_dynamics(name: str) -> tuple[str, ...]:
    """The scenarios whose dynamics data is the same as scenario ``name``'s (module docstring
    table): ``D_X ∪ D_E`` in IL and RL-expert, ``D_X`` in ILfO, RLfO and RL-sample. A learner that
    reads only the dynamics data with its true rewards (the Oracle) does the same computation in
    all of them."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario name={name!r}; valid scenarios are "
                         f"{list(SCENARIOS)}")
    group = name in WITH_EXPERT_ACTIONS
    return tuple(s for s in SCENARIOS if (s in WITH_EXPERT_ACTIONS) == group)


def ilfo(mixed: odata.Dataset, expert: odata.Dataset, **kwargs: Any
         ) -> tuple[odata.Dataset, RewardData]:
    """ILfO: dynamics ``D_X``; reward data = expert states labelled ``R_max``."""
    return make("ILfO", mixed, expert, **kwargs)


def il(mixed: odata.Dataset, expert: odata.Dataset, **kwargs: Any
       ) -> tuple[odata.Dataset, RewardData]:
    """IL: dynamics ``D_X ∪ D_E``; reward data = expert states labelled ``R_max``."""
    return make("IL", mixed, expert, **kwargs)


def rlfo(mixed: odata.Dataset, expert: odata.Dataset, **kwargs: Any
         ) -> tuple[odata.Dataset, RewardData]:
    """RLfO: dynamics ``D_X``; reward data = expert states with their true rewards."""
    return make("RLfO", mixed, expert, **kwargs)


def rl_expert(mixed: odata.Dataset, expert: odata.Dataset, **kwargs: Any
              ) -> tuple[odata.Dataset, RewardData]:
    """RL-expert: dynamics ``D_X ∪ D_E``; reward data = expert states with true rewards."""
    return make("RL-expert", mixed, expert, **kwargs)


def rl_sample(mixed: odata.Dataset, *, key: jax.Array, **kwargs: Any
              ) -> tuple[odata.Dataset, RewardData]:
    """RL-sample: dynamics ``D_X``; reward data = a random ``fraction`` of its episodes."""
    return make("RL-sample", mixed, key=key, **kwargs)


__all__ = [
    "REWARD_FIELDS",
    "RL_SAMPLE_FRACTION",
    "SCENARIOS",
    "WITH_EXPERT_ACTIONS",
    "RewardData",
    "il",
    "ilfo",
    "load_reward_data",
    "make",
    "reward_data",
    "rl_expert",
    "rl_sample",
    "rlfo",
    "same_dynamics",
    "save_reward_data",
    "terminals_as_timeouts",
    "validate_reward_data",
]
