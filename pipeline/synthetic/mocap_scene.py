"""Two-person scenes from DeepMimic mocap clips, seen by the synthetic bout's cameras.

A scene ``"deepmimic:punch+walk"`` is athlete 0 doing the ``punch`` clip and athlete 1 the
``walk`` clip (:mod:`pipeline.synthetic.deepmimic`), with the bodies, cameras, 2D noise,
occlusion, misses, track-id swaps and bystander that ``make_bout`` draws for the same
:class:`SyntheticConfig` (same seed: same bodies and rig). The motion is not what the
physics defaults were tuned on: mocap of walking, running, kicks, spins and flips.

Placement: each athlete starts facing the other (athlete 0 towards +x, 1 towards -x),
``DISTANCE_M`` apart along x; they are then moved apart sideways (along y, in steps of
``OFFSET_STEP_M``) until their bodies (the evaluation's capsules plus ``GAP_M``) stay
apart in every frame, since a travelling clip (walk, run) would otherwise walk into the
other athlete. The scene is centred on the ring centre. Every seed also starts each clip
at its own random phase.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from pipeline.evaluate.physics_metrics import CapsuleProxy, inter_person_penetration_mm
from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.joints import COCO17_FEET
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.synthetic.bout import (
    BOXER_ARM_RATIOS,
    BOXER_HEIGHTS_M,
    BYSTANDER_BEHIND_CAMERA_M,
    BYSTANDER_HEIGHT_M,
    BYSTANDER_LOOP_M,
    SyntheticBout,
    make_bout,
)
from pipeline.synthetic.config import SyntheticConfig
from pipeline.synthetic.deepmimic import (
    CLIPS,
    clip_keypoints_dm,
    floor_and_contact,
    loop_clip,
    move_to,
    retarget_to_body,
    start_frame,
)
from pipeline.synthetic.occlusion import capsules, occluded
from pipeline.synthetic.render2d import render_tracks
from pipeline.synthetic.rig import make_rig
from pipeline.synthetic.skeleton import J, make_body
from pipeline.synthetic.walker import walker_joints

log = logging.getLogger(__name__)

PREFIX = "deepmimic:"
"""Scene names: ``"synthetic"`` (the synthetic bout) or ``"deepmimic:<clip>+<clip>"``."""

DISTANCE_M = 1.75
"""Distance between the athletes' starting pelvis positions along the facing line (m)."""

GAP_M = 0.10
"""Clearance kept between the athletes' capsules (``CapsuleProxy``) in every frame (m)."""

OFFSET_STEP_M = 0.1
"""Step of the sideways offset search (m); it tries 0, +step, -step, +2 step, ... up to ``MAX_OFFSET_M``."""

MAX_OFFSET_M = 4.0
"""Largest sideways offset tried before giving up (m)."""

CAMERA_CLEARANCE_M = 1.5
"""Every joint stays at least this far (horizontally) inside the nearest camera's circle (m)."""


@dataclass(frozen=True)
class MocapScene:
    """A DeepMimic scene with the fields of ``SyntheticBout`` that the benches read.

    Fields:
        clips: the two clip names (athlete 0, athlete 1).
        rig: the cameras (``make_rig`` of the config's seed).
        tracks: simulated detector + tracker output (``COCO17_FEET``).
        gt: ground-truth 3D joints of the two athletes (``source="gt"``, persons [0, 1]).
        gt_person_of_det: (dets,) true person id of each tracks row (-1 = bystander).
        foot_contact: (frames, 2, 2) bool, (left, right) foot planted, per athlete.
        swap_frames: (S, 2) int rows [view, frame] of the injected track-id swaps.
        limb_lengths_m: person id -> segment lengths (``BodyDims`` fields, metres).
        clean_keypoints_px: (dets, 23, 2) noise-free projections of each row's joints.
        occluded: (dets, 23) bool, joint hidden behind a body volume in that view.
        bystander_xyz_m: (frames, 23, 3) the bystander's joints ((0, 23, 3) if none).
        offset_m: sideways offset (m) the placement needed to keep the athletes apart.
    """

    clips: tuple[str, str]
    rig: CameraRig
    tracks: Tracks2D
    gt: Keypoints3D
    gt_person_of_det: np.ndarray
    foot_contact: np.ndarray
    swap_frames: np.ndarray
    limb_lengths_m: dict[int, dict[str, float]]
    clean_keypoints_px: np.ndarray
    occluded: np.ndarray
    bystander_xyz_m: np.ndarray
    offset_m: float

    def gt_association(self) -> Association:
        """The true identities of ``tracks`` (athletes 0 and 1, bystander -1)."""
        pod = self.gt_person_of_det.astype(np.int64)
        return Association(
            person_ids=np.array([0, 1]),
            person_names=("", ""),
            person_of_det=pod,
            confidence=np.ones(pod.shape[0]),
        )


def parse_scene(name: str) -> tuple[str, str] | None:
    """``None`` for ``"synthetic"``, the two clip names for ``"deepmimic:a+b"``; a
    ``ValueError`` naming the valid forms otherwise (checked before any work)."""
    if name == "synthetic":
        return None
    clips = name[len(PREFIX) :].split("+") if name.startswith(PREFIX) else []
    if len(clips) != 2 or any(c not in CLIPS for c in clips):
        raise ValueError(
            f"scene {name!r}: expected 'synthetic' or '{PREFIX}<clip>+<clip>' with clips from {list(CLIPS)}, "
            f"e.g. '{PREFIX}punch+walk'"
        )
    return clips[0], clips[1]


def make_scene(name: str, cfg: SyntheticConfig) -> SyntheticBout | MocapScene:
    """The scene ``name`` (see ``parse_scene``) for ``cfg`` (seed, frames, cameras, noise)."""
    clips = parse_scene(name)
    if clips is None:
        return make_bout(cfg)
    try:
        return make_mocap_scene(clips, cfg)
    except ImportError as e:
        raise ValueError(f"scene {name!r} needs the DeepMimic clips of the 'pybullet' package: {e}") from e


def _keypoints(xyz: np.ndarray, fps: float, n_views: np.ndarray | None = None) -> Keypoints3D:
    n_f, n_p, n_j = xyz.shape[:3]
    return Keypoints3D(
        joint_names=COCO17_FEET,
        person_ids=np.arange(n_p, dtype=np.int64),
        frame_indices=np.arange(n_f, dtype=np.int64),
        fps=float(fps),
        xyz_m=xyz,
        valid=np.ones((n_f, n_p, n_j), dtype=bool),
        confidence=np.ones((n_f, n_p, n_j)),
        n_views=n_views if n_views is not None else np.zeros((n_f, n_p, n_j), dtype=np.int64),
        reproj_err_px=np.full((n_f, n_p, n_j), np.nan),
        source="gt",
    )


def place_pair(a: np.ndarray, b: np.ndarray, fps: float) -> tuple[np.ndarray, float]:
    """(F, 2, 23, 3) athletes ``a`` and ``b`` (F, 23, 3 each) placed as the module
    docstring says, and the sideways offset used (m). ``ValueError`` when no offset up
    to ``MAX_OFFSET_M`` keeps them apart."""
    starts = [move_to(m, start_frame(m[0]), (np.zeros(2), yaw)) for m, yaw in ((a, 0.0), (b, np.pi))]
    proxy = CapsuleProxy(tuple((p, q, r + 0.5 * GAP_M) for p, q, r in CapsuleProxy().segments))
    n_steps = int(round(MAX_OFFSET_M / OFFSET_STEP_M))
    for k in range(2 * n_steps + 1):
        offset = OFFSET_STEP_M * ((k + 1) // 2) * (1 if k % 2 else -1) if k else 0.0
        xyz = np.stack(
            [
                starts[0] + np.array([-0.5 * DISTANCE_M, -0.5 * offset, 0.0]),
                starts[1] + np.array([0.5 * DISTANCE_M, 0.5 * offset, 0.0]),
            ],
            axis=1,
        )
        if inter_person_penetration_mm(_keypoints(xyz, fps), proxy).max() <= 0.0:
            pelvis = 0.5 * (xyz[:, :, J["left_hip"], :2] + xyz[:, :, J["right_hip"], :2]).reshape(-1, 2)
            centre = 0.5 * (pelvis.min(axis=0) + pelvis.max(axis=0))
            return xyz - np.r_[centre, 0.0], float(offset)
    raise ValueError(
        f"DeepMimic scene: no sideways offset up to {MAX_OFFSET_M} m keeps the two athletes apart"
    )


def make_mocap_scene(clips: tuple[str, str], cfg: SyntheticConfig) -> MocapScene:
    """Athletes doing ``clips`` (see the module docstring), rendered like ``make_bout``.

    ``ValueError`` when a clip is unknown or the scene leaves the cameras' circle
    (a running clip over many frames: use fewer frames); ``ImportError`` without pybullet."""
    ss = np.random.SeedSequence(cfg.seed)
    # make_bout's first four streams (bodies, choreography, rig, render) plus one for the phases.
    rng_body, _, rng_rig, rng_render, _, rng_phase = (np.random.default_rng(s) for s in ss.spawn(6))
    bodies = [make_body(h, a, rng_body) for h, a in zip(BOXER_HEIGHTS_M, BOXER_ARM_RATIOS, strict=True)]
    motions, contacts = [], []
    for clip, body in zip(clips, bodies, strict=True):
        kp, dt, loops = clip_keypoints_dm(clip)
        start_s = float(rng_phase.uniform(0.0, (kp.shape[0] - 1) * dt))
        m, c = floor_and_contact(
            retarget_to_body(loop_clip(kp, dt, loops, cfg.n_frames, cfg.fps, start_s), body), cfg.fps
        )
        motions.append(m)
        contacts.append(c)
    athletes, offset = place_pair(motions[0], motions[1], cfg.fps)
    rig = make_rig(cfg.n_cameras, cfg.image_size_wh, cfg.fps, cfg.distortion, rng_rig, cfg.camera_step_deg)
    limit = float(np.linalg.norm(rig.centers_world_m[:, :2], axis=1).min()) - CAMERA_CLEARANCE_M
    reach = float(np.linalg.norm(athletes[..., :2], axis=-1).max())
    if reach > limit:
        raise ValueError(
            f"scene '{PREFIX}{clips[0]}+{clips[1]}': over {cfg.n_frames} frames the athletes reach {reach:.1f} m from "
            f"the ring centre, beyond {limit:.1f} m (the cameras' circle minus {CAMERA_CLEARANCE_M} m); use fewer frames "
            "or a clip that travels less"
        )

    persons = [athletes[:, 0], athletes[:, 1]]
    person_bodies = list(bodies)
    person_ids = [0, 1]
    bystander = np.zeros((0, len(COCO17_FEET), 3))
    if cfg.bystander:  # as make_bout places it (behind the first camera)
        by_body = make_body(BYSTANDER_HEIGHT_M, 1.0, rng_body)
        c0 = rig.centers_world_m[0, :2]
        r0 = float(np.linalg.norm(c0))
        loop_centre = c0 / r0 * (r0 + BYSTANDER_BEHIND_CAMERA_M + BYSTANDER_LOOP_M)
        phase = float(rng_body.uniform(-np.pi, np.pi))
        t_s = np.arange(cfg.n_frames) / cfg.fps
        bystander = walker_joints(by_body, loop_centre, BYSTANDER_LOOP_M, phase, t_s, cfg.fps)
        persons.append(bystander)
        person_bodies.append(by_body)
        person_ids.append(-1)
    xyz = np.stack(persons, axis=1)
    caps = [capsules(xyz[:, p], person_bodies[p]) for p in range(len(persons))]
    ends = np.concatenate([c[0] for c in caps], axis=1)
    radii = np.concatenate([c[1] for c in caps])
    n_f, n_p, n_j = xyz.shape[:3]
    occ = occluded(rig.centers_world_m, xyz.reshape(n_f, n_p * n_j, 3), ends, radii).reshape(
        rig.n_views, n_f, n_p, n_j
    )
    r2d = render_tracks(
        rig, xyz, np.array(person_ids), occ, cfg.noise_px, cfg.miss_rate, cfg.id_swaps, rng_render
    )
    gt = _keypoints(athletes.copy(), cfg.fps, r2d.n_views_visible[:, :2].copy())
    log.debug("DeepMimic scene %s: offset %.1f m, %d detections", clips, offset, r2d.tracks.n_dets)
    return MocapScene(
        clips=clips,
        rig=rig,
        tracks=r2d.tracks,
        gt=gt,
        gt_person_of_det=r2d.person_of_det,
        foot_contact=np.stack(contacts, axis=1),
        swap_frames=r2d.swap_frames,
        limb_lengths_m={i: bodies[i].as_dict() for i in range(2)},
        clean_keypoints_px=r2d.clean_px,
        occluded=r2d.occluded,
        bystander_xyz_m=bystander,
        offset_m=offset,
    )
