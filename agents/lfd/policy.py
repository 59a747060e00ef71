"""The learned RMP² policy class of thesis §5.3.1 for the Franka hand (velocity form, eq 5.1).

**Policy class** (§5.3.1). ``K`` learned leaves, each a subtask map, a latent potential and a
latent Riemannian metric ``(ψ_k, Φ̄, G_k)``:

* ``ψ_k(q) = φ_k(x_k(q)) − φ_k(0)`` with ``x_k(q) = FK_k(q) − g_k`` the k-th hand control point
  relative to its goal (§5.2.3; :func:`mjxrmp.data.franka_demos.hand_points`) — or, for
  configuration-space regression, ``x(q) = q − q_g`` — and ``φ_k`` a Euclideanizing flow
  (§4.2.2, eqs 4.4–4.5; :class:`mjxrmp.learned.flows.EuclideanizingFlow`);
* ``Φ̄(y) = ½γ‖y‖²`` (§5.3.1, "a simple pre-specified potential"; ``γ`` = ``latent_gain``);
* ``G_k(y)`` a Cholesky metric network on the latent space (§4.3.1, §5.2.2;
  :class:`mjxrmp.learned.gds.CholeskyMetric`, exactly ``I`` at initialisation).

Leaf k is the velocity-form RMP ``(M_k, v_k) = (G_k, −G_k⁻¹∇Φ̄)`` (§5.3.1), i.e. the natural pair
``(G_k, p_k = −γ y_k)``. As in §5.3.2 a hand-specified *default* leaf on each control point pulls
it in a straight line to its goal: ``(w I, p = −w γ_d x_k)`` (a convex potential
``½γ_d‖x_k‖²`` with the constant inertia ``w``, ``default_weight`` = 10 as in §5.3.2, ``γ_d`` =
``default_gain``; ``w = 0`` removes it). The configuration-space policy is the velocity-form RMP²
of eq 5.1,

    q̇ = π_θ(q) = argmin_v Σ_k ½‖J_k v − v_k‖²_{G_k} + ½‖J_{x,k} v − v_k^d‖²_{wI}
        = (Σ_k J_kᵀ G_k J_k + w J_{x,k}ᵀ J_{x,k} + εI)⁻¹ Σ_k (J_kᵀ p_k − w γ_d J_{x,k}ᵀ x_k),   (*)

``J_k = ∂ψ_k/∂q``, ``J_{x,k} = ∂x_k/∂q``, with the small diagonal offset ``ε``
(``regularization``, 0.02 as in §5.3.2) that keeps the root metric non-singular (three points on
the rigid hand constrain at most 6 of the 7 joints; one control point only 3). The default leaves
are part of the policy class during learning too (the joint strategy learns to bias against them,
§5.3.2). **Stability for every θ:** ``V(q) = Σ_k [Φ̄(ψ_k(q)) + ½wγ_d‖x_k(q)‖²]`` has
``V̇ = −fᵀ(M + εI)⁻¹f ≤ 0`` with ``f`` the right-hand side of (*) (``f = −∇V``); each ``ψ_k`` is a
diffeomorphism of the control point with ``ψ_k = 0`` only at its goal.

The policy is trained by :mod:`agents.lfd.strategies` (or :mod:`agents.lfd.two_step`) and
executed, with the hand-specified execution-time leaves, by :mod:`agents.lfd.execution`.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from agents.lfd.config import StrategyConfig
from mjxrmp.learned.flows import CONSTANTS

__all__ = [
    "StrategyResult",
    "init_params",
    "latent_leaves",
    "leaf_task_velocity",
    "resolve_velocity",
    "training_velocity",
]


class StrategyResult(NamedTuple):
    """A fitted policy: ``params = {"flow", "metric"}`` and ``constants`` (the flows' fixed
    random features), every leaf stacked over the ``K`` leaves; the loss of every iteration of
    both stages, ``flow_losses (flow_iterations,)`` and ``metric_losses (metric_iterations,)``
    (for ``"independent"`` the mean over leaves)."""

    params: Any
    constants: Any
    flow_losses: jax.Array
    metric_losses: jax.Array


def init_params(config: StrategyConfig, key: jax.Array) -> tuple[Any, Any]:
    """Initial ``(params, constants)`` of the ``K`` leaves (stacked): flows at the identity,
    metrics at ``I`` (§4.2.2, §4.3.1)."""
    m = config.leaf_dim

    def one(k):
        k_flow, k_metric = jax.random.split(k)
        fv = config.flow.init(k_flow, jnp.zeros((m,), jnp.float32))
        mp = config.metric.init(k_metric, jnp.zeros((m,), jnp.float32))["params"]
        return {"flow": fv["params"], "metric": mp}, fv[CONSTANTS]

    return jax.vmap(one)(jax.random.split(key, config.num_leaves))


def latent_leaves(config: StrategyConfig, params: Any, constants: Any, x: jax.Array
                  ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Per leaf ``y_k = φ_k(x_k) − φ_k(0)``, ``J_{φ_k}(x_k)`` and ``G_k(y_k)`` for one sample
    ``x (K, m)``: ``(y (K, m), Jφ (K, m, m), G (K, m, m))`` (§4.2, §5.3.1)."""
    flow, metric = config.flow, config.metric

    def one(fp, fc, mp, xk):
        fv = {"params": fp, CONSTANTS: fc}

        def phi(z):
            y = flow.apply(fv, z)
            return y, y

        Jphi, y = jax.jacfwd(phi, has_aux=True)(xk)
        y = y - flow.apply(fv, jnp.zeros_like(xk))
        return y, Jphi, metric.apply({"params": mp}, y)

    return jax.vmap(one)(params["flow"], constants, params["metric"], x)


def resolve_velocity(M: jax.Array, f: jax.Array, regularization: float) -> jax.Array:
    """``q̇ = (M + εI)⁻¹ f``: the velocity-form root resolve of eq 5.1 with the diagonal offset
    ``ε`` of §5.3.2 (``M = Σ J_kᵀ G_k J_k``, ``f = Σ J_kᵀ p_k``)."""
    eye = jnp.eye(M.shape[-1], dtype=M.dtype)
    with jax.default_matmul_precision("highest"):
        return jnp.linalg.solve(M + regularization * eye, f)


def training_velocity(config: StrategyConfig, params: Any, constants: Any, x: jax.Array,
                      J: jax.Array) -> jax.Array:
    """(*) of the module docstring at one sample from its task coordinates ``x (K, m)`` and their
    Jacobians ``J (K, m, 7)`` (so ``J_k = J_{φ_k} J``): the policy the losses differentiate."""
    y, Jphi, G = latent_leaves(config, params, constants, x)
    A = jnp.einsum("kab,kbq->kaq", Jphi, J)
    p = -config.latent_gain * y
    M = jnp.einsum("kaq,kab,kbr->qr", A, G, A)
    f = jnp.einsum("kaq,ka->q", A, p)
    w = config.default_weight
    M = M + w * jnp.einsum("kaq,kar->qr", J, J)
    f = f - w * config.default_gain * jnp.einsum("kaq,ka->q", J, x)
    return resolve_velocity(M, f, config.regularization)


def leaf_task_velocity(config: StrategyConfig, params: Any, constants: Any, x: jax.Array
                       ) -> jax.Array:
    """``ẋ_k = J_{φ_k}⁻¹ G_k⁻¹ (−γ y_k)`` per leaf, ``(K, m)``: each leaf alone (eq 5.3)."""
    y, Jphi, G = latent_leaves(config, params, constants, x)
    v_latent = jnp.linalg.solve(G, -config.latent_gain * y[..., None])
    return jnp.linalg.solve(Jphi, v_latent)[..., 0]
