"""A small session built in code: 3-camera rig, two persons walking, artifacts of
track/associate/triangulate (and optionally physics contacts) and the evaluate stage's
problem flags, written with the real schema classes and ``ArtifactStore.write``."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pipeline.artifacts import ArtifactStore, Manifest
from pipeline.geometry.projection import project
from pipeline.geometry.rotations import look_at_T_world_cam
from pipeline.io.calibration import save_toml
from pipeline.schema import COCO17, Association, CameraRig, Keypoints3D, SessionConfig, Tracks2D, save_npz
from pipeline.schema.analytics import AthleteSeries, BoutEvents
from pipeline.schema.results import PhysicsResult
from pipeline.stages.evaluate import EvaluateConfig, EvaluateInputs
from pipeline.stages.evaluate import run as evaluate

FAST_STAGES: tuple[str, ...] = ("detect2d", "track", "associate", "triangulate")
"""Stages the viewer tests run through the real worker (fit and physics would be slow)."""

# A standing pose (x forward, y left, z up), metres, COCO-17 order.
_POSE = np.array(
    [
        [0.05, 0.0, 1.65], [0.07, 0.03, 1.68], [0.07, -0.03, 1.68], [0.03, 0.07, 1.66], [0.03, -0.07, 1.66],
        [0.0, 0.2, 1.45], [0.0, -0.2, 1.45], [0.1, 0.25, 1.2], [0.1, -0.25, 1.2], [0.3, 0.15, 1.35], [0.3, -0.15, 1.35],
        [0.0, 0.1, 0.95], [0.0, -0.1, 0.95], [0.02, 0.1, 0.5], [0.02, -0.1, 0.5], [0.0, 0.1, 0.08], [0.0, -0.1, 0.08],
    ]
)  # fmt: skip


def make_rig(n_views: int = 3, size_wh: tuple[int, int] = (640, 360)) -> CameraRig:
    Ts, Ks = [], []
    for v in range(n_views):
        a = 2 * np.pi * v / n_views + 0.3
        eye = np.array([6.0 * np.cos(a), 6.0 * np.sin(a), 2.5])
        Ts.append(look_at_T_world_cam(eye, np.array([0.0, 0.0, 1.0])))
        Ks.append([[500.0, 0, size_wh[0] / 2], [0, 500.0, size_wh[1] / 2], [0, 0, 1]])
    return CameraRig(
        names=tuple(f"cam{v + 1}" for v in range(n_views)),
        K=np.array(Ks),
        dist=np.zeros((n_views, 5)),
        T_world_cam=np.array(Ts),
        image_size_wh=np.tile(np.array(size_wh, dtype=np.int64), (n_views, 1)),
        fps=25.0,
    )


def motion(n_frames: int) -> np.ndarray:
    """(frames, 2, 17, 3): person 0 at x=-1, person 1 at x=+1, both drifting along y; person 0 punches."""
    t = np.arange(n_frames) / 25.0
    out = np.zeros((n_frames, 2, 17, 3))
    for p, x0 in enumerate((-1.0, 1.0)):
        yaw = 0.0 if p == 0 else np.pi
        R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
        base = _POSE @ R.T
        out[:, p] = base[None] + np.stack([np.full_like(t, x0), 0.3 * np.sin(t + p), np.zeros_like(t)], axis=1)[:, None]
    out[:, 0, 10, 0] += 0.4 * np.clip(np.sin(4 * t), 0, None)  # right-hand jabs of person 0
    return out


def _manifest(stage: str) -> Manifest:
    return Manifest(stage=stage, code_version="test", config={}, config_hash="0", inputs={})


def build_session(
    root: Path, n_frames: int = 12, n_views: int = 3, physics: bool = False, low_conf_frame: int | None = 5
) -> Path:
    """Write a session folder under ``root`` and return it."""
    sdir = root / "bout"
    (sdir / "inputs").mkdir(parents=True)
    rig = make_rig(n_views)
    save_toml(rig, sdir / "inputs" / "calib.toml")
    X = motion(n_frames)
    uv, depth = project(rig, X)  # (views, frames, 2, 17, 2)
    rows = {k: [] for k in ("view", "frame", "bbox", "kp", "tid", "pid", "conf")}
    for v in range(n_views):
        for f in range(n_frames):
            for p in range(2):
                k = uv[v, f, p]
                if f == n_frames - 2 and p == 1:  # every view disagrees with the 3D here
                    k = k + 0.15 * (k[:, 1].max() - k[:, 1].min())
                rows["view"].append(v)
                rows["frame"].append(f)
                rows["bbox"].append([*k.min(0) - 5, *k.max(0) + 5])
                rows["kp"].append(k)
                rows["tid"].append(10 + p)  # per-view track ids 10 (person 0) and 11 (person 1)
                rows["pid"].append(p)
                rows["conf"].append(0.2 if (f == low_conf_frame and v <= 1) else 0.95)  # doubt in 2 of 3 views
    n = len(rows["view"])
    tracks = Tracks2D(
        joint_names=COCO17, n_views=n_views, n_frames=n_frames,
        view=np.array(rows["view"], dtype=np.int64), frame=np.array(rows["frame"], dtype=np.int64),
        bbox_xyxy_px=np.array(rows["bbox"], dtype=np.float64), bbox_score=np.full(n, 0.9),
        keypoints_px=np.array(rows["kp"], dtype=np.float64), keypoint_conf=np.full((n, 17), 0.9),
        keypoint_valid=np.ones((n, 17), dtype=bool), track_id=np.array(rows["tid"], dtype=np.int64),
    )  # fmt: skip
    save_npz(sdir / "inputs" / "tracks.npz", tracks)
    SessionConfig(
        name="test bout", source="tracks", calibration="inputs/calib.toml", tracks="inputs/tracks.npz", stages=FAST_STAGES
    ).save(sdir)
    assoc = Association(
        person_ids=np.array([0, 1]), person_names=("Red", "Blue"),
        person_of_det=np.array(rows["pid"], dtype=np.int64), confidence=np.array(rows["conf"]),
    )  # fmt: skip
    err = np.full((n_frames, 2, 17), 2.0)
    err[n_frames - 2, 1] = 30.0  # a frame with a high reprojection error
    kp = Keypoints3D(
        joint_names=COCO17, person_ids=np.array([0, 1]), frame_indices=np.arange(n_frames), fps=25.0,
        xyz_m=X, valid=np.ones((n_frames, 2, 17), dtype=bool), confidence=np.full((n_frames, 2, 17), 0.9),
        n_views=np.full((n_frames, 2, 17), n_views), reproj_err_px=err, source="filtered",
    )  # fmt: skip
    store = ArtifactStore(sdir)
    store.write(_manifest("track"), {"tracks": tracks})
    store.write(_manifest("associate"), {"association": assoc})
    store.write(_manifest("triangulate"), {"keypoints3d": kp})
    sources: dict[str, Keypoints3D] = {"filtered": kp}
    if physics:
        f = np.arange(n_frames)
        res = PhysicsResult(
            person_ids=np.array([0, 1]), frame_indices=f, fps=25.0, qpos=_qpos(n_frames), qvel=np.zeros((n_frames, 12)),
            ctrl=np.zeros((n_frames, 0)), joint_torque_nm=np.zeros((n_frames, 0)), residual_root_force=np.zeros((n_frames, 2, 6)),
            actuation="pd", contact_frame=np.array([3, 4]), contact_person=np.array([[0, 1], [0, -1]]),
            contact_body=np.zeros((2, 2), dtype=np.int64), contact_depth_m=np.array([0.08, 0.2]), body_names=("a",),
        )  # fmt: skip
        xyz = X.copy()
        if n_frames > 3:
            xyz[3, 1] = X[3, 0] + np.array([0.05, 0.0, 0.0])  # the physics result overlaps at frame 3
        sources["physics"] = kp.replace(source="physics", xyz_m=xyz)
        store.write(_manifest("physics"), {"result": res, "keypoints3d": sources["physics"], "scene.xml": _TWO_BALLS_XML})
    _, flags = evaluate(EvaluateInputs(rig, tracks, assoc, sources), EvaluateConfig())
    store.write(_manifest("evaluate"), {"problems": flags.to_arrays()})
    return sdir


_TWO_BALLS_XML = """<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="p0_pelvis" pos="0 0 1"><freejoint name="p0_root"/>
      <geom type="capsule" size="0.1 0.3"/><geom type="box" size="0.1 0.05 0.02" pos="0 0 -0.5"/></body>
    <body name="p1_pelvis" pos="1 0 1"><freejoint name="p1_root"/><geom type="sphere" size="0.2"/></body>
  </worldbody>
</mujoco>"""


def _qpos(n_frames: int) -> np.ndarray:
    """Two free bodies: person 0 rising over time, identity orientations."""
    q = np.zeros((n_frames, 14))
    q[:, 2] = 1.0 + 0.01 * np.arange(n_frames)
    q[:, 3] = 1.0
    q[:, 7] = 1.0
    q[:, 9] = 1.0
    q[:, 10] = 1.0
    return q


def wait_for(cond: Callable[[], object], timeout_s: float) -> bool:
    """Poll ``cond`` every 20 ms until it is truthy (True) or ``timeout_s`` seconds pass (False)."""
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if cond():
            return True
        time.sleep(0.02)
    return bool(cond())



def sample_events(n_frames: int) -> tuple[BoutEvents, AthleteSeries]:
    """Three punches of athletes 0 and 1 (a landed jab at 6, a blocked cross at 15, a landed rear
    hook at 28; 25 fps) and flat series over ``n_frames`` (>= 33) frames."""
    ev = BoutEvents.empty(25.0, np.array([0, 1]))
    ev = BoutEvents(**{
        **ev.__dict__, "punch_person": np.array([0, 1, 0]), "punch_hand": np.array(["left", "right", "right"]),
        "punch_type": np.array(["jab", "cross", "rear_hook"]), "punch_start_frame": np.array([3, 12, 24]),
        "punch_peak_frame": np.array([6, 15, 28]), "punch_end_frame": np.array([9, 19, 32]),
        "punch_peak_speed_mps": np.array([7.5, 8.0, 6.5]), "punch_extension": np.array([0.95, 0.9, 0.7]),
        "punch_target": np.array(["head", "guard", "head"]), "punch_outcome": np.array(["landed", "blocked", "landed"]),
        "punch_confidence": np.array([0.9, 0.8, 0.7]),
    })  # fmt: skip
    f = n_frames
    series = AthleteSeries(
        frame_indices=np.arange(f), fps=25.0, person_ids=np.array([0, 1]), valid=np.ones((f, 2), bool),
        distance_m=np.full(f, 1.2), distance_valid=np.ones(f, bool), stance=np.ones((f, 2), np.int64),
        stance_width_m=np.full((f, 2), 0.5), guard_height_m=np.zeros((f, 2, 2)), punches_per_min=np.zeros((f, 2)),
    )  # fmt: skip
    return ev, series


def write_events(session_dir: Path, events: BoutEvents, series: AthleteSeries) -> None:
    """Store ``events`` and ``series`` as the session's analyze artifact (on the filtered joints)."""
    m = Manifest(stage="analyze", code_version="test", config={}, config_hash="0", inputs={}, metrics={"source": "filtered"})
    ArtifactStore(session_dir).write(m, {"events": events, "series": series})
