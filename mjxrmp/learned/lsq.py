"""Exact constrained linear least squares, jittable: NNLS → LSI → LSEI (Lawson & Hanson 1974).

The bias fit of the nominal-trajectory potential (thesis eq 4.12,
:func:`mjxrmp.learned.nominal_fit.fit_biases`) is a strictly convex least-squares problem with
linear inequality and equality constraints. It is solved *exactly* (finite active-set
termination, no tolerance-driven iteration on the objective) by Lawson & Hanson's reductions
(*Solving Least Squares Problems*, 1974, ch. 20–23), the method of SLSQP's subproblem solver:

* :func:`nnls` — ``min ‖Ax − b‖ s.t. x ≥ 0``, their active-set method (the algorithm of
  ``scipy.optimize.nnls``) with fixed-shape masks so that it runs under ``jax.jit``/``jax.vmap``;
* :func:`lsi` — ``min ‖Cx − d‖ s.t. Gx ≥ h``: with ``C = QR`` it becomes the least-distance
  program ``min ‖z‖ s.t. G R⁻¹ z ≥ h − G R⁻¹ Qᵀd``, solved through one NNLS;
* :func:`lsei` — adds equalities ``Ex = e``, eliminated through the SVD of ``E``.

Run in float64 (``jax_enable_x64``): NNLS solves normal equations on its passive set, and
float32 loses the exactness. Each NNLS takes at most ``3n`` active-set steps with an ``O(n³)``
solve each.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.scipy.linalg import solve_triangular

__all__ = ["lsei", "lsi", "nnls"]


def nnls(A: jax.Array, b: jax.Array, maxiter: int | None = None
         ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``min ‖Ax − b‖ s.t. x ≥ 0`` by the Lawson–Hanson active-set method (jittable).

    Returns ``(x, ‖Ax − b‖, status)`` with ``status = 0`` on convergence (KKT: ``w = Aᵀ(b − Ax)
    ≤ tol`` off the passive set, passive-set least squares with ``x > 0`` on it) and ``−1`` if
    ``maxiter`` (default ``3n``) inner (step-back) iterations, or ``maxiter + n`` outer ones,
    were exhausted. This is the algorithm of ``scipy.optimize.nnls`` (normal equations on the
    passive set, the same iteration count and tolerance ``10·max(m, n)·eps`` scaled by
    ``max(1, max|AᵀA|)``), with fixed-shape masks in place of index sets so that it runs under
    ``jax.jit``/``jax.vmap``.
    """
    A = jnp.asarray(A)
    b = jnp.asarray(b)
    m, n = A.shape
    maxiter = 3 * n if maxiter is None else int(maxiter)
    dtype = A.dtype
    AtA = A.T @ A
    Atb = A.T @ b
    tol = 10.0 * max(m, n) * jnp.finfo(dtype).eps * jnp.maximum(jnp.max(jnp.abs(AtA)), 1.0)
    eye = jnp.eye(n, dtype=dtype)

    def passive_solve(P):
        both = P[:, None] & P[None, :]
        K = jnp.where(both, AtA, 0.0) + jnp.where(P, 0.0, 1.0)[:, None] * eye
        s = jnp.linalg.solve(K, jnp.where(P, Atb, 0.0))
        return jnp.where(P, s, 0.0)

    def inner_cond(state):
        _, s, P, it = state
        return (it < maxiter) & jnp.any(P & (s < 0))

    def inner_body(state):
        x, s, P, it = state
        bad = P & (s < 0)
        ratios = jnp.where(bad, x / jnp.where(bad, x - s, 1.0), jnp.inf)
        alpha = jnp.min(ratios)
        x = x + alpha * (s - x)
        P = P & (x > tol)
        return x, passive_solve(P), P, it + 1

    def outer_cond(state):
        _, w, P, it, outer = state
        return (it < maxiter) & (outer < maxiter + n) & jnp.any(~P & (w > tol))

    def outer_body(state):
        x, w, P, it, outer = state
        k = jnp.argmax(jnp.where(P, -jnp.inf, w))
        P = P.at[k].set(True)
        _, s, P, it = jax.lax.while_loop(inner_cond, inner_body, (x, passive_solve(P), P, it))
        return s, Atb - AtA @ s, P, it, outer + 1

    zero = jnp.asarray(0)
    state = (jnp.zeros(n, dtype), Atb, jnp.zeros(n, bool), zero, zero)
    x, _, _, it, outer = jax.lax.while_loop(outer_cond, outer_body, state)
    status = jnp.where((it >= maxiter) | (outer >= maxiter + n), -1, 0)
    return x, jnp.linalg.norm(A @ x - b), status


def lsi(C: jax.Array, d: jax.Array, G: jax.Array, h: jax.Array, maxiter: int | None = None
        ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``min ‖Cx − d‖ s.t. Gx ≥ h`` for ``C (r, n)`` of full column rank (jittable).

    Lawson & Hanson (1974) ch. 23: with ``C = QR``, ``z = Rx − Qᵀd`` turns the problem into the
    least-distance program ``min ‖z‖ s.t. (GR⁻¹) z ≥ h − GR⁻¹Qᵀd``; with ``E = [(GR⁻¹)ᵀ; ĥᵀ]``
    and ``f = e_{n+1}``, the NNLS solution ``u`` of ``min ‖Eu − f‖, u ≥ 0`` gives the residual
    ``ρ = Eu − f`` and ``z = −ρ_{1:n}/ρ_{n+1}``; ``ρ = 0`` means the constraints are
    inconsistent. Returns ``(x, feasible, nnls_status)``; equalities go through :func:`lsei`.
    """
    C = jnp.asarray(C)
    n = C.shape[1]
    Q, R = jnp.linalg.qr(C)                 # reduced: Q (r, n), R (n, n)
    qd = Q.T @ jnp.asarray(d)
    GRi = solve_triangular(R, jnp.asarray(G).T, trans="T", lower=False).T   # G R⁻¹ (p, n)
    h_hat = jnp.asarray(h) - GRi @ qd
    E = jnp.concatenate([GRi.T, h_hat[None, :]], axis=0)                    # (n+1, p)
    f = jnp.zeros(n + 1, C.dtype).at[n].set(1.0)
    # NNLS is invariant to positive column scaling; equilibrate the columns (helps the normal
    # equations NNLS solves on its passive set).
    norms = jnp.linalg.norm(E, axis=0)
    scale = jnp.where(norms > 0, 1.0 / jnp.where(norms > 0, norms, 1.0), 1.0)
    u, rnorm, status = nnls(E * scale, f, maxiter)
    u = u * scale
    rho = E @ u - f
    feasible = (rnorm > jnp.sqrt(jnp.finfo(C.dtype).eps) * 1e-3) & (rho[n] < 0)
    z = -rho[:n] / jnp.where(feasible, rho[n], -1.0)
    x = solve_triangular(R, z + qd, lower=False)
    return x, feasible, status


def lsei(C: jax.Array, d: jax.Array, E: jax.Array, e: jax.Array, G: jax.Array, h: jax.Array,
         maxiter: int | None = None) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``min ‖Cx − d‖ s.t. Ex = e, Gx ≥ h`` (``C`` of full column rank, ``Ex = e`` consistent).

    The equalities are eliminated exactly (Lawson & Hanson ch. 20): with the SVD
    ``E = U S Vᵀ``, the directions ``v_i`` of the numerically non-zero singular values
    (``s_i > max(m, n)·eps·s_1``) are fixed at ``x₀ = Σ_i v_i (u_iᵀe)/s_i`` and the rest are
    free, ``x = x₀ + N y``. A rank-deficient ``E`` (e.g. a straight-line trajectory, where both
    rows of the goal-stationarity constraint are parallel) is handled with fixed shapes: ``N``
    is ``V`` with the fixed columns zeroed and the matching ``y_i`` are pinned to 0 by unit rows
    added to the objective (they do not move ``x``). The remaining LSI goes to :func:`lsi`.
    Returns ``(x, feasible, nnls_status)``.
    """
    C = jnp.asarray(C)
    E = jnp.asarray(E)
    n = C.shape[1]
    U, sv, Vt = jnp.linalg.svd(E, full_matrices=True)       # U (k, k), sv (k,), Vt (n, n)
    k = sv.shape[0]
    fixed = sv > max(E.shape) * jnp.finfo(C.dtype).eps * jnp.max(sv)
    coef = jnp.where(fixed, (U.T @ jnp.asarray(e)) / jnp.where(fixed, sv, 1.0), 0.0)
    x0 = Vt[:k].T @ coef
    mask = jnp.concatenate([fixed, jnp.zeros(n - k, bool)])
    N = jnp.where(mask[None, :], 0.0, Vt.T)
    C_y = jnp.concatenate([C @ N, jnp.diag(mask.astype(C.dtype))], axis=0)
    d_y = jnp.concatenate([jnp.asarray(d) - C @ x0, jnp.zeros(n, C.dtype)])
    y, feasible, status = lsi(C_y, d_y, jnp.asarray(G) @ N, jnp.asarray(h) - jnp.asarray(G) @ x0,
                              maxiter)
    return x0 + N @ y, feasible, status
