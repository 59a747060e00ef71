"""The naive RMP² baseline: every subtask differentiated on its own (thesis §3.2.2, "Complexity").

:func:`acceleration_naive` has the contract of :func:`mjxrmp.core.rmp2.acceleration` and returns the
same joint acceleration, but computes it the way a straightforward implementation of the RMP
algebra would. For every family ``k`` and every one of its ``n_k`` rows ``i`` it takes the
single-subtask map ``ψ_{k,i}: q ↦ task_map(q, *ctx)[k][i]`` and computes, one subtask at a time,

* its explicit Jacobian ``J_{k,i} = ∂ψ_{k,i}/∂q`` (``jax.jacfwd``, shape ``(m_k, d)``),
* its position, velocity ``J q̇`` and curvature ``J̇ q̇`` (a jvp nested in a jvp);

then it evaluates the leaf RMPs on the tree assembled from those rows, accumulates
``M = Σ Jᵀ M_{k,i} J`` and ``f = Σ Jᵀ (f_{k,i} − M_{k,i} c_{k,i})`` one subtask at a time, and
resolves the root with :func:`mjxrmp.core.rmp2.resolve` (the same numerics as RMP²).

**Why it is slow.** Nothing is shared between subtasks: each of the ``N = Σ n_k`` subtask maps
re-runs the robot's forward kinematics (for the Franka ~180 subtasks, each walking the 7-joint
chain) with ``d`` tangents for the Jacobian and once more for the second-order pass, so the work
grows as ``O(N · d · cost(FK))``, and the ``N`` small ``JᵀMJ`` products run one after another.
RMP² (:mod:`mjxrmp.core.rmp2`) instead pushes ``d + 1`` tangents through *one* pass of the
whole task map and contracts every family with one batched ``einsum``.

**Keeping the baseline honest under XLA.** The subtask maps of one family are identical
computations of ``q``, so XLA's common-subexpression elimination (or loop-invariant code motion)
would merge them and quietly turn the naive algorithm back into a shared forward pass. Every
subtask therefore evaluates its map at ``q + z_i`` where ``z_i = 0·(q̇_0 + i)`` is exactly zero
for finite inputs but different for every subtask and opaque to the compiler (XLA does not fold
``0·x`` for floats).

**Loops.** By default (``unroll=False``) the families are a Python loop and the rows of a family
a ``lax.fori_loop``: compile time stays a few seconds. ``unroll=True`` unrolls the rows as a
Python loop at trace time instead (the literal textbook form); for the Franka's ~180 subtasks
that compiles for minutes on a CPU. Both are jittable and vmappable and give the same result.

This module exists for comparison (``scripts/bench.py``) and as an independent second
implementation in tests; use :func:`mjxrmp.core.rmp2.acceleration` for real work.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from mjxrmp.core import rmp2
from mjxrmp.core.rmp import RMP


def _family_shapes(task_map, q, ctx):
    shapes = jax.eval_shape(lambda q_: task_map(q_, *ctx), q)
    rmp2.check_task_tree(shapes)
    return jax.tree.flatten(shapes)


def _subtask_kinematics(task_map, k: int, i, q, qd, ctx):
    """``(x, ẋ, c, J)`` of the single subtask ``(family k, row i)``, computed on its own.

    ``i`` is a Python int (unrolled) or a traced loop index (``fori_loop``).
    """
    # Exactly zero, but distinct per subtask and opaque to XLA: no sharing between subtasks.
    z = jnp.zeros((), q.dtype) * (qd[0] + jnp.asarray(i, q.dtype))
    q_i = q + z

    def psi(q_):
        family = jax.tree.leaves(task_map(q_, *ctx))[k]
        return jax.lax.dynamic_index_in_dim(family, i, axis=0, keepdims=False)

    def position_and_velocity(q_):
        return jax.jvp(psi, (q_,), (qd,))

    (x, xd), (_, c) = jax.jvp(position_and_velocity, (q_i,), (qd,))
    J = jax.jacfwd(psi)(q_i)
    return x, xd, c, J


def _family_kinematics(task_map, k: int, n: int, m: int, q, qd, ctx, unroll: bool):
    """Stacked ``(x (n,m), ẋ (n,m), c (n,m), J (n,m,d))`` of family ``k``, row by row."""
    if unroll:
        rows = [_subtask_kinematics(task_map, k, i, q, qd, ctx) for i in range(n)]
        return tuple(jnp.stack(parts) for parts in zip(*rows, strict=True))

    d = q.shape[0]
    init = (
        jnp.zeros((n, m), q.dtype),
        jnp.zeros((n, m), q.dtype),
        jnp.zeros((n, m), q.dtype),
        jnp.zeros((n, m, d), q.dtype),
    )

    def body(i, acc):
        row = _subtask_kinematics(task_map, k, i, q, qd, ctx)
        return tuple(a.at[i].set(r) for a, r in zip(acc, row, strict=True))

    return jax.lax.fori_loop(0, n, body, init)


def _subtask_pullback(J, M, f, c):
    """``(JᵀMJ, Jᵀ(f − Mc))`` of one subtask."""
    return J.T @ M @ J, J.T @ (f - M @ c)


def acceleration_naive(
    task_map, leaf_fn, q: jax.Array, qd: jax.Array, *ctx: Any, unroll: bool = False
) -> jax.Array:
    """RMP² acceleration computed subtask by subtask (the naive baseline; see the module doc).

    Same arguments and result as :func:`mjxrmp.core.rmp2.acceleration` (without ``debug``):
    ``q`` and ``qd`` are single configurations ``(d,)``, ``ctx`` goes to ``task_map`` and
    ``leaf_fn``.
    ``unroll=True`` unrolls the per-subtask loop in Python (slow to compile).
    """
    q = rmp2.check_configuration("q", q)
    qd = rmp2.check_configuration("qd", qd, q.shape[0])
    leaves, treedef = _family_shapes(task_map, q, ctx)

    # Forward pass: every subtask on its own.
    fams = [
        _family_kinematics(task_map, k, *leaf.shape, q, qd, ctx, unroll)
        for k, leaf in enumerate(leaves)
    ]

    # Leaf RMPs on the assembled tree.
    x_tree = jax.tree.unflatten(treedef, [fam[0] for fam in fams])
    xd_tree = jax.tree.unflatten(treedef, [fam[1] for fam in fams])
    rmps = rmp2.flatten_leaf_rmps(x_tree, leaf_fn(x_tree, xd_tree, *ctx), "f")

    # Backward pass: accumulate Σ JᵀMJ and Σ Jᵀ(f − Mc) one subtask at a time.
    d = q.shape[0]
    M_root = jnp.zeros((d, d), q.dtype)
    f_root = jnp.zeros((d,), q.dtype)
    for (_, _, c_k, J_k), node in zip(fams, rmps, strict=True):
        M_k, f_k = node
        if unroll:
            for i in range(J_k.shape[0]):
                dM, df = _subtask_pullback(J_k[i], M_k[i], f_k[i], c_k[i])
                M_root, f_root = M_root + dM, f_root + df
        else:
            def body(i, acc, J_k=J_k, M_k=M_k, f_k=f_k, c_k=c_k):
                dM, df = _subtask_pullback(J_k[i], M_k[i], f_k[i], c_k[i])
                return acc[0] + dM, acc[1] + df

            M_root, f_root = jax.lax.fori_loop(0, J_k.shape[0], body, (M_root, f_root))
    return rmp2.resolve(RMP(M_root, f_root))
