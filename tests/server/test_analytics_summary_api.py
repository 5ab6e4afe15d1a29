"""REST ``GET /api/sessions/{id}/summary``: the ring zones (from session.json's ring), blocks
and parries, and the fatigue indicators per round (from its round times) with their trends,
equal to the pipeline's summary; a malformed session.json answers 409."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from pipeline.stages.analyze import summarize
from pipeline.stages.analyze.zones import RING_ZONES
from tests.report.fixtures import write_analysed_bout
from tests.server.conftest import auth, make_bout

RING = [[-1.6, -1.6], [1.6, -1.6], [1.6, 1.6], [-1.6, 1.6]]
ROUNDS = [[0.0, 4.0], [4.0, 8.0], [8.0, 12.0]]


def test_summary_has_ring_zones_blocks_and_fatigue(
    client: TestClient, tokens: dict, bout_folder: Path
) -> None:
    bout = make_bout(client, tokens["admin"], bout_folder)
    sid, folder = bout["id"], Path(bout["folder"])
    out = write_analysed_bout(folder, write_session=False)  # the server's bout keeps its session.json
    coach = auth(tokens["coach"])
    r = client.get(f"/api/sessions/{sid}/summary", headers=coach)
    assert r.status_code == 200, r.text
    s = r.json()
    assert (
        not s["ring_known"] and s["period_kind"] == "periods" and len(s["periods"]) == 1
    )  # 12 s: one minute
    assert all(a[f"ring_{z}_pct"] is None for a in s["athletes"] for z in RING_ZONES)
    assert s["ring_zones"] == {"centre_scale": 0.5, "ropes_band_m": 0.9, "corner_radius_m": 1.5}
    d = json.loads((folder / "session.json").read_text())
    d.update(rounds_s=ROUNDS, ring_xy_m=RING)
    (folder / "session.json").write_text(json.dumps(d))
    s = client.get(f"/api/sessions/{sid}/summary", headers=coach).json()
    names = {a["person_id"]: a["name"] for a in s["athletes"]}
    want = summarize(
        out.events, out.series, names, ring_xy_m=RING, rounds_s=((0.0, 4.0), (4.0, 8.0), (8.0, 12.0))
    )
    assert s["ring_known"] and s["period_kind"] == "rounds" and [p["label"] for p in s["periods"]] == [
        "round 1", "round 2", "round 3",
    ]  # fmt: skip
    for got, exp in zip(s["athletes"], want["athletes"], strict=True):
        for key in ("blocks", "parries", *(f"ring_{z}_pct" for z in RING_ZONES)):
            assert got[key] == exp[key], key
        assert sum(got[f"ring_{z}_pct"] for z in RING_ZONES) == pytest.approx(100.0, abs=0.3)
        assert got["by_period"] == exp["by_period"] and got["fatigue"] == exp["fatigue"]
        assert got["fatigue"]["guard_height_median_m"]["trend"] in ("rising", "falling", "flat")
        assert got["fatigue"]["guard_height_median_m"]["unit"] == "m per min"
    assert sum(a["blocks"] for a in s["athletes"]) == int((out.events.evade_kind == "block").sum()) > 0
    ev = client.get(f"/api/sessions/{sid}/events", headers=coach).json()
    assert sorted({e["kind"] for e in ev["evades"]}) == sorted(set(out.events.evade_kind.tolist()))
    d["ring_xy_m"] = [[0, 0], [1, 1]]
    (folder / "session.json").write_text(json.dumps(d))
    r = client.get(f"/api/sessions/{sid}/summary", headers=coach)
    assert r.status_code == 409 and "ring_xy_m" in r.json()["detail"]
