"""Pieces of the reaching task shared by every environment (thesis §6.2, docs/design.md §2.2).

* :func:`check_action` — clear errors at trace time for an action of the wrong shape or dtype;
* :func:`clean_action` — NaNs replaced by 0 and clipped to ``±limit`` (no acceleration rather
  than a non-finite state);
* :func:`reach_reward` — ``exp(−½‖x−g‖²/σ²) − Σ_i max(0, 1 − d_i/δ) − λ‖u‖²`` clipped to
  ``[reward_min, reward_max]`` (σ 0.1, δ 0.05, λ 1e-5, ``[−5, 1]``: :class:`RewardParams`);
* :func:`episode_info` / :func:`accumulate_episode` — the per-episode accumulators in
  ``state.info`` (``episode_return``, ``episode_length``, ``episode_collided`` and, where
  tracked, ``episode_nonfinite``). They restart with every episode, also under brax's
  ``AutoResetWrapper``, which restores only the physics state and the observation and keeps
  ``state.info``: brax zeroes its ``EpisodeWrapper`` counter ``info["steps"]`` of a finished
  episode before the next step, so a step that sees ``steps == 0`` while its ``episode_length``
  has reached the finished episode's length as brax counted it
  (``info["episode_metrics"]["length"] > 0``, updated only after the step) zeroes the
  accumulators first. The comparison keeps the rule right with ``action_repeat > 1`` (brax's
  counters move once per repeated step). It never fires under
  :class:`envs.wrappers.AutoResetWrapper` (which replaces the accumulators by a reset's zeros)
  nor without brax's ``EpisodeWrapper``;
* :func:`layout` — named slices of an observation vector from ``(name, size)`` pairs;
* :func:`sample_first_valid` — bounded rejection sampling of a scene (:mod:`envs.samplers`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from envs.samplers import first_valid, take

__all__ = [
    "EPISODE_ACCUMULATORS",
    "RewardParams",
    "accumulate_episode",
    "check_action",
    "clean_action",
    "episode_info",
    "layout",
    "reach_reward",
    "sample_first_valid",
]


def check_action(action: Any, action_size: int) -> None:
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


def clean_action(action: jax.Array, limit: float) -> jax.Array:
    """``action`` with non-finite entries replaced by 0, clipped to ``±limit``."""
    return jnp.clip(jnp.where(jnp.isfinite(action), action, 0.0), -limit, limit)


class RewardParams(NamedTuple):
    """Constants of the reaching reward (thesis §6.2.2, docs/design.md §4.3)."""

    goal_sigma: float = 0.1
    obstacle_delta: float = 0.05
    effort_weight: float = 1e-5
    reward_min: float = -5.0
    reward_max: float = 1.0


def reach_reward(goal_distance: jax.Array, obstacle_distances: jax.Array, active: jax.Array,
                 effort: jax.Array, params: RewardParams) -> jax.Array:
    """``exp(−½‖x−g‖²/σ²) − Σ_i max(0, 1 − d_i/δ) − λ‖u‖²`` clipped to the reward range.

    ``obstacle_distances (O,)`` are the surface distances ``d_i`` of the obstacles (only the
    ``active`` ones count) and ``effort`` the vector ``u`` whose squared norm is penalised
    (actuator torques for MJX robots, the acceleration for the point robot).
    """
    obstacle_cost = jnp.sum(jnp.where(
        active, jnp.maximum(0.0, 1.0 - obstacle_distances / params.obstacle_delta), 0.0))
    r = (jnp.exp(-0.5 * goal_distance**2 / params.goal_sigma**2) - obstacle_cost
         - params.effort_weight * jnp.sum(effort * effort))
    return jnp.clip(r, params.reward_min, params.reward_max)


#: The per-episode accumulators :func:`episode_info` puts in ``state.info``.
EPISODE_ACCUMULATORS = ("episode_return", "episode_length", "episode_collided",
                        "episode_nonfinite")


def episode_info(track_nonfinite: bool = True) -> dict[str, jax.Array]:
    """Zeroed per-episode accumulators for ``state.info`` at reset."""
    keys = EPISODE_ACCUMULATORS if track_nonfinite else EPISODE_ACCUMULATORS[:3]
    return {k: jnp.zeros((), jnp.float32) for k in keys}


def _first_step_after_brax_reset(info: dict) -> jax.Array | None:
    """True at the first step of an episode that brax's ``AutoResetWrapper`` restarted (the
    accumulators still hold the finished episode: module docstring); None without brax's
    ``EpisodeWrapper`` counters."""
    if "steps" not in info or "length" not in info.get("episode_metrics", {}):
        return None
    counted = info["episode_metrics"]["length"]
    return (info["steps"] == 0) & (counted > 0) & (info["episode_length"] >= counted)


def accumulate_episode(info: dict, reward: jax.Array, collision: jax.Array,
                       nonfinite: jax.Array) -> dict:
    """``info`` with one control step added to the per-episode accumulators (a new dict); at
    the first step of an episode restarted by brax's auto-reset they restart from zero."""
    restart = _first_step_after_brax_reset(info)
    info = dict(info)
    if restart is not None:
        for k in EPISODE_ACCUMULATORS:
            if k in info:
                info[k] = jnp.where(restart, jnp.zeros_like(info[k]), info[k])
    info["episode_return"] = info["episode_return"] + reward
    info["episode_length"] = info["episode_length"] + 1.0
    info["episode_collided"] = jnp.maximum(info["episode_collided"], collision)
    if "episode_nonfinite" in info:
        info["episode_nonfinite"] = jnp.maximum(info["episode_nonfinite"], nonfinite)
    return info


def layout(sizes: Sequence[tuple[str, int]]) -> dict[str, slice]:
    """Consecutive named slices ``{name: slice}`` of a vector made of ``(name, size)`` parts."""
    out, start = {}, 0
    for name, n in sizes:
        out[name] = slice(start, start + n)
        start += n
    return out


def sample_first_valid(key: jax.Array, candidates: int,
                       candidate: Callable[[jax.Array], tuple[Any, jax.Array]]
                       ) -> tuple[Any, jax.Array]:
    """Draw ``candidates`` scenes with ``candidate(key) -> (scene, margin)`` (``vmap``) and keep
    the first whose ``margin >= 0`` (bounded rejection). Returns ``(scene, ok)``; ``ok`` is False
    (and the scene the one of largest margin) when none is valid."""
    keys = jax.random.split(key, candidates)
    scenes, margin = jax.vmap(candidate)(keys)
    idx, ok = first_valid(margin >= 0.0, margin)
    return take(scenes, idx), ok
