"""Geometric dynamical systems (GDS) and their curvature terms by autodiff (thesis §3.2.3–3.2.5).

A GDS on a subtask space is given by a Riemannian metric ``G(x, ẋ)`` (possibly velocity
dependent), a potential ``Φ(x)`` and a damping matrix ``B(x, ẋ)`` (eq 3.17):

    M(x, ẋ) ẍ + ξ_G(x, ẋ) = −∇Φ(x) − B(x, ẋ) ẋ,      M = G + Ξ_G              (3.14, 3.17)

with the curvature terms of eq 3.13 (Cheng et al. 2018, RMPflow, §4)

    Ξ_G = ½ Σ_i ẋ_i ∂_ẋ g_i,       ξ_G = Ġ_x ẋ − ½ ∇_x(ẋᵀ G ẋ),      Ġ_x = [∂_x g_i ẋ]_i,

``g_i`` the i-th column of ``G``. (The thesis' typeset definition of ``Ġ_x`` below eq 3.13 reads
``∂_ẋ``; the proof of Lemma 3.2.1 and RMPflow both use the position derivative, which is what
is implemented here.) Every term is computed by forward-mode autodiff of the user's ``G``, so any
differentiable metric works without hand-derived formulas.

Everything here is written for **one subtask** ``x (m,)``. A task-map leaf is a family
``(n, m)``; :func:`family` (``jax.vmap`` over the leading axis) lifts a single-subtask leaf
``(x, ẋ) -> RMP(M (m,m), f (m,))`` to the ``RMP(M (n,m,m), f (n,m))`` that
:mod:`mjxrmp.core.rmp2` leaf functions return::

    goal_leaf = gds_family(G, Phi, B)             # == family(gds(G, Phi, B))
    leaf_fn = lambda x, xd, *ctx: {"goal": goal_leaf(x["goal"], xd["goal"])}
    qdd = mjxrmp.core.rmp2.acceleration(task_map, leaf_fn, q, qd, *ctx)

:func:`energy` evaluates the configuration-space Lyapunov function of eqs 3.21–3.22 through a task
map, which is what the stability tests of Theorem 3.2.1 monitor.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from mjxrmp.core.rmp import RMP

Metric = Callable[[jax.Array, jax.Array], jax.Array]
Potential = Callable[[jax.Array], jax.Array]
Damping = Callable[[jax.Array, jax.Array], jax.Array]
Leaf = Callable[[jax.Array, jax.Array], RMP]

__all__ = [
    "curvature_terms",
    "energy",
    "family",
    "gds",
    "gds_family",
    "inertia",
    "potential_gradient",
    "subtask_energy",
]


def _check_subtask(x: jax.Array, xd: jax.Array) -> tuple[jax.Array, jax.Array]:
    x = jnp.asarray(x)
    xd = jnp.asarray(xd)
    if x.ndim != 1:
        raise ValueError(
            f"x must be a single subtask coordinate of shape (m,), got shape {x.shape}; "
            "lift to a family (n, m) with mjxrmp.leaves.gds.family (jax.vmap)"
        )
    if xd.shape != x.shape:
        raise ValueError(f"xd must have the shape of x {x.shape}, got {xd.shape}")
    return x, xd


def _metric(G: Metric, x: jax.Array, xd: jax.Array) -> jax.Array:
    Gx = G(x, xd)
    m = x.shape[0]
    if Gx.shape != (m, m):
        raise ValueError(f"metric G(x, xd) must return an ({m}, {m}) matrix, got {Gx.shape}")
    return Gx


def curvature_terms(G: Metric, x: jax.Array, xd: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Curvature terms ``(Ξ_G (m,m), ξ_G (m,))`` of eq 3.13 for one subtask, by autodiff.

    ``Ξ_G = ½ Σ_i ẋ_i ∂_ẋ g_i`` is ``½ ∂_v (G(x, v) ẋ)|_{v=ẋ}`` with the right factor ``ẋ`` held
    fixed; ``ξ_G = Ġ_x ẋ − ½ ∇_x(ẋᵀGẋ)`` where ``Ġ_x ẋ`` is the directional derivative of
    ``G(·, ẋ)`` along ``ẋ`` applied to ``ẋ``. Both are zero at ``ẋ = 0``; ``Ξ_G ≡ 0`` for a
    position-only metric.
    """
    x, xd = _check_subtask(x, xd)
    _metric(G, x, xd)  # shape check
    # Ξ_G: Jacobian with respect to the velocity argument of G only.
    Xi = 0.5 * jax.jacfwd(lambda v: G(x, v) @ xd)(xd)
    # Ġ_x = d/dε G(x + ε ẋ, ẋ): one forward-mode JVP in the position argument.
    _, Gdot_x = jax.jvp(lambda y: G(y, xd), (x,), (xd,))
    kinetic = lambda y: xd @ G(y, xd) @ xd  # noqa: E731
    xi = Gdot_x @ xd - 0.5 * jax.grad(kinetic)(x)
    return Xi, xi


def inertia(G: Metric, x: jax.Array, xd: jax.Array) -> jax.Array:
    """Inertia (importance weight) ``M = G + Ξ_G`` induced by the metric (eq 3.14)."""
    x, xd = _check_subtask(x, xd)
    Xi, _ = curvature_terms(G, x, xd)
    return _metric(G, x, xd) + Xi


def potential_gradient(Phi: Potential, x: jax.Array) -> jax.Array:
    """``∇Φ(x)`` for a scalar potential of one subtask (checks that ``Φ`` returns a scalar)."""
    out = jax.eval_shape(Phi, x)
    if out.shape != ():
        raise ValueError(f"potential Phi(x) must return a scalar, got shape {out.shape}")
    return jax.grad(Phi)(x)


def gds(G: Metric, Phi: Potential, B: Damping) -> Leaf:
    """The GDS leaf ``(x (m,), ẋ (m,)) -> RMP(M = G + Ξ_G, f = −∇Φ − Bẋ − ξ_G)`` (eq 3.17).

    ``G(x, ẋ) -> (m, m)`` is the (possibly velocity-dependent) metric, ``Phi(x) -> ()`` the
    potential and ``B(x, ẋ) -> (m, m)`` the damping matrix; all are pure JAX callables. The
    result is in natural form, ready for :func:`mjxrmp.core.rmp2.pullback` once lifted with
    :func:`family`. By Lemma 3.2.1 it satisfies ``V̇ = −ẋᵀBẋ`` for ``V = ½ẋᵀGẋ + Φ``.
    """

    def leaf(x: jax.Array, xd: jax.Array) -> RMP:
        x, xd = _check_subtask(x, xd)
        Gx = _metric(G, x, xd)
        Xi, xi = curvature_terms(G, x, xd)
        Bx = B(x, xd)
        if Bx.shape != Gx.shape:
            raise ValueError(f"damping B(x, xd) must have shape {Gx.shape}, got {Bx.shape}")
        f = -potential_gradient(Phi, x) - Bx @ xd - xi
        return RMP(Gx + Xi, f)

    return leaf


def family(leaf: Leaf) -> Callable[[jax.Array, jax.Array], RMP]:
    """Lift a single-subtask leaf to a family: ``(x (n,m), ẋ (n,m)) -> RMP((n,m,m), (n,m))``.

    This is ``jax.vmap(leaf)``; every member of the family shares the leaf's parameters (put
    per-member data such as goals into the task map, e.g. ``x = y − g``).
    """
    return jax.vmap(leaf)


def gds_family(G: Metric, Phi: Potential, B: Damping) -> Callable[[jax.Array, jax.Array], RMP]:
    """:func:`gds` lifted to a family of subtasks ``(n, m)`` for rmp2 leaf functions."""
    return family(gds(G, Phi, B))


def subtask_energy(G: Metric, Phi: Potential, x: jax.Array, xd: jax.Array) -> jax.Array:
    """Subtask energy ``V_k = ½ ẋᵀ G(x, ẋ) ẋ + Φ(x)`` of eq 3.15 for one subtask."""
    x, xd = _check_subtask(x, xd)
    return 0.5 * xd @ _metric(G, x, xd) @ xd + Phi(x)


def energy(
    task_map: Callable[..., Any],
    metric_fn: Callable[..., Any],
    potential_fn: Callable[..., Any],
    q: jax.Array,
    qd: jax.Array,
    *ctx: Any,
) -> jax.Array:
    """Lyapunov function ``V(q, q̇) = ½ q̇ᵀ G(q, q̇) q̇ + Φ(q)`` of eqs 3.21–3.22 (a scalar).

    Computed as ``Σ_k Σ_n [½ ẋᵀ G_k(x, ẋ) ẋ + Φ_k(x)]`` (eq 3.24) with ``x = task_map(q, *ctx)``
    and ``ẋ = J q̇`` from one ``jax.jvp`` of the task map.

    * ``task_map(q, *ctx)`` returns the same pytree of ``(n_k, m_k)`` arrays as for
      :func:`mjxrmp.core.rmp2.pullback`;
    * ``metric_fn(x_tree, xd_tree, *ctx)`` returns a tree of the same structure whose leaves are
      the family metrics ``G_k`` of shape ``(n_k, m_k, m_k)``;
    * ``potential_fn(x_tree, *ctx)`` returns a tree of the same structure whose leaves are the
      per-subtask potentials ``Φ_k`` of shape ``(n_k,)``.

    Per-subtask ``G(x, ẋ)``/``Φ(x)`` callables lift with ``jax.vmap``, e.g.
    ``metric_fn = lambda x, xd: {"goal": jax.vmap(G)(x["goal"], xd["goal"])}``.
    """
    q = jnp.asarray(q)
    qd = jnp.asarray(qd)
    if q.ndim != 1 or qd.shape != q.shape:
        raise ValueError(
            f"q and qd must be configuration vectors of equal shape (d,), got {q.shape}, {qd.shape}"
        )
    x, xd = jax.jvp(lambda q_: task_map(q_, *ctx), (q,), (qd,))
    G = metric_fn(x, xd, *ctx)
    Phi = potential_fn(x, *ctx)
    struct = jax.tree.structure(x)
    G_leaves = struct.flatten_up_to(G)
    Phi_leaves = struct.flatten_up_to(Phi)
    total = jnp.zeros((), dtype=q.dtype)
    for xk, xdk, Gk, Pk in zip(jax.tree.leaves(x), jax.tree.leaves(xd), G_leaves, Phi_leaves,
                               strict=True):
        n, m = xk.shape
        if Gk.shape != (n, m, m):
            raise ValueError(f"metric_fn leaf must have shape {(n, m, m)}, got {Gk.shape}")
        if Pk.shape != (n,):
            raise ValueError(f"potential_fn leaf must have shape {(n,)}, got {Pk.shape}")
        total = total + 0.5 * jnp.einsum("na,nab,nb->", xdk, Gk, xdk) + jnp.sum(Pk)
    return total
