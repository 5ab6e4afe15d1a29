"""The viewer app against a real viser server (no browser) and the real API + worker."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import viser

from pipeline.artifacts import ArtifactStore
from tests.webui.conftest import ApiEnv, api_client
from tests.webui.fixtures import build_session
from webui.app import ViewerApp
from webui.colors import hex_to_rgb


def _count(img: np.ndarray, rgb: tuple[int, int, int], tol: int = 12) -> int:
    return int(np.all(np.abs(img.astype(int) - np.array(rgb)) <= tol, axis=-1).sum())


def test_read_only_viewer_renders_frames_and_persons(tmp_path: Path, server: viser.ViserServer) -> None:
    sdir = build_session(tmp_path, n_frames=10, physics=True)
    app = ViewerApp(server, sdir, role="coach", max_image_width=320)
    try:
        assert app.annotate is None  # a coach gets no editing controls
        app.timeline.frame.value = 4
        app.render(4)
        assert app.frame == 4
        img = app.views.images["cam2"].image
        assert img.shape == (180, 320, 3)
        assert _count(img, hex_to_rgb("#d62728")) > 20 and _count(img, hex_to_rgb("#1f77b4")) > 20
        assert sorted(app.persons.nodes) == [0, 1]
        kp = app.data.keypoints[app.opts.source]
        joints = app.persons.nodes[1].joints.points
        np.testing.assert_allclose(joints[:17], kp.xyz_m[4, 1], atol=2e-3)  # viser sends float16 points
        assert app.persons.nodes[0].physics is not None and app.persons.nodes[0].physics.visible
        # problems: low identity confidence at 5, high reprojection error at 8, penetration at 3
        app.timeline.next_problem.value = True
        assert app.frame == 5
        app.timeline.next_problem.value = True
        assert app.frame == 8
        app.render(8)
        assert "reprojection error high" in app.timeline.info.content
        # switching the source to triangulated keeps working (no physics keypoints drawn then)
        app.display.source.value = "Filtered"
        assert app.opts.source == "filtered"
        # a reload keeps the compiled physics model unless the physics stage was rewritten
        geoms = app.persons.physics_geoms
        app.reload()
        assert app.persons.physics_geoms is geoms and app.reloads == 1
        store = ArtifactStore(sdir)
        m = store.manifest("physics")
        store.write(m, {"result": app.data.physics, "keypoints3d": app.data.keypoints["physics"],
                        "scene.xml": (store.stage_dir("physics") / "scene.xml").read_text()})  # fmt: skip
        app.reload()
        assert app.persons.physics_geoms is not geoms and app.persons.physics_geoms is not None
    finally:
        app.close()


def test_annotator_swap_reruns_and_reloads(api_env: ApiEnv, server: viser.ViserServer) -> None:
    pytest.importorskip("pipeline.runner.steps.associate")
    from server.jobs.worker import Worker

    worker = Worker(api_env.settings)
    api = api_client(api_env, "annotator")
    api.start_job(api_env.session_id)
    worker.run_until_idle(timeout_s=120)
    app = ViewerApp(server, api_env.session_dir, api=api, session_id=api_env.session_id, role="annotator", max_image_width=320)
    try:
        a = app.annotate
        assert a is not None
        app.timeline.frame.value = 8
        app.render(8)
        a.view.value = "cam1"
        app.render(8)
        before = {int(o.split()[0][1:]): o.split()[1] for o in a.track.options if o.startswith("#")}
        assert sorted(before.values()) == ["Blue", "Red"]
        app.timeline.frame.value = 6
        a.swap_scope.value = "this view"
        a.swap.value = True  # the button click
        assert "Saved swap_identities" in a.status.content
        anns = api.annotations(api_env.session_id)
        assert anns[-1]["payload"] == {"kind": "swap_identities", "frame": 6, "person_a": 0, "person_b": 1, "view": "cam1"}
        worker.run_until_idle(timeout_s=120)
        t_end = time.monotonic() + 30
        while "results reloaded" not in a.status.content and time.monotonic() < t_end:
            time.sleep(0.2)
        assert "results reloaded" in a.status.content, a.status.content
        app.timeline.frame.value = 8
        app.render(8)
        after = {int(o.split()[0][1:]): o.split()[1] for o in a.track.options if o.startswith("#")}
        assert after == {t: {"Red": "Blue", "Blue": "Red"}[p] for t, p in before.items()}
        # undo brings the original identities back after the next re-run
        a.undo.value = True
        assert "Undo of annotation" in a.status.content
        worker.run_until_idle(timeout_s=120)
        t_end = time.monotonic() + 30
        while "results reloaded" not in a.status.content and time.monotonic() < t_end:
            time.sleep(0.2)
        assert "Undo of annotation" in a.status.content and "results reloaded" in a.status.content
        app.render(8)
        again = {int(o.split()[0][1:]): o.split()[1] for o in a.track.options if o.startswith("#")}
        assert again == before
    finally:
        app.close()


def test_play_advances_frames(tmp_path: Path, server: viser.ViserServer) -> None:
    app = ViewerApp(server, build_session(tmp_path, n_frames=40), role="coach", max_image_width=160)
    try:
        app.timeline.speed.value = "2x"
        app.timeline.play.value = True
        time.sleep(0.6)  # 25 fps x 2: about 30 frames
        app.timeline.play.value = False
        time.sleep(0.1)  # a frame step already past the loop's Play check when Pause came may still land
        played = app.frame
        assert played > 3
        time.sleep(0.3)
        assert app.frame == played  # paused
    finally:
        app.close()


def test_viewer_of_a_session_not_run_yet(tmp_path: Path, server: viser.ViserServer) -> None:
    sdir = build_session(tmp_path, n_frames=6)
    store = ArtifactStore(sdir)
    for stage in ("track", "associate", "triangulate"):
        store.invalidate(stage)
    app = ViewerApp(server, sdir, role="coach", max_image_width=160)
    try:
        app.render(0)
        assert app.persons.nodes == {} and app.data.n_frames == 1
        img = app.views.images["cam1"].image
        assert img.shape == (90, 160, 3) and img.max() > 0  # the rendered stand-in frame (floor grid)
    finally:
        app.close()
