"""Swept error area between two 2-D trajectories (LASA benchmark metric, docs/design.md §4.6)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp.metrics.resampling import (
    as_float64,
    check_pair,
    common_length,
    resample,
    resample_jax,
)

__all__ = ["swept_error_area", "swept_error_area_jax"]


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
    check_pair(a, b, min_len=2, dim=2)
    a, b = common_length(as_float64(a), as_float64(b), resample)
    return float(np.sum(_quad_areas(a[:-1], a[1:], b[1:], b[:-1], np)))


def swept_error_area_jax(a: jax.Array, b: jax.Array) -> jax.Array:
    """JAX version of :func:`swept_error_area`."""
    check_pair(a, b, min_len=2, dim=2)
    a, b = common_length(jnp.asarray(a), jnp.asarray(b), resample_jax)
    return jnp.sum(_quad_areas(a[:-1], a[1:], b[1:], b[:-1], jnp))
