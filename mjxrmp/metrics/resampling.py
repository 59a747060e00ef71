"""Input checks and resampling shared by the trajectory metrics (thesis chapters 4–5).

Every metric takes trajectories ``(T, d)`` (rows are samples in time order, columns are
coordinates). Bad inputs raise ``ValueError`` naming the argument and the shape received: each
trajectory must be a 2-D array with ``T ≥ 1`` (``T ≥ 2`` where resampling or areas need it),
both must have the same ``d``. The checks only read static shapes, so they also run at trace
time inside the ``*_jax`` metrics.

Resampling to a common length (used by the time-aligned metrics when ``T ≠ S``): both
trajectories are linearly interpolated in *normalised time* ``u ∈ [0, 1]``, sample ``k`` of a
length-``T`` trajectory sitting at ``u = k / (T − 1)``, onto ``n = max(T, S)`` equally spaced
``u``. The longer trajectory is therefore returned unchanged and the shorter one is stretched,
first point to first point and last to last. This assumes both trajectories span the same
motion (a reproduction rolled out for a demonstration's duration); for trajectories sampled
with the same ``dt`` but of different durations, pad or cut them yourself before calling.
:func:`resample` also offers arc-length resampling for purely geometric comparisons.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["as_float64", "check_pair", "check_traj", "common_length", "resample", "resample_jax"]


def check_traj(x, name: str, *, min_len: int = 1, dim: int | None = None) -> None:
    """Raise ``ValueError`` unless ``x`` is a trajectory ``(T, d)`` with ``T ≥ min_len`` (and
    ``d = dim`` when given); ``name`` is the argument named in the message."""
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


def check_pair(a, b, *, min_len: int = 1, dim: int | None = None) -> None:
    """:func:`check_traj` for ``a`` and ``b``, which must also have the same dimension ``d``."""
    check_traj(a, "a", min_len=min_len, dim=dim)
    check_traj(b, "b", min_len=min_len, dim=dim)
    if np.shape(a)[1] != np.shape(b)[1]:
        raise ValueError(
            f"a and b must have the same dimension d; got shapes {np.shape(a)} and {np.shape(b)}"
        )


def as_float64(x) -> np.ndarray:
    """``x`` as a float64 NumPy array."""
    return np.asarray(x, dtype=np.float64)


def resample(x, num: int, *, by: Literal["time", "arclength"] = "time") -> np.ndarray:
    """Linearly resample a trajectory ``x (T, d)`` to ``num`` samples (float64).

    ``by="time"``: sample ``k`` of ``x`` sits at normalised time ``k / (T − 1)``; the output is
    ``x`` interpolated at ``num`` equally spaced normalised times in ``[0, 1]`` (first and last
    samples kept). ``by="arclength"``: the same with the normalised cumulative arc length as the
    parameter (zero-length steps are dropped first), i.e. equally spaced points along the
    curve. A single-sample ``x``, or one of zero length with ``by="arclength"``, is repeated.
    """
    check_traj(x, "x")
    if int(num) < 1:
        raise ValueError(f"num must be at least 1; got {num}")
    x = as_float64(x)
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
    check_traj(x, "x")
    x = jnp.asarray(x)
    if x.shape[0] == 1:
        return jnp.repeat(x, num, axis=0)
    u = jnp.linspace(0.0, 1.0, x.shape[0], dtype=x.dtype)
    u_new = jnp.linspace(0.0, 1.0, num, dtype=x.dtype)
    return jax.vmap(lambda col: jnp.interp(u_new, u, col), in_axes=1, out_axes=1)(x)


def common_length(a, b, resample_fn: Callable) -> tuple:
    """``(a, b)`` resampled in normalised time to ``max(T, S)`` samples by ``resample_fn``
    (:func:`resample` or :func:`resample_jax`; the longer one is returned unchanged)."""
    n = max(a.shape[0], b.shape[0])
    if a.shape[0] != n:
        a = resample_fn(a, n)
    if b.shape[0] != n:
        b = resample_fn(b, n)
    return a, b
