from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.schema import SessionConfig
from tests.webui.fixtures import build_session
from webui.colors import IdentityPalette, hex_to_rgb
from webui.frames import BACKGROUND_RGB, FrameProvider, draw_overlay, overlay_for, render_synthetic_background
from webui.scene.session_data import load_session_data

RED, BLUE = hex_to_rgb("#d62728"), hex_to_rgb("#1f77b4")


def _count(img: np.ndarray, rgb: tuple[int, int, int], tol: int = 12) -> int:
    return int(np.all(np.abs(img.astype(int) - np.array(rgb)) <= tol, axis=-1).sum())


def test_synthetic_background_shows_the_floor(tmp_path: Path) -> None:
    d = load_session_data(build_session(tmp_path, n_frames=4))
    img = render_synthetic_background(d.rig, 0, 0.5)
    assert img.shape == (180, 320, 3)
    bg = np.all(img == np.array(BACKGROUND_RGB, dtype=np.uint8), axis=-1).mean()
    assert 0.5 < bg < 0.99  # mostly dark, but the grid and the ring are drawn


def test_overlay_colours_follow_identity(tmp_path: Path) -> None:
    d = load_session_data(build_session(tmp_path, n_frames=4))
    pal = IdentityPalette(None, ("Red", "Blue"))
    fp = FrameProvider(d, max_width=320)
    img = fp.frame(0, 2)
    ov = overlay_for(d, 0, 2, "filtered")
    assert ov.boxes_px.shape == (2, 4) and ov.reproj_px.shape == (2, 17, 2)
    out = draw_overlay(img, ov, fp.scale(0), pal)
    # each athlete's box region holds its colour
    for i in range(2):
        p = int(ov.persons[i])
        x0, y0, x1, y1 = (ov.boxes_px[i] * fp.scale(0)).astype(int)
        crop = out[max(0, y0 - 2) : y1 + 3, max(0, x0 - 2) : x1 + 3]
        assert _count(crop, (RED, BLUE)[p]) > 20, f"no {('red', 'blue')[p]} pixels in the box of person {p}"
    # unassigned detections are grey: drop the association
    d.association = None
    grey = draw_overlay(fp.frame(0, 2), overlay_for(d, 0, 2, "filtered"), fp.scale(0), pal)
    assert _count(grey, (150, 150, 150)) > 20


def test_overlay_reprojection_matches_detections(tmp_path: Path) -> None:
    d = load_session_data(build_session(tmp_path, n_frames=4))
    ov = overlay_for(d, 1, 3, "filtered")
    # the fixture's detections are exact projections of the 3D keypoints
    for i in range(2):
        k = int(np.flatnonzero(ov.reproj_persons == ov.persons[i])[0])
        np.testing.assert_allclose(ov.reproj_px[k], ov.keypoints_px[i], atol=1e-6)
    assert overlay_for(d, 1, 3, "physics").reproj_px.shape[0] == 0  # absent source: nothing reprojected


def test_video_frames_are_decoded_lazily_and_cached(tmp_path: Path) -> None:
    sdir = build_session(tmp_path, n_frames=6)
    cfg = SessionConfig.load(sdir)
    vids = {}
    for name in cfg_names(sdir):
        path = sdir / "inputs" / f"{name}.avi"
        w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (640, 360))
        if not w.isOpened():
            pytest.skip("OpenCV cannot write MJPG video here")
        for f in range(6):
            frame = np.zeros((360, 640, 3), np.uint8)
            frame[:, : 100 * (f + 1)] = (0, 200, 0)  # BGR green band whose width encodes the frame
            w.write(frame)
        w.release()
        vids[name] = f"inputs/{name}.avi"
    SessionConfig(**{**cfg.__dict__, "source": "video", "videos": vids}).save(sdir)
    d = load_session_data(sdir)
    fp = FrameProvider(d, max_width=320)
    assert fp.decoded == 0  # nothing decoded up front
    for f in range(6):
        img = fp.frame(0, f)
        band = int((img[90, :, 1] > 100).sum())
        assert abs(band - 50 * (f + 1)) <= 3, (f, band)
    assert fp.decoded == 6
    fp.frame(0, 2)
    fp.frame(0, 5)
    assert fp.decoded == 6  # served from the cache
    both = fp.frames(4)  # every view at once, decoded in parallel
    assert len(both) == d.rig.n_views and all(abs(int((b[90, :, 1] > 100).sum()) - 250) <= 3 for b in both)
    img = fp.frame(0, 6)  # past the end: a blank stand-in, not an exception
    assert img.shape == (180, 320, 3)
    fp.close()


def cfg_names(sdir: Path) -> tuple[str, ...]:
    return load_session_data(sdir).camera_names
