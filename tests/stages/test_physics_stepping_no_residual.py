"""A walking humanoid tracked with no residual root force stays up and on target (issue 38).

The input is mocap: athlete 0 of the DeepMimic ``walk`` scene (the pybullet wheel's clip
retargeted to a synthetic boxer, ``make_mocap_scene``), played at two speeds:

- **half speed**: resampled at 100 fps and read at 50 fps, 0.48 m/s (Shelf's actors walk at
  0.2 m/s). In its 72 frames (1.44 s) the right foot lifts off, swings 1.23 m and lands. The
  clip stops before the walk's loop seam (frame 73 on, where both planted feet jump 8-14 cm
  sideways); the clip's own discontinuity (between two key frames the hips and shoulders turn
  12 degrees and the landing left foot jumps 9 cm) falls at the right foot's lift-off and stays
  in. Tracked with the residual-free recipe of docs/design/physics-effort.md
  (``residual.mode: off``, ``solver.ilqr`` ``{max_iter: 30, jacobian_reuse: 2, deriv_every: 1,
  fd_interval_s: 0}``), about 40 s here.
- **full speed**: read at 50 fps, 0.96 m/s, 48 frames (0.96 s) in which the right foot lifts
  off, swings 1.26 m at up to 3.5 m/s and lands, and the left foot lifts off. The recipe as it
  is stops too early there (``rel_tol`` 1e-3): one of five runs (the clip and four draws, below) had an
  untrackable window and ended 19 cm off its target. With the iLQR converged further (``rel_tol`` 1e-6,
  up to 100 iterations), it tracked all eight runs; 25-50 s here.

Every bound is about 1.5x the largest of the measurements on the clip and on the same clip
with 10 um of Gaussian noise on the input (the iLQR's result moves with it): four draws at half
speed, seven at full speed.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, replace

import numpy as np
import pytest

pytest.importorskip("mujoco")

from pipeline.backends.mujoco.config import ILQRConfig, ResidualConfig, SolverConfig  # noqa: E402
from pipeline.schema.joints import COCO17_FEET  # noqa: E402
from pipeline.schema.keypoints3d import Keypoints3D  # noqa: E402
from pipeline.stages.physics import PhysicsConfig, PhysicsInputs, PhysicsOutput, run  # noqa: E402
from pipeline.synthetic.config import SyntheticConfig  # noqa: E402
from pipeline.synthetic.mocap_scene import make_mocap_scene  # noqa: E402

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("pybullet_data") is None, reason="pybullet (DeepMimic clips) not installed"
)

FPS = 50.0
RECIPE = ILQRConfig(max_iter=30, jacobian_reuse=2, deriv_every=1, fd_interval_s=0.0)
"""The residual-free solver settings (``solver.ilqr``) of docs/design/physics-effort.md."""

OFF_FLOOR_M = 0.05
"""A foot whose lowest point (heel, toes) is above this is off the floor (the input's swing
peaks at 8 cm, its stance at 1-3 cm)."""
ON_FLOOR_M = 0.03
"""A foot whose lowest point is below this and moves slower than ``PLANTED_SPEED_M_S`` is planted."""
PLANTED_SPEED_M_S = 0.3
"""Horizontal speed of the foot's centre below which a foot on the floor counts as planted
(the swing peaks at 1.8 m/s at half speed)."""
MIN_STEP_M = 0.15
"""Shortest step the input must contain (foot centre, lift-off to landing)."""
STEP_MISMATCH_M = 0.13
"""Bound on the difference between the simulated and the input step length (m); measured
2.2-8.8 cm at half speed (the simulated foot landing short), 0-5.1 cm at full speed."""


@dataclass(frozen=True)
class Clip:
    """One way of playing the walk, the solver that tracks it and its bounds (measured values
    in the comments: half speed / full speed)."""

    name: str
    slow: int
    """The clip is resampled at ``slow`` x FPS and read at FPS: played ``slow`` times slower."""
    skip: int
    """Frames of the resampled scene before the clip (the right foot planted before its step)."""
    n_frames: int
    """Frames of the clip at FPS, ending before the walk's loop seam."""
    ilqr: ILQRConfig
    mean_error_m: float
    """Bound on the mean keypoint-site error against the input (m); 17.5-21.4 / 22.7-30.0 mm."""
    frame_error_m: float
    """Bound on any frame's mean keypoint-site error (m); 48-55 / 48-54 mm."""
    pelvis_dz_m: float
    """Bound on the simulated root's (pelvis) height difference from the input's pelvis in any
    frame (m); 19-22 / 14-20 mm (a fall drops it by tens of centimetres)."""
    lift_frames: int
    """Bound on the difference between the simulated and the input lift-off frame; 0-1 / 1."""
    land_frames: int
    """Bound on the difference between the simulated and the input landing frame; 1-2 / 0-3."""


HALF = Clip(
    name="half speed",
    slow=2,
    skip=20,
    n_frames=72,
    ilqr=RECIPE,
    mean_error_m=0.034,
    frame_error_m=0.083,
    pelvis_dz_m=0.033,
    lift_frames=2,
    land_frames=3,
)
FULL = Clip(
    name="full speed",
    slow=1,
    skip=10,
    n_frames=48,
    ilqr=replace(RECIPE, max_iter=100, rel_tol=1e-6),
    mean_error_m=0.045,
    frame_error_m=0.082,
    pelvis_dz_m=0.030,
    lift_frames=2,
    land_frames=5,
)


def _hips_mid(xyz: np.ndarray) -> np.ndarray:
    """(frames, 3) midpoint of the hips of (frames, joints, 3) ``COCO17_FEET`` points."""
    return 0.5 * (xyz[:, COCO17_FEET.index("left_hip")] + xyz[:, COCO17_FEET.index("right_hip")])


def _foot(xyz: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
    """(frames,) height of the lowest of the foot's heel and toes (m), and (frames, 2)
    horizontal centre of the three, of (frames, joints, 3) points."""
    idx = [COCO17_FEET.index(f"{side}_{k}") for k in ("heel", "big_toe", "small_toe")]
    return xyz[:, idx, 2].min(axis=1), xyz[:, idx, :2].mean(axis=1)


def _steps(xyz: np.ndarray, fps: float) -> dict[str, tuple[int, int, float]]:
    """Each foot that takes a full step in (frames, joints, 3) points: side -> (last planted
    frame before it leaves the floor, first planted frame after it lands, step length in m)."""
    out = {}
    for side in ("left", "right"):
        low, centre = _foot(xyz, side)
        speed = np.r_[0.0, np.linalg.norm(np.diff(centre, axis=0), axis=1) * fps]
        planted = (low < ON_FLOOR_M) & (speed < PLANTED_SPEED_M_S)
        off = np.flatnonzero(low > OFF_FLOOR_M)
        if off.size == 0:
            continue
        before = np.flatnonzero(planted[: off[0]])
        after = np.flatnonzero(planted[off[-1] :]) + off[-1]
        if before.size and after.size:
            lift, land = int(before[-1]), int(after[0])
            out[side] = (lift, land, float(np.linalg.norm(centre[land] - centre[lift])))
    return out


@pytest.fixture(scope="module", params=[HALF, FULL], ids=lambda c: c.name.replace(" ", "_"))
def clip(request: pytest.FixtureRequest) -> Clip:
    return request.param


@pytest.fixture(scope="module")
def walk(clip: Clip) -> Keypoints3D:
    """The walk played as ``clip`` says (see the module docstring), one person, ``source="fit"``."""
    scene = make_mocap_scene(
        ("walk", "walk"), SyntheticConfig(seed=0, n_frames=clip.skip + clip.n_frames, fps=clip.slow * FPS)
    )
    gt, rows = scene.gt, slice(clip.skip, clip.skip + clip.n_frames)
    return gt.replace(
        person_ids=gt.person_ids[:1],
        frame_indices=np.arange(clip.n_frames),
        fps=FPS,
        xyz_m=gt.xyz_m[rows, :1],
        valid=gt.valid[rows, :1],
        confidence=gt.confidence[rows, :1],
        n_views=gt.n_views[rows, :1],
        reproj_err_px=gt.reproj_err_px[rows, :1],
        source="fit",
    )


@pytest.fixture(scope="module")
def tracked(clip: Clip, walk: Keypoints3D) -> PhysicsOutput:
    """The walk tracked by the physics stage with no residual and the clip's solver."""
    cfg = PhysicsConfig(
        skeleton="keypoints", residual=ResidualConfig(mode="off"), solver=SolverConfig(ilqr=clip.ilqr)
    )
    return run(PhysicsInputs(walk), cfg)


def test_the_input_takes_a_full_step(clip: Clip, walk: Keypoints3D) -> None:
    steps = _steps(walk.xyz_m[:, 0], walk.fps)
    assert "right" in steps, f"no foot lifts off and lands in the clip: {steps}"
    lift, land, length = steps["right"]
    assert length >= MIN_STEP_M and 0 < lift < land < clip.n_frames - 1
    pelvis = _hips_mid(walk.xyz_m[:, 0])
    speed = np.linalg.norm(pelvis[-1, :2] - pelvis[0, :2]) / (clip.n_frames / FPS)
    assert speed > 0.3 * (2 / clip.slow), f"walks at {speed:.2f} m/s"


def test_no_window_is_untrackable_and_no_root_force_is_applied(clip: Clip, tracked: PhysicsOutput) -> None:
    s, solver = tracked.stats, SolverConfig()
    assert s["residual_mode"] == "off"
    assert s["windows"] >= -(-(clip.n_frames - solver.window) // solver.commit) + 1  # 5 / 3
    assert s["untrackable_windows"] == 0, f"{s['untrackable_windows']} of {s['windows']} windows untrackable"
    assert s["untrackable_frames"] == 0
    assert s["windows_with_residual"] == 0 and s["kinematic_frames"] == 0 and s["resets"] == 0
    assert s["residual_force_mean_frac_bw"] == 0.0 and s["residual_force_max_frac_bw"] == 0.0
    assert np.abs(tracked.result.residual_root_force).max() == 0.0


def test_stays_up(clip: Clip, walk: Keypoints3D, tracked: PhysicsOutput) -> None:
    # One person: qpos = [root xyz, root quaternion, hinges], the root body at the pelvis.
    dz = tracked.result.qpos[:, 2] - _hips_mid(walk.xyz_m[:, 0])[:, 2]
    worst = int(np.abs(dz).argmax())
    assert abs(dz[worst]) < clip.pelvis_dz_m, (
        f"root {dz[worst] * 1000:.0f} mm off the input's pelvis height at frame {worst}"
    )


def test_on_target(clip: Clip, walk: Keypoints3D, tracked: PhysicsOutput) -> None:
    err = np.linalg.norm(tracked.keypoints.xyz_m - walk.xyz_m, axis=-1)[:, 0]
    assert err.mean() < clip.mean_error_m, f"mean keypoint error {err.mean() * 1000:.1f} mm"
    per_frame = err.mean(axis=1)
    worst = int(per_frame.argmax())
    assert per_frame[worst] < clip.frame_error_m, f"frame {worst}: {per_frame[worst] * 1000:.0f} mm"


def test_the_simulated_foot_steps_too(clip: Clip, walk: Keypoints3D, tracked: PhysicsOutput) -> None:
    """A humanoid standing still, or sliding its feet along the floor, takes no step here."""
    lift, land, length = _steps(walk.xyz_m[:, 0], walk.fps)["right"]
    sim = tracked.keypoints.xyz_m[:, 0]
    steps = _steps(sim, walk.fps)
    assert "right" in steps, (
        f"the simulated right foot does not lift off and land (highest {_foot(sim, 'right')[0].max() * 1000:.0f} mm)"
    )
    sim_lift, sim_land, sim_length = steps["right"]
    assert abs(sim_lift - lift) <= clip.lift_frames and abs(sim_land - land) <= clip.land_frames, (
        f"simulated lift-off / landing at frames {sim_lift} / {sim_land}, input {lift} / {land}"
    )
    assert abs(sim_length - length) < STEP_MISMATCH_M, (
        f"step {sim_length:.2f} m simulated, {length:.2f} m input"
    )
