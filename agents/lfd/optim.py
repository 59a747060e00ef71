"""The optimisation rules shared by every LfD trainer (docs/design.md §4.6): the SmoothL1 loss,
Adam with L2 weight decay and gradient clipping, the LASA reference code's early stop, and a
``lax.scan`` of optimiser steps with optional weighted minibatches.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, TypeVar

import jax
import jax.numpy as jnp
import optax

__all__ = ["early_stop_update", "fit", "minibatch", "regularised_adam", "smooth_l1"]

WeightedT = TypeVar("WeightedT", bound=NamedTuple)


def smooth_l1(err: jax.Array, beta: float) -> jax.Array:
    """PyTorch's elementwise SmoothL1 loss: ``½e²/β`` where ``|e| < β``, else ``|e| − ½β``."""
    a = jnp.abs(err)
    return jnp.where(a < beta, 0.5 * err * err / beta, a - 0.5 * beta)


def regularised_adam(learning_rate: float, weight_decay: float,
                     max_grad_norm: float | None) -> optax.GradientTransformation:
    """The LfD trainers' optimiser: global-norm gradient clipping (when ``max_grad_norm`` is
    given), then weight decay added to the gradient (when ``weight_decay > 0``; PyTorch's
    ``Adam(weight_decay=…)``, not AdamW), then Adam."""
    chain = []
    if max_grad_norm is not None:
        chain.append(optax.clip_by_global_norm(max_grad_norm))
    if weight_decay > 0:
        chain.append(optax.add_decayed_weights(weight_decay))
    chain.append(optax.adam(learning_rate))
    return optax.chain(*chain)


def early_stop_update(loss: jax.Array, params: Any, best_params: Any, best_loss: jax.Array,
                      since_best: jax.Array, stopped: jax.Array, patience: int | None
                      ) -> tuple[jax.Array, Any, jax.Array, jax.Array, jax.Array, jax.Array]:
    """One step of the early-stop rule of the LASA reference code (docs/design.md §4.6):
    ``loss`` of ``params`` improves on ``best_loss`` (never when not finite) → new best;
    ``move`` says whether this step's update may be applied (finite loss, not yet stopped);
    after ``patience`` steps without improvement ``stopped`` turns True (never with
    ``patience=None``). Returns ``(improved, best_params, best_loss, since_best, move,
    stopped)``."""
    improved = loss < best_loss
    best_params = jax.tree.map(lambda a, b: jnp.where(improved, a, b), params, best_params)
    since = jnp.where(improved, 0, since_best + 1)
    move = jnp.logical_and(jnp.isfinite(loss), ~stopped)
    if patience is not None:
        stopped = jnp.logical_or(stopped, since >= patience)
    return improved, best_params, jnp.where(improved, loss, best_loss), since, move, stopped


def fit(loss: Callable[[Any, jax.Array], jax.Array], params: Any,
        tx: optax.GradientTransformation, iterations: int, key: jax.Array,
        patience: int | None = None) -> tuple[Any, jax.Array]:
    """``iterations`` steps of ``tx`` on ``loss(params, key)`` in one ``lax.scan`` (a fresh key
    per step for minibatches); a step whose loss is not finite leaves the parameters unchanged.
    With ``patience`` (:func:`early_stop_update`) the parameters freeze once the loss has not
    improved on its lowest value for ``patience`` steps, and the parameters of the lowest loss
    are returned. Returns the parameters and the loss before every step."""
    if iterations == 0:
        return params, jnp.zeros((0,), jnp.float32)

    def pick(flag, new, old):
        return jax.tree.map(lambda a, b: jnp.where(flag, a, b), new, old)

    def step(carry, k):
        p, opt, best = carry  # best: early-stop record (``()`` without patience)
        value, grads = jax.value_and_grad(loss)(p, k)
        updates, new_opt = tx.update(grads, opt, p)
        move = jnp.isfinite(value)
        if patience is not None:
            _, *best, move, stopped = early_stop_update(value, p, *best, patience)
            best = (*best, stopped)
        return (pick(move, optax.apply_updates(p, updates), p), pick(move, new_opt, opt),
                best), value

    best = () if patience is None else (params, jnp.asarray(jnp.inf, jnp.float32),
                                        jnp.zeros((), jnp.int32), jnp.zeros((), bool))
    (last, _, best), losses = jax.lax.scan(step, (params, tx.init(params), best),
                                           jax.random.split(key, iterations))
    return (last if patience is None else best[0]), losses


def minibatch(data: WeightedT, key: jax.Array, batch_size: int | None) -> WeightedT:
    """``batch_size`` rows of the weighted pytree ``data`` (a NamedTuple with per-row weights
    ``w``) drawn with probability ``∝ w`` (with replacement, then weighted equally), or all
    rows when ``batch_size`` is ``None``."""
    if batch_size is None:
        return data
    w = data.w
    idx = jax.random.choice(key, w.shape[0], (batch_size,), p=w / jnp.sum(w))
    picked = jax.tree.map(lambda a: a[idx], data)
    return picked._replace(w=jnp.ones((batch_size,), w.dtype))
