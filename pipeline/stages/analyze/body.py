"""Per-athlete joint tracks for the analytics: short gaps filled, named points, facing frames."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry.segments import point_weights
from pipeline.schema.keypoints3d import Keypoints3D

UP = np.array([0.0, 0.0, 1.0])


def fill_gaps(x: np.ndarray, ok: np.ndarray, max_gap: int) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation over interior runs of at most ``max_gap`` invalid frames.

    ``x`` (F, ...) values, ``ok`` (F,) bool. Returns copies; longer or open-ended gaps
    stay invalid (their values are left as they were)."""
    x, ok = x.copy(), ok.copy()
    good = np.flatnonzero(ok)
    if good.size < 2 or max_gap <= 0:
        return x, ok
    d = np.diff(good)
    for i in np.flatnonzero((d > 1) & (d <= max_gap + 1)):
        a, b = good[i], good[i + 1]
        w = (np.arange(a + 1, b) - a) / (b - a)
        w = w.reshape((-1,) + (1,) * (x.ndim - 1))
        x[a + 1 : b] = (1 - w) * x[a] + w * x[b]
        ok[a + 1 : b] = True
    return x, ok


@dataclass(frozen=True)
class Body:
    """One athlete's joints over the analysed frames.

    Fields: person_id; names (joints,); xyz (frames, joints, 3) metres, world z-up; ok
    (frames, joints) bool (estimate present, gaps up to ``max_gap_frames`` filled);
    confidence (frames, joints) in [0, 1]; fps.
    """

    person_id: int
    names: tuple[str, ...]
    xyz: np.ndarray
    ok: np.ndarray
    confidence: np.ndarray
    fps: float

    @property
    def n_frames(self) -> int:
        return int(self.xyz.shape[0])

    def point(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(frames, 3) position and (frames,) validity of a named point (a joint, ``mid:a+b``
        or ``frac:a,b,t``; ``geometry.segments.point_weights``)."""
        idx, w = point_weights(name, self.names)
        pos = sum(wk * self.xyz[:, i] for i, wk in zip(idx, w, strict=True))
        return np.asarray(pos), np.logical_and.reduce([self.ok[:, i] for i in idx])

    def has(self, *names: str) -> bool:
        return all(n in self.names for n in names)


def bodies(kp: Keypoints3D, max_gap: int) -> list[Body]:
    """One ``Body`` per person of ``kp``, each joint's short gaps filled."""
    out = []
    for p in range(kp.n_persons):
        xyz = np.where(kp.valid[:, p, :, None], kp.xyz_m[:, p], 0.0)
        ok = kp.valid[:, p].copy()
        for j in range(len(kp.joint_names)):
            xyz[:, j], ok[:, j] = fill_gaps(xyz[:, j], ok[:, j], max_gap)
        conf = np.where(ok, np.clip(kp.confidence[:, p], 0.0, 1.0), 0.0)
        out.append(Body(int(kp.person_ids[p]), kp.joint_names, xyz, ok, conf, float(kp.fps)))
    return out


def opponent_of(bs: list[Body], i: int) -> Body | None:
    """The other athlete nearest to athlete ``i`` over the bout (median mid-hip distance);
    None when alone."""
    me, ok = bs[i].point("mid:left_hip+right_hip")
    best, best_d = None, np.inf
    for k, b in enumerate(bs):
        if k == i:
            continue
        q, qk = b.point("mid:left_hip+right_hip")
        both = ok & qk
        if both.any():
            d = float(np.median(np.linalg.norm((me - q)[both, :2], axis=1)))
            if d < best_d:
                best, best_d = b, d
    return best


def facing_frames(me: Body, opp: Body | None) -> tuple[np.ndarray, np.ndarray]:
    """(frames, 3, 3) rotations R_world_facing (columns: x towards the opponent's neck,
    horizontal; y to the athlete's left; z up) and (frames,) validity. Where the opponent
    is unknown, x is the torso's forward direction (shoulder line x up)."""
    neck, ok = me.point("mid:left_shoulder+right_shoulder")
    ls, lok = me.point("left_shoulder")
    rs, rok = me.point("right_shoulder")
    torso_fwd = np.cross(ls - rs, UP)
    fwd = torso_fwd.copy()
    fwd_ok = lok & rok
    if opp is not None:
        on, o_ok = opp.point("mid:left_shoulder+right_shoulder")
        to_opp = on - neck
        to_opp[:, 2] = 0.0
        use = o_ok & ok & (np.linalg.norm(to_opp, axis=1) > 1e-3)
        fwd[use] = to_opp[use]
        fwd_ok = fwd_ok | use
    fwd[:, 2] = 0.0
    n = np.linalg.norm(fwd, axis=1)
    fwd_ok &= n > 1e-6
    x = fwd / np.maximum(n, 1e-9)[:, None]
    y = np.cross(UP, x)
    z = np.broadcast_to(UP, x.shape)
    return np.stack([x, y, z], axis=2), fwd_ok & ok


def to_local(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """World vectors (frames, 3) in the frames ``R`` (frames, 3, 3): R^T v."""
    return np.einsum("fji,fj->fi", R, v)
