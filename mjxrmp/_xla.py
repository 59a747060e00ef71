"""XLA settings every CPU entry point needs (docs/design.md §5.2).

With jaxlib 0.7.1–0.10.x, XLA:CPU's fusion emitters make MJX kinematics of deep chains extremely
slow (seconds per step for the Franka); disabling them restores millisecond steps. The flag is read
when the first backend initialises, so it must be set before any JAX computation runs. jaxlib 0.11
removed the flag (and aborts on unknown XLA flags), so it is only set where jaxlib knows it.
"""

from __future__ import annotations

import os
from importlib import metadata

CPU_FLAG = "--xla_cpu_use_fusion_emitters=false"


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


def cpu_xla_flags(flags: str | None = None) -> str:
    """``XLA_FLAGS`` with the fusion-emitter workaround added where jaxlib supports it."""
    flags = os.environ.get("XLA_FLAGS", "") if flags is None else flags
    if cpu_flag_supported() and "xla_cpu_use_fusion_emitters" not in flags:
        flags = f"{flags} {CPU_FLAG}".strip()
    return flags


def configure_cpu_flags() -> None:
    """Set ``XLA_FLAGS`` for CPU runs (idempotent; a no-op on jaxlib without the flag)."""
    os.environ["XLA_FLAGS"] = cpu_xla_flags()
