"""DTW and discrete Fréchet distances: the classic dynamic programs (thesis §5.2.1, §5.3).

Both families (NumPy in float64, and pure ``*_jax`` versions that are ``jax.jit``- and
``jax.vmap``-able) evaluate the ``T × S`` table in anti-diagonal (wavefront) order: every cell
is still filled exactly once from its three predecessors (the classic ``O(TS)`` recursion), but
the cells of one anti-diagonal are independent and computed together, so the sequential depth
is ``T + S − 1`` instead of ``T·S``. Neither resamples. All are symmetric in ``(a, b)`` (DTW's
*path length* only up to exact ties, see :func:`dtw_path`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp.metrics.resampling import as_float64, check_pair

__all__ = [
    "dtw",
    "dtw_jax",
    "dtw_normalized",
    "dtw_normalized_jax",
    "dtw_path",
    "frechet",
    "frechet_jax",
    "warping_table",
]


def _cost_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)


def warping_table(a: np.ndarray, b: np.ndarray, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """The DTW (``kind="dtw"``) or Fréchet (``"frechet"``) table of float64 trajectories and
    the optimal path length of every cell, both ``(T, S)`` (NumPy, wavefront order).

    Padded tables ``P (T+1, S+1)``: row/column 0 are +inf except ``P[0, 0] = 0``, so cell
    ``(i, j)`` of the result is ``P[i+1, j+1]`` and its predecessors are ``P[i, j]`` (diagonal),
    ``P[i, j+1]`` (from ``(i−1, j)``) and ``P[i+1, j]`` (from ``(i, j−1)``); the start cell then
    gets ``C[0, 0]``. Ties go to the first of (diagonal, (i−1, j), (i, j−1)).
    """
    c = _cost_matrix(a, b)
    n, m = c.shape
    p = np.full((n + 1, m + 1), np.inf)
    p[0, 0] = 0.0
    steps = np.zeros((n + 1, m + 1), dtype=np.int64)
    for k in range(n + m - 1):
        i = np.arange(max(0, k - m + 1), min(k, n - 1) + 1)
        j = k - i
        pred = np.stack([p[i, j], p[i, j + 1], p[i + 1, j]])  # diag, up, left
        choice = np.argmin(pred, axis=0)
        best = pred[choice, np.arange(i.size)]
        prev_steps = np.stack([steps[i, j], steps[i, j + 1], steps[i + 1, j]])
        steps[i + 1, j + 1] = prev_steps[choice, np.arange(i.size)] + 1
        p[i + 1, j + 1] = c[i, j] + best if kind == "dtw" else np.maximum(c[i, j], best)
    return p[1:, 1:], steps[1:, 1:]


def dtw(a, b) -> float:
    """True dynamic-time-warping distance with Euclidean point cost (docs/design.md §4.6).

    ``D(i, j) = ‖a_i − b_j‖ + min(D(i−1, j−1), D(i−1, j), D(i, j−1))``, ``D(0, 0) = ‖a_0 − b_0‖``,
    returns ``D(T−1, S−1)``: the minimum, over monotone warping paths from ``(0, 0)`` to
    ``(T−1, S−1)`` with unit steps, of the summed matched-pair distances. This is the
    dissimilarity the thesis uses to pick the nominal demonstration (§5.2.1: the demonstration
    with the least mean DTW distance to the others). It is the full ``O(TS)`` program without a
    window, not a closest-point average. See :func:`dtw_normalized` for the per-step version.
    """
    check_pair(a, b)
    table, _ = warping_table(as_float64(a), as_float64(b), "dtw")
    return float(table[-1, -1])


def dtw_path(a, b) -> tuple[float, np.ndarray]:
    """DTW distance and one optimal warping path, an int array ``(K, 2)`` of ``(i, j)`` pairs.

    ``max(T, S) ≤ K ≤ T + S − 1``. Where several paths are optimal, the backtrack from
    ``(T−1, S−1)`` prefers the diagonal predecessor, then ``(i−1, j)``, then ``(i, j−1)``; the
    same rule defines the path length used by :func:`dtw_normalized`.
    """
    check_pair(a, b)
    table, _ = warping_table(as_float64(a), as_float64(b), "dtw")
    pad = np.full((table.shape[0] + 1, table.shape[1] + 1), np.inf)
    pad[1:, 1:] = table
    pad[0, 0] = 0.0
    i, j = table.shape[0] - 1, table.shape[1] - 1
    path = [(i, j)]
    while (i, j) != (0, 0):
        moves = ((i - 1, j - 1), (i - 1, j), (i, j - 1))
        i, j = min(moves, key=lambda ij: pad[ij[0] + 1, ij[1] + 1])  # first minimum wins
        path.append((i, j))
    return float(table[-1, -1]), np.asarray(path[::-1], dtype=np.int64)


def dtw_normalized(a, b) -> float:
    """DTW distance divided by the length of its warping path, ``D(T−1, S−1) / K``.

    docs/design.md §4.6 lists "DTW distance divided by length" for LASA; the length taken here
    is the number ``K`` of matched pairs on the optimal warping path (ties broken as in
    :func:`dtw_path`), which makes the result the mean matched-pair distance, in the units of
    the trajectories and comparable with :func:`rmse` and :func:`mean_error`. For equal lengths
    it is at most :func:`mean_error` (the diagonal path is one candidate, though the optimal
    path may be longer); a time-shifted copy of a curve scores far lower than under RMSE.
    """
    check_pair(a, b)
    table, steps = warping_table(as_float64(a), as_float64(b), "dtw")
    return float(table[-1, -1] / steps[-1, -1])


def frechet(a, b) -> float:
    """Discrete Fréchet distance (Eiter & Mannila 1994) with Euclidean point distance.

    ``F(i, j) = max(‖a_i − b_j‖, min(F(i−1, j−1), F(i−1, j), F(i, j−1)))``, returns
    ``F(T−1, S−1)``: the smallest, over monotone couplings of the two sample sequences, of the
    largest matched-pair distance (docs/design.md §4.6 "Fréchet distance"). It is the discrete
    version on the samples, an upper bound on the continuous Fréchet distance of the polylines.
    """
    check_pair(a, b)
    table, _ = warping_table(as_float64(a), as_float64(b), "frechet")
    return float(table[-1, -1])


def _dp_jax(a: jax.Array, b: jax.Array, kind: str):
    """Wavefront DP in JAX: returns (value at (T−1, S−1), path length there).

    The carry holds anti-diagonals ``k−1`` and ``k−2`` indexed by row ``i`` (cell
    ``(i, k−i)``). For cell ``(i, j)`` on diagonal ``k``: ``(i−1, j)`` is row ``i−1`` of
    diagonal ``k−1``, ``(i, j−1)`` row ``i`` of ``k−1``, ``(i−1, j−1)`` row ``i−1`` of ``k−2``.
    The virtual cell ``(−1, −1)`` is 0 (so the start gets ``C[0, 0]``), every other outside
    cell +inf; ties go to the diagonal, then ``(i−1, j)``, then ``(i, j−1)`` as in NumPy.
    """
    a = jnp.asarray(a)
    b = jnp.asarray(b)
    dtype = jnp.result_type(a.dtype, b.dtype, jnp.float32)
    c = jnp.linalg.norm(a[:, None, :].astype(dtype) - b[None, :, :].astype(dtype), axis=-1)
    n, m = c.shape
    rows = jnp.arange(n)
    inf = jnp.asarray(jnp.inf, dtype)

    def shift(x, fill):  # x[i-1], with `fill` at row 0
        return jnp.concatenate([jnp.asarray(fill, x.dtype)[None], x[:-1]])

    def step(carry, k):
        d1, d2, l1, l2 = carry
        cols = k - rows
        valid = (cols >= 0) & (cols < m)
        cost = c[rows, jnp.clip(cols, 0, m - 1)]
        start = k == 0
        pred = jnp.stack([shift(d2, jnp.where(start, 0.0, inf)), shift(d1, inf), d1])
        prev_len = jnp.stack([shift(l2, 0), shift(l1, 0), l1])
        choice = jnp.argmin(pred, axis=0)
        best = jnp.take_along_axis(pred, choice[None], axis=0)[0]
        length = jnp.take_along_axis(prev_len, choice[None], axis=0)[0] + 1
        value = cost + best if kind == "dtw" else jnp.maximum(cost, best)
        value = jnp.where(valid, value, inf)
        length = jnp.where(valid, length, 0)
        return (value, d1, length, l1), None

    init_d = jnp.full((n,), jnp.inf, dtype)
    init_l = jnp.zeros((n,), jnp.int32)
    init = (init_d, init_d, init_l, init_l)
    (d, _, length, _), _ = jax.lax.scan(step, init, jnp.arange(n + m - 1))
    return d[n - 1], length[n - 1]


def dtw_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`dtw` (jit/vmap-able; ``T + S − 1`` sequential steps)."""
    check_pair(a, b)
    return _dp_jax(a, b, "dtw")[0]


def dtw_normalized_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`dtw_normalized`."""
    check_pair(a, b)
    value, length = _dp_jax(a, b, "dtw")
    return value / length


def frechet_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`frechet`."""
    check_pair(a, b)
    return _dp_jax(a, b, "frechet")[0]
