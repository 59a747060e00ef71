"""Region samplers and bounded rejection sampling for the reaching environments.

Everything here is a pure JAX function of an explicit key and runs inside ``jit``/``vmap``.

Rejection sampling is *bounded*: a sampler draws ``K`` complete candidates at once (with
``vmap``), checks each, and keeps the first valid one (:func:`first_valid`). If none of the ``K``
is valid it falls back to the candidate with the largest validity score and reports
``ok = False``, so a caller can count (and a test can bound) how often that happens.

Region conventions (angles in radians, counter-clockwise from +x):

* :func:`annulus`: area-uniform in ``{r_min ≤ ‖p‖ ≤ r_max}`` ∩ the sector
  ``|angle − angle_center| ≤ angle_range/2`` (``r = √U(r_min², r_max²)``).
* :func:`annulus` with ``area_uniform=False``: the original implementation's 2-D "torus"
  sampler, uniform in the *radius* (not area-uniform) — used by ``obstacle_sampler="original"``.
* :func:`half_torus_volume_uniform`: volume-uniform in the solid torus around the z-axis
  (major radius ``R``, minor radius ``r``, centre height ``h``) restricted to azimuths
  ``|φ − angle_center| ≤ angle_range/2`` (the "front half" for ``angle_range = π``): uniform
  azimuth, and a cross-section point accepted with probability ∝ its distance from the axis.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp


def first_valid(valid: jax.Array, score: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Index of the first ``True`` in ``valid (K,)`` (else ``argmax(score)``) and ``any(valid)``."""
    ok = jnp.any(valid)
    idx = jnp.where(ok, jnp.argmax(valid), jnp.argmax(score))
    return idx, ok


def take(tree: Any, idx: jax.Array) -> Any:
    """Select candidate ``idx`` along the leading axis of every leaf of ``tree``."""
    return jax.tree.map(lambda x: x[idx], tree)


def annulus(
    key: jax.Array,
    shape: tuple[int, ...],
    r_min: float,
    r_max: float,
    angle_center: float = 0.0,
    angle_range: float = 2.0 * math.pi,
    area_uniform: bool = True,
) -> jax.Array:
    """Points ``shape + (2,)`` in an annular sector: area-uniform, or (``area_uniform=False``)
    with the radius uniform in ``[r_min, r_max]`` as the original implementation's sampler."""
    k_r, k_a = jax.random.split(key)
    if area_uniform:
        r = jnp.sqrt(jax.random.uniform(k_r, shape, minval=r_min**2, maxval=r_max**2))
    else:
        r = jax.random.uniform(k_r, shape, minval=r_min, maxval=r_max)
    a = angle_center + angle_range * (jax.random.uniform(k_a, shape) - 0.5)
    return jnp.stack([r * jnp.cos(a), r * jnp.sin(a)], axis=-1)


def in_half_torus(
    p: jax.Array,
    major: float,
    minor: float,
    height: float,
    angle_center: float = 0.0,
    angle_range: float = math.pi,
) -> jax.Array:
    """Whether points ``(..., 3)`` lie in the solid torus sector (see module docstring)."""
    rho = jnp.sqrt(p[..., 0] ** 2 + p[..., 1] ** 2)
    inside = (rho - major) ** 2 + (p[..., 2] - height) ** 2 <= minor**2
    phi = jnp.arctan2(p[..., 1], p[..., 0])
    dphi = jnp.abs(jnp.mod(phi - angle_center + math.pi, 2.0 * math.pi) - math.pi)
    return inside & (dphi <= angle_range / 2.0)


def half_torus_volume_uniform(
    key: jax.Array,
    shape: tuple[int, ...],
    major: float,
    minor: float,
    height: float,
    angle_center: float = 0.0,
    angle_range: float = math.pi,
    candidates: int = 16,
) -> tuple[jax.Array, jax.Array]:
    """Volume-uniform points ``shape + (3,)`` in a solid-torus sector, and per-point ``ok``.

    In cylindrical coordinates the volume element is ``ρ dρ dz dφ``, so the azimuth is uniform
    in the sector and independent of the cross-section point, whose density is proportional to
    ``ρ = R + s`` over the disk of radius ``r``. Each candidate draws the cross-section point
    uniformly in the disk and accepts it with probability ``(R + s)/(R + r)`` (acceptance
    ``R/(R + r)`` = 0.625 for R = 0.5, r = 0.3, so 16 candidates fail with probability ≈ 2e-7;
    a failed point keeps its last draw and ``ok = False``).
    """
    k_phi, k_r, k_a, k_u = jax.random.split(key, 4)
    size = (*shape, candidates)
    phi = angle_center + angle_range * (jax.random.uniform(k_phi, size) - 0.5)
    radius = minor * jnp.sqrt(jax.random.uniform(k_r, size))
    angle = 2.0 * math.pi * jax.random.uniform(k_a, size)
    s, t = radius * jnp.cos(angle), radius * jnp.sin(angle)
    accept = jax.random.uniform(k_u, size) * (major + minor) <= major + s
    rho = major + s
    pts = jnp.stack([rho * jnp.cos(phi), rho * jnp.sin(phi), height + t], axis=-1)
    ok = jnp.any(accept, axis=-1)
    idx = jnp.where(ok, jnp.argmax(accept, axis=-1), candidates - 1)
    chosen = jnp.take_along_axis(pts, idx[..., None, None], axis=-2)[..., 0, :]
    return chosen, ok


__all__ = [
    "annulus",
    "first_valid",
    "half_torus_volume_uniform",
    "in_half_torus",
    "take",
]
