"""Nominal-trajectory potential (thesis §4.3.1, eqs 4.8–4.11).

Given a nominal trajectory ``ζ = (ζ_t)_{t=1}^T`` ending at the goal, the potential is a convex
combination of potential elements centred on the trajectory points (eq 4.9)::

    Φ(x) = Σ_t w_t(x) φ_t(x),   w_t(x) = k(x, ζ_t) / Σ_t' k(x, ζ_t'),
    k(x, ζ_t) = exp(−‖x − ζ_t‖² / (2σ²)),   φ_t(x) = φ_t^⊥(x) + φ_t^0,                   (4.9)

with the attractive element of Cheng et al. (2018) (eq 4.11)::

    φ_t^⊥(x) = (1/η) log(e^{η r_t} + e^{−η r_t}),  r_t = ‖x − ζ_t‖,
    ∇φ_t^⊥(x) = s_η(r_t) (x − ζ_t)/r_t,           s_η(r) = tanh(η r),                    (4.11)

and scalar bias terms ``φ_t^0 ≥ 0`` that decrease monotonically along the trajectory, fitted by
eq 4.12 (:mod:`mjxrmp.learned.nominal_fit`).

Readings of the typeset equations (stated because the text is ambiguous or has typos):

* **Goal frame.** Eq 4.8 asks for ``ζ_T = 0`` and the constraint of eq 4.12 is ``∇Φ(0) = 0``.
  Here the trajectory may be given in any frame: the goal is ``ζ_T`` and the constraint is
  ``∇Φ(ζ_T) = 0``, which is eq 4.12 after the translation ``x ↦ x − ζ_T``.
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
  ``offset=False`` in :func:`mjxrmp.learned.nominal_fit.fit_nominal_potential` keeps
  ``offset = 0`` (eq 4.9 verbatim).

``∇Φ(x; φ^0) = A(x) φ^0 + b(x)`` is affine in the biases with ``A(x)[:, t] = ∇w_t(x)``
(:func:`design_matrix`), which makes eq 4.12 a least-squares problem.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from mjxrmp.config import check_float, param_dataclass

__all__ = [
    "NominalPotential",
    "attractor_element",
    "design_matrix",
    "kernel_weights",
    "nominal_potential",
    "nominal_potential_gradient",
    "nominal_potential_gradient_parts",
    "raw_potential",
    "trajectory_velocity",
]


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
            if isinstance(value, int | float):
                check_float(value, f"NominalPotential.{name}")
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
