"""Pytest configuration shared by the whole suite.

Sets the XLA:CPU flag MJX needs (DESIGN §8.2, only where the installed jaxlib knows it) and pins
JAX to the CPU before JAX initialises, so the suite behaves the same on a laptop, in CI and on a
GPU host.
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

from mjxrmp._xla import configure_cpu_flags

configure_cpu_flags()
