"""Learning RMP² policies for the Franka from demonstrations: the strategies of thesis chapter 5.

The policy class is that of :mod:`agents.lfd.policy` (learned leaves ``(ψ_k, Φ̄, G_k)`` and the
default straight-line leaves, resolved by eq 5.1); the data are
:class:`agents.lfd.samples.Samples`.

**Strategies** (:data:`agents.lfd.config.STRATEGIES`), each a two-stage fit (docs/design.md §4.6):
stage 1 trains the flows with the latent metrics held at ``I``; stage 2 trains the metrics with
the flows frozen. Every stage is one ``lax.scan`` of Adam steps (:func:`agents.lfd.optim.fit`;
weight decay ``1e-8`` as an L2 term, §5.3.2; full batch, or minibatches drawn ``∝ w`` with
``batch_size``), the whole fit one jittable
function ``train(key, samples)`` that ``vmap``s over seeds and over demonstration subsets (the
per-sample weights ``samples.w`` select the demonstrations, so leave-one-out folds share one
array and differ only in ``w``). Losses are SmoothL1 (``β``) averaged over coordinates, leaves
and (weighted) samples.

* ``"cspace"`` — configuration-space regression (§5.1 eq 5.2): one leaf on ``x = q − q_g``
  (``J = ∂ψ/∂q`` square), loss ``SmoothL1(π_θ(q) − q̇_demo)`` — a *stable* flow DS in
  configuration space (docs/design.md §4.6) rather than an unconstrained regressor, so that its
  rollouts can be compared with the others'.
* ``"independent"`` — independent per-subtask learning (§5.1 eq 5.3, §5.2): each control point's
  leaf is fitted on its own, to reproduce that point's demonstrated velocity in its task space,
  ``ẋ_k = J_{φ_k}⁻¹ G_k⁻¹(−∇Φ̄(y_k))`` (the single-leaf solution of eq 5.1; eq 5.6 in the latent
  coordinates); the leaves meet each other and the default leaves only at execution, through
  (*). The fits are ``vmap``-ped over the leaves, so they are exactly independent.
* ``"joint"`` — joint learning through the velocity-form RMP² (§5.1 eq 5.4, §5.3, eq 5.8):
  ``mean_k SmoothL1(J_{FK,k}(π_θ(q) − q̇_demo))``, differentiating through the resolve (*)
  (default leaves included, ``λ_k = 1``).
  ``J_{FK,k}`` is the task-space Jacobian of the control point (so errors are control-point
  velocities in m/s; eq 5.4 writes the subtask Jacobian, which would make the weighting depend
  on the learned flow).
* ``"single_link"`` — the single-link baseline of §5.3.2: only the centre control point, learned
  independently.
* ``"two_step"`` — the two-step strategy of §5.2 (a nominal-demonstration potential per control
  point, then a Cholesky metric by eq 5.6; no flows): trained by :mod:`agents.lfd.two_step`
  (its potential fit runs on the host, so :func:`make_train` refuses it); executed like the
  others, with the leaf ``(G_k, −∇Φ_k)`` in place of the flow-based learned leaf.

Execution, identical for every strategy, is :mod:`agents.lfd.execution`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from agents.lfd.config import DOF, INDEPENDENT_STRATEGIES, StrategyConfig
from agents.lfd.optim import fit, minibatch, regularised_adam, smooth_l1
from agents.lfd.policy import StrategyResult, init_params, leaf_task_velocity, training_velocity
from agents.lfd.samples import Samples
from mjxrmp.divergence import guard_finite_series, guard_finite_tree

__all__ = ["fold_trainer", "guard_finite_result", "make_train", "strategy_loss"]


def strategy_loss(config: StrategyConfig, params: Any, constants: Any, samples: Samples
                  ) -> jax.Array:
    """The training loss of ``config.strategy`` (module docstring) on weighted ``samples``.

    ``"cspace"``: ``SmoothL1(π(q) − q̇_d)`` (eq 5.2); ``"joint"``: ``mean_k SmoothL1(J_{FK,k}(π(q)
    − q̇_d))`` (eq 5.4); ``"independent"``/``"single_link"``: ``mean_k SmoothL1(ẋ_k − ẋ_{d,k})``
    with each leaf alone (eq 5.3). Means over coordinates and leaves, weighted mean over samples.
    """
    beta = config.smooth_l1_beta
    if config.strategy in INDEPENDENT_STRATEGIES:
        pred = jax.vmap(lambda x: leaf_task_velocity(config, params, constants, x))(samples.x)
        per = jnp.mean(smooth_l1(pred - samples.xd, beta), axis=(1, 2))
    else:
        qd = jax.vmap(lambda x, J: training_velocity(config, params, constants, x, J))(
            samples.x, samples.J)
        err = jnp.einsum("skaq,sq->ska", samples.J, qd - samples.qd)
        per = jnp.mean(smooth_l1(err, beta), axis=(1, 2))
    w = samples.w
    return jnp.sum(w * per) / jnp.maximum(jnp.sum(w), 1.0)


def _two_stage(config: StrategyConfig, params: Any, constants: Any, samples: Samples,
               key: jax.Array) -> tuple[Any, jax.Array, jax.Array]:
    """Stage 1: flows with the metrics at their initial value ``I``; stage 2: metrics with the
    flows frozen (docs/design.md §4.6)."""
    def loss(p, k):
        return strategy_loss(config, p, constants, minibatch(samples, k, config.batch_size))

    k1, k2 = jax.random.split(key)
    tx_flow, tx_metric = (regularised_adam(lr, config.weight_decay, config.max_grad_norm)
                          for lr in (config.learning_rate, config.metric_learning_rate))
    flow, flow_losses = fit(lambda fp, k: loss({**params, "flow": fp}, k), params["flow"],
                            tx_flow, config.flow_iterations, k1, config.patience)
    metric, metric_losses = fit(lambda mp, k: loss({"flow": flow, "metric": mp}, k),
                                params["metric"], tx_metric, config.metric_iterations, k2,
                                config.patience)
    return {"flow": flow, "metric": metric}, flow_losses, metric_losses


def make_train(config: StrategyConfig) -> Callable[[jax.Array, Samples], StrategyResult]:
    """``train(key, samples) -> StrategyResult`` for ``config`` (module docstring): initialise
    the ``K`` leaves from ``key`` and run both stages. Pure and jittable; ``jax.vmap`` it over
    keys (seeds) and/or ``samples.w`` (demonstration subsets)."""
    if not isinstance(config, StrategyConfig):
        raise TypeError(f"config must be a StrategyConfig, got {type(config)}")
    if config.strategy == "two_step":
        raise ValueError("strategy 'two_step' needs the nominal potentials of its training "
                         "demonstrations: train it with agents.lfd.two_step.train_folds")

    def check(samples: Samples) -> None:
        K, m = config.num_leaves, config.leaf_dim
        S = samples.w.shape[0]
        want = Samples((S, K, m), (S, K, m, DOF), (S, K, m), (S, DOF), (S,))
        for name, shape, got in zip(Samples._fields, want, samples, strict=True):
            if got.shape != shape:
                raise ValueError(f"samples.{name} must have shape {shape} for strategy "
                                 f"{config.strategy!r}, got {got.shape}")

    def train(key: jax.Array, samples: Samples) -> StrategyResult:
        check(samples)
        k_init, k_fit = jax.random.split(key)
        params, constants = init_params(config, k_init)
        if config.strategy not in INDEPENDENT_STRATEGIES:
            out, fl, ml = _two_stage(config, params, constants, samples, k_fit)
            return StrategyResult(out, constants, fl, ml)
        # Independent leaves: the same two-stage fit, vmapped over leaves (eq 5.3).
        one = dataclasses.replace(config, strategy="single_link", point=0)

        def leaf(p, c, x, J, xd, k):
            p1 = jax.tree.map(lambda a: a[None], p)
            c1 = jax.tree.map(lambda a: a[None], c)
            s1 = samples._replace(x=x[:, None], J=J[:, None], xd=xd[:, None])
            out, fl, ml = _two_stage(one, p1, c1, s1, k)
            return jax.tree.map(lambda a: a[0], out), fl, ml

        out, fl, ml = jax.vmap(leaf, in_axes=(0, 0, 1, 1, 1, 0))(
            params, constants, samples.x, samples.J, samples.xd,
            jax.random.split(k_fit, config.num_leaves))
        return StrategyResult(out, constants, jnp.mean(fl, axis=0), jnp.mean(ml, axis=0))

    return train


@functools.lru_cache(maxsize=16)
def fold_trainer(config: StrategyConfig) -> Callable[[jax.Array, Samples, jax.Array],
                                                     StrategyResult]:
    """``train(keys (F, 2), samples, weights (F, S)) -> StrategyResult`` (leaves with a leading
    ``F``): :func:`make_train` jitted and ``vmap``-ped over keys and sample weights (seeds and/or
    demonstration subsets, e.g. leave-one-out folds), cached per configuration so that every
    caller with the same configuration and array shapes shares one compiled program. The
    result is checked by :func:`guard_finite_result` (it waits for the program)."""

    def train(keys: jax.Array, samples: Samples, weights: jax.Array) -> StrategyResult:
        return jax.vmap(make_train(config), in_axes=(0, Samples(None, None, None, None, 0)))(
            keys, samples._replace(w=weights))

    program = jax.jit(train)

    def checked(keys: jax.Array, samples: Samples, weights: jax.Array) -> StrategyResult:
        return guard_finite_result(program(keys, samples, weights),
                                   f"LfD {config.strategy} training")

    return checked


def guard_finite_result(result: StrategyResult, what: str) -> StrategyResult:
    """``result`` (stacked over runs, as :func:`fold_trainer` returns it) if its losses and
    parameters are finite, else :class:`mjxrmp.divergence.DivergenceError` naming ``what``, the
    first non-finite stage loss (``flow_loss``, then ``metric_loss``) with its iteration and
    run, or the first non-finite parameter after the last iteration (docs/design.md §5.5). A step
    with a non-finite loss leaves the parameters unchanged (:func:`agents.lfd.optim.fit`), so
    without this check a diverged run would silently stop learning."""
    guard_finite_series({"flow_loss": result.flow_losses}, what, unit="iteration")
    guard_finite_series({"metric_loss": result.metric_losses}, what, unit="iteration")
    guard_finite_tree(result.params, what,
                      result.flow_losses.shape[1] + result.metric_losses.shape[1],
                      unit="iteration", batched=True)
    return result
