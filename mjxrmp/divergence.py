"""Divergence guards of the trainers (docs/design.md §5.5): a non-finite loss or parameter stops a
run with :class:`DivergenceError`, whose one-line message names the trainer, the step, the run
and the first non-finite quantity, e.g. ``ATAC diverged at gradient step 1200 (seed 3):
critic_loss is nan``.

The checks read values that already reach the host (a chunk's losses) or reduce a parameter
tree to one flag on the device first (:func:`guard_finite_tree`), so a finite run pays one small
reduction per chunk and its results are unchanged: the checks only read.

* :func:`guard_finite_series` — per-step values ``{quantity: (runs, steps)}`` (a compiled
  chunk's metrics): the earliest non-finite step, over every run and quantity;
* :func:`guard_finite_tree` — a pytree (parameters), optionally with a leading run axis: the
  first non-finite leaf, named by its path.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

#: Exit status of a script whose training run diverged.
EXIT_DIVERGED = 3


class DivergenceError(FloatingPointError):
    """A training run produced a non-finite loss or parameter. Attributes: ``what`` (the
    trainer), ``unit`` and ``step`` (where), ``run`` (which member of a batched run, or None),
    ``quantity`` (the metric or the parameter's path), ``value`` (nan, inf or -inf) and
    ``note`` (what was kept, e.g. the last finite checkpoint; appended after ``; ``)."""

    def __init__(self, what: str, step: int, quantity: str, value: float, *,
                 unit: str = "step", run: str | None = None, note: str | None = None):
        self.what, self.step, self.quantity, self.value = what, int(step), quantity, value
        self.unit, self.run, self.note = unit, run, note
        where = "" if run is None else f" ({run})"
        tail = "" if note is None else f"; {note}"
        super().__init__(f"{what} diverged at {unit} {self.step}{where}: {quantity} is "
                         f"{float(value)}{tail}")

    def with_note(self, note: str) -> DivergenceError:
        """The same error with ``note`` appended to its message."""
        return DivergenceError(self.what, self.step, self.quantity, self.value, unit=self.unit,
                               run=self.run, note=note)


def _run_label(runs: Sequence[str] | None, index: int | None) -> str | None:
    """The label of run ``index``: ``runs[index]``, ``run <index>`` without labels, None for an
    unbatched value."""
    if index is None:
        return None
    return f"run {index}" if runs is None else str(runs[index])


def guard_finite_series(series: Mapping[str, Any], what: str, *, start: int = 0,
                        unit: str = "step", runs: Sequence[str] | None = None) -> None:
    """Raise :class:`DivergenceError` at the earliest step where a value of ``series``
    (``{quantity: (runs, steps)}``, step ``i`` of the array being ``unit start + i + 1``) is not
    finite; ties go to the first run, then the first quantity. ``runs`` labels the rows
    (default ``run <i>``). Nothing happens when every value is finite."""
    first: tuple[int, int, str, float] | None = None
    for name, values in series.items():
        bad = ~np.isfinite(np.asarray(values))
        if bad.ndim != 2:
            raise ValueError(f"series[{name!r}] must have shape (runs, steps), got {bad.shape}")
        if not bad.any():
            continue
        run_steps = np.where(bad.any(axis=1), bad.argmax(axis=1), bad.shape[1])
        run = int(np.argmin(run_steps))
        hit = (int(run_steps[run]), run, name, float(np.asarray(values)[run, run_steps[run]]))
        if first is None or hit[:2] < first[:2]:
            first = hit
    if first is not None:
        step, run, name, value = first
        raise DivergenceError(what, start + step + 1, name, value, unit=unit,
                              run=_run_label(runs, run))


@jax.jit
def all_finite(tree: Any) -> jax.Array:
    """Whether every floating leaf of ``tree`` is finite (one boolean on the device)."""
    flags = [jnp.all(jnp.isfinite(x)) for x in map(jnp.asarray, jax.tree.leaves(tree))
             if jnp.issubdtype(x.dtype, jnp.inexact)]
    return jnp.all(jnp.stack(flags)) if flags else jnp.asarray(True)


def first_nonfinite_leaf(tree: Any, *, batched: bool = False
                        ) -> tuple[str, float, int | None] | None:
    """``(path, value, run)`` of the first floating-point leaf of ``tree`` holding a NaN or
    inf (``path`` as ``jax.tree_util.keystr``, e.g. ``['actor']['Dense_0']['kernel']``; ``run``
    the index along the leading axis with ``batched``, else None), or None if all are finite.
    Searched on the host: no compilation per leaf shape."""
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        # A leaf's own dtype where it has one: np.result_type(jax.Array) is deprecated (jax 0.12).
        dtype = leaf.dtype if hasattr(leaf, "dtype") else np.result_type(leaf)
        if not jnp.issubdtype(dtype, jnp.inexact):
            continue
        values = np.asarray(leaf)
        flat = values.reshape((values.shape[0], -1) if batched else (1, -1))
        bad = ~np.isfinite(flat)
        if not bad.any():
            continue
        run = int(np.argmax(bad.any(axis=1)))
        return jax.tree_util.keystr(path), float(flat[run][bad[run]][0]), (
            run if batched else None)
    return None


def guard_finite_tree(tree: Any, what: str, step: int, *, unit: str = "step",
                      runs: Sequence[str] | None = None, prefix: str = "params",
                      batched: bool = False, finite: Any = None) -> None:
    """Raise :class:`DivergenceError` naming the first non-finite leaf of ``tree`` (its path
    after ``prefix``, e.g. ``params['actor']['Dense_0']['kernel']``) at ``unit step``. With
    ``batched`` every leaf has a leading run axis and the run is named too (``runs[i]``,
    default ``run <i>``). Integer and key leaves are skipped. The tree is reduced to one flag
    on the device first (:func:`all_finite`; ``finite``: that flag, already dispatched by the
    caller); only a non-finite tree is searched on the host."""
    if bool(all_finite(tree) if finite is None else finite):
        return
    found = first_nonfinite_leaf(tree, batched=batched)
    if found is not None:
        path, value, run = found
        raise DivergenceError(what, step, prefix + path, value, unit=unit,
                              run=_run_label(runs, run))


__all__ = ["EXIT_DIVERGED", "DivergenceError", "all_finite", "first_nonfinite_leaf",
           "guard_finite_series", "guard_finite_tree"]
