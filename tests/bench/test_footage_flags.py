"""bench footage: the share of frames the evaluate stage flagged, one column per kind of
``FLAG_KINDS``, from a current problems.npz and from one written before the physics kinds."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from pipeline.artifacts import ArtifactStore, Manifest
from pipeline.bench.footage import _session_row
from pipeline.stages.evaluate import FLAG_KINDS, ProblemFlags


def _store(tmp_path: Path, arrays: dict[str, np.ndarray]) -> ArtifactStore:
    store = ArtifactStore(tmp_path)
    store.write(
        Manifest(stage="evaluate", code_version="t", config={}, config_hash="0", inputs={}),
        {"problems": arrays},
    )
    return store


def test_flag_shares_per_kind(tmp_path: Path) -> None:
    F = 20
    flags = np.zeros((F, len(FLAG_KINDS)), bool)
    keys = [k.key for k in FLAG_KINDS]
    flags[:5, keys.index("residual_high")] = True  # 25 %
    flags[3:7, keys.index("torque_high")] = True  # 20 %, overlapping: any = 7 frames
    flags[6:9, keys.index("reprojection_high")] = True  # 15 %: tracking = 3 frames, any = 9
    z = np.zeros(F)
    pf = ProblemFlags(np.arange(F), np.ones(F), z, z, z, flags, np.array(keys), z, z)
    row = _session_row(_store(tmp_path, pf.to_arrays()), [], tmp_path)
    assert row["flag_frames"] == F
    assert row["flag_residual_high_pct"] == pytest.approx(25.0)
    assert row["flag_torque_high_pct"] == pytest.approx(20.0)
    assert row["flag_identity_low_pct"] == 0.0
    assert row["flag_any_pct"] == pytest.approx(45.0)
    assert row["flag_tracking_pct"] == pytest.approx(15.0)  # the physics kinds are not tracking problems
    assert {f"flag_{k}_pct" for k in keys} <= set(row)


def test_older_problems_have_no_share_for_the_new_kinds(tmp_path: Path) -> None:
    F = 4
    flags = np.array([[1, 0, 0], [0, 0, 0], [0, 1, 0], [0, 0, 0]], bool)
    z = np.zeros(F)
    old = {
        "frame_indices": np.arange(F),
        "identity_conf_min": np.ones(F),
        "reproj_err_px": z,
        "penetration_mm": z,
        "flags": flags,
    }
    row = _session_row(_store(tmp_path, old), [], tmp_path)
    assert row["flag_identity_low_pct"] == 25.0 and row["flag_any_pct"] == 50.0 and row["flag_tracking_pct"] == 50.0
    assert math.isnan(row["flag_residual_high_pct"]) and math.isnan(row["flag_torque_high_pct"])
    bad = {**old, "flags": np.zeros((F, 2), bool)}
    with pytest.raises(ValueError, match="not the evaluate stage's problem flags"):
        _session_row(_store(tmp_path, bad), [], tmp_path)
