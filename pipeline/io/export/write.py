"""Atomic writing of an export: one file as is, several files as one ZIP."""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path

ZIP_DATE_TIME: tuple[int, int, int, int, int, int] = (1980, 1, 1, 0, 0, 0)
"""Timestamp of every member of an export ZIP (the earliest a ZIP can hold): fixed, so that the
same files always give the same bytes (checksums, re-downloads)."""


def bundle(files: dict[str, bytes]) -> bytes:
    """One file's bytes, or a ZIP (deflated) of several named files, in the given order, with
    the same bytes for the same files (``ZIP_DATE_TIME``, permissions rw-r--r--)."""
    if len(files) == 1:
        return next(iter(files.values()))
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as z:
        for name, data in files.items():
            info = zipfile.ZipInfo(name, date_time=ZIP_DATE_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            z.writestr(info, data)
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
    """Write ``files`` to ``path`` atomically (temporary file + rename); no stray file on failure.
    Several files are one ZIP, so ``path`` must then end in ``.zip`` (``ValueError``): a ZIP named
    ``out.bvh`` would not open as BVH."""
    check_out(path)
    if len(files) > 1 and path.suffix.lower() != ".zip":
        raise ValueError(
            f"--out {path}: this export is {len(files)} files ({', '.join(files)}), written as one ZIP; "
            "give a name ending in .zip"
        )
    data = bundle(files)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_bytes(data)
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
