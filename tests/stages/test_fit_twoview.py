"""``FitConfig.accel_fast_view_px``: a fist one view sees fly is not held back by the
acceleration and jerk penalties (docs/design/fit.md, "Fast fists seen by one view").

Toy fits on free keypoints (no body model): the loss is the stage's own 3D, acceleration and
jerk terms (``terms.build_terms``) minimised by the stage's pose passes (``run_pose_passes``).
"""

from __future__ import annotations

import pytest

from pipeline.schema import COCO17_FEET
from pipeline.stages.fit import FitConfig

pytest.importorskip("torch")

import torch  # noqa: E402

from pipeline.backends.fitting.body_model import FitState, Rest, Skeleton  # noqa: E402
from pipeline.backends.fitting.common import run_pose_passes  # noqa: E402
from pipeline.backends.fitting.terms import (  # noqa: E402
    Targets,
    TermContext,
    accel_term,
    build_terms,
    evaluate_terms,
    fast_view_relief,
    jerk_term,
)

NJ = len(COCO17_FEET)
WRIST = COCO17_FEET.index("right_wrist")
ELBOW = COCO17_FEET.index("right_elbow")
NF = 40
PEAK = 20
F64 = torch.float64


def _punch() -> torch.Tensor:
    """(NF, NJ, 3) every keypoint at rest except the right wrist and elbow, which both throw
    the same 0.4 m punch along x over 5 frames (a smoothstep) from frame PEAK - 5."""
    x = torch.zeros(NF, NJ, 3, dtype=F64)
    x[:, :, 1] = 0.05 * torch.arange(NJ, dtype=F64)  # distinct rest positions
    u = ((torch.arange(NF, dtype=F64) - (PEAK - 5)) / 5).clamp(0, 1)
    for j in (WRIST, ELBOW):
        x[:, j, 0] += 0.4 * u * u * (3 - 2 * u)
    return x


def _targets(kp: torch.Tensor, w3d: torch.Tensor) -> Targets:
    """One person seen by two views: view 0 sees every keypoint of ``kp`` at 1000 px per m
    (x, y), view 1 sees nothing (its weights are 0)."""
    uv = torch.zeros(2, NF, NJ, 2, dtype=F64)
    uv[0] = 1000.0 * kp[:, :, :2]
    w2d = torch.zeros(2, NF, NJ, dtype=F64)
    w2d[0] = 0.9
    P = torch.zeros(2, 3, 4, dtype=F64)
    return Targets(kp, w3d, uv, w2d, P, torch.ones(1, NF, dtype=torch.bool), n_persons=1, n_frames=NF)


def _fit(cfg: FitConfig, targets: Targets) -> torch.Tensor:
    """Keypoints (NF, NJ, 3) minimising the stage's 3D, acceleration and jerk terms of ``cfg``,
    initialised at the 3D targets (as the stage's limb initialisation does)."""
    terms = build_terms(("3d", "accel", "jerk"), TermContext(cfg, None, targets))  # type: ignore[arg-type]
    x = targets.kp3d_m.clone().requires_grad_(True)
    z = torch.zeros(NF, 4, 3, dtype=F64)
    G = torch.eye(3, dtype=F64).expand(NF, 4, 3, 3)

    def evaluate(use_2d: bool, w: torch.Tensor | None) -> tuple[torch.Tensor, dict, torch.Tensor]:
        s = FitState(z[:, :3], G[:, 0], z, z[:, 0], Rest(z), Skeleton(G, z, x), x, z[:1], z[:1, 0], use_2d, w)
        parts = evaluate_terms(terms, s)
        return sum(parts.values()), parts, x  # type: ignore[return-value]

    run_pose_passes([x], evaluate, cfg, 1, NF)
    return x.detach()


def _punch_error(x: torch.Tensor, truth: torch.Tensor, j: int) -> float:
    """RMS distance (m) of keypoint ``j`` of ``x`` to ``truth`` (NF, NJ, 3) around the punch."""
    d = (x[PEAK - 8 : PEAK + 4, j] - truth[PEAK - 8 : PEAK + 4, j]).norm(dim=-1)
    return float(d.square().mean().sqrt())


def test_relief_marks_the_wrist_frames_a_view_sees_move_fast() -> None:
    """Relief is the config's factor at the wrist rows whose 2D speed in some view (central
    difference, both neighbours seen) passes the threshold, and the rows either side; 1 at
    every other keypoint (the elbow moves as fast) and frame; None when off. The threshold is
    stated per frame at ``reference_fps``: at half the rate it doubles."""
    kp = _punch()
    t = _targets(kp, torch.ones(NF, NJ, dtype=F64))
    speed = 1000.0 * (kp[2:, WRIST, 0] - kp[:-2, WRIST, 0]) / 2  # px per frame at rows 0..NF-3
    cfg = FitConfig(accel_fast_view_px=40.0, accel_fast_view_scale=0.25)
    relief = fast_view_relief(t, cfg)
    assert relief is not None and relief.shape == (1, NF - 2, NJ)
    fast = speed > 40.0
    assert 2 <= int(fast.sum()) < 6
    near = fast.clone()
    near[1:] |= fast[:-1]
    near[:-1] |= fast[1:]
    assert torch.equal(relief[0, :, WRIST], torch.where(near, 0.25, 1.0).to(F64))
    others = [j for j in range(NJ) if j not in (WRIST, COCO17_FEET.index("left_wrist"))]
    assert torch.all(relief[0][:, others] == 1.0)
    assert fast_view_relief(t, FitConfig()) is None
    # A frame where the only view does not see the wrist breaks the central difference.
    row = int(torch.argmax(speed))
    t.w2d[0, row + 2, WRIST] = 0.0
    t.w2d[0, row, WRIST] = 0.0
    unseen = fast_view_relief(t, cfg)
    assert unseen is not None and float(unseen[0, row, WRIST]) <= 0.25  # still near a fast row
    assert FitConfig(accel_fast_view_px=40.0).at_rate(25.0).accel_fast_view_px == pytest.approx(80.0)
    for bad in ({"accel_fast_view_px": -1.0}, {"accel_fast_view_scale": 0.0}, {"accel_fast_view_scale": 1.5}):
        with pytest.raises(ValueError, match="accel_fast_view"):
            FitConfig(**bad)  # type: ignore[arg-type]


def test_relief_multiplies_the_acceleration_and_jerk_terms() -> None:
    """``relief`` multiplies each keypoint's term of both penalties at its rows, plain,
    pseudo-Huber or re-weighted."""
    kp = _punch()[None]
    relief = torch.ones(1, NF - 2, NJ, dtype=F64)
    relief[0, PEAK - 4, WRIST] = 0.3
    only = torch.zeros_like(relief)
    only[0, PEAK - 4, WRIST] = 1.0
    for s, w in ((0.0, None), (0.005, None), (0.0, 1.0 + torch.rand(1, NF - 2, NJ, dtype=F64))):
        part = float(accel_term(kp, s, 0.3, w, only))
        assert part > 0.0
        assert float(accel_term(kp, s, 0.3, w, relief)) == pytest.approx(
            float(accel_term(kp, s, 0.3, w)) - 0.7 * part
        )
    w = torch.ones(1, NF - 2, NJ, dtype=F64)
    assert float(jerk_term(kp, w, relief)) < float(jerk_term(kp, w))
    assert float(jerk_term(kp, w, torch.ones_like(w))) == pytest.approx(float(jerk_term(kp, w)))


def test_a_fist_one_view_sees_fly_follows_its_weak_targets_with_the_relief() -> None:
    """The wrist and the elbow throw the same punch with weak 3D targets on the way out (the
    filter bridged them); the view sees the wrist only. Without the relief the acceleration
    penalty smears the wrist's punch; with it the wrist follows its targets more closely,
    and the elbow, unseen, is fitted as before."""
    kp = _punch()
    w3d = torch.full((NF, NJ), 0.9, dtype=F64)
    w3d[PEAK - 6 : PEAK + 3, [WRIST, ELBOW]] = 0.05
    t = _targets(kp, w3d)
    t.w2d[0, :, ELBOW] = 0.0
    iters = {"pose_iters_3d": 0, "pose_iters": 60, "accel_adapt_after": 30}
    plain = _fit(FitConfig(**iters), t)  # type: ignore[arg-type]
    relieved = _fit(FitConfig(**iters, accel_fast_view_px=20.0, accel_fast_view_scale=0.1), t)  # type: ignore[arg-type]
    wrist_plain, wrist_relieved = _punch_error(plain, kp, WRIST), _punch_error(relieved, kp, WRIST)
    assert wrist_plain > 0.05
    assert wrist_relieved < 0.7 * wrist_plain
    # The elbow shares only the whole-body part of the penalty with the wrist.
    elbow_change = abs(_punch_error(relieved, kp, ELBOW) - _punch_error(plain, kp, ELBOW))
    assert elbow_change < 0.25 * (wrist_plain - wrist_relieved)
