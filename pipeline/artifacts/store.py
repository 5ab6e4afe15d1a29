"""ArtifactStore: one folder per stage under ``<session>/artifacts``, written atomically.

Layout::

    <session>/artifacts/<stage>/<name>.npz   schema dataclasses (allow_pickle=False)
    <session>/artifacts/<stage>/<name>.<ext> other outputs (MJCF xml, JSON metrics)
    <session>/artifacts/<stage>/manifest.json

A stage's outputs are first written to ``artifacts/.tmp-<stage>-<uuid>/``; the
manifest is written last, then the folder is swapped into place with renames. A
crash at any point leaves the previous version of that stage (and every other
stage) untouched; leftovers ``.tmp-*`` / ``.old-*`` are cleaned on the next open.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
import os
import shutil
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from pipeline.schema.base import load_npz, to_arrays

log = logging.getLogger(__name__)
T = TypeVar("T")

MANIFEST = "manifest.json"
SCHEMA_VERSION = 1


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while b := f.read(chunk):
            h.update(b)
    return h.hexdigest()


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def config_hash(cfg_dict: dict[str, Any]) -> str:
    return sha256_bytes(json.dumps(cfg_dict, sort_keys=True, default=str).encode())


@dataclass(frozen=True)
class Manifest:
    """What produced a stage's artifacts (JSON in ``manifest.json``).

    Fields:
        stage: stage name.
        schema_version: artifact layout version.
        code_version: package version + stage code version.
        config: the resolved stage config.
        config_hash: sha256 of ``config``.
        inputs: input key -> sha256 (``file:<path>``, ``artifact:<stage>``, ``annotations``).
        outputs: output file name -> sha256.
        created_unix_s: creation time.
        duration_s: wall time of the stage.
        metrics: small scalar summary for tables (e.g. ``{"mpjpe_mm": 21.3}``).
    """

    stage: str
    code_version: str
    config: dict[str, Any]
    config_hash: str
    inputs: dict[str, str]
    outputs: dict[str, str] = field(default_factory=dict)
    created_unix_s: float = 0.0
    duration_s: float = 0.0
    metrics: dict[str, Any] = field(default_factory=dict)
    schema_version: int = SCHEMA_VERSION

    @property
    def outputs_hash(self) -> str:
        """One hash over all outputs: what downstream stages record as their input."""
        return sha256_bytes(json.dumps(self.outputs, sort_keys=True).encode())

    def to_json(self) -> str:
        return json.dumps(self.__dict__, indent=2, sort_keys=True, default=str)

    @classmethod
    def from_json(cls, text: str, where: str) -> Manifest:
        try:
            d = json.loads(text)
            return cls(**d)
        except (json.JSONDecodeError, TypeError) as e:
            raise ValueError(f"{where}: corrupt manifest: {e}") from e


class ArtifactStore:
    """Atomic, manifest-tracked artifact folders of one session."""

    def __init__(self, session_dir: str | Path) -> None:
        self.session_dir = Path(session_dir)
        self.root = self.session_dir / "artifacts"
        self.root.mkdir(parents=True, exist_ok=True)
        self._recover()

    @contextlib.contextmanager
    def _write_lock(self, exclusive: bool) -> Any:
        """Writers hold a shared lock on ``<session>/.artifacts.lock``; recovery needs it exclusively and is
        skipped while another process (e.g. a worker, seen from the server) is writing."""
        with open(self.session_dir / ".artifacts.lock", "a") as f:
            try:
                fcntl.flock(f, (fcntl.LOCK_EX | fcntl.LOCK_NB) if exclusive else fcntl.LOCK_SH)
            except BlockingIOError:
                yield False
                return
            try:
                yield True
            finally:
                fcntl.flock(f, fcntl.LOCK_UN)

    def _recover(self) -> None:
        """Finish or undo a swap interrupted by a crash, and drop temp folders."""
        with self._write_lock(exclusive=True) as free:
            if free:
                self._recover_unlocked()

    def _recover_unlocked(self) -> None:
        for p in self.root.iterdir():
            if p.name.startswith(".old-"):
                stage = p.name[len(".old-") :].rsplit("-", 1)[0]
                if not (self.root / stage / MANIFEST).exists():
                    # Crash between the two renames: the old version is the last complete one.
                    if (self.root / stage).exists():
                        shutil.rmtree(self.root / stage)
                    p.rename(self.root / stage)
                    log.warning("restored previous artifacts of stage %s after an interrupted write", stage)
                else:
                    shutil.rmtree(p, ignore_errors=True)
            elif p.name.startswith(".tmp-"):
                shutil.rmtree(p, ignore_errors=True)

    def stage_dir(self, stage: str) -> Path:
        return self.root / stage

    def manifest(self, stage: str) -> Manifest | None:
        """The stage's manifest, or None when the stage has no complete artifacts."""
        path = self.stage_dir(stage) / MANIFEST
        if not path.exists():
            return None
        return Manifest.from_json(path.read_text(), str(path))

    def path(self, stage: str, name: str) -> Path:
        """Path of an output file of a complete stage; ``ValueError`` if absent."""
        p = self.stage_dir(stage) / name
        if self.manifest(stage) is None:
            raise ValueError(f"stage {stage!r} has no complete artifacts in {self.root} (run it first)")
        if not p.exists():
            raise ValueError(f"{p}: artifact {name!r} missing from stage {stage!r}")
        return p

    def load(self, stage: str, name: str, cls: type[T]) -> T:
        """Load ``<stage>/<name>.npz`` as schema type ``cls``."""
        return load_npz(self.path(stage, f"{name}.npz"), cls)

    def has(self, stage: str, name: str) -> bool:
        return self.manifest(stage) is not None and (self.stage_dir(stage) / name).exists()

    def write(self, manifest: Manifest, outputs: dict[str, Any]) -> Manifest:
        """Write all outputs of one stage and its manifest atomically.

        ``outputs`` maps a name to a schema dataclass (saved as ``<name>.npz``),
        a ``dict[str, np.ndarray]`` (``<name>.npz``), ``bytes`` or ``str`` (saved
        under ``name`` verbatim, which must carry its extension).
        """
        with self._write_lock(exclusive=False):
            return self._write_unlocked(manifest, outputs)

    def _write_unlocked(self, manifest: Manifest, outputs: dict[str, Any]) -> Manifest:
        """The body of :meth:`write` (caller holds the shared write lock)."""
        stage = manifest.stage
        tmp = self.root / f".tmp-{stage}-{uuid.uuid4().hex[:8]}"
        tmp.mkdir()
        hashes: dict[str, str] = {}
        try:
            for name, obj in outputs.items():
                if "/" in name or name.startswith("."):
                    raise ValueError(f"invalid artifact name {name!r}")
                if isinstance(obj, (bytes, str)):
                    fname = name
                    data = obj.encode() if isinstance(obj, str) else obj
                    (tmp / fname).write_bytes(data)
                else:
                    fname = f"{name}.npz"
                    arrays = obj if isinstance(obj, dict) else to_arrays(obj)
                    with open(tmp / fname, "wb") as f:
                        np.savez(f, **arrays)
                hashes[fname] = sha256_file(tmp / fname)
            final = Manifest(**{**manifest.__dict__, "outputs": hashes, "created_unix_s": time.time()})
            mpath = tmp / MANIFEST
            with open(mpath, "w") as f:
                f.write(final.to_json())
                f.flush()
                os.fsync(f.fileno())
            dest = self.stage_dir(stage)
            old = self.root / f".old-{stage}-{uuid.uuid4().hex[:8]}"
            if dest.exists():
                dest.rename(old)
            tmp.rename(dest)
            if old.exists():
                shutil.rmtree(old)
            return final
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise

    def invalidate(self, stage: str) -> None:
        """Remove a stage's artifacts (used by ``cornerman run --force`` and tests)."""
        d = self.stage_dir(stage)
        if d.exists():
            old = self.root / f".old-{stage}-{uuid.uuid4().hex[:8]}"
            d.rename(old)
            shutil.rmtree(old)


class FileHashCache:
    """sha256 of input files, cached by (path, size, mtime) so large videos hash once."""

    def __init__(self, cache_path: Path) -> None:
        self.cache_path = cache_path
        try:
            self.data: dict[str, list] = json.loads(cache_path.read_text()) if cache_path.exists() else {}
        except json.JSONDecodeError:
            self.data = {}

    def sha256(self, path: Path) -> str:
        if not path.exists():
            raise ValueError(f"{path}: input file does not exist")
        if path.is_dir():
            h = hashlib.sha256()
            for p in sorted(q for q in path.rglob("*") if q.is_file()):
                h.update(str(p.relative_to(path)).encode())
                h.update(self.sha256(p).encode())
            return h.hexdigest()
        st = path.stat()
        key = str(path.resolve())
        hit = self.data.get(key)
        if hit and hit[0] == st.st_size and hit[1] == st.st_mtime_ns:
            return str(hit[2])
        digest = sha256_file(path)
        self.data[key] = [st.st_size, st.st_mtime_ns, digest]
        return digest

    def save(self) -> None:
        tmp = self.cache_path.with_suffix(f".{os.getpid()}-{uuid.uuid4().hex[:6]}.tmp")  # concurrent savers
        tmp.write_text(json.dumps(self.data))
        tmp.replace(self.cache_path)
