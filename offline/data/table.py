"""The :class:`Dataset` pytree of offline transitions, its JSON :class:`Metadata` and the
invariants every dataset satisfies (:func:`validate`); the field table and the invariants are
documented in :mod:`offline.data.dataset` (docs/design.md §2.4)."""

from __future__ import annotations

import dataclasses
import inspect
import json
import warnings
from collections.abc import Iterator, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

#: Array fields in file and pytree order.
FIELDS = ("observations", "actions", "rewards", "next_observations", "terminals", "timeouts",
          "episode_ids")
_FLOAT_FIELDS = ("observations", "actions", "rewards", "next_observations")
_NDIM = {"observations": 2, "actions": 2, "rewards": 1, "next_observations": 2, "terminals": 1,
         "timeouts": 1, "episode_ids": 1}
#: Reward relabellings by name (thesis §8.3: zero, random U[0, 1] and negated rewards).


class Metadata(Mapping[str, Any]):
    """Immutable, hashable JSON dict (the static part of a :class:`Dataset` pytree).

    Built from any JSON-serialisable mapping; values are normalised through a JSON round trip
    (tuples become lists), so a dataset's metadata compares equal after :func:`save` /
    :func:`load`. Hash and equality use the canonical JSON text.
    """

    __slots__ = ("_data", "_text")

    def __init__(self, data: Mapping[str, Any] | None = None):
        data = {} if data is None else data
        if not isinstance(data, Mapping):
            raise TypeError(f"metadata must be a mapping, got {type(data).__name__}")
        try:
            text = json.dumps(dict(data), sort_keys=True, allow_nan=False)
        except (TypeError, ValueError) as e:
            raise ValueError(f"metadata must be JSON-serialisable (str keys, finite numbers, "
                             f"lists, dicts, str, bool, None): {e}") from e
        self._text = text
        self._data = json.loads(text)

    def __getitem__(self, key: str) -> Any:
        return self._data[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __hash__(self) -> int:
        return hash(self._text)

    def __eq__(self, other: object) -> bool:
        if isinstance(other, Metadata):
            return self._text == other._text
        if isinstance(other, Mapping):
            return self._data == dict(other)
        return NotImplemented

    def __repr__(self) -> str:
        return f"Metadata({self._data!r})"

    def to_dict(self) -> dict[str, Any]:
        """A fresh (mutable) copy of the metadata."""
        return json.loads(self._text)

    def updated(self, **entries: Any) -> Metadata:
        """A copy with ``entries`` added or replaced."""
        return Metadata({**self._data, **entries})


class TransitionTable:
    """What :class:`Dataset` and :class:`offline.data.scenarios.RewardData` share: ``metadata``
    coerced to :class:`Metadata`, ``size`` / ``len`` (rows ``N``), ``observation_size`` and
    ``replace``. Subclasses are frozen dataclasses with ``rewards``, ``observations`` and
    ``metadata`` fields."""

    def __post_init__(self) -> None:
        if not isinstance(self.metadata, Metadata):
            object.__setattr__(self, "metadata", Metadata(self.metadata))

    @property
    def size(self) -> int:
        """Number of transitions ``N``."""
        return int(self.rewards.shape[0])

    def __len__(self) -> int:
        return self.size

    @property
    def observation_size(self) -> int:
        return int(self.observations.shape[-1])

    def replace(self, **changes: Any) -> Any:
        """A copy with some fields (or ``metadata``) replaced; not validated."""
        return dataclasses.replace(self, **changes)


@dataclasses.dataclass(frozen=True)
class Dataset(TransitionTable):
    """``N`` transitions as flat arrays plus static JSON metadata (see the module docstring).

    A pytree whose leaves are the seven arrays of :data:`FIELDS` (NumPy or JAX arrays); the
    ``metadata`` is static auxiliary data. Build one with :func:`create` (coerces flag and id
    dtypes, validates) or :func:`from_transitions`; the plain constructor does not validate (it
    also runs inside JAX transformations, on tracers).
    """

    observations: Any
    actions: Any
    rewards: Any
    next_observations: Any
    terminals: Any
    timeouts: Any
    episode_ids: Any
    metadata: Metadata = dataclasses.field(default_factory=Metadata)

    @property
    def action_size(self) -> int:
        return int(self.actions.shape[-1])

    def arrays(self) -> dict[str, Any]:
        """The array fields by name, in :data:`FIELDS` order."""
        return {name: getattr(self, name) for name in FIELDS}


jax.tree_util.register_dataclass(Dataset, data_fields=list(FIELDS), meta_fields=["metadata"])



def is_traced(x: Any) -> bool:
    """Whether ``x`` is a JAX tracer (value checks need concrete arrays)."""
    return isinstance(x, jax.core.Tracer)


def validate(dataset: Dataset, *, name: str = "dataset") -> Dataset:
    """Check the invariants of the module docstring; return ``dataset`` unchanged.

    Raises ``ValueError`` (``TypeError`` for a non-Dataset) naming ``name``, the field and what
    is wrong. Value checks (finite, flags, episode layout) need concrete arrays: they are
    skipped for traced ones.
    """
    if not isinstance(dataset, Dataset):
        raise TypeError(f"{name} must be an offline.data.dataset.Dataset, got "
                        f"{type(dataset).__name__}")
    arrays = dataset.arrays()
    for field, x in arrays.items():
        if not hasattr(x, "shape") or not hasattr(x, "dtype"):
            raise ValueError(f"{name}.{field} must be an array, got {type(x).__name__}")
        if x.ndim != _NDIM[field]:
            raise ValueError(f"{name}.{field} must have {_NDIM[field]} dimension(s), got shape "
                             f"{tuple(x.shape)}")
    n = arrays["rewards"].shape[0]
    sizes = {f: x.shape[0] for f, x in arrays.items()}
    if any(s != n for s in sizes.values()):
        raise ValueError(f"{name}: inconsistent leading sizes (number of transitions) {sizes}")
    if arrays["next_observations"].shape != arrays["observations"].shape:
        raise ValueError(f"{name}.next_observations has shape "
                         f"{tuple(arrays['next_observations'].shape)}, observations "
                         f"{tuple(arrays['observations'].shape)}; they must match")
    for field in _FLOAT_FIELDS:
        if not jnp.issubdtype(arrays[field].dtype, jnp.floating):
            raise ValueError(f"{name}.{field} must have a floating dtype, got "
                             f"{arrays[field].dtype}")
    if arrays["next_observations"].dtype != arrays["observations"].dtype:
        raise ValueError(f"{name}.next_observations dtype {arrays['next_observations'].dtype} "
                         f"differs from observations dtype {arrays['observations'].dtype}")
    for field in ("terminals", "timeouts"):
        if arrays[field].dtype != np.bool_:
            raise ValueError(f"{name}.{field} must have dtype bool, got {arrays[field].dtype} "
                             f"(use offline.data.dataset.create to convert 0/1 flags)")
    if arrays["episode_ids"].dtype != np.int32:
        raise ValueError(f"{name}.episode_ids must have dtype int32, got "
                         f"{arrays['episode_ids'].dtype}")
    if any(is_traced(x) for x in arrays.values()):
        return dataset

    np_arrays = {f: np.asarray(x) for f, x in arrays.items()}
    for field in _FLOAT_FIELDS:
        bad = ~np.isfinite(np_arrays[field])
        if bad.any():
            idx = np.argwhere(bad)[0]
            raise ValueError(f"{name}.{field} has {int(bad.sum())} non-finite value(s), the "
                             f"first at index {tuple(int(i) for i in idx)}: "
                             f"{np_arrays[field][tuple(idx)]}")
    limit = dataset.metadata.get("action_limit")
    if limit is not None and n:
        excess = np.abs(np_arrays["actions"]) > float(limit) * (1 + 1e-6)
        if excess.any():
            idx = np.argwhere(excess)[0]
            raise ValueError(f"{name}.actions has {int(excess.sum())} value(s) outside the action "
                             f"space [-{limit}, {limit}] (metadata['action_limit']), the first "
                             f"at index {tuple(int(i) for i in idx)}: "
                             f"{np_arrays['actions'][tuple(idx)]}")
    term, tout, ids = np_arrays["terminals"], np_arrays["timeouts"], np_arrays["episode_ids"]
    both = term & tout
    if both.any():
        raise ValueError(f"{name}: transition {int(np.argmax(both))} is both a terminal and a "
                         f"timeout ({int(both.sum())} such); an episode ends by one or the other "
                         f"(a terminal wins: clear its timeout)")
    if n and ids.min() < 0:
        raise ValueError(f"{name}.episode_ids must be >= 0, found {int(ids.min())}")
    if n:
        change = ids[1:] != ids[:-1]
        if int(change.sum()) + 1 != len(np.unique(ids)):
            raise ValueError(f"{name}: episodes are not contiguous (an episode id reappears "
                             f"after another episode); store each episode's transitions "
                             f"adjacently, in time order")
        ends = (term | tout)[:-1] & ~change
        if ends.any():
            i = int(np.argmax(ends))
            raise ValueError(f"{name}: transition {i} ends episode {int(ids[i])} (terminal or "
                             f"timeout) but transition {i + 1} continues it")
    return dataset


def environment_id(env: Any) -> str | None:
    """The :func:`envs.make` name of the environment object ``env`` (brax wrappers unwrapped),
    or None for an object that no registered constructor builds."""
    from envs.registry import ENVIRONMENTS  # lazy: holding an env means envs is loaded already
    inner = getattr(env, "unwrapped", env)
    for env_id, ctor in ENVIRONMENTS.items():
        cls = getattr(ctor, "func", ctor)
        if type(inner) is cls:
            bound = inspect.signature(cls).bind_partial(*getattr(ctor, "args", ()),
                                                        **getattr(ctor, "keywords", {}))
            if all(getattr(inner, k, None) == v for k, v in bound.arguments.items()):
                return env_id
    return None


def check_environment(dataset: Dataset, env: Any, *, name: str = "dataset") -> Dataset:
    """Refuse ``dataset`` for environment ``env`` (an object with ``observation_size``,
    ``action_size`` and ``action_limit``, e.g. from :func:`envs.make`) unless the environment id
    it was collected on (``metadata["env"]``) is ``env``'s (:func:`environment_id`), its
    observation and action sizes match and its actions lie in the environment's action box. A
    dataset without a recorded id is checked on sizes only, with a warning."""
    validate(dataset, name=name)
    from envs.registry import BRAX_NAMES  # lazy: holding an env means envs is loaded already
    recorded, target = dataset.metadata.get("env"), environment_id(env)
    label = target or type(env).__name__
    if recorded is None:
        warnings.warn(f"{name} records no environment id (metadata['env']); only its sizes are "
                      f"checked against {label}", UserWarning, stacklevel=2)
    elif target is not None and BRAX_NAMES.get(str(recorded), str(recorded)) != target:
        raise ValueError(f"{name} was collected on {recorded}, the learner's environment is "
                         f"{target}")
    for what, have, want in (("observation size", dataset.observation_size,
                              int(env.observation_size)),
                             ("action size", dataset.action_size, int(env.action_size))):
        if have != want:
            raise ValueError(f"{name} has {what} {have}, but the environment {label!r} expects "
                             f"{want}")
    limit = float(getattr(env, "action_limit", np.inf))
    if dataset.size and np.abs(np.asarray(dataset.actions)).max() > limit * (1 + 1e-6):
        raise ValueError(f"{name}.actions leave the environment's action space [-{limit}, "
                         f"{limit}] (largest |a| = {np.abs(np.asarray(dataset.actions)).max()})")
    return dataset


def create(observations: Any, actions: Any, rewards: Any, next_observations: Any,
           terminals: Any, timeouts: Any, episode_ids: Any,
           metadata: Mapping[str, Any] | None = None) -> Dataset:
    """A validated :class:`Dataset` from NumPy arrays (or array-likes, JAX arrays included).

    Float fields keep their dtype (they must be floating); ``terminals`` / ``timeouts`` are
    converted to ``bool`` (values must be 0/1) and ``episode_ids`` to ``int32`` (values must be
    integers in range).
    """
    def flags(x, field):
        x = np.asarray(x)
        if x.dtype != np.bool_:
            if x.size and not np.isin(x, (0, 1)).all():
                raise ValueError(f"{field} must contain only 0/1 (or bool) values")
            x = x.astype(bool)
        return x

    ids = np.asarray(episode_ids)
    if ids.dtype != np.int32:
        if ids.size and not (np.issubdtype(ids.dtype, np.integer)
                             or np.array_equal(ids, np.round(ids))):
            raise ValueError(f"episode_ids must be integers, got dtype {ids.dtype}")
        if ids.size and (ids.min() < 0 or ids.max() > np.iinfo(np.int32).max):
            raise ValueError("episode_ids must lie in [0, 2**31 - 1]")
        ids = ids.astype(np.int32)
    ds = Dataset(np.asarray(observations), np.asarray(actions), np.asarray(rewards),
                 np.asarray(next_observations), flags(terminals, "terminals"),
                 flags(timeouts, "timeouts"), ids, Metadata(metadata))
    return validate(ds)



def dense_episode_ids(ids: np.ndarray) -> np.ndarray:
    """Dense ids ``0 … K−1`` in order of appearance for contiguous episodes."""
    if ids.size == 0:
        return ids.astype(np.int32)
    new = np.concatenate([[0], np.cumsum(ids[1:] != ids[:-1])])
    return new.astype(np.int32)


def renumber_episodes(dataset: Dataset) -> Dataset:
    """The dataset with episode ids ``0 … K−1`` in order of appearance (host-side)."""
    return dataset.replace(episode_ids=dense_episode_ids(np.asarray(dataset.episode_ids)))


__all__ = [
    "FIELDS",
    "Dataset",
    "Metadata",
    "TransitionTable",
    "check_environment",
    "create",
    "dense_episode_ids",
    "environment_id",
    "is_traced",
    "renumber_episodes",
    "validate",
]
