"""``make_bout``: the whole synthetic sparring bout (rig, 2D tracks and ground truth)."""

from __future__ import annotations

import dataclasses
import functools
import logging
from dataclasses import dataclass

import numpy as np

from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.joints import COCO17_FEET, mirror_joints
from pipeline.schema.keypoints3d import Keypoints3D
from pipeline.synthetic import combos
from pipeline.synthetic.choreo import Choreography, make_choreography, with_stances
from pipeline.synthetic.config import SyntheticConfig
from pipeline.synthetic.mirror import mirror_feet, mirror_truth
from pipeline.synthetic.motion import boxer_arms, boxer_trunk, parry_contacts, punch_peak_speeds
from pipeline.synthetic.occlusion import capsules, occluded
from pipeline.synthetic.render2d import render_tracks
from pipeline.synthetic.rig import make_rig
from pipeline.synthetic.separate import separate_persons
from pipeline.synthetic.skeleton import BodyDims, make_body
from pipeline.synthetic.truth import BoutTruth, record_truth
from pipeline.synthetic.walker import walker_joints

log = logging.getLogger(__name__)

BOXER_HEIGHTS_M = (1.70, 1.85)
BOXER_ARM_RATIOS = (0.98, 1.03)
BYSTANDER_HEIGHT_M = 1.78
BYSTANDER_BEHIND_CAMERA_M = 1.6
"""The bystander's loop stays at least this far behind the first camera."""
BYSTANDER_LOOP_M = 1.5
"""Radius of the loop the bystander walks (behind the first camera)."""


@dataclass(frozen=True)
class SyntheticBout:
    """A generated bout. ``tracks`` rows are ordered by (frame, view, person).

    Fields:
        rig: the cameras.
        tracks: simulated detector + tracker output (23 joints ``COCO17_FEET``).
        gt: ground-truth 3D joints of the two boxers (``source="gt"``, persons [0, 1],
            valid everywhere; ``n_views`` = number of views seeing the joint unoccluded).
        gt_person_of_det: (dets,) true person id of each tracks row (-1 = bystander).
        foot_contact: (frames, 2, 2) bool, (left, right) foot planted, per boxer.
        swap_frames: (S, 2) int rows [view, frame]: from that frame on the two boxers'
            track ids are exchanged in that view.
        limb_lengths_m: person id -> segment lengths (``BodyDims`` fields, metres).
        clean_keypoints_px: (dets, 23, 2) noise-free projections of each row's joints.
        occluded: (dets, 23) bool, joint hidden behind a body volume in that view.
        bystander_xyz_m: (frames, 23, 3) the bystander's joints (empty (0, 23, 3) if none).
        punch_peak_speed_mps: (punches,) measured peak wrist speed of every scripted punch.
        choreography: the script (phases, punches, slips, intents; with
            ``SyntheticConfig.mixed_stance`` boxer 1's punches have ``lead="right"``): with
            ``SyntheticConfig.southpaw`` its ``Punch.hand`` is the mirror's other hand
            (``truth`` has the hands as performed).
        truth: the labelled events (punches with type and outcome, feints, slips and
            ducks, clinch frames; ``pipeline.synthetic.truth``).
    """

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
    punch_peak_speed_mps: np.ndarray
    choreography: Choreography
    truth: BoutTruth

    def gt_association(self) -> Association:
        """The true identities of ``tracks`` as an ``Association`` (boxers 0 and 1, bystander -1):
        benchmarks of the later stages start from it to isolate them from association errors."""
        pod = self.gt_person_of_det.astype(np.int64)
        return Association(
            person_ids=np.array([0, 1]), person_names=("", ""), person_of_det=pod, confidence=np.ones(pod.shape[0])
        )


def _boxers(
    ch: Choreography, bodies: list[BodyDims], fps: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joints (F, 2, 23, 3), foot contacts (F, 2, 2) and per-punch peak wrist speeds."""
    trunks = [boxer_trunk(ch, i, bodies[i], fps) for i in range(2)]
    joints = [boxer_arms(ch, i, bodies[i], trunks[i], trunks[1 - i], bodies[1 - i]) for i in range(2)]
    if any(p.parry is not None for p in ch.punches):
        # Parries meet the punching glove where the first pass put it: until the contact a
        # punch's own arm does not depend on the opponent's arms.
        first = joints
        contacts = parry_contacts(ch, first, trunks, bodies)
        joints = [
            boxer_arms(ch, i, bodies[i], trunks[i], trunks[1 - i], bodies[1 - i], first[1 - i], contacts)
            for i in range(2)
        ]
    speeds = np.zeros(len(ch.punches))
    for i in range(2):
        idx = [k for k, p in enumerate(ch.punches) if p.person == i]
        speeds[idx] = punch_peak_speeds(joints[i], ch.punches, i, ch.t_s, fps)
    contact = np.stack([t.feet.contact for t in trunks], axis=1)
    return np.stack(joints, axis=1), contact, speeds


def _calibrated_boxers(
    ch: Choreography, bodies: list[BodyDims], fps: float
) -> tuple[Choreography, np.ndarray, np.ndarray, np.ndarray]:
    """Rescale each punch's duration until its measured peak wrist speed matches its target
    (the body moves and twists under the fist, so the nominal duration is only a guess)."""
    n_iter = 6
    for it in range(n_iter):
        joints, contact, speeds = _boxers(ch, bodies, fps)
        targets = np.array([p.target_speed_mps for p in ch.punches])
        ratio = speeds / np.maximum(targets, 1e-9)
        # A feint's speed is what its short path gives (the trunk's motion dominates it).
        ratio[[k for k, p in enumerate(ch.punches) if p.feint]] = 1.0
        if np.all(np.abs(ratio - 1.0) < 0.03) or it == n_iter - 1:
            break
        punches = tuple(
            dataclasses.replace(
                p, out_s=p.out_s * float(np.clip(r, 0.5, 2.0)), back_s=p.back_s * float(np.clip(r, 0.5, 2.0))
            )
            for p, r in zip(ch.punches, ratio, strict=True)
        )
        punches = tuple(p for p in punches if p.end_s + 0.1 < ch.t_s[-1])
        ch = dataclasses.replace(ch, punches=punches)
    return ch, joints, contact, speeds


def _planted_joints(contact: np.ndarray) -> np.ndarray:
    """(F, 2, 23) bool: the joints of feet in contact (they must not move)."""
    pinned = np.zeros((*contact.shape[:2], len(COCO17_FEET)), dtype=bool)
    for k, side in enumerate(("left", "right")):
        for part in ("ankle", "heel", "big_toe", "small_toe"):
            pinned[:, :, COCO17_FEET.index(f"{side}_{part}")] = contact[:, :, k]
    return pinned


def make_bout(cfg: SyntheticConfig = SyntheticConfig()) -> SyntheticBout:
    """Generate the bout described by ``cfg`` (deterministic: same config -> same arrays)."""
    ss = np.random.SeedSequence(cfg.seed)
    # A fifth child stream for the varied script and a sixth for its parries: the streams
    # before each are the same with or without it.
    streams = (np.random.default_rng(s) for s in ss.spawn(6))
    rng_body, rng_choreo, rng_rig, rng_render, rng_vary, rng_parry = streams
    bodies = [make_body(h, a, rng_body) for h, a in zip(BOXER_HEIGHTS_M, BOXER_ARM_RATIOS, strict=True)]
    vary = (
        functools.partial(combos.vary, rng=rng_vary, parry_prob=cfg.parry_prob, rng_parry=rng_parry)
        if cfg.variety
        else None
    )
    ch = make_choreography(cfg.n_frames, cfg.fps, cfg.clinch, rng_choreo, vary)
    if cfg.mixed_stance:
        ch = with_stances(ch, (False, True))
    ch, boxers, contact, speeds = _calibrated_boxers(ch, bodies, cfg.fps)
    boxers = separate_persons(boxers, _planted_joints(contact))
    truth = record_truth(ch, boxers, speeds, cfg.fps)
    if cfg.southpaw:  # the script's orthodox bout in a mirror (``mirror``): truth recorded before
        boxers, contact, truth = mirror_joints(boxers), mirror_feet(contact), mirror_truth(truth)
    rig = make_rig(cfg.n_cameras, cfg.image_size_wh, cfg.fps, cfg.distortion, rng_rig, cfg.camera_step_deg)

    persons = [boxers[:, 0], boxers[:, 1]]
    person_bodies = list(bodies)
    person_ids = [0, 1]
    bystander = np.zeros((0, len(COCO17_FEET), 3))
    if cfg.bystander:
        by_body = make_body(BYSTANDER_HEIGHT_M, 1.0, rng_body)
        c0 = rig.centers_world_m[0, :2]
        r0 = float(np.linalg.norm(c0))
        loop_centre = c0 / r0 * (r0 + BYSTANDER_BEHIND_CAMERA_M + BYSTANDER_LOOP_M)
        phase = float(rng_body.uniform(-np.pi, np.pi))
        bystander = walker_joints(by_body, loop_centre, BYSTANDER_LOOP_M, phase, ch.t_s, cfg.fps)
        persons.append(bystander)
        person_bodies.append(by_body)
        person_ids.append(-1)
    xyz = np.stack(persons, axis=1)  # (F, P, 23, 3)

    caps = [capsules(xyz[:, p], person_bodies[p]) for p in range(len(persons))]
    ends = np.concatenate([c[0] for c in caps], axis=1)
    radii = np.concatenate([c[1] for c in caps])
    n_f, n_p, n_j = xyz.shape[:3]
    occ = occluded(rig.centers_world_m, xyz.reshape(n_f, n_p * n_j, 3), ends, radii)
    occ = occ.reshape(rig.n_views, n_f, n_p, n_j)
    r2d = render_tracks(
        rig, xyz, np.array(person_ids), occ, cfg.noise_px, cfg.miss_rate, cfg.id_swaps, rng_render
    )

    gt = Keypoints3D(
        joint_names=COCO17_FEET,
        person_ids=np.array([0, 1], dtype=np.int64),
        frame_indices=np.arange(n_f, dtype=np.int64),
        fps=float(cfg.fps),
        xyz_m=boxers.copy(),
        valid=np.ones((n_f, 2, n_j), dtype=bool),
        confidence=np.ones((n_f, 2, n_j)),
        n_views=r2d.n_views_visible[:, :2].copy(),
        reproj_err_px=np.full((n_f, 2, n_j), np.nan),
        source="gt",
    )
    log.debug("synthetic bout: %d detections, swaps %s", r2d.tracks.n_dets, r2d.swap_frames.tolist())
    return SyntheticBout(
        rig=rig,
        tracks=r2d.tracks,
        gt=gt,
        gt_person_of_det=r2d.person_of_det,
        foot_contact=contact,
        swap_frames=r2d.swap_frames,
        limb_lengths_m={i: bodies[i].as_dict() for i in range(2)},
        clean_keypoints_px=r2d.clean_px,
        occluded=r2d.occluded,
        bystander_xyz_m=bystander,
        punch_peak_speed_mps=speeds,
        choreography=ch,
        truth=truth,
    )
