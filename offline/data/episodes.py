"""Host-side episode operations on datasets: building one from time-major rollout arrays
(:func:`from_transitions`), per-episode statistics, filtering, splitting and concatenating whole
episodes (NumPy; docs/design.md §2.4)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import jax
import numpy as np

from offline.data.table import FIELDS, Dataset, Metadata, create, dense_episode_ids, validate


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
        limit), as brax's ``EpisodeWrapper`` / ``agents.ppo.state.Transition.dones``.
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
    obs, act, rew, nxt = _time_major(observations, actions, rewards, next_observations)
    t, b = act.shape[:2]

    def mask(x, field, default):
        if x is None:
            return np.full((t, b), default)
        x = np.asarray(x)
        if x.shape != (t, b):
            raise ValueError(f"{field} must have shape (T, B) = {(t, b)}, got {x.shape}")
        return x != 0

    done = mask(dones, "dones", False)
    trunc = mask(truncations, "truncations", False)
    if (trunc & ~done).any():
        i = np.argwhere(trunc & ~done)[0]
        raise ValueError(f"truncations must be a subset of dones; step {int(i[0])} of "
                         f"environment {int(i[1])} is truncated but not done")
    keep, timeout, ids = _episode_layout(done, trunc, mask(valid, "valid", True), unfinished)

    # Environment-major order: (B, T, ...) flattened, so each episode is contiguous.
    def flat(x):
        return np.swapaxes(x, 0, 1).reshape((b * t, *x.shape[2:]))

    sel = flat(keep)
    return create(flat(obs)[sel], flat(act)[sel], flat(rew)[sel], flat(nxt)[sel],
                  flat(done & ~trunc)[sel], flat(timeout)[sel],
                  dense_episode_ids(flat(ids)[sel]), metadata)


def _time_major(observations: Any, actions: Any, rewards: Any, next_observations: Any | None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(observations, actions, rewards, next_observations)`` as checked ``(T, B, ...)`` NumPy
    arrays (:func:`from_transitions`'s shape rules)."""
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
        return obs[:-1], act, rew, obs[1:]
    nxt = np.asarray(next_observations)
    if obs.ndim != 3 or obs.shape[:2] != (t, b):
        raise ValueError(f"observations must have shape (T, B, O) = ({t}, {b}, O), got "
                         f"{obs.shape}")
    if nxt.shape != obs.shape:
        raise ValueError(f"next_observations must have the shape of observations "
                         f"{obs.shape}, got {nxt.shape}")
    return obs, act, rew, nxt


def _episode_layout(done: np.ndarray, trunc: np.ndarray, keep: np.ndarray, unfinished: str
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(keep, timeout, ids)`` ``(T, B)`` masks and episode ids of :func:`from_transitions`:
    episodes numbered environment by environment, each environment's unfinished last episode
    handled as ``unfinished`` says."""
    t = done.shape[0]
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
    return keep, timeout, local + offset[None, :]




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
        local = dense_episode_ids(np.asarray(ds.episode_ids)).astype(np.int64)
        ids.append(local + offset)
        offset += int(local.max()) + 1 if local.size else 0
    arrays["episode_ids"] = dense_episode_ids(np.concatenate(ids))
    if metadata is None:
        metadata = {"concatenated": [ds.metadata.to_dict() for ds in datasets]}
    return validate(Dataset(**arrays, metadata=Metadata(metadata)))



__all__ = [
    "EpisodeStats",
    "concatenate",
    "episode_bounds",
    "episode_statistics",
    "filter_episodes",
    "from_transitions",
    "split_by_episode",
    "take_rows",
]
