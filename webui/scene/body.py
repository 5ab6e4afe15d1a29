"""Body meshes of the fit stage, posed for every frame in a background thread.

``pipeline.backends.anny.body.posed_mesh`` imports torch, so it is imported lazily in
the viewer process only. Until a person's meshes are ready (or when the backend is
unavailable) the viewer shows the skeleton only.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import numpy as np

from pipeline.schema.results import BodyFit

log = logging.getLogger(__name__)

CHUNK_FRAMES = 64


class BodyMeshCache:
    """Decimated posed vertices of every fitted person for every frame row of ``bodyfit``."""

    def __init__(
        self, bodyfit: BodyFit, on_chunk: Callable[[], None] | None = None, body_model_path: str = ""
    ) -> None:
        """``on_chunk`` is called (from the worker thread) whenever more frames are ready;
        ``body_model_path``: the user's SMPL/SMPL-X model folder (SMPL fits only)."""
        self.bodyfit = bodyfit
        self.body_model_path = body_model_path
        self.on_chunk = on_chunk
        n, p = bodyfit.frame_indices.shape[0], bodyfit.person_ids.shape[0]
        self._verts: list[np.ndarray | None] = [None] * p
        self._done = np.zeros((p, n), dtype=bool)
        self.faces: np.ndarray | None = None
        self.error: str | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="body-meshes", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    @property
    def progress(self) -> float:
        return float(self._done.mean()) if self._done.size else 1.0

    def _run(self) -> None:
        try:
            if self.bodyfit.body_model == "anny":
                from pipeline.backends.anny.body import posed_mesh
            else:
                from pipeline.backends.smpl.body import posed_mesh as smpl_mesh

                def posed_mesh(
                    bodyfit: BodyFit, person_index: int, frames: np.ndarray, decimate: bool = True
                ) -> tuple[np.ndarray, np.ndarray]:  # SMPL: the full mesh (6890 / 10475 vertices)
                    return smpl_mesh(bodyfit, person_index, frames, self.body_model_path)
        except ImportError as e:
            self.error = f"body model backend unavailable: {e}"
            log.warning("%s; showing skeletons only", self.error)
            return
        n = self.bodyfit.frame_indices.shape[0]
        try:
            for pi in range(self.bodyfit.person_ids.shape[0]):
                for start in range(0, n, CHUNK_FRAMES):
                    if self._stop.is_set():
                        return
                    rows = np.arange(start, min(n, start + CHUNK_FRAMES))
                    verts, faces = posed_mesh(self.bodyfit, pi, rows, decimate=True)
                    if self._verts[pi] is None:
                        self._verts[pi] = np.zeros((n, verts.shape[1], 3), dtype=np.float32)
                        self.faces = np.asarray(faces, dtype=np.int64)
                    buf = self._verts[pi]
                    assert buf is not None
                    buf[rows] = verts
                    self._done[pi, rows] = True
                    if self.on_chunk is not None:
                        self.on_chunk()
        except (ValueError, RuntimeError) as e:
            self.error = f"posing the body meshes failed: {e}"
            log.warning("%s; showing skeletons only", self.error)

    def get(self, person_index: int, row: int) -> np.ndarray | None:
        """(verts, 3) float32 world vertices, or None while not computed."""
        if not (0 <= person_index < self._done.shape[0] and 0 <= row < self._done.shape[1]):
            return None
        if not self._done[person_index, row]:
            return None
        buf = self._verts[person_index]
        return None if buf is None else buf[row]
