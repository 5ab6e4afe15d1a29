"""The Edit tab's range swap and edit history, in-process against the real API (the edits'
re-runs are queued but not run: the edits and their history are what is checked)."""

from __future__ import annotations

import pytest
import viser

from tests.webui.conftest import ApiEnv, api_client
from webui.app import ViewerApp
from webui.panels.annotate import parse_entry_label


def test_range_swap_and_undo_of_an_older_entry(api_env: ApiEnv, server: viser.ViserServer) -> None:
    pytest.importorskip("pipeline.runner.steps.associate")
    from server.jobs.worker import Worker

    api = api_client(api_env, "annotator")
    sid = api_env.session_id
    api.start_job(sid)
    Worker(api_env.settings).run_until_idle(timeout_s=120)  # 12 frames to move through
    app = ViewerApp(server, api_env.session_dir, api=api, session_id=sid, role="annotator", max_image_width=160)
    try:
        a = app.annotate
        assert a is not None and "No edits yet" in a.history.content
        app.timeline.frame.value = 7
        a.swap_until.value = 4
        a.swap.value = True
        assert "Edit refused: swap until frame 4 must come after the current frame 7" in a.status.content
        assert api.annotations(sid) == []
        app.timeline.frame.value = 9
        a.until_here.value = True
        assert a.swap_until.value == 9
        app.timeline.frame.value = 3
        a.swap_scope.value = "all views"
        a.swap.value = True  # frames 3..8
        a.swap_until.value = 0
        app.timeline.frame.value = 5
        a.swap.value = True  # from 5 to the end
        first, second = api.annotations(sid)
        assert first["payload"] == {"kind": "swap_identities", "frame": 3, "frame_end": 9, "person_a": 0, "person_b": 1, "view": ""}
        assert "frame_end" not in second["payload"] and second["payload"]["frame"] == 5
        lines = [ln for ln in a.history.content.splitlines() if ln.startswith("- #")]
        assert [ln.split()[1] for ln in lines] == [f"#{second['id']}", f"#{first['id']}"]  # newest first
        assert all("annotator1" in ln for ln in lines)
        assert sorted(parse_entry_label(o) for o in a.entry.options) == [first["id"], second["id"]]
        # undo the older one from the list (not the last edit)
        a.entry.value = next(o for o in a.entry.options if parse_entry_label(o) == first["id"])
        a.goto_entry.value = True
        assert app.frame == 3
        a.undo_entry.value = True
        assert f"Undo of annotation {first['id']}" in a.status.content
        assert [x["id"] for x in api.annotations(sid)] == [second["id"]]
        states = {e["id"]: e["state"] for e in api.history(sid)}
        assert states[first["id"]] == "undone" and states[second["id"]] == "active"
        assert [parse_entry_label(o) for o in a.entry.options] == [second["id"]]
        assert "*(undone)*" in next(ln for ln in a.history.content.splitlines() if ln.startswith(f"- #{first['id']} "))
    finally:
        app.close()
