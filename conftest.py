"""Pytest configuration shared by the whole suite.

Sets the XLA:CPU flag MJX needs (docs/design.md §5.2, only where the installed jaxlib knows it)
and pins JAX to the CPU before JAX initialises, so the suite behaves the same on a laptop, in CI
and on a GPU host.

The suite is dominated by compilation (hundreds of small programs, each run briefly), so it also
turns XLA's backend (LLVM) optimisation off: compiles get about twice as fast, the compiled code
somewhat slower; measured on 2 cores, the evaluation and policy-class tests went from 184 s to
109 s. The same HLO is compiled; results can differ only by rounding.
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

from mjxrmp._xla import configure_cpu_flags

configure_cpu_flags()
if "xla_backend_optimization_level" not in os.environ["XLA_FLAGS"]:
    os.environ["XLA_FLAGS"] += " --xla_backend_optimization_level=0"
