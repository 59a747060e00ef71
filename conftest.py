"""Pytest configuration shared by the whole suite.

Sets the XLA:CPU flag MJX needs (DESIGN §8.2) and pins JAX to the CPU before JAX initialises,
so the suite behaves the same on a laptop, in CI and on a GPU host.
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
_flags = os.environ.get("XLA_FLAGS", "")
if "xla_cpu_use_fusion_emitters" not in _flags:
    os.environ["XLA_FLAGS"] = f"{_flags} --xla_cpu_use_fusion_emitters=false".strip()
