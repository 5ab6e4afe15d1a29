from pathlib import Path

import numpy as np

from pipeline.stages.evaluate import FLAG_KINDS
from tests.webui.fixtures import build_session
from webui.analysis import FrameProblems, compute_problems, compute_series, fill_gaps
from webui.scene.session_data import load_session_data


def test_problem_frames_are_the_evaluate_stages(tmp_path: Path) -> None:
    """The viewer shows the flags the evaluate stage wrote (problems.npz), not its own."""
    d = load_session_data(build_session(tmp_path, n_frames=12, physics=True, low_conf_frame=5))
    p = compute_problems(d)
    assert np.flatnonzero(p.of("identity_low")).tolist() == [5]
    # Frame 10: the 2D of one person disagrees in every view; frame 3: the physics result
    # moved that person into the other, away from what the cameras saw.
    assert np.flatnonzero(p.of("reprojection_high")).tolist() == [3, 10]
    assert np.flatnonzero(p.of("penetration_high")).tolist() == [3]
    assert p.kinds_at(5) == ["identity confidence low"]
    assert d.problems is not None and d.problems.flags.shape == (12, len(FLAG_KINDS))
    # Without an evaluate artifact there is nothing to show.
    (d.session_dir / "artifacts" / "evaluate" / "problems.npz").unlink()
    assert not compute_problems(load_session_data(d.session_dir)).any.any()


def test_next_problem_skips_runs_and_wraps() -> None:
    flags = np.zeros((20, len(FLAG_KINDS)), dtype=bool)
    flags[[3, 4, 5, 12], 0] = True
    p = FrameProblems(flags)
    assert p.next_after(0) == 3
    assert p.next_after(3) == 12  # 4 and 5 belong to the same problem
    assert p.next_after(12) == 3  # wraps around
    assert p.segments() == [(3, 5), (12, 12)]
    assert FrameProblems.none(5).next_after(2) is None


def test_series(tmp_path: Path) -> None:
    d = load_session_data(build_session(tmp_path, n_frames=20))
    s = compute_series(d, "filtered")
    assert s is not None
    # person 0 jabs (the right wrist moves 0.4 m back and forth), person 1 only drifts
    assert np.nanmax(s.wrist_speed_mps[:, 0]) > 2 * np.nanmax(s.wrist_speed_mps[:, 1])
    np.testing.assert_allclose(np.nanmedian(s.distance_m), 2.0, atol=0.05)
    assert np.isnan(s.wrist_speed_mps[0]).all()  # no speed at the first frame
    assert s.reproj_err_px[18, 1] == 30.0 and s.reproj_err_px[0, 0] == 2.0
    assert compute_series(d, "fit") is None


def test_fill_gaps() -> None:
    np.testing.assert_allclose(fill_gaps(np.array([np.nan, 1.0, np.nan, 3.0])), [1.0, 1.0, 2.0, 3.0])
    np.testing.assert_allclose(fill_gaps(np.array([np.nan, np.nan])), [0.0, 0.0])
