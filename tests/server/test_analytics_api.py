"""REST: ``GET /api/sessions/{id}/events`` and ``/summary`` from the analyze stage's artifacts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient

from pipeline.artifacts import ArtifactStore, Manifest
from pipeline.schema.analytics import AthleteSeries, BoutEvents
from tests.server.conftest import auth, make_bout


def _artifacts(folder: Path) -> None:
    ev = BoutEvents.empty(50.0, np.array([0, 1]))
    ev = BoutEvents(**{
        **ev.__dict__, "punch_person": np.array([0, 1, 0]), "punch_hand": np.array(["left", "right", "right"]),
        "punch_type": np.array(["jab", "cross", "rear_hook"]), "punch_start_frame": np.array([5, 20, 40]),
        "punch_peak_frame": np.array([10, 25, 46]), "punch_end_frame": np.array([18, 33, 55]),
        "punch_peak_speed_mps": np.array([7.5, 8.0, 6.5]), "punch_extension": np.array([0.95, 0.9, 0.7]),
        "punch_target": np.array(["head", "guard", "none"]), "punch_outcome": np.array(["landed", "blocked", "missed"]),
        "punch_confidence": np.array([0.9, 0.8, 0.7]),
        "evade_person": np.array([1]), "evade_kind": np.array(["slip"]), "evade_start_frame": np.array([38]),
        "evade_peak_frame": np.array([46]), "evade_end_frame": np.array([52]), "evade_displacement_m": np.array([0.2]),
        "evade_punch": np.array([2]), "clinch_start_frame": np.array([60]), "clinch_end_frame": np.array([79]),
    })  # fmt: skip
    f = 100
    series = AthleteSeries(
        frame_indices=np.arange(f), fps=50.0, person_ids=np.array([0, 1]), valid=np.ones((f, 2), bool),
        distance_m=np.full(f, 1.2), distance_valid=np.ones(f, bool), stance=np.ones((f, 2), np.int64),
        stance_width_m=np.full((f, 2), 0.5), guard_height_m=np.zeros((f, 2, 2)), punches_per_min=np.zeros((f, 2)),
    )  # fmt: skip
    m = Manifest(stage="analyze", code_version="test", config={}, config_hash="0", inputs={}, metrics={"source": "fit"})
    ArtifactStore(folder).write(m, {"events": ev, "series": series})


def test_events_and_summary(client: TestClient, tokens: dict, bout_folder: Path) -> None:
    bout = make_bout(client, tokens["admin"], bout_folder)
    sid, folder = bout["id"], Path(bout["folder"])
    coach = auth(tokens["coach"])
    r = client.get(f"/api/sessions/{sid}/events", headers=coach)
    assert r.status_code == 404 and "analyze stage has not run" in r.json()["detail"]
    assert client.get(f"/api/sessions/{sid}/summary").status_code == 401
    _artifacts(folder)
    r = client.get(f"/api/sessions/{sid}/events", headers=coach)
    assert r.status_code == 200, r.text
    doc = r.json()
    assert doc["format"] == "cornerman.events/v1" and doc["source"] == "fit"
    assert [p["type"] for p in doc["punches"]] == ["jab", "cross", "rear_hook"]
    assert doc["punches"][0]["peak_s"] == 0.2 and doc["evades"][0]["punch"] == 2 and doc["clinches"][0]["end_frame"] == 79
    r = client.get(f"/api/sessions/{sid}/events", params={"format": "csv"}, headers=coach)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    lines = r.text.strip().splitlines()
    assert lines[0].startswith("event,athlete_id") and len(lines) == 1 + 3 + 1 + 1
    r = client.get(f"/api/sessions/{sid}/summary", headers=coach)
    assert r.status_code == 200, r.text
    s = r.json()
    red = s["athletes"][0]
    assert red["punches"] == 2 and red["punches_landed"] == 1 and red["landed_pct"] == 50.0
    assert red["types"]["rear_hook"] == 1 and s["athletes"][1]["slips"] == 1 and s["clinches"] == 1
    assert client.get("/api/sessions/999/summary", headers=coach).status_code == 404
