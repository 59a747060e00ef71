"""Which MuJoCo pipeline stages the reaching environments run (docs/design.md §5.8).

Neither robot model has contacts or equality constraints (every geom has ``contype =
conaffinity = 0``) and the environments keep the joints inside their ranges by clipping the
servo's position target (:mod:`envs.reaching`), so MuJoCo's constraint pipeline has no work
that changes the motion; yet under MJX it is a large part of a control step (building the
constraint rows and running the solver's warm start, and, wherever a Franka joint touches a
limit, solver iterations with a 50-step line search for every environment of the batch).
:func:`set_constraint_stages` switches the whole pipeline off or back on.

:func:`substep_unroll` says how the physics substeps of a control step are looped
(docs/design.md §5.9): written out one after the other on a GPU, where a loop's iteration costs
kernel launches and copies of the whole simulation state, a loop elsewhere.

:func:`written_out_mass_solves` has MuJoCo-MJX factor and solve with the mass matrix through
:mod:`mjxrmp.core.linalg`'s written-out Cholesky instead of the library's (docs/design.md §5.10).
"""

from __future__ import annotations

import contextlib
import copy
from collections.abc import Iterator

import jax
import jax.scipy.linalg
import mujoco

from mjxrmp.core import linalg

#: The ``mjtDisableBit`` flags of the constraint pipeline: the constraint solver itself and the
#: contact, equality, friction-loss and joint-limit rows.
CONSTRAINT_STAGES = ("mjDSBL_CONSTRAINT", "mjDSBL_CONTACT", "mjDSBL_EQUALITY",
                     "mjDSBL_FRICTIONLOSS", "mjDSBL_LIMIT")

__all__ = ["CONSTRAINT_STAGES", "constraint_stages_on", "set_constraint_stages", "substep_unroll",
           "written_out_mass_solves"]


def _mask() -> int:
    mask = 0
    for flag in CONSTRAINT_STAGES:
        mask |= int(getattr(mujoco.mjtDisableBit, flag))
    return mask


def set_constraint_stages(mj_model: mujoco.MjModel, on: bool) -> mujoco.MjModel:
    """A copy of ``mj_model`` with MuJoCo's constraint pipeline (:data:`CONSTRAINT_STAGES`)
    enabled (``on=True``: the model as its MJCF generates it) or disabled."""
    m = copy.deepcopy(mj_model)
    if on:
        m.opt.disableflags &= ~_mask()
    else:
        m.opt.disableflags |= _mask()
    return m


def constraint_stages_on(mj_model: mujoco.MjModel) -> bool:
    """Whether every stage of :data:`CONSTRAINT_STAGES` is enabled in ``mj_model``."""
    return not (int(mj_model.opt.disableflags) & _mask())


def gpu_default(value: bool | None) -> bool:
    """``value``, or where it is None whether JAX's default backend is a GPU: the default of the
    launch-level options that pay on a GPU and cost compile time on a CPU (§5.9, §5.10)."""
    return jax.default_backend() == "gpu" if value is None else value


def substep_unroll(substeps: int, unroll: bool | None) -> int:
    """The ``lax.scan`` unroll of ``substeps`` physics substeps: all of them when ``unroll``
    (default None: when JAX's default backend is a GPU), else 1. Unrolling changes neither the
    operations nor their order, only how they are launched (docs/design.md §5.9)."""
    return substeps if gpu_default(unroll) else 1


@contextlib.contextmanager
def written_out_mass_solves(on: bool = True) -> Iterator[None]:
    """While tracing inside it (``on``), ``jax.scipy.linalg.cho_factor``/``cho_solve`` are
    :func:`mjxrmp.core.linalg.cho_factor`/:func:`~mjxrmp.core.linalg.cho_solve`: MJX's dense
    mass-matrix factorisations and solves (two of each per ``mjx.step`` under ``implicitfast``)
    become elementwise arithmetic XLA fuses, instead of batched cuSOLVER/cuBLAS calls with gaps
    between them. The same factorisation up to rounding (docs/design.md §5.10); a compiled
    program is unaffected by leaving the context. Not for threads tracing at the same time."""
    if not on:
        yield
        return
    module = jax.scipy.linalg
    saved = module.cho_factor, module.cho_solve
    module.cho_factor, module.cho_solve = linalg.cho_factor, linalg.cho_solve
    try:
        yield
    finally:
        module.cho_factor, module.cho_solve = saved
