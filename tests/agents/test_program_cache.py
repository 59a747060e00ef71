"""Training programs kept between processes (agents.run.program_cache, docs/design.md §5.6):
an exported function gives the same outputs, is read back instead of traced again, is keyed
by everything that shapes it (not by object addresses), and a PPO chunk compiled from its
artifact trains bitwise like the one compiled directly."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.run import program as program_module
from agents.run.program import build, seed_keys
from agents.run.program_cache import artifact_dir, exported, program_key
from agents.run.spec import RunSpec, preset


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
    program_module._program.cache_clear()
    for got in (via, again):
        jax.tree.map(np.testing.assert_array_equal, got, direct)
