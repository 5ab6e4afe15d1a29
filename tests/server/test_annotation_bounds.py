"""Edits that point outside the bout (frames, persons, cameras) are refused with the reason."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from pipeline.schema.annotation_checks import AnnotationBounds, check_annotation
from pipeline.schema.annotations import LabelContact, MarkInvalid, SwapIdentities
from server.core.config import Settings
from tests.server.conftest import auth, make_bout, run_jobs

BOUNDS = AnnotationBounds(n_frames=60, person_ids=(0, 1), cameras=("cam0", "cam1"))


@pytest.mark.parametrize(
    ("edit", "reason"),
    [
        (SwapIdentities(frame=60, person_a=0, person_b=1), r"frame 60 is outside the bout \(frames \[0, 59\]\)"),
        (SwapIdentities(frame=-1, person_a=0, person_b=1), "frame -1 is outside the bout"),
        (SwapIdentities(frame=5, person_a=0, person_b=7), r"person_b 7 is not a person of this session \(known persons \[0, 1\]\)"),
        (SwapIdentities(frame=5, person_a=1, person_b=1), "a swap needs two persons"),
        (SwapIdentities(frame=5, person_a=0, person_b=1, view="cam9"), "view 'cam9' is not a camera"),
        (SwapIdentities(frame="5", person_a=0, person_b=1), "frame must be an integer"),  # type: ignore[arg-type]
        (LabelContact(10, 5, 0, "left_hand", 1, "head"), "frame_start 10 is after frame_end 5"),
        (MarkInvalid(view="cam0", frame=99, track=0), "frame 99 is outside"),
    ],
)
def test_check_annotation_names_the_reason(edit: object, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        check_annotation(edit, BOUNDS)  # type: ignore[arg-type]


def test_unknown_bounds_check_only_what_is_known() -> None:
    check_annotation(SwapIdentities(frame=10_000, person_a=0, person_b=5), AnnotationBounds())
    with pytest.raises(ValueError, match="frame -3 is outside the bout"):
        check_annotation(SwapIdentities(frame=-3, person_a=0, person_b=1), AnnotationBounds())
    check_annotation(SwapIdentities(frame=59, person_a=1, person_b=0, view="cam1"), BOUNDS)


def test_api_refuses_a_swap_outside_the_bout_with_422(client: TestClient, tokens: dict, bout_folder: Path,
                                                      settings: Settings) -> None:
    admin, ann = auth(tokens["admin"]), auth(tokens["annotator"])
    sid = make_bout(client, tokens["admin"], bout_folder)["id"]
    url = f"/api/sessions/{sid}/annotations"

    def post(edit: dict) -> tuple[int, str]:
        r = client.post(url, json={"annotation": edit, "rerun": False}, headers=ann)
        return r.status_code, r.text

    swap = {"kind": "swap_identities", "person_a": 0, "person_b": 1}
    # before any run: the frame count comes from the input tracks (60 frames), persons are unknown
    code, text = post({**swap, "frame": 60})
    assert code == 422 and "frame 60 is outside the bout (frames [0, 59])" in text
    client.post("/api/jobs", json={"session_id": sid}, headers=admin)
    run_jobs(settings)
    code, text = post({**swap, "frame": -1})
    assert code == 422 and "frame -1 is outside the bout" in text
    code, text = post({**swap, "frame": 10, "person_b": 5})
    assert code == 422 and "person_b 5 is not a person of this session (known persons [0, 1])" in text
    code, text = post({**swap, "frame": 10, "view": "nope"})
    assert code == 422 and "view 'nope' is not a camera" in text
    folder = Path(client.get(f"/api/sessions/{sid}", headers=admin).json()["folder"])
    assert not (folder / "annotations.json").exists() or json.loads((folder / "annotations.json").read_text()) == []
    code, text = post({**swap, "frame": 59, "view": "cam1"})
    assert code == 201, text
    a_id = json.loads(text)["annotation"]["id"]
    r = client.put(f"/api/annotations/{a_id}", json={"annotation": {**swap, "frame": 600}, "rerun": False}, headers=ann)
    assert r.status_code == 422 and "frame 600 is outside the bout" in r.text
    assert json.loads((folder / "annotations.json").read_text()) == [{**swap, "frame": 59, "view": "cam1"}]
