"""Offline datasets: a pytree of transitions, versioned/checksummed files, and the operations the
offline learners need (thesis chapters 7–8, docs/design.md §2.4).

A :class:`Dataset` holds ``N`` transitions as flat arrays

====================  ===========  ==========================================================
field                 shape        meaning
====================  ===========  ==========================================================
``observations``      ``(N, O)``   float, the state ``s`` the action was taken in
``actions``           ``(N, A)``   float, the action ``a``
``rewards``           ``(N,)``     float, the reward ``r(s, a)`` (or a relabelling of it)
``next_observations`` ``(N, O)``   float, the state ``s'`` reached (the *terminal* one on the
                                   last transition of an episode, not a reset observation)
``terminals``         ``(N,)``     bool, the episode ended in an absorbing state (collision)
``timeouts``          ``(N,)``     bool, the episode was cut by a time limit (or by the end of
                                   the rollout); *not* a terminal: learners bootstrap through it
``episode_ids``       ``(N,)``     int32, which episode the transition belongs to
====================  ===========  ==========================================================

plus ``metadata``, a JSON-serialisable dict (environment, behaviour policy, seed, recipe,
relabelling, …) kept outside the array pytree: it is static auxiliary data, so a dataset can be
passed through ``jax.jit`` / ``jax.device_put`` and keeps its metadata. Terminals and timeouts
are kept apart because they mean different Bellman targets — ``r + γ(1 − d)V(s')`` uses
``d = terminal`` only — and because cutting episodes at collisions is what creates the length
bias of thesis §8.3.3.

Invariants (checked by :func:`validate`, which :func:`create`, :func:`from_transitions`,
:func:`save` and :func:`load` call): equal leading sizes, the dtypes above (floating arrays of
one dtype per field, ``bool`` flags, ``int32`` ids ≥ 0), finite values, no transition both a
terminal and a timeout, every episode *contiguous* (its transitions adjacent, in time order) and
an end flag only on the last transition of its episode. Episode ids need not be dense: filtering
and splitting keep the original ids (so parts can be traced back); :func:`concatenate` and
:func:`renumber_episodes` make them ``0 … K−1`` in order of appearance.

Files (:func:`save` / :func:`load`): an uncompressed ``.npz``-style zip archive with one ``.npy``
member per field and a ``header.json`` member holding the format name and
:data:`FORMAT_VERSION`, every field's dtype, shape and SHA-256 of its raw (C-order) bytes, a
SHA-256 over all of that and the metadata. It is written to a temporary file in the target
directory, flushed to disk and moved into place with ``os.replace`` (never half-written). Loading
checks the archive, the header, the version, each member's zip CRC, dtype, shape and SHA-256,
then :func:`validate`; any failure raises :class:`DatasetFileError` naming the file and what is
wrong. A round trip is bit-exact (dtypes and bytes preserved). ``numpy.load`` reads the arrays of
such a file too (``np.load(path)["rewards"]``, without any check).

Host-side vs in-graph: :func:`sample` is a pure, jittable function (``batch_size`` static);
:func:`relabel_rewards` is jittable when its ``fn`` is. Everything whose output size depends on
the data (:func:`from_transitions`, :func:`filter_episodes`, :func:`split_by_episode`,
:func:`concatenate`, :func:`episode_statistics`) runs on the host in NumPy; move the result to
the accelerator once with ``jax.device_put(dataset)``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import tempfile
import zipfile
from collections.abc import Callable, Iterator, Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

#: Version of the file layout written by :func:`save`; :func:`load` refuses any other.
FORMAT_VERSION = 1
#: Format name stored in every file's header.
FORMAT_NAME = "mjxrmp.offline.Dataset"
HEADER_MEMBER = "header.json"

#: Array fields in file and pytree order.
FIELDS = ("observations", "actions", "rewards", "next_observations", "terminals", "timeouts",
          "episode_ids")
_FLOAT_FIELDS = ("observations", "actions", "rewards", "next_observations")
_NDIM = {"observations": 2, "actions": 2, "rewards": 1, "next_observations": 2, "terminals": 1,
         "timeouts": 1, "episode_ids": 1}
#: Reward relabellings by name (thesis §8.3: zero, random U[0, 1] and negated rewards).
RELABELLINGS = ("zero", "random", "negated")
# Fixed zip member timestamp: the same dataset always gives the same file bytes.
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


class DatasetFileError(ValueError):
    """A dataset file that cannot be loaded (corrupted, truncated, tampered, other version)."""


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

    def replace(self, **changes: Any):
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


# --------------------------------------------------------------------------------------------
# Construction and validation


def _is_traced(x: Any) -> bool:
    return isinstance(x, jax.core.Tracer)


def validate(dataset: Dataset, *, name: str = "dataset") -> Dataset:
    """Check the invariants of the module docstring; return ``dataset`` unchanged.

    Raises ``ValueError`` (``TypeError`` for a non-Dataset) naming ``name``, the field and what
    is wrong. Value checks (finite, flags, episode layout) need concrete arrays: they are
    skipped for traced ones.
    """
    if not isinstance(dataset, Dataset):
        raise TypeError(f"{name} must be an offline.data.dataset.Dataset, got {type(dataset).__name__}")
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
    if any(_is_traced(x) for x in arrays.values()):
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


def check_environment(dataset: Dataset, env: Any, *, name: str = "dataset") -> Dataset:
    """Refuse ``dataset`` for environment ``env`` (an object with ``observation_size``,
    ``action_size`` and ``action_limit``, e.g. from :func:`envs.make`) unless its observation
    and action sizes match and its actions lie in the environment's action box."""
    validate(dataset, name=name)
    for what, have, want in (("observation size", dataset.observation_size,
                              int(env.observation_size)),
                             ("action size", dataset.action_size, int(env.action_size))):
        if have != want:
            raise ValueError(f"{name} has {what} {have}, but the environment "
                             f"{dataset.metadata.get('env', type(env).__name__)!r} expects {want}")
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


def _renumber(ids: np.ndarray) -> np.ndarray:
    """Dense ids ``0 … K−1`` in order of appearance for contiguous episodes."""
    if ids.size == 0:
        return ids.astype(np.int32)
    new = np.concatenate([[0], np.cumsum(ids[1:] != ids[:-1])])
    return new.astype(np.int32)


def renumber_episodes(dataset: Dataset) -> Dataset:
    """The dataset with episode ids ``0 … K−1`` in order of appearance (host-side)."""
    return dataset.replace(episode_ids=_renumber(np.asarray(dataset.episode_ids)))


def from_transitions(observations: Any, actions: Any, rewards: Any, dones: Any,
                     truncations: Any | None = None, *, next_observations: Any | None = None,
                     valid: Any | None = None, unfinished: str = "timeout",
                     metadata: Mapping[str, Any] | None = None) -> Dataset:
    """Flatten time-major rollout arrays ``(T, B, ...)`` into a validated :class:`Dataset`.

    Args:
      observations: ``(T, B, O)`` observations the actions were taken in, or ``(T + 1, B, O)``
        when ``next_observations`` is not given (then ``s'_t = observations[t + 1]``).
      actions: ``(T, B, A)``.
      rewards: ``(T, B)``.
      dones: ``(T, B)``, nonzero where the episode ends with this transition (collision or time
        limit), as brax's ``EpisodeWrapper`` / ``agents.ppo.train.Transition.dones``.
      truncations: ``(T, B)`` or None (no time limits), nonzero where the end is a time limit;
        must be a subset of ``dones``. A done that is not a truncation is a *terminal*, a
        truncation a *timeout*.
      next_observations: ``(T, B, O)``; required with auto-resetting environments
        (:func:`envs.wrappers.wrap`), whose observation after a done step is already the first
        one of the *next* episode — pass the observation reached before the reset.
      valid: ``(T, B)`` or None (all valid): transitions to keep, e.g. False after the end of
        an episode in a frozen rollout (:func:`envs.evaluate.make_rollout`). Invalid
        transitions are dropped before episodes are counted.
      unfinished: what to do with each environment's last episode when the rollout ends before
        its done: ``"timeout"`` (default) flags its last transition as a timeout — the rollout
        cut it, like a time limit; ``"drop"`` removes its transitions; ``"keep"`` keeps them
        without an end flag.
      metadata: JSON-serialisable dict stored with the dataset.

    Episode ids: along each environment's column an episode continues until a done; episodes
    are numbered ``0 … K−1`` environment by environment (environment 0's episodes in time
    order, then environment 1's, …), and the dataset stores each episode's transitions
    contiguously in that order. Host-side (NumPy); JAX inputs are copied to the host.
    """
    if unfinished not in ("timeout", "drop", "keep"):
        raise ValueError(f"unfinished must be 'timeout', 'drop' or 'keep', got {unfinished!r}")
    obs, act, rew = np.asarray(observations), np.asarray(actions), np.asarray(rewards)
    if act.ndim != 3:
        raise ValueError(f"actions must have shape (T, B, A), got {act.shape}")
    t, b = act.shape[:2]
    if rew.shape != (t, b):
        raise ValueError(f"rewards must have shape (T, B) = {(t, b)}, got {rew.shape}")
    if next_observations is None:
        if obs.ndim != 3 or obs.shape[:2] != (t + 1, b):
            raise ValueError(f"without next_observations, observations must have shape "
                             f"(T + 1, B, O) = ({t + 1}, {b}, O), got {obs.shape}")
        nxt, obs = obs[1:], obs[:-1]
    else:
        nxt = np.asarray(next_observations)
        if obs.ndim != 3 or obs.shape[:2] != (t, b):
            raise ValueError(f"observations must have shape (T, B, O) = ({t}, {b}, O), got "
                             f"{obs.shape}")
        if nxt.shape != obs.shape:
            raise ValueError(f"next_observations must have the shape of observations "
                             f"{obs.shape}, got {nxt.shape}")

    def mask(x, field, default):
        if x is None:
            return np.full((t, b), default)
        x = np.asarray(x)
        if x.shape != (t, b):
            raise ValueError(f"{field} must have shape (T, B) = {(t, b)}, got {x.shape}")
        return x != 0

    done = mask(dones, "dones", False)
    trunc = mask(truncations, "truncations", False)
    keep = mask(valid, "valid", True)
    if (trunc & ~done).any():
        i = np.argwhere(trunc & ~done)[0]
        raise ValueError(f"truncations must be a subset of dones; step {int(i[0])} of "
                         f"environment {int(i[1])} is truncated but not done")

    # Environment-major order: (B, T, ...) flattened, so each episode is contiguous.
    def flat(x):
        return np.swapaxes(x, 0, 1).reshape((b * t, *x.shape[2:]))

    done_v = done & keep
    local = np.cumsum(done_v, axis=0) - done_v  # episodes finished before step t, per env
    n_done = done_v.sum(axis=0)  # (B,)
    open_tail = keep & (local == n_done[None, :])  # transitions of an unfinished last episode
    has_open = open_tail.any(axis=0)
    timeout = trunc & keep
    if unfinished == "drop":
        keep = keep & ~open_tail
    elif unfinished == "timeout":
        last = t - 1 - np.argmax(open_tail[::-1], axis=0)  # last open step per env
        cols = np.nonzero(has_open)[0]
        timeout[last[cols], cols] = True
    per_env = n_done + (has_open & (unfinished != "drop"))
    offset = np.concatenate([[0], np.cumsum(per_env)[:-1]])
    ids = local + offset[None, :]

    sel = flat(keep)
    ds = create(flat(obs)[sel], flat(act)[sel], flat(rew)[sel], flat(nxt)[sel],
                flat(done & ~trunc)[sel], flat(timeout)[sel], _renumber(flat(ids)[sel]),
                metadata)
    return ds


# --------------------------------------------------------------------------------------------
# Files


def _digest(x: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest()


def _total_digest(fields: Mapping[str, Mapping[str, Any]], metadata: Any) -> str:
    """SHA-256 over every field's name, dtype, shape and digest, and the canonical metadata."""
    h = hashlib.sha256()
    for name in FIELDS:
        f = fields[name]
        h.update(f"{name}:{f['dtype']}:{f['shape']}:{f['sha256']};".encode())
    h.update(json.dumps(metadata, sort_keys=True, allow_nan=False).encode())
    return h.hexdigest()


def _header(arrays: Mapping[str, np.ndarray], metadata: Metadata) -> dict[str, Any]:
    fields = {name: {"dtype": arrays[name].dtype.str, "shape": list(arrays[name].shape),
                     "sha256": _digest(arrays[name])} for name in FIELDS}
    return {"format": FORMAT_NAME, "format_version": FORMAT_VERSION, "fields": fields,
            "sha256": _total_digest(fields, metadata.to_dict()), "metadata": metadata.to_dict()}


def save(dataset: Dataset, path: str | os.PathLike) -> str:
    """Write ``dataset`` to ``path`` atomically (see the module docstring); return the path.

    The dataset is validated first. The path is used as given (no suffix is added; ``.npz`` is
    the convention). Parent directories are created.
    """
    validate(dataset)
    path = os.fspath(path)
    arrays = {name: np.ascontiguousarray(np.asarray(x)) for name, x in dataset.arrays().items()}
    header = json.dumps(_header(arrays, dataset.metadata), indent=1, sort_keys=True)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{os.path.basename(path)}.",
                               suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            with zipfile.ZipFile(f, "w", compression=zipfile.ZIP_STORED) as zf:
                zf.writestr(zipfile.ZipInfo(HEADER_MEMBER, _ZIP_DATE), header)
                for name in FIELDS:
                    buf = io.BytesIO()
                    np.lib.format.write_array(buf, arrays[name], allow_pickle=False)
                    zf.writestr(zipfile.ZipInfo(f"{name}.npy", _ZIP_DATE), buf.getvalue())
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def load(path: str | os.PathLike) -> Dataset:
    """Read a dataset written by :func:`save`, refusing anything corrupted.

    Returns NumPy arrays (``jax.device_put`` the result to use it on an accelerator). Raises
    :class:`DatasetFileError` (a ``ValueError``) naming the file and the problem: not a zip
    archive or truncated, missing/unreadable header, another format or version, missing or
    unexpected members, zip CRC error, dtype/shape differing from the header, SHA-256
    mismatch, or invalid contents (:func:`validate`); ``FileNotFoundError`` if it is absent.
    """
    path = os.fspath(path)

    def fail(msg: str) -> DatasetFileError:
        return DatasetFileError(f"dataset file {path!r}: {msg}")

    if not os.path.exists(path):
        raise FileNotFoundError(f"dataset file {path!r} does not exist")
    try:
        zf = zipfile.ZipFile(path, "r")
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        raise fail(f"not a readable zip archive (truncated or corrupted?): {e}") from e
    with zf:
        members = set(zf.namelist())
        if HEADER_MEMBER not in members:
            raise fail(f"no {HEADER_MEMBER} member (not written by offline.data.dataset.save?)")
        try:
            header = json.loads(zf.read(HEADER_MEMBER).decode("utf-8"))
        except (zipfile.BadZipFile, OSError, EOFError, UnicodeDecodeError, ValueError) as e:
            raise fail(f"unreadable {HEADER_MEMBER} (corrupted?): {e}") from e
        if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
            fmt = header.get("format") if isinstance(header, dict) else None
            raise fail(f"header format is {fmt!r}, expected {FORMAT_NAME!r}")
        if header.get("format_version") != FORMAT_VERSION:
            raise fail(f"format_version {header.get('format_version')!r} is not supported "
                       f"(this code reads version {FORMAT_VERSION})")
        fields = header.get("fields")
        if not isinstance(fields, dict) or set(fields) != set(FIELDS):
            got = sorted(fields) if isinstance(fields, dict) else fields
            raise fail(f"header lists fields {got}, expected {sorted(FIELDS)}")
        for name in FIELDS:
            f = fields[name]
            if not (isinstance(f, dict) and {"dtype", "shape", "sha256"} <= set(f)):
                raise fail(f"header entry for field {name!r} lacks dtype/shape/sha256: {f!r}")
        try:
            total = _total_digest(fields, header.get("metadata"))
        except (TypeError, ValueError) as e:
            raise fail(f"header metadata is not canonical JSON: {e}") from e
        if header.get("sha256") != total:
            raise fail("header checksum mismatch (the header or metadata was modified or "
                       "corrupted)")
        expected = {HEADER_MEMBER} | {f"{n}.npy" for n in FIELDS}
        if members - expected:
            raise fail(f"unexpected member(s) {sorted(members - expected)}")
        arrays = {}
        for name in FIELDS:
            member, f = f"{name}.npy", fields[name]
            if member not in members:
                raise fail(f"field {name!r} is missing (no member {member!r})")
            try:
                raw = zf.read(member)  # checks the zip CRC-32
                x = np.lib.format.read_array(io.BytesIO(raw), allow_pickle=False)
            except (zipfile.BadZipFile, OSError, EOFError, ValueError) as e:
                raise fail(f"field {name!r} is corrupted ({e})") from e
            if x.dtype.str != f["dtype"] or list(x.shape) != list(f["shape"]):
                raise fail(f"field {name!r} has dtype {x.dtype.str} and shape "
                           f"{list(x.shape)}, the header says {f['dtype']} and {f['shape']}")
            if _digest(x) != f["sha256"]:
                raise fail(f"field {name!r} SHA-256 checksum mismatch (the array data was "
                           f"modified or corrupted)")
            arrays[name] = x
    try:
        ds = Dataset(**arrays, metadata=Metadata(header["metadata"]))
        return validate(ds, name=os.path.basename(path))
    except (TypeError, ValueError) as e:
        raise fail(f"invalid contents: {e}") from e


# --------------------------------------------------------------------------------------------
# In-graph operations


def sample(dataset: Dataset, key: jax.Array, batch_size: int) -> Dataset:
    """A minibatch of ``batch_size`` transitions drawn uniformly with replacement.

    Pure and jittable (``batch_size`` static: ``jax.jit(sample, static_argnames="batch_size")``
    or a closure); the result is a :class:`Dataset` of ``batch_size`` rows with the same
    metadata. Indices come from ``jax.random.randint(key, (batch_size,), 0, N)``.
    """
    return sample_with(dataset, None, key, batch_size)[0]


def sample_with(dataset: Dataset, rows: Any, key: jax.Array, batch_size: int
                ) -> tuple[Dataset, Any]:
    """:func:`sample` together with the same rows of ``rows``, a pytree of per-transition arrays
    (leading size ``N``, e.g. values precomputed for every transition; ``None`` leaves stay
    ``None``). The minibatch is the one :func:`sample` draws with ``key``."""
    if not isinstance(batch_size, int | np.integer) or batch_size <= 0:
        raise ValueError(f"batch_size must be a positive (static) integer, got {batch_size!r}")
    n = dataset.rewards.shape[0]
    if n == 0:
        raise ValueError("cannot sample from an empty dataset (N = 0)")
    bad = [x.shape for x in jax.tree.leaves(rows) if x.shape[:1] != (n,)]
    if bad:
        raise ValueError(f"rows must have one entry per transition ({n}), got shapes {bad}")
    idx = jax.random.randint(key, (int(batch_size),), 0, n)
    take = lambda x: jnp.take(x, idx, axis=0)  # noqa: E731
    return jax.tree.map(take, dataset), jax.tree.map(take, rows)


def relabel_rewards(dataset: Dataset, fn: str | Callable[[Dataset], Any] | Any, *,
                    key: jax.Array | None = None) -> Dataset:
    """The dataset with new rewards (thesis §8.3 wrong-reward experiments, PLfO labelling).

    ``fn`` is one of

    * ``"zero"`` — all rewards 0; ``"negated"`` — ``−r``; ``"random"`` — i.i.d. ``U[0, 1]``
      (needs ``key``);
    * a callable ``fn(dataset) -> (N,)`` array (e.g. a learned reward model applied to
      ``observations`` / ``next_observations``);
    * an ``(N,)`` array of rewards.

    The new rewards keep the dataset's reward dtype. The relabelling is recorded in
    ``metadata["reward_relabel"]`` (a list, oldest first). Jittable when ``fn`` is (the
    finiteness check runs only on concrete arrays).
    """
    rewards = dataset.rewards
    n, dtype = rewards.shape[0], rewards.dtype
    if isinstance(fn, str):
        if fn not in RELABELLINGS:
            raise ValueError(f"unknown relabelling fn={fn!r}; valid names are "
                             f"{list(RELABELLINGS)} or a callable / array")
        if fn == "zero":
            new = jnp.zeros_like(rewards)
        elif fn == "negated":
            new = -rewards
        else:
            if key is None:
                raise ValueError("relabel_rewards(fn='random') needs a PRNG key (key=...)")
            new = jax.random.uniform(key, (n,), dtype=dtype)
        label = fn
    elif callable(fn):
        new = fn(dataset)
        label = getattr(fn, "__name__", type(fn).__name__)
    else:
        new = fn
        label = "array"
    if not hasattr(new, "shape"):
        new = np.asarray(new)
    if tuple(new.shape) != (n,):
        raise ValueError(f"relabelled rewards must have shape ({n},), got {tuple(new.shape)}")
    new = new.astype(dtype)
    if not _is_traced(new) and not np.isfinite(np.asarray(new)).all():
        raise ValueError(f"relabelled rewards ({label}) contain non-finite values")
    history = list(dataset.metadata.get("reward_relabel", []))
    return dataset.replace(rewards=new,
                           metadata=dataset.metadata.updated(reward_relabel=[*history, label]))


# --------------------------------------------------------------------------------------------
# Host-side episode operations


class EpisodeStats(NamedTuple):
    """Per-episode arrays (NumPy, one entry per episode in order of appearance)."""

    episode_ids: np.ndarray  # int32 (K,)
    returns: np.ndarray  # float64 (K,), undiscounted sum of rewards
    lengths: np.ndarray  # int64 (K,), number of transitions
    terminated: np.ndarray  # bool (K,), the last transition is a terminal
    timed_out: np.ndarray  # bool (K,), the last transition is a timeout


def episode_bounds(ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start index and length of each contiguous episode of the ``episode_ids`` array ``ids``."""
    if ids.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    starts = np.concatenate([[0], np.nonzero(ids[1:] != ids[:-1])[0] + 1])
    lengths = np.diff(np.concatenate([starts, [ids.size]]))
    return starts, lengths


def episode_statistics(dataset: Dataset) -> tuple[EpisodeStats, dict[str, Any]]:
    """``(per_episode, summary)`` of a (valid, contiguous-episode) dataset.

    ``per_episode`` is an :class:`EpisodeStats`; ``summary`` a JSON-ready dict:
    ``num_transitions``, ``num_episodes``, ``return_mean`` / ``return_std`` (population) /
    ``return_min`` / ``return_max`` (NaN with no episodes), ``length_mean``, and how episodes
    ended: ``num_terminals``, ``num_timeouts``, ``num_unfinished`` (no end flag). Returns are
    accumulated in float64.
    """
    ids = np.asarray(dataset.episode_ids)
    rewards = np.asarray(dataset.rewards, dtype=np.float64)
    starts, lengths = episode_bounds(ids)
    k = starts.size
    if k:
        returns = np.add.reduceat(rewards, starts)
        last = starts + lengths - 1
    else:
        returns, last = np.zeros(0), np.zeros(0, np.int64)
    per = EpisodeStats(ids[starts].astype(np.int32), returns, lengths.astype(np.int64),
                       np.asarray(dataset.terminals)[last].astype(bool),
                       np.asarray(dataset.timeouts)[last].astype(bool))

    def stat(f):
        return float(f(returns)) if k else float("nan")

    summary = {
        "num_transitions": int(ids.size),
        "num_episodes": int(k),
        "return_mean": stat(np.mean),
        "return_std": stat(np.std),
        "return_min": stat(np.min),
        "return_max": stat(np.max),
        "length_mean": float(lengths.mean()) if k else float("nan"),
        "num_terminals": int(per.terminated.sum()),
        "num_timeouts": int(per.timed_out.sum()),
        "num_unfinished": int((~per.terminated & ~per.timed_out).sum()),
    }
    return per, summary


def take_rows(dataset: Dataset, rows: np.ndarray) -> Dataset:
    """The transitions ``rows`` (a boolean mask or indices) of ``dataset``, host-side."""
    return jax.tree.map(lambda x: np.asarray(x)[rows], dataset)


def filter_episodes(dataset: Dataset,
                    mask: Callable[[EpisodeStats], Any] | Any) -> Dataset:
    """Keep whole episodes (host-side); episode ids and order are kept.

    ``mask`` is a boolean array with one entry per episode, in order of appearance (the order
    of :func:`episode_statistics`), or a callable ``mask(per_episode: EpisodeStats)`` returning
    one, e.g. ``lambda ep: ~ep.terminated`` (drop episodes that ended in a collision, thesis
    §8.4) or ``lambda ep: ep.returns > 50``.
    """
    per, _ = episode_statistics(dataset)
    m = mask(per) if callable(mask) else mask
    m = np.asarray(m)
    k = per.episode_ids.size
    if m.shape != (k,):
        raise ValueError(f"episode mask must have shape (num_episodes,) = ({k},), got {m.shape}")
    if m.dtype != np.bool_:
        raise ValueError(f"episode mask must be boolean, got dtype {m.dtype}")
    _, lengths = episode_bounds(np.asarray(dataset.episode_ids))
    rows = np.repeat(m, lengths) if k else np.zeros(0, bool)
    return take_rows(dataset, rows)


def split_by_episode(dataset: Dataset, fraction: float,
                     key: jax.Array) -> tuple[Dataset, Dataset]:
    """Split whole episodes at random into ``(first, second)`` (host-side).

    ``first`` gets ``round(fraction · K)`` of the ``K`` episodes, chosen uniformly at random
    with ``key``; ``second`` the rest. No episode straddles both; each part keeps the original
    episode ids and order. ``fraction`` must lie in [0, 1].
    """
    if not 0.0 <= float(fraction) <= 1.0:
        raise ValueError(f"fraction must lie in [0, 1], got {fraction!r}")
    _, lengths = episode_bounds(np.asarray(dataset.episode_ids))
    k = lengths.size
    n_first = round(float(fraction) * k)
    perm = np.asarray(jax.random.permutation(key, k))
    first = np.zeros(k, bool)
    first[perm[:n_first]] = True
    return filter_episodes(dataset, first), filter_episodes(dataset, ~first)


def concatenate(*datasets: Dataset, metadata: Mapping[str, Any] | None = None) -> Dataset:
    """One dataset with all transitions, in argument order (host-side).

    Episode ids are renumbered ``0 … K−1`` in order of appearance, so episodes of different
    inputs never share an id. Observation/action sizes and dtypes must agree. ``metadata``
    defaults to ``{"concatenated": [metadata of each input, …]}``.
    """
    if not datasets:
        raise ValueError("concatenate needs at least one dataset")
    for i, ds in enumerate(datasets):
        validate(ds, name=f"datasets[{i}]")
    ref = datasets[0]
    for i, ds in enumerate(datasets[1:], start=1):
        for field in FIELDS:
            a, b = getattr(ref, field), getattr(ds, field)
            if a.shape[1:] != b.shape[1:] or a.dtype != b.dtype:
                raise ValueError(f"datasets[{i}].{field} has shape {tuple(b.shape)} and dtype "
                                 f"{b.dtype}, datasets[0] {tuple(a.shape)} and {a.dtype}; "
                                 f"trailing shapes and dtypes must agree")
    arrays = {f: np.concatenate([np.asarray(getattr(ds, f)) for ds in datasets])
              for f in FIELDS}
    # Offset each input so equal ids of different inputs stay distinct, then make them dense.
    ids, offset = [], 0
    for ds in datasets:
        local = _renumber(np.asarray(ds.episode_ids)).astype(np.int64)
        ids.append(local + offset)
        offset += int(local.max()) + 1 if local.size else 0
    arrays["episode_ids"] = _renumber(np.concatenate(ids))
    if metadata is None:
        metadata = {"concatenated": [ds.metadata.to_dict() for ds in datasets]}
    return validate(Dataset(**arrays, metadata=Metadata(metadata)))


__all__ = [
    "FIELDS",
    "FORMAT_VERSION",
    "RELABELLINGS",
    "Dataset",
    "DatasetFileError",
    "EpisodeStats",
    "Metadata",
    "TransitionTable",
    "check_environment",
    "concatenate",
    "create",
    "episode_bounds",
    "episode_statistics",
    "filter_episodes",
    "from_transitions",
    "load",
    "relabel_rewards",
    "renumber_episodes",
    "sample",
    "sample_with",
    "save",
    "split_by_episode",
    "take_rows",
    "validate",
]
