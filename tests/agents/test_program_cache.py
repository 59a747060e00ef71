"""Training programs kept between processes (agents.run.program_cache, docs/design.md §5.6):
an exported function gives the same outputs, is read back instead of traced again, is keyed
by everything that shapes it (not by object addresses), a PPO chunk compiled from its
artifact trains bitwise like the one compiled directly (and its init artifact gives a resume's
restore target), and the programs of a repeated command are compiled ahead in the background."""

from __future__ import annotations

import json
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from script_main import load_script

from agents.run import program as program_module
from agents.run import program_cache
from agents.run.program import Program, build, seed_keys
from agents.run.program_cache import (
    artifact_dir,
    command_label,
    exported,
    prefetch,
    program_key,
    remember,
    start_device,
)
from agents.run.spec import RunSpec, preset
from mjxrmp._xla import run_once_compiler_options


class Pair(NamedTuple):
    a: jax.Array
    b: dict


@pytest.fixture
def cache_dir(tmp_path):
    before = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", str(tmp_path))
    yield tmp_path
    jax.config.update("jax_compilation_cache_dir", before)


def test_exported_function_round_trips_and_is_read_back(cache_dir):
    """Custom pytrees in and out; the second request reads the artifact (fn is not traced)."""
    traced = []

    def fn(p: Pair, k: int | jax.Array):
        traced.append(1)
        return Pair(jnp.sin(p.a) * k, {"s": p.b["x"].sum()})

    args = (Pair(jnp.arange(3.0), {"x": jnp.ones((2, 2))}), jnp.asarray(2.0))
    first = exported(fn, args, {"what": "test"})
    second = exported(fn, args, {"what": "test"})
    assert len(traced) == 1 and len(list(artifact_dir().iterdir())) == 1
    for call in (first, second):
        out = call(*args)
        assert isinstance(out, Pair)
        np.testing.assert_array_equal(out.a, jnp.sin(args[0].a) * 2.0)
        np.testing.assert_array_equal(out.b["s"], 4.0)
    exported(fn, args, {"what": "other"})  # another description is another program
    assert len(traced) == 2


def test_an_unreadable_artifact_is_exported_again(cache_dir):
    """A damaged artifact file gives a warning naming it and is replaced by a good one."""
    args = (jnp.arange(3.0),)
    exported(jnp.cos, args, {"what": "damaged"})
    (path,) = artifact_dir().iterdir()
    path.write_bytes(b"not an artifact")
    with pytest.warns(UserWarning, match="unreadable program artifact"):
        call = exported(jnp.cos, args, {"what": "damaged"})
    np.testing.assert_array_equal(call(*args), jnp.cos(args[0]))
    assert exported(jnp.cos, args, {"what": "damaged"}) is not None  # readable again


def test_nothing_is_kept_without_a_compile_cache():
    before = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", None)
    try:
        assert artifact_dir() is None
        assert exported(jnp.sin, (jnp.ones(2),), {"what": "test"}) is None
    finally:
        jax.config.update("jax_compilation_cache_dir", before)


def test_key_follows_shapes_and_description():
    x = (jnp.ones((2, 3)),)
    assert program_key({"a": 1}, x) == program_key({"a": 1}, (jnp.zeros((2, 3)),))
    assert program_key({"a": 1}, x) != program_key({"a": 2}, x)
    assert program_key({"a": 1}, x) != program_key({"a": 1}, (jnp.ones((3, 2)),))
    assert program_key({"a": 1}, x) != program_key({"a": 1}, (jnp.ones((2, 3), jnp.int32),))


SPEC = RunSpec(env="three_link/env3", policy="nn", seeds=(0, 1), log_every=1,
               checkpoint_every=1,
               ppo=preset("cpu", num_envs=4, rollout_length=8, num_minibatches=2,
                          update_epochs=1, total_iterations=1))


def test_ppo_chunk_from_its_artifact_trains_like_the_direct_compile(cache_dir):
    """Rebuilt from scratch (new environment objects), the program finds the same artifacts;
    one chunk from them equals the directly compiled chunk bitwise."""
    program_module._program.cache_clear()
    program = build(SPEC)
    state = program.initial_state(seed_keys(SPEC.seeds))
    direct = program.run.lower(state, 1).compile()(state)
    via = program.executable(state, 1)(state)
    files = sorted(p.name for p in artifact_dir().iterdir())
    assert len(files) == 2  # init and the chunk
    program_module._program.cache_clear()
    rebuilt = build(SPEC)
    again = rebuilt.executable(rebuilt.initial_state(seed_keys(SPEC.seeds)), 1)(state)
    assert sorted(p.name for p in artifact_dir().iterdir()) == files
    # a resume's restore target, read from the init artifact instead of traced
    keys = seed_keys(SPEC.seeds)
    # the init program runs once: its artifact is keyed and compiled with the run-once options
    options = run_once_compiler_options(jax.default_backend())
    assert program_cache.exported_shapes((keys,), {**rebuilt.description, "program": "init"},
                                         options)
    if options:  # on the CPU: another key than the default options'
        assert program_cache.exported_shapes((keys,), {**rebuilt.description, "program": "init"},
                                             {}) is None
    shapes, traced = rebuilt.state_shapes(keys), jax.eval_shape(rebuilt.init, keys)
    assert jax.tree.structure(shapes) == jax.tree.structure(traced)
    assert [(x.shape, x.dtype) for x in jax.tree.leaves(shapes)] == [
        (x.shape, x.dtype) for x in jax.tree.leaves(traced)]
    program_module._program.cache_clear()
    for got in (via, again):
        jax.tree.map(np.testing.assert_array_equal, got, direct)


@pytest.fixture
def new_process(cache_dir):
    """The artifact bookkeeping of a fresh process (what it used, what it compiles ahead)."""
    program_cache._USED.clear()
    program_cache._DEVICE.clear()
    yield cache_dir
    program_cache._USED.clear()
    program_cache._AHEAD.clear()
    program_cache._DEVICE.clear()


def test_a_repeated_command_gets_its_programs_compiled_ahead(new_process):
    """remember() notes what a command used; the next process with that label has them compiled
    in the background and exported() hands over that compile (fn is not traced again; the
    ``lowered`` callback is called)."""
    args = (Pair(jnp.arange(3.0), {"x": jnp.ones((2, 2))}), jnp.asarray(2.0))

    def fn(p: Pair, k: jax.Array):
        return Pair(jnp.sin(p.a) * k, {"s": p.b["x"].sum()})

    exported(fn, args, {"what": "ahead"})
    exported(jnp.cos, (jnp.ones(4),), {"what": "ahead"})
    remember("train --seeds 0")
    program_cache._USED.clear()  # a new process
    assert prefetch("train --seeds 1") == 0 and not program_cache._AHEAD
    assert prefetch("train --seeds 0") == 2 and len(program_cache._AHEAD) == 2
    # the background thread leaves the output tree pickled (loading it imports its node types)
    assert all(isinstance(job.result()[1], bytes) for job in program_cache._AHEAD.values())

    def untraceable(*_):
        raise AssertionError("traced although compiled ahead")

    lowered = []  # nothing left to trace: a waiting trace (compile_ahead's init) may go on
    out = exported(untraceable, args, {"what": "ahead"}, lowered=lambda: lowered.append(1))(*args)
    assert lowered == [1] and len(program_cache._AHEAD) == 1  # the other one was not asked for
    np.testing.assert_array_equal(out.a, jnp.sin(args[0].a) * 2.0)
    np.testing.assert_array_equal(out.b["s"], 4.0)
    remember("train --seeds 0")  # used now first, then what the label used before
    record = json.loads(program_cache._record(artifact_dir(), "train --seeds 0").read_text())
    assert record == list(dict.fromkeys([*program_cache._USED, *record]))
    assert len(record) == 2 and record[0] == program_cache._USED[0]


def test_a_damaged_artifact_compiled_ahead_is_exported_again(new_process):
    args = (jnp.arange(3.0),)
    exported(jnp.cos, args, {"what": "damaged ahead"})
    remember("label")
    (path,) = artifact_dir().glob("*.jaxexport")
    path.write_bytes(b"not an artifact")
    assert prefetch("label") == 1
    with pytest.warns(UserWarning, match="unreadable program artifact"):
        call = exported(jnp.cos, args, {"what": "damaged ahead"})
    np.testing.assert_array_equal(call(*args), jnp.cos(args[0]))


def test_command_label_leaves_out_what_does_not_compile():
    label = command_label(["--env", "a", "--out", "r1", "--resume", "--out=r2", "--seeds", "0"],
                          {"--out"}, {"--resume"})
    assert json.loads(label) == ["--env", "a", "--seeds", "0"]


def test_train_script_prefetches_except_in_a_multi_process_run(new_process):
    """scripts/train.py starts the device and the compile ahead for its label, never before
    jax.distributed (abbreviated options included)."""
    train = load_script("train.py")
    exported(jnp.sin, (jnp.ones(2),), {"what": "script"})
    argv = ["--seeds", "0", "--out", "runs/x"]
    for extra in (["--coordinator", "h:1"], ["--dist"], ["--num-proc=2"]):
        remember(command_label(argv + extra, *train._UNCOMPILED))
        train._start_prefetch(argv + extra)
        assert not program_cache._AHEAD and not program_cache._DEVICE
    remember(command_label(argv, *train._UNCOMPILED))
    train._start_prefetch([*argv[:2], "--out", "runs/y", "--no-progress"])
    assert len(program_cache._AHEAD) == 1
    assert program_cache._DEVICE[0].result(timeout=60) == {jax.devices()[0]}


def test_the_device_is_started_once_per_process(new_process, monkeypatch):
    """start_device() makes one first transfer in a background thread; later calls get the same
    future, and an error in that thread stays in it (the main thread meets it on its own)."""
    first = start_device()
    assert start_device() is first and first.result(timeout=60) == {jax.devices()[0]}
    program_cache._DEVICE.clear()

    def no_device(x):
        raise RuntimeError("no device")

    monkeypatch.setattr(jax, "device_put", no_device)
    with pytest.raises(RuntimeError, match="no device"):
        start_device().result(timeout=60)


def test_a_chunk_compiled_ahead_is_the_one_the_run_uses(cache_dir, monkeypatch):
    """compile_ahead() compiles the chunk for init's shapes while init compiles, init's trace
    waiting until the chunk is lowered; executable() takes that compile (nothing compiled
    twice), and it trains exactly like a direct compile."""
    program_module._program.cache_clear()
    order, compile_run, from_artifact = [], Program._compile_run, Program._from_artifact

    def noting_compile_run(self, state, n, lowered=lambda: None):
        return compile_run(self, state, n, lambda: (order.append("chunk lowered"), lowered()))

    def noting_from_artifact(self, fn, args, what, *rest, **named):
        order.extend(["init traced"] if what.get("program") == "init" else [])
        return from_artifact(self, fn, args, what, *rest, **named)

    monkeypatch.setattr(Program, "_compile_run", noting_compile_run)
    monkeypatch.setattr(Program, "_from_artifact", noting_from_artifact)
    program = build(SPEC)
    keys = seed_keys(SPEC.seeds)
    job = program.compile_ahead(keys, 1)
    state = program.initial_state(keys)
    chunk = program.executable(state, 1)
    assert order == ["chunk lowered", "init traced"]
    assert job.done() and not program.ahead and len(program.executables) == 1
    assert program.executable(state, 1) is chunk
    direct = program.run.lower(state, 1).compile()(state)
    for a, b in zip(jax.tree.leaves(chunk(state)), jax.tree.leaves(direct), strict=True):
        np.testing.assert_array_equal(a, b)


def test_an_error_compiling_ahead_is_raised_where_the_chunk_is_needed(cache_dir, monkeypatch):
    program_module._program.cache_clear()
    program = build(SPEC)
    keys = seed_keys(SPEC.seeds)

    def broken(keys):
        raise RuntimeError("shapes unavailable")

    monkeypatch.setattr(program, "state_shapes", broken)
    program.compile_ahead(keys, 1)
    state = program.initial_state(keys)
    with pytest.raises(RuntimeError, match="shapes unavailable"):
        program.executable(state, 1)
    program_module._program.cache_clear()
