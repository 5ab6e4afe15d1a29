"""Build a config dataclass from untyped values (``session.json``), checking every field's type.

JSON has no tuples and no distinction between a stage's int and float settings, and a
string where a number belongs would otherwise fail later as a bare ``TypeError`` from a
comparison, naming no field. ``build_config`` checks each value against the field's type
hint before the dataclass runs its own range checks, and names the offending key path:

    stage_config.physics.floor_solref[1] must be float, got 'stiff' (str)

Accepted: ``bool`` only for bool fields; any integer (not bool) for int fields; any real
number (not bool) for float fields; ``str``; ``None`` where the hint allows it; a value of
a ``Literal``; a list or tuple for ``tuple[...]`` / ``list[...]`` fields (returned as the
hinted container, so the config hashes the same either way); a JSON object for
``dict[str, ...]`` and for a nested config dataclass (built recursively). Other hints
(``Any``, arrays, paths) are passed through for the dataclass to check.
"""

from __future__ import annotations

import dataclasses
import numbers
import types
import typing
from collections.abc import Mapping
from typing import Any, Literal, TypeVar

T = TypeVar("T")


def _got(v: Any) -> str:
    return f"got {v!r} ({type(v).__name__})"


def _describe(hint: Any) -> str:
    origin = typing.get_origin(hint)
    if origin is Literal:
        return f"one of {list(typing.get_args(hint))}"
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_describe(a) for a in typing.get_args(hint))
    if hint is type(None):
        return "null"
    return getattr(hint, "__name__", str(hint))


def _coerce(v: Any, hint: Any, path: str) -> Any:
    """``v`` checked against ``hint`` (containers converted to the hinted kind)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Any:
        return v
    if hint is bool:
        if not isinstance(v, bool):
            raise ValueError(f"{path} must be bool, {_got(v)}")
        return v
    if hint is int:
        if not isinstance(v, numbers.Integral) or isinstance(v, bool):
            raise ValueError(f"{path} must be int, {_got(v)}")
        return v
    if hint is float:
        if not isinstance(v, numbers.Real) or isinstance(v, bool):
            raise ValueError(f"{path} must be float, {_got(v)}")
        return v
    if hint is str:
        if not isinstance(v, str):
            raise ValueError(f"{path} must be str, {_got(v)}")
        return v
    if hint is type(None):
        if v is not None:
            raise ValueError(f"{path} must be null, {_got(v)}")
        return v
    if origin is Literal:
        # ``True == 1``: compare types too, so that 1 is not accepted for Literal[True].
        if not any(v == a and type(v) is type(a) for a in args):
            raise ValueError(f"{path} must be one of {list(args)}, {_got(v)}")
        return v
    if origin in (typing.Union, types.UnionType):
        for a in args:
            try:
                return _coerce(v, a, path)
            except ValueError:
                continue
        raise ValueError(f"{path} must be {_describe(hint)}, {_got(v)}")
    if origin in (tuple, list):
        if not isinstance(v, (list, tuple)):
            raise ValueError(f"{path} must be a list, {_got(v)}")
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(v) != len(args):
                raise ValueError(f"{path} must be a list of {len(args)} values, got {len(v)}: {list(v)!r}")
            items = [_coerce(x, a, f"{path}[{i}]") for i, (x, a) in enumerate(zip(v, args, strict=True))]
        else:
            item = args[0] if args else Any
            items = [_coerce(x, item, f"{path}[{i}]") for i, x in enumerate(v)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(v, Mapping):
            raise ValueError(f"{path} must be an object, {_got(v)}")
        kh, vh = args if args else (Any, Any)
        return {_coerce(k, kh, f"{path} key"): _coerce(x, vh, f"{path}[{k!r}]") for k, x in v.items()}
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        if isinstance(v, hint):
            return v
        if not isinstance(v, Mapping):
            raise ValueError(f"{path} must be an object of {hint.__name__} settings, {_got(v)}")
        return build_config(hint, v, path)
    return v


def build_config(cls: type[T], values: Mapping[str, Any], where: str) -> T:
    """``cls(**values)`` after checking the keys and each value's type; every error is a
    ``ValueError`` that starts with ``where`` (e.g. ``"stage_config.fit"``) and names the key."""
    if not isinstance(values, Mapping):
        raise ValueError(f"{where} must be an object of {cls.__name__} settings, {_got(values)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    extra = set(values) - set(fields)
    moved: dict[str, str] = getattr(cls, "MOVED", {})
    if extra & set(moved):
        hints_ = "; ".join(f"{k} is now {where.split(': ')[-1]}.{moved[k]}" for k in sorted(extra & set(moved)))
        raise ValueError(f"{where}: settings moved into nested objects: {hints_}")
    if extra:
        raise ValueError(f"{where} has unknown keys {sorted(map(str, extra))}; known: {sorted(fields)}")
    hints = typing.get_type_hints(cls)
    kwargs = {k: _coerce(v, hints.get(k, Any), f"{where}.{k}") for k, v in values.items()}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: {e}") from e


def check_field_types(obj: Any) -> None:
    """``ValueError`` naming ``Class.field`` when a dataclass instance holds a value of the
    wrong type (for configs built in Python rather than from ``session.json``)."""
    cls = type(obj)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(obj):
        _coerce(getattr(obj, f.name), hints.get(f.name, Any), f"{cls.__name__}.{f.name}")
