"""Small symmetric positive-definite systems written out entry by entry (docs/design.md §5.10).

RMP² resolves the root ``q̈ = M⁻¹ f`` (thesis eq 3.10) with ``M`` of the robot's size (2, 3 or
7 joints), and the residual RMP policy factors the hand-designed target metric of the
end-effector (2 or 3 dimensions). Batched over a few hundred environments on a GPU, a library
solve of such a matrix costs a dozen kernels (cuSOLVER's LU or Cholesky, cuBLAS's triangular
solves and the pointer arrays they need), each moving a few kilobytes. Written out as the
Cholesky recurrences on individual entries, the same arithmetic is elementwise over the batch,
and XLA fuses it into one or two kernels, forward and backward.

Matrices larger than :data:`MAX_UNROLLED` go to ``jnp.linalg`` (the written-out program grows
as ``n³``). Only the lower triangle of ``M``'s symmetric part ``(M + Mᵀ)/2`` is read.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jax.scipy.linalg

#: Largest size written out entry by entry; larger systems use ``jnp.linalg``.
MAX_UNROLLED = 12
#: The library's solve, kept for the sizes it handles even while :mod:`envs.physics` lets
#: MuJoCo-MJX call :func:`cho_solve` in its place.
_LIBRARY_CHO_SOLVE = jax.scipy.linalg.cho_solve

__all__ = ["MAX_UNROLLED", "cho_factor", "cho_solve", "cholesky", "spd_solve"]


def _check_square(name: str, M: jax.Array) -> int:
    if M.ndim < 2 or M.shape[-1] != M.shape[-2]:
        raise ValueError(f"{name} must be square matrices (..., n, n), got shape {M.shape}")
    return M.shape[-1]


def _entries(M: jax.Array) -> list[list[jax.Array]]:
    """The lower-triangle entries ``S[i][j]`` (j ≤ i) of the symmetric part of ``M``."""
    n = M.shape[-1]
    return [[M[..., i, i] if i == j else 0.5 * (M[..., i, j] + M[..., j, i])
             for j in range(i + 1)] for i in range(n)]


def _factor(S: list[list[jax.Array]]) -> list[list[jax.Array]]:
    """Cholesky recurrences ``L_jj = √(S_jj − Σ_k L_jk²)``, ``L_ij = (S_ij − Σ_k L_ik L_jk) /
    L_jj`` on lists of batched entries."""
    n = len(S)
    L: list[list[jax.Array]] = [[] for _ in range(n)]
    for j in range(n):
        s = S[j][j]
        for k in range(j):
            s = s - L[j][k] * L[j][k]
        L[j].append(jnp.sqrt(s))
        for i in range(j + 1, n):
            s = S[i][j]
            for k in range(j):
                s = s - L[i][k] * L[j][k]
            L[i].append(s / L[j][j])
    return L


def cholesky(M: jax.Array) -> jax.Array:
    """Lower Cholesky factor ``L`` with ``L Lᵀ = (M + Mᵀ)/2`` for ``M (..., n, n)`` symmetric
    positive definite (NaN where it is not, as ``jnp.linalg.cholesky``)."""
    n = _check_square("cholesky: M", M)
    if n > MAX_UNROLLED:
        return jnp.linalg.cholesky(0.5 * (M + jnp.swapaxes(M, -1, -2)))
    L = _factor(_entries(M))
    zero = jnp.zeros_like(L[0][0])
    return jnp.stack([jnp.stack(L[i] + [zero] * (n - 1 - i), axis=-1) for i in range(n)],
                     axis=-2)


def _substitute(L: list[list[jax.Array]], f: jax.Array) -> jax.Array:
    """``x`` with ``L Lᵀ x = f``: forward substitution ``L y = f``, then ``Lᵀ x = y``."""
    n = len(L)
    y: list[jax.Array] = []
    for i in range(n):
        s = f[..., i]
        for k in range(i):
            s = s - L[i][k] * y[k]
        y.append(s / L[i][i])
    x: list[jax.Array] = [y[0]] * n
    for i in reversed(range(n)):
        s = y[i]
        for k in range(i + 1, n):
            s = s - L[k][i] * x[k]
        x[i] = s / L[i][i]
    return jnp.stack(x, axis=-1)


@jax.custom_jvp
def _solve_unrolled(M: jax.Array, f: jax.Array) -> jax.Array:
    return _substitute(_factor(_entries(M)), f)


@_solve_unrolled.defjvp
def _solve_jvp(primals: tuple, tangents: tuple) -> tuple[jax.Array, jax.Array]:
    """``ẋ = S⁻¹ (ḟ − Ṡ x)`` with ``S`` the symmetric part of ``M``, solved with the same factor:
    derivatives (and, transposed, gradients) never pass through the factorisation."""
    (M, f), (dM, df) = primals, tangents
    L = _factor(_entries(M))
    x = _substitute(L, f)
    dS = 0.5 * (dM + jnp.swapaxes(dM, -1, -2))
    return x, _substitute(L, df - jnp.sum(dS * x[..., None, :], axis=-1))


def spd_solve(M: jax.Array, f: jax.Array) -> jax.Array:
    """``x = M⁻¹ f`` for ``M (..., n, n)`` symmetric positive definite and ``f (..., n)``, by
    Cholesky: ``L y = f``, then ``Lᵀ x = y`` (thesis eq 3.10's resolve). Its derivative
    ``ẋ = M⁻¹ (ḟ − Ṁ x)`` reuses the factor, so gradients cost two more triangular solves."""
    n = _check_square("spd_solve: M", M)
    if f.shape[-1:] != (n,):
        raise ValueError(f"spd_solve: f must have shape (..., {n}) to match M {M.shape}, got "
                         f"{f.shape}")
    if n > MAX_UNROLLED:
        sym = 0.5 * (M + jnp.swapaxes(M, -1, -2))
        return _LIBRARY_CHO_SOLVE((jnp.linalg.cholesky(sym), True), f[..., None])[..., 0]
    return _solve_unrolled(M, f)


def cho_factor(a: jax.Array, lower: bool = False) -> tuple[jax.Array, bool]:
    """``(c, lower)`` as :func:`jax.scipy.linalg.cho_factor` returns it: the Cholesky factor of
    the symmetric positive-definite ``a (..., n, n)``, ``L`` with ``L Lᵀ = a`` where ``lower``,
    else ``U = Lᵀ``, the other triangle zero. Written out up to :data:`MAX_UNROLLED`; reads the
    symmetric part of ``a`` (for a symmetric ``a`` exactly ``a``)."""
    L = cholesky(a)
    return (L if lower else jnp.swapaxes(L, -1, -2)), lower


def cho_solve(c_and_lower: tuple[jax.Array, bool], b: jax.Array) -> jax.Array:
    """``x`` with ``a x = b`` from :func:`cho_factor`'s ``(c, lower)``, as
    :func:`jax.scipy.linalg.cho_solve` computes it: forward then backward substitution, written
    out for one right-hand side ``b (..., n)`` up to :data:`MAX_UNROLLED`, else the library's."""
    c, lower = c_and_lower
    n = _check_square("cho_solve: c", c)
    if n > MAX_UNROLLED or b.shape != c.shape[:-1]:
        return _LIBRARY_CHO_SOLVE((c, lower), b)
    L = [[c[..., i, k] if lower else c[..., k, i] for k in range(i + 1)] for i in range(n)]
    return _substitute(L, b)
