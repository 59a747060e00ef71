"""Training data of the chapter-5 strategies: one row per demonstration sample (thesis §5.2.3).

Every sample of the stacked Franka demonstrations (:func:`mjxrmp.data.franka_demos.stack`) becomes
one row of :class:`Samples`: the strategy's task coordinates relative to the goal, their
Jacobians (forward-mode autodiff through the kinematics), the demonstrated task and joint
velocities, and a weight. Leave-one-out folds share the rows and differ only in the weights
(:func:`fold_weights`), so every fold trains in one ``vmap``-ped program.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from agents.lfd.config import StrategyConfig
from mjxrmp.data.franka_demos import StackedDemos, hand_points

__all__ = ["Samples", "fold_weights", "make_samples", "task_coordinates"]


class Samples(NamedTuple):
    """Training pairs, one row per demonstration sample (a pytree; ``S`` samples):
    ``x (S, K, m)`` task coordinates relative to the goal, ``J (S, K, m, 7)`` their Jacobians
    ``∂x/∂q``, ``xd (S, K, m)`` demonstrated task velocities, ``qd (S, 7)`` demonstrated joint
    velocities, ``w (S,)`` sample weights (0: not used)."""

    x: jax.Array
    J: jax.Array
    xd: jax.Array
    qd: jax.Array
    w: jax.Array


def task_coordinates(strategy: str, point: int, q: jax.Array, goals: jax.Array,
                     q_goal: jax.Array) -> jax.Array:
    """``x(q) (K, m)``: control points minus their goals (§5.2.3, ``FK_k − g_k``) for
    ``"joint"``/``"independent"``, the ``point``-th one for ``"single_link"``, ``q − q_g``
    for ``"cspace"``. ``goals (3, 3)``, ``q_goal (7,)``, one configuration ``q (7,)``."""
    if strategy == "cspace":
        return (q - q_goal)[None]
    x = hand_points(q) - goals
    return x[point:point + 1] if strategy == "single_link" else x


def make_samples(config: StrategyConfig, demos: StackedDemos) -> Samples:
    """:class:`Samples` of every (padded) sample of ``demos`` with ``w = mask`` (fold weights
    come from :func:`fold_weights`). Jacobians by forward-mode autodiff of the kinematics."""
    s, k = config.strategy, config.point
    N, T = demos.mask.shape

    def one(q, qd, pv, g, qg):
        fn = lambda q_: task_coordinates(s, k, q_, g, qg)  # noqa: E731
        x = fn(q)
        J = jax.jacfwd(fn)(q)
        xd = qd[None] if s == "cspace" else pv[k:k + 1] if s == "single_link" else pv
        return x, J, xd

    rep = lambda a: jnp.repeat(a[:, None], T, axis=1).reshape((N * T, *a.shape[1:]))  # noqa: E731
    flat = lambda a: a.reshape((N * T, *a.shape[2:]))  # noqa: E731
    x, J, xd = jax.jit(jax.vmap(one))(flat(demos.q), flat(demos.qd),
                                      flat(demos.point_velocities), rep(demos.goals),
                                      rep(demos.q_goal))
    return Samples(x=x, J=J, xd=xd, qd=flat(demos.qd), w=flat(demos.mask))


def fold_weights(mask: jax.Array, train: jax.Array) -> jax.Array:
    """Sample weights ``(N·T,)`` using the demonstrations with ``train (N,)`` true:
    ``mask (N, T) · train[:, None]``, flattened like :func:`make_samples`."""
    mask = jnp.asarray(mask)
    train = jnp.asarray(train, mask.dtype)
    if train.shape != mask.shape[:1]:
        raise ValueError(f"train must have shape ({mask.shape[0]},), got {train.shape}")
    return (mask * train[:, None]).reshape(-1)
