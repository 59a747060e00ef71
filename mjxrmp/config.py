"""Configuration: frozen parameter dataclasses that are also pytrees, and the one set of
validators every config in the project uses (docs/design.md §6).

Leaf parameters are frozen (hashable, usable as static configuration) and at the same time JAX
pytrees, so a loss can be differentiated with respect to them. Construction validates concrete
values (Python and numpy numbers, concrete ``jax.Array``; traced values pass, since parameters
are differentiated): a non-numeric, non-finite or negative value raises a ``ValueError`` naming
the field; fields marked ``positive`` (a formula divides by them) also refuse zero; fields
marked ``signed`` (joint positions, limits) accept any sign.

:func:`parse_field` and :func:`parse_assignments` turn command-line text (``--set NAME=VALUE``)
into a field's value by the field's declared type.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Iterable, Sequence
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

T = TypeVar("T")


def signed(default: Any) -> Any:
    """A dataclass field that may hold negative values (e.g. joint angles, lower limits)."""
    if isinstance(default, (list, tuple)):
        return dataclasses.field(default=tuple(default), metadata={"signed": True})
    return dataclasses.field(default=default, metadata={"signed": True})


def positive(default: Any) -> Any:
    """A dataclass field that must be ``> 0`` because a formula divides by it (length scales,
    regularising epsilons): zero is refused as well as negative values."""
    return dataclasses.field(default=default, metadata={"positive": True})


def _is_traced(value: Any) -> bool:
    items = value if isinstance(value, tuple | list) else (value,)
    return any(isinstance(v, jax.core.Tracer) for v in items)


def _shown(value: Any, arr: np.ndarray, bad: np.ndarray) -> str:
    """``value`` for a one-line message: itself when scalar, else its first bad entry."""
    if arr.ndim == 0:
        return repr(value) if type(value) in (int, float) else repr(arr.item())
    index = tuple(int(i) for i in np.argwhere(bad)[0])
    return f"{arr[index].item()!r} at index {index}"


def _numbers(name: str, value: Any) -> np.ndarray:
    """``value`` as a float64 array, or a ``ValueError`` naming ``name`` if it is not numeric."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        arr = np.asarray(None)
    if arr.dtype == np.bool_ or not jnp.issubdtype(arr.dtype, jnp.number):
        raise ValueError(f"{name} must be a number or an array of numbers, got {value!r}")
    return arr.astype(np.float64)


def _validate(obj: Any) -> None:
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if _is_traced(value):
            continue
        name = f"{type(obj).__name__}.{f.name}"
        arr = _numbers(name, value)
        bad = ~np.isfinite(arr)
        if np.any(bad):
            raise ValueError(f"{name} must be finite, got {_shown(value, arr, bad)}")
        if f.metadata.get("signed"):
            continue
        if f.metadata.get("positive") and np.any(arr <= 0):
            raise ValueError(f"{name} must be >= 0 and non-zero (a formula divides by it), got "
                             f"{_shown(value, arr, arr <= 0)}")
        if np.any(arr < 0):
            raise ValueError(f"{name} must be >= 0, got {_shown(value, arr, arr < 0)}")


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


def check_bool(value: Any, name: str, *, allow_none: bool = False) -> bool | None:
    """``value`` if it is a ``bool`` (``None`` passes with ``allow_none``)."""
    if value is None and allow_none:
        return None
    if not isinstance(value, bool | np.bool_):
        raise ValueError(f"{name} must be a bool{' or None' if allow_none else ''}, "
                         f"got {value!r}")
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


# --------------------------------------------------------------------------------------------
# Command-line text → field values, by the field's declared type (``--set NAME=VALUE``).

_TRUE, _FALSE = ("true", "1"), ("false", "0")


def _members(tp: Any) -> tuple[Any, ...] | None:
    """The member types of a union annotation (``X | None``, ``Optional[X]``), else ``None``."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return typing.get_args(tp)
    return None


def _describe(tp: Any) -> str:
    """What text a field of type ``tp`` accepts, for error messages."""
    members, args = _members(tp), typing.get_args(tp)
    if members is not None:
        kinds = [_describe(m) for m in members if m is not type(None)]
        return " or ".join(kinds + (["none"] if type(None) in members else []))
    if typing.get_origin(tp) is typing.Literal:
        return f"one of {list(args)}"
    if typing.get_origin(tp) is tuple:
        if args[-1:] == (Ellipsis,):
            return f"comma-separated values, each {_describe(args[0])}"
        return f"{len(args)} comma-separated values ({', '.join(map(_describe, args))})"
    return {bool: "a boolean (true, false, 1 or 0)", int: "an integer", float: "a number",
            str: "a string"}.get(tp, f"a {getattr(tp, '__name__', tp)} (not settable from text)")


def _parse_text(tp: Any, text: str) -> Any:
    """``text`` as a value of type ``tp``; a bare ``ValueError`` when it is not one."""
    members, args = _members(tp), typing.get_args(tp)
    if members is not None:
        if type(None) in members and text.strip().lower() == "none":
            return None
        for member in (m for m in members if m is not type(None)):
            try:
                return _parse_text(member, text)
            except ValueError:
                continue
        raise ValueError
    if typing.get_origin(tp) is typing.Literal:
        matches = [c for c in args if str(c) == text]
        if not matches:
            raise ValueError
        return matches[0]
    if typing.get_origin(tp) is tuple:
        items = text.split(",") if text.strip() else []
        if args[-1:] == (Ellipsis,):
            return tuple(_parse_text(args[0], t) for t in items)
        if len(items) != len(args):
            raise ValueError
        return tuple(_parse_text(a, t) for a, t in zip(args, items, strict=True))
    if tp is bool:
        word = text.strip().lower()
        if word not in _TRUE + _FALSE:
            raise ValueError
        return word in _TRUE
    if tp in (int, float, str):
        return tp(text)
    raise ValueError


def parse_field(cls: type, name: str, text: str) -> Any:
    """``text`` parsed by the declared type of dataclass field ``cls.name`` (resolved with
    :func:`typing.get_type_hints`): ``str``, ``int``, ``float``, ``bool`` (``true``/``false``/
    ``1``/``0``, any case), ``X | None`` (``none``), ``Literal[...]`` and tuples
    (comma-separated; empty text is the empty tuple). Raises a ``ValueError`` naming the field
    and the expected type."""
    hints = typing.get_type_hints(cls)
    fields = sorted(f.name for f in dataclasses.fields(cls))
    if name not in fields:
        raise ValueError(f"unknown {cls.__name__} field {name!r}; valid fields are {fields}")
    tp = hints[name]
    try:
        return _parse_text(tp, text)
    except ValueError:
        raise ValueError(f"{cls.__name__}.{name} expects {_describe(tp)}, got {text!r}") from None


def parse_assignments(cls: type, items: Sequence[str], option: str = "--set") -> dict[str, Any]:
    """``["name=value", …]`` → ``{name: value}`` typed by :func:`parse_field`; errors start
    with ``option`` and the offending item."""
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"{option} expects NAME=VALUE, got {item!r}")
        name, text = item.split("=", 1)
        try:
            out[name] = parse_field(cls, name, text)
        except ValueError as e:
            raise ValueError(f"{option} {item}: {e}") from None
    return out
