"""Stale layers after an edit: the pure rules (stage order, ``stale_from``, rewritten stages ->
stale layers, their labels, the progress fraction), then the viewer in-process against the
real API and worker: an annotator's swap greys the out-of-date layers until the re-run's
artifacts are loaded, and an identity renamed / recoloured through the API reaches an open viewer."""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import pytest
import viser

from pipeline.runner.registry import STAGE_ORDER
from tests.webui.conftest import ApiEnv, api_client
from tests.webui.fixtures import wait_for
from webui.app import ViewerApp
from webui.colors import hex_to_rgb
from webui.jobs import job_fraction, job_summary
from webui.scene.persons import DIM_RGB
from webui.staleness import (
    LAYERS,
    StaleMark,
    job_activity,
    layer_states,
    layers_markdown,
    rewritten_since,
    stale_layers,
    stale_stages,
    unix_time,
)

ALL = list(STAGE_ORDER)


def test_stale_layers_follow_the_stage_order() -> None:
    assert stale_layers(ALL, None, ()) == frozenset()
    assert stale_layers(ALL, "track", ()) == frozenset(LAYERS)
    # the 2D stages and triangulate rewritten: the 2D labels and the 3D are fresh again
    assert stale_layers(ALL, "track", {"track", "associate", "calibrate", "triangulate"}) == {"fit", "physics", "analytics"}
    # a layer with two stages stays stale until both are rewritten
    assert "2D labels" in stale_layers(ALL, "track", {"track"})
    assert stale_layers(ALL, "fit", ()) == {"fit", "physics", "analytics"}
    assert stale_layers(ALL, "physics", {"physics", "analyze"}) == {"analytics"}  # evaluate still old
    # a stage the session does not run is never stale (nothing would refresh it)
    assert stale_layers(["track", "associate", "triangulate"], "track", {"track", "associate"}) == {"3D (filtered)"}
    assert stale_stages(["detect2d", "track", "fit"], "associate", ()) == ("fit",)
    with pytest.raises(ValueError, match="unknown stage 'tracking'"):
        stale_layers(ALL, "tracking", ())
    with pytest.raises(ValueError, match="unknown stage 'bogus'"):
        stale_layers(["track", "bogus"], "track", ())


def test_rewritten_since_and_api_times() -> None:
    assert rewritten_since({"track": 10.0, "fit": 5.0, "physics": 0.0}, 7.0) == {"track"}
    assert unix_time("1970-01-01T00:01:40") == 100.0  # a naive time from the API is UTC
    assert unix_time("1970-01-01T01:01:40+01:00") == 100.0
    with pytest.raises(ValueError, match="not an ISO 8601 time"):
        unix_time("yesterday")


def test_labels_say_what_the_rerun_is_doing() -> None:
    job = {"id": 7, "status": "running", "current_stage": "physics",
           "progress": {"fit": {"status": "ran", "done": 1, "total": 1},
                        "physics": {"status": "running", "done": 3, "total": 12, "message": "window 3/12"}}}  # fmt: skip
    assert job_activity(job) == "re-running physics (window 3/12)"
    assert job_activity({**job, "status": "queued"}) == "re-run queued"
    assert job_activity({**job, "status": "failed", "error": "ValueError: boom\ntrace"}) == "re-run failed: ValueError: boom"
    assert "physics: window 3/12" in job_summary(job)
    mark = StaleMark("fit", since_unix_s=100.0, job_id=7, job=job)
    states = layer_states(ALL, mark, {"fit": 150.0, "physics": 90.0, "analyze": 90.0, "evaluate": 90.0})
    assert states == {"2D labels": "", "3D (filtered)": "", "fit": "",
                      "physics": "re-running physics (window 3/12)", "analytics": "re-running physics (window 3/12)"}  # fmt: skip
    text = layers_markdown(states)
    assert "**physics**: ⚠ out of date — re-running physics (window 3/12)" in text
    assert "**fit**: ✓ up to date" in text
    assert layers_markdown(layer_states(ALL, None, {})) == ""


def test_job_fraction_moves_within_a_stage_and_counts_stages_that_ran() -> None:
    def job(fit_done: float, phys: dict) -> dict:
        return {"status": "running", "progress": {
            "track": {"status": "skipped"}, "triangulate": {"status": "ran", "done": 1, "total": 1},
            "fit": {"status": "ran" if fit_done >= 40 else "running", "done": fit_done, "total": 40}, "physics": phys}}  # fmt: skip

    pending = {"status": "pending", "done": 0, "total": None}
    seq = [job(0, pending), job(10, pending), job(30, pending), job(40, {"status": "running", "done": 1, "total": 12}),
           job(40, {"status": "running", "done": 6, "total": 12})]
    fr = [job_fraction(j) for j in seq]
    assert fr == sorted(fr) and len(set(fr)) == len(fr)
    assert fr[0] == pytest.approx(2 / 4)  # the stage that ran counts (it was left out before)
    assert job_fraction(seq[-1]) == pytest.approx((3 + 0.5) / 4)
    # weighted by the stages' usual durations, physics (long) fills most of the bar
    w = {"track": 0.1, "triangulate": 0.1, "fit": 40.0, "physics": 200.0}
    assert job_fraction(seq[-1], w) == pytest.approx((0.2 + 40 + 100) / 240.2)
    assert job_fraction({"status": "done", "progress": {}}) == 1.0


# ---------------------------------------------------------------------- the viewer in-process
def _count(img: np.ndarray, rgb: tuple[int, int, int], tol: int = 12) -> int:
    return int(np.all(np.abs(img.astype(int) - np.array(rgb)) <= tol, axis=-1).sum())


def _colours(app: ViewerApp, pid: int) -> set[tuple[int, ...]]:
    return {tuple(int(c) for c in row) for row in np.asarray(app.persons.nodes[pid].skeleton.colors).reshape(-1, 3)}


_wait = partial(wait_for, timeout_s=30.0)


def test_a_swap_marks_layers_stale_until_the_rerun_is_loaded(api_env: ApiEnv, server: viser.ViserServer) -> None:
    pytest.importorskip("pipeline.runner.steps.associate")
    from server.jobs.worker import Worker

    worker = Worker(api_env.settings)
    api = api_client(api_env, "annotator")
    api.start_job(api_env.session_id)
    worker.run_until_idle(timeout_s=120)
    app = ViewerApp(server, api_env.session_dir, api=api, session_id=api_env.session_id, role="annotator", max_image_width=320)
    try:
        a = app.annotate
        assert a is not None and not app.layers.visible
        red = hex_to_rgb(app.palette.get(0).color_hex)  # type: ignore[union-attr]
        app.timeline.frame.value = 6
        app.render(6)
        assert _count(app.views.images["cam1"].image, red) > 20
        assert _colours(app, 0) == {red}
        a.swap.value = True  # the button: swap from frame 6 in cam1
        assert "Saved swap_identities" in a.status.content
        # before the worker has run anything, every layer this session has is out of date
        text = app.layers.content
        assert app.layers.visible
        for layer in ("2D labels", "3D (filtered)"):
            assert f"**{layer}**: ⚠ out of date — re-run queued" in text
        assert "**fit**: ✓" in text  # this session does not fit: nothing of it is stale
        app.render(6)
        assert _colours(app, 0) == {DIM_RGB}  # the old 3D is grey, not red
        assert _count(app.views.images["cam1"].image, red) == 0  # old 2D labels grey too
        worker.run_until_idle(timeout_s=120)
        assert _wait(lambda: not app.layers.visible), app.layers.content
        assert app.stale is None
        app.render(6)
        assert _colours(app, 0) == {red}
        assert _count(app.views.images["cam1"].image, red) > 20
    finally:
        app.close()


def test_identity_rename_and_colour_reach_an_open_viewer(api_env: ApiEnv, server: viser.ViserServer) -> None:
    pytest.importorskip("pipeline.runner.steps.associate")
    from server.jobs.worker import Worker

    api = api_client(api_env, "annotator")
    api.start_job(api_env.session_id)
    Worker(api_env.settings).run_until_idle(timeout_s=120)
    app = ViewerApp(server, api_env.session_dir, api=api, session_id=api_env.session_id, role="annotator", max_image_width=320)
    try:
        a = app.annotate
        assert a is not None and "Red" in app.header.content
        r = api_env.client.put(f"/api/sessions/{api_env.session_id}/identities/0", json={"name": "Rojo", "color": "#10c040"},
                               headers={"Authorization": f"Bearer {api_env.tokens['annotator']}"})  # fmt: skip
        assert r.status_code == 200, r.text
        assert _wait(lambda: "Rojo" in app.header.content, timeout_s=5.0), app.header.content
        assert "Red" not in app.header.content
        assert a.assign[0].label == "Assign to Rojo" and a.swap.label == "Swap Rojo and Blue from this frame"
        assert _colours(app, 0) == {(0x10, 0xC0, 0x40)}
        app.timeline.frame.value = 3
        app.render(3)
        assert _count(app.views.images["cam2"].image, (0x10, 0xC0, 0x40)) > 20
        assert any(o.endswith(" Rojo") for o in a.track.options)
    finally:
        app.close()


def test_a_viewer_without_api_never_marks_layers(tmp_path: Path, server: viser.ViserServer) -> None:
    from tests.webui.fixtures import build_session

    app = ViewerApp(server, build_session(tmp_path, n_frames=6), role="coach", max_image_width=160)
    try:
        assert app.layer_states() == {name: "" for name in LAYERS}
        app.mark_stale("triangulate", None)  # an edit that queued no re-run
        assert app.layers.visible and "no re-run queued" in app.layers.content
        assert "**2D labels**: ✓" in app.layers.content
    finally:
        app.close()
