"""XLA settings every CPU entry point needs (docs/design.md §5.2) and the scripts' compile cache.

With jaxlib 0.7.1–0.10.x, XLA:CPU's fusion emitters make MJX kinematics of deep chains extremely
slow (seconds per step for the Franka); disabling them restores millisecond steps. jaxlib 0.10's
YNNPACK reduction fusions compute some sums wrongly in a program with a batch axis of size 1 (a
one-seed run); they are switched off (:data:`YNN_FLAG`). The flags are read when the first
backend initialises, so they must be set before any JAX computation runs. jaxlib 0.11 removed
the first (and aborts on unknown XLA flags), so each is only set where jaxlib needs it.

Scripts also turn on JAX's persistent compilation cache (docs/design.md §5.6), so a repeated or
resumed command loads its compiled programs instead of compiling them again, keep one
source frame per operation in the programs they compile instead of up to 100 of its Python
traceback (smaller program artifacts), and let XLA:GPU run independent kernels side by side
(:data:`GPU_FLAG`, docs/design.md §5.11). Importing the library does none of these: only
:func:`configure_script`, which every script calls, does.
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Mapping
from importlib import metadata

CPU_FLAG = "--xla_cpu_use_fusion_emitters=false"
#: jaxlib 0.10's XLA:CPU hands reductions to YNNPACK fusions, and one of those computes a sum
#: over the last axis of a broadcast product wrongly when the program carries a batch axis of
#: size 1: a one-seed PPO run's gradients through the residual RMP policy were wrong (off by
#: up to the gradient's own size), and depended on what memory the call was given, so they
#: changed from call to call (docs/design.md §5.2). With no YNNPACK fusions the sums are XLA's
#: own and right; jaxlib 0.11 computes them right either way.
YNN_FLAG = "--xla_cpu_experimental_ynn_fusion_type="
#: Environment variable choosing the scripts' compile cache: a directory, or off/0/false.
CACHE_ENV = "MJXRMP_COMPILE_CACHE"
CACHE_OFF = ("off", "0", "false")
#: JAX's own variables; a user who sets the directory keeps full control of the cache.
JAX_CACHE_DIR_ENV = "JAX_COMPILATION_CACHE_DIR"
JAX_MIN_TIME_ENV = "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"
#: JAX's variable: how many Python frames each operation's location in a compiled program keeps.
TRACEBACK_LIMIT_ENV = "JAX_TRACEBACK_IN_LOCATIONS_LIMIT"
#: The scripts' default: the operation's own source frame (JAX's default keeps up to 100).
TRACEBACK_FRAMES = 1
#: Compiles shorter than this are not cached. JAX's default, 1 s, would skip most CPU programs;
#: 0 stores every one: on a GPU even the environment's small set-up programs (a dozen of them,
#: each a few tens of ms to compile) add about 0.6 s to a warm start (docs/design.md §5.6).
MIN_COMPILE_TIME_S = 0.0


#: XLA:GPU records a program's kernels into command buffers (CUDA graphs); in its default mode
#: (``LHS``) they run one after another in the compiled schedule's order, with ``CONCURRENT``
#: in the order of their data dependencies only, so independent small kernels (the policy's and
#: the value network's passes, the environments' geometry beside the physics, ATAC's critics
#: beside its actor) share the GPU. A thesis PPO iteration took a third less time on an H200
#: (docs/design.md §5.11). Ignored by the CPU backend.
GPU_FLAG = "--xla_gpu_command_buffer_scheduling_mode=CONCURRENT"
_GPU_MODE_OPTION = GPU_FLAG[2:].split("=")[0]  # xla_gpu_command_buffer_scheduling_mode
#: The flags the scripts set themselves (not a user's choice, so not recorded with a result).
SCRIPT_FLAGS = (CPU_FLAG, YNN_FLAG, GPU_FLAG)


def _jaxlib_version() -> tuple[int, ...]:
    try:
        raw = metadata.version("jaxlib")
    except metadata.PackageNotFoundError:
        return ()
    return tuple(int(p) for p in raw.split(".")[:2] if p.isdigit())


def cpu_flag_supported() -> bool:
    """Whether the installed jaxlib understands ``--xla_cpu_use_fusion_emitters``."""
    version = _jaxlib_version()
    return bool(version) and (0, 7) <= version < (0, 11)


def ynn_flag_needed() -> bool:
    """Whether the installed jaxlib has the YNNPACK reduction fusions of :data:`YNN_FLAG`."""
    version = _jaxlib_version()
    return bool(version) and (0, 10) <= version < (0, 11)


def cpu_xla_flags(flags: str | None = None) -> str:
    """``XLA_FLAGS`` (``flags``, default the environment's) with the fusion-emitter and YNNPACK
    workarounds added where the installed jaxlib needs them, unless they set that option."""
    flags = os.environ.get("XLA_FLAGS", "") if flags is None else flags
    for flag, wanted in ((CPU_FLAG, cpu_flag_supported()), (YNN_FLAG, ynn_flag_needed())):
        if wanted and flag.split("=")[0] not in flags:
            flags = f"{flags} {flag}".strip()
    return flags


def gpu_xla_flags(flags: str | None = None) -> str:
    """``XLA_FLAGS`` (``flags``, default the environment's) with :data:`GPU_FLAG` added, unless
    they already choose a command-buffer scheduling mode: a user's ``LHS`` or ``SERIALIZE``
    is kept (the opt-out)."""
    flags = os.environ.get("XLA_FLAGS", "") if flags is None else flags
    if _GPU_MODE_OPTION not in flags:
        flags = f"{flags} {GPU_FLAG}".strip()
    return flags


#: XLA:CPU optimisation level for programs that run once (a PPO run's ``init``): their compile
#: at XLA's default level 3 took 11 s (3-link) and 29 s (Franka) on a 2-core CPU, at level 1
#: 2.9 s and 2.8 s, for the same run time (docs/design.md §5.6).
RUN_ONCE_CPU_LEVEL = 1
_LEVEL_FLAG = re.compile(r"--xla_backend_optimization_level=(\d+)")


def run_once_compiler_options(backend: str) -> dict[str, int]:
    """``compiler_options`` for a program that runs once: on the CPU, optimisation level
    :data:`RUN_ONCE_CPU_LEVEL` (or the lower level ``XLA_FLAGS`` sets), elsewhere none."""
    if backend != "cpu":
        return {}
    found = _LEVEL_FLAG.findall(os.environ.get("XLA_FLAGS", ""))
    level = min([RUN_ONCE_CPU_LEVEL, *map(int, found[-1:])])
    return {"xla_backend_optimization_level": level}


def configure_cpu_flags() -> None:
    """Set ``XLA_FLAGS`` for CPU runs (idempotent; a no-op on jaxlib without the flag)."""
    os.environ["XLA_FLAGS"] = cpu_xla_flags()


def configure_gpu_flags() -> None:
    """Set ``XLA_FLAGS`` to :func:`gpu_xla_flags` (idempotent); effective only when JAX's
    backends are not yet initialised."""
    os.environ["XLA_FLAGS"] = gpu_xla_flags()


def compile_cache_dir(environ: Mapping[str, str] | None = None) -> str | None:
    """The directory the scripts' compile cache goes to, or ``None`` when there is none to set.

    ``None`` when the user set ``JAX_COMPILATION_CACHE_DIR`` (JAX then uses theirs) or
    ``MJXRMP_COMPILE_CACHE`` is ``off``/``0``/``false``; a directory given in
    ``MJXRMP_COMPILE_CACHE``; otherwise ``$XDG_CACHE_HOME/mjxrmp/jax`` (``~/.cache/mjxrmp/jax``
    where ``XDG_CACHE_HOME`` is unset or not absolute). ``environ`` defaults to ``os.environ``.
    """
    env = os.environ if environ is None else environ
    if env.get(JAX_CACHE_DIR_ENV):
        return None
    choice = env.get(CACHE_ENV, "").strip()
    if choice.lower() in CACHE_OFF:
        return None
    if choice:
        return os.path.abspath(os.path.expanduser(choice))
    xdg = env.get("XDG_CACHE_HOME", "")
    base = xdg if os.path.isabs(xdg) else os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "mjxrmp", "jax")


def child_cache_environ(cache_dir: str, environ: Mapping[str, str] | None = None
                        ) -> dict[str, str]:
    """``environ`` (default ``os.environ``) for a child process whose compile cache is
    ``cache_dir``: ``MJXRMP_COMPILE_CACHE`` set to it and ``JAX_COMPILATION_CACHE_DIR`` dropped.
    A script's :func:`configure_compile_cache` exports JAX's variable to its children, and
    :func:`compile_cache_dir` lets that variable win, so without the drop a child would share
    its parent's cache (a benchmark's "cold" run would find the programs of an earlier one)."""
    env = dict(os.environ if environ is None else environ)
    env.pop(JAX_CACHE_DIR_ENV, None)
    env[CACHE_ENV] = cache_dir
    return env


def configure_compile_cache() -> str | None:
    """Turn JAX's persistent compilation cache on in :func:`compile_cache_dir`; return that path.

    Sets ``JAX_COMPILATION_CACHE_DIR`` (inherited by child processes) and, unless the user set it,
    a minimum compile time of :data:`MIN_COMPILE_TIME_S`; where JAX is already imported, also its
    config. A directory that cannot be created leaves the cache off with one warning line.
    """
    path = compile_cache_dir()
    if path is None:
        return None
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as err:
        print(f"warning: compile cache off: cannot create {path} ({err.strerror}); "
              f"set {CACHE_ENV}=DIR or {CACHE_ENV}=off", file=sys.stderr)
        return None
    os.environ[JAX_CACHE_DIR_ENV] = path
    os.environ.setdefault(JAX_MIN_TIME_ENV, str(MIN_COMPILE_TIME_S))
    jax = sys.modules.get("jax")
    if jax is not None:  # imported already: it read the environment at import time
        jax.config.update("jax_compilation_cache_dir", path)
        jax.config.update("jax_persistent_cache_min_compile_time_secs",
                          float(os.environ[JAX_MIN_TIME_ENV]))
    return path


def configure_locations() -> int:
    """Compile programs whose operations keep :data:`TRACEBACK_FRAMES` Python frame as their
    location instead of JAX's default 100, unless ``JAX_TRACEBACK_IN_LOCATIONS_LIMIT`` is set
    (the user's value is kept); return the limit in force.

    Only debug information changes: not a computation, and not the operations' names (their
    ``jax.named_scope`` path, which profiles and :mod:`offline.experiment.step_profile` read).
    On a GPU, XLA formats every kernel's frames into a profiler annotation each time it loads a
    program; with one frame that takes less of the background load, though a warm start measured
    no faster, and the exported programs are smaller (docs/design.md §5.6)."""
    os.environ.setdefault(TRACEBACK_LIMIT_ENV, str(TRACEBACK_FRAMES))
    value = os.environ[TRACEBACK_LIMIT_ENV].strip()
    try:
        limit = int(value)
    except ValueError:
        raise ValueError(f"{TRACEBACK_LIMIT_ENV} must be an integer (a negative one: no limit), "
                         f"got {value!r}") from None
    jax = sys.modules.get("jax")
    if jax is not None:  # imported already: it read the environment at import time
        jax.config.update("jax_traceback_in_locations_limit", limit)
    return limit


def configure_script() -> None:
    """What every script runs before compiling: the CPU and GPU flags, the compile cache and
    the programs' source locations."""
    configure_cpu_flags()
    configure_gpu_flags()
    configure_compile_cache()
    configure_locations()
