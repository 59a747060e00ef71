"""Training programs kept between processes as ``jax.export`` artifacts (docs/design.md §5.6).

JAX's persistent compilation cache saves the XLA compile of a repeated command, but to look a
program up JAX must first trace and lower it again, which for a PPO chunk takes longer than
anything else a warm start does. :func:`exported` keeps the lowered program itself: the first
process exports it (``jax.export``) next to the compilation cache, later processes deserialise
it and compile it, which the persistent cache answers. An artifact is found only by a key over
everything that shapes the program: the caller's description (run settings, chunk length, the
input's tree structure, shapes and dtypes), the JAX version and the numeric settings (x64,
default matmul precision), the device kind and a hash of the project's own source files, so any
code change makes new artifacts. Sharded and multi-process programs are not kept.
"""

from __future__ import annotations

import functools
import hashlib
import json
import pickle
import re
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax

from mjxrmp.atomic import atomic_write

_PACKAGES = ("mjxrmp", "envs", "agents")
ROOT = Path(__file__).resolve().parents[2]


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
             "config": [jax.config.jax_enable_x64, jax.config.jax_default_matmul_precision],
             "source": source_hash()}
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


def _load(path: Path) -> tuple[Any, Any]:
    """``(Exported, output tree)`` of an artifact file."""
    record = pickle.loads(path.read_bytes())
    return jax.export.deserialize(bytearray(record["exported"])), record["out_tree"]


def exported(fn: Callable[..., Any], args: tuple[Any, ...], description: dict[str, Any]
             ) -> Callable[..., Any] | None:
    """``fn`` for arguments shaped like ``args`` (any pytrees of arrays), compiled from its
    exported program: read from the artifact directory when there, else exported and written
    there (atomically, with the output's tree structure). The compile itself is answered by
    the persistent compilation cache on a repeat. None when that cache is off or ``fn``
    cannot be exported (with a warning; the caller then compiles it as usual)."""
    folder = artifact_dir()
    if folder is None:
        return None
    leaves, in_tree = jax.tree.flatten(args)
    path = folder / f"{program_key(description, args)}.jaxexport"
    loaded = None
    if path.exists():
        try:
            loaded = _load(path)
        except Exception as e:  # any unreadable artifact is exported again
            warnings.warn(f"unreadable program artifact {path} ({type(e).__name__}: {e}); "
                          "exporting it again", stacklevel=2)
    if loaded is not None:
        exp, out_tree = loaded
    else:
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
            return None
        out_tree = box["out_tree"]
        folder.mkdir(parents=True, exist_ok=True)
        atomic_write(path, pickle.dumps({"exported": data, "out_tree": out_tree}))
    compiled = jax.jit(exp.call).lower(leaves).compile()

    def call(*a: Any) -> Any:
        return jax.tree.unflatten(out_tree, compiled(jax.tree.leaves(a)))

    return call


__all__ = ["artifact_dir", "exported", "program_key", "source_hash"]
