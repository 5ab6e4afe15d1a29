"""What the annotate page shows of a session: camera frames as JPEG and the 2D detections of one
view at one frame, read from the artifacts (``webui.scene.session_data.load_session_data``) and
the videos (``webui.frames.FrameProvider``: the real frame, or the rendered stand-in for sessions
without videos).

Loaded sessions are cached per folder and reloaded when a stage re-runs (the manifests' times,
``artifacts_stamp``, or ``session.json`` change); encoded JPEGs are cached by
(folder, stamp, view, frame, width). Everything is thread-safe: FastAPI runs these sync
handlers in a thread pool. Errors are ``LookupError`` (unknown camera) and ``ValueError``
(frame outside the bout, unreadable session); ``server.api`` turns them into HTTP errors.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # webui and cv2 are imported when a page is first used, not with the server
    from webui.colors import IdentityPalette
    from webui.frames import FrameProvider
    from webui.scene.session_data import SessionData

SESSIONS_CACHED = 4
"""Sessions kept loaded at once (each holds its artifacts and decoders)."""
JPEGS_CACHED = 384
"""Encoded frames kept (about 50-150 kB each at 960-1280 px)."""
DECODED_FRAMES_CACHED = 8
"""Decoded RGB frames per (session, width): the JPEG cache is the one that matters."""
JPEG_QUALITY = 85
"""``cv2.IMWRITE_JPEG_QUALITY`` of the served frames (0-100)."""


@dataclass
class SessionView:
    """One loaded session as the annotate page reads it.

    Fields:
        folder: the session folder.
        stamp: manifests' times plus ``session.json``'s mtime (a change = reload).
        data: the artifacts (``SessionData``: rig, tracks, association, ...).
        n_frames: frames of the bout: the longest of the 2D input, the 3D results, the
            ``detect2d`` count and the shortest video.
        videos: view index -> video file, for the cameras a video backs (the others show
            the rendered stand-in).
        providers: ``FrameProvider`` per display width (px).
    """

    folder: Path
    stamp: tuple[float, ...]
    data: SessionData
    n_frames: int
    videos: dict[int, Path] = field(default_factory=dict)
    providers: dict[int, FrameProvider] = field(default_factory=dict)
    _spans: dict[int, dict[int, tuple[int, int]]] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def view_index(self, view: str) -> int:
        """Index of camera ``view``; ``LookupError`` naming the session's cameras otherwise."""
        names = self.data.rig.names
        if view not in names:
            raise LookupError(f"camera {view!r} is not in this session; its cameras are {list(names)}")
        return names.index(view)

    def check_frame(self, frame: int) -> None:
        if not 0 <= frame < self.n_frames:
            raise ValueError(f"frame {frame} is outside the bout: frames are 0..{self.n_frames - 1}")

    def provider(self, max_width: int) -> FrameProvider:
        from webui.frames import FrameProvider

        with self._lock:
            p = self.providers.get(max_width)
            if p is None:
                p = FrameProvider(self.data, max_width=max_width, cache_frames=DECODED_FRAMES_CACHED)
                self.providers[max_width] = p
            return p

    def track_spans(self, view: int) -> dict[int, tuple[int, int]]:
        """Track id -> (first, last) frame of that track in ``view`` (empty without tracks)."""
        with self._lock:
            hit = self._spans.get(view)
            if hit is None:
                hit = {}
                t = self.data.tracks
                if t is not None:
                    m = (t.view == view) & (t.track_id >= 0)
                    ids, frames = t.track_id[m].astype(np.int64), t.frame[m].astype(np.int64)
                    for tid in np.unique(ids):
                        f = frames[ids == tid]
                        hit[int(tid)] = (int(f.min()), int(f.max()))
                self._spans[view] = hit
            return hit

    def close(self) -> None:
        for p in self.providers.values():
            p.close()


def _stamp(folder: Path) -> tuple[float, ...]:
    from webui.scene.session_data import artifacts_stamp

    cfg = folder / "session.json"
    return (*artifacts_stamp(folder), cfg.stat().st_mtime if cfg.exists() else 0.0)


def _video_frames(videos: dict[int, Path]) -> int:
    """Frames of the shortest of ``videos`` (0 without videos or when none opens)."""
    import cv2

    counts = []
    for path in videos.values():
        cap = cv2.VideoCapture(str(path))
        try:
            if cap.isOpened():
                counts.append(int(cap.get(cv2.CAP_PROP_FRAME_COUNT)))
        finally:
            cap.release()
    return min(counts) if counts else 0


def _load(folder: Path, stamp: tuple[float, ...]) -> SessionView:
    from pipeline.runner.annotation_bounds import annotation_bounds
    from webui.frames import FrameProvider
    from webui.scene.session_data import load_session_data

    data = load_session_data(folder)
    videos = FrameProvider(data, cache_frames=1).videos  # the cameras the session takes from a video
    has_2d_or_3d = data.tracks is not None or bool(data.keypoints)
    counts = [data.n_frames if has_2d_or_3d else 0, annotation_bounds(folder).n_frames or 0, _video_frames(videos)]
    return SessionView(folder=folder, stamp=stamp, data=data, n_frames=max(1, max(counts)), videos=videos)


class AnnotateCache:
    """Loaded sessions (``SessionView``, LRU of ``SESSIONS_CACHED``) and encoded frames."""

    def __init__(self) -> None:
        self._views: OrderedDict[Path, SessionView] = OrderedDict()
        self._jpegs: OrderedDict[tuple[Any, ...], bytes] = OrderedDict()
        self._lock = threading.Lock()
        self._load_lock = threading.Lock()

    def view(self, folder: Path) -> SessionView:
        """The session at ``folder``, reloaded when its artifacts changed; ``ValueError`` when it
        cannot be read (no or malformed ``session.json``, a calibration that does not load)."""
        stamp = _stamp(folder)
        with self._lock:
            hit = self._views.get(folder)
            if hit is not None and hit.stamp == stamp:
                self._views.move_to_end(folder)
                return hit
        with self._load_lock:  # one load at a time: two requests for a new session load it once
            with self._lock:
                hit = self._views.get(folder)
                if hit is not None and hit.stamp == stamp:
                    return hit
            sv = _load(folder, stamp)
            with self._lock:
                old = self._views.pop(folder, None)
                self._views[folder] = sv
                while len(self._views) > SESSIONS_CACHED:
                    self._views.popitem(last=False)[1].close()
            if old is not None:
                old.close()
            return sv

    def jpeg(self, folder: Path, view: str, frame: int, max_width: int) -> bytes:
        """Frame ``frame`` of camera ``view`` at most ``max_width`` px wide, JPEG-encoded."""
        import cv2

        sv = self.view(folder)
        v = sv.view_index(view)
        sv.check_frame(frame)
        key = (folder, sv.stamp, v, frame, max_width)
        with self._lock:
            hit = self._jpegs.get(key)
            if hit is not None:
                self._jpegs.move_to_end(key)
                return hit
        rgb = sv.provider(max_width).frame(v, frame)
        ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            raise ValueError(f"camera {view!r} frame {frame}: JPEG encoding failed")
        out = buf.tobytes()
        with self._lock:
            self._jpegs[key] = out
            while len(self._jpegs) > JPEGS_CACHED:
                self._jpegs.popitem(last=False)
        return out

    def clear(self) -> None:
        with self._lock:
            views, self._views = list(self._views.values()), OrderedDict()
            self._jpegs.clear()
        for sv in views:
            sv.close()


def palette_for(data: SessionData, identities: list[tuple[int, str, str]]) -> IdentityPalette:
    """Identity names and colours as the viewer shows them: the session's athletes, then the
    server's identities ``(person_id, name, colour #rrggbb)`` (a malformed colour keeps the default)."""
    from webui.colors import Identity, IdentityPalette, default_identity, hex_to_rgb

    rows = []
    for pid, name, color in identities:
        try:
            hex_to_rgb(color)
        except ValueError:
            color = default_identity(pid).color_hex
        rows.append(Identity(pid, name or default_identity(pid).name, color))
    return IdentityPalette(rows, tuple(data.config.athletes))


def session_info(sv: SessionView, palette: IdentityPalette, named: list[int]) -> dict[str, Any]:
    """The page's static part: cameras (name, size px, whether a video backs it), frame count,
    fps, the persons edits may name (id, name, colour), joints and bones of the detections."""
    from pipeline.schema.joints import bone_indices

    data = sv.data
    t = data.tracks
    joints = t.joint_names if t is not None else ()
    pids = sorted(set(range(len(data.config.athletes))) | set(data.person_ids) | set(named))
    return {
        "name": data.config.name,
        "n_frames": sv.n_frames,
        "fps": data.fps,
        "cameras": [
            {"name": n, "width_px": int(data.rig.image_size_wh[i, 0]), "height_px": int(data.rig.image_size_wh[i, 1]),
             "video": i in sv.videos}
            for i, n in enumerate(data.rig.names)
        ],
        "persons": [{"id": p, "name": palette.name(p), "color": _hex(palette.rgb(p))} for p in pids],
        "joint_names": list(joints),
        "bones": [list(b) for b in bone_indices(joints)] if joints else [],
        "tracks": t is not None,
        "associated": data.association is not None,
    }


def _hex(rgb: tuple[int, int, int]) -> str:
    return "#{:02x}{:02x}{:02x}".format(*rgb)


def detections_at(sv: SessionView, view: str, frame: int, palette: IdentityPalette) -> dict[str, Any]:
    """The detections of camera ``view`` at ``frame`` after the last track and associate runs:
    per detection its track id (``-1`` = untracked), that track's first/last frame in the view,
    the person (``-1`` = nobody or not associated), name, colour, identity confidence (0-1,
    ``null`` before the associate stage), box (xyxy px) and keypoints (px of the full image,
    ``null`` where not valid), all in full-resolution pixels of the distorted image."""
    v = sv.view_index(view)
    sv.check_frame(frame)
    data = sv.data
    rows = data.det_rows(v, frame)
    t = data.tracks
    persons = data.person_of_rows(rows)
    conf = data.confidence_of_rows(rows) if data.association is not None else None
    spans = sv.track_spans(v)
    dets = []
    if t is not None:
        for k, r in enumerate(rows.tolist()):
            tid, pid = int(t.track_id[r]), int(persons[k])
            kp = t.keypoints_px[r]
            dets.append({
                "track": tid,
                "track_frames": list(spans.get(tid, (frame, frame))),
                "person": pid,
                "name": palette.name(pid),
                "color": _hex(palette.rgb(pid)),
                "confidence": None if conf is None else round(float(conf[k]), 4),
                "box_xyxy_px": [round(float(x), 2) for x in t.bbox_xyxy_px[r]],
                "keypoints_px": [[round(float(kp[j, 0]), 2), round(float(kp[j, 1]), 2)] if t.keypoint_valid[r, j] else None
                                 for j in range(kp.shape[0])],
            })  # fmt: skip
    return {"view": view, "frame": frame, "detections": dets}
