"""Multi-process (multi-host) training with ``jax.distributed`` (docs/multihost.md).

Every process of a multi-process run executes the same program on one global device mesh
(:func:`agents.ppo.make_mesh` over ``jax.devices()``, which then lists the devices of every
process); the environment batch and every minibatch are sharded over it. :func:`initialize`
connects the processes (flags, ``MJXRMP_*`` variables or JAX's cluster auto-detection);
:func:`to_host` gathers a sharded state to host numpy on every process, :func:`place` puts host
arrays back onto the mesh, :func:`is_writer` says who writes (process 0), :func:`barrier` waits
for every process and :func:`agree` stops all processes when one refuses. In a single process
all of these are no-ops or plain conversions.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import SingleDeviceSharding

from mjxrmp.config import check_int

#: Environment variables read when no flag is given (all three or none).
ENV_VARS = ("MJXRMP_COORDINATOR", "MJXRMP_NUM_PROCESSES", "MJXRMP_PROCESS_ID")
_FLAGS = ("coordinator", "num_processes", "process_id")


def _check_coordinator(value: Any, name: str) -> str:
    """``HOST:PORT`` with a port in 1..65535."""
    host, _, port = str(value).rpartition(":")
    if not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"{name} must be HOST:PORT (port 1..65535), got {value!r}")
    return str(value)


def _from_environment(environ: Mapping[str, str]) -> tuple[str, int, int] | None:
    """``(coordinator, num_processes, process_id)`` from :data:`ENV_VARS`, None if none is set;
    an error naming the missing or malformed variable."""
    given = {v: environ[v] for v in ENV_VARS if environ.get(v, "").strip()}
    if not given:
        return None
    missing = [v for v in ENV_VARS if v not in given]
    if missing:
        raise ValueError(f"{', '.join(sorted(given))} set but not {', '.join(missing)}: set "
                         f"all of {', '.join(ENV_VARS)} or none")
    values = []
    for var in ENV_VARS[1:]:
        if not given[var].strip().isdigit():
            raise ValueError(f"{var} must be a non-negative integer, got {given[var]!r}")
        values.append(int(given[var]))
    return given[ENV_VARS[0]].strip(), values[0], values[1]


def resolve(coordinator: str | None = None, num_processes: int | None = None,
            process_id: int | None = None, environ: Mapping[str, str] | None = None
            ) -> tuple[str, int, int] | None:
    """``(coordinator, num_processes, process_id)`` from the arguments (all three or none), else
    from :data:`ENV_VARS` in ``environ`` (default ``os.environ``); None when neither is given
    (JAX's own cluster auto-detection then applies). Checks ``HOST:PORT``, a process count
    ``>= 1`` and ``0 <= process_id < num_processes``."""
    flags = dict(zip(_FLAGS, (coordinator, num_processes, process_id), strict=True))
    given = [k for k, v in flags.items() if v is not None]
    if given and len(given) < len(flags):
        missing = [k for k in flags if k not in given]
        raise ValueError(f"{', '.join(given)} given without {', '.join(missing)}: give "
                         "coordinator, num_processes and process_id together (or none, for "
                         "the environment)")
    found = (coordinator, num_processes, process_id) if given else _from_environment(
        os.environ if environ is None else environ)
    if found is None:
        return None
    coordinator = _check_coordinator(found[0], "coordinator")
    count = check_int(found[1], "num_processes")
    pid = check_int(found[2], "process_id", minimum=0)
    if pid >= count:
        raise ValueError(f"process_id must be in 0..{count - 1} for num_processes={count}, "
                         f"got {pid}")
    return coordinator, count, pid


def initialize(coordinator: str | None = None, num_processes: int | None = None,
               process_id: int | None = None) -> tuple[int, int]:
    """Connect this process to the others with ``jax.distributed.initialize`` (before any JAX
    computation) and return ``(process_index, process_count)``: the coordinator ``HOST:PORT``,
    process count and id from the arguments, else :data:`ENV_VARS`, else JAX's cluster
    auto-detection (SLURM, Open MPI, …). CPU collectives go through gloo."""
    found = resolve(coordinator, num_processes, process_id)
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    try:
        if found is None:
            jax.distributed.initialize()
        else:
            jax.distributed.initialize(*found)
    except ValueError as e:
        if found is not None:
            raise
        raise ValueError(f"no cluster detected ({e}); give coordinator, num_processes and "
                         f"process_id or set {', '.join(ENV_VARS)}") from None
    return jax.process_index(), jax.process_count()


def is_multiprocess() -> bool:
    """Whether this run spans several processes."""
    return jax.process_count() > 1


def is_writer() -> bool:
    """Whether this process writes the run's files (process 0; always true in one process)."""
    return jax.process_index() == 0


def to_host(tree: Any) -> Any:
    """Every leaf of ``tree`` as a host numpy array holding the whole (global) value, on every
    process: a leaf sharded over other processes' devices is all-gathered (a collective: every
    process must call this in the same order)."""

    def one(x: Any) -> np.ndarray:
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            return np.asarray(multihost_utils.process_allgather(x, tiled=True))
        return np.asarray(x)

    return jax.tree.map(one, tree)


def place(host: Any, shardings: Any) -> Any:
    """The host arrays ``host`` (the same on every process) as global ``jax.Array`` s with
    ``shardings`` (a matching tree of :class:`jax.sharding.Sharding`)."""
    return jax.tree.map(
        lambda x, s: jax.make_array_from_callback(np.shape(x), s, lambda i: np.asarray(x)[i]),
        host, shardings)


def mesh_devices(requested: int | None) -> int | None:
    """How many devices the run's mesh spans (:func:`agents.ppo.make_mesh`): ``requested`` in
    one process; in a multi-process run every device of every process (``requested`` must be
    None or that number)."""
    if not is_multiprocess():
        return requested
    total = jax.device_count()
    if requested not in (None, total):
        raise ValueError(f"devices must be {total} (every device of the {jax.process_count()} "
                         f"processes) or unset in a multi-process run, got {requested!r}")
    return total


def barrier(name: str) -> None:
    """Wait until every process reaches the barrier ``name`` (a no-op in one process)."""
    if is_multiprocess():
        multihost_utils.sync_global_devices(name)


def agree(error: BaseException | None, what: str) -> None:
    """Raise ``error`` if this process has one, else a ``RuntimeError`` naming the processes
    that had one (a collective in a multi-process run: every process calls it, so that all stop
    together instead of waiting for a refused one); nothing if no process has an error."""
    if not is_multiprocess():
        if error is not None:
            raise error
        return
    failed = multihost_utils.process_allgather(np.int32(error is not None))
    if error is not None:
        raise error
    if failed.any():
        raise RuntimeError(f"{what}: process(es) {np.flatnonzero(failed).tolist()} refused "
                           "(see their output)")


def orbax() -> Any:
    """``orbax.checkpoint``, imported on first use: a training run reaches its first iteration
    without its 0.5 s of imports."""
    import orbax.checkpoint as ocp  # lazy: 0.5 s of imports, needed only at the first checkpoint

    return ocp


def manager_options(directory: str, create: bool) -> dict[str, Any]:
    """``orbax.checkpoint.CheckpointManagerOptions`` arguments: in a multi-process run the
    manager is local to this process (no barriers; only process 0 saves) and ``directory`` is
    created here when ``create``."""
    if not is_multiprocess():
        return {"create": create}
    if create:
        os.makedirs(directory, exist_ok=True)
    me = jax.process_index()
    return {"create": False, "multiprocessing_options": orbax().options.MultiprocessingOptions(
        primary_host=me, active_processes={me})}


def restore_target(leaf: Any) -> Any:
    """What orbax restores a state leaf as, whatever devices and processes wrote it: a host
    numpy array in a multi-process run, else a ``jax.ShapeDtypeStruct`` with the template's
    sharding, or on the first device where the template has none (:func:`place` then puts it on
    a mesh)."""
    if is_multiprocess():
        return np.zeros(leaf.shape, leaf.dtype)
    sharding = getattr(leaf, "sharding", None) or SingleDeviceSharding(jax.local_devices()[0])
    return jax.ShapeDtypeStruct(leaf.shape, leaf.dtype, sharding=sharding)


__all__ = ["ENV_VARS", "agree", "barrier", "initialize", "is_multiprocess", "is_writer",
           "manager_options", "mesh_devices", "orbax", "place", "resolve", "restore_target",
           "to_host"]
