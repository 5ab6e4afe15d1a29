"""Video 2D stage benchmark: detector and keypoint model speed per camera, and the
end-to-end time of the 4 × 100-frame Pose2Sim multi-person demo.

Needs ``CORNERMAN_MODELS_DIR`` (or models in the cache) and
``CORNERMAN_TEST_DATA_DIR/pose2sim_multiperson``.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

COMBOS: tuple[tuple[str, str], ...] = (
    ("rtmdet_nano", "blazepose_full"),
    ("yolox_nano", "blazepose_full"),
    ("rtmdet_nano", "movenet_lightning"),
    ("yolox_nano", "movenet_lightning"),
)


def _data_dir(data_dir: str | None) -> Path:
    if data_dir:
        if not (Path(data_dir) / "pose2sim_multiperson").is_dir():
            raise ValueError(f"pose2sim_multiperson data not found under {data_dir!r}")
        return Path(data_dir) / "pose2sim_multiperson"
    from pipeline.shared import dataset_dir

    return dataset_dir("pose2sim_multiperson")


def _speed_rows(data: Path, frames: int, num_threads: int, models_dir: str | None) -> list[dict[str, Any]]:
    from pipeline.io.video import iter_frames
    from pipeline.stages.detect2d import Detect2DConfig, Models, detect_boxes

    cams = sorted(p.stem for p in (data / "videos").glob("*.mp4"))
    images = {c: [im for _, im in iter_frames(data / "videos" / f"{c}.mp4", 0, frames)] for c in cams}
    rows = []
    for det, pose in COMBOS:
        cfg = Detect2DConfig(detector=det, pose_model=pose, num_threads=num_threads, models_dir=models_dir)  # type: ignore[arg-type]
        models = Models(cfg)
        models.detector.detect(images[cams[0]][:1])  # warm-up
        t_det = t_kp = 0.0
        n_frames = n_people = 0
        for cam in cams:
            ims = images[cam]
            t0 = time.perf_counter()
            boxes = []
            for s in range(0, len(ims), cfg.batch_size):
                boxes += detect_boxes(ims[s : s + cfg.batch_size], models, cfg)
            t_det += time.perf_counter() - t0
            t0 = time.perf_counter()
            for im, (b, _) in zip(ims, boxes, strict=True):
                models.pose.estimate(im, b)
            t_kp += time.perf_counter() - t0
            n_frames += len(ims)
            n_people += sum(len(b) for b, _ in boxes)
        rows.append(
            {
                "kind": "speed",
                "detector": det,
                "pose_model": pose,
                "frames": n_frames,
                "people_per_frame": round(n_people / n_frames, 2),
                "det_fps": round(n_frames / t_det, 1),
                "keypoints_fps": round(n_frames / t_kp, 1),
                "keypoints_per_person_ms": round(1000 * t_kp / max(n_people, 1), 1),
                "total_fps": round(n_frames / (t_det + t_kp), 1),
            }
        )
    return rows


def _e2e_row(data: Path, num_threads: int, models_dir: str | None) -> dict[str, Any]:
    from pipeline.evaluate.metrics import reprojection_error
    from pipeline.io.calibration import load_calibration
    from pipeline.stages import associate, triangulate
    from pipeline.stages.association.config import AssociateConfig
    from pipeline.stages.detect2d import Detect2DConfig, run_videos
    from pipeline.stages.track import run as run_tracker
    from pipeline.stages.triangulate import TriangulateConfig

    rig = load_calibration(data / "calibration" / "Calib.qca.txt")
    rig = dataclasses.replace(rig, fps=60.0)  # the videos are 60 fps (the .qca says 30)
    cfg = Detect2DConfig(num_threads=num_threads, models_dir=models_dir)
    t0 = time.perf_counter()
    dets = run_videos({n: data / "videos" / f"{n}.mp4" for n in rig.names}, rig, None, cfg)
    t1 = time.perf_counter()
    tracks = run_tracker(dets, rig)
    assoc = associate.run(tracks, rig, AssociateConfig(n_persons=2), [])
    raw, filt = triangulate.run(tracks, assoc, rig, TriangulateConfig())
    t2 = time.perf_counter()
    err = reprojection_error(raw, tracks, assoc, rig)
    err_f = reprojection_error(filt, tracks, assoc, rig)
    return {
        "kind": "e2e",
        "detector": cfg.detector,
        "pose_model": cfg.pose_model,
        "frames": int(dets.n_frames * dets.n_views),
        "people_per_frame": round(dets.n_dets / max(1, dets.n_frames * dets.n_views), 2),
        "detect2d_s": round(t1 - t0, 1),
        "track_assoc_tri_s": round(t2 - t1, 2),
        "e2e_s": round(t2 - t0, 1),
        "persons": int(raw.n_persons),
        "median_reproj_px": round(float(np.nanmedian(err)), 1),
        "median_reproj_filtered_px": round(float(np.nanmedian(err_f)), 1),
    }


def run_bench(
    frames: int = 20,
    num_threads: int = 0,
    e2e: bool = True,
    data_dir: str | None = None,
    models_dir: str | None = None,
) -> list[dict[str, Any]]:
    """Rows: per (detector, keypoint model) frames/s per camera over ``frames`` frames of
    each camera (``kind="speed"``), then one end-to-end row (``kind="e2e"``: default
    models, 4 × 100 frames, detect2d → track → associate → triangulate)."""
    data = _data_dir(data_dir)
    rows = _speed_rows(data, int(frames), int(num_threads), models_dir)
    if e2e:
        rows.append(_e2e_row(data, int(num_threads), models_dir))
    return rows


def print_table(rows: list[dict[str, Any]]) -> None:
    """Two tables: model speeds (frames/s per camera, averaged over the cameras) and the e2e run."""
    console = Console()
    for kind, title in (
        ("speed", "video 2D models, frames/s per camera (CPU, onnxruntime)"),
        ("e2e", "pose2sim_multiperson end to end (4 cameras x 100 frames)"),
    ):
        sel = [r for r in rows if r.get("kind") == kind]
        if not sel:
            continue
        cols = [k for k in sel[0] if k != "kind"]
        t = Table(title=title)
        for c in cols:
            t.add_column(c)
        for r in sel:
            t.add_row(*(str(r.get(c, "")) for c in cols))
        console.print(t)
