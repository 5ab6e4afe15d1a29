"""The annotate page's endpoints (``server/api/routes/frames.py``, ``annotate.py``) on a small bout
whose track and associate stages ran: cameras and timeline, detections equal to the artifacts (and
following a re-run of associate), frames as JPEG (the stand-in for a session without videos, the
real frame for the Pose2Sim sample videos), the reasons for a bad camera, frame or width, and the
page itself per role (sign-in redirect, edit controls for an annotator, none for a coach)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlmodel import Session

from pipeline.schema.association import Association
from pipeline.schema.base import load_npz
from pipeline.schema.detections import Tracks2D
from server import crud
from server.app import create_app
from server.core.config import Settings
from server.models import UserCreate
from tests.server.conftest import ROLES, auth

STAGES = ("detect2d", "track", "associate")
N_FRAMES = 40


@dataclass
class Bout:
    client: TestClient
    tokens: dict[str, str]
    sid: int
    folder: Path

    def get(self, path: str, role: str = "coach", **kw: object):  # noqa: ANN201
        return self.client.get(path, headers=auth(self.tokens[role]), **kw)  # type: ignore[arg-type]


def _app_with_users(home: Path, roots: list[Path]) -> tuple[TestClient, dict[str, str]]:
    app = create_app(Settings(home=home, allowed_roots=roots))
    tokens = {}
    with Session(app.state.engine, expire_on_commit=False) as db:
        for role in ROLES:
            user = crud.create_user(db, user_in=UserCreate.model_validate({"name": f"{role}1", "role": role}))
            tokens[role] = crud.issue_token(db, user=user)
    return TestClient(app), tokens


@pytest.fixture(scope="module")
def bout(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Bout]:
    from pipeline.runner.core import run
    from server.demo import make_session

    root = tmp_path_factory.mktemp("annotate")
    src = make_session(root / "data" / "b", n_frames=N_FRAMES, n_cameras=3, seed=0, stages=STAGES, use_synthetic=False)
    client, tokens = _app_with_users(root / "home", [root / "data"])
    with client:
        r = client.post("/api/sessions/from-folder", json={"path": str(src), "name": "sparring"},
                        headers=auth(tokens["admin"]))
        assert r.status_code == 201, r.text
        folder = Path(r.json()["folder"])
        run(folder)
        yield Bout(client, tokens, r.json()["id"], folder)


def _decode(jpeg: bytes) -> np.ndarray:
    """(H, W, 3) uint8 BGR."""
    img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None, "not a JPEG"
    return img


def _artifacts(folder: Path) -> tuple[Tracks2D, Association]:
    art = folder / "artifacts"
    return load_npz(art / "track" / "tracks.npz", Tracks2D), load_npz(art / "associate" / "association.npz", Association)


def test_info_lists_cameras_frames_persons_and_the_role(bout: Bout) -> None:
    from pipeline.io.session_rig import session_rig
    from pipeline.schema.session import SessionConfig

    rig = session_rig(bout.folder, SessionConfig.load(bout.folder))
    tracks, _ = _artifacts(bout.folder)
    info = bout.get(f"/api/sessions/{bout.sid}/frames").json()
    assert [c["name"] for c in info["cameras"]] == list(rig.names)
    assert [[c["width_px"], c["height_px"]] for c in info["cameras"]] == rig.image_size_wh.tolist()
    assert not any(c["video"] for c in info["cameras"])
    assert info["n_frames"] == N_FRAMES and info["fps"] == pytest.approx(rig.fps)
    assert [(p["id"], p["name"]) for p in info["persons"]] == [(0, "Red"), (1, "Blue")]
    assert info["joint_names"] == list(tracks.joint_names) and info["tracks"] and info["associated"]
    assert all(0 <= a < len(tracks.joint_names) and 0 <= b < len(tracks.joint_names) for a, b in info["bones"])
    assert info["can_edit"] is False and info["role"] == "coach"
    assert bout.get(f"/api/sessions/{bout.sid}/frames", "annotator").json()["can_edit"] is True


def test_detections_are_the_artifacts_rows(bout: Bout) -> None:
    tracks, assoc = _artifacts(bout.folder)
    cam = bout.get(f"/api/sessions/{bout.sid}/frames").json()["cameras"][1]["name"]
    for frame in (0, 17, N_FRAMES - 1):
        dets = bout.get(f"/api/sessions/{bout.sid}/detections", params={"view": cam, "frame": frame}).json()
        rows = tracks.rows(1, frame)
        assert dets["view"] == cam and dets["frame"] == frame and len(dets["detections"]) == len(rows) > 0
        by_track = {d["track"]: d for d in dets["detections"]}
        for r in rows:
            d = by_track[int(tracks.track_id[r])]
            assert d["person"] == int(assoc.person_of_det[r])
            assert d["name"] == ("Red", "Blue")[d["person"]] and d["color"] == ("#d62728", "#1f77b4")[d["person"]]
            assert d["confidence"] == pytest.approx(float(assoc.confidence[r]), abs=1e-4)
            assert np.allclose(d["box_xyxy_px"], tracks.bbox_xyxy_px[r], atol=0.01)
            kp = [p for p in d["keypoints_px"] if p is not None]
            assert np.allclose(kp, tracks.keypoints_px[r][tracks.keypoint_valid[r]], atol=0.01)
            same = (tracks.view == 1) & (tracks.track_id == tracks.track_id[r])
            assert d["track_frames"] == [int(tracks.frame[same].min()), int(tracks.frame[same].max())]


def test_standin_frame_jpeg_size_and_cache(bout: Bout) -> None:
    from pipeline.io.session_rig import session_rig
    from pipeline.schema.session import SessionConfig
    from webui.frames import render_synthetic_background

    rig = session_rig(bout.folder, SessionConfig.load(bout.folder))
    cam = rig.names[2]
    r = bout.get(f"/api/sessions/{bout.sid}/frames/{cam}/5.jpg", params={"max_width": 640})
    assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg"
    img = cv2.cvtColor(_decode(r.content), cv2.COLOR_BGR2RGB)
    w, h = rig.image_size_wh[2]
    assert img.shape == (round(h * 640 / w), 640, 3)
    expected = render_synthetic_background(rig, 2, 640 / w)
    assert np.abs(img.astype(float) - expected).mean() < 3.0  # the viewer's stand-in, JPEG-compressed
    again = bout.get(f"/api/sessions/{bout.sid}/frames/{cam}/5.jpg", params={"max_width": 640})
    assert again.content == r.content
    # never upscaled: a width above the camera's gives the camera's size
    big = bout.get(f"/api/sessions/{bout.sid}/frames/{cam}/5.jpg", params={"max_width": 4000})
    assert _decode(big.content).shape[:2] == (h, w)


@pytest.mark.parametrize(("path", "code", "reason"), [
    ("/frames/nocam/3.jpg", 404, "camera 'nocam' is not in this session; its cameras are ['cam0', 'cam1', 'cam2']"),
    ("/frames/cam0/40.jpg", 422, "frame 40 is outside the bout: frames are 0..39"),
    ("/frames/cam0/-2.jpg", 422, "frame -2 is outside the bout: frames are 0..39"),
    ("/frames/cam0/x.jpg", 422, "frame"),
    ("/frames/cam0/3.jpg?max_width=10", 422, "max_width"),
    ("/detections?view=nocam&frame=3", 404, "camera 'nocam' is not in this session"),
    ("/detections?view=cam0&frame=99", 422, "frame 99 is outside the bout: frames are 0..39"),
    ("/detections?frame=3", 422, "view"),
])  # fmt: skip
def test_bad_camera_frame_or_width_names_the_problem(bout: Bout, path: str, code: int, reason: str) -> None:
    r = bout.get(f"/api/sessions/{bout.sid}{path}")
    assert r.status_code == code, r.text
    assert reason in str(r.json()["detail"])


def test_unknown_session_and_no_token(bout: Bout) -> None:
    r = bout.get("/api/sessions/999/frames/cam0/1.jpg")
    assert r.status_code == 404 and "session 999 not found" in r.json()["detail"]
    assert bout.client.get(f"/api/sessions/{bout.sid}/frames/cam0/1.jpg").status_code == 401
    assert bout.client.get(f"/api/sessions/{bout.sid}/detections?view=cam0&frame=1").status_code == 401


def test_detections_follow_a_rerun_of_associate(bout: Bout) -> None:
    from pipeline.runner.core import run

    before = bout.get(f"/api/sessions/{bout.sid}/detections", params={"view": "cam0", "frame": 20}).json()
    swap = {"kind": "swap_identities", "frame": 15, "frame_end": 25, "person_a": 0, "person_b": 1}
    r = bout.client.post(f"/api/sessions/{bout.sid}/annotations", json={"annotation": swap, "rerun": False},
                         headers=auth(bout.tokens["annotator"]))
    assert r.status_code == 201, r.text
    run(bout.folder)
    try:
        after = bout.get(f"/api/sessions/{bout.sid}/detections", params={"view": "cam0", "frame": 20}).json()
        outside = bout.get(f"/api/sessions/{bout.sid}/detections", params={"view": "cam0", "frame": 30}).json()
        pb = {d["track"]: d["person"] for d in before["detections"]}
        pa = {d["track"]: (d["person"], d["name"]) for d in after["detections"]}
        assert set(pb.values()) == {0, 1}
        assert pa == {t: (1 - p, ("Red", "Blue")[1 - p]) for t, p in pb.items()}
        assert {d["person"] for d in outside["detections"]} == {0, 1}
    finally:  # the other tests read the unswapped association
        bout.client.post(f"/api/annotations/{r.json()['annotation']['id']}/undo", json={"rerun": False},
                         headers=auth(bout.tokens["annotator"]))
        run(bout.folder)


def _login(client: TestClient, role: str, token: str) -> None:
    r = client.post("/login", data={"name": f"{role}1", "token": token, "next": "/"}, follow_redirects=False)
    assert r.status_code == 303, r.text


def test_page_needs_sign_in_and_shows_edit_controls_by_role(bout: Bout) -> None:
    c = bout.client
    c.cookies.clear()
    r = c.get(f"/sessions/{bout.sid}/annotate", follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == f"/login?next=/sessions/{bout.sid}/annotate"
    try:
        _login(c, "annotator", bout.tokens["annotator"])
        page = c.get(f"/sessions/{bout.sid}/annotate").text
        assert 'data-can-edit="1"' in page and 'id="edit-controls"' in page and 'id="swap-to"' in page
        assert "<strong>sparring</strong>" in page and 'id="hotkeys"' in page
        assert c.get("/sessions/999/annotate").status_code == 404
        _login(c, "coach", bout.tokens["coach"])
        page = c.get(f"/sessions/{bout.sid}/annotate").text
        assert 'data-can-edit="0"' in page and 'id="readonly"' in page
        for control in ("edit-controls", "assign", "swap", "merge-a", "joint", "contact"):
            assert f'id="{control}"' not in page
        # the picker links to the page
        assert f'href="/sessions/{bout.sid}/annotate"' in c.get("/").text
    finally:
        c.cookies.clear()


def test_page_assets(bout: Bout) -> None:
    js = bout.client.get("/static/annotate/annotate.js")
    css = bout.client.get("/static/annotate/annotate.css")
    assert js.status_code == 200 and js.headers["content-type"].startswith("text/javascript") and "swap_identities" in js.text
    assert css.status_code == 200 and css.headers["content-type"].startswith("text/css")
    r = bout.client.get("/static/annotate/annotate.html")
    assert r.status_code == 404 and "annotate.js" in r.json()["detail"]


def test_pose2sim_video_frame_is_the_real_frame(tmp_path: Path, test_data_dir: Path) -> None:
    from pipeline.schema.session import SessionConfig

    data = test_data_dir / "pose2sim_multiperson"
    if not data.is_dir():
        pytest.skip(f"{data} not present in CORNERMAN_TEST_DATA_DIR")
    videos = {p.stem: str(p) for p in sorted((data / "videos").glob("*.mp4"))}
    src = tmp_path / "data" / "p2s"
    src.mkdir(parents=True)
    SessionConfig(name="p2s", source="video", calibration=str(data / "calibration" / "Calib.qca.txt"),
                  videos=videos).save(src)
    client, tokens = _app_with_users(tmp_path / "home", [tmp_path / "data", data])
    with client:
        r = client.post("/api/sessions/from-folder", json={"path": str(src)}, headers=auth(tokens["admin"]))
        assert r.status_code == 201, r.text
        sid = r.json()["id"]
        info = client.get(f"/api/sessions/{sid}/frames", headers=auth(tokens["coach"])).json()
        cap = cv2.VideoCapture(videos["cam02"])
        n_video = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        assert info["n_frames"] == n_video and all(c["video"] for c in info["cameras"])
        cam = next(c for c in info["cameras"] if c["name"] == "cam02")
        r = client.get(f"/api/sessions/{sid}/frames/cam02/30.jpg", params={"max_width": 544},
                       headers=auth(tokens["coach"]))
        assert r.status_code == 200, r.text
    served = _decode(r.content)
    cap.set(cv2.CAP_PROP_POS_FRAMES, 30)
    ok, bgr = cap.read()
    cap.release()
    assert ok and bgr is not None and bgr.shape[:2] == (cam["height_px"], cam["width_px"])
    h = round(bgr.shape[0] * 544 / bgr.shape[1])
    assert served.shape == (h, 544, 3)
    truth = cv2.resize(bgr, (544, h), interpolation=cv2.INTER_AREA).astype(float)
    assert np.abs(served - truth).mean() < 4.0  # the video's frame 30 (JPEG-compressed)
    cap = cv2.VideoCapture(videos["cam02"])
    cap.set(cv2.CAP_PROP_POS_FRAMES, 60)
    ok, later = cap.read()
    cap.release()
    assert ok and later is not None
    other = cv2.resize(later, (544, h), interpolation=cv2.INTER_AREA).astype(float)
    assert np.abs(served - other).mean() > np.abs(served - truth).mean() + 1.0  # not some other frame
    from webui.frames import BACKGROUND_RGB  # the stand-in is mostly this colour; the video is not

    assert np.mean(np.all(np.abs(served[..., ::-1].astype(int) - BACKGROUND_RGB) < 8, axis=-1)) < 0.5
