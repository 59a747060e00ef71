"""Trajectory-comparison metrics for learning from demonstrations (thesis chapters 4–5).

One shared implementation of the metrics docs/design.md §2.3 and docs/design.md §4.6 list for the LASA and
Franka experiments: RMSE, true dynamic-time-warping (DTW) distance and DTW per warping-path step,
discrete Fréchet distance, swept error area (2-D), final-point error, plus the thesis' own mean
position error (§5.3.2). The thesis gives no equations for these metrics; where a choice was
needed it is stated in the function's docstring.

Every metric takes two trajectories ``a (T, d)`` and ``b (S, d)`` (rows are samples in time
order, columns are coordinates) and returns a float. All of them are symmetric in ``(a, b)``
(DTW's *path length* only up to exact ties, see :func:`dtw_path`), so the argument order
(reproduction, demonstration) is a convention, not a requirement.

NumPy functions (``rmse``, ``dtw``, …) compute in float64 and return Python floats. The
``*_jax`` functions are pure, ``jax.jit``- and ``jax.vmap``-able versions of the same
computations (shapes are static; they compute in float32 unless x64 is enabled). Both families
evaluate the DTW and Fréchet dynamic programs in anti-diagonal (wavefront) order: every cell of
the ``T × S`` table is still filled exactly once from its three predecessors (the classic
``O(TS)`` recursion), but the cells of one anti-diagonal are independent and computed together,
so the sequential depth is ``T + S − 1`` instead of ``T·S``.

Resampling to a common length (used by :func:`rmse`, :func:`mean_error` and
:func:`swept_error_area` when ``T ≠ S``; DTW and Fréchet never resample): both trajectories are
linearly interpolated in *normalised time* ``u ∈ [0, 1]``, sample ``k`` of a length-``T``
trajectory sitting at ``u = k / (T − 1)``, onto ``n = max(T, S)`` equally spaced ``u``. The
longer trajectory is therefore returned unchanged and the shorter one is stretched, first point
to first point and last to last. This assumes both trajectories span the same motion (a
reproduction rolled out for a demonstration's duration); for trajectories sampled with the same
``dt`` but of different durations, pad or cut them yourself before calling. :func:`resample`
also offers arc-length resampling for purely geometric comparisons.

:func:`distance_to_paths` is the one per-sample measure: the distance of every sample of a
trajectory to the nearest point of a set of demonstrated paths (polylines), for corridor tests
such as the Franka "task success" of ``scripts/lfd_franka.py``.

Bad inputs raise ``ValueError`` naming the argument and the shape received: each trajectory must
be a 2-D array ``(T, d)`` with ``T ≥ 1`` (``T ≥ 2`` where resampling or areas need it), both
must have the same ``d``, and the swept error area needs ``d = 2``. Non-finite values are not
rejected (a diverged rollout gives ``nan``/``inf`` metrics rather than an exception).
"""

from __future__ import annotations

from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "all_metrics",
    "distance_to_paths",
    "dtw",
    "dtw_jax",
    "dtw_normalized",
    "dtw_normalized_jax",
    "dtw_path",
    "final_point_error",
    "final_point_error_jax",
    "frechet",
    "frechet_jax",
    "mean_error",
    "mean_error_jax",
    "resample",
    "resample_jax",
    "rmse",
    "rmse_jax",
    "swept_error_area",
    "swept_error_area_jax",
]


# ---------------------------------------------------------------------------------------------
# Input checks (shared by the NumPy and JAX versions; JAX shapes are static, so these run at
# trace time)
# ---------------------------------------------------------------------------------------------


def _check_traj(x, name: str, *, min_len: int = 1, dim: int | None = None) -> None:
    shape = tuple(np.shape(x))
    if len(shape) != 2:
        raise ValueError(
            f"{name} must be a trajectory of shape (T, d) (one row per sample); got shape {shape}"
        )
    if shape[0] < min_len:
        raise ValueError(f"{name} needs at least {min_len} sample(s); got shape {shape}")
    if shape[1] < 1:
        raise ValueError(f"{name} needs at least one coordinate; got shape {shape}")
    if dim is not None and shape[1] != dim:
        raise ValueError(f"{name} must be {dim}-D, shape (T, {dim}); got shape {shape}")


def _check_pair(a, b, *, min_len: int = 1, dim: int | None = None) -> None:
    _check_traj(a, "a", min_len=min_len, dim=dim)
    _check_traj(b, "b", min_len=min_len, dim=dim)
    if np.shape(a)[1] != np.shape(b)[1]:
        raise ValueError(
            f"a and b must have the same dimension d; got shapes {np.shape(a)} and {np.shape(b)}"
        )


def _f64(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# Resampling
# ---------------------------------------------------------------------------------------------


def resample(x, num: int, *, by: Literal["time", "arclength"] = "time") -> np.ndarray:
    """Linearly resample a trajectory ``x (T, d)`` to ``num`` samples (float64).

    ``by="time"``: sample ``k`` of ``x`` sits at normalised time ``k / (T − 1)``; the output is
    ``x`` interpolated at ``num`` equally spaced normalised times in ``[0, 1]`` (first and last
    samples kept). ``by="arclength"``: the same with the normalised cumulative arc length as the
    parameter (zero-length steps are dropped first), i.e. equally spaced points along the
    curve. A single-sample ``x``, or one of zero length with ``by="arclength"``, is repeated.
    """
    _check_traj(x, "x")
    if int(num) < 1:
        raise ValueError(f"num must be at least 1; got {num}")
    x = _f64(x)
    num = int(num)
    if x.shape[0] == 1:
        return np.repeat(x, num, axis=0)
    if by == "time":
        u = np.linspace(0.0, 1.0, x.shape[0])
    elif by == "arclength":
        step = np.linalg.norm(np.diff(x, axis=0), axis=1)
        keep = np.concatenate([[True], step > 0.0])
        x = x[keep]
        if x.shape[0] == 1:
            return np.repeat(x, num, axis=0)
        s = np.concatenate([[0.0], np.cumsum(step[step > 0.0])])
        u = s / s[-1]
    else:
        raise ValueError(f"by must be 'time' or 'arclength'; got {by!r}")
    u_new = np.linspace(0.0, 1.0, num)
    return np.stack([np.interp(u_new, u, x[:, j]) for j in range(x.shape[1])], axis=1)


def resample_jax(x: jax.Array, num: int) -> jax.Array:
    """JAX version of :func:`resample` with ``by="time"`` (``num`` static)."""
    _check_traj(x, "x")
    x = jnp.asarray(x)
    if x.shape[0] == 1:
        return jnp.repeat(x, num, axis=0)
    u = jnp.linspace(0.0, 1.0, x.shape[0], dtype=x.dtype)
    u_new = jnp.linspace(0.0, 1.0, num, dtype=x.dtype)
    return jax.vmap(lambda col: jnp.interp(u_new, u, col), in_axes=1, out_axes=1)(x)


def _common_length(a, b, resample_fn):
    n = max(a.shape[0], b.shape[0])
    if a.shape[0] != n:
        a = resample_fn(a, n)
    if b.shape[0] != n:
        b = resample_fn(b, n)
    return a, b


# ---------------------------------------------------------------------------------------------
# Pointwise metrics
# ---------------------------------------------------------------------------------------------


def rmse(a, b) -> float:
    """Root-mean-square Euclidean error ``sqrt(mean_t ‖a_t − b_t‖²)`` between time-aligned
    trajectories (docs/design.md §4.6 / docs/design.md §2.3 "RMSE").

    The error at each time is the Euclidean norm over the ``d`` coordinates (a parallel shift by
    ``δ`` gives exactly ``δ``), averaged over samples, not over samples × coordinates. If
    ``T ≠ S`` both are first resampled in normalised time to ``max(T, S)`` samples (module
    docstring).
    """
    _check_pair(a, b)
    a, b = _common_length(_f64(a), _f64(b), resample)
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def mean_error(a, b) -> float:
    """Mean Euclidean error ``mean_t ‖a_t − b_t‖`` between time-aligned trajectories.

    The thesis' "mean position error" of §5.3.2 (``error(p₁(t), p₂(t)) = ‖p₁(t) − p₂(t)‖₂``
    averaged over the duration of a trajectory). Resamples like :func:`rmse` when ``T ≠ S``.
    """
    _check_pair(a, b)
    a, b = _common_length(_f64(a), _f64(b), resample)
    return float(np.mean(np.linalg.norm(a - b, axis=1)))


def final_point_error(a, b) -> float:
    """Euclidean distance between the last samples, ``‖a_T − b_S‖`` (docs/design.md §2.3).

    With ``b`` a demonstration (LASA demonstrations end at the goal) this is the reproduction's
    distance to the goal when it stops.
    """
    _check_pair(a, b)
    return float(np.linalg.norm(_f64(a)[-1] - _f64(b)[-1]))


def rmse_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`rmse` (resampling included; shapes static)."""
    _check_pair(a, b)
    a, b = _common_length(jnp.asarray(a), jnp.asarray(b), resample_jax)
    return jnp.sqrt(jnp.mean(jnp.sum((a - b) ** 2, axis=1)))


def mean_error_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`mean_error`."""
    _check_pair(a, b)
    a, b = _common_length(jnp.asarray(a), jnp.asarray(b), resample_jax)
    return jnp.mean(jnp.linalg.norm(a - b, axis=1))


def final_point_error_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`final_point_error`."""
    _check_pair(a, b)
    return jnp.linalg.norm(jnp.asarray(a)[-1] - jnp.asarray(b)[-1])


# ---------------------------------------------------------------------------------------------
# DTW and discrete Fréchet: the classic dynamic programs, filled anti-diagonal by anti-diagonal
# ---------------------------------------------------------------------------------------------


def _cost_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)


def _dp_numpy(a, b, kind: str):
    """Fill the DTW (``kind="dtw"``) or Fréchet table; returns (table, path lengths) (T, S).

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
    _check_pair(a, b)
    table, _ = _dp_numpy(_f64(a), _f64(b), "dtw")
    return float(table[-1, -1])


def dtw_path(a, b) -> tuple[float, np.ndarray]:
    """DTW distance and one optimal warping path, an int array ``(K, 2)`` of ``(i, j)`` pairs.

    ``max(T, S) ≤ K ≤ T + S − 1``. Where several paths are optimal, the backtrack from
    ``(T−1, S−1)`` prefers the diagonal predecessor, then ``(i−1, j)``, then ``(i, j−1)``; the
    same rule defines the path length used by :func:`dtw_normalized`.
    """
    _check_pair(a, b)
    table, _ = _dp_numpy(_f64(a), _f64(b), "dtw")
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

    docs/design.md §4.6 lists "DTW distance divided by length" for LASA; the length taken here is the
    number ``K`` of matched pairs on the optimal warping path (ties broken as in
    :func:`dtw_path`), which makes the result the mean matched-pair distance, in the units of
    the trajectories and comparable with :func:`rmse` and :func:`mean_error`. For equal lengths
    it is at most :func:`mean_error` (the diagonal path is one candidate, though the optimal
    path may be longer); a time-shifted copy of a curve scores far lower than under RMSE.
    """
    _check_pair(a, b)
    table, steps = _dp_numpy(_f64(a), _f64(b), "dtw")
    return float(table[-1, -1] / steps[-1, -1])


def frechet(a, b) -> float:
    """Discrete Fréchet distance (Eiter & Mannila 1994) with Euclidean point distance.

    ``F(i, j) = max(‖a_i − b_j‖, min(F(i−1, j−1), F(i−1, j), F(i, j−1)))``, returns
    ``F(T−1, S−1)``: the smallest, over monotone couplings of the two sample sequences, of the
    largest matched-pair distance (docs/design.md §4.6 "Fréchet distance"). It is the discrete
    version on the samples, an upper bound on the continuous Fréchet distance of the polylines.
    """
    _check_pair(a, b)
    table, _ = _dp_numpy(_f64(a), _f64(b), "frechet")
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
    _check_pair(a, b)
    return _dp_jax(a, b, "dtw")[0]


def dtw_normalized_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`dtw_normalized`."""
    _check_pair(a, b)
    value, length = _dp_jax(a, b, "dtw")
    return value / length


def frechet_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`frechet`."""
    _check_pair(a, b)
    return _dp_jax(a, b, "frechet")[0]


# ---------------------------------------------------------------------------------------------
# Swept error area (2-D)
# ---------------------------------------------------------------------------------------------


def _cross(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _tri_area(p, q, r, xp):
    return 0.5 * xp.abs(_cross(q - p, r - p))


def _quad_areas(p0, p1, p2, p3, xp):
    """Unsigned area ``∫ |winding number|`` of the closed quadrilaterals ``p0 p1 p2 p3`` (batched).

    A simple quadrilateral (convex or not) gets its area ``|shoelace|``. A self-intersecting
    one ("bow tie") gets the sum of its two triangular lobes rather than their signed
    difference: if edge ``p0p1`` properly crosses edge ``p2p3`` at ``X`` the lobes are
    ``(p0, X, p3)`` and ``(X, p1, p2)``; if ``p1p2`` crosses ``p3p0`` they are ``(p0, p1, X)``
    and ``(X, p2, p3)``. (A closed 4-gon has at most one such crossing.) Touching or collinear
    configurations differ from these cases only by zero-area pieces and use the shoelace value.
    """
    shoelace = 0.5 * (_cross(p0, p1) + _cross(p1, p2) + _cross(p2, p3) + _cross(p3, p0))

    def crossing(p, q, r, s):
        o1 = _cross(q - p, r - p)
        o2 = _cross(q - p, s - p)
        o3 = _cross(s - r, p - r)
        o4 = _cross(s - r, q - r)
        proper = (o1 * o2 < 0) & (o3 * o4 < 0)
        # r + t (s − r) with t = o1 / (o1 − o2) lies on pq; safe denominator where not proper.
        denom = xp.where(proper, o1 - o2, 1.0)
        t = xp.where(proper, o1 / denom, 0.0)
        return proper, r + t[..., None] * (s - r)

    cross02, x02 = crossing(p0, p1, p2, p3)
    cross13, x13 = crossing(p1, p2, p3, p0)
    lobes02 = _tri_area(p0, x02, p3, xp) + _tri_area(x02, p1, p2, xp)
    lobes13 = _tri_area(p0, p1, x13, xp) + _tri_area(x13, p2, p3, xp)
    return xp.where(cross02, lobes02, xp.where(cross13, lobes13, xp.abs(shoelace)))


def swept_error_area(a, b) -> float:
    """Swept error area between two 2-D trajectories (docs/design.md §4.6; LASA benchmark metric).

    Computes ``Σ_{t=0}^{n−2} area(Q_t)`` with ``Q_t`` the quadrilateral
    ``a_t → a_{t+1} → b_{t+1} → b_t`` joining corresponding samples of the two curves at
    consecutive times, i.e. the polygon area swept between reproduction and demonstration over
    time. ``area`` is the unsigned area ``∫ |winding number|``: ``|shoelace|`` for a simple
    quadrilateral, the sum of both lobes where the two curves cross between ``t`` and ``t+1``
    (plain shoelace would subtract them; a convex hull would add area that is not between the
    curves). Correspondence is by time index; if ``T ≠ S`` both are first resampled in
    normalised time to ``n = max(T, S)`` samples (module docstring). For two parallel straight
    segments of length ``L`` a distance ``δ`` apart, sampled alike, it is exactly ``δ·L``.
    Units: squared trajectory units. Needs ``d = 2`` and at least 2 samples each.
    """
    _check_pair(a, b, min_len=2, dim=2)
    a, b = _common_length(_f64(a), _f64(b), resample)
    return float(np.sum(_quad_areas(a[:-1], a[1:], b[1:], b[:-1], np)))


def swept_error_area_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`swept_error_area`."""
    _check_pair(a, b, min_len=2, dim=2)
    a, b = _common_length(jnp.asarray(a), jnp.asarray(b), resample_jax)
    return jnp.sum(_quad_areas(a[:-1], a[1:], b[1:], b[:-1], jnp))


# ---------------------------------------------------------------------------------------------
# Distance to a set of demonstrated paths
# ---------------------------------------------------------------------------------------------


def distance_to_paths(x, paths) -> np.ndarray:
    """Per-sample distance ``d_t = min_i min_{p ∈ P_i} ‖x_t − p‖`` from a trajectory ``x (T, d)``
    to the union of the polylines ``paths`` (a sequence of ``(S_i, d)`` arrays, consecutive
    samples joined by straight segments; a single-sample path is a point), float64, shape ``(T,)``.

    Exact: each sample is projected onto every segment, ``p = a + clip((x − a)·(b − a) /
    ‖b − a‖², 0, 1)(b − a)``; zero-length segments reduce to their end point. Used for corridor
    tests (how far a reproduction strays from where the demonstrations went).
    """
    _check_traj(x, "x")
    if isinstance(paths, np.ndarray) and paths.ndim == 2:
        raise ValueError("paths must be a sequence of (S, d) arrays (wrap a single path in a "
                         f"list); got one array of shape {paths.shape}")
    if len(paths) == 0:
        raise ValueError("paths must hold at least one path; got none")
    x = _f64(x)
    best = np.full(x.shape[0], np.inf)
    for i, path in enumerate(paths):
        _check_traj(path, f"paths[{i}]", dim=x.shape[1])
        p = _f64(path)
        if p.shape[0] == 1:
            best = np.minimum(best, np.linalg.norm(x - p[0], axis=1))
            continue
        a, ab = p[:-1], p[1:] - p[:-1]                                     # (S-1, d)
        len2 = np.sum(ab * ab, axis=1)
        t = np.einsum("tsd,sd->ts", x[:, None] - a[None], ab) / np.where(len2 > 0, len2, 1.0)
        t = np.clip(np.where(len2 > 0, t, 0.0), 0.0, 1.0)
        nearest = a[None] + t[..., None] * ab[None]                        # (T, S-1, d)
        best = np.minimum(best, np.min(np.linalg.norm(x[:, None] - nearest, axis=2), axis=1))
    return best


# ---------------------------------------------------------------------------------------------
# Everything at once
# ---------------------------------------------------------------------------------------------


def all_metrics(a, b) -> dict[str, float]:
    """Every metric of this module for one pair (NumPy): keys ``rmse``, ``mean_error``, ``dtw``,
    ``dtw_normalized``, ``frechet``, ``final_point_error`` and, for 2-D trajectories with at
    least two samples each, ``swept_error_area``."""
    _check_pair(a, b)
    a = _f64(a)
    b = _f64(b)
    table, steps = _dp_numpy(a, b, "dtw")
    out = {
        "rmse": rmse(a, b),
        "mean_error": mean_error(a, b),
        "dtw": float(table[-1, -1]),
        "dtw_normalized": float(table[-1, -1] / steps[-1, -1]),
        "frechet": frechet(a, b),
        "final_point_error": final_point_error(a, b),
    }
    if a.shape[1] == 2 and min(a.shape[0], b.shape[0]) >= 2:
        out["swept_error_area"] = swept_error_area(a, b)
    return out
