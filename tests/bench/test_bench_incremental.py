"""``cornerman bench incremental`` on a tiny session: a swap through the annotation overlay,
the stale stages re-run, one row per re-run stage with its ratio computed from the manifests.

The session (``write_tiny_session``, 24 frames, three cameras, two keypoint humanoids) runs
every stage up to physics with a tiny fit and solver. No timing is asserted.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

pytest.importorskip("mujoco")
pytest.importorskip("torch")

from pipeline.artifacts import ArtifactStore  # noqa: E402
from pipeline.bench.incremental import run_bench  # noqa: E402
from pipeline.runner import run  # noqa: E402
from pipeline.schema import Association  # noqa: E402
from pipeline.schema.annotations import SwapIdentities, load_annotations  # noqa: E402
from tests.conftest import write_tiny_session  # noqa: E402

N_FRAMES, EDIT_FRAME = 24, 18
STAGES = ("detect2d", "track", "associate", "triangulate", "fit", "physics")
CONFIG = {
    "fit": {"pose_iters": 20, "pose_iters_3d": 10, "shape_iters": 10},
    "physics": {
        "skeleton": "keypoints",
        "solver": {"window": 5, "commit": 3, "ilqr": {"max_iter": 2, "n_alpha": 3}},
    },
}


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Path:
    s = write_tiny_session(tmp_path_factory.mktemp("bench") / "tiny", stages=STAGES, n_frames=N_FRAMES)
    d = json.loads((s / "session.json").read_text())
    d["stage_config"] = CONFIG
    (s / "session.json").write_text(json.dumps(d))
    run(s)
    return s


@pytest.fixture(scope="module")
def bench(source: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[list[dict], Path]:
    kept = tmp_path_factory.mktemp("kept") / "edited"
    rows = run_bench(session=str(source), frame=EDIT_FRAME, camera="cam2", keep=str(kept))
    return rows, kept


def test_the_table_has_a_row_per_rerun_stage_and_a_total(bench: tuple[list[dict], Path]) -> None:
    rows, _ = bench
    stages = [r["stage"] for r in rows]
    # the swap is an associate edit: associate and everything after it is stale
    assert stages == ["associate", "triangulate", "fit", "physics", "all re-run stages"]
    for r in rows:
        assert r["incremental_s"] > 0 and r["full_s"] > 0


def test_the_ratio_is_the_incremental_time_over_the_full_time_in_the_manifests(
    source: Path, bench: tuple[list[dict], Path]
) -> None:
    rows, kept = bench
    before, after = ArtifactStore(source), ArtifactStore(kept)
    for r in rows[:-1]:
        m_full, m_inc = before.manifest(r["stage"]), after.manifest(r["stage"])
        assert m_full is not None and m_inc is not None
        assert r["full_s"] == pytest.approx(m_full.duration_s, abs=0.006)
        assert r["incremental_s"] == pytest.approx(m_inc.duration_s, abs=0.006)
        assert r["ratio"] == pytest.approx(m_inc.duration_s / m_full.duration_s, rel=0.01)
        assert r["incremental"] == str(m_inc.metrics.get("incremental", ""))
    total = rows[-1]
    assert total["incremental_s"] == pytest.approx(sum(r["incremental_s"] for r in rows[:-1]))
    assert total["ratio"] == pytest.approx(total["incremental_s"] / total["full_s"], rel=0.01)


def test_the_physics_row_says_what_its_manifest_reused(bench: tuple[list[dict], Path]) -> None:
    rows, kept = bench
    (phys,) = [r for r in rows if r["stage"] == "physics"]
    m = ArtifactStore(kept).manifest("physics")
    assert m is not None
    assert phys["reused_frames"] == m.metrics["reused_frames"]
    assert phys["recomputed_from_frame"] == m.metrics["replanned_from_frame"]
    assert phys["first_changed_reference_frame"] == m.metrics["first_changed_reference_frame"]
    assert not math.isnan(phys["ratio"])


def test_the_source_is_left_alone_and_the_edit_goes_through_the_overlay(
    source: Path, bench: tuple[list[dict], Path]
) -> None:
    """By default the bench times a fix: the swap as a tracking error, then the same swap again,
    which undoes it; the association is the source's again."""
    rows, kept = bench
    assert not (source / "annotations.json").exists()
    assert rows[0]["edit"] == f"fix of an identity swap at frame {EDIT_FRAME} in cam2"
    edits = load_annotations(kept / "annotations.json")
    assert len(edits) == 2 and edits[0] == edits[1]
    assert isinstance(edits[0], SwapIdentities) and edits[0].frame == EDIT_FRAME and edits[0].view == "cam2"
    a = ArtifactStore(source).load("associate", "association", Association)
    b = ArtifactStore(kept).load("associate", "association", Association)
    assert (a.person_of_det == b.person_of_det).all()


def test_an_edit_outside_the_session_is_a_clear_error(source: Path) -> None:
    with pytest.raises(ValueError, match="frame=999"):
        run_bench(session=str(source), frame=999, camera="cam2")
    with pytest.raises(ValueError, match="camera='nope'"):
        run_bench(session=str(source), frame=EDIT_FRAME, camera="nope")
    with pytest.raises(ValueError, match="session=.*no session.json"):
        run_bench(session=str(source / "missing"))


def test_options_of_the_wrong_type_are_refused_before_any_work(source: Path) -> None:
    # ``--opt frame=abc`` reaches the bench as a string: refused by name, not a TypeError later.
    with pytest.raises(ValueError, match="frame='abc': must be an integer"):
        run_bench(session=str(source), frame="abc")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="full='yes': must be true or false"):
        run_bench(session=str(source), full="yes")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="repeat=0: must be >= 1"):
        run_bench(session=str(source), repeat=0)


def test_repeat_reports_the_median_of_every_run(source: Path, tmp_path: Path) -> None:
    """``repeat=3, full=true``: three forced full runs and three timed re-runs, each on its
    own copy of the fixed session; the row's times are the medians of the listed runs, and
    the kept session is the last timed copy."""
    kept = tmp_path / "kept"
    rows = run_bench(session=str(source), frame=EDIT_FRAME, camera="cam2", keep=str(kept), repeat=3, full=True)
    for r in rows[:-1]:
        assert len(r["incremental_runs_s"]) == 3 and len(r["full_runs_s"]) == 3
        assert r["incremental_s"] == pytest.approx(sorted(r["incremental_runs_s"])[1], abs=0.006)
        assert r["full_s"] == pytest.approx(sorted(r["full_runs_s"])[1], abs=0.006)
    # The forced full runs re-run every stage, the timed ones only the stale stages.
    assert [r["stage"] for r in rows] == ["associate", "triangulate", "fit", "physics", "all re-run stages"]
    m = ArtifactStore(kept).manifest("physics")
    assert m is not None
    (phys,) = [r for r in rows if r["stage"] == "physics"]
    assert phys["incremental_runs_s"][-1] == pytest.approx(m.duration_s, abs=0.006)
    assert phys["incremental"] == str(m.metrics.get("incremental", ""))
    assert len(load_annotations(kept / "annotations.json")) == 2


def test_fix_false_times_the_breaking_swap(source: Path, tmp_path: Path) -> None:
    kept = tmp_path / "swapped"
    rows = run_bench(session=str(source), frame=EDIT_FRAME, camera="cam2", keep=str(kept), fix=False)
    assert rows[0]["edit"] == f"identity swap at frame {EDIT_FRAME} in cam2" and rows[-1]["stage"] == "all re-run stages"
    (edit,) = load_annotations(kept / "annotations.json")
    assert isinstance(edit, SwapIdentities) and edit.frame == EDIT_FRAME
    a = ArtifactStore(source).load("associate", "association", Association)
    b = ArtifactStore(kept).load("associate", "association", Association)
    assert not (a.person_of_det == b.person_of_det).all()
    with pytest.raises(ValueError, match="fix='no': must be true or false"):
        run_bench(session=str(source), fix="no")  # type: ignore[arg-type]
