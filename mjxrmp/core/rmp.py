"""The RMP pytree: a Riemannian motion policy in natural form (thesis §3.2.1, §3.2.6)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp


class RMP(NamedTuple):
    """An RMP in natural form ``[M, f]`` with ``f = M a`` (thesis §3.2.6).

    For a family of ``n`` subtasks of dimension ``m`` (the leaves of a task map), ``M`` has shape
    ``(n, m, m)`` and ``f`` has shape ``(n, m)``. At the root, ``M`` is ``(d, d)`` and ``f`` is
    ``(d,)``. In the velocity form (eq 5.1) the second entry holds ``p = M v``.
    """

    M: jax.Array
    f: jax.Array


def natural(M: jax.Array, a: jax.Array) -> RMP:
    """Natural form ``[M, M a]`` of the canonical RMP ``(M, a)`` for a family (thesis §3.2.6)."""
    return RMP(M, jnp.sum(M * a[..., None, :], axis=-1))


def is_rmp(node: object) -> bool:
    """Whether a pytree node is an :class:`RMP` (used as ``is_leaf`` in tree utilities)."""
    return isinstance(node, RMP)
