"""Minari datasets (Minari 0.5.4, the optional ``minari`` extra) to and from our
:class:`~offline.data.dataset.Dataset` (docs/design.md §2.4).

:func:`export_minari` writes a dataset as a local Minari dataset (HDF5): Box observation and
action spaces of the data's dtypes (actions bounded by ``metadata["action_limit"]``, else by the
recorded environment's action limit, else unbounded), one Minari episode per run of chaining
transitions of one of our episodes (``next_observations[t] == observations[t + 1]``, bitwise; an
episode whose observations do not chain is cut into several), terminals as ``terminations`` and
timeouts as ``truncations``. Our JSON metadata is kept as JSON text under the Minari metadata key
:data:`METADATA_KEY`, each Minari episode's own episode id under the episode attribute
:data:`EPISODE_KEY`; reference returns (``metadata["reference"]`` with ``expert_return`` and
``random_return``) also become Minari's ``ref_max_score`` / ``ref_min_score``. The dataset is
written into a temporary folder next to its target and renamed into place, so no half-written
dataset carries the id.

:func:`import_minari` reads any Minari dataset whose spaces are floating-point Boxes (others raise
``ValueError`` naming the space): every Minari episode's ``T`` steps become ``T`` transitions
(observations ``[0, T)``, next observations ``[1, T]``), ``terminations`` become terminals and
``truncations`` timeouts (a step that is both is a terminal). Episode ids and metadata come from
:data:`EPISODE_KEY` / :data:`METADATA_KEY` where our exporter wrote them — the round trip is
exact — else the Minari episode indices and a metadata naming the source (Minari's reference
scores as ``reference``). ``scripts/train_offline.py --dataset minari:ID_OR_PATH`` trains on one
(:func:`offline.experiment.single.read_dataset`).

Dataset ids are Minari's ``(namespace/)name-v<version>``; a dataset lives in ``root/<id>/data``
where ``root`` defaults to Minari's own (``$MINARI_DATASETS_PATH``, else ``~/.minari/datasets``),
so ``minari.load_dataset(id)`` finds what :func:`export_minari` writes there. An exported
dataset records no Gymnasium ``env_spec`` (``recover_environment`` is unavailable); the
environment is named in our metadata (``metadata["env"]``, an :func:`envs.make` name).
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
from pathlib import Path
from typing import Any

import gymnasium as gym
import minari
import numpy as np
from minari.data_collector import EpisodeBuffer
from minari.dataset.minari_dataset import parse_dataset_id
from minari.dataset.minari_storage import MinariStorage
from minari.storage import get_dataset_path

from offline.data import dataset as odata
from offline.data.rollouts import make_env

#: Minari metadata key holding our metadata as JSON text.
METADATA_KEY = "mjxrmp_metadata"
#: Minari episode attribute holding our episode id.
EPISODE_KEY = "mjxrmp_episode_id"


def _action_bound(metadata: odata.Metadata) -> float:
    """The action box half-width: ``metadata["action_limit"]``, else the recorded environment's
    limit, else infinity."""
    if metadata.get("action_limit") is not None:
        return float(metadata["action_limit"])
    if metadata.get("env") is not None:
        return float(make_env(str(metadata["env"]), metadata.get("env_kwargs")).action_limit)
    return float("inf")


def _segments(dataset: odata.Dataset) -> list[tuple[int, int]]:
    """``[start, stop)`` row ranges of the Minari episodes: cut where the episode id changes or
    the observations do not chain (bitwise)."""
    def bits(x: Any) -> np.ndarray:  # compared bitwise: -0.0 and 0.0 differ
        x = np.ascontiguousarray(x)
        return x.view(f"u{x.dtype.itemsize}")

    obs, nxt = bits(dataset.observations), bits(dataset.next_observations)
    ids = np.asarray(dataset.episode_ids)
    cut = (ids[1:] != ids[:-1]) | np.any(nxt[:-1] != obs[1:], axis=1)
    starts = [0, *(np.flatnonzero(cut) + 1).tolist()]
    return list(zip(starts, [*starts[1:], dataset.size], strict=True))


def _buffers(dataset: odata.Dataset) -> tuple[list[EpisodeBuffer], list[dict[str, int]]]:
    """The Minari episode buffers of ``dataset`` and each one's episode attributes."""
    a = {k: np.asarray(v) for k, v in dataset.arrays().items()}
    buffers, attrs = [], []
    for start, stop in _segments(dataset):
        rows = slice(start, stop)
        buffers.append(EpisodeBuffer(
            observations=np.concatenate([a["observations"][rows],
                                         a["next_observations"][stop - 1:stop]]),
            actions=a["actions"][rows], rewards=a["rewards"][rows],
            terminations=a["terminals"][rows], truncations=a["timeouts"][rows], infos={}))
        attrs.append({EPISODE_KEY: int(a["episode_ids"][start])})
    return buffers, attrs


def _minari_metadata(dataset: odata.Dataset, dataset_id: str) -> dict[str, Any]:
    """The Minari dataset metadata: id, version, description, our metadata (JSON text) and the
    reference scores when ours carry them."""
    meta = dataset.metadata
    out: dict[str, Any] = {
        "dataset_id": dataset_id, "minari_version": minari.__version__,
        "author": {"mjxrmp"}, "algorithm_name": str(meta.get("recipe", "mjxrmp offline data")),
        "description": f"mjxrmp offline dataset on {meta.get('env', 'an unnamed environment')} "
                       f"({dataset.size} transitions), exported by offline.data.minari",
        METADATA_KEY: json.dumps(meta.to_dict(), sort_keys=True)}
    ref = meta.get("reference")
    if isinstance(ref, dict) and {"expert_return", "random_return"} <= ref.keys():
        out["ref_max_score"] = float(ref["expert_return"])
        out["ref_min_score"] = float(ref["random_return"])
    return out


def export_minari(dataset: odata.Dataset, dataset_id: str, root: str | os.PathLike | None = None
                  ) -> Path:
    """Write ``dataset`` as the local Minari dataset ``dataset_id`` under ``root`` (default:
    Minari's root) and return its folder ``root/<dataset_id>`` (module docstring). Refuses an
    id that is malformed or already present there (``ValueError`` / ``FileExistsError``)."""
    odata.validate(dataset)
    if not dataset.size:
        raise ValueError("dataset has no transitions; a Minari dataset needs an episode")
    try:
        parse_dataset_id(dataset_id)
    except (ValueError, TypeError):
        raise ValueError(f"dataset_id must look like (namespace/)name-v<version>, got "
                         f"{dataset_id!r}") from None
    target = Path(root if root is not None else get_dataset_path()) / dataset_id
    if target.exists():
        raise FileExistsError(f"dataset_id {dataset_id!r} already exists at {target}")
    target.parent.mkdir(parents=True, exist_ok=True)
    obs, act = np.asarray(dataset.observations), np.asarray(dataset.actions)
    bound = _action_bound(dataset.metadata)
    spaces = {"observation_space": gym.spaces.Box(-np.inf, np.inf, obs.shape[1:], obs.dtype),
              "action_space": gym.spaces.Box(-bound, bound, act.shape[1:], act.dtype)}
    tmp = target.parent / f".{target.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"
    tmp.mkdir()
    try:
        storage = MinariStorage.new(tmp / "data", data_format="hdf5", **spaces)
        storage.update_metadata(_minari_metadata(dataset, dataset_id))
        buffers, attrs = _buffers(dataset)
        storage.update_episodes(buffers)
        storage.update_episode_metadata(attrs)
        os.rename(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target


def locate(source: str | os.PathLike, root: str | os.PathLike | None = None) -> Path:
    """The ``data`` folder of the Minari dataset ``source`` (a dataset folder, its ``data``
    folder or a dataset id under ``root`` / Minari's root)."""
    path = Path(source)
    for candidate in (path / "data", path):
        if (candidate / "metadata.json").is_file():
            return candidate
    base = Path(root) if root is not None else get_dataset_path()
    by_id = base / str(source) / "data"
    if (by_id / "metadata.json").is_file():
        return by_id
    raise FileNotFoundError(f"dataset_id_or_path {str(source)!r}: no Minari dataset there nor "
                            f"under {base} (expected <folder>/data/metadata.json)")


def _box(space: gym.Space, what: str, source: str) -> gym.spaces.Box:
    """``space`` if it is a floating-point Box, else ``ValueError`` naming it."""
    if not (isinstance(space, gym.spaces.Box) and np.issubdtype(space.dtype, np.floating)):
        raise ValueError(f"Minari dataset {source!r}: {what} {space} is not a continuous Box; "
                         f"only floating-point Box spaces can be imported")
    return space


def _foreign_metadata(meta: dict[str, Any], action: gym.spaces.Box) -> dict[str, Any]:
    """A metadata naming the Minari source of a dataset our exporter did not write."""
    out: dict[str, Any] = {"source": "minari", "minari_dataset_id": meta.get("dataset_id")}
    if meta.get("env_spec") is not None:
        out["minari_env_spec"] = meta["env_spec"]
    low, high = np.asarray(action.low), np.asarray(action.high)
    if np.isfinite(high).all() and np.array_equal(low, -high) and np.ptp(high) == 0:
        out["action_limit"] = float(high.flat[0])
    if meta.get("ref_max_score") is not None and meta.get("ref_min_score") is not None:
        out["reference"] = {"expert_return": float(meta["ref_max_score"]),
                            "random_return": float(meta["ref_min_score"])}
    return out


def import_minari(dataset_id_or_path: str | os.PathLike,
                  root: str | os.PathLike | None = None) -> odata.Dataset:
    """The :class:`~offline.data.dataset.Dataset` of a Minari dataset with floating-point Box
    spaces, given by id (under ``root``, default Minari's root) or folder (module docstring)."""
    source = str(dataset_id_or_path)
    mds = minari.MinariDataset(locate(dataset_id_or_path, root))
    _box(mds.observation_space, "observation_space", source)
    act_space = _box(mds.action_space, "action_space", source)
    meta = mds.storage.metadata
    indices = [int(i) for i in mds.episode_indices]
    if not indices:
        raise ValueError(f"Minari dataset {source!r} has no episodes")
    attrs = list(mds.storage.get_episode_metadata(indices))
    ours = all(EPISODE_KEY in a for a in attrs)
    parts: dict[str, list[np.ndarray]] = {f: [] for f in odata.FIELDS}
    for ep, attr in zip(mds.iterate_episodes(indices), attrs, strict=True):
        o = np.asarray(ep.observations).reshape(len(ep) + 1, -1)
        term = np.asarray(ep.terminations, bool)
        parts["observations"].append(o[:-1])
        parts["next_observations"].append(o[1:])
        parts["actions"].append(np.asarray(ep.actions).reshape(len(ep), -1))
        parts["rewards"].append(np.asarray(ep.rewards))
        parts["terminals"].append(term)
        parts["timeouts"].append(np.asarray(ep.truncations, bool) & ~term)
        parts["episode_ids"].append(np.full(len(ep), attr[EPISODE_KEY] if ours else ep.id))
    arrays = {f: np.concatenate(p) for f, p in parts.items()}
    if not np.issubdtype(arrays["rewards"].dtype, np.floating):
        arrays["rewards"] = arrays["rewards"].astype(np.float32)
    metadata = (json.loads(meta[METADATA_KEY]) if METADATA_KEY in meta
                else _foreign_metadata(meta, act_space))
    return odata.create(**arrays, metadata=metadata)


__all__ = ["EPISODE_KEY", "METADATA_KEY", "export_minari", "import_minari", "locate"]
