"""An independent float64 formulation of RMP² for reference tests.

Jacobians by central finite differences, curvatures ``J̇q̇`` by a five-point second difference
along ``q̇``, explicit per-subtask loops for ``M = Σ JᵀM_kJ`` and ``f = Σ Jᵀ(f_k − M_k c_k)``
(eq 3.31), and the resolve numerics written out in NumPy.
"""

from __future__ import annotations

import jax
import numpy as np

H_JAC = 1e-5
H_CURV = 1e-3


def _np_tree(tree):
    return jax.tree.map(lambda a: np.asarray(a, dtype=np.float64), tree)


def fd_kinematics(task_map, q, qd, *ctx):
    """``(x, xd, c, J)`` by finite differences; ``J`` leaves ``(n, m, d)``."""
    q = np.asarray(q, np.float64)
    qd = np.asarray(qd, np.float64)
    d = q.shape[0]
    task_map = jax.jit(task_map)  # evaluated at 2·d + 5 points: compiled once, not op by op

    def x_at(qq):
        return _np_tree(task_map(qq, *ctx))

    x = x_at(q)
    cols = []
    for j in range(d):
        e = np.zeros(d)
        e[j] = H_JAC
        cols.append(jax.tree.map(lambda a, b: (a - b) / (2 * H_JAC), x_at(q + e), x_at(q - e)))
    J = jax.tree.map(lambda *c: np.stack(c, axis=-1), *cols)
    h = H_CURV
    xs = [x_at(q + k * h * qd) for k in (2, 1, 0, -1, -2)]
    c = jax.tree.map(
        lambda a2, a1, a0, m1, m2: (-a2 + 16 * a1 - 30 * a0 + 16 * m1 - m2) / (12 * h * h), *xs
    )
    xd = jax.tree.map(lambda Jk: np.einsum("nmd,d->nm", Jk, qd), J)
    return x, xd, c, J


def explicit_sum(J_leaves, rmp_leaves, c_leaves=None):
    """Root ``(M, f)`` by explicit loops over every subtask of every family."""
    d = J_leaves[0].shape[-1]
    M = np.zeros((d, d))
    f = np.zeros(d)
    for k, (Jk, (Mk, fk)) in enumerate(zip(J_leaves, rmp_leaves, strict=True)):
        Mk = np.asarray(Mk, np.float64)
        fk = np.asarray(fk, np.float64)
        for n in range(Jk.shape[0]):
            Jn = Jk[n]
            force = fk[n] if c_leaves is None else fk[n] - Mk[n] @ c_leaves[k][n]
            M += Jn.T @ Mk[n] @ Jn
            f += Jn.T @ force
    return M, f


def reference_pullback(task_map, leaf_fn, q, qd, *ctx, jit_leaves=True):
    """Root RMP ``(M, f)`` of eq 3.31 with finite-difference Jacobians and curvatures
    (``jit_leaves=False`` for a ``leaf_fn`` written with NumPy)."""
    x, xd, c, J = fd_kinematics(task_map, q, qd, *ctx)
    rmps = (jax.jit(leaf_fn) if jit_leaves else leaf_fn)(x, xd, *ctx)
    rmp_leaves = jax.tree.structure(x).flatten_up_to(rmps)
    return explicit_sum(jax.tree.leaves(J), rmp_leaves, jax.tree.leaves(c))


def reference_pullback_velocity(task_map, leaf_fn, q, *ctx):
    """Root ``(Σ JᵀM_kJ, Σ Jᵀp_k)`` of the first-order form (eq 5.1)."""
    d = np.asarray(q).shape[0]
    x, _, _, J = fd_kinematics(task_map, q, np.zeros(d), *ctx)
    rmps = jax.jit(leaf_fn)(x, *ctx)
    rmp_leaves = jax.tree.structure(x).flatten_up_to(rmps)
    return explicit_sum(jax.tree.leaves(J), rmp_leaves)


def reference_resolve(M, f):
    """``(M/s + 1e-3 I)⁻¹ f/s`` with ``s = max(1, 0.01 max|M|)`` (the original numerics)."""
    s = max(1.0, 0.01 * np.max(np.abs(M)))
    return np.linalg.solve(M / s + 1e-3 * np.eye(M.shape[0]), f / s)


def rel_err(a, b) -> float:
    """``‖a − b‖ / max(‖b‖, 1e-12)`` in float64."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-12))
