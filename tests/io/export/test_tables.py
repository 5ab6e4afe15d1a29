"""The ``csv`` export: read back with the csv module and numpy, compared with the source keypoints."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import pytest

from pipeline.io.export import ExportSelection, export_files
from pipeline.io.export.tables import CSV_COLUMNS
from tests.io.export.export_session import FIRST_FRAME, FPS, INVALID, write_export_session


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_export_session(tmp_path_factory.mktemp("csv") / "s", physics=False)


def _read(session: Path, **kw: object) -> tuple[list[dict[str, str]], ExportSelection, str]:
    sel = ExportSelection(session, names={0: "Red", 1: "Blue"}, **kw)  # type: ignore[arg-type]
    files = export_files(sel, "csv")
    assert list(files) == ["keypoints3d_fit.csv"]
    text = files["keypoints3d_fit.csv"].decode()
    assert text.splitlines()[0] == ",".join(CSV_COLUMNS)  # the header is the first row, no comments
    return list(csv.DictReader(io.StringIO(text))), sel, text


def test_csv_rows_match_the_keypoints(session: Path) -> None:
    rows, sel, text = _read(session)
    kp, _ = sel.keypoints()
    assert len(rows) == kp.n_frames * kp.n_persons * len(kp.joint_names)
    for r in rows[:: max(1, len(rows) // 97)] + rows[-3:]:
        f, p = int(r["frame"]) - FIRST_FRAME, int(r["athlete_id"])
        j = kp.joint_names.index(r["joint"])
        assert r["athlete_name"] == ("Red", "Blue")[p]
        assert float(r["time_s"]) == pytest.approx(int(r["frame"]) / FPS, abs=1e-6)
        assert float(r["confidence"]) == pytest.approx(kp.confidence[f, p, j], abs=5e-4)
    # The whole table through numpy: positions to the micrometre, invalid joints empty.
    table = np.genfromtxt(io.StringIO(text), delimiter=",", dtype=None, encoding=None, names=True)
    at = (
        table["frame"] - FIRST_FRAME,
        table["athlete_id"],
        np.array([kp.joint_names.index(n) for n in table["joint"]]),
    )
    xyz = np.stack([table["x_m"], table["y_m"], table["z_m"]], axis=1)
    valid = table["valid"].astype(bool)
    np.testing.assert_array_equal(valid, kp.valid[at])
    assert np.abs(xyz[valid] - kp.xyz_m[at][valid]).max() <= 0.5e-6
    assert np.isnan(xyz[~valid]).all() and (~valid).sum() == len(INVALID)


def test_csv_frames_and_athlete_restrict_the_rows(session: Path) -> None:
    rows, _, _ = _read(session, frames=(FIRST_FRAME + 2, FIRST_FRAME + 5), athletes=(1,))
    assert {int(r["frame"]) for r in rows} == {FIRST_FRAME + 2, FIRST_FRAME + 3, FIRST_FRAME + 4}
    assert {r["athlete_name"] for r in rows} == {"Blue"} and {r["athlete_id"] for r in rows} == {"1"}
    blank = [r for r in rows if r["valid"] == "0"]
    assert [(int(r["frame"]) - FIRST_FRAME, r["joint"]) for r in blank] == [(3, "nose")]
    assert blank[0]["x_m"] == blank[0]["y_m"] == blank[0]["z_m"] == "" and blank[0]["confidence"] == "0.000"
    with pytest.raises(ValueError, match="no frame"):
        _read(session, frames=(0, 10))
