"""DeepMimic mocap clips as motion of the synthetic athletes (world z-up, metres).

The clips and the DeepMimic humanoid ship in the ``pybullet`` wheel (zlib licence); their
reader and the mapping of the DeepMimic joints onto ``COCO17_FEET`` are those of the pose
prior (:mod:`pipeline.priors.build`). One clip becomes one athlete's motion in four steps:

1. :func:`clip_keypoints_dm`: key frames -> ``COCO17_FEET`` points of the DeepMimic
   character (its own proportions; y-up converted to z-up, floor at z = 0).
2. :func:`loop_clip`: looped (or trimmed) to the bout length and resampled to its fps.
   A looping clip (``"Loop": "wrap"``) starts each cycle on the foot that stands at the
   end of the last one (turned and shifted to keep it in place), the rest of the pose
   mismatch faded out over ``BLEND_S``; a one-shot clip (punch, kick) starts its next
   cycle where the last one's pelvis and heading ended, cross-faded over ``BLEND_S``.
3. :func:`retarget_to_body`: every segment keeps its direction and gets the length of a
   synthetic athlete's ``BodyDims``; the pelvis path is scaled by the leg-length ratio.
   The face and foot points are rigid offsets (``face_offsets``, ``foot_offsets``) in
   head and foot frames taken from the clip, so bone lengths are exact.
4. :func:`floor_and_contact`: foot contact labels from foot height and speed, and a
   smooth vertical shift that puts the feet in contact on the floor.
"""

from __future__ import annotations

import json

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import gaussian_filter1d

from pipeline.priors.build import DEFAULT_CLIPS, clip_keypoints, clip_path, load_clip, load_skeleton
from pipeline.synthetic.skeleton import SOLE_HEIGHT_M, BodyDims, J, face_offsets, foot_offsets

CLIPS: tuple[str, ...] = DEFAULT_CLIPS
"""Names of the DeepMimic humanoid clips (``humanoid3d_<name>.txt``)."""

BLEND_S = 0.25
"""Cross-fade (seconds) between two cycles of a one-shot clip (its last and first poses differ)."""

CONTACT_HEIGHT_M = 0.03
"""A foot is in contact while its lowest point is within this of ``SOLE_HEIGHT_M`` (m) ..."""

CONTACT_SPEED_MPS = 0.35
"""... and its centre (and, to count as planted, its slowest heel/toe point) moves slower
than this horizontally (m/s)."""

PLANT_HEIGHT_M = 0.08
"""Before the floor correction, a slow foot counts as planted up to this high above
``SOLE_HEIGHT_M`` (mocap feet float a few cm when the floor is not level)."""

MIN_RUN = 3
"""Contact and non-contact runs shorter than this many frames are flipped (gaps first)."""

_NOSE_TILT = float(np.arctan2(0.08, 0.40))  # DeepMimic's nose sits 0.08 below the head centre, 0.40 ahead
_SIDES = ("left", "right")


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def clip_keypoints_dm(name: str) -> tuple[np.ndarray, float, bool]:
    """Clip ``name``: ((K, 23, 3) key-frame points of the DeepMimic character, z-up metres,
    key-frame interval in seconds, whether the clip loops). ``ValueError`` for an unknown
    clip, ``ImportError`` without pybullet."""
    if name not in CLIPS:
        raise ValueError(f"unknown DeepMimic clip {name!r}; choose from {list(CLIPS)}")
    frames = load_clip(name)
    dt = float(np.median(frames[:-1, 0]))
    if not dt > 0:
        raise ValueError(f"{clip_path(name)}: key-frame durations must be > 0, got {dt}")
    loops = json.loads(clip_path(name).read_text()).get("Loop") == "wrap"
    return clip_keypoints(frames, load_skeleton()), dt, loops


def root_frame(kp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(…, 2) pelvis position on the floor and (…,) facing yaw (rad, 0 = +x) of (…, 23, 3)
    points; the facing is perpendicular to the hip and shoulder lines."""
    left = kp[..., J["left_hip"], :] - kp[..., J["right_hip"], :]
    left = left + kp[..., J["left_shoulder"], :] - kp[..., J["right_shoulder"], :]
    pelvis = 0.5 * (kp[..., J["left_hip"], :2] + kp[..., J["right_hip"], :2])
    return pelvis, np.arctan2(-left[..., 0], left[..., 1])


def start_frame(kp: np.ndarray) -> tuple[np.ndarray, float]:
    """``root_frame`` of one pose (23, 3): (pelvis xy, facing yaw in rad)."""
    xy, yaw = root_frame(kp)
    return xy, float(yaw)


def _rot_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def move_to(kp: np.ndarray, src: tuple[np.ndarray, float], dst: tuple[np.ndarray, float]) -> np.ndarray:
    """Rigidly move (…, 23, 3) points about z so that root frame ``src`` (pelvis xy, yaw)
    lands on ``dst``."""
    R = _rot_z(dst[1] - src[1])
    out = (kp - np.r_[src[0], 0.0]) @ R.T
    return out + np.r_[dst[0], 0.0]


def _lower_foot(pose: np.ndarray) -> list[int]:
    """Indices of the sole points (heel, big toe, small toe) and ankle of the lower foot of one pose (23, 3)."""
    sides = [[J[f"{s}_{p}"] for p in ("heel", "big_toe", "small_toe", "ankle")] for s in _SIDES]
    return min(sides, key=lambda idx: float(pose[idx[:3], 2].mean()))


def _continue_cycle(kp: np.ndarray, last: np.ndarray, n_blend: int) -> np.ndarray:
    """The looping clip ``kp`` (K, 23, 3) as the cycle after one that ended in pose ``last``
    (23, 3): turned about z and shifted so that ``last``'s lower (planted) foot keeps its
    place (least squares over its sole points and ankle), then the rest of the first pose's
    mismatch with ``last`` faded out over ``n_blend`` key frames (a raised cosine), so the
    cycle starts exactly at ``last`` and the planted foot does not jump."""
    idx = _lower_foot(last)
    p, q = kp[0, idx, :2], last[idx, :2]
    pc, qc = p - p.mean(0), q - q.mean(0)
    yaw = float(np.arctan2(np.sum(pc[:, 0] * qc[:, 1] - pc[:, 1] * qc[:, 0]), np.sum(pc * qc)))
    R = _rot_z(yaw)
    out = kp @ R.T
    out[..., :2] += q.mean(0) - p.mean(0) @ R[:2, :2].T
    n = min(n_blend, kp.shape[0] - 1)
    fade = 0.5 + 0.5 * np.cos(np.pi * np.arange(n) / n)  # 1 -> 0
    out[:n] += (last - out[0]) * fade[:, None, None]
    return out


def loop_clip(
    kp: np.ndarray, dt_s: float, loops: bool, n_frames: int, fps: float, start_s: float = 0.0
) -> np.ndarray:
    """(n_frames, 23, 3) points at ``fps``: the clip from ``start_s`` (seconds into it),
    looped as long as needed (see the module docstring), cubic-spline resampled."""
    n_key = kp.shape[0]
    if n_key < 3:
        raise ValueError(f"a DeepMimic clip needs >= 3 key frames, got {n_key}")
    n_blend = 0 if loops else min(max(2, int(round(BLEND_S / dt_s))), n_key // 3)
    need_s = start_s + (n_frames - 1) / fps
    seq = kp.copy()
    prev = kp
    while (seq.shape[0] - 1) * dt_s < need_s + 2 * dt_s:
        if loops:
            nxt = _continue_cycle(kp, prev[-1], max(2, int(round(BLEND_S / dt_s))))
            seq = np.concatenate([seq, nxt[1:]])
        else:
            nxt = move_to(kp, start_frame(kp[0]), start_frame(prev[n_key - n_blend]))
            w = 0.5 - 0.5 * np.cos(np.pi * (np.arange(n_blend) + 1) / (n_blend + 1))  # 0 -> 1
            head = seq[-n_blend:] * (1 - w[:, None, None]) + nxt[:n_blend] * w[:, None, None]
            seq = np.concatenate([seq[:-n_blend], head, nxt[n_blend:]])
        prev = nxt
    t = start_s + np.arange(n_frames) / fps
    return np.asarray(CubicSpline(np.arange(seq.shape[0]) * dt_s, seq, axis=0)(t))


def leg_length_m(kp: np.ndarray) -> float:
    """Median hip-knee-ankle length of (…, 23, 3) points (both sides)."""
    out = []
    for side in _SIDES:
        hip, knee, ankle = (kp[..., J[f"{side}_{p}"], :] for p in ("hip", "knee", "ankle"))
        out.append(np.linalg.norm(knee - hip, axis=-1) + np.linalg.norm(ankle - knee, axis=-1))
    return float(np.median(np.concatenate([o.ravel() for o in out])))


def _head_frame(kp: np.ndarray) -> np.ndarray:
    """(F, 3, 3) head rotation (columns: forward, left, up) from the clip's nose and ears."""
    centre = 0.5 * (kp[:, J["left_ear"]] + kp[:, J["right_ear"]])
    y = _unit(kp[:, J["left_ear"]] - kp[:, J["right_ear"]])
    a = kp[:, J["nose"]] - centre
    a = _unit(a - np.sum(a * y, -1, keepdims=True) * y)
    x = np.cos(_NOSE_TILT) * a + np.sin(_NOSE_TILT) * np.cross(a, y)  # undo the nose's downward tilt
    return np.stack([x, y, np.cross(x, y)], axis=-1)


def _foot_frame(kp: np.ndarray, side: str) -> np.ndarray:
    """(F, 3, 3) foot rotation (columns: along the foot, left, up) from the clip's sole points."""
    heel, big, small = (kp[:, J[f"{side}_{p}"]] for p in ("heel", "big_toe", "small_toe"))
    up = _unit(np.cross(big - heel, small - heel))
    up *= np.sign(np.sum((kp[:, J[f"{side}_ankle"]] - heel) * up, -1, keepdims=True))
    fwd = kp[:, J[f"{side}_ankle"]] - heel  # above the heel and ahead of it along the sole
    fwd = _unit(fwd - np.sum(fwd * up, -1, keepdims=True) * up)
    return np.stack([fwd, np.cross(up, fwd), up], axis=-1)


def retarget_to_body(kp_dm: np.ndarray, body: BodyDims) -> np.ndarray:
    """(F, 23, 3) points of an athlete with ``body``'s segment lengths performing the
    clip's motion ``kp_dm`` (F, 23, 3): same segment directions, pelvis path scaled by
    the ratio of leg lengths. Hip, shoulder, limb, trunk (pelvis to shoulder centre) and
    neck (shoulder centre to head centre) lengths equal ``body``'s; face and foot points
    are ``body``'s rigid offsets in the clip's head and foot frames."""
    d = kp_dm
    out = np.zeros_like(d)
    scale = body.leg_m / leg_length_m(d)
    pelvis_dm = 0.5 * (d[:, J["left_hip"]] + d[:, J["right_hip"]])
    pelvis = pelvis_dm * scale

    def seg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return _unit(b - a)

    hip_dir = seg(d[:, J["right_hip"]], d[:, J["left_hip"]])
    out[:, J["left_hip"]] = pelvis + body.hip_half_m * hip_dir
    out[:, J["right_hip"]] = pelvis - body.hip_half_m * hip_dir
    neck_dm = 0.5 * (d[:, J["left_shoulder"]] + d[:, J["right_shoulder"]])
    neck = pelvis + body.torso_m * seg(pelvis_dm, neck_dm)
    sho_dir = seg(d[:, J["right_shoulder"]], d[:, J["left_shoulder"]])
    out[:, J["left_shoulder"]] = neck + body.shoulder_half_m * sho_dir
    out[:, J["right_shoulder"]] = neck - body.shoulder_half_m * sho_dir
    for side in _SIDES:
        for a, b, length in (
            ("shoulder", "elbow", body.upper_arm_m),
            ("elbow", "wrist", body.forearm_m),
            ("hip", "knee", body.thigh_m),
            ("knee", "ankle", body.shank_m),
        ):
            ja, jb = J[f"{side}_{a}"], J[f"{side}_{b}"]
            out[:, jb] = out[:, ja] + length * seg(d[:, ja], d[:, jb])
        R_foot = _foot_frame(d, side)
        ankle = out[:, J[f"{side}_ankle"]]
        for name, off in foot_offsets(body, side).items():
            if name != f"{side}_ankle":
                out[:, J[name]] = ankle + R_foot @ (off - np.array([0.0, 0.0, body.ankle_height_m]))
    head_dm = 0.5 * (d[:, J["left_ear"]] + d[:, J["right_ear"]])
    head = neck + neck_length_m(body) * seg(neck_dm, head_dm)
    R_head = _head_frame(d)
    for name, off in face_offsets(body).items():
        out[:, J[name]] = head + R_head @ off
    return out


def neck_length_m(body: BodyDims) -> float:
    """Shoulder centre to head centre, as the synthetic bout places the head."""
    return float(np.hypot(0.01 * body.height_m, body.neck_m))


def _foot_lowest_and_speed(kp: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(F, 2) lowest heel/toe height of each foot, the horizontal speed (m/s) of its
    slowest heel/toe point (the point a rolling foot pivots on) and of its centre (the
    mean of heel and toes, whose motion the skating metric measures)."""
    low = np.zeros((kp.shape[0], 2))
    pivot = np.zeros((kp.shape[0], 2))
    centre = np.zeros((kp.shape[0], 2))
    for k, side in enumerate(_SIDES):
        pts = kp[:, [J[f"{side}_{p}"] for p in ("heel", "big_toe", "small_toe")]]
        low[:, k] = pts[..., 2].min(axis=1)
        v = np.gradient(pts[..., :2], axis=0) * fps
        pivot[:, k] = np.linalg.norm(v, axis=-1).min(axis=1)
        centre[:, k] = np.linalg.norm(v.mean(axis=1), axis=-1)
    return low, pivot, centre


def _runs(x: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of the runs of equal values of a 1D bool array."""
    edges = np.flatnonzero(np.diff(x.astype(np.int8))) + 1
    bounds = np.r_[0, edges, x.size]
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def _clean_runs(x: np.ndarray, min_run: int) -> np.ndarray:
    """Fill interior False runs shorter than ``min_run``, then drop True runs shorter than it
    (a run touching either end is kept: it may continue outside the clip)."""
    out = x.copy()
    for value in (False, True):
        for a, b in _runs(out):
            if out[a] == value and b - a < min_run and a > 0 and b < out.size:
                out[a:b] = not value
    return out


def floor_and_contact(kp: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Put the feet on the floor: ((F, 23, 3) points, (F, 2) bool left/right contact).

    A constant shift first brings the lowest foot points (5th percentile over frames) to
    ``SOLE_HEIGHT_M``. A foot is planted while slow (``CONTACT_SPEED_MPS``) and within
    ``PLANT_HEIGHT_M`` of the floor (slow: its slowest heel/toe point); a smooth per-frame vertical shift of the whole body
    (interpolated across flight phases) sets the lower planted foot to ``SOLE_HEIGHT_M``.
    The contact labels are the planted frames whose foot centre is also slow (a foot
    rolling over its heel or toes is not labelled) and whose foot then lies within
    ``CONTACT_HEIGHT_M`` of ``SOLE_HEIGHT_M``; runs and gaps under ``MIN_RUN`` frames are
    removed."""
    out = kp.copy()
    low = _foot_lowest_and_speed(out, fps)[0]
    out[..., 2] -= np.percentile(low.min(axis=1), 5) - SOLE_HEIGHT_M
    low, pivot, centre = _foot_lowest_and_speed(out, fps)
    planted = _clean(pivot <= CONTACT_SPEED_MPS) & (low <= SOLE_HEIGHT_M + PLANT_HEIGHT_M)
    err = np.where(planted, low - SOLE_HEIGHT_M, np.inf).min(axis=1)
    has = np.isfinite(err)
    if has.any():
        f = np.arange(out.shape[0])
        shift = np.interp(f, f[has], err[has])
        out[..., 2] -= gaussian_filter1d(shift, 1.5, mode="nearest")[:, None]
    low = _foot_lowest_and_speed(out, fps)[0]
    contact = _clean(
        planted & (centre <= CONTACT_SPEED_MPS) & (np.abs(low - SOLE_HEIGHT_M) <= CONTACT_HEIGHT_M)
    )
    return out, contact


def _clean(contact: np.ndarray) -> np.ndarray:
    return np.stack([_clean_runs(contact[:, k], MIN_RUN) for k in range(contact.shape[1])], axis=1)
