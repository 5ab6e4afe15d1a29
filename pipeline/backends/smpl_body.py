"""SMPL / SMPL-X through the ``smplx`` package, with the user's own model files.

Nothing of SMPL is shipped (its licence forbids it). The files must be laid out as
``smplx.create`` expects::

    <body_model_path>/smpl/SMPL_NEUTRAL.pkl   (and/or SMPL_MALE.pkl, SMPL_FEMALE.pkl)
    <body_model_path>/smplx/SMPLX_NEUTRAL.npz (and/or SMPLX_MALE.npz, SMPLX_FEMALE.npz; .pkl also accepted)

Download them from https://smpl.is.tue.mpg.de and https://smpl-x.is.tue.mpg.de after
accepting their licences, and install the package with ``pip install smplx``.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

EXPECTED_FILES: dict[str, tuple[str, ...]] = {
    "smpl": ("smpl/SMPL_NEUTRAL.pkl", "smpl/SMPL_MALE.pkl", "smpl/SMPL_FEMALE.pkl"),
    "smplx": (
        "smplx/SMPLX_NEUTRAL.npz",
        "smplx/SMPLX_MALE.npz",
        "smplx/SMPLX_FEMALE.npz",
        "smplx/SMPLX_NEUTRAL.pkl",
        "smplx/SMPLX_MALE.pkl",
        "smplx/SMPLX_FEMALE.pkl",
    ),
}


def find_model_files(body_model: str, body_model_path: str | Path) -> list[Path]:
    """The expected model files present under ``body_model_path`` (may be empty)."""
    if body_model not in EXPECTED_FILES:
        raise ValueError(f"unknown body model {body_model!r}; expected one of {sorted(EXPECTED_FILES)}")
    root = Path(body_model_path)
    return [root / rel for rel in EXPECTED_FILES[body_model] if (root / rel).is_file()]


def check_smpl_available(body_model: str, body_model_path: str | Path) -> list[Path]:
    """Raise ``ValueError`` saying exactly what is missing; return the model files found."""
    expected = ", ".join(EXPECTED_FILES.get(body_model, ()))
    if not str(body_model_path):
        raise ValueError(
            f"--body-model {body_model} needs --body-model-path: a folder with {expected} "
            "(your own licensed copy; nothing of SMPL is shipped)"
        )
    root = Path(body_model_path)
    if not root.is_dir():
        raise ValueError(f"body model path {root} is not a folder; it must contain {expected}")
    files = find_model_files(body_model, root)
    if not files:
        raise ValueError(
            f"no {body_model.upper()} model file under {root}: expected at least one of "
            f"{', '.join(str(root / r) for r in EXPECTED_FILES[body_model])} "
            "(download from https://smpl.is.tue.mpg.de / https://smpl-x.is.tue.mpg.de)"
        )
    if importlib.util.find_spec("smplx") is None:
        raise ValueError(
            f"found {files[0]} but the 'smplx' package is not installed: run `pip install smplx` to fit {body_model}"
        )
    return files
