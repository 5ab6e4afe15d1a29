"""Playback that keeps real time: the frame shown follows the wall clock, not one frame per render.

While a view plays, ``PlaybackClock.frame()`` says which frame is due now (the frame Play
started from plus the elapsed time times fps times speed, wrapping at the end of the bout).
When renders (or the browser) are slower than the bout's frame rate, frames are skipped
rather than the bout slowing down. Scrubbing or changing the speed while playing re-anchors
the clock at the current frame.

While playing, the views also send less: the 3D at most ``PLAY_MAX_HZ`` times per second and
the camera images at ``PLAY_IMAGE_SCALE`` of their size at most ``PLAY_IMAGES_HZ`` times per
second, and the 3D casts no shadows (``PLAY_SHADOWS``); paused (or scrubbing), every render is
the exact frame with full-size images and shadows.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

PLAY_MAX_HZ = 25.0
"""Renders per second at most while playing (> 0); the frames in between are skipped."""
PLAY_IMAGES_HZ = 8.0
"""Camera image updates per second at most while playing (> 0)."""
PLAY_IMAGE_SCALE = 0.5
"""Size of the camera images while playing, relative to their paused size, in (0, 1]."""
PLAY_SHADOWS = False
"""Whether the default lights cast shadows while playing; shadow maps cost the browser most of
its time per 3D frame with software WebGL (about 5 vs 9 frames/s on the demo, 2 cores)."""


@dataclass
class PlaybackClock:
    """Which frame is due while playing (see the module docstring).

    Fields:
        fps: frame rate of the bout (Hz, > 0).
        n_frames: frames of the bout (>= 1); playback wraps to 0 after the last.
        clock: seconds of a monotonic clock (``time.monotonic``; tests pass a fake one).
    """

    fps: float
    n_frames: int
    clock: Callable[[], float] = time.monotonic
    _anchor: tuple[float, int, float] | None = field(default=None, repr=False)
    """(clock time, frame, speed) when the clock was (re)started; None while stopped."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"PlaybackClock.fps must be positive, got {self.fps}")
        if self.n_frames < 1:
            raise ValueError(f"PlaybackClock.n_frames must be >= 1, got {self.n_frames}")

    @property
    def running(self) -> bool:
        return self._anchor is not None

    @property
    def speed(self) -> float | None:
        """The playback speed factor (1.0 = real time) while running, else None."""
        return None if self._anchor is None else self._anchor[2]

    def start(self, frame: int, speed: float) -> None:
        """(Re)start at ``frame`` now, playing at ``speed`` times real time (> 0)."""
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"PlaybackClock.start: speed must be positive, got {speed}")
        self._anchor = (self.clock(), int(frame) % self.n_frames, float(speed))

    def stop(self) -> None:
        self._anchor = None

    def frame(self) -> int:
        """The frame due now (``ValueError`` when stopped)."""
        if self._anchor is None:
            raise ValueError("PlaybackClock.frame: the clock is stopped (call start first)")
        t0, f0, speed = self._anchor
        elapsed_s = max(0.0, self.clock() - t0)
        return (f0 + int(elapsed_s * self.fps * speed + 1e-9)) % self.n_frames
