"""The session description: ``<session>/session.json``.

A session is one bout: a folder with ``session.json``, an ``inputs/`` folder, the
optional ``annotations.json`` overlay and the ``artifacts/`` written by the runner.
All paths inside ``session.json`` are relative to the session folder (absolute
paths are accepted for server-side folders).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

SourceKind = Literal["video", "keypoints", "tracks"]
KeypointFormat = Literal["openpose", "coco"]


@dataclass(frozen=True)
class SessionConfig:
    """What a session holds and how to run it.

    Fields:
        name: human-readable bout name.
        source: ``"video"`` (videos -> detect2d runs the ONNX models),
            ``"keypoints"`` (2D keypoint files: OpenPose or COCO JSON) or
            ``"tracks"`` (a ``Tracks2D`` npz, as the synthetic bout provides).
        calibration: calibration file (TOML, Qualisys .qca.txt, EasyMocap
            intri/extri folder, or Campus/Shelf JSON).
        videos: camera name -> video file (``source="video"``).
        keypoints: camera name -> folder or file of 2D keypoints (``source="keypoints"``).
        keypoint_format: format of ``keypoints``.
        tracks: path of a ``Tracks2D`` npz (``source="tracks"``).
        ground_truth: optional ``Keypoints3D`` npz (``source="gt"``) for evaluation.
        ground_truth_labels: optional npz of per-detection true person ids
            (``person_of_det``, aligned with the input tracks) and foot contacts
            (``foot_contact``: frames x persons x 2 bool), for evaluation.
        fps: frame rate; overrides the calibration's when set (> 0).
        cameras: the calibration's cameras this session uses, in this order (``()`` = all of
            them; at least 2 otherwise, since a 3D reconstruction needs two views). Inputs of
            the other cameras are kept in ``videos``/``keypoints`` but not read.
        athletes: display names of the athletes, by global person id order; with the default
            ``stage_config.associate.n_persons = "athletes"`` their number is the person count.
        stage_config: per-stage config overrides, ``{"triangulate": {"min_views": 2}}``.
        stages: stages to run (default: every stage the runner knows).
        auto_rerun: when an annotation is written, re-run the stale stages.
        rounds_s: ``[[start, end], ...]`` of each round, seconds from the bout's first frame
            (0 <= start < end, in order, not overlapping); empty = not known.
        ring_xy_m: the ring's corners ``[[x, y], ...]`` in the floor world (``calibrate/world.json``;
            the calibration's own when it was level), metres, in order around the ring (>= 3);
            empty = not known.
    """

    name: str
    source: SourceKind
    calibration: str
    videos: dict[str, str] = field(default_factory=dict)
    keypoints: dict[str, str] = field(default_factory=dict)
    keypoint_format: KeypointFormat = "openpose"
    tracks: str = ""
    ground_truth: str = ""
    ground_truth_labels: str = ""
    fps: float = 0.0
    cameras: tuple[str, ...] = ()
    athletes: tuple[str, ...] = ("Red", "Blue")
    stage_config: dict[str, dict[str, Any]] = field(default_factory=dict)
    stages: tuple[str, ...] = ()
    auto_rerun: bool = True
    rounds_s: tuple[tuple[float, float], ...] = ()
    ring_xy_m: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        if self.source not in ("video", "keypoints", "tracks"):
            raise ValueError(f"session.source must be video/keypoints/tracks, got {self.source!r}")
        if not self.calibration:
            raise ValueError("session.calibration is required")
        if self.source == "video" and not self.videos:
            raise ValueError("session.source='video' needs a non-empty 'videos' mapping")
        if self.source == "keypoints" and not self.keypoints:
            raise ValueError("session.source='keypoints' needs a non-empty 'keypoints' mapping")
        if self.source == "tracks" and not self.tracks:
            raise ValueError("session.source='tracks' needs 'tracks' (a Tracks2D npz)")
        if self.keypoint_format not in ("openpose", "coco"):
            raise ValueError(f"session.keypoint_format must be openpose/coco, got {self.keypoint_format!r}")
        if self.fps < 0:
            raise ValueError(f"session.fps must be >= 0, got {self.fps}")
        if any(not isinstance(c, str) or not c for c in self.cameras):
            raise ValueError(f"session.cameras must be camera names, got {list(self.cameras)}")
        dup = sorted({c for c in self.cameras if self.cameras.count(c) > 1})
        if dup:
            raise ValueError(f"session.cameras lists {dup} more than once")
        if len(self.cameras) == 1:
            raise ValueError(
                f"session.cameras (--cameras) lists one camera {list(self.cameras)}; a 3D reconstruction needs >= 2 views "
                "(list at least two, or none for every calibrated camera)"
            )
        last_end = 0.0
        for r in self.rounds_s:
            if len(r) != 2 or not 0.0 <= r[0] < r[1] or r[0] < last_end:
                raise ValueError(
                    f"session.rounds_s must be [[start, end], ...] seconds, 0 <= start < end, in order and not "
                    f"overlapping; got {[list(x) for x in self.rounds_s]}"
                )
            last_end = r[1]
        if self.ring_xy_m and (len(self.ring_xy_m) < 3 or any(len(c) != 2 for c in self.ring_xy_m)):
            raise ValueError(
                f"session.ring_xy_m must be >= 3 corners [[x, y], ...] in metres; got {[list(c) for c in self.ring_xy_m]}"
            )
        if not isinstance(self.stage_config, dict):
            raise ValueError(
                "session.stage_config must be an object of per-stage settings "
                f'({{"triangulate": {{"min_views": 2}}}}), got {type(self.stage_config).__name__}'
            )

    def camera_inputs(self) -> dict[str, str]:
        """Camera name -> input path of the ``videos`` or ``keypoints`` source, restricted to
        ``cameras`` when set (``{}`` for ``source="tracks"``)."""
        inputs = (
            self.videos if self.source == "video" else self.keypoints if self.source == "keypoints" else {}
        )
        return {c: p for c, p in inputs.items() if not self.cameras or c in self.cameras}

    def to_json(self) -> str:
        d = asdict(self)
        d["athletes"] = list(self.athletes)
        d["cameras"] = list(self.cameras)
        d["stages"] = list(self.stages)
        return json.dumps(d, indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "session.json") -> SessionConfig:
        if not isinstance(d, dict):
            raise ValueError(f"{where}: expected a JSON object")
        known = set(cls.__dataclass_fields__)
        extra = set(d) - known
        if extra:
            raise ValueError(f"{where}: unknown keys {sorted(extra)}; known: {sorted(known)}")
        kw = dict(d)
        for k in ("athletes", "cameras", "stages"):
            if k in kw:
                if not isinstance(kw[k], list | tuple):
                    raise ValueError(f"{where}: {k!r} must be a list, got {type(kw[k]).__name__}")
                kw[k] = tuple(kw[k])
        for k in ("rounds_s", "ring_xy_m"):
            if k in kw:
                pairs = kw[k]
                if not isinstance(pairs, list | tuple) or not all(
                    isinstance(p, list | tuple) and all(isinstance(v, int | float) for v in p) for p in pairs
                ):
                    raise ValueError(f"{where}: {k!r} must be a list of number pairs, got {pairs!r}")
                kw[k] = tuple(tuple(float(v) for v in p) for p in pairs)
        try:
            return cls(**kw)
        except TypeError as e:
            raise ValueError(f"{where}: {e}") from e
        except ValueError as e:
            raise ValueError(f"{where}: {e}") from e

    @classmethod
    def load(cls, session_dir: Path) -> SessionConfig:
        path = Path(session_dir) / "session.json"
        if not path.exists():
            raise ValueError(f"{path}: no session.json (is {session_dir} a cornerman session folder?)")
        try:
            d = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise ValueError(f"{path}: malformed JSON: {e}") from e
        return cls.from_dict(d, where=str(path))

    def save(self, session_dir: Path) -> None:
        path = Path(session_dir) / "session.json"
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(self.to_json())
        tmp.replace(path)
