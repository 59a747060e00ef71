"""Fitting the nominal-trajectory potential to a demonstration (thesis eq 4.12, §5.2.1).

**The bias terms (eq 4.12).** The potential of :mod:`mjxrmp.learned.nominal` carries scalar
biases ``φ_t^0 ≥ 0`` that decrease monotonically along the trajectory, fitted by the
constrained least-squares problem::

    min_{φ^0}  (1/T) Σ_t [ ‖ζ̇_t + ∇Φ(ζ_t; φ^0)‖² + λ (φ_t^0)² ]
    s.t.       0 ≤ φ_T^0 ≤ φ_{t+1}^0 ≤ φ_t^0   (t = 1 … T−1),     ∇Φ(ζ_T) = 0.             (4.12)

The regulariser ``λ‖φ_t^0‖²`` carries the summation index ``t``, so it is read as inside the
mean: ``(1/T)Σ_t λ(φ_t^0)² = (λ/T)‖φ^0‖²``. The goal is ``ζ_T`` (eq 4.12 after the translation
``x ↦ x − ζ_T``, see :mod:`mjxrmp.learned.nominal`).

``∇Φ(x; φ^0) = A(x) φ^0 + b(x)`` is affine in the biases
(:func:`mjxrmp.learned.nominal.design_matrix`), so eq 4.12 is a strictly convex least-squares
problem with linear inequality and equality constraints, solved exactly by
:func:`mjxrmp.learned.lsq.lsei` / :func:`~mjxrmp.learned.lsq.lsi` /
:func:`~mjxrmp.learned.lsq.nnls`. The monotone constraints always hold bit-exactly (a final
reverse running maximum clipped at 0 moves a solution by round-off only).

The equality ``∇Φ(ζ_T) = 0`` is the delicate part: it can be infeasible for monotone biases (a
trajectory curving into its goal, as most LASA demonstrations do), and where attainable it can
demand absurd biases or a much worse fit. :func:`fit_biases` therefore tests attainability
exactly, solves eq 4.12 verbatim when that is sound (``info.exact``), and otherwise minimises
``J + goal_weight·‖∇Φ(ζ_T)‖²`` over the monotone cone (an exact NNLS), see its docstring.

Everything is ``jax.jit``-able (``lax.while_loop``); fit with ``jax_enable_x64`` (float32 loses
the exactness). Cost: each NNLS takes at most ``3T`` active-set steps with an ``O(T³)`` solve
each, so keep ``T`` to a few hundred (LASA's 235 samples fit in about a second on a CPU).

**Nominal demonstration (§5.2.1).** :func:`select_nominal` returns the demonstration with the
least mean DTW distance (:func:`mjxrmp.metrics.warping.dtw`) to the other demonstrations; ties
go to the lowest index. :func:`fit_from_demonstrations` chains the two steps.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjxrmp.learned.lsq import lsei, lsi, nnls
from mjxrmp.learned.nominal import (
    NominalPotential,
    design_matrix,
    raw_potential,
    trajectory_velocity,
)
from mjxrmp.metrics.warping import dtw, dtw_jax

__all__ = [
    "GOAL_CONSTRAINTS",
    "FitInfo",
    "fit_biases",
    "fit_from_demonstrations",
    "fit_nominal_potential",
    "select_nominal",
    "select_nominal_jax",
]

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


class _Problem(NamedTuple):
    """Eq 4.12 as ``min ‖Cφ − d‖ s.t. Gφ ≥ h``, with the goal gradient ``∇Φ(ζ_T) = Eφ − e``
    and ``V``, the goal gradients reachable by monotone biases (one column per increment)."""

    C: jax.Array
    d: jax.Array
    G: jax.Array
    h: jax.Array
    E: jax.Array
    e: jax.Array
    V: jax.Array

    def objective(self, phi: jax.Array) -> jax.Array:
        """Eq 4.12's objective ``J(φ^0) = ‖Cφ − d‖²``."""
        r = self.C @ phi - self.d
        return r @ r

    def goal_gradient(self, phi: jax.Array) -> jax.Array:
        """``‖∇Φ(ζ_T)‖`` for biases ``phi``."""
        return jnp.linalg.norm(self.E @ phi - self.e)


def _check_fit_args(centers, velocities, lam, goal_constraint) -> tuple[jax.Array, jax.Array]:
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
    return centers, velocities


def _reachable_goal_gradients(E: jax.Array) -> jax.Array:
    """``V = EU`` (column ``k`` = ``Σ_{t≤k} ∇w_t(ζ_T)``): goal gradients of monotone biases.

    ``Σ_t ∇w_t ≡ 0``, so the last column (``φ_T^0`` moves no gradient) is exactly 0; its
    round-off, like any column below round-off size, would otherwise read as a direction
    reachable with an astronomically large bias.
    """
    T = E.shape[1]
    V = jnp.cumsum(E, axis=1)
    norms = jnp.linalg.norm(V, axis=0)
    keep = (norms > T * jnp.finfo(E.dtype).eps * jnp.max(norms)) & (jnp.arange(T) < T - 1)
    return jnp.where(keep[None, :], V, 0.0)


def _least_squares_problem(centers, velocities, sigma, eta, lam) -> _Problem:
    """Eq 4.12 in matrix form (:class:`_Problem`) for the trajectory ``centers``."""
    T, m = centers.shape
    dtype = centers.dtype
    A, b = design_matrix(centers, sigma, eta, centers)                    # (T, m, T), (T, m)
    # (1/T) Σ_t [‖ζ̇_t + A_t φ + b_t‖² + λ φ_t²]  =  ‖Cφ − d‖²
    C = jnp.concatenate([A.reshape(T * m, T), jnp.sqrt(lam) * jnp.eye(T, dtype=dtype)],
                        axis=0) / jnp.sqrt(T)
    d = jnp.concatenate([-(velocities + b).reshape(T * m), jnp.zeros(T, dtype)]) / jnp.sqrt(T)
    # Monotone cone: φ_t − φ_{t+1} ≥ 0 (t < T), φ_T ≥ 0.
    G = jnp.eye(T, dtype=dtype) - jnp.eye(T, k=1, dtype=dtype)
    E, e = A[-1], -b[-1]                                   # ∇Φ(ζ_T) = Eφ − e
    return _Problem(C, d, G, jnp.zeros(T, dtype), E, e, _reachable_goal_gradients(E))


def _cone_test(prob: _Problem) -> tuple[jax.Array, jax.Array]:
    """``(β, feasible)``: the exact NNLS ``min ‖Vβ − e‖, β ≥ 0`` and whether it reaches ``e``
    (``∇Φ(ζ_T) = 0`` is attainable by monotone biases)."""
    beta, gap, _ = nnls(prob.V, prob.e)
    return beta, gap <= 1e-8 * (1.0 + jnp.linalg.norm(prob.e))


def _penalised(prob: _Problem, goal_weight: float, maxiter: int | None
               ) -> tuple[jax.Array, jax.Array]:
    """``min J + goal_weight·‖∇Φ(ζ_T)‖²`` over the monotone cone: an NNLS in the increments
    ``β_t = φ_t^0 − φ_{t+1}^0``. Returns the monotone biases and the NNLS status."""
    root = jnp.sqrt(jnp.asarray(goal_weight, prob.C.dtype))
    Cw = jnp.concatenate([jnp.cumsum(prob.C, axis=1), root * prob.V], axis=0)
    beta, _, status = nnls(Cw, jnp.concatenate([prob.d, root * prob.e]), maxiter)
    return _monotone_projection(_increments_to_biases(beta)), status


def _exact_if_sound(prob: _Problem, goal_weight: float, maxiter: int | None):
    """``goal_constraint="auto"``: ``(biases, exact, feasible, status)``, the exact LSEI of
    eq 4.12 where it is attainable and sound (see :func:`fit_biases`), else the penalised fit."""
    phi_p, status_p = _penalised(prob, goal_weight, maxiter)
    beta, feasible = _cone_test(prob)
    bound = prob.objective(phi_p) + goal_weight * prob.goal_gradient(phi_p) ** 2
    # Attempt the exact LSEI only where the cone test's biases are of the scale of the
    # penalised ones (else the equality is met only by absurd biases, see fit_biases).
    attempt = feasible & (jnp.sum(beta) <= 10.0 * jnp.maximum(jnp.max(phi_p), 1e-12))
    tol = 1e-6 * (1.0 + jnp.linalg.norm(prob.e))

    def try_exact(_):
        phi_x, ok, st = lsei(prob.C, prob.d, prob.E, prob.V @ beta, prob.G, prob.h, maxiter)
        phi_x = _monotone_projection(phi_x)
        good = (ok & (st == 0) & jnp.all(jnp.isfinite(phi_x))
                & (prob.goal_gradient(phi_x) <= tol)
                & (prob.objective(phi_x) <= 2.0 * bound + 1e-12))
        return good, phi_x, st

    exact, phi_x, status_x = jax.lax.cond(
        attempt, try_exact, lambda _: (jnp.asarray(False), phi_p, status_p), None)
    return (jnp.where(exact, phi_x, phi_p), exact, feasible,
            jnp.where(exact, status_x, status_p))


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
    centers, velocities = _check_fit_args(centers, velocities, lam, goal_constraint)
    if jnp.finfo(centers.dtype).bits < 64:
        warnings.warn("fit_biases in float32 is not exact (NNLS solves normal equations); "
                      "enable jax_enable_x64 and pass float64 data", stacklevel=2)
    prob = _least_squares_problem(centers, velocities, sigma, eta, lam)
    if goal_constraint == "none":
        phi, _, status = lsi(prob.C, prob.d, prob.G, prob.h, maxiter)
        phi, exact, feasible = _monotone_projection(phi), jnp.asarray(False), jnp.asarray(True)
    elif goal_constraint == "penalty":
        phi, status = _penalised(prob, goal_weight, maxiter)
        exact, feasible = jnp.asarray(False), _cone_test(prob)[1]
    else:
        phi, exact, feasible, status = _exact_if_sound(prob, goal_weight, maxiter)
    info = FitInfo(objective=prob.objective(phi), exact=exact, feasible=feasible,
                   goal_gradient=prob.goal_gradient(phi), status=status)
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
    :func:`mjxrmp.learned.nominal.trajectory_velocity` with step ``dt``. ``sigma`` (``σ``,
    eq 4.9), ``eta`` (``η``, eq 4.11) and ``lam`` (``λ``, eq 4.12) are not given in the thesis;
    the defaults suit LASA's ``[−0.5, 0.5]²`` normalisation (σ a few sample spacings after ×4
    downsampling, ``1/η`` a tenth of the workspace). ``goal_constraint``/``goal_weight``: see
    :func:`fit_biases`. ``offset=True`` subtracts ``Φ_4.9(ζ_T)`` so the goal has potential 0.
    Jittable with ``goal_constraint``, ``offset`` and ``maxiter`` static.
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


def select_nominal(demos: Sequence[Any]) -> tuple[int, np.ndarray]:
    """Index of the demonstration with the least mean DTW distance to the others (§5.2.1).

    ``demos`` is a sequence of ``(T_i, m)`` arrays (lengths may differ) or one ``(N, T, m)``
    array. Returns ``(index, mean_dtw (N,))`` with ``mean_dtw[i] = Σ_{j≠i} DTW(i, j)/(N − 1)``
    (:func:`mjxrmp.metrics.warping.dtw`, float64 NumPy); ties go to the lowest index. A single
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
