from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.io.video import iter_frames, video_info


def _write_video(path: Path, n: int = 6, w: int = 64, h: int = 48) -> None:
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (w, h))
    assert vw.isOpened()
    for i in range(n):
        img = np.full((h, w, 3), (20 * i) % 256, dtype=np.uint8)
        vw.write(img)
    vw.release()


def test_streams_frames_in_order(tmp_path: Path) -> None:
    p = tmp_path / "v.avi"
    _write_video(p)
    info = video_info(p)
    assert (info.width_px, info.height_px, info.n_frames) == (64, 48, 6)
    got = list(iter_frames(p, start=1, stop=5, step=2))
    assert [i for i, _ in got] == [1, 3]
    assert got[0][1].shape == (48, 64, 3)
    assert abs(float(got[1][1].mean()) - 60) < 6  # frame 3 is grey level 60


def test_missing_video_names_file(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="nope.mp4"):
        list(iter_frames(tmp_path / "nope.mp4"))


def test_corrupt_video_names_file(tmp_path: Path) -> None:
    p = tmp_path / "broken.mp4"
    p.write_bytes(b"\x00\x01 this is not a video" * 100)
    with pytest.raises(ValueError, match="broken.mp4"):
        video_info(p)
    with pytest.raises(ValueError, match="broken.mp4"):
        list(iter_frames(p))


def test_empty_video_names_file(tmp_path: Path) -> None:
    p = tmp_path / "empty.mp4"
    p.write_bytes(b"")
    with pytest.raises(ValueError, match="empty.mp4"):
        list(iter_frames(p))


def test_memory_stays_flat_with_video_length(tmp_path: Path) -> None:
    """Streaming: the peak of Python-tracked allocations while consuming a video does not
    grow with its length (a reader that buffered frames would grow 4x here)."""
    import tracemalloc

    def peak(n: int) -> int:
        p = tmp_path / f"v{n}.avi"
        _write_video(p, n=n, w=320, h=240)
        tracemalloc.start()
        total = 0.0
        for _, img in iter_frames(p):
            total += float(img[0, 0, 0])
        _, pk = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        return pk

    short, long = peak(20), peak(80)
    frame_bytes = 320 * 240 * 3
    assert long < short + 2 * frame_bytes
