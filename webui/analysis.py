"""Per-frame diagnostics for the timeline and the plots (pure numpy).

Problem frames are where an analyst should look first: low identity confidence
(association), high reprojection error, deep inter-person penetration, and a physics
result held up by a residual root force or over human joint torques, as the evaluate
stage flagged them (``pipeline.stages.evaluate.problem_flags``, kinds ``FLAG_KINDS``).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass

import numpy as np

from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.stages.evaluate import FLAG_KINDS, EvaluateConfig
from webui.scene.session_data import SessionData


@dataclass(frozen=True)
class FrameProblems:
    """(frames, kinds) bool flags on the viewer's timeline, one column per ``FLAG_KINDS`` entry."""

    flags: np.ndarray

    def __post_init__(self) -> None:
        if self.flags.ndim != 2 or self.flags.shape[1] != len(FLAG_KINDS):
            raise ValueError(f"FrameProblems: flags of shape {self.flags.shape}, expected (frames, {len(FLAG_KINDS)})")

    @classmethod
    def none(cls, n_frames: int) -> FrameProblems:
        """Nothing flagged on ``n_frames`` frames."""
        return cls(np.zeros((n_frames, len(FLAG_KINDS)), dtype=bool))

    def of(self, key: str) -> np.ndarray:
        """(frames,) flags of kind ``key`` (a ``FlagKind.key``); ``ValueError`` for an unknown kind."""
        keys = [k.key for k in FLAG_KINDS]
        if key not in keys:
            raise ValueError(f"unknown problem kind {key!r}; known: {keys}")
        return self.flags[:, keys.index(key)]

    @property
    def any(self) -> np.ndarray:
        return np.asarray(self.flags.any(axis=1))

    @property
    def n_frames(self) -> int:
        return int(self.flags.shape[0])

    def kinds_at(self, frame: int) -> list[str]:
        """Labels of the kinds flagged at ``frame``, in ``FLAG_KINDS`` order."""
        return [k.label for k, on in zip(FLAG_KINDS, self.flags[frame], strict=True) if on]

    def counts(self) -> dict[str, int]:
        """Flagged frames per kind, by ``FlagKind.key``."""
        return {k.key: int(n) for k, n in zip(FLAG_KINDS, self.flags.sum(axis=0), strict=True)}

    def next_after(self, frame: int, kind: str | None = None) -> int | None:
        """First flagged frame strictly after ``frame``, wrapping around; None when nothing is flagged.

        ``kind``: a ``FlagKind.key`` to visit only that kind, None for any. Consecutive flagged
        frames count as one problem: the search skips to the end of the run containing
        ``frame`` first, so repeated clicks visit each problem once.
        """
        flags = self.any if kind is None else self.of(kind)
        if not flags.any():
            return None
        n = flags.shape[0]
        f = int(frame)
        while 0 <= f < n and flags[f]:
            f += 1
        order = np.r_[np.arange(f, n), np.arange(0, min(f, n))]
        hits = order[flags[order]]
        return int(hits[0]) if hits.size else None

    def segments(self) -> list[tuple[int, int]]:
        """Inclusive (start, end) runs of flagged frames."""
        flags = self.any.astype(np.int8)
        d = np.diff(np.r_[0, flags, 0])
        starts = np.flatnonzero(d == 1)
        ends = np.flatnonzero(d == -1) - 1
        return list(zip(starts.tolist(), ends.tolist(), strict=True))


def per_frame_reproj_error(kp: Keypoints3D, n_frames: int) -> np.ndarray:
    """(frames, persons) mean reprojection error over valid joints, NaN where unknown."""
    err = np.where(kp.valid & np.isfinite(kp.reproj_err_px), kp.reproj_err_px, np.nan)
    out = np.full((n_frames, kp.n_persons), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows are expected (person absent)
        m = np.nanmean(err, axis=2)
    keep = kp.frame_indices < n_frames
    out[kp.frame_indices[keep]] = m[keep]
    return out


def compute_problems(data: SessionData) -> FrameProblems:
    """The evaluate stage's per-frame flags (``evaluate/problems.npz``) on the viewer's frames;
    none while that stage has not run. One definition of a problem: ``pipeline.stages.evaluate``."""
    n = data.n_frames
    out = FrameProblems.none(n)
    pf = data.problems
    if pf is not None:
        keep = (pf.frame_indices >= 0) & (pf.frame_indices < n)
        for i, kind in enumerate(FLAG_KINDS):
            col = pf.column(kind.key)  # None in a file written before the kind existed
            if col is not None:
                out.flags[pf.frame_indices[keep], i] = col[keep]
    return out


def residual_series(data: SessionData) -> tuple[np.ndarray, float] | None:
    """(frames,) residual root force of the physics result, worst athlete, in body weights
    (NaN where the evaluate stage has no value), and the flag threshold; None when physics
    did not run or the evaluate stage has not reported it."""
    pf = data.problems
    if data.physics is None or pf is None or pf.residual_frac_bw.shape != pf.frame_indices.shape:
        return None
    n = data.n_frames
    y = np.full(n, np.nan)
    keep = (pf.frame_indices >= 0) & (pf.frame_indices < n)
    y[pf.frame_indices[keep]] = pf.residual_frac_bw[keep]
    cap = data.metrics.get("physics_residual_high_frac_bw")
    return y, float(cap) if isinstance(cap, int | float) else EvaluateConfig().residual_high_frac_bw


@dataclass(frozen=True)
class PlotSeries:
    """Per-frame curves for the plots; NaN where unknown.

    Fields:
        frames: (frames,) frame indices.
        time_s: (frames,) seconds.
        person_ids: (persons,) ids matching the columns below.
        wrist_speed_mps: (frames, persons) max of both wrists' speeds, m/s.
        distance_m: (frames,) distance between the first two persons' hip centres, m.
        reproj_err_px: (frames, persons) mean reprojection error (triangulation), px.
        residual_frac_bw: (frames,) physics residual root force, worst athlete, body
            weights (``residual_series``); None when physics did not run.
        residual_cap_frac_bw: the evaluate stage's flag threshold for it, body weights.
    """

    frames: np.ndarray
    time_s: np.ndarray
    person_ids: np.ndarray
    wrist_speed_mps: np.ndarray
    distance_m: np.ndarray
    reproj_err_px: np.ndarray
    residual_frac_bw: np.ndarray | None = None
    residual_cap_frac_bw: float = EvaluateConfig().residual_high_frac_bw


def _dense(kp: Keypoints3D, n_frames: int, joint: str) -> np.ndarray:
    """(frames, persons, 3) positions of ``joint`` on the full timeline, NaN where invalid."""
    out = np.full((n_frames, kp.n_persons, 3), np.nan)
    if joint not in kp.joint_names:
        return out
    j = kp.joint_names.index(joint)
    x = np.where(kp.valid[:, :, j, None], kp.xyz_m[:, :, j], np.nan)
    keep = kp.frame_indices < n_frames
    out[kp.frame_indices[keep]] = x[keep]
    return out


def compute_series(data: SessionData, source: str) -> PlotSeries | None:
    """Curves of keypoint source ``source`` (None when that source is absent)."""
    kp = data.keypoints.get(source)
    if kp is None:
        return None
    n = data.n_frames
    fps = data.fps
    speeds = []
    for w in ("left_wrist", "right_wrist"):
        x = _dense(kp, n, w)
        v = np.full((n, kp.n_persons), np.nan)
        v[1:] = np.linalg.norm(np.diff(x, axis=0), axis=-1) * fps
        speeds.append(v)
    with np.errstate(invalid="ignore"):
        wrist = np.fmax(speeds[0], speeds[1])
    hips = (_dense(kp, n, "left_hip") + _dense(kp, n, "right_hip")) / 2
    dist = np.full(n, np.nan)
    if kp.n_persons >= 2:
        dist = np.linalg.norm(hips[:, 0, :2] - hips[:, 1, :2], axis=-1)
    tri = data.keypoints.get("filtered")
    reproj = np.full((n, kp.n_persons), np.nan)
    if tri is not None:
        e = per_frame_reproj_error(tri, n)
        for i, pid in enumerate(kp.person_ids):
            hit = np.flatnonzero(tri.person_ids == pid)
            if hit.size:
                reproj[:, i] = e[:, hit[0]]
    frames = np.arange(n)
    res = residual_series(data)
    out = PlotSeries(frames, frames / fps, kp.person_ids.copy(), wrist, dist, reproj)
    return out if res is None else dataclasses.replace(out, residual_frac_bw=res[0], residual_cap_frac_bw=res[1])


def fill_gaps(y: np.ndarray) -> np.ndarray:
    """Linear interpolation over NaN gaps for display (all-NaN -> zeros)."""
    y = np.asarray(y, dtype=np.float64)
    ok = np.isfinite(y)
    if not ok.any():
        return np.zeros_like(y)
    x = np.arange(y.shape[0])
    return np.interp(x, x[ok], y[ok])
