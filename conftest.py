"""Pytest configuration shared by the whole suite.

Sets the XLA:CPU flag MJX needs (docs/design.md §5.2, only where the installed jaxlib knows it)
and pins JAX to the CPU before JAX initialises, so the suite behaves the same on a laptop, in CI
and on a GPU host.

The suite is dominated by compilation (hundreds of small programs, each run briefly), so it also
turns XLA's backend (LLVM) optimisation off: compiles get about twice as fast, the compiled code
somewhat slower; measured on 2 cores, the evaluation and policy-class tests went from 184 s to
109 s. The same HLO is compiled; results can differ only by rounding. Programs are lowered with
one Python frame per operation's location, as the scripts do (``configure_locations``,
docs/design.md §5.6): under pytest JAX's default of 100 frames walks deep test-runner stacks for
every operation (the pooled PPO test: 39–40 s of CPU time with 100 frames, 35–36 s with one).
Python's garbage collector runs less often (:data:`GC_THRESHOLDS`).

And it gives the whole session one fresh persistent compilation cache (docs/design.md §5.6): the
process that starts pytest creates the directory before JAX is imported and sets
``JAX_COMPILATION_CACHE_DIR``, which the xdist workers and the scripts the tests run inherit, so a
program compiled once is loaded, not compiled again, by every other worker and subprocess. The
directory is removed when that process ends the session. A ``JAX_COMPILATION_CACHE_DIR`` set by
the user is used as it is (and kept).

Under pytest-xdist (``--dist loadfile``) every test module is one unit of work, so its
module-scoped fixtures (a trained run, a compiled evaluator) are built by one worker only; the
modules in :data:`LONG_FIRST` are scheduled first, the rest follow in collection order
(``--no-loadscope-reorder``), so the two workers finish together.
"""

import gc
import os
import shutil
import tempfile

import pytest

#: Python's cyclic garbage collector runs less often than its default (700, 10, 10): tracing and
#: lowering allocate millions of short-lived objects, and in a test process holding every imported
#: module a full collection is slow. Measured on 2 cores, the reset-pool, RMP² and evaluation
#: modules in one process: 7.6 s of collections with the default, 2.3 s with these.
GC_THRESHOLDS = (10_000, 20, 100)

os.environ.setdefault("JAX_PLATFORMS", "cpu")
_SESSION_CACHE = None
if not os.environ.get("JAX_COMPILATION_CACHE_DIR"):  # unset here: not a worker, not the user's
    _SESSION_CACHE = tempfile.mkdtemp(prefix="mjxrmp-test-jax-cache-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _SESSION_CACHE
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

from mjxrmp._xla import configure_cpu_flags, configure_locations  # noqa: E402

configure_cpu_flags()
configure_locations()
gc.set_threshold(*GC_THRESHOLDS)
if "xla_backend_optimization_level" not in os.environ["XLA_FLAGS"]:
    os.environ["XLA_FLAGS"] += " --xla_backend_optimization_level=0"


#: The longest test modules, longest first (their summed durations in the default suite on 2
#: cores, 2026-11-28, --durations=60/80); scheduled before all others.
LONG_FIRST = (
    "tests/agents/test_sweep.py",
    "tests/agents/test_bench_peers.py",
    "tests/agents/test_limit_check.py",
    "tests/agents/test_eval.py",
    "tests/mjxrmp/test_linalg.py",
    "tests/agents/test_bench_scaling.py",
    "tests/envs/test_reset_pool.py",
    "tests/offline/test_reproduce_ch8.py",
    "tests/agents/test_bench.py",
    "tests/offline/test_minari_bridge.py",
    "tests/offline/test_offline_experiment.py",
    "tests/envs/test_envs_franka.py",
    "tests/envs/test_brax_interop.py",
    "tests/agents/test_distributed.py",
    "tests/offline/test_offline_evaluate.py",
    "tests/offline/test_atac.py",
    "tests/agents/test_program_cache.py",
    "tests/faults/test_ppo_divergence.py",
    "tests/agents/test_agent_policies.py",
    "tests/envs/test_envs.py",
    "tests/agents/test_export.py",
    "tests/agents/lfd/test_skills.py",
    "tests/envs/test_gymnasium_adapter.py",
    "tests/offline/test_residual_actor.py",
    "tests/agents/test_training.py",
    "tests/offline/test_iql_cql.py",
    "tests/mjxrmp/test_policies.py",
    "tests/agents/test_ppo.py",
    "tests/agents/lfd/test_lfd_franka_eval.py",
    "tests/agents/lfd/test_lfd_flow_field.py",
    "tests/agents/test_bench_profile.py",
    "tests/faults/test_run_directory.py",
    "tests/offline/test_offline_diagnostics.py",
    "tests/agents/test_sim2sim.py",
    "tests/test_docs.py",
)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Put the modules of :data:`LONG_FIRST` first (a stable sort: the order inside a module
    and of the other modules is kept)."""
    rank = {name: i for i, name in enumerate(LONG_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))


def pytest_unconfigure(config) -> None:
    """Remove the session's compile cache in the process that created it."""
    if _SESSION_CACHE is not None:
        shutil.rmtree(_SESSION_CACHE, ignore_errors=True)
