"""Orbax checkpoints of a training run: the state pytree, a JSON description, an integrity record.

A checkpoint directory holds orbax steps (``<dir>/<iteration>/``), each with

* ``state`` — every non-empty array leaf of the run's state pytree (a
  :class:`agents.ppo.state.TrainState`, possibly with a leading seed axis) as a flat
  ``{"leaf_00042": array}`` dict: orbax refuses MJX's zero-size arrays, and restoring needs a
  *template* of the expected state (e.g. ``jax.eval_shape`` of ``init``) whose leaves must match;
* ``meta`` — JSON: what the run is (environment, policy kind, configuration), the iteration,
  the metric history, anything the caller adds;
* ``integrity.json`` — written last and atomically, after orbax renamed the complete step into
  place: size and SHA-256 of every other file, one SHA-256 over them all, and whether every
  floating-point leaf of the state is finite.

Reading a step verifies it first: no record, a missing, added, resized or changed file, or an
orbax/tensorstore read error is a :class:`CorruptCheckpointError` naming the step directory and the
reason in one line. "The latest" means the newest intact step (a corrupt newer one is skipped with
``warning: skipping checkpoint <path>: <reason>`` on stderr); an explicitly requested corrupt step
raises. A NaN/inf leaf raises :class:`NonFiniteCheckpointError` naming it. **Legacy steps** (no
record and no ``integrity`` key in their meta: saved before records existed) are accepted
unverified with a one-line warning; a step whose meta promises a record it lacks (a save
interrupted before the record) is corrupt. **Rotation** keeps the ``max_to_keep`` newest steps
(``None``: all) and never deletes the newest verified finite one. **Multi-process runs**
(:mod:`agents.run.distributed`): process 0 alone saves; all restore on the host.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from agents.run.distributed import manager_options, orbax, restore_target
from mjxrmp.atomic import atomic_write
from mjxrmp.divergence import first_nonfinite_leaf

FORMAT_VERSION = 1
#: Version of the integrity record (``integrity.json``; also the ``integrity`` key of the meta).
INTEGRITY_VERSION, INTEGRITY_FILE = 1, "integrity.json"
#: Errors orbax and tensorstore raise for unreadable files (tensorstore's are ValueErrors).
_READ_ERRORS = (ValueError, OSError, KeyError)
_LEAF = "leaf_{:05d}"  # the name of the i-th state leaf in a step


class IncompatibleCheckpointError(ValueError):
    """A checkpoint that does not belong to the run trying to restore it."""


class CorruptCheckpointError(ValueError):
    """A checkpoint step whose files fail verification or cannot be read."""

    def __init__(self, path: str, reason: str):
        super().__init__(f"checkpoint {path} is corrupt: {reason}")
        self.path, self.reason = path, reason


class NonFiniteCheckpointError(ValueError):
    """A checkpoint whose state holds NaN or inf values (a diverged run)."""


def _manager(directory: str | os.PathLike, create: bool = True) -> Any:
    path = os.path.abspath(os.fspath(directory))
    options = orbax().CheckpointManagerOptions(max_to_keep=None, **manager_options(path, create))
    return orbax().CheckpointManager(path, options=options)


def _step_dir(directory: str | os.PathLike, step: int) -> str:
    return os.path.join(os.path.abspath(os.fspath(directory)), str(step))


def _stored(leaves: list[Any]) -> dict[str, Any]:
    """The leaves a step stores, by name: the non-empty ones (orbax refuses zero-size arrays)."""
    return {_LEAF.format(i): x for i, x in enumerate(leaves) if np.size(x) > 0}


def _first_line(e: BaseException) -> str:
    return f"{type(e).__name__}: {(str(e).strip().splitlines() or [''])[0][:300]}"


def _warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr, flush=True)


def first_nonfinite(tree: Any) -> str | None:
    """The path (e.g. ``params['policy']['Dense_0']['kernel']``) of the first floating-point
    leaf of ``tree`` holding a NaN or inf (:func:`mjxrmp.divergence.first_nonfinite_leaf`);
    None if all are finite."""
    found = first_nonfinite_leaf(tree)
    return None if found is None else (found[0].lstrip(".") or "<root>")


def _file_digests(root: str) -> dict[str, list]:
    """``{relative path: [size, sha256]}`` of every file under ``root`` but the record."""
    out = {}
    for dirpath, _, names in os.walk(root):
        for name in names:
            path = os.path.join(dirpath, name)
            rel = os.path.relpath(path, root).replace(os.sep, "/")
            if rel == INTEGRITY_FILE:
                continue
            with open(path, "rb") as f:
                out[rel] = [os.path.getsize(path), hashlib.file_digest(f, "sha256").hexdigest()]
    return out


def _total(files: dict[str, list]) -> str:
    """The step's content checksum: SHA-256 over the sorted relative paths and file hashes."""
    h = hashlib.sha256()
    for rel in sorted(files):
        h.update(f"{rel}\0{files[rel][0]}\0{files[rel][1]}\n".encode())
    return h.hexdigest()


def _read_record(root: str) -> dict[str, Any] | None:
    """The step's integrity record (None if there is none); corrupt if unreadable."""
    path = os.path.join(root, INTEGRITY_FILE)
    if not os.path.isfile(path):
        return None
    try:
        with open(path) as f:
            record = json.load(f)
        ok = isinstance(record["finite"], bool) and _total(record["files"]) == record["sha256"]
    except (OSError, ValueError, KeyError, TypeError, AttributeError, IndexError) as e:
        raise CorruptCheckpointError(
            root, f"{INTEGRITY_FILE} is unreadable ({_first_line(e)})") from None
    if not ok:
        raise CorruptCheckpointError(root, f"{INTEGRITY_FILE} does not match its own checksum")
    return record


def _compare(root: str, record: dict[str, Any]) -> None:
    """Raise :class:`CorruptCheckpointError` naming the first file that differs."""
    want, have = record["files"], _file_digests(root)
    for rel in sorted(set(want) | set(have)):
        problem = ("is missing" if rel not in have else f"is not in {INTEGRITY_FILE}"
                   if rel not in want else None)
        if problem is None and have[rel] != want[rel]:
            problem = (f"has {have[rel][0]} bytes, {want[rel][0]} were written (truncated?)"
                       if have[rel][0] != want[rel][0] else "does not match its SHA-256")
        if problem is not None:
            raise CorruptCheckpointError(root, f"file {rel} {problem}")


def _orbax_read(directory: str | os.PathLike, step: int, item: str, args: Any) -> Any:
    """Item ``item`` of step ``step`` read by orbax; read errors become one-line corruption."""
    try:
        with _manager(directory, create=False) as mgr:
            return mgr.restore(step, args=orbax().args.Composite(**{item: args}))[item]
    except _READ_ERRORS as e:
        raise CorruptCheckpointError(_step_dir(directory, step),
                                     f"{item} unreadable ({_first_line(e)})") from None


def _read_meta(directory: str | os.PathLike, step: int) -> dict[str, Any]:
    return dict(_orbax_read(directory, step, "meta", orbax().args.JsonRestore()))


def verify(directory: str | os.PathLike, step: int) -> dict[str, Any] | None:
    """Check step ``step`` of ``directory`` against its integrity record and return the record
    (None for a legacy step saved before records existed, after a one-line warning). Raises
    :class:`CorruptCheckpointError` naming the step directory and the first problem."""
    root = _step_dir(directory, step)
    record = _read_record(root)
    if record is not None:
        _compare(root, record)
        return record
    if "integrity" in _read_meta(directory, step):
        raise CorruptCheckpointError(root, f"{INTEGRITY_FILE} is missing (the save was "
                                           "interrupted before it was written?)")
    _warn(f"checkpoint {root} predates integrity records: used unverified")
    return None


def all_steps(directory: str | os.PathLike) -> list[int]:
    """Every complete step in ``directory``, ascending, verified or not ([] if none): orbax
    renames a step's temporary directory to ``<step>`` once complete, so these are the
    number-named directories, listed without importing orbax (0.3–0.6 s; docs/design.md §5.6)."""
    if not os.path.isdir(directory):
        return []
    return sorted(int(n) for n in os.listdir(directory)
                  if n.isdigit() and os.path.isdir(os.path.join(directory, n)))


def latest_step(directory: str | os.PathLike) -> int | None:
    """The newest complete step in ``directory``, not verified (None if there is none or no
    directory); :func:`latest_intact_step` verifies."""
    return (all_steps(directory) or [None])[-1]


def _first_intact(directory: str | os.PathLike, step: int | None,
                  read: Callable[[int], Any]) -> Any:
    """``read(step)``; for ``step=None`` ``read`` of the newest step whose read raises no
    :class:`CorruptCheckpointError` (each skipped one warned about on stderr)."""
    steps = all_steps(directory)
    where = os.path.abspath(os.fspath(directory))
    if step is not None:
        if step not in steps:
            raise FileNotFoundError(f"no checkpoint of step={step!r} in directory={where!r}; "
                                    f"available steps are {steps}")
        return read(step)
    if not steps:
        raise FileNotFoundError(f"no checkpoint in directory={where!r}")
    for s in reversed(steps):
        try:
            return read(s)
        except CorruptCheckpointError as e:
            _warn(f"skipping checkpoint {e.path}: {e.reason}")
    raise CorruptCheckpointError(where, f"none of its {len(steps)} step(s) {steps} is intact")


def _intact(directory: str | os.PathLike, step: int) -> bool:
    """Whether ``step`` passes :func:`verify` (if not, a one-line warning names it)."""
    try:
        verify(directory, step)
        return True
    except CorruptCheckpointError as e:
        _warn(f"skipping checkpoint {e.path}: {e.reason}")
        return False


def latest_intact_step(directory: str | os.PathLike) -> int | None:
    """The newest step of ``directory`` that passes :func:`verify`, corrupt newer ones skipped
    with a one-line warning each (None if no step is intact)."""
    return next((s for s in reversed(all_steps(directory)) if _intact(directory, s)), None)


def intact_steps(directory: str | os.PathLike) -> list[int]:
    """Every step of ``directory`` that passes :func:`verify`, ascending (each corrupt one
    skipped with a one-line warning)."""
    return [s for s in all_steps(directory) if _intact(directory, s)]


def _newest_finite(directory: str | os.PathLike, candidates: list[int]) -> int | None:
    """The newest of ``candidates`` whose record says finite and whose files verify."""
    for s in sorted(candidates, reverse=True):
        try:
            record = _read_record(_step_dir(directory, s))
            if record is not None and record["finite"]:
                _compare(_step_dir(directory, s), record)
                return s
        except CorruptCheckpointError:
            continue
    return None


def _rotate(directory: str | os.PathLike, max_to_keep: int | None, saved: int,
            finite: bool) -> None:
    """Delete all but the ``max_to_keep`` newest steps and the newest verified finite one
    (``saved``, just written and verified by construction, if finite and newest)."""
    steps = all_steps(directory)
    if max_to_keep is None or len(steps) <= max_to_keep:
        return
    protected = _newest_finite(directory, [s for s in steps if s > saved])
    if protected is None:
        protected = saved if finite else _newest_finite(directory, [s for s in steps if s < saved])
    keep = set(steps[-max_to_keep:]) | {protected}
    with _manager(directory) as mgr:
        for s in sorted(set(steps) - keep):
            mgr.delete(s)


def save(directory: str | os.PathLike, step: int, state: Any, meta: dict[str, Any],
         max_to_keep: int | None = 3) -> None:
    """Save ``state`` and the JSON-serialisable ``meta`` as step ``step`` of ``directory``, then
    its integrity record, then rotate (keeping the ``max_to_keep`` newest steps, all for
    ``None``, and the newest verified finite one); blocks until all is on disk. A corrupt step
    of the same number is replaced (with a warning); orbax refuses an intact one."""
    if not isinstance(step, int) or step < 0:
        raise ValueError(f"step must be a non-negative integer, got {step!r}")
    if max_to_keep is not None and not (isinstance(max_to_keep, int) and max_to_keep >= 1):
        raise ValueError(f"max_to_keep must be None (keep all) or a positive integer, got "
                         f"{max_to_keep!r}")
    meta = dict(meta, format_version=FORMAT_VERSION, integrity=INTEGRITY_VERSION, step=step,
                leaves=[[list(x.shape), str(x.dtype)] for x in jax.tree.leaves(state)])
    nonfinite, root = first_nonfinite(state), _step_dir(directory, step)
    flat = _stored(jax.tree.leaves(state))
    with _manager(directory) as mgr:
        if step in mgr.all_steps():
            try:
                verify(directory, step)
            except CorruptCheckpointError as e:
                _warn(f"replacing corrupt checkpoint {e.path}: {e.reason}")
                mgr.delete(step)
        mgr.save(step, args=orbax().args.Composite(state=orbax().args.StandardSave(flat),
                                                   meta=orbax().args.JsonSave(meta)),
                 force=True)
        mgr.wait_until_finished()
    files = _file_digests(root)  # orbax has renamed the complete step into place
    record = {"version": INTEGRITY_VERSION, "step": step, "algorithm": "sha256",
              "sha256": _total(files), "files": files, "finite": nonfinite is None,
              "nonfinite_leaf": nonfinite}
    atomic_write(os.path.join(root, INTEGRITY_FILE), (json.dumps(record) + "\n").encode())
    _rotate(directory, max_to_keep, step, nonfinite is None)


def _verified_meta(directory: str | os.PathLike, step: int) -> dict[str, Any]:
    verify(directory, step)
    return _read_meta(directory, step)


def load_meta(directory: str | os.PathLike, step: int | None = None) -> dict[str, Any]:
    """The JSON description of step ``step`` of ``directory`` after :func:`verify` (default:
    the newest intact step, corrupt newer ones skipped with a warning)."""
    return _first_intact(directory, step, lambda s: _verified_meta(directory, s))


_MISSING = object()


def _shown(value: Any) -> str:
    return "no value" if value is _MISSING else repr(value)


def _diffs(have: Any, want: Any, path: str) -> list[str]:
    """``path: checkpoint has …, this run has …`` for every differing leaf of two JSON values
    (dicts compared key by key, keys joined with dots)."""
    if isinstance(have, dict) and isinstance(want, dict):
        return [d for k in sorted(set(have) | set(want), key=str)
                for d in _diffs(have.get(k, _MISSING), want.get(k, _MISSING), f"{path}.{k}")]
    if have == want:
        return []
    return [f"{path}: checkpoint has {_shown(have)}, this run has {_shown(want)}"]


def check_compatible(meta: dict[str, Any], expected: dict[str, Any]) -> None:
    """Raise :class:`IncompatibleCheckpointError` naming, by dotted path (``ppo.learning_rate``),
    every value of ``expected`` that differs from the checkpoint's ``meta`` (nested dicts are
    compared key by key; only differing keys are named)."""
    diffs = [d for k, v in expected.items() for d in _diffs(meta.get(k, _MISSING), v, k)]
    if diffs:
        raise IncompatibleCheckpointError("checkpoint does not match this run: " + "; ".join(diffs))


def _check_leaves(meta: dict[str, Any], want: list[list]) -> None:
    """Refuse another checkpoint format or a state of other array shapes/dtypes."""
    if meta.get("format_version") != FORMAT_VERSION:
        raise IncompatibleCheckpointError(
            f"checkpoint format_version={meta.get('format_version')!r}, expected {FORMAT_VERSION}")
    if meta["leaves"] != want:
        bad = [i for i, (a, b) in enumerate(zip(meta["leaves"], want, strict=False)) if a != b]
        raise IncompatibleCheckpointError(
            f"checkpoint state has {len(meta['leaves'])} arrays, this run {len(want)}; first "
            f"mismatching leaf {bad[:1]} (different policy, environment or configuration?)")


def _nonfinite_error(directory: str | os.PathLike, step: int, leaf: str
                     ) -> NonFiniteCheckpointError:
    finite = _newest_finite(directory, [s for s in all_steps(directory) if s != step])
    hint = (f"the newest finite checkpoint is step {finite} (request that step)"
            if finite is not None else "no other verified finite checkpoint exists")
    return NonFiniteCheckpointError(
        f"checkpoint {_step_dir(directory, step)} holds non-finite values in {leaf} "
        f"(the run diverged); {hint}")


def _restore_step(directory: str | os.PathLike, step: int, template: Any,
                  expected: dict[str, Any] | None, allow_nonfinite: bool
                  ) -> tuple[Any, dict[str, Any]]:
    meta = _verified_meta(directory, step)
    if expected:
        check_compatible(meta, expected)
    leaves, treedef = jax.tree.flatten(template)
    _check_leaves(meta, [[list(x.shape), str(x.dtype)] for x in leaves])
    abstract = {name: restore_target(x) for name, x in _stored(leaves).items()}
    flat = _orbax_read(directory, step, "state", orbax().args.StandardRestore(abstract))
    # zero-size leaves made on the host, not by jnp.zeros (a compile per shape: 0.2 s on a CPU)
    out = [flat[name] if (name := _LEAF.format(i)) in flat else
           jax.device_put(np.zeros(x.shape, x.dtype)) for i, x in enumerate(leaves)]
    state = jax.tree.unflatten(treedef, out)
    leaf = None if allow_nonfinite else first_nonfinite(state)
    if leaf is not None:
        raise _nonfinite_error(directory, step, leaf)
    return state, meta


def restore(directory: str | os.PathLike, template: Any, step: int | None = None,
            expected: dict[str, Any] | None = None, allow_nonfinite: bool = False
            ) -> tuple[Any, dict[str, Any]]:
    """``(state, meta)`` of step ``step`` of ``directory`` (default: the newest intact step;
    corrupt newer ones are skipped with a one-line warning on stderr).

    ``template`` is a pytree of arrays or ``jax.ShapeDtypeStruct`` with the structure, shapes and
    dtypes of the state (with ``sharding`` set, leaves are placed accordingly). The files are
    verified (:func:`verify`), ``expected`` is checked against the meta
    (:func:`check_compatible`), then every leaf's shape and dtype; a NaN/inf leaf raises
    :class:`NonFiniteCheckpointError` naming it, unless ``allow_nonfinite``."""
    return _first_intact(directory, step, lambda s: _restore_step(
        directory, s, template, expected, allow_nonfinite))


__all__ = ["FORMAT_VERSION", "INTEGRITY_FILE", "INTEGRITY_VERSION", "CorruptCheckpointError",
           "IncompatibleCheckpointError", "NonFiniteCheckpointError", "all_steps",
           "check_compatible", "first_nonfinite", "intact_steps", "latest_intact_step",
           "latest_step", "load_meta", "restore", "save", "verify"]
