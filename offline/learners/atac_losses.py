"""The loss terms of ATAC / PSPI (thesis §7.3.3, eqs 7.1, 7.2 and 7.11; docs/design.md §4.5):
pure functions, tested against float64 NumPy references; :mod:`offline.learners.atac` combines
them into the trainer."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def combine(loss: jax.Array, reg: jax.Array, w: jax.Array | float) -> jax.Array:
    """``loss/w + reg`` if ``w > 1`` else ``loss + w·reg`` (docs/design.md §4.5; eq 7.1's weighted
    sum ``loss + w·reg`` rescaled by ``1/w`` for large ``w``). ``w`` may be traced; the unused
    branch never divides by a ``w ≤ 1``, so gradients stay finite at ``w = 0``."""
    w = jnp.asarray(w)
    big = w > 1.0
    return jnp.where(big, loss / jnp.where(big, w, 1.0) + reg, loss + w * reg)


def value_bounds(reward_min: float, reward_max: float, discount: float) -> tuple[float, float]:
    """``(V_min, V_max) = (min(−1/(1−γ), 2 r_min/(1−γ)), max(1/(1−γ), 2 r_max/(1−γ)))``
    (docs/design.md §4.5, the ``clip_v`` option)."""
    h = 1.0 / (1.0 - discount)
    return min(-h, 2.0 * reward_min * h), max(h, 2.0 * reward_max * h)


def _clip_straight_through(x: jax.Array, bounds: tuple[float, float] | None) -> jax.Array:
    if bounds is None:
        return x
    return x + jax.lax.stop_gradient(jnp.clip(x, *bounds) - x)


def dqra_loss(q: jax.Array, q_next: jax.Array, q_next_target: jax.Array, rewards: jax.Array,
              terminals: jax.Array, discount: float, w: float,
              bounds: tuple[float, float] | None = None) -> jax.Array:
    """Per-critic DQRA Bellman loss of eq 7.11, shape ``(K,)``.

    ``q = f_i(s, a)`` and ``q_next = f_i(s', a')`` are ``(B, K)``, ``q_next_target =
    min_j f̄_j(s', a')`` is ``(B,)``; ``rewards`` / ``terminals`` ``(B,)``. Returns
    ``w·mean (q − sg(y̅))² + (1 − w)·mean (q − y)²`` with ``y̅ = r + γ(1−d) q_next_target``
    (stop-gradient) and ``y = r + γ(1−d) q_next`` (gradient flows into ``q_next``: the residual
    algorithm). ``bounds`` clips both backups (straight-through gradient).
    """
    cont = discount * (1.0 - terminals.astype(q.dtype))
    y_target = _clip_straight_through(rewards + cont * q_next_target, bounds)
    y_resid = _clip_straight_through(rewards[:, None] + cont[:, None] * q_next, bounds)
    target_term = jnp.mean(jnp.square(q - jax.lax.stop_gradient(y_target)[:, None]), axis=0)
    resid_term = jnp.mean(jnp.square(q - y_resid), axis=0)
    return w * target_term + (1.0 - w) * resid_term


def pessimism_loss(q_pi: jax.Array, q_data: jax.Array, relative: bool = True) -> jax.Array:
    """Per-critic pessimism term (eq 7.2 on a minibatch), shape ``(K,)``: relative (ATAC)
    ``mean f_i(s, a_π) − f_i(s, a)`` or absolute (PSPI) ``mean f_i(s, a_π)``; inputs
    ``(B, K)`` (``a_π`` already detached by the caller)."""
    diff = q_pi - q_data if relative else q_pi
    return jnp.mean(diff, axis=0)


__all__ = ["combine", "dqra_loss", "pessimism_loss", "value_bounds"]
