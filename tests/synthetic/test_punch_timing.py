"""The varied bout's punch labels are true to the motion: the same hand never throws a
punch before the previous one is back, and the labelled strike frame is when the fist
arrives.

The strike (``pipeline.synthetic.truth``) is the end of the fist's outward stroke: on the
ground-truth joints, the first frame after the stroke's fastest frame at which the glove
has slowed below ``STOPPED_FRAC`` of that speed (the glove stops at the strike point, or
where a straightened arm leaves it when the point is out of reach). The label must be
within one frame of it on the seeds that were wrong, and over 41 seeds within two frames
for every punch and one frame for 98 % (the speed threshold is crossed ~0.15 of a stroke's
length early, two frames for the longest strokes the speed calibration stretches).
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from pipeline.synthetic import SyntheticBout, SyntheticConfig, make_bout
from pipeline.synthetic.strikes import glove_centre
from pipeline.synthetic.truth import STOPPED_FRAC

FAST_SEEDS = (23, 25, 30)
"""Seeds whose labels were wrong before the scheduling and strike-frame fixes."""
ALL_SEEDS = tuple(range(41))


@cache
def _bout(seed: int) -> SyntheticBout:
    return make_bout(
        SyntheticConfig(seed=seed, n_frames=300, n_cameras=2, variety=True, bystander=False, id_swaps=False)
    )


def _overlaps(b: SyntheticBout) -> list[str]:
    """Pairs of labelled punches and feints of one athlete's hand whose [start, end] meet."""
    tr = b.truth
    rows = [
        (
            int(tr.punch_person[i]),
            str(tr.punch_hand[i]),
            int(tr.punch_start_frame[i]),
            int(tr.punch_end_frame[i]),
        )
        for i in range(tr.n_punches)
    ] + [
        (
            int(tr.feint_person[i]),
            str(tr.feint_hand[i]),
            int(tr.feint_start_frame[i]),
            int(tr.feint_end_frame[i]),
        )
        for i in range(tr.feint_person.shape[0])
    ]
    bad = []
    for k, (p, h, s, e) in enumerate(rows):
        for p2, h2, s2, e2 in rows[k + 1 :]:
            if p == p2 and h == h2 and s <= e2 and s2 <= e:
                bad.append(f"person {p} {h}: [{s}, {e}] and [{s2}, {e2}]")
    return bad


def arrival_frame(xyz_m: np.ndarray, person: int, hand: str, start: int, peak: int, end: int) -> int:
    """First frame after the outward stroke's fastest frame (in ``start..peak``) at which
    the glove is slower than ``STOPPED_FRAC`` of that speed (``end`` if it never is)."""
    g = glove_centre(xyz_m[:, person], hand)
    v = np.zeros(len(g))
    v[1:-1] = np.linalg.norm(g[2:] - g[:-2], axis=1)
    fast = start + int(np.argmax(v[start : peak + 1]))
    return next((f for f in range(fast, end + 1) if v[f] < STOPPED_FRAC * v[fast]), end)


def _timing_errors(b: SyntheticBout) -> list[tuple[int, str]]:
    """(|label - arrival| in frames, description) of every labelled punch."""
    tr, xyz = b.truth, b.gt.xyz_m
    out = []
    for i in range(tr.n_punches):
        s, k, e = int(tr.punch_start_frame[i]), int(tr.punch_peak_frame[i]), int(tr.punch_end_frame[i])
        a = arrival_frame(xyz, int(tr.punch_person[i]), str(tr.punch_hand[i]), s, k, e)
        out.append(
            (
                abs(a - k),
                f"person {tr.punch_person[i]} {tr.punch_type[i]} {s}/{k}/{e}: the fist arrives at {a}",
            )
        )
    return out


def _late_or_early(b: SyntheticBout, tol: int = 1) -> list[str]:
    return [msg for err, msg in _timing_errors(b) if err > tol]


@pytest.mark.parametrize("seed", FAST_SEEDS)
def test_same_hand_punches_do_not_overlap(seed: int) -> None:
    b = _bout(seed)
    assert b.truth.n_punches >= 3
    assert _overlaps(b) == []


@pytest.mark.parametrize("seed", FAST_SEEDS)
def test_strike_frame_is_the_fists_arrival(seed: int) -> None:
    assert _late_or_early(_bout(seed)) == []


@pytest.mark.slow
def test_many_seeds_labels_true_to_motion() -> None:
    """No overlap on any seed; every strike label within 2 frames of the arrival and 98 %
    within 1 (a long stroke's speed falls under ``STOPPED_FRAC`` ~0.15 of its length early)."""
    overlaps, errors = {}, []
    for seed in ALL_SEEDS:
        b = _bout(seed)
        if _overlaps(b):
            overlaps[seed] = _overlaps(b)
        errors += [(err, f"seed {seed} {msg}") for err, msg in _timing_errors(b)]
        _bout.cache_clear()
    assert overlaps == {}
    assert len(errors) >= 5 * len(ALL_SEEDS)
    assert [msg for err, msg in errors if err > 2] == []
    assert sum(err <= 1 for err, _ in errors) >= 0.98 * len(errors), [msg for err, msg in errors if err > 1]
