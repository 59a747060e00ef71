"""Nominal-trajectory potential (thesis §4.3.1, eqs 4.8–4.12) and the DTW nominal (§5.2.1).

Given a nominal trajectory ``ζ = (ζ_t)_{t=1}^T`` ending at the goal, the potential is a convex
combination of potential elements centred on the trajectory points (eq 4.9)::

    Φ(x) = Σ_t w_t(x) φ_t(x),   w_t(x) = k(x, ζ_t) / Σ_t' k(x, ζ_t'),
    k(x, ζ_t) = exp(−‖x − ζ_t‖² / (2σ²)),   φ_t(x) = φ_t^⊥(x) + φ_t^0,                   (4.9)

with the attractive element of Cheng et al. (2018) (eq 4.11)::

    φ_t^⊥(x) = (1/η) log(e^{η r_t} + e^{−η r_t}),  r_t = ‖x − ζ_t‖,
    ∇φ_t^⊥(x) = s_η(r_t) (x − ζ_t)/r_t,           s_η(r) = tanh(η r),                    (4.11)

and scalar bias terms ``φ_t^0 ≥ 0`` that decrease monotonically along the trajectory, fitted by
the constrained least-squares problem (eq 4.12)::

    min_{φ^0}  (1/T) Σ_t [ ‖ζ̇_t + ∇Φ(ζ_t; φ^0)‖² + λ (φ_t^0)² ]
    s.t.       0 ≤ φ_T^0 ≤ φ_{t+1}^0 ≤ φ_t^0   (t = 1 … T−1),     ∇Φ(ζ_T) = 0.             (4.12)

Readings of the typeset equations (stated because the text is ambiguous or has typos):

* **Goal frame.** Eq 4.8 asks for ``ζ_T = 0`` and the constraint of eq 4.12 is ``∇Φ(0) = 0``.
  Here the trajectory may be given in any frame: the goal is ``ζ_T`` and the constraint is
  ``∇Φ(ζ_T) = 0``, which is eq 4.12 after the translation ``x ↦ x − ζ_T``.
* **Regulariser.** ``λ‖φ_t^0‖²`` carries the summation index ``t``, so it is read as inside the
  mean: ``(1/T)Σ_t λ(φ_t^0)² = (λ/T)‖φ^0‖²``.
* **s_η.** The text says ``s_η(r) → 1 as r → 0``; differentiating eq 4.11 gives
  ``s_η(r) = tanh(η r)``, which is 0 at 0 and tends to 1 as ``r → ∞`` (the intended statement).
* **Decomposition (eq 4.10).** With ``∇w_t(x) = w_t(x)(ζ_t − ζ̄(x))/σ²``,
  ``ζ̄(x) = Σ_t w_t(x) ζ_t``, the exact gradient of eq 4.9 is
  ``∇Φ = Σ_t w_t ∇φ_t^⊥ + Σ_t φ_t ∇w_t``. The first sum pulls towards the trajectory and is
  taken as ``∇Φ^⊥``; the second, which carries the biases and moves along the trajectory, is
  ``∇Φ^∥`` (:func:`nominal_potential_gradient_parts`).
* **Offset.** Eq 4.9 is not zero at the goal: ``Φ(ζ_T) = Σ_t w_t(ζ_T) φ_t(ζ_T) > 0`` (already
  ``φ_T^⊥(ζ_T) = log 2 / η``). :class:`NominalPotential` stores the constant
  ``offset = Φ_4.9(ζ_T)`` and :func:`nominal_potential` returns ``Φ_4.9(x) − offset``, so
  ``Φ(ζ_T) = 0`` exactly; the gradient, and so every GDS built on it, is eq 4.9's unchanged.
  Since ``φ_t^⊥ ≥ log 2 / η`` and ``φ_t^0 ≥ φ_T^0 ≥ 0``, eq 4.9 satisfies
  ``Φ_4.9 ≥ log 2/η + φ_T^0`` everywhere and ``Φ_4.9(x) ≥ min_t ‖x − ζ_t‖ → ∞`` (eq 4.8). That
  the goal is also the *global* minimum (``Φ ≥ 0`` after the offset) is not implied by eqs
  4.9–4.12 — a convex combination of elements can dip below its value at the goal — and is
  checked numerically on grids: in the tests for straight-line and circular-arc trajectories,
  and (when this was written) for the fitted nominal of each of the 30 LASA shapes.
  ``offset=False`` in :func:`fit_nominal_potential` keeps ``offset = 0`` (eq 4.9 verbatim).

**The fit.** ``∇Φ(x; φ^0) = A(x) φ^0 + b(x)`` is affine in the biases with
``A(x)[:, t] = ∇w_t(x)`` (:func:`design_matrix`), so eq 4.12 is a strictly convex least-squares
problem with linear inequality and equality constraints (LSEI). It is solved *exactly* (finite
active-set termination, no tolerance-driven iteration on the objective) by Lawson & Hanson's
reductions (*Solving Least Squares Problems*, 1974, ch. 20–23), the method of SLSQP's
subproblem solver: the equality is eliminated through the SVD of its matrix (:func:`lsei`), the
remaining ``min ‖Cφ − d‖ s.t. Gφ ≥ h`` with ``C = QR`` becomes the least-distance program
``min ‖z‖ s.t. G R⁻¹ z ≥ h − G R⁻¹ Qᵀd`` (:func:`lsi`), solved by their active-set NNLS
(:func:`nnls`, the algorithm of ``scipy.optimize.nnls``). The monotone constraints always hold
bit-exactly (a final reverse running maximum clipped at 0 moves a solution by round-off only).

The equality ``∇Φ(ζ_T) = 0`` is the delicate part: it can be infeasible for monotone biases (a
trajectory curving into its goal, as most LASA demonstrations do), and where attainable it can
demand absurd biases or a much worse fit. :func:`fit_biases` therefore tests attainability
exactly, solves eq 4.12 verbatim when that is sound (``info.exact``), and otherwise minimises
``J + goal_weight·‖∇Φ(ζ_T)‖²`` over the monotone cone (an exact NNLS), see its docstring.

Everything is ``jax.jit``-able (``lax.while_loop``); fit with ``jax_enable_x64`` (float32 loses
the exactness). Cost: each NNLS takes at most ``3T`` active-set steps with an ``O(T³)`` solve
each, so keep ``T`` to a few hundred (LASA's 235 samples fit in about a second on a CPU).

**Nominal demonstration (§5.2.1).** ``select_nominal`` returns the demonstration with the least
mean DTW distance (:func:`mjxrmp.metrics.trajectory.dtw`) to the other demonstrations; ties go to the
lowest index.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import solve_triangular

from mjxrmp.config import param_dataclass
from mjxrmp.metrics.trajectory import dtw, dtw_jax

__all__ = [
    "GOAL_CONSTRAINTS",
    "FitInfo",
    "NominalPotential",
    "attractor_element",
    "design_matrix",
    "fit_biases",
    "fit_from_demonstrations",
    "fit_nominal_potential",
    "kernel_weights",
    "lsei",
    "lsi",
    "nnls",
    "nominal_potential",
    "nominal_potential_gradient",
    "nominal_potential_gradient_parts",
    "raw_potential",
    "select_nominal",
    "select_nominal_jax",
    "trajectory_velocity",
]


# ---------------------------------------------------------------------------------------------
# The potential (eqs 4.9–4.11)
# ---------------------------------------------------------------------------------------------


@param_dataclass
class NominalPotential:
    """Parameters of the nominal-trajectory potential (eq 4.9); a frozen pytree.

    ``centers (T, m)`` is the nominal trajectory ``ζ`` (goal ``ζ_T = centers[-1]``),
    ``biases (T,)`` the fitted ``φ_t^0`` (non-increasing, ``≥ 0``), ``sigma`` the kernel
    length-scale ``σ``, ``eta`` the smoothing ``η`` of eq 4.11 and ``offset`` the constant
    subtracted so that the goal has potential 0 (module docstring). All fields are pytree leaves,
    so the potential can be differentiated with respect to them and ``jax.vmap``-ed over a batch
    of potentials.
    """

    centers: Any = dataclasses.field(metadata={"signed": True})
    biases: Any
    sigma: Any
    eta: Any
    offset: Any = dataclasses.field(default=0.0, metadata={"signed": True})

    def __post_init__(self) -> None:
        for name in ("sigma", "eta"):
            value = getattr(self, name)
            if isinstance(value, (int, float)) and not value > 0:
                raise ValueError(f"NominalPotential.{name} must be > 0, got {value!r}")
        c, b = self.centers, self.biases
        if hasattr(c, "shape") and hasattr(b, "shape") and (
                len(c.shape) != 2 or b.shape != c.shape[:1]):
            raise ValueError(f"NominalPotential: centers must be (T, m) and biases (T,), got "
                             f"{c.shape} and {b.shape}")

    @property
    def goal(self) -> jax.Array:
        """``ζ_T``, the last trajectory point."""
        return jnp.asarray(self.centers)[-1]


def attractor_element(r: jax.Array, eta: jax.Array | float) -> jax.Array:
    """``φ^⊥(r) = (1/η) log(e^{ηr} + e^{−ηr})`` of eq 4.11 for distances ``r ≥ 0``.

    Evaluated as ``r + log1p(e^{−2ηr})/η`` (no overflow); ``dφ^⊥/dr = tanh(ηr) = s_η(r)``.
    """
    return r + jnp.log1p(jnp.exp(-2.0 * eta * r)) / eta


def _safe_norm(v: jax.Array) -> jax.Array:
    sq = jnp.sum(v * v, axis=-1)
    pos = sq > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0)


def _tanh_over_r(r: jax.Array, eta: jax.Array | float) -> jax.Array:
    """``s_η(r)/r = tanh(ηr)/r`` with its limit ``η(1 − (ηr)²/3)`` near ``r = 0``."""
    z = eta * r
    small = z < 1e-4
    safe_r = jnp.where(small, 1.0, r)
    return jnp.where(small, eta * (1.0 - z * z / 3.0), jnp.tanh(z) / safe_r)


def _check_x(centers: jax.Array, x: jax.Array) -> tuple[jax.Array, jax.Array]:
    centers = jnp.asarray(centers)
    x = jnp.asarray(x)
    if centers.ndim != 2:
        raise ValueError(f"centers must have shape (T, m), got {centers.shape}")
    if x.ndim < 1 or x.shape[-1] != centers.shape[-1]:
        raise ValueError(f"x must have shape (..., {centers.shape[-1]}), got {x.shape}")
    return centers, x


def kernel_weights(centers: jax.Array, sigma: jax.Array | float, x: jax.Array) -> jax.Array:
    """``w_t(x)`` of eq 4.9 (a softmax of ``−‖x − ζ_t‖²/(2σ²)``), ``x (..., m) → (..., T)``."""
    centers, x = _check_x(centers, x)
    diff = x[..., None, :] - centers
    return jax.nn.softmax(-jnp.sum(diff * diff, axis=-1) / (2.0 * sigma * sigma), axis=-1)


def raw_potential(p: NominalPotential, x: jax.Array) -> jax.Array:
    """Eq 4.9 verbatim, ``Φ_4.9(x) = Σ_t w_t(x)(φ_t^⊥(x) + φ_t^0)``; ``x (..., m) → (...)``."""
    centers, x = _check_x(p.centers, x)
    diff = x[..., None, :] - centers
    w = jax.nn.softmax(-jnp.sum(diff * diff, axis=-1) / (2.0 * p.sigma * p.sigma), axis=-1)
    phi = attractor_element(_safe_norm(diff), p.eta) + p.biases
    return jnp.sum(w * phi, axis=-1)


def nominal_potential(p: NominalPotential, x: jax.Array) -> jax.Array:
    """``Φ(x) = Φ_4.9(x) − offset`` (eq 4.9 up to a constant; 0 at the goal after a fit).

    ``x (..., m) → (...)``; pure, ``jax.jit``/``jax.vmap``-able, differentiable in ``x`` and
    in every field of ``p``.
    """
    return raw_potential(p, x) - p.offset


def _gradient_terms(centers, sigma, eta, x):
    """``(∇Φ^⊥, A, ∇Φ^∥(φ^0=0))`` at one or many points ``x (..., m)``.

    ``A (..., m, T)`` has columns ``∇w_t(x) = w_t (ζ_t − ζ̄)/σ²``.
    """
    diff = x[..., None, :] - centers                                   # (..., T, m)
    sq = jnp.sum(diff * diff, axis=-1)
    w = jax.nn.softmax(-sq / (2.0 * sigma * sigma), axis=-1)           # (..., T)
    r = _safe_norm(diff)
    perp = jnp.sum((w * _tanh_over_r(r, eta))[..., None] * diff, axis=-2)   # Σ w_t ∇φ_t^⊥
    zeta_bar = jnp.sum(w[..., None] * centers, axis=-2)                # (..., m)
    grad_w = w[..., None] * (centers - zeta_bar[..., None, :]) / (sigma * sigma)  # (..., T, m)
    A = jnp.swapaxes(grad_w, -1, -2)                                    # (..., m, T)
    par0 = jnp.sum(attractor_element(r, eta)[..., None] * grad_w, axis=-2)
    return perp, A, par0


def nominal_potential_gradient_parts(p: NominalPotential, x: jax.Array
                                     ) -> tuple[jax.Array, jax.Array]:
    """``(∇Φ^⊥(x), ∇Φ^∥(x))`` of eq 4.10, closed form; their sum is ``∇Φ(x)``.

    ``∇Φ^⊥ = Σ_t w_t ∇φ_t^⊥`` (eq 4.11's unit-magnitude pull towards the points, weighted) and
    ``∇Φ^∥ = Σ_t (φ_t^⊥ + φ_t^0) ∇w_t`` (the part produced by the varying weights, which
    carries the bias terms). ``x (..., m)``.
    """
    centers, x = _check_x(p.centers, x)
    perp, A, par0 = _gradient_terms(centers, p.sigma, p.eta, x)
    return perp, par0 + jnp.einsum("...mt,t->...m", A, jnp.asarray(p.biases))


def nominal_potential_gradient(p: NominalPotential, x: jax.Array) -> jax.Array:
    """``∇Φ(x)`` in closed form (eqs 4.9–4.11), ``x (..., m) → (..., m)``.

    Equals ``jax.grad(nominal_potential)`` (tested, with float64 finite differences).
    """
    perp, par = nominal_potential_gradient_parts(p, x)
    return perp + par


def design_matrix(centers: jax.Array, sigma, eta, x: jax.Array
                  ) -> tuple[jax.Array, jax.Array]:
    """``(A (..., m, T), b (..., m))`` with ``∇Φ(x; φ^0) = A(x) φ^0 + b(x)`` (eqs 4.9–4.11).

    ``A[:, t] = ∇w_t(x)``; ``b = ∇Φ(x; φ^0 = 0)``. Eq 4.12 is least squares in ``φ^0``
    through these.
    """
    centers, x = _check_x(centers, x)
    perp, A, par0 = _gradient_terms(centers, sigma, eta, x)
    return A, perp + par0


def trajectory_velocity(traj: jax.Array, dt: float) -> jax.Array:
    """``ζ̇`` by finite differences (second-order central inside, first-order at the ends,
    i.e. ``numpy.gradient``), ``(T, m) → (T, m)``."""
    traj = jnp.asarray(traj)
    if traj.ndim != 2 or traj.shape[0] < 2:
        raise ValueError(f"traj must have shape (T, m) with T >= 2, got {traj.shape}")
    return jnp.gradient(traj, dt, axis=0)


# ---------------------------------------------------------------------------------------------
# Exact constrained least squares: NNLS → LDP → LSI (Lawson & Hanson 1974, ch. 23)
# ---------------------------------------------------------------------------------------------


def nnls(A: jax.Array, b: jax.Array, maxiter: int | None = None
         ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``min ‖Ax − b‖ s.t. x ≥ 0`` by the Lawson–Hanson active-set method (jittable).

    Returns ``(x, ‖Ax − b‖, status)`` with ``status = 0`` on convergence (KKT: ``w = Aᵀ(b − Ax)
    ≤ tol`` off the passive set, passive-set least squares with ``x > 0`` on it) and ``−1`` if
    ``maxiter`` (default ``3n``) inner (step-back) iterations, or ``maxiter + n`` outer ones,
    were exhausted. This is the algorithm of ``scipy.optimize.nnls`` (normal equations on the
    passive set, the same iteration count and tolerance ``10·max(m, n)·eps`` scaled by
    ``max(1, max|AᵀA|)``), with fixed-shape masks in place of index sets so that it runs under
    ``jax.jit``/``jax.vmap``.
    """
    A = jnp.asarray(A)
    b = jnp.asarray(b)
    m, n = A.shape
    maxiter = 3 * n if maxiter is None else int(maxiter)
    dtype = A.dtype
    AtA = A.T @ A
    Atb = A.T @ b
    tol = 10.0 * max(m, n) * jnp.finfo(dtype).eps * jnp.maximum(jnp.max(jnp.abs(AtA)), 1.0)
    eye = jnp.eye(n, dtype=dtype)

    def passive_solve(P):
        both = P[:, None] & P[None, :]
        K = jnp.where(both, AtA, 0.0) + jnp.where(P, 0.0, 1.0)[:, None] * eye
        s = jnp.linalg.solve(K, jnp.where(P, Atb, 0.0))
        return jnp.where(P, s, 0.0)

    def inner_cond(state):
        _, s, P, it = state
        return (it < maxiter) & jnp.any(P & (s < 0))

    def inner_body(state):
        x, s, P, it = state
        bad = P & (s < 0)
        ratios = jnp.where(bad, x / jnp.where(bad, x - s, 1.0), jnp.inf)
        alpha = jnp.min(ratios)
        x = x + alpha * (s - x)
        P = P & (x > tol)
        return x, passive_solve(P), P, it + 1

    def outer_cond(state):
        _, w, P, it, outer = state
        return (it < maxiter) & (outer < maxiter + n) & jnp.any(~P & (w > tol))

    def outer_body(state):
        x, w, P, it, outer = state
        k = jnp.argmax(jnp.where(P, -jnp.inf, w))
        P = P.at[k].set(True)
        _, s, P, it = jax.lax.while_loop(inner_cond, inner_body, (x, passive_solve(P), P, it))
        return s, Atb - AtA @ s, P, it, outer + 1

    zero = jnp.asarray(0)
    state = (jnp.zeros(n, dtype), Atb, jnp.zeros(n, bool), zero, zero)
    x, _, _, it, outer = jax.lax.while_loop(outer_cond, outer_body, state)
    status = jnp.where((it >= maxiter) | (outer >= maxiter + n), -1, 0)
    return x, jnp.linalg.norm(A @ x - b), status


def lsi(C: jax.Array, d: jax.Array, G: jax.Array, h: jax.Array, maxiter: int | None = None
        ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``min ‖Cx − d‖ s.t. Gx ≥ h`` for ``C (r, n)`` of full column rank (jittable).

    Lawson & Hanson (1974) ch. 23: with ``C = QR``, ``z = Rx − Qᵀd`` turns the problem into the
    least-distance program ``min ‖z‖ s.t. (GR⁻¹) z ≥ h − GR⁻¹Qᵀd``; with ``E = [(GR⁻¹)ᵀ; ĥᵀ]``
    and ``f = e_{n+1}``, the NNLS solution ``u`` of ``min ‖Eu − f‖, u ≥ 0`` gives the residual
    ``ρ = Eu − f`` and ``z = −ρ_{1:n}/ρ_{n+1}``; ``ρ = 0`` means the constraints are
    inconsistent. Returns ``(x, feasible, nnls_status)``; equalities go through :func:`lsei`.
    """
    C = jnp.asarray(C)
    n = C.shape[1]
    Q, R = jnp.linalg.qr(C)                 # reduced: Q (r, n), R (n, n)
    qd = Q.T @ jnp.asarray(d)
    GRi = solve_triangular(R, jnp.asarray(G).T, trans="T", lower=False).T   # G R⁻¹ (p, n)
    h_hat = jnp.asarray(h) - GRi @ qd
    E = jnp.concatenate([GRi.T, h_hat[None, :]], axis=0)                    # (n+1, p)
    f = jnp.zeros(n + 1, C.dtype).at[n].set(1.0)
    # NNLS is invariant to positive column scaling; equilibrate the columns (helps the normal
    # equations NNLS solves on its passive set).
    norms = jnp.linalg.norm(E, axis=0)
    scale = jnp.where(norms > 0, 1.0 / jnp.where(norms > 0, norms, 1.0), 1.0)
    u, rnorm, status = nnls(E * scale, f, maxiter)
    u = u * scale
    rho = E @ u - f
    feasible = (rnorm > jnp.sqrt(jnp.finfo(C.dtype).eps) * 1e-3) & (rho[n] < 0)
    z = -rho[:n] / jnp.where(feasible, rho[n], -1.0)
    x = solve_triangular(R, z + qd, lower=False)
    return x, feasible, status


def lsei(C: jax.Array, d: jax.Array, E: jax.Array, e: jax.Array, G: jax.Array, h: jax.Array,
         maxiter: int | None = None) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``min ‖Cx − d‖ s.t. Ex = e, Gx ≥ h`` (``C`` of full column rank, ``Ex = e`` consistent).

    The equalities are eliminated exactly (Lawson & Hanson ch. 20): with the SVD
    ``E = U S Vᵀ``, the directions ``v_i`` of the numerically non-zero singular values
    (``s_i > max(m, n)·eps·s_1``) are fixed at ``x₀ = Σ_i v_i (u_iᵀe)/s_i`` and the rest are
    free, ``x = x₀ + N y``. A rank-deficient ``E`` (e.g. a straight-line trajectory, where both
    rows of the goal-stationarity constraint are parallel) is handled with fixed shapes: ``N``
    is ``V`` with the fixed columns zeroed and the matching ``y_i`` are pinned to 0 by unit rows
    added to the objective (they do not move ``x``). The remaining LSI goes to :func:`lsi`.
    Returns ``(x, feasible, nnls_status)``.
    """
    C = jnp.asarray(C)
    E = jnp.asarray(E)
    n = C.shape[1]
    U, sv, Vt = jnp.linalg.svd(E, full_matrices=True)       # U (k, k), sv (k,), Vt (n, n)
    k = sv.shape[0]
    fixed = sv > max(E.shape) * jnp.finfo(C.dtype).eps * jnp.max(sv)
    coef = jnp.where(fixed, (U.T @ jnp.asarray(e)) / jnp.where(fixed, sv, 1.0), 0.0)
    x0 = Vt[:k].T @ coef
    mask = jnp.concatenate([fixed, jnp.zeros(n - k, bool)])
    N = jnp.where(mask[None, :], 0.0, Vt.T)
    C_y = jnp.concatenate([C @ N, jnp.diag(mask.astype(C.dtype))], axis=0)
    d_y = jnp.concatenate([jnp.asarray(d) - C @ x0, jnp.zeros(n, C.dtype)])
    y, feasible, status = lsi(C_y, d_y, jnp.asarray(G) @ N, jnp.asarray(h) - jnp.asarray(G) @ x0,
                              maxiter)
    return x0 + N @ y, feasible, status


# ---------------------------------------------------------------------------------------------
# Fitting the bias terms (eq 4.12)
# ---------------------------------------------------------------------------------------------


GOAL_CONSTRAINTS = ("auto", "penalty", "none")


class FitInfo(NamedTuple):
    """Diagnostics of :func:`fit_biases`.

    * ``objective``: eq 4.12's objective ``J(φ^0)`` at the returned biases;
    * ``exact``: the biases solve eq 4.12 *with* the equality ``∇Φ(ζ_T) = 0`` (``"auto"`` mode
      only; otherwise ``False``);
    * ``feasible``: the equality can be met by monotone biases at all (the cone test; ``True``
      for ``goal_constraint="none"``);
    * ``goal_gradient``: ``‖∇Φ(ζ_T)‖`` at the returned biases;
    * ``status``: NNLS status of the solve that produced them (0 converged, −1 iteration limit).
    """

    objective: jax.Array
    exact: jax.Array
    feasible: jax.Array
    goal_gradient: jax.Array
    status: jax.Array


def _monotone_projection(phi: jax.Array) -> jax.Array:
    """``φ_t ← max(0, max_{s ≥ t} φ_s)``: non-increasing and ≥ 0 exactly (moves a feasible
    solution by round-off only)."""
    return jnp.maximum(jax.lax.cummax(phi, reverse=True), 0.0)


def _increments_to_biases(beta: jax.Array) -> jax.Array:
    """``φ_t = Σ_{k ≥ t} β_k`` (``φ = Uβ``, ``U`` upper-triangular ones)."""
    return jnp.cumsum(beta[::-1])[::-1]


def fit_biases(
    centers: jax.Array,
    velocities: jax.Array,
    sigma: float,
    eta: float,
    lam: float = 1e-3,
    goal_constraint: str = "auto",
    goal_weight: float = 1e4,
    maxiter: int | None = None,
) -> tuple[jax.Array, FitInfo]:
    """Bias terms ``φ^0 (T,)`` of eq 4.12 (see the module docstring); ``(biases, FitInfo)``.

    ``centers (T, m)`` is ``ζ`` (goal ``ζ_T``), ``velocities (T, m)`` is ``ζ̇``, ``lam = λ > 0``.
    The monotonicity constraints ``0 ≤ φ_T^0 ≤ … ≤ φ_1^0`` always hold exactly. The equality
    ``∇Φ(ζ_T) = 0`` is handled by ``goal_constraint``:

    * ``"auto"`` (default): eq 4.12 verbatim, solved exactly (:func:`lsei`), whenever that is
      possible and sound: the equality is attainable by monotone biases (an exact ``m × T``
      NNLS cone test) with biases no larger than 10× the penalised solution's, the LSEI
      converged, its solution meets the equality to ``1e-6`` relative, and enforcing it costs
      at most twice the penalised optimum ``J + goal_weight·‖∇Φ(ζ_T)‖²``. Otherwise
      (``info.exact`` is ``False``) the penalised solution below.
    * ``"penalty"``: ``min J(φ^0) + goal_weight·‖∇Φ(ζ_T)‖²`` over the monotone cone, an exact
      NNLS in the increments ``β_t = φ_t^0 − φ_{t+1}^0 ≥ 0``; well posed for every trajectory.
    * ``"none"``: the equality is dropped (an LSI).

    Why a fallback: monotone biases can only add goal gradients in the cone spanned by
    ``Σ_{t≤k} ∇w_t(ζ_T)`` (pointing back along the trajectory, with magnitude ∝ the kernel
    weight of those points at the goal). A trajectory curving into its goal (a circular arc)
    leaves a sideways ``∇Φ(ζ_T; 0)`` outside that cone: eq 4.12 is infeasible (CVX would say
    so). Measured on LASA (the DTW nominal of each of the 30 shapes, defaults σ = 0.03,
    η = 10, λ = 1e-3, when this was written): the equality is infeasible for 25 shapes; of the
    other 5 only Zshape is solved exactly; Angle reaches it only through points of kernel weight
    ~1e-5 at the goal (biases ~1e4), CShape's exact solve does not converge, and for JShape and
    heee exact stationarity costs 8–60× the penalised objective. ``"auto"`` returned converged
    fits for all 30, with ``‖∇Φ(ζ_T)‖ ≤ 0.02``. Jittable with ``goal_constraint`` and
    ``maxiter`` static.
    """
    if goal_constraint not in GOAL_CONSTRAINTS:
        raise ValueError(f"goal_constraint must be one of {GOAL_CONSTRAINTS}, "
                         f"got {goal_constraint!r}")
    centers = jnp.asarray(centers)
    velocities = jnp.asarray(velocities)
    if centers.ndim != 2 or velocities.shape != centers.shape:
        raise ValueError(f"centers and velocities must both be (T, m), got {centers.shape} and "
                         f"{velocities.shape}")
    if isinstance(lam, (int, float)) and not lam > 0:
        raise ValueError(f"lam must be > 0 (eq 4.12's λ makes the problem strictly convex), "
                         f"got {lam!r}")
    T, m = centers.shape
    dtype = centers.dtype
    if jnp.finfo(dtype).bits < 64:
        warnings.warn("fit_biases in float32 is not exact (NNLS solves normal equations); "
                      "enable jax_enable_x64 and pass float64 data", stacklevel=2)
    A, b = design_matrix(centers, sigma, eta, centers)                    # (T, m, T), (T, m)
    # (1/T) Σ_t [‖ζ̇_t + A_t φ + b_t‖² + λ φ_t²]  =  ‖Cφ − d‖²
    C = jnp.concatenate([A.reshape(T * m, T), jnp.sqrt(lam) * jnp.eye(T, dtype=dtype)],
                        axis=0) / jnp.sqrt(T)
    d = jnp.concatenate([-(velocities + b).reshape(T * m), jnp.zeros(T, dtype)]) / jnp.sqrt(T)
    # Monotone cone: φ_t − φ_{t+1} ≥ 0 (t < T), φ_T ≥ 0.
    G = jnp.eye(T, dtype=dtype) - jnp.eye(T, k=1, dtype=dtype)
    h = jnp.zeros(T, dtype)
    E, e = A[-1], -b[-1]                                   # ∇Φ(ζ_T) = Eφ − e
    # Goal gradients reachable by monotone biases: V = EU (column k = Σ_{t≤k} ∇w_t(ζ_T)).
    # Σ_t ∇w_t ≡ 0, so the last column (φ_T^0 moves no gradient) is exactly 0; its round-off,
    # like any column below round-off size, would otherwise read as a direction reachable with
    # an astronomically large bias.
    V = jnp.cumsum(E, axis=1)
    norms = jnp.linalg.norm(V, axis=0)
    keep = (norms > T * jnp.finfo(dtype).eps * jnp.max(norms)) & (jnp.arange(T) < T - 1)
    V = jnp.where(keep[None, :], V, 0.0)

    def penalty(_=None):
        root = jnp.sqrt(jnp.asarray(goal_weight, dtype))
        Cw = jnp.concatenate([jnp.cumsum(C, axis=1), root * V], axis=0)
        beta, _, st = nnls(Cw, jnp.concatenate([d, root * e]), maxiter)
        return _increments_to_biases(beta), st

    def goal_gradient(phi):
        return jnp.linalg.norm(E @ phi - e)

    def objective(phi):
        r = C @ phi - d
        return r @ r

    if goal_constraint == "none":
        phi, _, status = lsi(C, d, G, h, maxiter)
        phi, exact, feasible = _monotone_projection(phi), jnp.asarray(False), jnp.asarray(True)
    elif goal_constraint == "penalty":
        phi, status = penalty()
        phi, exact = _monotone_projection(phi), jnp.asarray(False)
        feasible = nnls(V, e)[1] <= 1e-8 * (1.0 + jnp.linalg.norm(e))
    else:
        phi_p, status_p = penalty()
        phi_p = _monotone_projection(phi_p)
        beta, gap, _ = nnls(V, e)
        feasible = gap <= 1e-8 * (1.0 + jnp.linalg.norm(e))
        bound = objective(phi_p) + goal_weight * goal_gradient(phi_p) ** 2
        # Attempt the exact LSEI only where the cone test's biases are of the scale of the
        # penalised ones (else the equality is met only by absurd biases, see the docstring).
        attempt = feasible & (jnp.sum(beta) <= 10.0 * jnp.maximum(jnp.max(phi_p), 1e-12))

        def try_exact(_):
            phi_x, ok, st = lsei(C, d, E, V @ beta, G, h, maxiter)
            phi_x = _monotone_projection(phi_x)
            good = (ok & (st == 0) & jnp.all(jnp.isfinite(phi_x))
                    & (goal_gradient(phi_x) <= 1e-6 * (1.0 + jnp.linalg.norm(e)))
                    & (objective(phi_x) <= 2.0 * bound + 1e-12))
            return good, phi_x, st

        exact, phi_x, status_x = jax.lax.cond(
            attempt, try_exact, lambda _: (jnp.asarray(False), phi_p, status_p), None)
        phi = jnp.where(exact, phi_x, phi_p)
        status = jnp.where(exact, status_x, status_p)
    info = FitInfo(objective=objective(phi), exact=exact, feasible=feasible,
                   goal_gradient=goal_gradient(phi), status=status)
    return phi, info


def fit_nominal_potential(
    trajectory: jax.Array,
    dt: float | None = None,
    *,
    velocities: jax.Array | None = None,
    sigma: float = 0.03,
    eta: float = 10.0,
    lam: float = 1e-3,
    goal_constraint: str = "auto",
    goal_weight: float = 1e4,
    offset: bool = True,
    maxiter: int | None = None,
) -> tuple[NominalPotential, FitInfo]:
    """The nominal-trajectory potential of a demonstration: eq 4.12's biases, then eq 4.9.

    ``trajectory (T, m)`` ends at the goal; ``ζ̇`` is ``velocities`` if given, else
    :func:`trajectory_velocity` with step ``dt``. ``sigma`` (``σ``, eq 4.9), ``eta`` (``η``,
    eq 4.11) and ``lam`` (``λ``, eq 4.12) are not given in the thesis; the defaults suit LASA's
    ``[−0.5, 0.5]²`` normalisation (σ a few sample spacings after ×4 downsampling, ``1/η`` a
    tenth of the workspace). ``goal_constraint``/``goal_weight``: see :func:`fit_biases`.
    ``offset=True`` subtracts ``Φ_4.9(ζ_T)`` so the goal has potential 0. Jittable with
    ``goal_constraint``, ``offset`` and ``maxiter`` static.
    """
    zeta = jnp.asarray(trajectory)
    if velocities is None:
        if dt is None:
            raise ValueError("give either dt (velocities by finite differences) or velocities")
        velocities = trajectory_velocity(zeta, dt)
    biases, info = fit_biases(zeta, velocities, sigma, eta, lam, goal_constraint=goal_constraint,
                              goal_weight=goal_weight, maxiter=maxiter)
    dtype = zeta.dtype
    p = NominalPotential(zeta, biases, jnp.asarray(sigma, dtype), jnp.asarray(eta, dtype), 0.0)
    if offset:
        p = dataclasses.replace(p, offset=raw_potential(p, zeta[-1]))
    return p, info


# ---------------------------------------------------------------------------------------------
# The nominal demonstration by DTW (§5.2.1)
# ---------------------------------------------------------------------------------------------


def select_nominal(demos: Sequence[Any]) -> tuple[int, np.ndarray]:
    """Index of the demonstration with the least mean DTW distance to the others (§5.2.1).

    ``demos`` is a sequence of ``(T_i, m)`` arrays (lengths may differ) or one ``(N, T, m)``
    array. Returns ``(index, mean_dtw (N,))`` with ``mean_dtw[i] = Σ_{j≠i} DTW(i, j)/(N − 1)``
    (:func:`mjxrmp.metrics.trajectory.dtw`, float64 NumPy); ties go to the lowest index. A single
    demonstration is its own nominal.
    """
    demos = [np.asarray(d, dtype=np.float64) for d in demos]
    n = len(demos)
    if n == 0:
        raise ValueError("select_nominal needs at least one demonstration")
    D = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            D[i, j] = D[j, i] = dtw(demos[i], demos[j])
    mean = D.sum(axis=1) / max(n - 1, 1)
    return int(np.argmin(mean)), mean


def select_nominal_jax(demos: jax.Array) -> tuple[jax.Array, jax.Array]:
    """JAX version of :func:`select_nominal` for equal-length demos ``(N, T, m)`` (jittable)."""
    demos = jnp.asarray(demos)
    if demos.ndim != 3:
        raise ValueError(f"demos must have shape (N, T, m), got {demos.shape}")
    n = demos.shape[0]
    D = jax.vmap(lambda a: jax.vmap(lambda b: dtw_jax(a, b))(demos))(demos)
    D = jnp.where(jnp.eye(n, dtype=bool), 0.0, D)
    mean = jnp.sum(D, axis=1) / max(n - 1, 1)
    return jnp.argmin(mean), mean


def fit_from_demonstrations(
    demos: Sequence[Any], dt: float, **kwargs: Any
) -> tuple[NominalPotential, FitInfo, int]:
    """§5.2.1 end to end: pick the DTW nominal of ``demos`` and fit its potential.

    ``kwargs`` go to :func:`fit_nominal_potential`. Returns ``(potential, info, index)``.
    """
    index, _ = select_nominal(demos)
    p, info = fit_nominal_potential(jnp.asarray(demos[index]), dt, **kwargs)
    return p, info, index
