"""``cornerman export`` with the csv, trc, c3d and mujoco formats: a multi-file format written as a
ZIP, ``--frames``, ``--athlete Red``, and bad ``--out`` paths that leave no stray file."""

from __future__ import annotations

import csv
import io
import zipfile
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from pipeline.cli.main import app
from tests.io.export.export_session import FIRST_FRAME, write_export_session

runner = CliRunner()


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_export_session(tmp_path_factory.mktemp("cli") / "s")


def test_mujoco_zip_with_a_frame_range(session: Path, tmp_path: Path) -> None:
    out = tmp_path / "phys.zip"
    r = runner.invoke(
        app,
        [
            "export",
            str(session),
            "-f",
            "mujoco",
            "--frames",
            f"{FIRST_FRAME + 1}:{FIRST_FRAME + 4}",
            "--out",
            str(out),
        ],
    )
    assert r.exit_code == 0, r.output
    assert "wrote" in r.output and "replay.py" in r.output
    with zipfile.ZipFile(out) as z:
        assert sorted(z.namelist()) == ["motion.npz", "replay.py", "scene.xml"]
        motion = np.load(io.BytesIO(z.read("motion.npz")))
    assert motion["frame_indices"].tolist() == [FIRST_FRAME + 1, FIRST_FRAME + 2, FIRST_FRAME + 3]
    assert motion["qpos"].shape[0] == 3
    # Without --out the ZIP goes into the session folder.
    r = runner.invoke(app, ["export", str(session), "--format", "mujoco"])
    assert r.exit_code == 0, r.output
    assert zipfile.ZipFile(session / "export_mujoco.zip").namelist()


def test_athlete_by_name_and_frames(session: Path, tmp_path: Path) -> None:
    out = tmp_path / "red.csv"
    r = runner.invoke(
        app,
        [
            "export",
            str(session),
            "-f",
            "csv",
            "--athlete",
            "Red",
            "--frames",
            f"{FIRST_FRAME + 6}:",
            "-o",
            str(out),
        ],
    )
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(out.open()))
    assert {r["athlete_name"] for r in rows} == {"Red"} and {int(r["frame"]) for r in rows} == {
        FIRST_FRAME + 6,
        FIRST_FRAME + 7,
    }
    out = tmp_path / "blue.trc"
    r = runner.invoke(app, ["export", str(session), "-f", "trc", "-a", "blue", "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert out.read_text().splitlines()[3].split("\t")[2] == "nose"  # one athlete: unprefixed markers
    r = runner.invoke(
        app, ["export", str(session), "-f", "c3d", "-a", "Green", "-o", str(tmp_path / "g.c3d")]
    )
    assert r.exit_code == 2 and "no athlete of that name" in r.output and not (tmp_path / "g.c3d").exists()
    r = runner.invoke(
        app, ["export", str(session), "-f", "mujoco", "-a", "Red", "-o", str(tmp_path / "m.zip")]
    )
    assert r.exit_code == 2 and "whole scene" in r.output and not (tmp_path / "m.zip").exists()


@pytest.mark.parametrize("fmt", ["csv", "trc", "c3d", "mujoco"])
def test_bad_out_leaves_no_stray_file(session: Path, tmp_path: Path, fmt: str) -> None:
    before = sorted(p.name for p in session.iterdir())
    for bad, why in ((tmp_path / "missing" / f"x.{fmt}", "does not exist"), (tmp_path, "is a folder")):
        r = runner.invoke(app, ["export", str(session), "--format", fmt, "--out", str(bad)])
        assert r.exit_code == 2 and why in r.output, r.output
    assert not (tmp_path / "missing").exists() and list(tmp_path.iterdir()) == []
    assert sorted(p.name for p in session.iterdir()) == before


def test_unknown_format_and_bad_frames(session: Path, tmp_path: Path) -> None:
    r = runner.invoke(app, ["export", str(session), "--format", "xlsx", "-o", str(tmp_path / "x")])
    assert r.exit_code == 2 and all(f in r.output for f in ("csv", "trc", "c3d", "mujoco"))
    r = runner.invoke(
        app, ["export", str(session), "--format", "trc", "--frames", "3", "-o", str(tmp_path / "x.trc")]
    )
    assert r.exit_code == 2 and "FIRST:STOP" in r.output
    assert list(tmp_path.iterdir()) == []


def test_several_files_need_a_zip_name(session: Path, tmp_path: Path) -> None:
    """The MuJoCo export is a scene and its meshes: named *.xml it would be a ZIP that no tool opens."""
    r = runner.invoke(app, ["export", str(session), "-f", "mujoco", "-o", str(tmp_path / "scene.xml")])
    assert r.exit_code == 2 and "give a name ending in .zip" in r.output and "files (" in r.output, r.output
    assert list(tmp_path.iterdir()) == []
    r = runner.invoke(app, ["export", str(session), "-f", "mujoco", "-o", str(tmp_path / "scene.ZIP")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "scene.ZIP").read_bytes()[:2] == b"PK"
