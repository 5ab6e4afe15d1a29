"""Atomic writing of an export: one file as is, several files as one ZIP."""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path


def bundle(files: dict[str, bytes]) -> bytes:
    """One file's bytes, or a ZIP (deflated) of several named files."""
    if len(files) == 1:
        return next(iter(files.values()))
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for name, data in files.items():
            z.writestr(name, data)
    return buf.getvalue()


def default_out(session_dir: Path, files: dict[str, bytes], stem: str) -> Path:
    """Where an export goes without ``--out``: the single file's name, or ``{stem}.zip``, in the session."""
    if len(files) == 1:
        return session_dir / next(iter(files))
    return session_dir / f"{stem}.zip"


def check_out(path: Path) -> None:
    """``ValueError`` for an output path that cannot be written (a folder, or a missing folder)."""
    if path.is_dir():
        raise ValueError(f"--out {path}: is a folder; give a file name")
    if not path.parent.is_dir():
        raise ValueError(f"--out {path}: folder {path.parent} does not exist")


def write_files(files: dict[str, bytes], path: Path) -> Path:
    """Write ``files`` to ``path`` atomically (temporary file + rename); no stray file on failure."""
    check_out(path)
    data = bundle(files)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_bytes(data)
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
