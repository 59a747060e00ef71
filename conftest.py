"""Pytest configuration shared by the whole suite.

Sets the XLA:CPU flag MJX needs (docs/design.md §5.2, only where the installed jaxlib knows it)
and pins JAX to the CPU before JAX initialises, so the suite behaves the same on a laptop, in CI
and on a GPU host.

The suite is dominated by compilation (hundreds of small programs, each run briefly), so it also
turns XLA's backend (LLVM) optimisation off: compiles get about twice as fast, the compiled code
somewhat slower; measured on 2 cores, the evaluation and policy-class tests went from 184 s to
109 s. The same HLO is compiled; results can differ only by rounding.

And it gives the whole session one fresh persistent compilation cache (docs/design.md §5.6): the
process that starts pytest creates the directory before JAX is imported and sets
``JAX_COMPILATION_CACHE_DIR``, which the xdist workers and the scripts the tests run inherit, so a
program compiled once is loaded, not compiled again, by every other worker and subprocess. The
directory is removed when that process ends the session. A ``JAX_COMPILATION_CACHE_DIR`` set by
the user is used as it is (and kept).
"""

import os
import shutil
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
_SESSION_CACHE = None
if not os.environ.get("JAX_COMPILATION_CACHE_DIR"):  # unset here: not a worker, not the user's
    _SESSION_CACHE = tempfile.mkdtemp(prefix="mjxrmp-test-jax-cache-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _SESSION_CACHE
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

from mjxrmp._xla import configure_cpu_flags  # noqa: E402

configure_cpu_flags()
if "xla_backend_optimization_level" not in os.environ["XLA_FLAGS"]:
    os.environ["XLA_FLAGS"] += " --xla_backend_optimization_level=0"


def pytest_unconfigure(config) -> None:
    """Remove the session's compile cache in the process that created it."""
    if _SESSION_CACHE is not None:
        shutil.rmtree(_SESSION_CACHE, ignore_errors=True)
