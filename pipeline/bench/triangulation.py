"""``cornerman bench triangulation``: association + triangulation + filtering on the synthetic bout.

Scenarios: the built-in bout (bystander and per-view id swaps included) with 2, 3, 4 and 6
cameras at the default noise, and 4 cameras with 2x noise, 20 % missed detections and the
bystander. For each scenario three methods run side by side on the same input:

- ``cornerman``: ``associate`` + ``triangulate`` (weighted DLT, outlier views, filtering);
  ``fps`` covers all three steps (``fps (CPU)`` the same from this process's CPU time,
  which a busy shared machine disturbs less), ``tri+filt fps`` triangulation + filtering,
  ``tri fps`` the triangulation alone (undistortion, weighted DLT, outlier views).
- ``plain DLT``: per-frame, unweighted DLT of every joint seen in >= 2 views, no outlier
  rejection, no filtering, on cornerman's association (identity columns are therefore
  the same); ``tri fps`` is its triangulation speed.
- ``aniposelib``: ``CameraGroup.triangulate`` (aniposelib's DLT, jax-jitted, timed on a
  second, warm call) on the same associated 2D points, where aniposelib is installed.

PCP / MPJPE are computed against ground truth on the two boxers; ``id acc`` is the
fraction of detections (bystander's included: they must get -1) with the right identity;
``stolen`` counts bystander detections given an athlete id; ``swap err`` counts wrong
identities at or after a per-view id swap in the swapped view.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from pipeline.evaluate.metrics import identity_accuracy, mpjpe, pcp
from pipeline.geometry.dlt import triangulate_weighted
from pipeline.schema.association import Association
from pipeline.schema.camera import CameraRig
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D

log = logging.getLogger(__name__)

SCENARIOS: dict[str, dict[str, Any]] = {
    "2 cams": {"n_cameras": 2},
    "3 cams": {"n_cameras": 3},
    "4 cams": {"n_cameras": 4},
    "6 cams": {"n_cameras": 6},
    "4 cams hard": {"n_cameras": 4, "noise_scale": 2.0, "miss_rate": 0.2, "bystander": True},
}


def _make(name: str, n_frames: int, seed: int) -> Any:
    from pipeline.synthetic.bout import make_bout
    from pipeline.synthetic.config import SyntheticConfig

    kw = dict(SCENARIOS[name])
    scale = kw.pop("noise_scale", 1.0)
    kw["noise_px"] = SyntheticConfig().noise_px * scale
    return make_bout(SyntheticConfig(seed=seed, n_frames=n_frames, **kw))


def _id_scores(pod: np.ndarray, bout: Any) -> dict[str, float]:
    gt = bout.gt_person_of_det
    acc = identity_accuracy(pod, gt)
    stolen = int(np.sum((gt < 0) & (pod >= 0)))
    # Map estimated ids to true ids by majority before counting swap errors.
    lut = {}
    for e in np.unique(pod[pod >= 0]):
        vals = gt[(pod == e) & (gt >= 0)]
        lut[int(e)] = int(np.bincount(vals).argmax()) if vals.size else -1
    mapped = np.array([lut.get(int(p), -1) for p in pod]) if pod.size else pod
    swap_err = 0
    for v, f in np.asarray(bout.swap_frames).reshape(-1, 2):
        sel = (bout.tracks.view == v) & (bout.tracks.frame >= f) & (gt >= 0)
        swap_err += int(np.sum(mapped[sel] != gt[sel]))
    return {"id_acc_pct": 100.0 * acc, "stolen": stolen, "swap_err": swap_err}


def _pose_scores(est: Keypoints3D, gt: Keypoints3D) -> dict[str, float]:
    return {"pcp_pct": 100.0 * pcp(est, gt), "mpjpe_mm": mpjpe(est, gt)}


def _dense_pixels(tracks: Tracks2D, assoc: Association, rig: CameraRig) -> tuple[np.ndarray, np.ndarray]:
    """(frames, persons, joints, views, 2) distorted pixels and a validity mask (one det per slot)."""
    from pipeline.stages.triangulate import gather

    _, conf, _ = gather(tracks, assoc, rig, 0.0)
    F, P, J, V = conf.shape
    uv = np.full((F, P, J, V, 2), np.nan)
    lut = {int(p): i for i, p in enumerate(assoc.person_ids)}
    rows = np.flatnonzero(assoc.person_of_det >= 0)
    pi = np.array([lut[int(p)] for p in assoc.person_of_det[rows]], np.int64)
    f, v = tracks.frame[rows], tracks.view[rows]
    kp = np.where(tracks.keypoint_valid[rows][..., None], tracks.keypoints_px[rows], np.nan)
    uv[f, pi, :, v] = kp
    ok = conf > 0
    return np.where(ok[..., None], uv, np.nan), ok


def _keypoints(X: np.ndarray, ok: np.ndarray, like: Keypoints3D) -> Keypoints3D:
    return like.replace(
        xyz_m=np.where(ok[..., None], X, 0.0),
        valid=ok,
        confidence=ok.astype(float),
        n_views=np.zeros(ok.shape, np.int64),
        reproj_err_px=np.full(ok.shape, np.nan),
        source="raw",
    )


def _plain_dlt(tracks: Tracks2D, assoc: Association, rig: CameraRig, like: Keypoints3D) -> tuple[Keypoints3D, float]:
    from pipeline.geometry.projection import undistort_points

    uv, ok = _dense_pixels(tracks, assoc, rig)
    t0 = time.perf_counter()
    und = np.empty_like(uv)
    for v in range(rig.n_views):
        und[..., v, :] = undistort_points(np.nan_to_num(uv[..., v, :]), rig.K[v], rig.dist[v])
    X = np.zeros(uv.shape[:3] + (3,))
    good = np.zeros(uv.shape[:3], bool)
    P = rig.P
    for f in range(uv.shape[0]):  # per frame, like the classic tools
        X[f], good[f] = triangulate_weighted(P, und[f], ok[f].astype(float), method="svd")
    dt = time.perf_counter() - t0
    return _keypoints(X, good, like), dt


def _aniposelib(
    tracks: Tracks2D, assoc: Association, rig: CameraRig, like: Keypoints3D, repeats: int
) -> tuple[Keypoints3D, float] | None:
    try:
        from aniposelib.cameras import Camera, CameraGroup
    except ImportError:
        return None
    from pipeline.geometry.rotations import rodrigues_from_R

    T = rig.T_cam_world
    cams = [
        Camera(
            matrix=rig.K[v], dist=rig.dist[v], size=tuple(int(s) for s in rig.image_size_wh[v]),
            rvec=rodrigues_from_R(T[v, :3, :3]), tvec=T[v, :3, 3], name=rig.names[v],
        )
        for v in range(rig.n_views)
    ]
    group = CameraGroup(cams)
    uv, ok = _dense_pixels(tracks, assoc, rig)
    F, P, J, V, _ = uv.shape
    pts = np.moveaxis(uv, 3, 0).reshape(V, -1, 2)
    group.triangulate(pts[:, : min(64, pts.shape[1])], undistort=True)  # jit warm-up
    group.triangulate(pts, undistort=True)  # first full-size call compiles this shape
    dt = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        X = np.asarray(group.triangulate(pts, undistort=True)).reshape(F, P, J, 3)
        dt = min(dt, time.perf_counter() - t0)
    good = (ok.sum(axis=-1) >= 2) & np.all(np.isfinite(X), axis=-1)
    return _keypoints(np.nan_to_num(X), good, like), dt


def run_bench(
    n_frames: int = 300, seed: int = 0, scenarios: str = "", baselines: bool = True, repeats: int = 3
) -> list[dict]:
    """Rows: one per (scenario, method). ``scenarios``: comma-separated subset of ``SCENARIOS``.

    Timings are wall-clock, the best of ``repeats`` runs of each method (the machine may be
    shared; every method gets the same treatment).
    """
    from pipeline.stages.associate import AssociateConfig
    from pipeline.stages.associate import run as run_associate
    from pipeline.stages.filtering import FilterConfig
    from pipeline.stages.joint_fill import FillConfig
    from pipeline.stages.triangulate import TriangulateConfig
    from pipeline.stages.triangulate import run as run_triangulate

    names = [s.strip() for s in scenarios.split(",") if s.strip()] or list(SCENARIOS)
    unknown = [n for n in names if n not in SCENARIOS]
    if unknown:
        raise ValueError(f"unknown scenarios {unknown}; choose from {list(SCENARIOS)}")
    rows: list[dict] = []
    for name in names:
        bout = _make(name, int(n_frames), int(seed))
        tracks, rig = bout.tracks, bout.rig
        F = tracks.n_frames
        best_a = best_t = best_d = best_cpu = np.inf
        no_filter = TriangulateConfig(filter=FilterConfig(enabled=False), fill=FillConfig(enabled=False))
        for _ in range(max(1, int(repeats))):
            c0, t0 = time.process_time(), time.perf_counter()
            assoc = run_associate(tracks, rig, AssociateConfig(n_persons=2))
            t1 = time.perf_counter()
            raw, filtered = run_triangulate(tracks, assoc, rig, TriangulateConfig())
            t2, c2 = time.perf_counter(), time.process_time()
            run_triangulate(tracks, assoc, rig, no_filter)
            t3 = time.perf_counter()
            best_a, best_t, best_d = min(best_a, t1 - t0), min(best_t, t2 - t1), min(best_d, t3 - t2)
            best_cpu = min(best_cpu, c2 - c0)
        ids = _id_scores(assoc.person_of_det, bout)
        base = {"scenario": name, "cameras": rig.n_views, "frames": F}
        rows.append(
            {**base, "method": "cornerman", **_pose_scores(filtered, bout.gt), **ids,
             "fps": F / (best_a + best_t), "fps_cpu": F / best_cpu, "tri_filter_fps": F / best_t, "tri_fps": F / best_d}
        )
        if not baselines:
            continue
        est, dt = _plain_dlt(tracks, assoc, rig, raw)
        for _ in range(max(1, int(repeats)) - 1):
            dt = min(dt, _plain_dlt(tracks, assoc, rig, raw)[1])
        rows.append({**base, "method": "plain DLT", **_pose_scores(est, bout.gt), **ids, "tri_fps": F / dt})
        res = _aniposelib(tracks, assoc, rig, raw, max(1, int(repeats)))
        if res is not None:
            est, dt = res
            rows.append({**base, "method": "aniposelib", **_pose_scores(est, bout.gt), **ids, "tri_fps": F / dt})
        log.info("bench triangulation: %s done", name)
    return rows


def print_table(rows: list[dict]) -> None:
    from rich.console import Console
    from rich.table import Table

    cols = [
        ("scenario", "scenario", "{}"),
        ("method", "method", "{}"),
        ("pcp_pct", "PCP %", "{:.2f}"),
        ("mpjpe_mm", "MPJPE mm", "{:.1f}"),
        ("id_acc_pct", "id acc %", "{:.2f}"),
        ("stolen", "stolen", "{:d}"),
        ("swap_err", "swap err", "{:d}"),
        ("fps", "fps all", "{:.0f}"),
        ("fps_cpu", "fps all (CPU)", "{:.0f}"),
        ("tri_filter_fps", "tri+filt fps", "{:.0f}"),
        ("tri_fps", "tri fps", "{:.0f}"),
    ]
    table = Table(title="bench triangulation: synthetic bout, 2 boxers (fps all = associate + triangulate + filter)")
    for _, title, _ in cols:
        table.add_column(title, justify="right")
    for r in rows:
        table.add_row(*[fmt.format(r[k]) if k in r and r[k] == r[k] else "" for k, _, fmt in cols])
    Console(width=max(Console().width, 130)).print(table)
