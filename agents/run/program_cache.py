"""Training programs kept between processes as ``jax.export`` artifacts (docs/design.md §5.6).

JAX's persistent compilation cache saves the XLA compile of a repeated command, but to look a
program up JAX must first trace and lower it again, which for a PPO chunk takes longer than
anything else a warm start does. :func:`exported` keeps the lowered program itself: the first
process exports it (``jax.export``) next to the compilation cache, later processes deserialise
it and compile it, which the persistent cache answers. An artifact is found only by a key over
everything that shapes the program: the caller's description (run settings, chunk length, the
input's tree structure, shapes and dtypes), the JAX version, the numeric settings (x64,
default matmul precision), the traceback frames it keeps, the device kind and a hash of
the project's own source files, so any code change makes new artifacts. Sharded and
multi-process programs are not kept.

A script can also have the programs of a repeated command compiled ahead: :func:`remember`
notes which artifacts a command (labelled by :func:`command_label`) used, and :func:`prefetch`,
called by the next such command before its heavy imports, deserialises them in background
threads meanwhile (a compile ahead is only ever used for the artifact key it was made for),
and :func:`start_device` makes the device's first allocation in another (on a GPU, JAX's
allocator spends about a second on it).
"""

from __future__ import annotations

import functools
import hashlib
import json
import pickle
import re
import threading
import warnings
from collections.abc import Callable, Collection, Sequence
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import jax

from mjxrmp.atomic import atomic_write

_PACKAGES = ("mjxrmp", "envs", "agents")
ROOT = Path(__file__).resolve().parents[2]
#: At most this many programs are compiled ahead (:func:`prefetch`).
_MAX_AHEAD = 4
#: Programs being compiled ahead of their use (:func:`prefetch`), by artifact path.
_AHEAD: dict[Path, Future] = {}
#: The background start of the default device (:func:`start_device`), once per process.
_DEVICE: list[Future] = []
#: The artifact files this process used, in order of first use (:func:`remember`).
_USED: list[str] = []


@functools.lru_cache(maxsize=1)
def source_hash() -> str:
    """SHA-256 over the project's package sources (path and content of every ``.py`` file of
    ``mjxrmp``, ``envs`` and ``agents``)."""
    h = hashlib.sha256()
    for pkg in _PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            h.update(str(path.relative_to(ROOT)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()


def artifact_dir() -> Path | None:
    """Where artifacts go: ``programs/`` beside JAX's persistent compilation cache, or None
    when that cache is off (then nothing is kept)."""
    cache = jax.config.jax_compilation_cache_dir
    return Path(cache) / "mjxrmp-programs" if cache else None


def program_key(description: dict[str, Any], args: Any) -> str:
    """The artifact key of a program described by ``description`` (JSON data) applied to
    ``args`` (arrays or shape structs): a hash of both, the JAX version, the device kind and
    :func:`source_hash`."""
    leaves, tree = jax.tree.flatten(args)
    # static node data may print as "<object at 0x...>": drop the addresses, the source hash
    # and the description already fix what such data is derived from
    parts = {"description": description, "tree": re.sub(r" at 0x[0-9a-f]+", "", str(tree)),
             "avals": [[list(x.shape), str(x.dtype)] for x in leaves],
             "jax": jax.__version__, "device": jax.devices()[0].device_kind,
             "config": [jax.config.jax_enable_x64, jax.config.jax_default_matmul_precision,
                        jax.config.jax_traceback_in_locations_limit],
             "source": source_hash()}
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


def _read(path: Path) -> tuple[Any, bytes, dict[str, Any]]:
    """``(Exported, pickled output tree, compiler options)`` of an artifact file. The tree stays
    pickled: loading it imports the modules of its node types, which a compile ahead in a
    background thread leaves to the main thread (:func:`prefetch`)."""
    record = pickle.loads(path.read_bytes())
    return (jax.export.deserialize(bytearray(record["exported"])), record["out_tree"],
            dict(record["compiler_options"]))


def _compile(exp: Any, options: dict[str, Any],
             lowered: Callable[[], None] | None = None) -> Any:
    """The exported program ``exp`` compiled with XLA ``options`` (answered by the persistent
    compilation cache on a repeat), lowered from its own input shapes, so that a compile ahead
    of use (:func:`prefetch`) and one at use look up the same cache entry, whatever devices the
    arguments are on. ``lowered()`` is called between lowering and XLA's compile."""
    specs = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in exp.in_avals]
    program = jax.jit(exp.call).lower(specs)
    if lowered is not None:
        lowered()
    return program.compile(compiler_options=options or None)


def _calling(compiled: Any, out_tree: Any) -> Callable[..., Any]:
    """``compiled`` (flat arguments and results) called on pytrees, its results as ``out_tree``."""

    def call(*a: Any) -> Any:
        return jax.tree.unflatten(out_tree, compiled(jax.tree.leaves(a)))

    return call


def _artifact(folder: Path, description: dict[str, Any], args: Any,
              options: dict[str, Any] | None) -> Path:
    """The artifact file of a program (its key covers the compiler options too)."""
    described = {**description, "compiler_options": dict(options or {})}
    return folder / f"{program_key(described, args)}.jaxexport"


def exported_shapes(args: tuple[Any, ...], description: dict[str, Any],
                    compiler_options: dict[str, Any] | None = None) -> Any | None:
    """The output of the program :func:`exported` keeps for ``args``, ``description`` and
    ``compiler_options`` as a pytree of ``jax.ShapeDtypeStruct`` (what ``jax.eval_shape``
    gives, without tracing), read from its artifact; None where there is none (or it is
    unreadable)."""
    folder = artifact_dir()
    path = None if folder is None else _artifact(folder, description, args, compiler_options)
    if path is None or not path.exists():
        return None
    try:
        exp, tree, _ = _read(path)
        out_tree = pickle.loads(tree)
    except Exception:  # unreadable: the caller traces, exported() warns when it is needed
        return None
    return jax.tree.unflatten(out_tree, [jax.ShapeDtypeStruct(a.shape, a.dtype)
                                         for a in exp.out_avals])


def _ahead(path: Path, lowered: Callable[[], None] | None) -> Callable[..., Any] | None:
    """The program of ``path`` compiled ahead by :func:`prefetch` (waiting for it, after
    calling ``lowered()``: nothing is left to trace), or None when it was not prefetched or
    that failed (the caller then reads it as usual)."""
    job = _AHEAD.pop(path, None)
    if job is None:
        return None
    if lowered is not None:
        lowered()
    try:
        compiled, tree = job.result()
        return _calling(compiled, pickle.loads(tree))
    except Exception:  # e.g. an unreadable artifact: the usual path warns and exports it again
        return None


def exported(fn: Callable[..., Any], args: tuple[Any, ...], description: dict[str, Any],
             compiler_options: dict[str, Any] | None = None,
             lowered: Callable[[], None] | None = None) -> Callable[..., Any] | None:
    """``fn`` for arguments shaped like ``args`` (any pytrees of arrays), compiled (with XLA
    ``compiler_options``, part of the key) from its exported program: compiled ahead by
    :func:`prefetch`, or read from the artifact directory when there, else exported and
    written there (atomically, with the output's tree structure and the options). The compile
    itself is answered by the persistent compilation cache on a repeat. None when that cache is
    off or ``fn`` cannot be exported (with a warning; the caller then compiles it as usual).
    ``lowered()`` is called when what is left is XLA's compile (which does not hold the GIL)."""
    folder = artifact_dir()
    if folder is None:
        return None
    options = dict(compiler_options or {})
    leaves, in_tree = jax.tree.flatten(args)
    path = _artifact(folder, description, args, options)
    if path.name not in _USED:
        _USED.append(path.name)
    ahead = _ahead(path, lowered)
    if ahead is not None:
        return ahead
    loaded = None
    if path.exists():
        try:
            exp, tree, _ = _read(path)
            loaded = exp, pickle.loads(tree)
        except Exception as e:  # any unreadable artifact is exported again
            warnings.warn(f"unreadable program artifact {path} ({type(e).__name__}: {e}); "
                          "exporting it again", stacklevel=2)
    if loaded is not None:
        return _calling(_compile(loaded[0], options, lowered), loaded[1])
    box: dict[str, Any] = {}

    def flat(xs):
        out = fn(*jax.tree.unflatten(in_tree, xs))
        box["out_tree"] = jax.tree.structure(out)
        return jax.tree.leaves(out)

    specs = [jax.ShapeDtypeStruct(x.shape, x.dtype) for x in leaves]
    try:
        exp = jax.export.export(jax.jit(flat))(specs)
        data = bytes(exp.serialize())
    except (ValueError, NotImplementedError, TypeError) as e:
        # e.g. a custom call jax.export does not guarantee: the caller compiles as usual
        warnings.warn(f"program {description} is not kept between processes: {e}",
                      stacklevel=2)
        _USED.remove(path.name)
        return None
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write(path, pickle.dumps({"exported": data, "out_tree": pickle.dumps(box["out_tree"]),
                                     "compiler_options": options}))
    return _calling(_compile(exp, options, lowered), box["out_tree"])


def command_label(argv: Sequence[str], valued: Collection[str] = (),
                  flags: Collection[str] = ()) -> str:
    """A command line as the label its programs are remembered by (:func:`remember`): ``argv``
    without the options ``valued`` (with their values; ``--opt VALUE`` or ``--opt=VALUE``) and
    the switches ``flags``, which do not change what it compiles."""
    kept, value_next = [], False
    for arg in argv:
        name = arg.split("=", 1)[0]
        if value_next:
            value_next = False
        elif name in valued:
            value_next = "=" not in arg
        elif name not in flags:
            kept.append(arg)
    return json.dumps(kept)


def _record(folder: Path, label: str) -> Path:
    """The file naming the programs a command labelled ``label`` used (per JAX version and
    :func:`source_hash`, so a code change forgets it)."""
    key = json.dumps([label, jax.__version__, source_hash()])
    return folder / "recent" / f"{hashlib.sha256(key.encode()).hexdigest()}.json"


def _recorded(path: Path) -> list[str]:
    """The artifact file names a record holds ([] where there is none or it is unreadable)."""
    try:
        names = json.loads(path.read_text())
    except (OSError, ValueError):
        return []
    return [n for n in names if isinstance(n, str) and Path(n).name == n
            and n.endswith(".jaxexport")] if isinstance(names, list) else []


def remember(label: str) -> None:
    """Note the programs this process read or exported (in order of first use) as those of the
    command ``label`` (:func:`command_label`), for :func:`prefetch` in a later process; those
    noted before for it follow (a resumed command needs no init program, a fresh one does),
    :data:`_MAX_AHEAD` at most."""
    folder = artifact_dir()
    if folder is None or not _USED:
        return
    path = _record(folder, label)
    names = list(dict.fromkeys([*_USED, *_recorded(path)]))[:_MAX_AHEAD]
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, json.dumps(names).encode())


def prefetch(label: str) -> int:
    """Start compiling, each in a background thread, the programs the last command labelled
    ``label`` used (:func:`remember`), so that reading and deserialising them (XLA releases the
    GIL) overlaps what the process does before it needs them: its imports, building the
    environment. :func:`exported` then takes them when their key comes up; one never asked
    for is only wasted work. The number of programs started (0 without a record)."""
    folder = artifact_dir()
    if folder is None:
        return 0
    paths = [folder / n for n in _recorded(_record(folder, label)) if (folder / n).exists()]
    for path in paths[:_MAX_AHEAD]:
        if path not in _AHEAD:
            _AHEAD[path] = in_background(functools.partial(_compile_ahead, path),
                                         f"prefetch {path.name[:12]}", daemon=False)
    return min(len(paths), _MAX_AHEAD)


def in_background(work: Callable[[], Any], name: str, daemon: bool = True) -> Future:
    """Run ``work()`` in a thread named ``name``; the future of its result, or of the
    exception it raised (for the caller to raise or handle where it needs the result)."""
    job: Future = Future()
    job.set_running_or_notify_cancel()

    def run() -> None:
        try:
            job.set_result(work())
        except Exception as e:  # handed to the caller through the future
            job.set_exception(e)

    threading.Thread(target=run, name=name, daemon=daemon).start()
    return job


def start_device() -> Future:
    """Initialise JAX's default device and make its first allocation in a background thread, so
    that it overlaps the imports a script does before its first transfer; the future of that
    start, the same one for every call in a process.

    On a GPU the first allocation is slow: JAX's allocator reserves 75 % of the device memory
    and fills a bookkeeping table over all of it (about 1 s on an H200), and the default
    device's set-up takes as long again; the transfer releases the GIL, so the main thread's
    imports go on meanwhile (docs/design.md §5.6). An error stays in the future: the main thread
    meets the same one, with its own message, at its first use of the device."""
    if not _DEVICE:
        _DEVICE.append(in_background(
            lambda: jax.block_until_ready(jax.device_put(0.0)).devices(), "start device"))
    return _DEVICE[0]


def _compile_ahead(path: Path) -> tuple[Any, bytes]:
    """``(compiled program, pickled output tree)`` of the artifact ``path``, for a background
    thread (no module is imported here: :func:`_read`)."""
    exp, tree, options = _read(path)
    return _compile(exp, options), tree


__all__ = [
    "artifact_dir",
    "command_label",
    "exported",
    "exported_shapes",
    "in_background",
    "prefetch",
    "program_key",
    "remember",
    "source_hash",
    "start_device",
]
