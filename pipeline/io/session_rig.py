"""A session's camera rig at the session's frame rate.

Which rate, in order:

1. ``session.fps`` when set (> 0);
2. the calibration's own, when the file stores one (cornerman/Pose2Sim TOML with
   ``[metadata] fps``);
3. the videos' (``source="video"``), when every video reports a rate and they agree
   within 1 % (Qualisys, EasyMocap and JSON calibrations do not store a frame rate);
4. the calibration loader's default, 30 fps.

The pipeline, the server and the viewer all resolve the rig here, so they agree.
"""

from __future__ import annotations

import logging
import tomllib
from functools import lru_cache
from pathlib import Path

from pipeline.io.calibration import calibration_format, load_calibration
from pipeline.io.calibration_common import with_fps
from pipeline.schema.camera import CameraRig
from pipeline.schema.session import SessionConfig

log = logging.getLogger(__name__)


def stored_fps(path: Path) -> float | None:
    """The frame rate stored in a calibration file, or None if its format has none."""
    if calibration_format(path) != "toml":
        return None
    try:
        meta = tomllib.loads(path.read_text(encoding="utf-8")).get("metadata")
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None  # load_calibration reports the unreadable file
    fps = meta.get("fps") if isinstance(meta, dict) else None
    return float(fps) if isinstance(fps, int | float) and not isinstance(fps, bool) and fps > 0 else None


@lru_cache(maxsize=256)
def _video_fps(path: str, mtime_ns: int, size: int) -> float:
    """A video's reported rate; cached per file version, since every stage's fingerprint
    resolves the rig (opening a video and decoding a frame takes ~60 ms)."""
    from pipeline.io.video import video_info

    return video_info(Path(path)).fps


def videos_fps(session_dir: Path, cfg: SessionConfig) -> float | None:
    """The frame rate all of a video session's videos report (within 1 %), or None."""
    if cfg.source != "video" or not cfg.videos:
        return None
    rates = []
    for p in cfg.videos.values():
        path = Path(p) if Path(p).is_absolute() else session_dir / p
        try:
            st = path.stat()
            rates.append(_video_fps(str(path), st.st_mtime_ns, st.st_size))
        except (OSError, ValueError):
            return None  # detect2d reports the missing or unreadable video
    if not rates or min(rates) <= 0 or max(rates) - min(rates) > 0.01 * max(rates):
        return None
    return float(sorted(rates)[len(rates) // 2])


def session_rig(session_dir: Path, cfg: SessionConfig) -> CameraRig:
    """The session's calibration with the frame rate chosen as the module docstring says.

    Raises ``ValueError`` naming the calibration file when it cannot be read."""
    calib = Path(cfg.calibration)
    path = calib if calib.is_absolute() else session_dir / calib
    rig = load_calibration(path)
    if cfg.fps > 0:
        return rig if cfg.fps == rig.fps else with_fps(rig, float(cfg.fps))
    if stored_fps(path) is not None:
        return rig
    fps = videos_fps(session_dir, cfg)
    if fps is not None and abs(fps - rig.fps) > 1e-6 * fps:
        log.info("%s stores no frame rate: using the videos' %.4g fps", path, fps)
        return with_fps(rig, fps)
    return rig
