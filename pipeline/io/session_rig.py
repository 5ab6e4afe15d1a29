"""A session's camera rig at the session's frame rate.

Which rate, in order:

1. ``session.fps`` when set (> 0);
2. the calibration's own, when the file stores one (cornerman/Pose2Sim TOML with
   ``[metadata] fps``);
3. the videos' (``source="video"``), when every video reports a rate and they agree
   within 1 % (Qualisys, EasyMocap and JSON calibrations do not store a frame rate);
4. the calibration loader's default, 30 fps.

Which cameras: the calibration's, or the subset ``session.cameras`` lists (in that order).

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

MIN_VIEWS_3D = 2
"""Cameras a 3D reconstruction needs (association and triangulation match views)."""


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
    for p in cfg.camera_inputs().values():
        path = Path(p) if Path(p).is_absolute() else session_dir / p
        try:
            st = path.stat()
            rates.append(_video_fps(str(path), st.st_mtime_ns, st.st_size))
        except (OSError, ValueError):
            return None  # detect2d reports the missing or unreadable video
    if not rates or min(rates) <= 0 or max(rates) - min(rates) > 0.01 * max(rates):
        return None
    return float(sorted(rates)[len(rates) // 2])


def select_cameras(rig: CameraRig, cameras: tuple[str, ...], where: str) -> CameraRig:
    """``rig`` restricted to ``cameras`` (in that order; ``()`` = all). ``ValueError`` naming
    ``where`` (the calibration) and listing its cameras when a name is not in it."""
    if not cameras:
        return rig
    unknown = [c for c in cameras if c not in rig.names]
    if unknown:
        raise ValueError(
            f"cameras {unknown} (--cameras / session.json \"cameras\") are not in the calibration {where}, "
            f"which has {list(rig.names)}"
        )
    return rig.subset([rig.names.index(c) for c in cameras])


def check_multiview(rig: CameraRig, where: str) -> None:
    """``ValueError`` unless ``rig`` has at least ``MIN_VIEWS_3D`` cameras; ``where`` names the
    calibration file."""
    if rig.n_views < MIN_VIEWS_3D:
        raise ValueError(
            f"{where}: the session uses {rig.n_views} camera ({', '.join(rig.names)}); a 3D reconstruction needs "
            f">= {MIN_VIEWS_3D} views: use a calibration with more cameras, or list at least {MIN_VIEWS_3D} of "
            'them with --cameras (session.json "cameras")'
        )


def calibration_path(session_dir: Path, cfg: SessionConfig) -> Path:
    """The session's calibration file or folder (``session.json`` paths are relative to the session)."""
    calib = Path(cfg.calibration)
    return calib if calib.is_absolute() else session_dir / calib


def session_fps(session_dir: Path, cfg: SessionConfig, rig_fps: float) -> tuple[float, str]:
    """The session's frame rate in Hz and where it comes from (``"session.json fps"``,
    ``"calibration"``, ``"videos"`` or ``"calibration default"``), by the module docstring's rule.
    ``rig_fps`` is the rate the calibration loader gave."""
    if cfg.fps > 0:
        return float(cfg.fps), "session.json fps"
    if stored_fps(calibration_path(session_dir, cfg)) is not None:
        return rig_fps, "calibration"
    fps = videos_fps(session_dir, cfg)
    if fps is not None:
        return fps, "videos"
    return rig_fps, "calibration default"


def session_rig(session_dir: Path, cfg: SessionConfig) -> CameraRig:
    """The session's calibration with its ``cameras`` and the frame rate chosen as the module
    docstring says.

    Raises ``ValueError`` naming the calibration file when it cannot be read or lacks a
    camera of ``cameras``."""
    path = calibration_path(session_dir, cfg)
    rig = select_cameras(load_calibration(path), cfg.cameras, str(path))
    fps, source = session_fps(session_dir, cfg, rig.fps)
    if abs(fps - rig.fps) <= 1e-6 * fps:
        return rig
    if source == "videos":
        log.info("%s stores no frame rate: using the videos' %.4g fps", path, fps)
    return with_fps(rig, fps)
