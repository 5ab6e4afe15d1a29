"""``GET /sessions/{id}/report``: the bout report page for any signed-in user, 401 without a
valid token, 404 ("run the analyze stage") before the analyze stage, 404 for an unknown session."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from pipeline.stages.analyze import summarize
from tests.report.fixtures import write_analysed_bout
from tests.report.helpers import number, parse, svgs
from tests.server.conftest import auth, make_bout


def test_report_page(client: TestClient, tokens: dict, bout_folder: Path) -> None:
    bout = make_bout(client, tokens["admin"], bout_folder)
    sid, folder = bout["id"], Path(bout["folder"])
    url = f"/sessions/{sid}/report"
    assert client.get(url).status_code == 401
    assert client.get(url, headers=auth("not-a-token")).status_code == 401
    r = client.get(url, headers=auth(tokens["coach"]))
    assert (
        r.status_code == 404
        and "run the analyze stage" in r.text
        and r.headers["content-type"].startswith("text/html")
    )
    out = write_analysed_bout(folder, write_session=False)  # the server's bout keeps its session.json
    for role in ("coach", "annotator", "admin"):
        r = client.get(url, headers=auth(tokens[role]))
        assert r.status_code == 200, (role, r.text[:300])
        assert r.headers["content-type"].startswith("text/html")
    root = parse(r.text)
    names = {
        i["person_id"]: i["name"]
        for i in client.get(f"/api/sessions/{sid}/identities", headers=auth(tokens["coach"])).json()
    }
    summary = summarize(out.events, out.series, names)
    for a in summary["athletes"]:
        cell = root.find_all("td", data_key="punches", data_athlete=str(a["person_id"]), data_period="bout")[
            0
        ]
        assert number(cell.text) == a["punches"] and a["name"] in r.text
    assert len(svgs(r.text)) == 9
    r = client.get(url, params={"period_s": 3, "bin_s": 2}, headers=auth(tokens["coach"]))
    assert r.status_code == 200 and "split into 3 s periods" in r.text and 'data-t1="12"' in r.text
    assert client.get(url, params={"period_s": 0}, headers=auth(tokens["coach"])).status_code == 422
    assert client.get("/sessions/999/report", headers=auth(tokens["coach"])).status_code == 404
