"""Training the flow field of :mod:`agents.lfd.flow_field` on demonstrations (thesis §4.2).

Settings are :class:`agents.lfd.config.LfdConfig` (docs/design.md §4.6 defaults): regress the
demonstrated velocities with the SmoothL1 loss (PyTorch's, ``β = 1``, mean over all coordinates),
Adam with learning rate ``1e-4`` and L2 weight decay ``1e-10`` added to the gradient (PyTorch
``Adam(weight_decay=…)``, not AdamW), gradient-norm clip ``0.1`` applied first, full batch, up to
5000 iterations (full-batch epochs), early stop after 250 iterations without improvement of the
training loss; the parameters with the lowest loss are returned (:mod:`agents.lfd.optim`). Only
``variables["params"]`` is trained; the random Fourier features in ``variables["constants"]``
stay fixed.

**Arrival-time loss** (``LfdConfig.time_weight > 0``, applied when the demonstrations' time step
``dt`` is passed; :func:`agents.lfd.lasa_eval.train_shapes` passes each shape's): the velocity
loss fits the demonstrations' speeds sample by sample, but the 7 demonstrations of a shape all
last ``(T − 1)·dt`` from starts at latent distances ``‖ψ(x₀)‖`` that differ by up to 35 %,
and where they overlap no speed field fits all of them, so rollouts arrived anywhere from 0.76
to 1.2 × the duration (measured). The loss adds ``time_weight`` times the mean over the
demonstrations ``(N, T, dim)`` and :func:`time_anchors` ``t`` of
``(log τ(x_t) − log((t_a − t)·dt))²``, the field's exact time to the latent ``ε``-ball
(:meth:`agents.lfd.flow_field.FlowField.time_to_go`) against the demonstration's time to the
``ε``-ball of the goal (its first sample ``t_a`` there; some demonstrations creep the last
15 % of their duration within 1 % of the goal, which no field need copy).
It trains the speed network only (the flow enters through ``stop_gradient``), so it shapes when
the reproduction arrives, not where it goes; stability holds for every parameter value anyway
(:mod:`agents.lfd.flow_field`). Called without ``dt``, the trainer fits velocities only, exactly
as with ``time_weight = 0``.

The training loop is one ``lax.scan`` over gradient steps, a pure function of explicit arrays, so
it jits and ``vmap``s over seeds and over shapes stacked along a leading axis (all LASA shapes
have the same sizes)::

    config = LfdConfig()                      # docs/design.md §4.6; LfdConfig.tiny() for tests
    trainer = make_train(config)              # dim=2
    result = jax.jit(trainer.train)(key, demos, velocities, dt)   # demos (7, 235, 2)
    results = jax.jit(jax.vmap(trainer.train))(keys, D, V, dts)   # shapes stacked: D (S, 7, 235, 2)
    xs = rollout(trainer.field, result.variables, demos[:, 0], 234, dt, method="latent")
    #    (7, 235, 2): in latent coordinates, monotone in ‖ψ‖ (agents.lfd.flow_field.rollout)

For progress output run the same compiled step in chunks: ``state = trainer.init(key, x, v)``
then repeatedly ``state, losses = trainer.run(state, x, v, num_steps, dt)`` (``num_steps``
static),
and finally ``trainer.result(state, all_losses)`` (:func:`train_batched` does this for a batch).
Early stopping freezes the parameters (the scan keeps its static length; under ``vmap`` each
member stops on its own). The epoch time is documented in :mod:`agents.lfd.fast_trig`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from agents.lfd.config import LfdConfig
from agents.lfd.flow_field import FlowField
from agents.lfd.optim import early_stop_update, regularised_adam, smooth_l1
from mjxrmp.config import check_int
from mjxrmp.data.lasa import check_demonstrations
from mjxrmp.divergence import guard_finite_series, guard_finite_tree
from mjxrmp.learned.flows import CONSTANTS

__all__ = [
    "LfdResult",
    "TrainState",
    "Trainer",
    "arrival_time_loss",
    "check_data",
    "finite_difference_velocities",
    "make_train",
    "time_anchors",
    "train_batched",
]


#: The trainer's name in :class:`mjxrmp.divergence.DivergenceError` messages.
_WHAT = "LfD flow training"


class TrainState(NamedTuple):
    """Everything the training scan carries (a pytree; ``vmap`` adds leading axes)."""

    step: jax.Array          # () int32, gradient steps taken (frozen steps included)
    params: Any
    constants: Any
    opt_state: Any
    best_params: Any
    best_loss: jax.Array     # () lowest loss seen (loss of best_params on its batch)
    best_step: jax.Array     # () int32, the step at which best_params were evaluated
    since_best: jax.Array    # () int32
    stopped: jax.Array       # () bool, early stop reached: params frozen since
    key: jax.Array           # minibatch sampling key


class LfdResult(NamedTuple):
    """What :meth:`Trainer.train` returns: ``variables`` (the best parameters with the fixed
    constants, ready for :class:`FlowField` methods), the loss of every iteration ``losses``
    (``(iterations,)``, evaluated before that iteration's update), ``best_loss``, ``best_step``
    and ``stopped`` (early stop reached)."""

    variables: dict
    losses: jax.Array
    best_loss: jax.Array
    best_step: jax.Array
    stopped: jax.Array


class Trainer(NamedTuple):
    """``make_train``'s functions (all pure; jit and vmap them as needed).

    ``init(key, x, v) -> TrainState``; ``run(state, x, v, num_steps) -> (state, losses)`` with
    ``num_steps`` static; ``result(state, losses) -> LfdResult``; ``train(key, x, v) ->
    LfdResult`` = init, ``run`` for ``config.iterations``, result. ``x`` and ``v`` are positions
    and velocity targets of equal shape ``(..., dim)`` (e.g. demos ``(N, T, dim)``); every
    sample is one regression pair.
    """

    field: FlowField
    config: LfdConfig
    init: Callable[..., TrainState]
    run: Callable[..., tuple[TrainState, jax.Array]]
    result: Callable[..., LfdResult]
    train: Callable[..., LfdResult]


def finite_difference_velocities(demos: jax.Array, dt: float | jax.Array) -> jax.Array:
    """Velocity targets ``(x_{t+1} − x_t)/dt`` with zero at the last sample, ``demos (..., T, d)``
    (as :attr:`mjxrmp.data.lasa.LasaShape.velocities`: explicit Euler with the same ``dt``
    reproduces a demonstration whose velocities are fitted exactly)."""
    check_data(demos, "demos")
    demos = jnp.asarray(demos)
    vel = jnp.diff(demos, axis=-2) / dt
    return jnp.concatenate([vel, jnp.zeros_like(demos[..., :1, :])], axis=-2)


def check_data(x: Any, name: str, dim: int | None = None) -> None:
    """:func:`mjxrmp.data.lasa.check_demonstrations` on concrete arrays (NaN/inf, fewer than 2
    samples, wrong dimension → ``ValueError`` naming ``name``); traced values (inside ``jit``)
    can only be checked for their shape."""
    if isinstance(x, jax.core.Tracer):
        if x.ndim < 2 or x.shape[-2] < 2 or (dim is not None and x.shape[-1] != dim):
            raise ValueError(f"{name} must have shape (..., T >= 2, {dim or 'd'}), "
                             f"got {x.shape}")
        return
    check_demonstrations(x, name, dim=dim)


def _flat_data(config: LfdConfig, dim: int, x: Any, v: Any) -> tuple[jax.Array, jax.Array]:
    """Validated regression pairs ``(x, v)`` as float32 ``(samples, dim)`` arrays."""
    check_data(x, "positions x", dim)
    check_data(v, "velocities v", dim)
    if jnp.shape(x) != jnp.shape(v):
        raise ValueError(f"positions x {jnp.shape(x)} and velocities v {jnp.shape(v)} "
                         f"must have the same shape (..., T, {dim})")
    x = jnp.asarray(x, jnp.float32).reshape((-1, dim))
    v = jnp.asarray(v, jnp.float32).reshape((-1, dim))
    if config.batch_size is not None and config.batch_size > x.shape[0]:
        raise ValueError(f"LfdConfig.batch_size={config.batch_size} exceeds the number of "
                         f"samples {x.shape[0]}")
    return x, v


def _velocity_loss(field: FlowField, params: Any, constants: Any, x: jax.Array,
                   v: jax.Array) -> jax.Array:
    """The regression loss of ``field.config`` (SmoothL1 or MSE, mean over coordinates)."""
    err = field.velocity({"params": params, CONSTANTS: constants}, x) - v
    if field.config.loss == "mse":
        return jnp.mean(err * err)
    return jnp.mean(smooth_l1(err, field.config.smooth_l1_beta))


def time_anchors(num_samples: int, num_anchors: int) -> np.ndarray:
    """Sample indices of the arrival-time loss on a demonstration of ``num_samples`` samples:
    ``round(j·(T − 1)/A)`` for ``j = 0 … A − 1`` (the start first; the last anchor still has
    ``(T − 1)/A`` samples to go), ``(A,)`` int."""
    return np.round(np.arange(num_anchors) * (num_samples - 1) / num_anchors).astype(int)


def arrival_time_loss(field: FlowField, params: Any, constants: Any, x: jax.Array,
               dt: jax.Array) -> jax.Array:
    """The arrival-time loss (module docstring): over the demonstrations ``x (..., T, dim)``
    (goal at the origin) and their :func:`time_anchors` ``t`` before the demonstration's arrival
    ``t_a`` (its first sample within ``ε = potential_eps`` of the goal; ``T − 1`` if none), the
    mean of ``(log τ(x_t) − log((t_a − t)·dt))²``: the field's time to the latent ``ε``-ball
    against the demonstration's time to the ``ε``-ball. Only the speed network is trained by it
    (the flow's parameters enter through ``stop_gradient``)."""
    T = x.shape[-2]
    idx = jnp.asarray(time_anchors(T, field.config.time_anchors))
    inside = jnp.linalg.norm(x, axis=-1) <= field.config.potential_eps          # (..., T)
    arrive = jnp.where(inside.any(-1), jnp.argmax(inside, axis=-1), T - 1)      # (...)
    remaining = (arrive[..., None] - idx).astype(x.dtype) * dt                  # (..., A)
    valid = remaining > 0
    frozen = {"flow": jax.lax.stop_gradient(params["flow"]), "speed": params["speed"]}
    tau = field.time_to_go({"params": frozen, CONSTANTS: constants}, x[..., idx, :])
    err = jnp.log(jnp.maximum(tau, 1e-6)) - jnp.log(jnp.where(valid, remaining, 1.0))
    return jnp.sum(jnp.where(valid, err * err, 0.0)) / jnp.maximum(jnp.sum(valid), 1)


def make_train(config: LfdConfig | None = None, dim: int = 2) -> Trainer:
    """Build the training functions of a :class:`FlowField` for ``config`` (module docstring)."""
    config = LfdConfig() if config is None else config
    if not isinstance(config, LfdConfig):
        raise TypeError(f"config must be an LfdConfig, got {type(config)}")
    field = FlowField(dim=dim, config=config)
    tx = regularised_adam(config.learning_rate, config.weight_decay, config.max_grad_norm)
    flat_data = functools.partial(_flat_data, config, dim)

    def loss_fn(params, constants, x, v, demos, dt) -> jax.Array:
        loss = _velocity_loss(field, params, constants, x, v)
        if config.time_weight > 0.0 and dt is not None:
            timing = arrival_time_loss(field, params, constants, demos, dt)
            loss = loss + config.time_weight * timing
        return loss

    def init(key, x, v) -> TrainState:
        flat_data(x, v)  # validate
        k_init, k_data = jax.random.split(key)
        variables = field.init(k_init)
        params = variables["params"]
        return TrainState(
            step=jnp.zeros((), jnp.int32), params=params, constants=variables[CONSTANTS],
            opt_state=tx.init(params), best_params=params,
            best_loss=jnp.asarray(jnp.inf, jnp.float32), best_step=jnp.zeros((), jnp.int32),
            since_best=jnp.zeros((), jnp.int32), stopped=jnp.zeros((), bool), key=k_data)

    def step(state: TrainState, x, v, demos, dt) -> tuple[TrainState, jax.Array]:
        key, sub = jax.random.split(state.key)
        if config.batch_size is not None:
            idx = jax.random.choice(sub, x.shape[0], (config.batch_size,), replace=False)
            x, v = x[idx], v[idx]
        loss, grads = jax.value_and_grad(loss_fn)(state.params, state.constants, x, v,
                                                  demos, dt)
        improved, best_params, best_loss, since, move, stopped = early_stop_update(
            loss, state.params, state.best_params, state.best_loss, state.since_best,
            state.stopped, config.patience)
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        new_params = optax.apply_updates(state.params, updates)
        keep = lambda new, old: jax.tree.map(  # noqa: E731
            lambda a, b: jnp.where(move, a, b), new, old)
        new = TrainState(
            step=state.step + 1, params=keep(new_params, state.params),
            constants=state.constants, opt_state=keep(opt_state, state.opt_state),
            best_params=best_params, best_loss=best_loss,
            best_step=jnp.where(improved, state.step, state.best_step), since_best=since,
            stopped=stopped, key=key)
        return new, loss

    def run(state: TrainState, x, v, num_steps: int, dt=None) -> tuple[TrainState, jax.Array]:
        check_int(num_steps, "num_steps (static)")
        demos = jnp.asarray(x, jnp.float32)
        dt = None if dt is None else jnp.asarray(dt, jnp.float32)
        x, v = flat_data(x, v)
        return jax.lax.scan(lambda s, _: step(s, x, v, demos, dt), state, None,
                            length=int(num_steps))

    def result(state: TrainState, losses: jax.Array) -> LfdResult:
        # The best parameters seen so far; if the final parameters were never evaluated (the
        # last step's update), they are not considered — the usual "best checkpoint" rule.
        variables = {"params": state.best_params, CONSTANTS: state.constants}
        return LfdResult(variables, losses, state.best_loss, state.best_step, state.stopped)

    def train(key, x, v, dt=None) -> LfdResult:
        state = init(key, x, v)
        state, losses = run(state, x, v, config.iterations, dt)
        return result(state, losses)

    return Trainer(field, config, init, run, result, train)


@functools.lru_cache(maxsize=16)
def _batched_program(config: LfdConfig, dim: int, num_steps: int):
    """Jitted ``vmap``-ped ``init`` and ``run(·, num_steps)`` for one configuration (cached, so
    repeated calls with the same configuration, chunk size and array shapes compile once)."""
    trainer = make_train(config, dim)
    init = jax.jit(jax.vmap(trainer.init))
    run = jax.jit(jax.vmap(lambda s, x, v, dt: trainer.run(s, x, v, num_steps, dt)))
    result = jax.jit(jax.vmap(trainer.result))
    return trainer, init, run, result


def train_batched(config: LfdConfig, keys: jax.Array, x: jax.Array, v: jax.Array, *,
                  dt: Any = None, dim: int = 2, log_every: int | None = None,
                  callback: Callable[[int, int, np.ndarray, TrainState], None] | None = None,
                  labels: Sequence[str] | None = None) -> tuple[Trainer, LfdResult]:
    """Train ``B`` independent fields in one ``vmap``-ped program: ``keys (B, 2)``, ``x`` and
    ``v (B, ..., dim)`` (seeds: the same data repeated; shapes: stacked demonstrations).

    The ``config.iterations`` steps run as compiled ``lax.scan`` chunks of ``log_every``
    (default: all at once); after each chunk ``callback(done, total, losses (B, n), state)`` is
    called on the host (progress output). The result equals ``jax.vmap(trainer.train)`` and
    every member equals its own ``trainer.train`` run. Returns ``(trainer, result)`` with every
    leaf of ``result`` carrying the leading axis ``B``.

    **Divergence guard** (docs/design.md §5.5): after each chunk, before ``callback``, a
    non-finite loss or parameter raises :class:`mjxrmp.divergence.DivergenceError` naming the
    iteration (the first non-finite loss's, else the chunk's last) and the member
    (``labels[i]``, e.g. the shape's name; default ``run <i>``). (A step with a non-finite loss
    leaves the parameters unchanged, :func:`agents.lfd.optim.early_stop_update`, so without the
    guard a diverged member would silently stop learning.)
    """
    keys = jnp.asarray(keys)
    check_data(x, "positions x", dim)
    check_data(v, "velocities v", dim)
    if keys.ndim != 2 or np.ndim(x) < 3 or np.shape(x)[0] != keys.shape[0] \
            or np.shape(v) != np.shape(x):
        raise ValueError(f"keys (B, 2), x and v (B, ..., T, {dim}) of equal shapes need one "
                         f"leading batch axis B; got keys {keys.shape}, x {np.shape(x)}, "
                         f"v {np.shape(v)}")
    x, v = jnp.asarray(x, jnp.float32), jnp.asarray(v, jnp.float32)
    total = config.iterations
    chunk = total if log_every is None else int(log_every)
    if chunk < 1:
        raise ValueError(f"log_every must be >= 1, got {log_every!r}")
    trainer, init, _, result = _batched_program(config, dim, chunk)
    if dt is not None:
        dt = jnp.broadcast_to(jnp.asarray(dt, jnp.float32), keys.shape[:1])
    state = init(keys, x, v)
    done, losses = 0, []
    while done < total:
        n = min(chunk, total - done)
        state, ls = _batched_program(config, dim, n)[2](state, x, v, dt)
        ls = np.asarray(ls)                              # (B, n); waits for the chunk
        guard_finite_series({"loss": ls}, _WHAT, start=done, unit="iteration", runs=labels)
        done += n
        guard_finite_tree(state.params, _WHAT, done, unit="iteration", runs=labels,
                          batched=True)
        losses.append(ls)
        if callback is not None:
            callback(done, total, ls, state)
    return trainer, result(state, jnp.asarray(np.concatenate(losses, axis=1)))
