"""Parries in the synthetic choreography (``SyntheticConfig.parry_prob``): the parried punches
are parries by the analytics' definition, measured here on the ground-truth joints without the
analyze stage; with the option off the bouts are those of the code before it (a golden file);
the analyze stage's parry detector finds them, scored by ``pipeline.bench.analytics_parry``."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from pipeline.bench.analytics_parry import match_parries, parry_counts, parry_rates
from pipeline.evaluate.glove_contact import body_point, glove_gaps
from pipeline.schema.analytics import BoutEvents
from pipeline.schema.joints import COCO17_FEET
from pipeline.synthetic import SyntheticBout, SyntheticConfig, make_bout
from pipeline.synthetic.truth import CONTACT_TOL_M, BoutTruth

GOLDEN = Path(__file__).parent / "data" / "parry_off_golden.npz"
"""Two 60-frame bouts made by the generator before ``parry_prob`` existed (``_golden_configs``)."""
PARRIED = (
    SyntheticConfig(seed=81, n_frames=70, n_cameras=2, variety=True, bystander=False, parry_prob=1.0),
    SyntheticConfig(seed=47, n_frames=70, n_cameras=2, variety=True, bystander=False, parry_prob=1.0),
)
"""Two short bouts whose scripts aim a jab (seed 81) and a cross (seed 47) to be blocked: both
parried at ``parry_prob`` 1."""

# The definition of a parry (pipeline/stages/analyze/blocks.py), restated for an independent check.
MIN_GUARD_SPEED_MPS = 1.0
"""The parrying glove moves across the punch's line at least this fast over the window before the contact."""
MIN_DEFLECTION_M = 0.05
"""The punching glove is pushed sideways, the same way, by at least this over the window after it."""
WINDOW = 3
"""Frames of those windows (0.06 s at 50 fps)."""
R_GLOVE_M, R_FOREARM_M = 0.065, 0.045
"""``CapsuleProxy``'s glove sphere and forearm capsule radii (m)."""


def _golden_configs() -> dict[str, SyntheticConfig]:
    return {
        "base": SyntheticConfig(seed=0, n_frames=60, n_cameras=2, bystander=False),
        "varied": SyntheticConfig(seed=20, n_frames=60, n_cameras=2, variety=True, bystander=False),
    }


@pytest.fixture(scope="module")
def parried() -> list[SyntheticBout]:
    return [make_bout(cfg) for cfg in PARRIED]


def _glove(xyz: np.ndarray, hand: str) -> np.ndarray:
    """(frames, 3) glove-sphere centre: a quarter of the forearm past the wrist."""
    el, wr = xyz[:, COCO17_FEET.index(f"{hand}_elbow")], xyz[:, COCO17_FEET.index(f"{hand}_wrist")]
    return wr + 0.25 * (wr - el)


def _point_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(frames,) distance from points ``p`` to segments ``a``-``b`` (all (frames, 3))."""
    ab = b - a
    s = np.clip(np.sum((p - a) * ab, axis=1) / np.sum(ab * ab, axis=1), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[:, None] * ab), axis=1)


def _parry_gap(xyz: np.ndarray, attacker: int, hand: str, side: str) -> np.ndarray:
    """(frames,) gap (m) between the defender's ``side`` glove and the attacker's ``hand`` glove
    or forearm on the joints ``xyz`` (frames, 2, 23, 3)."""
    g = _glove(xyz[:, 1 - attacker], side)
    punch = xyz[:, attacker]
    el, wr = punch[:, COCO17_FEET.index(f"{hand}_elbow")], punch[:, COCO17_FEET.index(f"{hand}_wrist")]
    to_glove = np.linalg.norm(g - _glove(punch, hand), axis=1) - 2 * R_GLOVE_M
    return np.minimum(to_glove, _point_segment(g, el, wr) - R_GLOVE_M - R_FOREARM_M)


def test_config_rejects_bad_parry_prob() -> None:
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="parry_prob"):
            SyntheticConfig(variety=True, parry_prob=bad)
    with pytest.raises(ValueError, match="parry_prob.*variety"):
        SyntheticConfig(parry_prob=0.5)


@pytest.mark.parametrize("which", [0, 1], ids=["jab", "cross"])
def test_parried_punches_are_parries_on_the_ground_truth(parried: list[SyntheticBout], which: int) -> None:
    tr, xyz, fps = parried[which].truth, parried[which].gt.xyz_m, parried[which].truth.fps
    rows = np.flatnonzero(tr.punch_intent == "parry")
    assert tr.punch_type[rows].tolist() == [("jab", "cross")[which]]
    # Every scripted parry touched on the bodies, and the truth says who parried with what.
    assert sorted(tr.parry_punch.tolist()) == rows.tolist()
    for k in range(tr.parry_person.size):
        i = int(tr.parry_punch[k])
        att, hand = int(tr.punch_person[i]), str(tr.punch_hand[i])
        side = "right" if hand == "left" else "left"  # the glove on the side the punch arrives on
        assert (int(tr.parry_person[k]), str(tr.parry_hand[k])) == (1 - att, side)
        start, peak, end = (
            int(a[i]) for a in (tr.punch_start_frame, tr.punch_peak_frame, tr.punch_end_frame)
        )
        c = int(tr.parry_frame[k])
        # On the way out: the first touch of the gloves (or glove and forearm) is before the strike.
        assert start < c < peak
        gap = _parry_gap(xyz, att, hand, side)
        assert gap[c] <= CONTACT_TOL_M and np.all(gap[start:c] > CONTACT_TOL_M), gap[start : peak + 1]
        # Across the punch's line: horizontal, normal to the punching shoulder -> defender's head.
        head = body_point(xyz[start, 1 - att], "mid:left_ear+right_ear", COCO17_FEET)
        line = head - xyz[start, att, COCO17_FEET.index(f"{hand}_shoulder")]
        line[2] = 0.0
        across = np.cross([0.0, 0.0, 1.0], line / np.linalg.norm(line))
        g, p = _glove(xyz[:, 1 - att], side) @ across, _glove(xyz[:, att], hand) @ across
        v_guard = (g[c] - g[c - WINDOW]) * fps / WINDOW
        v_punch = (p[c] - p[c - WINDOW]) * fps / WINDOW
        deflection = (p[c + WINDOW] - p[c]) - v_punch * WINDOW / fps
        assert abs(v_guard) >= MIN_GUARD_SPEED_MPS, v_guard
        assert np.sign(deflection) == np.sign(v_guard) and abs(deflection) >= MIN_DEFLECTION_M, deflection
        # A short slap across (relative to the defender's shoulders).
        d = xyz[:, 1 - att]
        rel = _glove(d, side) - 0.5 * (
            d[:, COCO17_FEET.index("left_shoulder")] + d[:, COCO17_FEET.index("right_shoulder")]
        )
        w = np.sign(v_guard) * (rel[c - 6 : c + 1] @ across)
        assert 0.08 <= w[-1] - w.min() <= 0.25, w
        # No landing: the punching glove stays clear of the head and trunk all through the punch.
        gaps = glove_gaps(xyz[start : end + 1, att], hand, xyz[start : end + 1, 1 - att], COCO17_FEET)
        assert min(float(gaps["head"].min()), float(gaps["body"].min())) > 0.04
        assert tr.punch_outcome[i] in ("missed", "blocked")


def test_parry_stream_changes_only_the_parried_punches(parried: list[SyntheticBout]) -> None:
    plain = make_bout(dataclasses.replace(PARRIED[0], parry_prob=0.0))
    a, b = plain.choreography, parried[0].choreography
    assert a.phases == b.phases and a.slips == b.slips
    assert [(p.person, p.kind, p.t0_s) for p in a.punches] == [(p.person, p.kind, p.t0_s) for p in b.punches]
    diff = [(p.aim, q.aim) for p, q in zip(a.punches, b.punches, strict=True) if p.aim != q.aim]
    assert diff == [("block", "parry")]
    assert plain.truth.parry_person.size == 0
    np.testing.assert_array_equal(plain.rig.T_world_cam, parried[0].rig.T_world_cam)
    np.testing.assert_array_equal(plain.truth.clinch, parried[0].truth.clinch)


def test_parry_prob_off_reproduces_the_bouts_before_it() -> None:
    golden = np.load(GOLDEN)
    for name, cfg in _golden_configs().items():
        b = make_bout(dataclasses.replace(cfg, parry_prob=0.0))
        # Stored as float32: far below any change of the motion (mm) or of the detections (px).
        np.testing.assert_allclose(b.gt.xyz_m, golden[f"{name}_gt_xyz_m"], rtol=0, atol=1e-6)
        np.testing.assert_allclose(b.tracks.keypoints_px, golden[f"{name}_keypoints_px"], rtol=0, atol=1e-3)
        np.testing.assert_array_equal(b.truth.punch_peak_frame, golden[f"{name}_punch_peak_frame"])
        np.testing.assert_array_equal(b.truth.punch_intent, golden[f"{name}_punch_intent"])
    # The varied bout scripts a block, a slip and a landing: the guard moves are exercised.
    assert sorted(golden["varied_punch_intent"].tolist()) == ["block", "land", "slip"]


def test_analyze_finds_the_parries(parried: list[SyntheticBout]) -> None:
    from pipeline.stages.analyze import AnalyzeConfig, AnalyzeInputs
    from pipeline.stages.analyze import run as analyze

    total = {"gt_parries": 0, "parries_detected": 0, "parries_matched": 0}
    for bout in parried:
        counts = parry_counts(bout.truth, analyze(AnalyzeInputs(bout.gt), AnalyzeConfig()).events)
        total = {k: total[k] + counts[k] for k in total}
    assert total == {"gt_parries": 2, "parries_detected": 2, "parries_matched": 2}
    assert parry_rates(total) == {"parry_precision": 1.0, "parry_recall": 1.0}


def _merged(a: BoutTruth, b: BoutTruth) -> BoutTruth:
    """One truth with the punches and parries of ``a`` and then ``b`` (``b``'s frames shifted past
    ``a``'s): two parries to match."""
    n, f = a.n_punches, a.clinch.shape[0]
    cat = {
        k: np.concatenate([getattr(a, k), getattr(b, k) + f if k.endswith("_frame") else getattr(b, k)])
        for k in BoutTruth.__dataclass_fields__
        if k.startswith(("punch_", "parry_"))
    }
    cat["parry_punch"] = np.concatenate([a.parry_punch, b.parry_punch + n])
    return BoutTruth(**{**a.__dict__, **cat, "clinch": np.concatenate([a.clinch, b.clinch])})


def _events(tr: BoutTruth, parries: list[tuple[int, int, int]], shift: int = 0) -> BoutEvents:
    """The truth's punches as detected ``shift`` frames late, plus ``(defender, punch row,
    frame)`` parry events."""
    n, k = tr.n_punches, len(parries)
    ev = BoutEvents.empty(tr.fps, np.array([0, 1]))
    frames = np.array([f for _, _, f in parries], dtype=np.int64)
    return BoutEvents(**{
        **ev.__dict__, "punch_person": tr.punch_person, "punch_hand": tr.punch_hand, "punch_type": tr.punch_type,
        "punch_start_frame": tr.punch_start_frame + shift, "punch_peak_frame": tr.punch_peak_frame + shift,
        "punch_end_frame": tr.punch_end_frame + shift, "punch_peak_speed_mps": tr.punch_peak_speed_mps,
        "punch_extension": np.ones(n), "punch_target": np.full(n, "head"), "punch_outcome": tr.punch_outcome,
        "punch_confidence": np.ones(n), "evade_person": np.array([p for p, _, _ in parries], dtype=np.int64),
        "evade_kind": np.full(k, "parry"), "evade_start_frame": frames, "evade_peak_frame": frames,
        "evade_end_frame": frames, "evade_displacement_m": np.full(k, 0.1),
        "evade_punch": np.array([r for _, r, _ in parries], dtype=np.int64),
    })  # fmt: skip


def test_match_parries_conventions(parried: list[SyntheticBout]) -> None:
    tr = _merged(parried[0].truth, parried[1].truth)
    right = [
        (int(tr.parry_person[k]), int(tr.parry_punch[k]), int(tr.parry_frame[k]))
        for k in range(tr.parry_person.size)
    ]
    assert match_parries(tr, _events(tr, right)) == [(k, k) for k in range(len(right))]
    # credited to the puncher, or answering a punch that was not parried: no match
    other = next(i for i in range(tr.n_punches) if i not in set(tr.parry_punch.tolist()))
    wrong = [
        (1 - right[0][0], right[0][1], right[0][2]),
        right[1],
        (1 - int(tr.punch_person[other]), other, 0),
    ]
    counts = parry_counts(tr, _events(tr, wrong))
    assert counts == {"gt_parries": 2, "parries_detected": 3, "parries_matched": 1}
    assert parry_rates(counts) == {"parry_precision": 1 / 3, "parry_recall": 0.5}
    # one-to-one: two events on the same parried punch match it once
    assert len(match_parries(tr, _events(tr, [right[0], right[0]]))) == 1
    # the strike frames must be within tol_frames
    assert match_parries(tr, _events(tr, right, shift=3)) == [(0, 0), (1, 1)]
    assert match_parries(tr, _events(tr, right, shift=4)) == []
    assert match_parries(tr, _events(tr, right, shift=4), tol_frames=4) == [(0, 0), (1, 1)]
    assert np.isnan(parry_rates(parry_counts(tr, _events(tr, [])))["parry_precision"])
    with pytest.raises(ValueError, match="tol_frames"):
        match_parries(tr, _events(tr, right), tol_frames=-1)
