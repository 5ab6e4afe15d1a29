"""Body meshes of the fit stage, posed for every frame by a short-lived child process.

Posing needs the body model (torch for anny); importing torch alone costs a viewer about
180 MB and posing another 130 MB that the allocator keeps. So the viewer hands the
``BodyFit`` to ``python -m webui.scene.body_worker`` and keeps only the vertices it streams
back (about 9 MB for two athletes over 300 frames); the child exits when done. Until a
person's meshes are ready (or when the backend is unavailable) the viewer shows the
skeleton only. Every client of the viewer shares one cache.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO

import numpy as np

from pipeline.schema.base import to_arrays
from pipeline.schema.results import BodyFit

log = logging.getLogger(__name__)

CHUNK_FRAMES = 64
"""Frame rows posed (and sent back) at a time; the viewer shows each chunk as it arrives."""
CACHE_KEEP = 16
"""Posed mesh sets kept in ``cache_dir()`` (the oldest beyond are deleted)."""


def cache_dir() -> Path:
    """The viewer's cache of posed meshes by fit, so a viewer started again (after idling) skips posing:
    ``$CORNERMAN_VIEWER_MESH_CACHE_DIR``, else ``$CORNERMAN_CACHE_DIR/viewer-meshes`` (``CORNERMAN_CACHE_DIR``
    defaulting to ``~/.cache/cornerman``)."""
    own = os.environ.get("CORNERMAN_VIEWER_MESH_CACHE_DIR")
    if own:
        return Path(own)
    base = os.environ.get("CORNERMAN_CACHE_DIR") or str(Path.home() / ".cache" / "cornerman")
    return Path(base) / "viewer-meshes"


def read_record(stream: IO[bytes]) -> tuple[dict, np.ndarray | None] | None:
    """One record of the worker's stdout: a JSON header line, then the raw bytes of one array when
    the header has ``dtype`` and ``shape``; None at the end of the stream. ``ValueError`` when truncated."""
    line = stream.readline()
    if not line:
        return None
    header = json.loads(line)
    if "dtype" not in header:
        return header, None
    dtype, shape = np.dtype(header["dtype"]), tuple(int(n) for n in header["shape"])
    nbytes = dtype.itemsize * int(np.prod(shape))
    raw = stream.read(nbytes)
    if len(raw) != nbytes:
        raise ValueError(f"record {header.get('kind')!r}: {len(raw)} of {nbytes} bytes")
    return header, np.frombuffer(raw, dtype=dtype).reshape(shape)


def write_record(stream: IO[bytes], header: dict, arr: np.ndarray | None = None) -> None:
    """Write one record (see ``read_record``); ``arr`` goes as little-endian raw bytes."""
    if arr is not None:
        arr = np.ascontiguousarray(arr, dtype=arr.dtype.newbyteorder("<"))
        header = {**header, "dtype": arr.dtype.str, "shape": list(arr.shape)}
    stream.write((json.dumps(header) + "\n").encode())
    if arr is not None:
        stream.write(arr.tobytes())
    stream.flush()


class BodyMeshCache:
    """Decimated posed vertices of every fitted person for every frame row of ``bodyfit``."""

    def __init__(
        self, bodyfit: BodyFit, on_chunk: Callable[[], None] | None = None, body_model_path: str = "",
        cache: Path | None = None,
    ) -> None:
        """``on_chunk`` is called (from the reader thread) whenever more frames are ready;
        ``body_model_path``: the user's SMPL/SMPL-X model folder (SMPL fits only); ``cache``: a folder
        where posed meshes are kept by fit (e.g. ``cache_dir()``; None: always pose)."""
        self.bodyfit = bodyfit
        self.body_model_path = body_model_path
        self.cache = cache
        self.on_chunk = on_chunk
        n, p = bodyfit.frame_indices.shape[0], bodyfit.person_ids.shape[0]
        self._verts: list[np.ndarray | None] = [None] * p
        self._done = np.zeros((p, n), dtype=bool)
        self.faces: np.ndarray | None = None
        self.error: str | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._proc: subprocess.Popen[bytes] | None = None
        self.from_cache = False
        """True when the meshes came from ``cache`` instead of the worker."""

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="body-meshes", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        proc = self._proc
        if proc is not None and proc.poll() is None:
            proc.kill()

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    @property
    def progress(self) -> float:
        return float(self._done.mean()) if self._done.size else 1.0

    def _run(self) -> None:
        buf = io.BytesIO()
        np.savez(buf, **to_arrays(self.bodyfit))  # type: ignore[arg-type]
        key = hashlib.sha256(buf.getvalue() + self.body_model_path.encode()).hexdigest()[:24]
        if self.cache is not None and self._load_cached(self.cache, key):
            return
        self._pose(buf.getvalue())
        if self.cache is not None and self.error is None and not self._stop.is_set() and bool(self._done.all()):
            self._save_cached(self.cache, key)

    def _load_cached(self, d: Path, key: str) -> bool:
        path = d / f"{key}.npz"
        try:
            with np.load(path, allow_pickle=False) as z:
                faces, verts = z["faces"], z["verts"]
        except (OSError, ValueError, KeyError):
            return False
        if verts.shape[:2] != self._done.shape:
            return False
        self._verts = [np.asarray(v, dtype=np.float32) for v in verts]
        self.faces = np.asarray(faces, dtype=np.int64)
        self._done[:] = True
        self.from_cache = True
        log.info("body meshes from %s", path)
        if self.on_chunk is not None:
            self.on_chunk()
        return True

    def _save_cached(self, d: Path, key: str) -> None:
        """Best effort: a full disk or a read-only home only costs the next viewer a re-pose."""
        if self.faces is None:
            return
        try:
            d.mkdir(parents=True, exist_ok=True)
            tmp = d / f".{key}.{os.getpid()}.npz"
            np.savez(tmp, faces=self.faces, verts=np.stack([v for v in self._verts if v is not None]))
            os.replace(tmp, d / f"{key}.npz")
            for old in sorted(d.glob("*.npz"), key=lambda f: f.stat().st_mtime)[:-CACHE_KEEP]:
                old.unlink(missing_ok=True)
        except OSError as e:
            log.warning("body meshes not cached in %s: %s", d, e)

    def _pose(self, fit_npz: bytes) -> None:
        cmd = [sys.executable, "-m", "webui.scene.body_worker", "--chunk", str(CHUNK_FRAMES)]
        if self.body_model_path:
            cmd += ["--body-model-path", self.body_model_path]
        env = dict(os.environ)
        env.setdefault("OMP_NUM_THREADS", "1")
        try:
            proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
        except OSError as e:
            self.error = f"cannot start the body mesh worker: {e}"
            log.warning("%s; showing skeletons only", self.error)
            return
        self._proc = proc
        t0 = time.monotonic()
        assert proc.stdin is not None and proc.stdout is not None and proc.stderr is not None
        try:
            proc.stdin.write(fit_npz)
            proc.stdin.close()
            while not self._stop.is_set():
                rec = read_record(proc.stdout)
                if rec is None:
                    break
                self._take(*rec)
        except (OSError, ValueError) as e:  # a killed worker (stop) or a truncated record
            if not self._stop.is_set():
                self.error = f"body mesh worker failed: {e}"
        finally:
            if self._stop.is_set() and proc.poll() is None:
                proc.kill()
            err = proc.stderr.read().decode(errors="replace")[-2000:]
            code = proc.wait()
            for s in (proc.stdout, proc.stderr):
                s.close()
        if self.error is None and not self._stop.is_set():
            log.info("body meshes posed: %d persons x %d frames in %.1f s (worker pid %d)", self._done.shape[0],
                     self._done.shape[1], time.monotonic() - t0, proc.pid)
        if code != 0 and not self._stop.is_set() and self.error is None:
            self.error = f"body mesh worker exited with {code}: {err.strip().splitlines()[-1] if err.strip() else ''}"
        if self.error is not None:
            log.warning("%s; showing skeletons only", self.error)

    def _take(self, header: dict, arr: np.ndarray | None) -> None:
        kind = header.get("kind")
        if kind == "error":
            self.error = str(header.get("message", "unknown error"))
        elif kind == "faces" and arr is not None:
            self.faces = np.asarray(arr, dtype=np.int64)
        elif kind == "verts" and arr is not None:
            pi, start = int(header["person"]), int(header["start"])
            rows = np.arange(start, start + arr.shape[0])
            if self._verts[pi] is None:
                self._verts[pi] = np.zeros((self._done.shape[1], arr.shape[1], 3), dtype=np.float32)
            buf = self._verts[pi]
            assert buf is not None
            buf[rows] = arr
            self._done[pi, rows] = True
            if self.on_chunk is not None:
                self.on_chunk()

    def get(self, person_index: int, row: int) -> np.ndarray | None:
        """(verts, 3) float32 world vertices, or None while not computed."""
        if not (0 <= person_index < self._done.shape[0] and 0 <= row < self._done.shape[1]):
            return None
        if not self._done[person_index, row]:
            return None
        buf = self._verts[person_index]
        return None if buf is None else buf[row]
