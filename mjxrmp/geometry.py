"""Point–obstacle distances used by the collision RMPs (and by the environments' detectors)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp.leaves.hand_designed import safe_norm, smooth_norm

#: Obstacle shapes understood by :func:`point_obstacle_distances`.
OBSTACLE_SHAPES = ("sphere", "cylinder")


class Obstacles(NamedTuple):
    """A fixed-size (padded) set of obstacles.

    ``center (O, dim)``, ``radius (O,)`` and ``active (O,)`` (1 for a real obstacle, 0 for
    padding). Spheres use all coordinates of ``center``; vertical cylinders (infinite height)
    use only x and y. For the planar 3-link, ``dim = 2`` and both shapes are circles.
    """

    center: jax.Array
    radius: jax.Array
    active: jax.Array


def make_obstacles(center, radius, active=None) -> Obstacles:
    """Build :class:`Obstacles`, checking shapes and (when concrete, not traced) that every radius
    is finite and ``>= 0``; ``active`` defaults to all ones."""
    center = jnp.asarray(center)
    radius = jnp.asarray(radius, dtype=center.dtype)
    if center.ndim != 2:
        raise ValueError(f"center must have shape (O, dim), got {center.shape}")
    if radius.shape != center.shape[:1]:
        raise ValueError(f"radius must have shape ({center.shape[0]},), got {radius.shape}")
    if not isinstance(radius, jax.core.Tracer):
        r = np.asarray(radius)
        bad = ~(np.isfinite(r) & (r >= 0))
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"radius must be finite and >= 0, got radius[{i}] = "
                             f"{float(r[i])!r}")
    if active is None:
        active = jnp.ones_like(radius)
    active = jnp.asarray(active, dtype=center.dtype)
    if active.shape != radius.shape:
        raise ValueError(f"active must have shape {radius.shape}, got {active.shape}")
    return Obstacles(center, radius, active)


def point_obstacle_distances(
    points: jax.Array,
    point_radii: jax.Array,
    obstacles: Obstacles,
    shape: str = "sphere",
    smooth: bool = True,
) -> jax.Array:
    """Surface distances ``‖c − o‖ − (r_c + r_o)`` for every (point, obstacle) pair, ``(P, O)``.

    ``smooth=True`` uses the smoothed norm of the collision RMP (docs/design.md §4.1); ``False``
    the exact Euclidean norm (collision detection). ``shape="cylinder"`` measures in the
    xy-plane only (vertical cylinders).
    """
    if shape not in OBSTACLE_SHAPES:
        raise ValueError(f"shape must be one of {OBSTACLE_SHAPES}, got {shape!r}")
    diff = points[:, None, :] - obstacles.center[None, :, :]
    if shape == "cylinder":
        diff = diff[..., :2]
    norm = smooth_norm(diff) if smooth else safe_norm(diff)
    return norm - (point_radii[:, None] + obstacles.radius[None, :])
