"""Dataset releases: export a small session run through fit and analyze, validate it, and check that
corrupt files, schema violations, broken cross-references and bad ``--out`` folders are caught."""

from __future__ import annotations

import hashlib
import io
import json
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from jsonschema import Draft202012Validator
from typer.testing import CliRunner

from pipeline.artifacts import ArtifactStore
from pipeline.cli.main import app
from pipeline.dataset import AnnotationRecord, Problem, export_release, validate_release, write_checksums
from pipeline.runner import run
from pipeline.schema import Association, BodyFit, Keypoints3D, Tracks2D, load_npz
from tests.conftest import write_tiny_session

runner = CliRunner()
STAGES = ("detect2d", "track", "associate", "calibrate", "triangulate", "fit", "analyze")
N_FRAMES = 12
EDITS = [
    {"kind": "swap_identities", "frame": 6, "person_a": 0, "person_b": 1, "view": "cam2"},
    {"kind": "label_contact", "frame_start": 2, "frame_end": 4, "person_a": 0, "part_a": "right_wrist",
     "person_b": 1, "part_b": "head"},
]  # fmt: skip


@pytest.fixture(scope="module", autouse=True)
def no_server_home(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """The default server home is an empty folder: no test reads a real server database."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("CORNERMAN_HOME", str(tmp_path_factory.mktemp("empty_home")))
        yield


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 3-camera, 12-frame tracks session with two edits, run through fit (few iterations) and analyze."""
    s = write_tiny_session(tmp_path_factory.mktemp("bout") / "tiny", stages=STAGES, n_frames=N_FRAMES)
    cfg = json.loads((s / "session.json").read_text())
    cfg["stage_config"] = {"fit": {"shape_iters": 10, "pose_iters_3d": 5, "pose_iters": 10}}
    (s / "session.json").write_text(json.dumps(cfg))
    (s / "annotations.json").write_text(json.dumps(EDITS))
    assert [r.action for r in run(s)] == ["ran"] * len(STAGES)
    return s


@pytest.fixture(scope="module")
def release(session: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("rel") / "release"
    r = runner.invoke(app, ["dataset", "export", str(session), "--out", str(out), "--licence", "CC BY 4.0"])
    assert r.exit_code == 0, r.output
    return out


def _copy(release: Path, tmp_path: Path) -> Path:
    dest = tmp_path / "copy"
    shutil.copytree(release, dest)
    return dest


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)  # type: ignore[arg-type]
    path.write_bytes(buf.getvalue())


def test_export_writes_the_documented_layout_and_validates(session: Path, release: Path) -> None:
    store = ArtifactStore(session)
    rel = json.loads((release / "release.json").read_text())
    assert rel["format"] == "cornerman.dataset/v1" and [s["id"] for s in rel["sessions"]] == ["tiny"]
    d = release / "sessions" / "tiny"
    meta = json.loads((d / "meta.json").read_text())
    assert meta["n_frames"] == N_FRAMES and meta["cameras"] == ["cam1", "cam2", "cam3"]
    assert [s["stage"] for s in meta["stages"]] == list(STAGES) and {s["status"] for s in meta["stages"]} == {
        "fresh"
    }
    assert meta["stages"][5]["code_version"] == store.manifest("fit").code_version  # type: ignore[union-attr]
    kinds = sorted(f["path"] for f in meta["files"])
    assert kinds == sorted([
        "calibration.toml", "calibration.json", "videos.json", "tracks2d/cam1.npz", "tracks2d/cam2.npz",
        "tracks2d/cam3.npz", "keypoints3d/raw.npz", "keypoints3d/filtered.npz", "keypoints3d/fit.npz",
        "body/bodyfit.npz", "events.json", "annotations.json",
    ])  # fmt: skip
    # 2D tracks carry the association's final identities (after the swap edit).
    tracks = store.load("track", "tracks", Tracks2D)
    assoc = store.load("associate", "association", Association)
    with np.load(d / "tracks2d" / "cam2.npz", allow_pickle=False) as z:
        rows = np.flatnonzero(tracks.view == 1)
        order = np.lexsort((tracks.track_id[rows], tracks.frame[rows]))
        assert np.array_equal(z["person_id"], assoc.person_of_det[rows][order])
        assert np.array_equal(z["keypoints_px"], tracks.keypoints_px[rows][order])
    # Body parameters and 3D keypoints read back as the schema types, equal to the artifacts.
    fit = load_npz(d / "body" / "bodyfit.npz", BodyFit)
    assert (
        np.array_equal(fit.pose, store.load("fit", "bodyfit", BodyFit).pose) and fit.pose.shape[0] == N_FRAMES
    )
    raw = load_npz(d / "keypoints3d" / "raw.npz", Keypoints3D)
    assert raw.source == "raw" and np.array_equal(
        raw.xyz_m, store.load("triangulate", "raw", Keypoints3D).xyz_m
    )
    # Track sessions have no videos: said so, and the 2D input is hashed.
    videos = json.loads((d / "videos.json").read_text())
    assert videos["videos"] == [] and "no videos" in videos["note"]
    assert (
        videos["inputs"][0]["sha256"]
        == hashlib.sha256((session / "inputs" / "tracks2d.npz").read_bytes()).hexdigest()
    )
    # Annotations without a server: the edits in force, authors unknown.
    ann = json.loads((d / "annotations.json").read_text())
    assert [a["edit"] for a in ann["annotations"]] == EDITS and {a["author"] for a in ann["annotations"]} == {
        None
    }
    sheet = (release / "datasheet.md").read_text()
    assert "CC BY 4.0" in sheet and "| tiny | tiny | tracks | 3 | 50 | 12 | 0.2 |" in sheet
    assert "| swap_identities | unknown | 1 |" in sheet and "| human edits in force | 2 |" in sheet
    # checksums.sha256 covers every other file, in sha256sum format.
    lines = (release / "checksums.sha256").read_text().splitlines()
    files = sorted(p.relative_to(release).as_posix() for p in release.rglob("*") if p.is_file())
    assert sorted(line.split("  ", 1)[1] for line in lines) == [f for f in files if f != "checksums.sha256"]
    for line in lines:
        digest, name = line.split("  ", 1)
        assert hashlib.sha256((release / name).read_bytes()).hexdigest() == digest
    r = runner.invoke(app, ["dataset", "validate", str(release)])
    assert r.exit_code == 0 and "valid" in r.output, r.output


def test_schemas_are_draft_2020_12_and_shipped(release: Path) -> None:
    schemas = sorted((release / "schemas").glob("*.schema.json"))
    assert [p.name for p in schemas] == [f"{k}.schema.json" for k in sorted(
        ["release", "meta", "calibration", "videos", "events", "annotations"])]  # fmt: skip
    for p in schemas:
        doc = json.loads(p.read_text())
        assert doc["$schema"] == "https://json-schema.org/draft/2020-12/schema"
        Draft202012Validator.check_schema(doc)
    layouts = json.loads((release / "schemas" / "npz_layouts.json").read_text())
    assert layouts["bodyfit"]["pose"]["shape"] == ["frames", "persons", "bones", 3]


def test_a_corrupt_file_is_named(release: Path, tmp_path: Path) -> None:
    rel = _copy(release, tmp_path)
    f = rel / "sessions" / "tiny" / "keypoints3d" / "fit.npz"
    data = bytearray(f.read_bytes())
    data[len(data) // 2] ^= 0xFF
    f.write_bytes(bytes(data))
    r = runner.invoke(app, ["dataset", "validate", str(rel)])
    assert r.exit_code == 2, r.output
    assert "sessions/tiny/keypoints3d/fit.npz: sha256 differs from checksums.sha256" in r.output


def test_a_schema_violation_names_the_field(release: Path, tmp_path: Path) -> None:
    rel = _copy(release, tmp_path)
    cal = rel / "sessions" / "tiny" / "calibration.json"
    doc = json.loads(cal.read_text())
    doc["cameras"][1]["K"] = [[1100.0, 0.0], [0.0, 1100.0, 360.0], [0.0, 0.0, 1.0]]
    cal.write_text(json.dumps(doc))
    ann = rel / "sessions" / "tiny" / "annotations.json"
    doc = json.loads(ann.read_text())
    del doc["annotations"][0]["edit"]["frame"]
    ann.write_text(json.dumps(doc))
    write_checksums(rel)  # only the schemas can catch these now
    problems = validate_release(rel).problems
    assert problems == (
        Problem("sessions/tiny/annotations.json", "field annotations/0/edit: 'frame' is a required property"),
        Problem("sessions/tiny/calibration.json", "field cameras/1/K/0: [1100.0, 0.0] is too short"),
    )
    r = runner.invoke(app, ["dataset", "validate", str(rel)])
    assert r.exit_code == 2 and "field cameras/1/K/0" in r.output


def test_malformed_documents_are_reported_not_raised(release: Path, tmp_path: Path) -> None:
    rel = _copy(release, tmp_path)
    d = rel / "sessions" / "tiny"
    for path, edit in (
        (d / "meta.json", lambda doc: doc.update(files=[1, 2])),
        (d / "events.json", lambda doc: doc.update(clinches=[{"start_frame": 0, "end_frame": "late"}])),
        (rel / "release.json", lambda doc: doc["sessions"][0].update(n_frames="12")),
    ):
        doc = json.loads(path.read_text())
        edit(doc)
        path.write_text(json.dumps(doc))
    write_checksums(rel)
    assert set(validate_release(rel).problems) == {
        Problem("release.json", "field sessions/0/n_frames: '12' is not of type 'integer'"),
        Problem("sessions/tiny/meta.json", "field files/0: 1 is not of type 'object'"),
        Problem("sessions/tiny/meta.json", "field files/1: 2 is not of type 'object'"),
        Problem("sessions/tiny/events.json", "field clinches/0/end_frame: 'late' is not of type 'integer'"),
        Problem("sessions/tiny/events.json", "field clinches/0: 'start_s' is a required property"),
        Problem("sessions/tiny/events.json", "field clinches/0: 'end_s' is a required property"),
    }
    (rel / "release.json").write_text(json.dumps({"format": "cornerman.dataset/v9"}))
    write_checksums(rel)
    assert validate_release(rel).problems[-1] == Problem(
        "release.json", "format 'cornerman.dataset/v9': this cornerman reads cornerman.dataset/v1"
    )


def test_layout_and_cross_reference_errors(release: Path, tmp_path: Path) -> None:
    rel = _copy(release, tmp_path)
    d = rel / "sessions" / "tiny"
    with np.load(d / "keypoints3d" / "raw.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    short = {k: (v[:-1] if v.ndim and v.shape[0] == N_FRAMES else v) for k, v in arrays.items()}
    _save_npz(d / "keypoints3d" / "raw.npz", short)  # consistent in itself, one frame short of meta.json
    with np.load(d / "tracks2d" / "cam1.npz", allow_pickle=False) as z:
        tr = {k: z[k] for k in z.files if k != "person_id"}
    _save_npz(d / "tracks2d" / "cam1.npz", {**tr, "frame": tr["frame"].astype(np.float32)})
    shutil.copy(d / "events.json", d / "extra.json")
    write_checksums(rel)
    problems = set(validate_release(rel).problems)
    assert problems == {
        Problem("sessions/tiny/keypoints3d/raw.npz", f"{N_FRAMES - 1} frames, meta.json says {N_FRAMES}"),
        Problem("sessions/tiny/tracks2d/cam1.npz", "array 'person_id' missing (tracks2d layout)"),
        Problem("sessions/tiny/tracks2d/cam1.npz", "array 'frame': dtype float32 (expected kind 'iu')"),
        Problem("sessions/tiny/extra.json", "not part of the cornerman.dataset/v1 layout"),
        Problem("sessions/tiny/extra.json", "not listed in meta.json's files"),
    }
    shutil.rmtree(d)
    write_checksums(rel)
    assert validate_release(rel).problems == (Problem("sessions/tiny", "listed in release.json but missing"),)


def test_bad_out_is_a_clear_error_and_leaves_nothing(session: Path, release: Path, tmp_path: Path) -> None:
    def export(out: Path, *extra: str) -> str:
        r = runner.invoke(app, ["dataset", "export", str(session), "--out", str(out), *extra])
        assert r.exit_code == 2, r.output
        return r.output

    a_file = tmp_path / "taken.txt"
    a_file.write_text("x")
    assert "is a file" in export(a_file) and a_file.read_text() == "x"
    assert "does not exist" in export(tmp_path / "nope" / "rel") and not (tmp_path / "nope").exists()
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    assert "not empty" in export(busy)
    assert "holds no release.json" in export(busy, "--force") and [p.name for p in busy.iterdir()] == [
        "notes.txt"
    ]
    # A session whose stages never ran fails after the first session was written: nothing is left.
    bare = write_tiny_session(tmp_path / "bare", stages=STAGES, n_frames=N_FRAMES)
    with pytest.raises(LookupError, match="the track stage has not run"):
        export_release([session, bare], tmp_path / "half")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bare", "busy", "taken.txt"]
    # --force replaces a previous release, which stays valid.
    prev = _copy(release, tmp_path)
    (prev / "stray.txt").write_text("old")
    r = runner.invoke(app, ["dataset", "export", str(session), "--out", str(prev), "--force"])
    assert r.exit_code == 0, r.output
    assert not (prev / "stray.txt").exists() and validate_release(prev).ok
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bare", "busy", "copy", "taken.txt"]


def test_stale_stages_are_refused_unless_allowed(session: Path, tmp_path: Path) -> None:
    s = tmp_path / "s"
    shutil.copytree(session, s)
    cfg = json.loads((s / "session.json").read_text())
    cfg["stage_config"]["analyze"] = {"punch": {"min_excursion_m": 0.3}}
    (s / "session.json").write_text(json.dumps(cfg))
    with pytest.raises(ValueError, match="stages analyze are stale"):
        export_release([s], tmp_path / "rel")
    export_release([s], tmp_path / "rel", allow_stale=True)
    meta = json.loads((tmp_path / "rel" / "sessions" / "s" / "meta.json").read_text())
    assert {x["stage"]: x["status"] for x in meta["stages"]}["analyze"] == "stale"
    assert "stale when released" in (tmp_path / "rel" / "datasheet.md").read_text()
    assert validate_release(tmp_path / "rel").ok


def test_annotation_authors_and_times_come_from_the_server(session: Path, tmp_path: Path) -> None:
    from sqlmodel import Session

    from server import crud
    from server.db import init_db, make_engine
    from server.models import Bout

    home = tmp_path / "home"
    engine = make_engine(home / "cornerman.db")
    init_db(engine)
    with Session(engine) as db:
        bout = crud.create_bout(db, bout=Bout(name="tiny", folder=str(session), athletes=["Red", "Blue"]))
        assert bout.id is not None
        first = crud.add_annotation(db, bout_id=bout.id, payload={**EDITS[0], "frame": 3}, author="ana")
        crud.add_annotation(db, bout_id=bout.id, payload=EDITS[0], author="ben", supersedes=first)
        crud.add_annotation(db, bout_id=bout.id, payload=EDITS[1], author="ana")
    out = tmp_path / "rel"
    r = runner.invoke(app, ["dataset", "export", str(session), "--out", str(out), "--server-home", str(home)])
    assert r.exit_code == 0, r.output
    rows = json.loads((out / "sessions" / "tiny" / "annotations.json").read_text())["annotations"]
    assert [(a["author"], a["active"], a["edit"].get("frame")) for a in rows] == [
        ("ana", False, 3),
        ("ben", True, 6),
        ("ana", True, None),
    ]
    assert all(a["created_utc"].endswith("Z") for a in rows) and rows[0]["superseded_by"] == rows[1]["id"]
    sheet = (out / "datasheet.md").read_text()
    assert "| swap_identities | ben | 1 |" in sheet and "| label_contact | ana | 1 |" in sheet
    assert validate_release(out).ok
    r = runner.invoke(
        app,
        ["dataset", "export", str(session), "--out", str(tmp_path / "r2"), "--server-home", str(tmp_path)],
    )
    assert r.exit_code == 2 and "no server database" in r.output
    # A history whose active edits are not the ones the stages used is refused.
    with pytest.raises(ValueError, match="differ from the 1 active edits of the server's history"):
        export_release([session], tmp_path / "r3", histories={session: [AnnotationRecord(edit=EDITS[1])]})
    assert not (tmp_path / "r3").exists()
    r = runner.invoke(app, ["dataset", "export", str(session), "--out", str(tmp_path / "r4"), "--no-server"])
    assert r.exit_code == 0, r.output
    rows = json.loads((tmp_path / "r4" / "sessions" / "tiny" / "annotations.json").read_text())["annotations"]
    assert [a["author"] for a in rows] == [None, None]
