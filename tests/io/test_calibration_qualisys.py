"""Qualisys .qca.txt importer: the shared Pose2Sim multi-person calibration checked
physically against its videos, plus the format's options and errors.

The physical check runs the shared RTMDet-nano person detector on frame 0 of each
video, matches the boxes across views by triangulation, runs MoveNet on each matched
box and triangulates body points with a plain DLT: the reprojection errors must be a
few tens of pixels and the points must land where a standing person's are (ankles on
the floor z = 0, hips ~0.9 m, shoulders ~1.4 m) in a z-up metric world.
"""

from __future__ import annotations

import functools
import itertools
import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.geometry import project, undistort_points
from pipeline.io.calibration import load_calibration, rotate_images_cw
from pipeline.io.calibration_qualisys import load_qualisys
from pipeline.schema.camera import CameraRig

log = logging.getLogger(__name__)

QCA_FIXTURE = Path(__file__).resolve().parents[1] / "data" / "io" / "qualisys" / "Calib.qca.txt"
SHARED = "pose2sim_multiperson"


def shared_rig(test_data_dir: Path) -> CameraRig:
    p = test_data_dir / SHARED / "calibration" / "Calib.qca.txt"
    if not p.exists():
        pytest.skip(f"{p} not present in CORNERMAN_TEST_DATA_DIR")
    return load_calibration(p)


def first_frame(video: Path) -> np.ndarray:
    cap = cv2.VideoCapture(str(video))
    ok, img = cap.read()
    cap.release()
    if not ok:
        raise RuntimeError(f"{video}: cannot read frame 0")
    return img


# ------------------------------------------------------------------ test-only helpers


@functools.cache
def _session(model: Path):  # noqa: ANN202 (onnxruntime is imported lazily)
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    so.inter_op_num_threads = 1
    return ort.InferenceSession(str(model), so, providers=["CPUExecutionProvider"])


def detect_people(models_dir: Path, img: np.ndarray, min_score: float = 0.3) -> np.ndarray:
    """RTMDet-nano (see MODELS.md): (n, 5) person boxes x1 y1 x2 y2 score in image pixels."""
    sess = _session(models_dir / "rtmdet_nano.onnx")
    size = 320
    h, w = img.shape[:2]
    s = size / max(h, w)
    canvas = np.full((size, size, 3), 114, np.uint8)
    small = cv2.resize(img, (round(w * s), round(h * s)))
    canvas[: small.shape[0], : small.shape[1]] = small
    x = (canvas.astype(np.float32) - np.float32([103.53, 116.28, 123.675])) / np.float32(
        [57.375, 57.12, 58.395]
    )
    dets, labels = sess.run(None, {"input": x.transpose(2, 0, 1)[None]})
    keep = (labels[0] == 0) & (dets[0][:, 4] > min_score)
    out = dets[0][keep].astype(np.float64)
    out[:, :4] /= s
    return out


def movenet_keypoints(models_dir: Path, img: np.ndarray, box: np.ndarray) -> np.ndarray:
    """MoveNet Lightning on a square crop around ``box``: (17, 3) COCO-17 x, y (px), score."""
    sess = _session(models_dir / "movenet_lightning_int8.onnx")
    cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    side = 1.25 * max(box[2] - box[0], box[3] - box[1])
    x0, y0 = cx - side / 2, cy - side / 2
    A = np.array([[192 / side, 0, -x0 * 192 / side], [0, 192 / side, -y0 * 192 / side]])
    crop = cv2.cvtColor(cv2.warpAffine(img, A, (192, 192)), cv2.COLOR_BGR2RGB)
    out = sess.run(None, {sess.get_inputs()[0].name: crop[None]})[0][0, 0]  # (17, 3): y, x, score
    return np.stack([x0 + out[:, 1] * side, y0 + out[:, 0] * side, out[:, 2]], axis=1)


def dlt(rig: CameraRig, uv_undist: np.ndarray) -> np.ndarray:
    """Linear triangulation of one point from undistorted pixels (views, 2)."""
    P = rig.P
    A = np.concatenate([uv_undist[:, :1] * P[:, 2] - P[:, 0], uv_undist[:, 1:] * P[:, 2] - P[:, 1]])
    X = np.linalg.svd(A)[2][-1]
    return X[:3] / X[3]


def reprojection_px(rig: CameraRig, uv_dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate distorted pixels (views, 2); return the point and per-view errors (px)."""
    und = np.stack([undistort_points(uv_dist[v], rig.K[v], rig.dist[v]) for v in range(rig.n_views)])
    X = dlt(rig, und)
    uv, depth = project(rig, X[None])
    assert np.all(depth > 0), f"triangulated point {X} is behind a camera"
    return X, np.linalg.norm(uv[:, 0] - uv_dist, axis=1)


def match_people(rig: CameraRig, boxes: list[np.ndarray], max_err_px: float = 100.0) -> list[tuple[int, ...]]:
    """Cross-view matches (one box per view) by the reprojection error of box centres, greedily."""
    centres = [np.stack([(b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2], 1) for b in boxes]
    scored = []
    for combo in itertools.product(*[range(len(c)) for c in centres]):
        _, err = reprojection_px(rig, np.stack([centres[v][i] for v, i in enumerate(combo)]))
        scored.append((err.max(), combo))
    used: list[set[int]] = [set() for _ in boxes]
    matches = []
    for err, combo in sorted(scored):
        if err < max_err_px and all(i not in used[v] for v, i in enumerate(combo)):
            matches.append(combo)
            for v, i in enumerate(combo):
                used[v].add(i)
    return matches


def measure(rig: CameraRig, data_dir: Path, models_dir: Path) -> dict[str, np.ndarray]:
    """Per matched person: box-centre and body-point reprojection errors and 3D points."""
    imgs = [first_frame(data_dir / SHARED / "videos" / f"{n}.mp4") for n in rig.names]
    boxes = [detect_people(models_dir, im) for im in imgs]
    matches = match_people(rig, boxes)
    out: dict[str, list] = {
        "box_err": [],
        "hip_err": [],
        "shoulder_err": [],
        "hip": [],
        "shoulder": [],
        "ankle": [],
    }
    for combo in matches:
        b = np.stack([boxes[v][i] for v, i in enumerate(combo)])
        out["box_err"].append(
            reprojection_px(rig, np.stack([(b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2], 1))[1]
        )
        kp = np.stack([movenet_keypoints(models_dir, imgs[v], b[v]) for v in range(rig.n_views)])
        # Left/right midpoints are immune to MoveNet's left/right swaps in back views.
        for name, joints in (("hip", [11, 12]), ("shoulder", [5, 6]), ("ankle", [15, 16])):
            X, err = reprojection_px(rig, kp[:, joints, :2].mean(axis=1))
            out[name].append(X)
            if name != "ankle":
                out[f"{name}_err"].append(err)
    return {k: np.array(v) for k, v in out.items()}


# ------------------------------------------------------------------ tests on the shared data


@pytest.mark.requires_data
def test_shared_calibration_geometry(test_data_dir: Path) -> None:
    rig = shared_rig(test_data_dir)
    assert rig.names == ("cam01", "cam02", "cam03", "cam04")
    # Portrait videos: the rig's image size is the video frame size.
    for v, n in enumerate(rig.names):
        img = first_frame(test_data_dir / SHARED / "videos" / f"{n}.mp4")
        assert (img.shape[1], img.shape[0]) == tuple(rig.image_size_wh[v])
    c = rig.centers_world_m
    assert np.all((c[:, 2] > 1.5) & (c[:, 2] < 2.3)), f"camera heights {c[:, 2]}"
    # All optical axes meet near one point of the capture volume, above the floor.
    axes = rig.T_world_cam[:, :3, 2]
    A = sum(np.eye(3) - np.outer(a, a) for a in axes)
    b = sum((np.eye(3) - np.outer(a, a)) @ p for a, p in zip(axes, c, strict=True))
    target = np.linalg.solve(A, b)
    assert np.linalg.norm(target[:2]) < 1.5 and -0.5 < target[2] < 1.5, target
    to_target = (target - c) / np.linalg.norm(target - c, axis=1, keepdims=True)
    angles = np.degrees(np.arccos(np.sum(to_target * axes, axis=1)))
    assert np.all(angles < 15), angles
    # The target projects inside every image.
    uv, depth = project(rig, target[None])
    assert np.all(depth > 0) and np.all((uv[:, 0] >= 0) & (uv[:, 0] < rig.image_size_wh)), uv


@pytest.mark.requires_data
def test_shared_calibration_equals_repository_fixture(test_data_dir: Path) -> None:
    """The shared file is Pose2Sim's demo calibration (serials 'cam01' vs 'cam_01')."""
    a = shared_rig(test_data_dir)
    b = load_calibration(QCA_FIXTURE)
    np.testing.assert_allclose(a.T_world_cam, b.T_world_cam, atol=1e-12)
    np.testing.assert_allclose(a.K, b.K, atol=1e-12)


@pytest.mark.requires_models
@pytest.mark.requires_data
def test_shared_calibration_reprojects_detected_people(test_data_dir: Path, models_dir: Path) -> None:
    rig = shared_rig(test_data_dir)
    m = measure(rig, test_data_dir, models_dir)
    log.info(
        "Qualisys reprojection (px): boxes %s hips %s shoulders %s",
        m["box_err"],
        m["hip_err"],
        m["shoulder_err"],
    )
    # Two athletes walk on the treadmill; both are seen and matched in all four views
    # (a bystander visible in two views only is not).
    assert len(m["box_err"]) == 2, m["box_err"]
    assert np.median(m["box_err"]) < 25 and m["box_err"].max() < 80, m["box_err"]
    body = np.concatenate([m["hip_err"], m["shoulder_err"]])
    assert np.median(body) < 25 and body.max() < 75, body
    # A z-up metric world with the floor at z = 0.
    assert np.all(np.abs(m["ankle"][:, 2]) < 0.25), m["ankle"]
    assert np.all((m["hip"][:, 2] > 0.55) & (m["hip"][:, 2] < 1.2)), m["hip"]
    assert np.all((m["shoulder"][:, 2] > 1.0) & (m["shoulder"][:, 2] < 1.7)), m["shoulder"]
    # Hips are ~0.4-0.6 m below the shoulders of the same person, right above the ankles.
    assert np.all(np.linalg.norm(m["hip"][:, :2] - m["ankle"][:, :2], axis=1) < 0.35)


# ------------------------------------------------------------------ format options and errors


def _edit(tmp_path: Path, old: str, new: str, count: int = 1) -> Path:
    text = QCA_FIXTURE.read_text()
    assert old in text
    p = tmp_path / "edited.qca.txt"
    p.write_text(text.replace(old, new, count))
    return p


def test_video_resolution_and_binning_scale_intrinsics(tmp_path: Path) -> None:
    ref = load_qualisys(QCA_FIXTURE)
    p = _edit(tmp_path, 'serial="cam_01"', 'serial="cam_01" video_resolution="540p"')
    half = load_qualisys(p)
    np.testing.assert_allclose(half.K[0, :2], ref.K[0, :2] / 2)
    np.testing.assert_array_equal(half.image_size_wh[0], ref.image_size_wh[0] // 2)
    np.testing.assert_allclose(half.K[1:], ref.K[1:])
    # Projections scale with the resolution.
    X = np.array([[0.1, 0.2, 1.0]])
    np.testing.assert_allclose(project(half, X)[0][0], (project(ref, X)[0][0] + 0.0) / 2, atol=1e-9)
    binned = load_qualisys(QCA_FIXTURE, binning_factor=2)
    np.testing.assert_allclose(binned.K[:, 0, 0], ref.K[:, 0, 0] / 2)


def test_viewrotation_needs_an_explicit_direction(tmp_path: Path) -> None:
    p = _edit(tmp_path, 'serial="cam_02" viewrotation="0"', 'serial="cam_02" viewrotation="90"')
    with pytest.raises(ValueError, match=r"camera cam_02\]: viewrotation=90.*video_rotation_cw"):
        load_qualisys(p)
    ref = load_qualisys(QCA_FIXTURE)
    rot = load_qualisys(p, video_rotation_cw={"cam_02": 90})
    np.testing.assert_allclose(rot.T_world_cam, rotate_images_cw(ref, {"cam_02": 1}).T_world_cam)
    assert tuple(rot.image_size_wh[1]) == (1920, 1088)
    with pytest.raises(ValueError, match="unknown cameras"):
        load_qualisys(QCA_FIXTURE, video_rotation_cw={"cam_9": 90})
    with pytest.raises(ValueError, match="multiple of 90"):
        load_qualisys(QCA_FIXTURE, video_rotation_cw={"cam_01": 45})


def test_marker_cameras_are_skipped_and_order_is_natural(tmp_path: Path) -> None:
    p = _edit(
        tmp_path, 'model="none" point-count="999999999" serial="cam_03"', 'model="Miqus M3" serial="cam_03"'
    )
    rig = load_qualisys(p)
    assert rig.names == ("cam_01", "cam_02", "cam_04")


def test_qualisys_errors(tmp_path: Path) -> None:
    p = tmp_path / "broken.qca.txt"
    p.write_text(QCA_FIXTURE.read_text()[:900])
    with pytest.raises(ValueError, match=r"broken\.qca\.txt: malformed Qualisys XML"):
        load_qualisys(p)
    p = _edit(tmp_path, 'r11="0.5536380477336265" ', "")
    with pytest.raises(ValueError, match=r"camera cam_01\]: <transform> has no attribute 'r11'"):
        load_qualisys(p)
    p = _edit(tmp_path, 'focalLengthU="107599.671875"', 'focalLengthU="abc"')
    with pytest.raises(ValueError, match=r"focalLengthU='abc'> is not a number"):
        load_qualisys(p)
    p = _edit(tmp_path, 'r11="0.5536380477336265"', 'r11="5.5"')
    with pytest.raises(ValueError, match=r"camera cam_01\]: rotation is not a proper rotation"):
        load_qualisys(p)
