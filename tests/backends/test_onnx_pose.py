from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("onnxruntime")

from pipeline.backends.onnx.pose import (  # noqa: E402
    BLAZEPOSE_TO_COCO17_FEET,
    BlazePoseEstimator,
    MoveNetEstimator,
    PoseParams,
    apply_inverse,
    crop_transform,
    decode_heatmaps,
    decode_simcc,
)
from pipeline.schema.joints import COCO17, COCO17_FEET  # noqa: E402


def _gauss2d(h: int, w: int, x: float, y: float, s: float = 2.0) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    return np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * s * s))


def test_heatmap_decoder_subpixel() -> None:
    rng = np.random.default_rng(0)
    truth = rng.uniform(3, [45, 61], size=(2, 17, 2))
    hm = np.stack([np.stack([_gauss2d(64, 48, x, y) for x, y in p]) for p in truth])
    xy, score = decode_heatmaps(hm)
    err = np.abs(xy - truth)
    assert err.max() < 0.15  # argmax alone is off by up to 0.5
    assert np.abs(np.round(truth) - truth).max() > 0.3  # the test does exercise sub-pixel offsets
    assert np.all(score > 0.8)


def test_heatmap_decoder_border_peak() -> None:
    hm = np.zeros((1, 1, 8, 8))
    hm[0, 0, 0, 7] = 1.0
    xy, _ = decode_heatmaps(hm)
    np.testing.assert_allclose(xy[0, 0], [7, 0])


def test_simcc_decoder() -> None:
    x = np.arange(384)
    sx = np.exp(-((x - 101.0) ** 2) / 8.0)[None, None] * np.array([1.0, 0.4])[None, :, None]
    y = np.arange(512)
    sy = np.exp(-((y - 300.0) ** 2) / 8.0)[None, None] * np.array([0.9, 0.9])[None, :, None]
    xy, score = decode_simcc(sx, sy, split_ratio=2.0)
    np.testing.assert_allclose(xy[0], [[50.5, 150.0], [50.5, 150.0]])
    np.testing.assert_allclose(score[0], [0.9, 0.4])


def test_crop_transform_roundtrip_and_rotation() -> None:
    M = crop_transform(np.array([500.0, 800.0]), 400.0, np.pi / 2, 256)
    pts = np.array([[500.0, 800.0], [700.0, 800.0]])
    crop = pts @ M[:, :2].T + M[:, 2]
    np.testing.assert_allclose(crop[0], [128, 128], atol=1e-9)
    # Tilt +90°: the body's up direction points to +x; in the crop it points up.
    np.testing.assert_allclose(crop[1], [128, 0], atol=1e-9)
    np.testing.assert_allclose(apply_inverse(M, crop), pts, atol=1e-9)


def test_blazepose_mapping_names() -> None:
    mp = {
        0: "nose",
        2: "left_eye",
        5: "right_eye",
        11: "left_shoulder",
        24: "right_hip",
        29: "left_heel",
        32: "right_foot_index",
    }
    got = dict(zip(COCO17_FEET, BLAZEPOSE_TO_COCO17_FEET, strict=True))
    assert got["nose"] == 0 and got["left_eye"] == 2 and got["right_hip"] == 24
    assert got["left_heel"] == 29 and got["right_big_toe"] == 32 and got["left_small_toe"] == -1
    assert set(mp) <= set(BLAZEPOSE_TO_COCO17_FEET)


@pytest.fixture
def frame_and_box(models_dir: Path, test_data_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    from pipeline.backends.onnx.detectors import DetectorParams, YoloxDetector
    from pipeline.io.video import iter_frames

    img = next(iter(iter_frames(test_data_dir / "pose2sim_multiperson" / "videos" / "cam01.mp4", 0, 1)))[1]
    boxes, _ = YoloxDetector(models_dir / "yolox_nano.onnx", DetectorParams(num_threads=1)).detect([img])[0]
    return img, boxes[:1]


def _sanity(kp: np.ndarray, conf: np.ndarray, valid: np.ndarray, box: np.ndarray) -> None:
    h = box[3] - box[1]
    j = {n: i for i, n in enumerate(COCO17_FEET)}
    coco = [j[n] for n in COCO17]
    assert valid[coco].all()
    inside = (kp[coco, 0] > box[0] - 0.2 * h) & (kp[coco, 0] < box[2] + 0.2 * h)
    inside &= (kp[coco, 1] > box[1] - 0.2 * h) & (kp[coco, 1] < box[3] + 0.2 * h)
    assert inside.all()
    assert kp[j["nose"], 1] < kp[j["left_hip"], 1] < kp[j["left_ankle"], 1]
    assert np.median(conf[coco]) > 0.5


@pytest.mark.requires_models
@pytest.mark.requires_data
def test_blazepose_and_movenet_agree_on_real_frame(
    models_dir: Path, frame_and_box: tuple[np.ndarray, np.ndarray]
) -> None:
    img, box = frame_and_box
    bp = BlazePoseEstimator(models_dir / "pose_landmark_full.onnx", PoseParams(num_threads=1))
    mn = MoveNetEstimator(models_dir / "movenet_lightning_int8.onnx", PoseParams(num_threads=1))
    kb, cb, vb = bp.estimate(img, box)
    km, cm, vm = mn.estimate(img, box)
    _sanity(kb[0], cb[0], vb[0], box[0])
    _sanity(km[0], cm[0], vm[0], box[0])
    j = {n: i for i, n in enumerate(COCO17_FEET)}
    assert vb[0, [j["left_heel"], j["right_big_toe"]]].all() and not vb[0, j["left_small_toe"]]
    assert not vm[0, j["left_heel"]]  # MoveNet has no feet
    h = box[0, 3] - box[0, 1]
    body = [j[n] for n in COCO17[5:]]  # shoulders to ankles
    assert np.median(np.linalg.norm(kb[0, body] - km[0, body], axis=1)) < 0.06 * h


@pytest.mark.requires_models
@pytest.mark.requires_data
def test_blazepose_upright_crop_on_rotated_image(
    models_dir: Path, frame_and_box: tuple[np.ndarray, np.ndarray]
) -> None:
    img, box = frame_and_box
    bp = BlazePoseEstimator(models_dir / "pose_landmark_full.onnx", PoseParams(num_threads=1))
    k0, _, _ = bp.estimate(img, box)
    rot = cv2.rotate(img, cv2.ROTATE_90_CLOCKWISE)  # (x, y) -> (H - 1 - y, x)
    H = img.shape[0]
    x1, y1, x2, y2 = box[0]
    rbox = np.array([[H - 1 - y2, x1, H - 1 - y1, x2]])
    k1, _, _ = bp.estimate(rot, rbox)
    back = np.stack([k1[0, :, 1], H - 1 - k1[0, :, 0]], axis=1)
    body = [COCO17_FEET.index(n) for n in COCO17[5:]]
    err = np.median(np.linalg.norm(back[body] - k0[0, body], axis=1))
    assert err < 0.05 * (y2 - y1)


class _FakeSession:
    """Stands in for an onnxruntime session: returns outputs computed from known crop points."""

    def __init__(self, make: object) -> None:
        self.make = make
        self.batches: list[int] = []

    def run(self, names: object, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        (x,) = feeds.values()
        self.batches.append(x.shape[0])
        return self.make(x.shape[0])  # type: ignore[operator]


@pytest.mark.parametrize("kind", ["heatmap", "simcc"])
def test_mmpose_style_estimators_map_back_to_image(kind: str) -> None:
    """Full top-down path (crop → outputs → decode → image) with synthetic model outputs."""
    from pipeline.backends.onnx.pose import HeatmapEstimator, SimCCEstimator, crop_transform_rect

    rng = np.random.default_rng(0)
    H, W = 256, 192
    boxes = np.array([[100.0, 50.0, 300.0, 500.0], [400.0, 80.0, 520.0, 400.0]])
    truth = np.stack([rng.uniform(b[:2] + 10, b[2:] - 10, size=(17, 2)) for b in boxes])  # image px
    crop_pts = np.stack(
        [
            truth[i] @ crop_transform_rect(b, (W, H), 1.25)[:, :2].T
            + crop_transform_rect(b, (W, H), 1.25)[:, 2]
            for i, b in enumerate(boxes)
        ]
    )

    def make(n: int) -> list[np.ndarray]:
        assert n == len(boxes)
        if kind == "heatmap":
            return [np.stack([np.stack([_gauss2d(64, 48, x / 4, y / 4) for x, y in p]) for p in crop_pts])]
        xs, ys = np.arange(2 * W), np.arange(2 * H)
        sx = np.exp(-((xs[None, None] - 2 * crop_pts[..., :1]) ** 2) / 8.0)
        sy = np.exp(-((ys[None, None] - 2 * crop_pts[..., 1:]) ** 2) / 8.0)
        return [sx, sy]

    cls = HeatmapEstimator if kind == "heatmap" else SimCCEstimator
    est = cls.__new__(cls)
    est.params, est.input_hw, est.input_name, est.fixed_batch = PoseParams(), (H, W), "input", False
    est.sess = _FakeSession(make)  # type: ignore[assignment]
    img = np.zeros((600, 700, 3), np.uint8)
    kp, conf, valid = est.estimate(img, boxes)
    coco = [COCO17_FEET.index(n) for n in COCO17]
    px_per_img = np.array([crop_transform_rect(b, (W, H), 1.25)[0, 0] for b in boxes])  # crop px per image px
    err_crop_px = np.abs(kp[:, coco] - truth) * px_per_img[:, None, None]
    assert err_crop_px.max() < (0.5 if kind == "heatmap" else 0.3)  # SimCC bins are half a crop pixel
    assert valid[:, coco].all() and not valid[:, COCO17_FEET.index("left_heel")].any()
    assert np.all(conf[:, coco] > 0.5)
    # Batched across frames (e.g. views): one network call for the crops of every frame,
    # results identical to the per-frame call and routed back to the right frame.
    est.sess.batches.clear()  # type: ignore[attr-defined]
    many = est.estimate_many([img, img, img], [boxes[:1], np.zeros((0, 4)), boxes[1:]])
    assert est.sess.batches == [2]  # type: ignore[attr-defined]
    assert [len(m[0]) for m in many] == [1, 0, 1]
    np.testing.assert_allclose(np.concatenate([many[0][0], many[2][0]]), kp)
    np.testing.assert_array_equal(np.concatenate([many[0][2], many[2][2]]), valid)


@pytest.mark.requires_models
@pytest.mark.requires_data
def test_movenet_flip_test_and_refine_pass_keep_the_pose(
    models_dir: Path, frame_and_box: tuple[np.ndarray, np.ndarray]
) -> None:
    """Flip averaging and the closer second crop stay on the same person as one pass, with
    left and right where one pass puts them (a wrong mirror map would swap 12 of 17 joints)."""
    img, box = frame_and_box
    h = box[0, 3] - box[0, 1]
    path = models_dir / "movenet_lightning_int8.onnx"
    coco = [COCO17_FEET.index(n) for n in COCO17]
    k1, _, _ = MoveNetEstimator(path, PoseParams(num_threads=1)).estimate(img, box)
    for params in (PoseParams(num_threads=1, flip_test=True), PoseParams(num_threads=1, refine_scale=1.3)):
        k, c, v = MoveNetEstimator(path, params).estimate(img, box)
        _sanity(k[0], c[0], v[0], box[0])
        assert np.median(np.linalg.norm(k[0, coco] - k1[0, coco], axis=1)) < 0.03 * h
        assert ((c[0, coco] >= 0) & (c[0, coco] <= 1)).all()

