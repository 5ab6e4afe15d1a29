"""Streaming video reader: frames come one at a time, never all in memory.

``cv2`` is a light dependency here (OpenCV is already used for calibration and
undistortion), so this lives in ``io`` rather than ``backends``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm")
"""File endings taken as videos when a folder of videos is read (case-insensitive)."""


@dataclass(frozen=True)
class VideoInfo:
    """Header information of a video file.

    Fields:
        path: the file.
        n_frames: frame count reported by the container (may be approximate for some codecs).
        fps: frames per second reported by the container.
        width_px, height_px: frame size in pixels.
    """

    path: Path
    n_frames: int
    fps: float
    width_px: int
    height_px: int


def videos_in(folder: Path) -> dict[str, str]:
    """Camera name (the file's stem) -> path (``folder / name``) of each video directly in
    ``folder`` (``VIDEO_SUFFIXES``), sorted by name; ``{}`` when it holds none."""
    files = sorted(p for p in Path(folder).iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES)
    return {p.stem: str(p) for p in files}


def _open(path: Path) -> cv2.VideoCapture:
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"video file not found: {path}")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise ValueError(f"cannot open video (corrupt or unsupported codec): {path}")
    return cap


def video_info(path: Path) -> VideoInfo:
    """Header information; ``ValueError`` naming the file if it is missing, corrupt or empty."""
    cap = _open(path)
    try:
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        ok, _ = cap.read()
    finally:
        cap.release()
    if not ok or w <= 0 or h <= 0:
        raise ValueError(f"video has no decodable frames (empty or corrupt): {path}")
    return VideoInfo(path=Path(path), n_frames=max(n, 1), fps=fps, width_px=w, height_px=h)


def iter_frames(
    path: Path, start: int = 0, stop: int | None = None, step: int = 1
) -> Iterator[tuple[int, np.ndarray]]:
    """Yield ``(frame_index, image)`` with ``image`` a (H, W, 3) uint8 BGR array.

    Frames are decoded sequentially (seeking is unreliable across codecs); frames
    before ``start`` and between steps are grabbed without being decoded to RGB.
    Raises ``ValueError`` naming the file if it is missing, cannot be opened, or
    yields no frame at all in the requested range.
    """
    if start < 0 or step < 1 or (stop is not None and stop < start):
        raise ValueError(f"{path}: invalid frame range start={start} stop={stop} step={step}")
    cap = _open(path)
    n_yielded = 0
    try:
        i = 0
        while stop is None or i < stop:
            if i < start or (i - start) % step:
                if not cap.grab():
                    break
                i += 1
                continue
            ok, img = cap.read()
            if not ok or img is None:
                break
            yield i, img
            n_yielded += 1
            i += 1
    finally:
        cap.release()
    if n_yielded == 0 and (stop is None or stop > start):
        raise ValueError(f"video yielded no frames in [{start}, {stop}) (empty or corrupt): {path}")
