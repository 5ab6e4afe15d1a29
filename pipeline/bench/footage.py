"""``cornerman bench footage``: consistency of every stage on real video, without ground truth.

The Pose2Sim multi-person sample (4 portrait cameras, 100 frames at 60 fps, two performers
and bystanders; ``pipeline.shared.dataset_dir("pose2sim_multiperson")``) is set up as a
user would with ``cornerman new --calibration … --video camNN=…`` and run by the runner,
in ``work_dir``. The folder is kept: a second run re-runs only the stages that went stale
(a changed ``stage_config``, a code change), and ``fresh=True`` starts over.

One row per 3D output (raw and filtered triangulation, fit, physics), scored by
``pipeline.evaluate.consistency`` against the session's own 2D tracks and association:
reprojection error in every view (per camera and pooled), coverage, bone-length std,
inter-person overlap, foot skating, acceleration; the physics row adds its residual root
force. A session row holds the time of each stage (a stage skipped as fresh shows the
time its manifest recorded) and the share of frames the evaluate stage flagged; target
rows check the issue's targets.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.bench.effort import EFFORT_COLUMNS, session_effort_columns
from pipeline.evaluate.consistency import MIN_KEYPOINT_CONF, consistency
from pipeline.schema.session import SessionConfig
from pipeline.schema.sources import RESULT_ARTIFACTS
from pipeline.stages.evaluate import FLAG_KINDS, ProblemFlags

log = logging.getLogger(__name__)

DATASET = "pose2sim_multiperson"
SESSION_NAME = "pose2sim_multiperson (bench footage)"
"""The ``name`` of the bench's session: a folder holding another session is never reused or wiped."""
DEFAULT_DIR_NAME = "cornerman_bench_footage"
"""Name of the default ``work_dir`` (``default_work_dir``) in the system temp dir."""


def default_work_dir() -> Path:
    """The folder the bench runs the Pose2Sim sample in when no ``work_dir`` is given."""
    return Path(tempfile.gettempdir()) / DEFAULT_DIR_NAME


OUTPUTS: tuple[tuple[str, str, str], ...] = tuple((name, st, art) for name, (st, art) in RESULT_ARTIFACTS.items())
"""(row name, stage, artifact) of every 3D output scored, in pipeline order (``pipeline.schema.sources``)."""

FIXED_SESSION_KEYS = frozenset({"name", "source", "calibration", "videos", "keypoints", "tracks"})
"""``SessionConfig`` fields the bench sets itself (they define the footage)."""

TARGETS: tuple[tuple[str, str, float], ...] = (
    ("fit reprojection median, all views", "fit:reproj_median_px", 6.0),
    ("fit reprojection p95, all views", "fit:reproj_p95_px", 15.0),
    ("fit bone-length std", "fit:bone_length_std_mm", 10.0),
    ("frames with a tracking problem flag (identity, reprojection, penetration)", "session:flag_tracking_pct", 10.0),
    ("fit / filtered reprojection median", "ratio:reproj_median_px", 1.2),
    ("fit / filtered reprojection p95", "ratio:reproj_p95_px", 1.2),
)
"""(description, where the value comes from, upper limit) of the issue's targets: units px,
mm, % of frames, and a ratio for the fit vs the filtered triangulation on the same metric."""


def footage_session(data: Path, **overrides: Any) -> SessionConfig:
    """The ``SessionConfig`` ``cornerman new`` builds for the sample (``source="video"``, one video
    per calibrated camera, default athletes), with ``overrides`` of its other fields.

    ``ValueError`` for an override of a field the bench sets, an unknown field, or a missing video."""
    from pipeline.io.calibration import load_calibration

    fixed = sorted(FIXED_SESSION_KEYS & set(overrides))
    if fixed:
        raise ValueError(f"bench footage: {fixed} are set by the bench (the footage), not options")
    calib = data / "calibration" / "Calib.qca.txt"
    names = load_calibration(calib).names
    videos = {n: data / "videos" / f"{n}.mp4" for n in names}
    missing = [str(p) for p in videos.values() if not p.is_file()]
    if missing:
        raise ValueError(f"bench footage: videos of calibrated cameras {list(names)} missing: {missing}")
    if "stage_config" in overrides and not isinstance(overrides["stage_config"], dict):
        raise ValueError(
            "bench footage: stage_config must be a JSON object, e.g. "
            f'--opt \'stage_config={{"fit": {{"pose_iters": 100}}}}\', got {overrides["stage_config"]!r}'
        )
    d: dict[str, Any] = {
        "name": SESSION_NAME,
        "source": "video",
        "calibration": str(calib.resolve()),
        "videos": {n: str(p.resolve()) for n, p in videos.items()},
        **overrides,
    }
    return SessionConfig.from_dict(d, where="bench footage options")


def _stage_list(stages: str | list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """``"detect2d,track,…"`` or a list -> the session's ``stages`` (empty = every stage)."""
    from pipeline.runner import STAGE_ORDER

    items = [s.strip() for s in stages.split(",")] if isinstance(stages, str) else [str(s) for s in stages]
    items = [s for s in items if s]
    unknown = [s for s in items if s not in STAGE_ORDER]
    if unknown:
        raise ValueError(f"bench footage: stages {unknown} unknown; known: {list(STAGE_ORDER)}")
    return tuple(items)


def prepare_work_dir(work_dir: Path, session: SessionConfig, fresh: bool) -> None:
    """Create or reuse ``work_dir`` for ``session``: rewrite ``session.json`` only when it changed
    (the runner then re-runs what went stale); ``fresh`` wipes the folder first.

    ``ValueError`` when ``work_dir`` is not empty and holds no session of this bench (nothing
    that is not the bench's own is overwritten or deleted)."""
    cfg_path = work_dir / "session.json"
    if work_dir.exists():
        if not work_dir.is_dir():
            raise ValueError(f"bench footage: work_dir {work_dir} is a file")
        if cfg_path.exists():
            old_name = SessionConfig.load(work_dir).name
            if old_name != SESSION_NAME:
                raise ValueError(
                    f"bench footage: {work_dir} holds session {old_name!r}, not this bench's; choose another work_dir"
                )
        elif any(work_dir.iterdir()):
            raise ValueError(
                f"bench footage: {work_dir} is not empty and holds no session.json; choose another work_dir"
            )
        if fresh:
            log.info("bench footage: wiping %s", work_dir)
            shutil.rmtree(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    if cfg_path.exists() and cfg_path.read_text() == session.to_json():
        log.info("bench footage: reusing %s (session.json unchanged)", work_dir)
        return
    session.save(work_dir)


def _run_stages(work_dir: Path) -> list[Any]:
    """Run the session with progress (as ``cornerman run``); the ``StageReport``s."""
    from rich.console import Console

    from pipeline.cli.progress import progress_for, summary_table
    from pipeline.runner import run

    console = Console()
    with progress_for(console) as prog:
        reports = run(work_dir, progress=prog)
    console.print(summary_table(reports))
    return reports


def _physics_columns(store: Any) -> dict[str, Any]:
    """Residual root force of the physics stage: the manifest's metrics as they are (body
    weights), and the max / mean force magnitude in newtons from ``result.npz``."""
    from pipeline.schema.results import PhysicsResult

    m = store.manifest("physics")
    metrics = m.metrics if m is not None else {}
    out: dict[str, Any] = {k: metrics[k] for k in sorted(metrics) if k.startswith("residual_force_")}
    if "windows" in metrics and "windows_with_residual" in metrics:
        out["residual_windows"] = f"{metrics['windows_with_residual']}/{metrics['windows']}"
    if store.has("physics", "result.npz"):
        res = store.load("physics", "result", PhysicsResult)
        # (samples,) N, where each athlete was seen
        force = np.linalg.norm(res.residual_root_force[..., :3], axis=-1)[res.observed_mask()]
        if force.size:
            out["residual_force_max_n"] = float(force.max())
            out["residual_force_mean_n"] = float(force.mean())
    return out


def _session_row(store: Any, reports: list[Any], work_dir: Path) -> dict[str, Any]:
    """Stage times (ran, or the manifest's time when skipped as fresh), the stages' own key
    reprojection metrics, and the share of frames the evaluate stage flagged per kind."""
    row: dict[str, Any] = {"kind": "session", "output": "session", "work_dir": str(work_dir)}
    total = 0.0
    for r in reports:
        m = store.manifest(r.stage)
        dt = r.duration_s if r.action == "ran" or m is None else m.duration_s
        row[f"time_{r.stage}_s"] = float(dt)
        row[f"action_{r.stage}"] = r.action
        total += float(dt)
    row["time_total_s"] = total
    # The stages' own metrics, for comparison: triangulation over its kept views, fit's loss view.
    for stage, key, name in (
        ("triangulate", "kept_views_median_px", "tri_kept_views_median_px"),
        ("triangulate", "kept_views_p95_px", "tri_kept_views_p95_px"),
        ("triangulate", "reproj_median_px", "tri_all_views_median_px"),
        ("fit", "reproj_median_px", "fit_all_views_median_px"),
    ):
        m = store.manifest(stage)
        if m is not None and key in m.metrics:
            row[name] = m.metrics[key]
    if store.has("evaluate", "problems.npz"):
        path = store.path("evaluate", "problems.npz")
        with np.load(path, allow_pickle=False) as z:
            try:
                pf = ProblemFlags(**{k: z[k] for k in z.files})
            except (TypeError, ValueError) as e:
                raise ValueError(f"{path}: not the evaluate stage's problem flags ({e}); re-run evaluate") from e
        n = int(pf.frame_indices.shape[0])
        row["flag_frames"] = n
        for kind in FLAG_KINDS:
            col = pf.column(kind.key)  # None in a file written before the kind existed
            row[f"flag_{kind.key}_pct"] = 100.0 * float(col.mean()) if col is not None and n else float("nan")
        row["flag_any_pct"] = 100.0 * float(pf.flags.any(axis=1).mean()) if n else float("nan")
        tracking = [c for k in FLAG_KINDS if k.group == "tracking" and (c := pf.column(k.key)) is not None]
        row["flag_tracking_pct"] = 100.0 * float(np.any(tracking, axis=0).mean()) if n and tracking else float("nan")
    return row


def target_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per target of ``TARGETS``: its value (NaN when the output is missing), limit and ``ok``."""
    by = {str(r.get("output")): r for r in rows}
    out = []
    for what, src, limit in TARGETS:
        where, key = src.split(":", 1)
        if where == "ratio":
            fit, filt = by.get("fit", {}).get(key), by.get("filtered", {}).get(key)
            value = float(fit) / float(filt) if fit is not None and filt else float("nan")
        else:
            v = by.get(where, {}).get(key)
            value = float(v) if v is not None else float("nan")
        out.append(
            {
                "kind": "target",
                "output": "target",
                "target": what,
                "value": value,
                "limit": limit,
                "ok": bool(value <= limit),
            }
        )
    return out


def run_bench(
    work_dir: str = "",
    stages: str | list[str] = "",
    fresh: bool = False,
    min_keypoint_conf: float = MIN_KEYPOINT_CONF,
    **session_overrides: Any,
) -> list[dict]:
    """Set up (or reuse) the footage session in ``work_dir`` (default: a folder in the system temp
    dir), run its stale stages and score every 3D output.

    Args:
        work_dir: session folder; reused when it holds this bench's session.
        stages: the session's stages, comma-separated (``session.json`` ``stages``; empty = all).
        fresh: wipe ``work_dir`` first (only a folder holding this bench's session).
        min_keypoint_conf: lowest 2D keypoint confidence scored for reprojection, in [0, 1].
        session_overrides: other ``SessionConfig`` fields, e.g. ``stage_config={"fit": {...}}``.
    Returns:
        Rows: ``kind="output"`` per 3D output present, one ``kind="session"``, ``kind="target"``s.
    """
    from pipeline.artifacts import ArtifactStore
    from pipeline.runner.rig import rig_for
    from pipeline.schema.association import Association
    from pipeline.schema.detections import Tracks2D
    from pipeline.schema.keypoints3d import Keypoints3D
    from pipeline.shared import dataset_dir

    if not isinstance(fresh, bool):
        raise ValueError(f"bench footage: fresh must be true or false, got {fresh!r}")
    folder = Path(work_dir) if work_dir else default_work_dir()
    session = footage_session(dataset_dir(DATASET), **session_overrides)
    if stages:
        session = dataclasses.replace(session, stages=_stage_list(stages))
    prepare_work_dir(folder, session, fresh)
    reports = _run_stages(folder)
    store = ArtifactStore(folder)
    enabled = {r.stage for r in reports}
    tracks = store.load("track", "tracks", Tracks2D)
    assoc = store.load("associate", "association", Association)
    rig = rig_for("downstream", folder, session)  # the rig the 3D outputs were computed in
    rows: list[dict[str, Any]] = []
    for name, stage, art in OUTPUTS:
        if stage not in enabled or not store.has(stage, f"{art}.npz"):
            continue  # stage not enabled (old artifacts of a disabled stage would be stale)
        kp = store.load(stage, art, Keypoints3D)
        row: dict[str, Any] = {"kind": "output", "output": name, "artifact": f"{stage}/{art}.npz"}
        row.update(consistency(kp, tracks, assoc, rig, min_keypoint_conf).to_dict())
        if name == "physics":
            row.update(_physics_columns(store))
            row.update(session_effort_columns(store))
        rows.append(row)
    rows.append({**_session_row(store, reports, folder), "min_keypoint_conf": float(min_keypoint_conf)})
    rows += target_rows(rows)
    log.debug("bench footage rows: %s", json.dumps(rows, default=str))
    return rows


def _f(v: Any, fmt: str = "{:.1f}") -> str:
    """A number formatted, "" for a missing value or NaN."""
    if v is None or (isinstance(v, float) and v != v):  # NaN != NaN
        return ""
    return fmt.format(v) if isinstance(v, (int, float)) else str(v)


PLAUSIBILITY_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("coverage_pct", "valid %", "{:.1f}"),
    ("bone_length_std_mm", "bone std mm", "{:.1f}"),
    ("overlap_max_mm", "overlap max mm", "{:.1f}"),
    ("overlap_mean_mm", "overlap mean mm", "{:.2f}"),
    ("foot_skate_mm_per_frame", "skate mm/f", "{:.2f}"),
    ("planted_pct", "planted %", "{:.0f}"),
    ("ground_penetration_max_mm", "ground max mm", "{:.1f}"),
    ("accel_mm_per_frame2", "accel mm/f²", "{:.2f}"),
    ("accel_m_per_s2", "accel m/s²", "{:.1f}"),
    ("residual_force_mean_frac_bw", "resid F mean bw", "{:.2f}"),
    ("residual_force_max_frac_bw", "resid F max bw", "{:.2f}"),
    ("residual_force_mean_n", "resid F mean N", "{:.0f}"),
    ("residual_force_max_n", "resid F max N", "{:.0f}"),
    ("residual_windows", "resid windows", "{}"),
    *EFFORT_COLUMNS,
)


def _cameras(row: dict[str, Any]) -> list[str]:
    """Camera names of a row's per-camera reprojection columns (``reproj_<cam>_median_px``)."""
    head, tail = "reproj_", "_median_px"
    return [
        k[len(head) : -len(tail)]
        for k in row
        if k.startswith(head) and k.endswith(tail) and k != head + tail[1:]
    ]


def _med_p95(row: dict[str, Any], prefix: str) -> str:
    return f"{_f(row.get(prefix + 'median_px'))} / {_f(row.get(prefix + 'p95_px'), '{:.0f}')}"


def print_table(rows: list[dict]) -> None:
    """Tables: reprojection per camera (``median / p95`` px), plausibility (and the physics
    residual), stage times, problem flags, targets."""
    from rich.console import Console
    from rich.table import Table

    console = Console(width=max(Console().width, 200))
    outs = [r for r in rows if r.get("kind") == "output"]
    session = next((r for r in rows if r.get("kind") == "session"), {})
    targets = [r for r in rows if r.get("kind") == "target"]
    cams = _cameras(outs[0]) if outs else []
    conf = session.get("min_keypoint_conf", MIN_KEYPOINT_CONF)

    reproj = Table(
        title=f"bench footage ({DATASET}): reprojection error in all views, median / p95 px "
        f"(associated 2D keypoints with confidence >= {conf})",
        caption="2D scored % = confident associated 2D keypoints whose 3D joint is valid",
    )
    for head in ("output", "all cameras", *cams, "2D scored %", "valid 3D %"):
        reproj.add_column(head, justify="left" if head == "output" else "right", no_wrap=True)
    for r in outs:
        reproj.add_row(
            str(r["output"]),
            _med_p95(r, "reproj_"),
            *[_med_p95(r, f"reproj_{c}_") for c in cams],
            _f(r.get("reproj_scored_pct")),
            _f(r.get("coverage_pct")),
        )
    console.print(reproj)

    plaus = Table(
        title="plausibility (valid entries only; planted = foot below 3 cm; overlap of keypoint capsules)",
        caption="resid F = the physics' residual root force: mean / max in body weights (manifest), in N (result.npz)",
    )
    plaus.add_column("output", no_wrap=True)
    for _, head, _ in PLAUSIBILITY_COLUMNS:
        plaus.add_column(head, justify="right")
    for r in outs:
        plaus.add_row(str(r["output"]), *[_f(r.get(k), fmt) for k, _, fmt in PLAUSIBILITY_COLUMNS])
    console.print(plaus)

    stages = [k[len("time_") : -len("_s")] for k in session if k.startswith("time_") and k != "time_total_s"]
    times = Table(title="stage times, s ((cached) = skipped as fresh: the time its manifest recorded)")
    for s in (*stages, "total"):
        times.add_column(s, justify="right")
    times.add_row(
        *[
            f"{session[f'time_{s}_s']:.1f}{'' if session.get(f'action_{s}') == 'ran' else ' (cached)'}"
            for s in stages
        ],
        _f(session.get("time_total_s")),
    )
    console.print(times)

    flags = Table(
        title=f"evaluate stage: frames flagged, % of {session.get('flag_frames', '?')}; the stages' own reprojection",
        caption="tri own = the triangulation over its kept views; tri / fit all = the stages' own summaries, "
        "all views (the reprojection table's metric)",
    )
    extra = (
        ("tri_kept_views_median_px", "tri own med px"),
        ("tri_kept_views_p95_px", "tri own p95 px"),
        ("tri_all_views_median_px", "tri all med px"),
        ("fit_all_views_median_px", "fit all med px"),
    )
    keys = (*(k.key for k in FLAG_KINDS), "tracking", "any")
    for head in (*keys, *(h for _, h in extra)):
        flags.add_column(head, justify="right")
    flags.add_row(
        *[_f(session.get(f"flag_{key}_pct"), "{:.0f}") for key in keys],
        *[_f(session.get(k)) for k, _ in extra],
    )
    console.print(flags)

    goals = Table(title="targets")
    for head in ("target", "value", "limit", ""):
        goals.add_column(head, justify="left" if head == "target" else "right")
    for t in targets:
        goals.add_row(
            str(t["target"]), _f(t["value"], "{:.2f}"), f"<= {t['limit']:g}", "ok" if t["ok"] else "MISSED"
        )
    console.print(goals)
