"""Per-sample trajectory errors: RMSE, mean and final-point error, distance to demonstrated paths.

Metrics of thesis chapters 4–5 and docs/design.md §4.6 that compare time-aligned samples (after
resampling to a common length, :mod:`mjxrmp.metrics.resampling`) or measure each sample's
distance to a set of polylines. NumPy functions compute in float64 and return Python floats;
the ``*_jax`` versions are pure and ``jax.jit``/``jax.vmap``-able.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp.metrics.resampling import (
    as_float64,
    check_pair,
    check_traj,
    common_length,
    resample,
    resample_jax,
)

__all__ = [
    "distance_to_paths",
    "final_point_error",
    "final_point_error_jax",
    "mean_error",
    "mean_error_jax",
    "rmse",
    "rmse_jax",
]


def rmse(a, b) -> float:
    """Root-mean-square Euclidean error ``sqrt(mean_t ‖a_t − b_t‖²)`` between time-aligned
    trajectories (docs/design.md §4.6 / docs/design.md §2.3 "RMSE").

    The error at each time is the Euclidean norm over the ``d`` coordinates (a parallel shift by
    ``δ`` gives exactly ``δ``), averaged over samples, not over samples × coordinates. If
    ``T ≠ S`` both are first resampled in normalised time to ``max(T, S)`` samples (module
    docstring).
    """
    check_pair(a, b)
    a, b = common_length(as_float64(a), as_float64(b), resample)
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def mean_error(a, b) -> float:
    """Mean Euclidean error ``mean_t ‖a_t − b_t‖`` between time-aligned trajectories.

    The thesis' "mean position error" of §5.3.2 (``error(p₁(t), p₂(t)) = ‖p₁(t) − p₂(t)‖₂``
    averaged over the duration of a trajectory). Resamples like :func:`rmse` when ``T ≠ S``.
    """
    check_pair(a, b)
    a, b = common_length(as_float64(a), as_float64(b), resample)
    return float(np.mean(np.linalg.norm(a - b, axis=1)))


def final_point_error(a, b) -> float:
    """Euclidean distance between the last samples, ``‖a_T − b_S‖`` (docs/design.md §2.3).

    With ``b`` a demonstration (LASA demonstrations end at the goal) this is the reproduction's
    distance to the goal when it stops.
    """
    check_pair(a, b)
    return float(np.linalg.norm(as_float64(a)[-1] - as_float64(b)[-1]))


def rmse_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`rmse` (resampling included; shapes static)."""
    check_pair(a, b)
    a, b = common_length(jnp.asarray(a), jnp.asarray(b), resample_jax)
    return jnp.sqrt(jnp.mean(jnp.sum((a - b) ** 2, axis=1)))


def mean_error_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`mean_error`."""
    check_pair(a, b)
    a, b = common_length(jnp.asarray(a), jnp.asarray(b), resample_jax)
    return jnp.mean(jnp.linalg.norm(a - b, axis=1))


def final_point_error_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`final_point_error`."""
    check_pair(a, b)
    return jnp.linalg.norm(jnp.asarray(a)[-1] - jnp.asarray(b)[-1])


def distance_to_paths(x, paths) -> np.ndarray:
    """Per-sample distance ``d_t = min_i min_{p ∈ P_i} ‖x_t − p‖`` from a trajectory ``x (T, d)``
    to the union of the polylines ``paths`` (a sequence of ``(S_i, d)`` arrays, consecutive
    samples joined by straight segments; a single-sample path is a point), float64, shape ``(T,)``.

    Exact: each sample is projected onto every segment, ``p = a + clip((x − a)·(b − a) /
    ‖b − a‖², 0, 1)(b − a)``; zero-length segments reduce to their end point. Used for corridor
    tests (how far a reproduction strays from where the demonstrations went).
    """
    check_traj(x, "x")
    if isinstance(paths, np.ndarray) and paths.ndim == 2:
        raise ValueError("paths must be a sequence of (S, d) arrays (wrap a single path in a "
                         f"list); got one array of shape {paths.shape}")
    if len(paths) == 0:
        raise ValueError("paths must hold at least one path; got none")
    x = as_float64(x)
    best = np.full(x.shape[0], np.inf)
    for i, path in enumerate(paths):
        check_traj(path, f"paths[{i}]", dim=x.shape[1])
        p = as_float64(path)
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
