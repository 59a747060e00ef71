"""XLA settings every CPU entry point needs (DESIGN §8.2).

With jax >= 0.7.1, XLA:CPU's fusion emitters make MJX kinematics of deep chains extremely slow
(seconds per step for the Franka). Disabling them restores millisecond steps. The flag is read
when the first backend initialises, so it must be set before any JAX computation runs.
"""

from __future__ import annotations

import os

CPU_FLAG = "--xla_cpu_use_fusion_emitters=false"


def configure_cpu_flags() -> None:
    """Append the XLA:CPU fusion-emitter workaround to ``XLA_FLAGS`` (idempotent)."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_use_fusion_emitters" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {CPU_FLAG}".strip()
