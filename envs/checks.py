"""Input checks shared by the environments (clear errors at trace time, docs/design.md §2.2)."""

from __future__ import annotations

import jax.numpy as jnp


def check_action(action, action_size: int) -> None:
    """Refuse, at trace time, an action that is not a floating-point vector ``(action_size,)``
    (one un-batched environment; batch with ``jax.vmap`` or the training wrapper).

    Non-finite entries are allowed here: ``step`` replaces them by 0 (no
    acceleration), so NaN never reaches the physics state."""
    shape, dtype = getattr(action, "shape", None), getattr(action, "dtype", None)
    if shape is None or dtype is None:
        raise TypeError(f"action must be an array of shape ({action_size},), got "
                        f"{type(action).__name__}")
    if tuple(shape) != (action_size,):
        raise ValueError(f"action must have shape ({action_size},) for one environment, got "
                         f"{tuple(shape)} (batch environments with jax.vmap or "
                         "envs.wrappers.wrap)")
    if not jnp.issubdtype(dtype, jnp.floating):
        raise TypeError(f"action must have a floating-point dtype, got {dtype}")


__all__ = ["check_action"]
