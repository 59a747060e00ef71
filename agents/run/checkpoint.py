"""Orbax checkpoints of a training run: the whole state pytree plus a JSON description.

A checkpoint directory holds orbax steps (``<dir>/<iteration>/``), each with two items:

* ``state`` — every non-empty array leaf of the run's state pytree (a
  :class:`agents.ppo.state.TrainState`, possibly with a leading seed axis), saved as a flat
  ``{"leaf_00042": array}`` dict. Flattening keeps orbax away from MJX's zero-size arrays
  (which it refuses to write) and makes the structure check explicit: restoring needs a
  *template* of the expected state (e.g. ``jax.eval_shape`` of the trainer's ``init``) and
  refuses a checkpoint whose leaves differ.
* ``meta`` — JSON: what the run is (environment, policy kind, configuration), the iteration, the
  metric history, anything the caller adds.

Orbax writes each step to a temporary directory and renames it when complete, so an interrupted
save never leaves a half-written checkpoint behind; ``max_to_keep`` old steps are kept.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

FORMAT_VERSION = 1


class IncompatibleCheckpointError(ValueError):
    """A checkpoint that does not belong to the run trying to restore it."""


def _manager(directory: str | os.PathLike, max_to_keep: int | None = 3,
             create: bool = True) -> ocp.CheckpointManager:
    options = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=create)
    return ocp.CheckpointManager(os.path.abspath(os.fspath(directory)), options=options)


def _flat(state: Any) -> dict[str, jax.Array]:
    leaves = jax.tree.leaves(state)
    return {f"leaf_{i:05d}": x for i, x in enumerate(leaves) if np.size(x) > 0}


def save(directory: str | os.PathLike, step: int, state: Any, meta: dict[str, Any],
         max_to_keep: int | None = 3) -> None:
    """Save ``state`` and the JSON-serialisable ``meta`` as step ``step`` of ``directory``.

    Blocks until the checkpoint is on disk (atomically renamed into place by orbax).
    """
    if not isinstance(step, int) or step < 0:
        raise ValueError(f"step must be a non-negative integer, got {step!r}")
    meta = dict(meta, format_version=FORMAT_VERSION, step=step,
                leaves=[[list(x.shape), str(x.dtype)] for x in jax.tree.leaves(state)])
    with _manager(directory, max_to_keep) as mgr:
        mgr.save(step, args=ocp.args.Composite(state=ocp.args.StandardSave(_flat(state)),
                                               meta=ocp.args.JsonSave(meta)),
                 force=True)
        mgr.wait_until_finished()


def latest_step(directory: str | os.PathLike) -> int | None:
    """The newest complete step in ``directory`` (None if there is none or no directory)."""
    if not os.path.isdir(directory):
        return None
    with _manager(directory, create=False) as mgr:
        return mgr.latest_step()


def load_meta(directory: str | os.PathLike, step: int | None = None) -> dict[str, Any]:
    """The JSON description of step ``step`` (default: the latest) of ``directory``."""
    step = latest_step(directory) if step is None else step
    if step is None:
        raise FileNotFoundError(f"no checkpoint in directory={os.fspath(directory)!r}")
    with _manager(directory, create=False) as mgr:
        return dict(mgr.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore())).meta)


def check_compatible(meta: dict[str, Any], expected: dict[str, Any]) -> None:
    """Raise :class:`IncompatibleCheckpointError` naming every ``expected`` key whose value
    differs from the checkpoint's ``meta`` (e.g. another environment or policy kind)."""
    diffs = [f"{k}: checkpoint has {meta.get(k)!r}, this run has {v!r}"
             for k, v in expected.items() if meta.get(k) != v]
    if diffs:
        raise IncompatibleCheckpointError(
            "checkpoint does not match this run (" + "; ".join(diffs) + ")")


def restore(directory: str | os.PathLike, template: Any, step: int | None = None,
            expected: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
    """``(state, meta)`` of step ``step`` (default: latest) of ``directory``.

    ``template`` is a pytree of arrays or ``jax.ShapeDtypeStruct`` with the structure, shapes and
    dtypes of the state to restore (with ``sharding`` set, leaves are placed accordingly).
    ``expected`` entries are checked against the checkpoint's meta first
    (:func:`check_compatible`); then every leaf's shape and dtype.
    """
    meta = load_meta(directory, step)
    if meta.get("format_version") != FORMAT_VERSION:
        raise IncompatibleCheckpointError(
            f"checkpoint format_version={meta.get('format_version')!r}, expected "
            f"{FORMAT_VERSION}")
    if expected:
        check_compatible(meta, expected)
    leaves, treedef = jax.tree.flatten(template)
    want = [[list(x.shape), str(x.dtype)] for x in leaves]
    if meta["leaves"] != want:
        bad = [i for i, (a, b) in enumerate(zip(meta["leaves"], want, strict=False)) if a != b]
        raise IncompatibleCheckpointError(
            f"checkpoint state has {len(meta['leaves'])} arrays, this run {len(want)}; first "
            f"mismatching leaf {bad[:1]} (different policy, environment or configuration?)")
    abstract = {f"leaf_{i:05d}": jax.ShapeDtypeStruct(x.shape, x.dtype,
                                                      sharding=getattr(x, "sharding", None))
                for i, x in enumerate(leaves) if np.prod(x.shape) > 0}
    with _manager(directory, create=False) as mgr:
        flat = mgr.restore(meta["step"], args=ocp.args.Composite(
            state=ocp.args.StandardRestore(abstract))).state
    out = [flat[f"leaf_{i:05d}"] if np.prod(x.shape) > 0 else jnp.zeros(x.shape, x.dtype)
           for i, x in enumerate(leaves)]
    return jax.tree.unflatten(treedef, out), meta


__all__ = [
    "FORMAT_VERSION",
    "IncompatibleCheckpointError",
    "check_compatible",
    "latest_step",
    "load_meta",
    "restore",
    "save",
]
