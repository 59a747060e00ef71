"""Rows of stacked run states (seeds, a sweep's points and checkpoints share the leading axis;
docs/design.md §2.3): one seed's row, a block of rows, and states stacked along that axis.

Each is one compiled program per state layout (and block size), not one operation per leaf:
outside ``jit`` every leaf's slice or concatenation would be dispatched and compiled on its own.
The values are the plain slices and concatenations.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp


@jax.jit
def row(tree: Any, index: int | jax.Array) -> Any:
    """Row ``index`` of every leaf of ``tree`` (the leading axis dropped)."""
    return jax.tree.map(lambda x: x[index], tree)


@functools.partial(jax.jit, static_argnames="size")
def rows(tree: Any, start: int | jax.Array, size: int) -> Any:
    """Rows ``start … start + size − 1`` of every leaf of ``tree``."""
    return jax.tree.map(lambda x: jax.lax.dynamic_slice_in_dim(x, start, size), tree)


@jax.jit
def stacked(trees: Sequence[Any]) -> Any:
    """``trees`` (one layout) concatenated leaf by leaf along the leading axis, in order."""
    return jax.tree.map(lambda *xs: jnp.concatenate(xs), *trees)


__all__ = ["row", "rows", "stacked"]
