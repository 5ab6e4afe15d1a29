"""Build the shipped statistical pose prior of anny from DeepMimic's motion clips.

Source: the DeepMimic humanoid clips shipped in the ``pybullet`` wheel
(``pybullet_data/data/motions/humanoid3d_*.txt``) and its humanoid
(``pybullet_data/humanoid/humanoid.urdf``), both under the zlib licence, so the fitted prior
can be shipped (unlike the SMPLify GMM / VPoser, under the SMPL licence).

Steps (deterministic):
1. Forward kinematics of the DeepMimic humanoid (URDF offsets x 0.25, the scale its loaders
   use) at every key frame -> 3D joint positions, converted from DeepMimic's axes (y up,
   x forward, z right) to ours (z up, -y forward, +x left). Joints mapped to ``COCO17_FEET``:
   hips, knees, ankles, shoulders, elbows, wrists (DeepMimic joint centres); nose, eyes,
   ears from the head sphere; heel and toes from the foot box (lower weight). Every clip is
   mirrored left/right (x -> -x and the ``flip_pairs`` of the joint set) to double the data.
2. Retarget: our own fitter (:func:`pipeline.backends.anny.fit.fit_anny`) in 3D-only mode,
   no camera, all frames of all clips as one "person" (one shape and one set of landmark
   offsets for the DeepMimic character; no temporal terms, so clip boundaries do not matter).
3. A Gaussian mixture (own EM, full covariances + ``reg`` on the diagonal) over the
   axis-angle of ``PRIOR_BONES`` (all but the root, wrists and forearm twists, which the
   DeepMimic joints cannot observe; those are left to the joint limits and ``w_reg``).
"""

from __future__ import annotations

import importlib.util
import logging
import time
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline.schema.joints import COCO17_FEET, mirror_joints

logger = logging.getLogger(__name__)

DEFAULT_CLIPS: tuple[str, ...] = (
    "walk",
    "run",
    "punch",
    "kick",
    "jump",
    "spin",
    "spinkick",
    "dance_a",
    "dance_b",
    "getup_facedown",
    "getup_faceup",
    "roll",
    "crawl",
    "backflip",
    "cartwheel",
)
"""All 15 DeepMimic humanoid clips: everyday and athletic motion (walk, run, punch, kick,
jump, spins, dances), ground work (get-ups, roll, crawl) and two acrobatic ones (backflip,
cartwheel) that widen the coverage of hip/shoulder ranges."""

LICENCE_NOTE = (
    "Fitted by cornerman (pipeline.priors.build) to the DeepMimic humanoid motion "
    "clips distributed in the pybullet wheel (pybullet_data/data/motions, zlib licence, "
    "(c) Erwin Coumans / Xue Bin Peng); the prior itself is Apache-2.0 like cornerman."
)

EXCLUDED_PREFIXES: tuple[str, ...] = ("root", "wrist", "lowerarm02")
"""Bones left out of the GMM: the root (global orientation), the wrists and forearm twist
segments (DeepMimic has no hand, so their retargeted rotations are arbitrary)."""

PRIOR_BONES: tuple[str, ...] = (
    "pelvis.L",
    "upperleg01.L",
    "upperleg02.L",
    "lowerleg01.L",
    "lowerleg02.L",
    "foot.L",
    "pelvis.R",
    "upperleg01.R",
    "upperleg02.R",
    "lowerleg01.R",
    "lowerleg02.R",
    "foot.R",
    "spine05",
    "spine04",
    "spine03",
    "spine02",
    "spine01",
    "clavicle.L",
    "shoulder01.L",
    "upperarm01.L",
    "upperarm02.L",
    "lowerarm01.L",
    "clavicle.R",
    "shoulder01.R",
    "upperarm01.R",
    "upperarm02.R",
    "lowerarm01.R",
    "neck01",
    "neck02",
    "neck03",
    "head",
)
"""Bones modelled by the GMM (31 x 3 = 93 dimensions, rig order): every bone of the default
rig except ``EXCLUDED_PREFIXES``. Twist segments and clavicles are kept: the fit splits a
limb rotation between them the same way (``w_reg`` + joint limits) when retargeting and
when fitting."""

_SCALE = 0.25  # DeepMimic's loaders scale humanoid.urdf by 0.25 (metres)
# DeepMimic axes (x forward, y up, z right) -> ours (left +x, forward -y, up +z)
_DM_TO_WORLD = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
# frame layout: duration, root pos (3), root quat, chest, neck, r hip, r knee (1), r ankle,
# r shoulder, r elbow (1), l hip, l knee, l ankle, l shoulder, l elbow; quaternions w x y z
_LAYOUT: tuple[tuple[str, int, int], ...] = (
    ("chest", 8, 4),
    ("neck", 12, 4),
    ("right_hip", 16, 4),
    ("right_knee", 20, 1),
    ("right_ankle", 21, 4),
    ("right_shoulder", 25, 4),
    ("right_elbow", 29, 1),
    ("left_hip", 30, 4),
    ("left_knee", 34, 1),
    ("left_ankle", 35, 4),
    ("left_shoulder", 39, 4),
    ("left_elbow", 43, 1),
)
_FRAME_LEN = 44
# COCO17_FEET keypoint -> (DeepMimic link, point in the link frame before scaling (URDF units),
# weight). Joint centres where they correspond; head points from the head sphere (centre
# 0.70 above the neck joint, radius 0.41); foot points on the foot box (centre (0.18, -0.09),
# size 0.708 x 0.22 x 0.36). The fit's per-keypoint landmark offsets absorb definition gaps.
_KEYPOINTS: dict[str, tuple[str, tuple[float, float, float], float]] = {
    "nose": ("neck", (0.40, 0.62, 0.0), 0.5),
    "left_eye": ("neck", (0.34, 0.80, -0.14), 0.3),
    "right_eye": ("neck", (0.34, 0.80, 0.14), 0.3),
    "left_ear": ("neck", (0.0, 0.70, -0.40), 0.5),
    "right_ear": ("neck", (0.0, 0.70, 0.40), 0.5),
    "left_shoulder": ("left_shoulder", (0.0, 0.0, 0.0), 1.0),
    "right_shoulder": ("right_shoulder", (0.0, 0.0, 0.0), 1.0),
    "left_elbow": ("left_elbow", (0.0, 0.0, 0.0), 1.0),
    "right_elbow": ("right_elbow", (0.0, 0.0, 0.0), 1.0),
    "left_wrist": ("left_wrist", (0.0, 0.0, 0.0), 1.0),
    "right_wrist": ("right_wrist", (0.0, 0.0, 0.0), 1.0),
    "left_hip": ("left_hip", (0.0, 0.0, 0.0), 1.0),
    "right_hip": ("right_hip", (0.0, 0.0, 0.0), 1.0),
    "left_knee": ("left_knee", (0.0, 0.0, 0.0), 1.0),
    "right_knee": ("right_knee", (0.0, 0.0, 0.0), 1.0),
    "left_ankle": ("left_ankle", (0.0, 0.0, 0.0), 1.0),
    "right_ankle": ("right_ankle", (0.0, 0.0, 0.0), 1.0),
    "left_big_toe": ("left_ankle", (0.50, -0.18, 0.08), 0.5),
    "left_small_toe": ("left_ankle", (0.42, -0.18, -0.14), 0.3),
    "left_heel": ("left_ankle", (-0.14, -0.18, 0.0), 0.5),
    "right_big_toe": ("right_ankle", (0.50, -0.18, -0.08), 0.5),
    "right_small_toe": ("right_ankle", (0.42, -0.18, 0.14), 0.3),
    "right_heel": ("right_ankle", (-0.14, -0.18, 0.0), 0.5),
}


def _pybullet_data_dir() -> Path:
    if importlib.util.find_spec("pybullet_data") is None:
        raise ImportError(
            "building the anny pose prior needs the DeepMimic clips of the 'pybullet' package: "
            "pip install 'cornerman[priors]' (or pip install pybullet)"
        )
    import pybullet_data

    return Path(pybullet_data.getDataPath())


def clip_path(name: str) -> Path:
    """Path of DeepMimic clip ``name`` (e.g. ``"walk"``); ``ImportError`` without pybullet."""
    p = _pybullet_data_dir() / "data" / "motions" / f"humanoid3d_{name}.txt"
    if not p.is_file():
        raise ValueError(f"{p}: no such DeepMimic clip {name!r}")
    return p


def load_skeleton() -> dict[str, tuple[str, np.ndarray]]:
    """DeepMimic humanoid joints: name -> (parent link, offset in the parent frame, metres)."""
    path = _pybullet_data_dir() / "humanoid" / "humanoid.urdf"
    try:
        root = ET.fromstring(path.read_bytes().replace(b"\x00", b"").decode())
    except (OSError, ET.ParseError) as e:
        raise ValueError(f"{path}: cannot read the DeepMimic humanoid: {e}") from e
    out: dict[str, tuple[str, np.ndarray]] = {}
    for j in root.findall("joint"):
        parent, origin = j.find("parent"), j.find("origin")
        if parent is None or origin is None or j.get("name") == "root":
            continue
        xyz = np.array([float(v) for v in origin.get("xyz", "0 0 0").split()]) * _SCALE
        out[str(j.get("name"))] = (str(parent.get("link")), xyz)
    return out


def load_clip(name: str) -> np.ndarray:
    """(frames, 44) key frames of a clip (the last frame of a looping clip is kept)."""
    import json

    path = clip_path(name)
    try:
        frames = np.asarray(json.loads(path.read_text())["Frames"], dtype=np.float64)
    except (OSError, KeyError, ValueError) as e:
        raise ValueError(f"{path}: not a DeepMimic motion file: {e}") from e
    if frames.ndim != 2 or frames.shape[1] != _FRAME_LEN:
        raise ValueError(f"{path}: expected (frames, {_FRAME_LEN}) key frames, got {frames.shape}")
    return frames


def _quat_wxyz_to_mat(q: np.ndarray) -> np.ndarray:
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def _rot_z(angle: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(angle), np.zeros_like(angle)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def clip_keypoints(frames: np.ndarray, skeleton: dict[str, tuple[str, np.ndarray]]) -> np.ndarray:
    """(frames, 23, 3) ``COCO17_FEET`` positions (world z-up, metres) by forward kinematics."""
    n = frames.shape[0]
    G: dict[str, np.ndarray] = {"root": _quat_wxyz_to_mat(frames[:, 4:8])}
    X: dict[str, np.ndarray] = {"root": frames[:, 1:4]}
    local = {
        name: _quat_wxyz_to_mat(frames[:, i : i + 4]) if k == 4 else _rot_z(frames[:, i])
        for name, i, k in _LAYOUT
    }
    pending = dict(skeleton)
    while pending:  # parents before children
        for name, (parent, off) in list(pending.items()):
            if parent not in G:
                continue
            X[name] = X[parent] + G[parent] @ off
            G[name] = G[parent] @ local[name] if name in local else G[parent]
            del pending[name]
    kp = np.zeros((n, len(COCO17_FEET), 3))
    for j, name in enumerate(COCO17_FEET):
        link, pt, _ = _KEYPOINTS[name]
        kp[:, j] = X[link] + G[link] @ (np.asarray(pt) * _SCALE)
    return kp @ _DM_TO_WORLD.T


def keypoint_weights() -> np.ndarray:
    """(23,) confidence weight of each synthesised keypoint."""
    return np.array([_KEYPOINTS[name][2] for name in COCO17_FEET])


def retarget(
    kp_m: np.ndarray, weights: np.ndarray, iters: int = 300, w_3d: float = 1000.0
) -> tuple[np.ndarray, np.ndarray]:
    """Fit anny's reduced rig to (frames, 23, 3) joints, 3D term only, frames independent.

    ``w_3d`` is raised well above the stage default (1) because the 3D term is the only data
    term here: at 1, ``w_reg`` and the joint limits (rad^2) outweigh centimetre residuals
    (m^2) and the fit under-bends knees and elbows. The joint limits and landmark offsets
    are scaled with it so that they keep their stage-default strength relative to the data
    (the limits decide how a rotation splits between a bone and its twist segment).

    Returns ((frames, bones, 3) pose in our BodyFit convention, (frames, 23) residual m).
    """
    from pipeline.backends.anny.fit import PersonObservations, fit_anny
    from pipeline.backends.fitting.config import FitConfig

    nf, nj = kp_m.shape[:2]
    obs = PersonObservations(
        kp3d_m=kp_m,
        w3d=np.broadcast_to(weights, (nf, nj)).copy(),
        uv_px=np.zeros((0, nf, nj, 2)),
        w2d=np.zeros((0, nf, nj)),
    )
    cfg = replace(
        FitConfig(),
        use_2d=False,
        w_3d=w_3d,
        w_landmarks=10.0 * w_3d,
        w_limits=w_3d,
        w_smooth=0.0,
        w_accel=0.0,
        w_ground=0.0,
        w_prior=0.0,
        pose_prior_path="",
        pose_iters_3d=iters,
        threads=1,
    )
    res = fit_anny([obs], np.zeros((0, 3, 4)), cfg)
    resid = np.linalg.norm(res.keypoints_m[:, 0] - kp_m, axis=-1)
    return res.pose_aa[:, 0], resid


def retarget_clips(clips: tuple[str, ...] = DEFAULT_CLIPS) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Retarget ``clips`` and their mirror images to anny: (frames, bones, 3) poses, a clip
    label per frame (``"<clip>"`` / ``"<clip>_mirror"``) and (frames, 23) residuals (m)."""
    skeleton = load_skeleton()
    kps, labels = [], []
    for name in clips:
        kp = clip_keypoints(load_clip(name), skeleton)
        kps += [kp, mirror_joints(kp)]
        labels += [name] * kp.shape[0] + [f"{name}_mirror"] * kp.shape[0]
    pose, resid = retarget(np.concatenate(kps), keypoint_weights())
    return pose, labels, resid


def build_pose_prior(
    out_path: str | Path,
    clips: tuple[str, ...] = DEFAULT_CLIPS,
    seed: int = 0,
    n_components: int = 4,
    reg: float = 1e-2,
    poses_out: str | Path | None = None,
) -> dict:
    """Retarget ``clips`` (and their mirror images) to anny and fit the GMM pose prior.

    Writes the prior to ``out_path`` (``GMMPrior.load`` format with metadata: rig, bone
    names, source clips, licence) and, when ``poses_out`` is given, every 2nd retargeted pose
    of ``PRIOR_BONES`` (float16) with its clip label (the test sample). Deterministic for a
    given ``seed``; ~3-5 min on one core. Defaults (K = 4, reg = 0.01 rad^2) had the best
    leave-one-clip-out likelihood among K in {4, 8, 12}, reg in {0.003, 0.01}. Returns a
    summary (frames, residuals, NLL, timings). ``ImportError`` when pybullet is missing.
    """
    t0 = time.perf_counter()
    pose, labels, resid = retarget_clips(clips)
    summary = fit_prior(pose, labels, resid, out_path, clips, seed, n_components, reg, poses_out)
    summary["total_s"] = time.perf_counter() - t0
    return summary


def fit_prior(
    pose: np.ndarray,
    labels: list[str],
    resid: np.ndarray,
    out_path: str | Path,
    clips: tuple[str, ...] = DEFAULT_CLIPS,
    seed: int = 0,
    n_components: int = 4,
    reg: float = 1e-2,
    poses_out: str | Path | None = None,
) -> dict:
    """The GMM step of :func:`build_pose_prior` on retargeted (frames, bones, 3) poses."""
    from pipeline.backends.anny.model import DEFAULT_RIG, anny_body
    from pipeline.backends.anny.priors import GMMPrior

    t0 = time.perf_counter()
    bone_names = anny_body(DEFAULT_RIG).bone_names
    idx = [bone_names.index(b) for b in PRIOR_BONES]
    x = pose[:, idx].reshape(pose.shape[0], -1)
    gmm = GMMPrior.fit(x, n_components=n_components, seed=seed, reg=reg)
    gmm = GMMPrior(
        gmm.means.numpy(),
        gmm.precisions.numpy(),
        gmm.weights,
        bone_names=PRIOR_BONES,
        rig=DEFAULT_RIG,
        meta={
            "source_clips": ",".join(clips),
            "mirrored": "true",
            "frames": str(x.shape[0]),
            "licence": LICENCE_NOTE,
            "seed": str(seed),
            "reg": str(reg),
            "builder": "pipeline.priors.build.build_pose_prior",
        },
    )
    gmm.save(out_path)
    if poses_out is not None:
        np.savez_compressed(
            poses_out,
            poses=x[::2].astype(np.float16),
            clip=np.asarray(labels)[::2],
            bone_names=np.asarray(PRIOR_BONES),
            rig=np.asarray(DEFAULT_RIG),
        )
    w = keypoint_weights() > 0.9
    summary = {
        "frames": int(x.shape[0]),
        "clips": list(clips),
        "dim": int(x.shape[1]),
        "n_components": n_components,
        "retarget_resid_mm_median": float(np.median(resid[:, w]) * 1000),
        "retarget_resid_mm_p95": float(np.percentile(resid[:, w], 95) * 1000),
        "median_nll": float(np.median(gmm.nll_numpy(x))),
        "fit_s": time.perf_counter() - t0,
    }
    logger.info("anny pose prior: %s -> %s", summary, out_path)
    return summary
