"""2D keypoint importers on real files (Pose2Sim's OpenPose BODY_25B output, a
COCO-WholeBody sample) plus files derived from them in tmp_path for the other
skeletons, and every bad-input case."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.io.calibration import load_calibration
from pipeline.io.keypoints2d import load_keypoints, load_keypoints_with_ids
from pipeline.schema.camera import CameraRig
from pipeline.schema.joints import COCO17, COCO17_FEET

DATA = Path(__file__).resolve().parents[1] / "data" / "io"
OP25B = DATA / "openpose_body25b"
COCO_FILE = DATA / "coco" / "coco_wholebody_sample.json"


@pytest.fixture
def rig2() -> CameraRig:
    """The calibration of the cameras that recorded the OpenPose fixture (cam_01, cam_02)."""
    return load_calibration(DATA / "pose2sim" / "Calib_qualisys.toml").subset([0, 1])


def op_paths(root: Path = OP25B) -> dict[str, Path]:
    return {"cam_01": root / "cam01", "cam_02": root / "cam02"}


def people(path: Path) -> list[np.ndarray]:
    return [np.array(p["pose_keypoints_2d"]).reshape(-1, 3) for p in json.loads(path.read_text())["people"]]


def convert_fixture(tmp_path: Path, fn) -> Path:  # noqa: ANN001 (a small converter callback)
    """Copy the BODY_25B fixture, rewriting every person's keypoints with ``fn``."""
    root = tmp_path / "converted"
    for cam in ("cam01", "cam02"):
        (root / cam).mkdir(parents=True)
        for f in (OP25B / cam).glob("*.json"):
            doc = json.loads(f.read_text())
            for p in doc["people"]:
                p["pose_keypoints_2d"] = fn(np.array(p["pose_keypoints_2d"]).reshape(-1, 3)).ravel().tolist()
            (root / cam / f.name).write_text(json.dumps(doc))
    return root


def mid(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = (a + b) / 2
    out[2] = min(a[2], b[2])
    return out


def to_body25(k: np.ndarray) -> np.ndarray:
    """BODY_25B -> BODY_25 order (neck = mid-shoulders, mid-hip = mid-hips)."""
    c = {n: k[i] for i, n in enumerate(COCO17)}
    order = [
        c["nose"], mid(c["left_shoulder"], c["right_shoulder"]), c["right_shoulder"], c["right_elbow"],
        c["right_wrist"], c["left_shoulder"], c["left_elbow"], c["left_wrist"], mid(c["left_hip"], c["right_hip"]),
        c["right_hip"], c["right_knee"], c["right_ankle"], c["left_hip"], c["left_knee"], c["left_ankle"],
        c["right_eye"], c["left_eye"], c["right_ear"], c["left_ear"],
    ]  # fmt: skip
    return np.vstack([np.stack(order), k[19:25]])


def to_halpe26(k: np.ndarray) -> np.ndarray:
    head, neck, hip = k[18], k[17], mid(k[11], k[12])
    lbt, lst, lh, rbt, rst, rh = k[19:25]
    return np.vstack([k[:17], [head, neck, hip, lbt, rbt, lst, rst, lh, rh]])


def to_coco18(k: np.ndarray) -> np.ndarray:
    c = {n: k[i] for i, n in enumerate(COCO17)}
    names = [
        "nose",
        None,
        "right_shoulder",
        "right_elbow",
        "right_wrist",
        "left_shoulder",
        "left_elbow",
        "left_wrist",
    ]
    names += ["right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle"]
    names += ["right_eye", "left_eye", "right_ear", "left_ear"]
    return np.stack([c[n] if n else mid(c["left_shoulder"], c["right_shoulder"]) for n in names])


# ------------------------------------------------------------------ OpenPose


def test_openpose_body25b_real_files(rig2: CameraRig) -> None:
    dets = load_keypoints(op_paths(), "openpose", rig2, openpose_skeleton="body25b")
    assert dets.joint_names == COCO17_FEET
    assert (dets.n_views, dets.n_frames, dets.n_dets) == (2, 1, 4)
    np.testing.assert_array_equal(dets.view, [0, 0, 1, 1])
    np.testing.assert_array_equal(dets.frame, [0, 0, 0, 0])  # file number 5 is the first frame
    src = people(OP25B / "cam02" / "cam02.0005.json")[0]
    row = 2
    # COCO-17 part is copied, the feet come from BODY_25B's points 19-24.
    np.testing.assert_allclose(dets.keypoints_px[row, :17], src[:17, :2])
    np.testing.assert_allclose(dets.keypoints_px[row, 17:], src[19:25, :2])
    np.testing.assert_allclose(dets.keypoint_conf[row, 17], 0.57607)
    kept = src[[*range(17), *range(19, 25)]]  # upper neck and head top are not in COCO17_FEET
    np.testing.assert_allclose(dets.bbox_xyxy_px[row], [*kept[:, :2].min(0), *kept[:, :2].max(0)])
    assert dets.bbox_score[row] == pytest.approx(kept[:, 2].mean())
    # Confidence 0 -> invalid (cam01 person 1: right shoulder, right hip, right heel).
    bystander = dets.keypoint_valid[1]
    assert (
        not bystander[COCO17_FEET.index("right_shoulder")] and not bystander[COCO17_FEET.index("right_heel")]
    )
    assert bystander.sum() == 20
    assert np.all(dets.keypoints_px[1][~bystander] == 0)


def test_openpose_auto_rejects_body25b_as_body25(rig2: CameraRig) -> None:
    with pytest.raises(ValueError, match=r"cam01: 25-point keypoints.*openpose_skeleton='body25b'"):
        load_keypoints(op_paths(), "openpose", rig2)


@pytest.mark.parametrize(
    ("convert", "joints"), [(to_body25, COCO17_FEET), (to_halpe26, COCO17_FEET), (to_coco18, COCO17)]
)
def test_openpose_skeletons_auto_detected(convert, joints, rig2: CameraRig, tmp_path: Path) -> None:  # noqa: ANN001
    ref = load_keypoints(op_paths(), "openpose", rig2, openpose_skeleton="body25b")
    dets = load_keypoints(op_paths(convert_fixture(tmp_path, convert)), "openpose", rig2)
    assert dets.joint_names == joints
    J = len(joints)
    np.testing.assert_allclose(dets.keypoints_px, ref.keypoints_px[:, :J])
    np.testing.assert_allclose(dets.keypoint_conf, ref.keypoint_conf[:, :J])
    np.testing.assert_array_equal(dets.keypoint_valid, ref.keypoint_valid[:, :J])


def write_openpose(
    folder: Path, frames: dict[int, list[list[float]]], ids: dict[int, int] | None = None
) -> None:
    """OpenPose-named files ``clip_<12 digits>_keypoints.json`` with the given people."""
    folder.mkdir(parents=True, exist_ok=True)
    for f, ppl in frames.items():
        doc = {
            "version": 1.3,
            "people": [
                {"person_id": [(ids or {}).get(f, -1)], "pose_keypoints_2d": k, "face_keypoints_2d": []}
                for k in ppl
            ],
        }
        (folder / f"clip_{f:012d}_keypoints.json").write_text(json.dumps(doc))


def body25_person(seed: int) -> list[float]:
    base = to_body25(people(OP25B / "cam01" / "cam01.0005.json")[0])
    base[:, :2] += np.random.default_rng(seed).normal(0, 5, size=(25, 2))
    return base.ravel().tolist()


def test_openpose_frames_ids_and_padding(rig2: CameraRig, tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    write_openpose(a, {0: [body25_person(0)], 1: [], 3: [body25_person(1), body25_person(2)]}, ids={3: 7})
    write_openpose(b, {0: [body25_person(3)], 1: [body25_person(4)], 3: []})
    dets, ids = load_keypoints_with_ids({"cam_01": a, "cam_02": b}, "openpose", rig2)
    assert dets.n_frames == 4  # frame 2 has no file in either camera: it stays empty
    np.testing.assert_array_equal(dets.frame, [0, 0, 1, 3, 3])
    np.testing.assert_array_equal(dets.view, [0, 1, 1, 0, 0])
    np.testing.assert_array_equal(ids, [-1, -1, -1, 7, 7])
    # Without any person_id the ids are None.
    assert load_keypoints_with_ids({"cam_01": b, "cam_02": b}, "openpose", rig2)[1] is None
    # frame_from="order": frames are ranks in file order.
    dets = load_keypoints({"cam_01": a, "cam_02": b}, "openpose", rig2, frame_from="order")
    np.testing.assert_array_equal(dets.frame, [0, 0, 1, 2, 2])
    assert dets.n_frames == 3
    # Mismatched frames: an error naming both cameras, or padding when asked.
    (b / "clip_000000000003_keypoints.json").rename(b / "clip_000000000005_keypoints.json")
    with pytest.raises(
        ValueError, match=r"camera 'cam_02'.*has 3 frames.*only in 'cam_01': \[3\].*only in 'cam_02': \[5\]"
    ):
        load_keypoints({"cam_01": a, "cam_02": b}, "openpose", rig2)
    dets = load_keypoints({"cam_01": a, "cam_02": b}, "openpose", rig2, pad_frames=True)
    assert dets.n_frames == 6


def test_openpose_camera_checks(rig2: CameraRig) -> None:
    with pytest.raises(ValueError, match=r"camera\(s\) \['cam_09'\].*not in the calibration"):
        load_keypoints(
            op_paths() | {"cam_09": OP25B / "cam01"}, "openpose", rig2, openpose_skeleton="body25b"
        )
    with pytest.raises(ValueError, match=r"calibration camera\(s\) \['cam_02'\] have no keypoints"):
        load_keypoints({"cam_01": OP25B / "cam01"}, "openpose", rig2, openpose_skeleton="body25b")
    dets = load_keypoints(
        {"cam_01": OP25B / "cam01"}, "openpose", rig2, openpose_skeleton="body25b", allow_missing_cameras=True
    )
    assert dets.n_views == 2 and set(dets.view.tolist()) == {0}


def test_openpose_bad_inputs(rig2: CameraRig, tmp_path: Path) -> None:
    root = tmp_path / "op"
    shutil.copytree(OP25B, root)
    paths = op_paths(root)
    f = root / "cam02" / "cam02.0005.json"
    good = f.read_text()

    def fails(match: str, **kw: object) -> None:
        with pytest.raises(ValueError, match=match):
            load_keypoints(paths, "openpose", rig2, **({"openpose_skeleton": "body25b"} | kw))

    with pytest.raises(ValueError, match=r"cam09: OpenPose keypoint folder for camera 'cam_02' not found"):
        load_keypoints(paths | {"cam_02": root / "cam09"}, "openpose", rig2)
    with pytest.raises(ValueError, match=r"expected a folder"):
        load_keypoints(paths | {"cam_02": f}, "openpose", rig2)
    f.write_text(good[:200] + "\n" + good[200:].replace(",", ";", 1))
    fails(r"cam02\.0005\.json: malformed JSON at line 2, column")
    f.write_text(good.replace("563.089", "NaN", 1))
    fails(r"cam02\.0005\.json: person 0: NaN/inf value in keypoint 0")
    f.write_text(good.replace("563.089, 473.699, 0.648743, ", "", 1))
    with pytest.raises(ValueError, match=r"cam02\.0005\.json: person 0: 72 values in pose_keypoints_2d"):
        load_keypoints({"cam_02": root / "cam02"}, "openpose", rig2, allow_missing_cameras=True)
    fails(r"cam02\.0005\.json: person 0: expected 75 values")
    f.write_text(good.replace("0.648743", "-0.5", 1))
    fails(r"cam02\.0005\.json: person 0: negative confidence")
    f.write_text('{"version": 1.3}')
    fails(r"cam02\.0005\.json: not an OpenPose file")
    f.unlink()
    fails(r"cam02: no OpenPose \*\.json files")
    (root / "cam02" / "notes.json").write_text(good)
    fails(r"notes\.json: no frame number in the file name")
    with pytest.raises(ValueError, match="openpose_skeleton must be one of"):
        load_keypoints(paths, "openpose", rig2, openpose_skeleton="body_99")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="format must be 'openpose' or 'coco'"):
        load_keypoints(paths, "alphapose", rig2)  # type: ignore[arg-type]


# ------------------------------------------------------------------ COCO


def test_coco_wholebody_real_file(rig2: CameraRig) -> None:
    dets, ids = load_keypoints_with_ids({"cam_01": COCO_FILE, "cam_02": COCO_FILE}, "coco", rig2)
    assert ids is None
    assert dets.joint_names == COCO17_FEET
    assert (dets.n_frames, dets.n_dets) == (2, 4)  # images 785 and 40083 -> frames 0 and 1
    ann = json.loads(COCO_FILE.read_text())["annotations"]
    first = dets.rows(0, 0)[0]
    kp = np.array(ann[0]["keypoints"]).reshape(17, 3)
    feet = np.array(ann[0]["foot_kpts"]).reshape(6, 3)
    np.testing.assert_allclose(dets.keypoints_px[first], np.vstack([kp[:, :2], feet[:, :2]]))
    assert dets.keypoint_valid[first].all() and np.all(dets.keypoint_conf[first] == 1.0)  # v = 2 -> 1
    x, y, w, h = ann[0]["bbox"]
    np.testing.assert_allclose(dets.bbox_xyxy_px[first], [x, y, x + w, y + h])
    second = dets.rows(0, 1)[0]
    valid = dets.keypoint_valid[second]
    assert valid.sum() == 14 + 3  # 14 labelled body points, the right foot is unlabelled
    assert not valid[COCO17_FEET.index("right_heel")] and valid[COCO17_FEET.index("left_heel")]
    assert dets.keypoint_conf[second, COCO17_FEET.index("left_knee")] == 1.0  # v = 1 (occluded) is valid


def test_coco_results_list_with_scores_and_track_ids(rig2: CameraRig, tmp_path: Path) -> None:
    ann = json.loads(COCO_FILE.read_text())["annotations"]
    res = [
        {"image_id": 20, "category_id": 1, "keypoints": ann[1]["keypoints"], "score": 0.8, "track_id": 4},
        {"image_id": 10, "category_id": 1, "keypoints": ann[0]["keypoints"], "score": 0.9, "track_id": 2},
    ]
    p = tmp_path / "res.json"
    p.write_text(json.dumps(res))
    dets, ids = load_keypoints_with_ids({"cam_01": p, "cam_02": p}, "coco", rig2)
    assert dets.joint_names == COCO17  # no foot points anywhere
    np.testing.assert_array_equal(dets.frame, [0, 0, 1, 1])  # image 10 before 20
    np.testing.assert_allclose(dets.bbox_score, [0.9, 0.9, 0.8, 0.8])
    np.testing.assert_array_equal(ids, [2, 2, 4, 4])


def test_coco_bad_inputs(rig2: CameraRig, tmp_path: Path) -> None:
    doc = json.loads(COCO_FILE.read_text())
    p = tmp_path / "c.json"

    def fails(d: object, match: str) -> None:
        p.write_text(d if isinstance(d, str) else json.dumps(d))
        with pytest.raises(ValueError, match=match):
            load_keypoints({"cam_01": p, "cam_02": COCO_FILE}, "coco", rig2)

    fails('{"images": [],\n "annotations": [}', r"c\.json: malformed JSON at line 2")
    bad = json.loads(json.dumps(doc))
    bad["annotations"][0]["keypoints"] = bad["annotations"][0]["keypoints"][:-3]
    fails(bad, r"c\.json: annotations\[0\]: 'keypoints' must hold 3 x 17.*got 48")
    bad = json.loads(json.dumps(doc))
    bad["annotations"][1]["image_id"] = 5
    fails(bad, r"annotations\[1\]: image_id 5 is not in 'images'")
    bad = json.loads(json.dumps(doc))
    bad["annotations"][0]["keypoints"][4] = float("nan")
    fails(bad, r"annotations\[0\]: NaN/inf value in keypoint 1")
    bad = json.loads(json.dumps(doc))
    bad["images"] = bad["images"][:1]
    bad["annotations"] = bad["annotations"][:1]
    fails(bad, r"camera 'cam_02'.*has 2 frames but camera 'cam_01'.*has 1")
    fails({"annotations": []}, r"c\.json: a COCO file needs 'images' and 'annotations'")
    with pytest.raises(ValueError, match=r"nope\.json: COCO keypoint file for camera 'cam_01' not found"):
        load_keypoints({"cam_01": tmp_path / "nope.json", "cam_02": COCO_FILE}, "coco", rig2)


def test_a_camera_without_keypoints_names_the_cli_options(rig2: CameraRig) -> None:
    rig3 = load_calibration(DATA / "pose2sim" / "Calib_qualisys.toml").subset([0, 1, 2])
    with pytest.raises(ValueError) as e:
        load_keypoints(op_paths(), "openpose", rig3)
    msg = str(e.value)
    assert rig3.names[2] in msg and "--keypoints CAM=PATH" in msg and "--cameras cam_01,cam_02" in msg
    assert "allow_missing_cameras" not in msg


@pytest.mark.parametrize("doc", [{"images": [], "annotations": []}, []])
def test_an_empty_coco_file_is_named(tmp_path: Path, rig2: CameraRig, doc: object) -> None:
    empty = tmp_path / "empty.json"
    empty.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"empty\.json: COCO keypoint file for camera 'cam_02' holds no frames"):
        load_keypoints({"cam_01": COCO_FILE, "cam_02": empty}, "coco", rig2)
