"""Configuration of the built-in synthetic sparring bout."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SyntheticConfig:
    """What to generate. Every random choice derives from ``seed`` (same seed -> same arrays)."""

    seed: int = 0
    """Seed of every random choice (body proportions, choreography, rig, noise, misses, swaps)."""

    n_cameras: int = 4
    """Number of cameras on a circle around the ring, 2..8."""

    camera_step_deg: float | None = None
    """Angle around the ring from one camera to the next, in degrees, in [15, 360 / n_cameras];
    None spreads them evenly (360 / n_cameras: two cameras face each other, 90 puts them a
    quarter turn apart). The random draws are the same either way."""

    n_frames: int = 300
    """Number of synchronised frames. The script cycles exchange -> clinch -> range phases
    (~4.5 s per cycle); at 50 fps the first clinch contact is at ~1.7 s (frame ~85)."""

    fps: float = 50.0
    """Frame rate of the rig in Hz."""

    noise_px: float = 3.0
    """Standard deviation of the Gaussian pixel noise added to visible keypoints (occluded
    ones that are kept get 2.5x that)."""

    miss_rate: float = 0.03
    """Probability that a whole detection (one person in one view and frame) is missed."""

    bystander: bool = True
    """Add a walking bystander outside the ring, seen by some cameras only (true id -1)."""

    id_swaps: bool = True
    """Inject per-view track-id swaps at frames where the boxers' boxes overlap strongly."""

    distortion: bool = False
    """Give the cameras OpenCV lens distortion (k1 in [-0.25, -0.1])."""

    clinch: bool = True
    """Include clinch phases (bodies touching, arms around the other). When False the clinch
    phases are replaced by close-range exchanges without contact."""

    variety: bool = False
    """Re-script the punches (``pipeline.synthetic.combos``): random combinations of every
    punch type, closing in so that they can land, an intended outcome per punch (land,
    blocked, slipped or ducked, short), feints and counters. From its own random stream:
    phases, clinches, circling and drift stay those of the same seed without it."""

    parry_prob: float = 0.0
    """Probability in [0, 1] that a jab or cross the varied script aims to be blocked is
    parried instead (the defender's glove slaps it sideways on its way out; needs
    ``variety``). From its own random stream: every other choice stays that of 0."""

    southpaw: bool = False
    """Both boxers southpaw (lead = right): the whole bout mirrored in the plane x = 0 with
    left and right exchanged (``pipeline.synthetic.mirror``). False: two orthodox boxers."""

    mixed_stance: bool = False
    """Boxer 1 southpaw against orthodox boxer 0: the script's punches thrown with his other
    hand, his bladed stance, guard, lead hook and trunk twists mirrored in his own facing
    frame; the script's times, clinch grips and slips unchanged (``choreo.with_stances``).
    With ``southpaw`` the mirror makes boxer 0 the southpaw. False: no boxer mirrored."""

    image_size_wh: tuple[int, int] = (1280, 720)
    """Image width and height in pixels (same for every camera)."""

    def __post_init__(self) -> None:
        if not 2 <= self.n_cameras <= 8:
            raise ValueError(f"SyntheticConfig.n_cameras must be in 2..8, got {self.n_cameras}")
        if self.camera_step_deg is not None and not (
            np.isfinite(self.camera_step_deg) and 15.0 <= self.camera_step_deg <= 360.0 / self.n_cameras
        ):
            raise ValueError(
                f"SyntheticConfig.camera_step_deg must be in [15, {360.0 / self.n_cameras:g}] deg for"
                f" {self.n_cameras} cameras (or None: evenly spread), got {self.camera_step_deg}"
            )
        if self.n_frames < 2:
            raise ValueError(f"SyntheticConfig.n_frames must be >= 2, got {self.n_frames}")
        if not (np.isfinite(self.fps) and 5.0 <= self.fps <= 1000.0):
            raise ValueError(f"SyntheticConfig.fps must be in [5, 1000] Hz, got {self.fps}")
        if not (np.isfinite(self.noise_px) and self.noise_px >= 0):
            raise ValueError(f"SyntheticConfig.noise_px must be >= 0, got {self.noise_px}")
        if not 0.0 <= self.miss_rate < 1.0:
            raise ValueError(f"SyntheticConfig.miss_rate must be in [0, 1), got {self.miss_rate}")
        if len(self.image_size_wh) != 2 or min(self.image_size_wh) < 64:
            raise ValueError(
                f"SyntheticConfig.image_size_wh must be two sizes >= 64 px, got {self.image_size_wh}"
            )
        if not 0.0 <= self.parry_prob <= 1.0:
            raise ValueError(f"SyntheticConfig.parry_prob must be in [0, 1], got {self.parry_prob}")
        if self.parry_prob > 0.0 and not self.variety:
            raise ValueError(
                f"SyntheticConfig.parry_prob={self.parry_prob} needs variety=True (the base script has no blocks to parry)"
            )
        if self.seed < 0:
            raise ValueError(f"SyntheticConfig.seed must be >= 0, got {self.seed}")
