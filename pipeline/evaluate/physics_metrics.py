"""Physical plausibility and accuracy metrics of 3D motion (pure numpy).

Every metric works on a ``Keypoints3D`` (COCO-17, feet optional), so the kinematic
input, the physics output and ground truth are scored the same way. Inter-person
penetration uses capsule proxies of the body built from the joints (same radii for
every method), so it does not depend on the simulator's geometry.

Units: mm, frames at the sequence's fps. Foot contact is a (frames, persons, 2)
bool mask (left, right), e.g. the synthetic bout's ``foot_contact``; without it,
a foot is in contact when its lowest point is below ``contact_height_m``. Foot skating
is also split into the first and last step of each stance (``foot_skate_edge_*``: a
foot settling or rolling off, within a frame of the labelled touchdown) and the steps
in between (``foot_skate_interior_*``: a planted foot sliding).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry.segments import point_weights, segment_distance
from pipeline.schema.keypoints3d import Keypoints3D


@dataclass(frozen=True)
class CapsuleProxy:
    """Body capsules between two points, ``(a, b, radius_m)``; ``a == b`` gives a sphere.

    A point is a joint name, ``"mid:a+b"`` (the midpoint of two joints) or
    ``"frac:a,b,t"`` (``a + t (b - a)``; ``t`` may lie outside [0, 1], e.g. past the
    wrist). ``pipeline.geometry.segments.point_weights`` resolves them.

    The default is an average adult in boxing gloves, for athletes of 1.70-1.85 m,
    measured on anny's average body (``girth_prior`` 0.5, 0.5: what the fit assumes and
    the physics stage collides), whose trunk is 35-39 cm wide and 22-25 cm deep: the
    trunk as two vertical capsules side by side (r 11 cm, 35 cm wide), a capsule across
    the hips, the head (r 10 cm), upper arms 5.5 cm, forearms 4.5 cm, gloves (a sphere of
    6.5 cm around the fist, its centre ~6.5 cm past the wrist), thighs 8.5 cm and shins
    5.5 cm. The synthetic bout separates its boxers with these volumes, so ground truth
    does not interpenetrate in them.
    """

    segments: tuple[tuple[str, str, float], ...] = (
        ("frac:right_hip,left_hip,0.8", "frac:right_shoulder,left_shoulder,0.7", 0.11),
        ("frac:left_hip,right_hip,0.8", "frac:left_shoulder,right_shoulder,0.7", 0.11),
        ("left_hip", "right_hip", 0.11),
        ("mid:left_ear+right_ear", "mid:left_ear+right_ear", 0.10),
        ("left_shoulder", "left_elbow", 0.055),
        ("right_shoulder", "right_elbow", 0.055),
        ("left_elbow", "left_wrist", 0.045),
        ("right_elbow", "right_wrist", 0.045),
        ("frac:left_elbow,left_wrist,1.25", "frac:left_elbow,left_wrist,1.25", 0.065),
        ("frac:right_elbow,right_wrist,1.25", "frac:right_elbow,right_wrist,1.25", 0.065),
        ("left_hip", "left_knee", 0.085),
        ("right_hip", "right_knee", 0.085),
        ("left_knee", "left_ankle", 0.055),
        ("right_knee", "right_ankle", 0.055),
    )


def _point(kp: Keypoints3D, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(frames, persons, 3) positions and (frames, persons) validity of a proxy point."""
    idx, w = point_weights(name, kp.joint_names)
    pos = sum(wk * kp.xyz_m[:, :, i] for i, wk in zip(idx, w, strict=True))
    ok = np.logical_and.reduce([kp.valid[:, :, i] for i in idx])
    return np.asarray(pos), ok


def inter_person_penetration_mm(kp: Keypoints3D, proxy: CapsuleProxy = CapsuleProxy()) -> np.ndarray:
    """(frames,) deepest capsule overlap between any two persons, mm (0 = none)."""
    F, P = kp.n_frames, kp.n_persons
    ends = [(_point(kp, a), _point(kp, b), r) for a, b, r in proxy.segments]
    out = np.zeros(F)
    for i in range(P):
        for j in range(i + 1, P):
            for (pa, va), (pb, vb), ri in ends:
                for (qa, wa), (qb, wb), rj in ends:
                    dist = segment_distance(pa[:, i], pb[:, i], qa[:, j], qb[:, j])
                    ok = va[:, i] & vb[:, i] & wa[:, j] & wb[:, j]
                    pen = np.where(ok, np.maximum(ri + rj - dist, 0.0), 0.0)
                    out = np.maximum(out, pen)
    return 1000.0 * out


def _foot_points(kp: Keypoints3D) -> dict[str, list[int]]:
    out = {}
    for side in ("left", "right"):
        names = [f"{side}_heel", f"{side}_big_toe", f"{side}_small_toe"]
        idx = [kp.joint_names.index(n) for n in names if n in kp.joint_names]
        out[side] = idx if idx else [kp.joint_names.index(f"{side}_ankle")]
    return out


def foot_contact_from_height(kp: Keypoints3D, contact_height_m: float = 0.03) -> np.ndarray:
    """(frames, persons, 2) contact estimate: lowest foot point below the threshold."""
    fp = _foot_points(kp)
    out = np.zeros((kp.n_frames, kp.n_persons, 2), dtype=bool)
    for k, side in enumerate(("left", "right")):
        z = kp.xyz_m[:, :, fp[side], 2].min(axis=-1)
        out[..., k] = z < contact_height_m
    return out


def stance_edge_steps(contact: np.ndarray) -> np.ndarray:
    """(frames - 1, ...) True for the steps f -> f+1 that are the first or the last of a
    stance: both frames in contact (``contact`` (frames, ...) bool) but f - 1 or f + 2
    not. A stance running past either end of the clip continues there (no edge).

    The skating of these steps (the foot settling as it lands, or starting to roll off)
    is reported apart from the interior of the stance (``physics_metrics``): the ground
    truth's contact labels put the touchdown at a frame that an estimate hits only to
    within a frame."""
    c = np.asarray(contact, dtype=bool)
    if c.shape[0] < 2:
        return np.zeros((0,) + c.shape[1:], dtype=bool)
    padded = np.concatenate([c[:1], c, c[-1:]], axis=0)  # padded[f + 1] = c[f]
    both = c[1:] & c[:-1]
    return both & ~(padded[:-3] & padded[3:])


def _smooth_diff(x: np.ndarray, order: int) -> np.ndarray:
    for _ in range(order):
        x = np.diff(x, axis=0)
    return x


def physics_metrics(
    kp: Keypoints3D,
    gt: Keypoints3D | None = None,
    foot_contact: np.ndarray | None = None,
    proxy: CapsuleProxy = CapsuleProxy(),
) -> dict[str, float]:
    """All metrics of one motion; ``gt`` enables MPJPE / acceleration / foot-height errors.

    ``gt`` must have the same frames and persons (matched by id); joints are matched
    by name. Raises ``ValueError`` on mismatched extents.
    """
    pen = inter_person_penetration_mm(kp, proxy)
    z = np.where(kp.valid, kp.xyz_m[..., 2], np.inf)
    ground = 1000.0 * np.maximum(-z.min(axis=-1), 0.0)  # (frames, persons)
    contact = foot_contact if foot_contact is not None else foot_contact_from_height(kp)
    if contact.shape != (kp.n_frames, kp.n_persons, 2):
        raise ValueError(f"foot_contact shape {contact.shape} != {(kp.n_frames, kp.n_persons, 2)}")
    fp = _foot_points(kp)
    skate: list[np.ndarray] = []
    edge: list[np.ndarray] = []
    for k, side in enumerate(("left", "right")):
        xy = kp.xyz_m[:, :, fp[side], :2].mean(axis=2)  # (F, P, 2)
        step = np.linalg.norm(np.diff(xy, axis=0), axis=-1)  # (F-1, P)
        both = contact[1:, :, k] & contact[:-1, :, k]
        skate.append(step[both])
        edge.append(stance_edge_steps(contact[:, :, k])[both])
    skate_all = np.concatenate(skate) if skate else np.zeros(0)
    is_edge = np.concatenate(edge) if edge else np.zeros(0, dtype=bool)
    speed = skate_all * kp.fps
    acc = np.linalg.norm(_smooth_diff(kp.xyz_m, 2), axis=-1)
    jerk = np.linalg.norm(_smooth_diff(kp.xyz_m, 3), axis=-1)
    out: dict[str, float] = {
        "inter_penetration_max_mm": float(pen.max(initial=0.0)),
        "inter_penetration_mean_mm": float(pen.mean()) if pen.size else 0.0,
        "ground_penetration_max_mm": float(ground.max(initial=0.0)),
        "ground_penetration_mean_mm": float(ground.mean()) if ground.size else 0.0,
        "foot_skate_mm_per_frame": float(1000.0 * skate_all.mean()) if skate_all.size else 0.0,
        "foot_skate_edge_mm_per_frame": float(1000.0 * skate_all[is_edge].mean()) if is_edge.any() else 0.0,
        "foot_skate_interior_mm_per_frame": float(1000.0 * skate_all[~is_edge].mean()) if (~is_edge).any() else 0.0,
        "foot_speed_contact_mm_s": float(1000.0 * speed.mean()) if speed.size else 0.0,
        "accel_mm_per_frame2": float(1000.0 * acc.mean()) if acc.size else 0.0,
        "jerk_mm_per_frame3": float(1000.0 * jerk.mean()) if jerk.size else 0.0,
    }
    if gt is not None:
        if gt.n_frames != kp.n_frames:
            raise ValueError(f"gt has {gt.n_frames} frames, prediction {kp.n_frames}")
        prow = [gt.person_index(int(p)) for p in kp.person_ids]
        names = [n for n in kp.joint_names if n in gt.joint_names]
        ip = [kp.joint_names.index(n) for n in names]
        ig = [gt.joint_names.index(n) for n in names]
        a = kp.xyz_m[:, :, ip]
        b = gt.xyz_m[:, prow][:, :, ig]
        ok = kp.valid[:, :, ip] & gt.valid[:, prow][:, :, ig]
        err = np.linalg.norm(a - b, axis=-1)
        out["mpjpe_mm"] = float(1000.0 * err[ok].mean()) if ok.any() else float("nan")
        acc_err = np.linalg.norm(_smooth_diff(a, 2) - _smooth_diff(b, 2), axis=-1)
        out["accel_err_mm_per_frame2"] = float(1000.0 * acc_err.mean()) if acc_err.size else 0.0
        fh = []
        gfp = _foot_points(gt)
        for k, side in enumerate(("left", "right")):
            zp = kp.xyz_m[:, :, fp[side], 2].min(axis=-1)
            zg = gt.xyz_m[:, prow][:, :, gfp[side], 2].min(axis=-1)
            fh.append(np.abs(zp - zg)[contact[:, :, k]])
        fh_all = np.concatenate(fh)
        out["foot_height_err_contact_mm"] = float(1000.0 * fh_all.mean()) if fh_all.size else 0.0
    return out
