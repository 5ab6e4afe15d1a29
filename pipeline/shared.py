"""Where the shared models and benchmark data are: one rule for the CLI, the benches and the tests.

Lookup, first hit wins:

1. the environment variable (``CORNERMAN_MODELS_DIR`` for models, ``CORNERMAN_TEST_DATA_DIR``
   for data), when set;
2. ``$CORNERMAN_SHARED_DIR/models`` or ``/data``, when that variable is set;
3. a ``shared`` folder beside the checkout (``<repo>/../shared``) or beside the working
   directory (``./../shared``), the layout CI and a development machine use.

A variable that is set but names a missing folder is not silently replaced by a guess:
the functions return ``None`` and ``describe_lookup`` says what was looked at.
"""

from __future__ import annotations

import os
from pathlib import Path

MODELS_ENV = "CORNERMAN_MODELS_DIR"
DATA_ENV = "CORNERMAN_TEST_DATA_DIR"
SHARED_ENV = "CORNERMAN_SHARED_DIR"

_REPO = Path(__file__).resolve().parents[1]


def _candidates(env: str, sub: str) -> list[Path]:
    """Folders tried for ``sub`` ("models" or "data"), in order."""
    val = os.environ.get(env)
    if val:
        return [Path(val).expanduser()]
    shared = os.environ.get(SHARED_ENV)
    if shared:
        return [Path(shared).expanduser() / sub]
    out: list[Path] = []
    for base in (_REPO.parent / "shared", Path.cwd().parent / "shared"):
        p = (base / sub).resolve()
        if p not in out:
            out.append(p)
    return out


def _first_dir(env: str, sub: str) -> Path | None:
    for p in _candidates(env, sub):
        if p.is_dir():
            return p
    return None


def shared_models_dir() -> Path | None:
    """Folder of the shared ONNX models, or ``None`` when none of the candidates exists."""
    return _first_dir(MODELS_ENV, "models")


def shared_data_dir() -> Path | None:
    """Folder of the shared datasets (``shelf/``, ``pose2sim_multiperson/``), or ``None``."""
    return _first_dir(DATA_ENV, "data")


def dataset_dir(name: str) -> Path:
    """``<shared data>/<name>``; ``ValueError`` naming every folder looked at when absent."""
    root = shared_data_dir()
    if root is not None and (root / name).is_dir():
        return root / name
    looked = ", ".join(str(p / name) for p in _candidates(DATA_ENV, "data"))
    raise ValueError(
        f"dataset {name!r} not found (looked in {looked}); set {DATA_ENV} to the folder holding {name}/ "
        f"or {SHARED_ENV} to the shared folder"
    )


def describe_lookup() -> str:
    """One line per kind: the folders tried and which one is used."""
    lines = []
    for env, sub in ((MODELS_ENV, "models"), (DATA_ENV, "data")):
        found = _first_dir(env, sub)
        tried = ", ".join(str(p) for p in _candidates(env, sub))
        lines.append(f"{sub}: {found if found else 'not found'} (tried {tried})")
    return "\n".join(lines)
