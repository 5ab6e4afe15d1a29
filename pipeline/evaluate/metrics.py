"""Standard multi-person 3D pose metrics (pure numpy).

Units: position errors are in **millimetres**, acceleration errors in **mm / frame^2**,
reprojection errors in **pixels** (of the distorted image), PCP and identity accuracy
are fractions in [0, 1].

Estimates and ground truth are ``Keypoints3D``; they are compared on the frames present
in both (by ``frame_indices``) and on the joints present in both (by name). Persons are
paired with ``match_persons`` unless a mapping is passed. Entries invalid in the ground
truth are skipped; entries valid in the ground truth but missing in the estimate count
as wrong for PCP and are skipped (and reported by ``coverage``) for the distance metrics.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from pipeline.geometry.projection import project
from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.joints import PCP_LIMBS, RIGID_BONES
from pipeline.schema.keypoints3d import Keypoints3D


def _align(
    est: Keypoints3D, gt: Keypoints3D, joint_names: tuple[str, ...] | None, mapping: dict[int, int] | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[str, ...]]:
    """Common frames/joints: est_xyz, est_valid, gt_xyz, gt_valid of shape (frames, gt persons, joints[, 3])."""
    names = joint_names if joint_names is not None else tuple(n for n in gt.joint_names if n in est.joint_names)
    missing = [n for n in names if n not in est.joint_names or n not in gt.joint_names]
    if missing:
        raise ValueError(f"joints {missing} are not in both joint sets")
    je = [est.joint_names.index(n) for n in names]
    jg = [gt.joint_names.index(n) for n in names]
    frames, fe, fg = np.intersect1d(est.frame_indices, gt.frame_indices, return_indices=True)
    if mapping is None:
        mapping = match_persons(est, gt)
    F, Pg, J = frames.size, gt.n_persons, len(names)
    e_xyz = np.zeros((F, Pg, J, 3))
    e_ok = np.zeros((F, Pg, J), bool)
    for pi, pid in enumerate(gt.person_ids):
        eid = mapping.get(int(pid))
        if eid is None or eid not in est.person_ids:
            continue
        ei = est.person_index(eid)
        e_xyz[:, pi] = est.xyz_m[fe][:, ei][:, je]
        e_ok[:, pi] = est.valid[fe][:, ei][:, je]
    g_xyz = gt.xyz_m[fg][:, :, jg]
    g_ok = gt.valid[fg][:, :, jg]
    return e_xyz, e_ok, g_xyz, g_ok, names


def match_persons(est: Keypoints3D, gt: Keypoints3D) -> dict[int, int]:
    """Pair ground-truth persons with estimated ones: ``{gt_person_id: est_person_id}``.

    Hungarian assignment on the mean joint distance over the frames and joints valid in
    both; persons that never overlap are left unmatched (absent from the dict).
    """
    names = tuple(n for n in gt.joint_names if n in est.joint_names)
    je = [est.joint_names.index(n) for n in names]
    jg = [gt.joint_names.index(n) for n in names]
    _, fe, fg = np.intersect1d(est.frame_indices, gt.frame_indices, return_indices=True)
    E = est.xyz_m[fe][:, :, je]  # (F, Pe, J, 3)
    G = gt.xyz_m[fg][:, :, jg]
    ok = est.valid[fe][:, :, je][:, None] & gt.valid[fg][:, :, jg][:, :, None]  # (F, Pg, Pe, J)
    d = np.linalg.norm(np.where(ok[..., None], G[:, :, None] - E[:, None], 0.0), axis=-1)
    n = ok.sum(axis=(0, 3))
    cost = np.where(n > 0, d.sum(axis=(0, 3)) / np.maximum(n, 1), np.inf)
    if cost.size == 0:
        return {}
    r, c = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e12))
    return {int(gt.person_ids[i]): int(est.person_ids[j]) for i, j in zip(r, c, strict=True) if np.isfinite(cost[i, j])}


def pcp(
    est: Keypoints3D,
    gt: Keypoints3D,
    joint_names: tuple[str, ...] | None = None,
    limbs: tuple[tuple[str, str], ...] = PCP_LIMBS,
    alpha: float = 0.5,
    mapping: dict[int, int] | None = None,
) -> float:
    """Percentage of Correct Parts as on Campus/Shelf, as a fraction in [0, 1].

    A limb (a, b) is correct when ``(|e_a - g_a| + |e_b - g_b|) / 2 <= alpha * |g_a - g_b|``.
    Limbs whose ground truth is incomplete are not scored; a missing estimate is wrong.
    ``joint_names`` restricts the joints considered (limbs outside it are skipped).
    """
    e, eo, g, go, names = _align(est, gt, joint_names, mapping)
    idx = [(names.index(a), names.index(b)) for a, b in limbs if a in names and b in names]
    if not idx:
        raise ValueError(f"no PCP limb has both joints in {names}")
    a, b = np.array(idx).T
    scored = go[..., a] & go[..., b]
    err = 0.5 * (np.linalg.norm(e[..., a, :] - g[..., a, :], axis=-1) + np.linalg.norm(e[..., b, :] - g[..., b, :], axis=-1))
    length = np.linalg.norm(g[..., a, :] - g[..., b, :], axis=-1)
    correct = eo[..., a] & eo[..., b] & (err <= alpha * length) & scored
    n = scored.sum()
    return float(correct.sum() / n) if n else float("nan")


def mpjpe(
    est: Keypoints3D, gt: Keypoints3D, joint_names: tuple[str, ...] | None = None, mapping: dict[int, int] | None = None
) -> float:
    """Mean per-joint position error in mm over entries valid in both (NaN if none)."""
    e, eo, g, go, _ = _align(est, gt, joint_names, mapping)
    ok = eo & go
    return float(np.linalg.norm(e - g, axis=-1)[ok].mean() * 1000.0) if ok.any() else float("nan")


def coverage(est: Keypoints3D, gt: Keypoints3D, mapping: dict[int, int] | None = None) -> float:
    """Fraction of valid ground-truth joints that have a valid estimate."""
    _, eo, _, go, _ = _align(est, gt, None, mapping)
    return float((eo & go).sum() / go.sum()) if go.any() else float("nan")


def procrustes_align(X: np.ndarray, Y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Similarity transform (scale, rotation, translation) of X (..., J, 3) onto Y, least squares
    over joints with ``w`` (..., J) True (Umeyama); returns the aligned X."""
    wf = w.astype(float)[..., None]
    n = np.maximum(wf.sum(axis=-2, keepdims=True), 1.0)
    mx = (X * wf).sum(axis=-2, keepdims=True) / n
    my = (Y * wf).sum(axis=-2, keepdims=True) / n
    Xc, Yc = (X - mx) * wf, (Y - my) * wf
    S = np.swapaxes(Xc, -1, -2) @ Yc  # (..., 3, 3)
    U, s, Vt = np.linalg.svd(S)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.ones(s.shape)
    D[..., -1] = d
    R = U @ (D[..., :, None] * Vt)  # X_c @ R ~ Y_c
    var = (Xc**2).sum(axis=(-1, -2))
    scale = (s * D).sum(axis=-1) / np.maximum(var, 1e-12)
    return scale[..., None, None] * ((X - mx) @ R) + my


def pa_mpjpe(
    est: Keypoints3D, gt: Keypoints3D, joint_names: tuple[str, ...] | None = None, mapping: dict[int, int] | None = None
) -> float:
    """MPJPE in mm after a per-(frame, person) similarity Procrustes alignment (>= 3 joints)."""
    e, eo, g, go, _ = _align(est, gt, joint_names, mapping)
    ok = eo & go
    poses = ok.sum(axis=-1) >= 3
    if not poses.any():
        return float("nan")
    aligned = procrustes_align(e[poses], g[poses], ok[poses])
    err = np.linalg.norm(aligned - g[poses], axis=-1)[ok[poses]]
    return float(err.mean() * 1000.0)


def identity_accuracy(person_of_det_est: np.ndarray, person_of_det_gt: np.ndarray) -> float:
    """Fraction of detections assigned to the right person, up to a global relabelling.

    Estimated ids are matched to true ids by the permutation that maximises agreement
    (Hungarian on the confusion matrix); ``-1`` ("nobody") always maps to ``-1``, so a
    bystander given an athlete's id, or an athlete dropped to ``-1``, is an error.
    """
    est = np.asarray(person_of_det_est)
    gt = np.asarray(person_of_det_gt)
    if est.shape != gt.shape:
        raise ValueError(f"identity_accuracy: shapes differ {est.shape} vs {gt.shape}")
    if est.size == 0:
        return float("nan")
    e_ids = np.unique(est[est >= 0])
    g_ids = np.unique(gt[gt >= 0])
    mapped = np.full(est.shape, -2, np.int64)
    mapped[est < 0] = -1
    if e_ids.size and g_ids.size:
        conf = np.zeros((e_ids.size, g_ids.size))
        ei = np.searchsorted(e_ids, est)
        gi = np.searchsorted(g_ids, gt)
        both = (est >= 0) & (gt >= 0)
        np.add.at(conf, (ei[both], gi[both]), 1)
        r, c = linear_sum_assignment(-conf)
        lut = dict(zip(e_ids[r].tolist(), g_ids[c].tolist(), strict=True))
        for k, v in lut.items():
            mapped[est == k] = v
    return float(np.mean(mapped == gt))


def reprojection_error(kp3d: Keypoints3D, tracks: Tracks2D, assoc: Association, rig: CameraRig) -> np.ndarray:
    """(dets, joints) pixel distance between each 2D keypoint and its person's projected 3D joint.

    Projection includes lens distortion (errors are in the original image). NaN where not
    applicable: detection of nobody, person or frame absent from ``kp3d``, invalid 2D or
    3D joint, or a 3D point behind the camera. Joints are matched by name.
    """
    out = np.full((tracks.n_dets, len(tracks.joint_names)), np.nan)
    common = [n for n in tracks.joint_names if n in kp3d.joint_names]
    j2 = np.array([tracks.joint_names.index(n) for n in common], np.int64)
    j3 = np.array([kp3d.joint_names.index(n) for n in common], np.int64)
    pidx = np.full(int(max(assoc.person_of_det.max(initial=-1), kp3d.person_ids.max(initial=-1))) + 2, -1)
    pidx[kp3d.person_ids] = np.arange(kp3d.n_persons)
    p = np.where(assoc.person_of_det >= 0, pidx[np.maximum(assoc.person_of_det, 0)], -1)
    fpos = np.searchsorted(kp3d.frame_indices, tracks.frame)
    fpos_c = np.minimum(fpos, max(kp3d.n_frames - 1, 0))
    has = (p >= 0) & (kp3d.n_frames > 0)
    has &= kp3d.frame_indices[fpos_c] == tracks.frame if kp3d.n_frames else has
    rows = np.flatnonzero(has)
    if rows.size == 0 or j2.size == 0:
        return out
    X = kp3d.xyz_m[fpos_c[rows]][np.arange(rows.size), p[rows]][:, j3]  # (n, J, 3)
    ok3 = kp3d.valid[fpos_c[rows], p[rows]][:, j3]
    for v in np.unique(tracks.view[rows]):
        sel = tracks.view[rows] == v
        uv, depth = project(rig.subset([int(v)]), X[sel])
        err = np.linalg.norm(uv[0] - tracks.keypoints_px[rows[sel]][:, j2], axis=-1)
        ok = ok3[sel] & tracks.keypoint_valid[rows[sel]][:, j2] & (depth[0] > 0)
        block = np.full((int(sel.sum()), j2.size), np.nan)
        block[ok] = err[ok]
        out[np.ix_(rows[sel], j2)] = block
    return out


def bone_length_std(kp: Keypoints3D, bones: tuple[tuple[str, str], ...] = RIGID_BONES) -> float:
    """Mean over (person, bone) of the standard deviation of the bone length over time, in mm.

    Only frames where both ends are valid count; bones with fewer than 2 such frames are skipped.
    """
    idx = [(kp.joint_names.index(a), kp.joint_names.index(b)) for a, b in bones if a in kp.joint_names and b in kp.joint_names]
    if not idx:
        return float("nan")
    a, b = np.array(idx).T
    length = np.linalg.norm(kp.xyz_m[:, :, a] - kp.xyz_m[:, :, b], axis=-1)  # (F, P, B)
    ok = kp.valid[:, :, a] & kp.valid[:, :, b]
    n = ok.sum(axis=0)
    mean = np.where(ok, length, 0).sum(axis=0) / np.maximum(n, 1)
    var = np.where(ok, (length - mean) ** 2, 0).sum(axis=0) / np.maximum(n, 1)
    use = n >= 2
    return float(np.sqrt(var[use]).mean() * 1000.0) if use.any() else float("nan")


def acceleration_error(
    est: Keypoints3D, gt: Keypoints3D, joint_names: tuple[str, ...] | None = None, mapping: dict[int, int] | None = None
) -> float:
    """Mean norm of the difference of second finite differences, in mm / frame^2.

    Needs three consecutive frames (consecutive ``frame_indices``) valid in both.
    """
    e, eo, g, go, _ = _align(est, gt, joint_names, mapping)
    frames = np.intersect1d(est.frame_indices, gt.frame_indices)
    if frames.size < 3:
        return float("nan")
    consecutive = (frames[2:] - frames[:-2]) == 2
    ok = eo & go
    ok3 = ok[:-2] & ok[1:-1] & ok[2:] & consecutive[:, None, None]
    acc_e = e[:-2] - 2 * e[1:-1] + e[2:]
    acc_g = g[:-2] - 2 * g[1:-1] + g[2:]
    if not ok3.any():
        return float("nan")
    return float(np.linalg.norm(acc_e - acc_g, axis=-1)[ok3].mean() * 1000.0)
