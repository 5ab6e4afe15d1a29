"""Validation and npz (de)serialisation shared by every schema dataclass.

Every schema type is a frozen dataclass whose fields are numpy arrays, scalars
(int/float/str/bool) or tuples of strings. ``to_arrays`` turns one into a flat
``dict[str, np.ndarray]`` that ``np.savez`` writes without pickle, and
``from_arrays`` rebuilds it (running ``__post_init__`` validation again).
"""

from __future__ import annotations

import dataclasses
import io
import json
import types
import typing
import zipfile
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")

_STR_TUPLE_PREFIX = "__strtuple__"
_SCALAR_PREFIX = "__scalar__"
_NONE_PREFIX = "__none__"


def check_array(
    name: str,
    arr: Any,
    shape: tuple[int | None, ...],
    dtype_kind: str | None = None,
    finite: bool = False,
) -> np.ndarray:
    """Validate ``arr`` against ``shape`` (``None`` = any size) and a dtype kind.

    ``dtype_kind`` is a string of allowed numpy kinds, e.g. ``"f"``, ``"iu"``, ``"b"``.
    Raises ``ValueError`` naming the field and the offending shape/dtype/values.
    """
    if not isinstance(arr, np.ndarray):
        raise ValueError(f"{name}: expected a numpy array, got {type(arr).__name__}")
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape, strict=True)):
        raise ValueError(f"{name}: expected shape {shape}, got {arr.shape}")
    if dtype_kind is not None and arr.dtype.kind not in dtype_kind:
        raise ValueError(f"{name}: expected dtype kind in {dtype_kind!r}, got {arr.dtype}")
    if finite and arr.size and not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[:3].tolist()
        raise ValueError(f"{name}: contains NaN/inf values (first at indices {bad})")
    return arr


def check_finite_where(name: str, arr: np.ndarray, valid: np.ndarray) -> None:
    """Values where ``valid`` is True must be finite (invalid entries may hold anything)."""
    sel = arr[valid]
    if sel.size and not np.all(np.isfinite(sel)):
        raise ValueError(f"{name}: NaN/inf values at entries marked valid")


def check_unit_interval_where(name: str, arr: np.ndarray, valid: np.ndarray) -> None:
    """Values where ``valid`` is True must lie in [0, 1] (NaN fails); the error names the
    first offending entry's index and value."""
    sel = arr[valid]
    bad = ~((sel >= 0.0) & (sel <= 1.0))
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(valid)[int(np.argmax(bad))])
        raise ValueError(
            f"{name}: {int(bad.sum())} entries marked valid are outside [0, 1] or not finite, "
            f"first at index {idx}: {float(sel[bad][0])}"
        )


def to_arrays(obj: Any) -> dict[str, np.ndarray]:
    """Flatten a schema dataclass into npz-ready arrays (no object dtype)."""
    if not dataclasses.is_dataclass(obj):
        raise ValueError(f"to_arrays: {type(obj).__name__} is not a dataclass")
    out: dict[str, np.ndarray] = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if v is None:
            out[_NONE_PREFIX + f.name] = np.zeros(0)
        elif isinstance(v, np.ndarray):
            if v.dtype.kind == "O":
                raise ValueError(f"to_arrays: field {f.name} has object dtype (would need pickle)")
            out[f.name] = v
        elif isinstance(v, tuple) and all(isinstance(s, str) for s in v):
            out[_STR_TUPLE_PREFIX + f.name] = np.array(v, dtype=np.str_) if v else np.zeros(0, dtype="<U1")
        elif isinstance(v, (bool, int, float, str, np.integer, np.floating)):
            out[_SCALAR_PREFIX + f.name] = np.array(v)
        elif isinstance(v, dict):
            out[_SCALAR_PREFIX + f.name] = np.array(json.dumps(v, sort_keys=True))
        else:
            raise ValueError(f"to_arrays: field {f.name} has unsupported type {type(v).__name__}")
    return out


def _wants_dict(cls: type, name: str) -> bool:
    hints = typing.get_type_hints(cls)
    t = hints.get(name)
    origin = typing.get_origin(t)
    if origin in (typing.Union, types.UnionType):
        return any(typing.get_origin(a) is dict or a is dict for a in typing.get_args(t))
    return origin is dict or t is dict


def from_arrays(cls: type[T], arrays: dict[str, np.ndarray]) -> T:
    """Inverse of :func:`to_arrays`; validation runs again in ``__post_init__``."""
    kwargs: dict[str, Any] = {}
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    for key, arr in arrays.items():
        if key.startswith(_NONE_PREFIX):
            kwargs[key[len(_NONE_PREFIX) :]] = None
        elif key.startswith(_STR_TUPLE_PREFIX):
            kwargs[key[len(_STR_TUPLE_PREFIX) :]] = tuple(str(s) for s in arr.tolist())
        elif key.startswith(_SCALAR_PREFIX):
            name = key[len(_SCALAR_PREFIX) :]
            val = arr.item()
            if isinstance(val, str) and _wants_dict(cls, name):
                val = json.loads(val)
            kwargs[name] = val
        else:
            kwargs[key] = np.asarray(arr)
    unknown = set(kwargs) - names
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown fields in stored arrays: {sorted(unknown)}")
    return cls(**kwargs)


def save_npz(path: str | Path, obj: Any) -> None:
    """Write a schema dataclass to ``path`` as an uncompressed npz (no pickle)."""
    buf = io.BytesIO()
    np.savez(buf, **to_arrays(obj))  # type: ignore[arg-type]  # numpy's stub types **kwds like allow_pickle
    Path(path).write_bytes(buf.getvalue())


_UNREADABLE = (OSError, EOFError, zipfile.BadZipFile, ValueError)
"""What numpy raises for a missing, truncated, corrupt or pickled npz."""


def load_npz_scalar(path: str | Path, name: str) -> Any:
    """One scalar field (``int``, ``float``, ``str``, ``bool``) of an npz written by
    :func:`save_npz`, without reading its arrays; ``ValueError`` naming the file."""
    try:
        z = np.load(path, allow_pickle=False)
    except _UNREADABLE as e:
        raise ValueError(f"{path}: cannot read npz: {e}") from e
    with z:
        if _SCALAR_PREFIX + name not in z.files:
            raise ValueError(f"{path}: no scalar field {name!r}")
        return z[_SCALAR_PREFIX + name].item()


def load_npz(path: str | Path, cls: type[T]) -> T:
    """Load a schema dataclass saved by :func:`save_npz`; errors name the file."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except _UNREADABLE as e:
        raise ValueError(f"{path}: cannot read npz: {e}") from e
    try:
        return from_arrays(cls, arrays)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{path}: invalid {cls.__name__}: {e}") from e
