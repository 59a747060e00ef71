"""Configuration: frozen parameter dataclasses that are also pytrees, and the one set of
validators every config in the project uses (docs/design.md §6).

Leaf parameters are frozen (hashable, usable as static configuration) and at the same time JAX
pytrees, so a loss can be differentiated with respect to them. Construction validates concrete
values: a negative gain or length scale raises a ``ValueError`` naming the field; fields marked
``signed`` (joint positions, limits) accept any sign.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from typing import Any, TypeVar

import jax
import numpy as np

T = TypeVar("T")


def signed(default: Any) -> Any:
    """A dataclass field that may hold negative values (e.g. joint angles, lower limits)."""
    if isinstance(default, (list, tuple)):
        return dataclasses.field(default=tuple(default), metadata={"signed": True})
    return dataclasses.field(default=default, metadata={"signed": True})


def _is_concrete(value: Any) -> bool:
    if isinstance(value, (int, float, np.ndarray, np.generic)):
        return True
    if isinstance(value, tuple):
        return all(isinstance(v, (int, float, np.generic)) for v in value)
    return False


def _validate(obj: Any) -> None:
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if f.metadata.get("signed") or not _is_concrete(value):
            continue
        arr = np.asarray(value, dtype=np.float64)
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{type(obj).__name__}.{f.name} must be finite, got {value!r}")
        if np.any(arr < 0):
            raise ValueError(f"{type(obj).__name__}.{f.name} must be >= 0, got {value!r}")


def param_dataclass(cls: type[T]) -> type[T]:
    """Make ``cls`` a frozen, validated dataclass registered as a JAX pytree (all fields data)."""
    user_post_init = getattr(cls, "__post_init__", None)

    def __post_init__(self: Any) -> None:
        _validate(self)
        if user_post_init is not None:
            user_post_init(self)

    # Set before the dataclass transform so the generated __init__ calls it.
    cls.__post_init__ = __post_init__
    cls = dataclasses.dataclass(frozen=True)(cls)
    names = tuple(f.name for f in dataclasses.fields(cls))

    def flatten(obj: Any) -> tuple[tuple[Any, ...], None]:
        return tuple(getattr(obj, n) for n in names), None

    def unflatten(_: None, children: tuple[Any, ...]) -> Any:
        obj = object.__new__(cls)
        for n, c in zip(names, children, strict=True):
            object.__setattr__(obj, n, c)
        return obj

    jax.tree_util.register_pytree_node(cls, flatten, unflatten)
    return cls


# --------------------------------------------------------------------------------------------
# Validators for configuration fields: each returns the value in its canonical Python type or
# raises ValueError naming the field (``name``, e.g. "PPOConfig.num_envs") and what was expected.


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_)


def check_int(value: Any, name: str, minimum: int = 1) -> int:
    """``value`` as an ``int`` if it is an integer (not a bool) ``>= minimum``."""
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | np.integer) or (
            value < minimum):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def check_float(value: Any, name: str, *, allow_zero: bool = False) -> float:
    """``value`` as a ``float`` if it is a finite number ``> 0`` (``>= 0`` with ``allow_zero``)."""
    if not _is_number(value) or not math.isfinite(value) or value < 0 or (
            value == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be a finite number {bound}, got {value!r}")
    return float(value)


def check_fraction(value: Any, name: str, *, closed: bool = False,
                   allow_zero: bool = False) -> float:
    """``value`` as a ``float`` if it lies in ``(0, 1)`` (``(0, 1]`` when ``closed``, ``[0, …``
    with ``allow_zero``)."""
    ok = _is_number(value) and (value >= 0.0 if allow_zero else value > 0.0) and (
        value <= 1.0 if closed else value < 1.0)
    if not ok:
        interval = f"{'[' if allow_zero else '('}0, 1{']' if closed else ')'}"
        raise ValueError(f"{name} must lie in {interval}, got {value!r}")
    return float(value)


def check_bool(value: Any, name: str) -> bool:
    """``value`` if it is a ``bool``."""
    if not isinstance(value, bool | np.bool_):
        raise ValueError(f"{name} must be a bool, got {value!r}")
    return bool(value)


def check_choice(value: Any, name: str, choices: Iterable[Any]) -> Any:
    """``value`` if it is one of ``choices``."""
    choices = tuple(choices)
    if value not in choices:
        raise ValueError(f"{name} must be one of {list(choices)}, got {value!r}")
    return value


def check_finite(value: Any, name: str, *, allow_none: bool = False) -> float | None:
    """``value`` as a ``float`` if it is a finite number of any sign (``None`` passes with
    ``allow_none``)."""
    if value is None and allow_none:
        return None
    if not _is_number(value) or not math.isfinite(value):
        extra = " or None" if allow_none else ""
        raise ValueError(f"{name} must be a finite number{extra}, got {value!r}")
    return float(value)


def check_sizes(value: Any, name: str, *, allow_empty: bool = False,
                require_tuple: bool = False) -> tuple[int, ...]:
    """``value`` as a tuple of positive integers (network hidden sizes); ``require_tuple``
    refuses other sequences (a hashable config field must already be a tuple)."""
    kind = tuple if require_tuple else Sequence
    if isinstance(value, str | bytes) or not isinstance(value, kind) or (
            len(value) == 0 and not allow_empty):
        what = "tuple" if require_tuple else "sequence"
        size = "" if allow_empty else "non-empty "
        raise ValueError(f"{name} must be a {size}{what} of positive integers, got {value!r}")
    return tuple(check_int(h, f"{name}[{i}]") for i, h in enumerate(value))


def check_parts(config: Any, **parts: type) -> None:
    """Each field ``name`` of a composite ``config`` must be an instance of ``parts[name]``."""
    for name, cls in parts.items():
        value = getattr(config, name)
        if not isinstance(value, cls):
            raise ValueError(f"{type(config).__name__}.{name} must be a {cls.__name__}, got "
                             f"{type(value).__name__}")
