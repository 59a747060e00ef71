"""agents.run.rows: a seed's row, a block of rows and stacked states equal the plain slices and
concatenations leaf by leaf, and a new index or start does not compile again."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.run.rows import row, rows, stacked

TREE = {"w": jnp.arange(24.0).reshape(6, 2, 2), "n": jnp.arange(6, dtype=jnp.int32),
        "key": jax.random.split(jax.random.key(0), 6)}


def _same(a, b):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            x, y = jax.random.key_data(x), jax.random.key_data(y)
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@settings(max_examples=20, deadline=None)
@given(st.integers(-6, 5), st.integers(0, 6), st.integers(1, 3))
def test_rows_equal_the_plain_slices(index, start, size):
    start = min(start, 6 - size)
    _same(row(TREE, index), jax.tree.map(lambda x: x[index], TREE))
    _same(rows(TREE, start, size), jax.tree.map(lambda x: x[start:start + size], TREE))


def test_stacked_is_the_concatenation_in_order_and_compiles_once_per_layout():
    parts = [rows(TREE, 0, 2), rows(TREE, 2, 4)]
    _same(stacked(parts), TREE)
    before = row._cache_size()
    row(TREE, 1), row(TREE, 4)
    assert row._cache_size() - before <= 1  # the index is data, not part of the program
