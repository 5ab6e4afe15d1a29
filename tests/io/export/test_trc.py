"""The ``trc`` export, read back by a parser written here from the TRC layout OpenSim reads
(``TRCFileAdapter``: 8 header keys, marker and X1/Y1/Z1 label rows, tab-separated rows of
3 * markers + 2 cells, empty cells = no value), and compared with the source keypoints."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.io.export import ExportSelection, export_files
from pipeline.io.export.trc import keypoints3d_to_trc
from tests.io.export.export_session import FIRST_FRAME, FPS, INVALID, write_export_session

KEYS = [
    "DataRate",
    "CameraRate",
    "NumFrames",
    "NumMarkers",
    "Units",
    "OrigDataRate",
    "OrigDataStartFrame",
    "OrigNumFrames",
]


def _cells(line: str) -> list[str]:
    """Tab-separated cells; as OpenSim, a trailing tab does not open another cell."""
    cells = line.rstrip("\r\n").split("\t")
    return cells[:-1] if cells and cells[-1] == "" else cells


def parse_trc(text: str) -> dict:
    lines = text.split("\n")
    assert lines[0].split("\t")[:3] == ["PathFileType", "4", "(X/Y/Z)"]
    keys = [c for c in _cells(lines[1]) if c]
    values = [c for c in _cells(lines[2]) if c]
    assert keys == KEYS and len(values) == len(KEYS)
    meta = dict(zip(keys, values, strict=True))
    n_markers, n_frames = int(meta["NumMarkers"]), int(meta["NumFrames"])
    labels = [c for c in _cells(lines[3]) if c]
    assert labels[:2] == ["Frame#", "Time"] and len(labels) == n_markers + 2
    xyz_labels = [c for c in _cells(lines[4]) if c]
    assert xyz_labels == [f"{a}{i}" for i in range(1, n_markers + 1) for a in "XYZ"]
    rows = [_cells(ln) for ln in lines[5:] if ln.strip()]
    assert len(rows) == n_frames and all(len(r) == 3 * n_markers + 2 for r in rows)
    xyz = np.array([[float(c) if c else np.nan for c in r[2:]] for r in rows]).reshape(n_frames, n_markers, 3)
    return {
        "meta": meta,
        "markers": labels[2:],
        "frame": np.array([int(r[0]) for r in rows]),
        "time_s": np.array([float(r[1]) for r in rows]),
        "xyz": xyz,
    }


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_export_session(tmp_path_factory.mktemp("trc") / "s", physics=False)


def test_trc_reads_back_within_a_tenth_of_a_millimetre(session: Path) -> None:
    sel = ExportSelection(session, names={0: "Red", 1: "Blue"})
    kp, _ = sel.keypoints()
    files = export_files(sel, "trc")
    assert list(files) == ["keypoints3d_fit.trc"]
    trc = parse_trc(files["keypoints3d_fit.trc"].decode())
    assert (
        trc["meta"]["Units"] == "m"
        and float(trc["meta"]["DataRate"]) == float(trc["meta"]["CameraRate"]) == FPS
    )
    assert int(trc["meta"]["OrigDataStartFrame"]) == FIRST_FRAME + 1
    assert trc["markers"] == [f"{who}_{j}" for who in ("Red", "Blue") for j in kp.joint_names]
    np.testing.assert_array_equal(trc["frame"], kp.frame_indices + 1)
    np.testing.assert_allclose(trc["time_s"], kp.frame_indices / FPS, atol=1e-6)
    # y-up: Y is the world's z (height), Z is -y.
    ours = kp.xyz_m.reshape(kp.n_frames, -1, 3)
    back = np.stack([trc["xyz"][..., 0], -trc["xyz"][..., 2], trc["xyz"][..., 1]], axis=-1)
    valid = kp.valid.reshape(kp.n_frames, -1)
    assert np.abs(back[valid] - ours[valid]).max() <= 1e-4
    assert np.isnan(back[~valid]).all() and (~valid).sum() == len(INVALID)
    assert trc["xyz"][..., 1][valid].min() > -0.01  # the feet are on the floor: heights >= 0


def test_trc_in_millimetres_z_up_for_one_athlete(session: Path) -> None:
    sel = ExportSelection(
        session, athletes=(1,), frames=(FIRST_FRAME + 3, FIRST_FRAME + 6), names={1: "Blue"}
    )
    kp, _ = sel.keypoints()
    trc = parse_trc(keypoints3d_to_trc(kp, {1: "Blue"}, units="mm", up="z"))
    assert trc["meta"]["Units"] == "mm" and trc["meta"]["NumFrames"] == "3"
    assert trc["markers"] == list(kp.joint_names)  # one athlete: no name prefix
    valid = kp.valid[:, 0]
    assert np.abs(trc["xyz"][valid] / 1000.0 - kp.xyz_m[:, 0][valid]).max() <= 1e-4
    assert np.isnan(trc["xyz"][0, 0]).all() and not valid[0, 0]  # Blue's nose at frame row 3
    with pytest.raises(ValueError, match="units"):
        keypoints3d_to_trc(kp, {}, units="cm")  # type: ignore[arg-type]
