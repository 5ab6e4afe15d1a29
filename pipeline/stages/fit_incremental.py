"""What the fit stage keeps for an incremental re-run, and which frames it re-optimises.

After an edit at frame f, the fit's inputs (triangulated joints, associated 2D keypoints)
change from about f on; the triangulation's smoother spreads a change a few frames back,
by amounts that fade out. A re-run compares its gathered inputs with the previous run's
(``FitCheckpoints``) frame by frame, within ``INPUT_TOL`` (0.5 mm for the 3D targets), and
re-optimises only the changed frames, with ``FitConfig.incremental_margin_frames`` on each
side (default 0: the temporal terms couple neighbours, and the kept neighbours in the
context hold them), keeping every other frame, the shapes and the landmark offsets of the
previous fit. The changed frames start as a fresh fit does (the previous pose may be
another athlete's), the margin from the previous pose. The re-fit sees ``CONTEXT_FRAMES``
kept frames on each side, so every temporal term of a re-optimised frame is in its loss.

Pure numpy: no torch import here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.schema.base import check_array
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.schema.results import BodyFit

INPUT_TOL: dict[str, float] = {"kp3d_m": 5e-4, "w3d": 1e-6, "uv_px": 1e-4, "w2d": 1e-6}
"""Largest change of an input (metres, confidence, undistorted pixels) that counts as none.
The 3D targets' 0.5 mm stops the triangulation smoother's fading backward reach from an
edit (on the demo bout: 1 µm 33 frames before a swap, 0.5 mm 17 frames before it); it is
far below the targets' own noise (about 10 mm) and what a re-fit moves a frame whose inputs
did not change (several mm, see docs/design/incremental.md)."""

CONTEXT_FRAMES = 6
"""Kept frames on each side of the re-optimised ones that the re-fit includes: at least the
widest temporal stencil (the jerk's four frames) minus one, plus the adaptive acceleration
weights' window (``FitConfig.accel_adapt_window``)."""


@dataclass(frozen=True)
class FitCheckpoints:
    """The fit's gathered inputs and per-person constants, saved as ``checkpoints.npz``
    beside the fit (frames F, persons P, joints J = ``COCO17_FEET``, views V).

    person_ids (P,), frame_indices (F,): the layout; fitted (P,) bool: persons the fit
    optimised; kp3d_m (F, P, J, 3), w3d (F, P, J): the 3D targets and weights; uv_px
    (V, F, P, J, 2), w2d (V, F, P, J): the undistorted 2D keypoints and weights
    (``pipeline.stages.fit.gather_inputs``); landmark_offsets_m (P, J, 3): each person's
    landmark offsets (m, in their landmark bones' frames).
    """

    person_ids: np.ndarray
    frame_indices: np.ndarray
    fitted: np.ndarray
    kp3d_m: np.ndarray
    w3d: np.ndarray
    uv_px: np.ndarray
    w2d: np.ndarray
    landmark_offsets_m: np.ndarray

    def __post_init__(self) -> None:
        F, P = self.frame_indices.shape[0], self.person_ids.shape[0]
        check_array("FitCheckpoints.fitted", self.fitted, (P,), "b")
        check_array("FitCheckpoints.kp3d_m", self.kp3d_m, (F, P, None, 3), "f")
        J = self.kp3d_m.shape[2]
        check_array("FitCheckpoints.w3d", self.w3d, (F, P, J), "f")
        check_array("FitCheckpoints.uv_px", self.uv_px, (None, F, P, J, 2), "f")
        check_array("FitCheckpoints.w2d", self.w2d, (self.uv_px.shape[0], F, P, J), "f")
        check_array("FitCheckpoints.landmark_offsets_m", self.landmark_offsets_m, (P, J, 3), "f")


@dataclass(frozen=True)
class FitPrevious:
    """The stage's previous run, read back by the runner: the fit, its keypoints and its
    checkpoints."""

    bodyfit: BodyFit
    keypoints3d: Keypoints3D
    checkpoints: FitCheckpoints


def changed_frames(old: FitCheckpoints, new: FitCheckpoints) -> np.ndarray:
    """(frames,) True where any input of any person differs by more than ``INPUT_TOL``
    (the layouts must match: ``layout_mismatch``)."""
    out = np.zeros(new.frame_indices.shape[0], dtype=bool)
    for name, tol in INPUT_TOL.items():
        a, b = getattr(old, name), getattr(new, name)
        frame_axis = 1 if name in ("uv_px", "w2d") else 0
        d = np.moveaxis(np.abs(a - b), frame_axis, 0).reshape(out.shape[0], -1)
        out |= (d > tol).any(axis=1)
    return out


def layout_mismatch(prev: FitPrevious, new: FitCheckpoints, body_model: str, rig: str) -> str:
    """Why ``prev`` cannot be reused for inputs ``new`` ("" when it can)."""
    ck = prev.checkpoints
    if prev.bodyfit.body_model != body_model or prev.bodyfit.rig != rig:
        return f"body model changed ({prev.bodyfit.body_model}/{prev.bodyfit.rig} -> {body_model}/{rig})"
    if not np.array_equal(ck.frame_indices, new.frame_indices) or not np.array_equal(
        prev.bodyfit.frame_indices, new.frame_indices
    ):
        return f"frames changed ({ck.frame_indices.size} -> {new.frame_indices.size})"
    if not np.array_equal(ck.person_ids, new.person_ids) or not np.array_equal(
        prev.bodyfit.person_ids, new.person_ids
    ):
        return f"persons changed ({ck.person_ids.tolist()} -> {new.person_ids.tolist()})"
    if not np.array_equal(ck.fitted, new.fitted):
        return f"fitted persons changed ({ck.fitted.tolist()} -> {new.fitted.tolist()})"
    if ck.uv_px.shape != new.uv_px.shape:
        return f"views changed ({ck.uv_px.shape[0]} -> {new.uv_px.shape[0]})"
    return ""


def free_frames(changed: np.ndarray, margin: int) -> np.ndarray:
    """(frames,) the changed frames grown by ``margin`` frames on each side."""
    out = changed.copy()
    for k in range(1, margin + 1):
        out[k:] |= changed[:-k]
        out[:-k] |= changed[k:]
    return out


def refit_span(free: np.ndarray, accel_adapt_window: int) -> tuple[int, int]:
    """Frames [lo, hi) the re-fit covers: the free frames and the context on each side
    (``CONTEXT_FRAMES``, more for a wider adaptive acceleration window)."""
    ctx = max(CONTEXT_FRAMES, 3 + accel_adapt_window)
    idx = np.flatnonzero(free)
    return max(int(idx[0]) - ctx, 0), min(int(idx[-1]) + 1 + ctx, free.shape[0])
