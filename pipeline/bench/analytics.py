"""``cornerman bench analytics``: the analyze stage against the synthetic bout's choreography.

For each seed and camera count the bout is generated with the varied script
(``SyntheticConfig(variety=True)``: random combinations of every punch type, intended
outcomes, feints, counters; ``pipeline.synthetic.combos``), identities come from ground
truth (as in ``bench fit``, to isolate the 3D and the analytics from association errors),
then triangulation and the fit run and the analytics run on the fit's keypoints, with
the raw triangulation for the glove speeds, as the analyze step does (the physics stage
is left out: minutes per bout). Scores (``pipeline.bench.analytics_score``):
punch precision / recall (strikes matched within 3 frames, same athlete and hand), type
and outcome accuracy among the matched, peak-speed error, clinch-frame F1, and the
feints taken for punches, and the blocks' precision / recall (the defender's ``block``
events against the choreography's blocked punches). Rows per camera count sum the seeds; ``source="gt"`` adds rows
on the ground-truth joints (the analytics alone) and ``"filtered"`` on the triangulation.

A last row counts the punches found on the Pose2Sim sample (two people moving, no
punches): its fit (else physics, else filtered) keypoints of a session that ran on it
(``pose2sim_session``, read only), as false punches per minute.

The thresholds were tuned on seeds 0-3 (``TUNING_SEEDS``); the default seeds are others.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from pipeline.bench.analytics_score import rates, score
from pipeline.schema.keypoints3d import Keypoints3D

log = logging.getLogger(__name__)

TUNING_SEEDS: tuple[int, ...] = (0, 1, 2, 3)
"""Seeds the analytics' thresholds were tuned on."""
HELD_OUT_SEEDS: tuple[int, ...] = (10, 11, 12)
"""The default seeds: never looked at while tuning."""
POSE2SIM_SESSION = "/tmp/cm/fb_def"
"""A session folder that ran the stages on the Pose2Sim multi-person sample."""
COUNT_KEYS = ("gt_punches", "detected", "matched", "type_correct", "outcome_correct", "speed_err_sum",
              "feints", "feint_hits", "clinch_tp", "clinch_gt", "clinch_pred", "frames",
              "gt_blocks", "blocks_detected", "blocks_matched")  # fmt: skip


def _fit_keypoints(bout: Any, sources: tuple[str, ...]) -> dict[str, Keypoints3D]:
    from pipeline.stages.triangulate import TriangulateConfig
    from pipeline.stages.triangulate import run as run_triangulate

    assoc = bout.gt_association()
    raw, tri = run_triangulate(bout.tracks, assoc, bout.rig, TriangulateConfig())
    out: dict[str, Keypoints3D] = {"raw": raw}
    if "filtered" in sources:
        out["filtered"] = tri
    if "fit" in sources:
        from pipeline.stages.fit import FitConfig
        from pipeline.stages.fit import run as run_fit

        out["fit"] = run_fit(tri, bout.tracks, assoc, bout.rig, FitConfig()).keypoints3d
    if "gt" in sources:
        out["gt"] = bout.gt
    return out


def _cached(cache: Path | None, key: str, make: Any) -> Keypoints3D:
    from pipeline.schema.base import load_npz, save_npz

    if cache is not None and (cache / f"{key}.npz").exists():
        return load_npz(cache / f"{key}.npz", Keypoints3D)
    kp = make()
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        save_npz(cache / f"{key}.npz", kp)
    return kp


def pose2sim_row(session_dir: str = POSE2SIM_SESSION) -> dict[str, Any] | None:
    """Punches found on a session's 3D result (fit, else physics, else filtered); None
    when the session is not there."""
    from pipeline.artifacts import ArtifactStore
    from pipeline.schema.sources import RESULT_ARTIFACTS
    from pipeline.stages.analyze import AnalyzeInputs
    from pipeline.stages.analyze import run as analyze

    path = Path(session_dir)
    if not (path / "session.json").exists():
        log.warning("bench analytics: no session at %s; Pose2Sim row skipped", path)
        return None
    store = ArtifactStore(path)
    for name in ("fit", "physics", "filtered"):
        stage, art = RESULT_ARTIFACTS[name]
        if store.has(stage, f"{art}.npz"):
            kp = store.load(stage, art, Keypoints3D)
            ev = analyze(AnalyzeInputs(kp)).events
            minutes = kp.n_frames / kp.fps / 60.0
            return {
                "data": f"Pose2Sim sample ({name})", "cameras": 4, "seeds": "-", "frames": kp.n_frames,
                "detected": ev.n_punches, "false_per_min": ev.n_punches / minutes if minutes else float("nan"),
                "clinch_frames": int(sum(int(e - s + 1) for s, e in zip(ev.clinch_start_frame, ev.clinch_end_frame, strict=True))),
            }  # fmt: skip
    return None


def run_bench(
    seeds: list[int] | tuple[int, ...] = HELD_OUT_SEEDS,
    n_frames: int = 300,
    cameras: list[int] | tuple[int, ...] | int = (4, 2),
    sources: str = "fit",
    cache_dir: str = "",
    pose2sim: str = POSE2SIM_SESSION,
) -> list[dict[str, Any]]:
    """Rows: one per (3D source, camera count) over ``seeds``, then the Pose2Sim row.

    ``sources``: comma-separated among ``fit``, ``filtered``, ``gt``. ``cache_dir``: keep
    the 3D results there and reuse them (for tuning; they are keyed by seed, cameras,
    frames and source only, so empty it when the generator changes). ``pose2sim``: the
    session folder read for the last row ("" to skip it).
    """
    from pipeline.stages.analyze import AnalyzeInputs
    from pipeline.stages.analyze import run as analyze
    from pipeline.synthetic import SyntheticConfig, make_bout

    wanted = tuple(s.strip() for s in sources.split(",") if s.strip())
    bad = [s for s in wanted if s not in ("fit", "filtered", "gt")]
    if bad or not wanted:
        raise ValueError(f"bench analytics: sources must be among fit, filtered, gt; got {sources!r}")
    cams = (cameras,) if isinstance(cameras, int) else tuple(cameras)
    cache = Path(cache_dir) if cache_dir else None
    totals: dict[tuple[str, int], dict[str, Any]] = {}
    for n_cams in cams:
        for seed in seeds:
            t0 = time.perf_counter()
            bout = make_bout(SyntheticConfig(seed=int(seed), n_frames=int(n_frames), n_cameras=n_cams, variety=True))
            made: dict[str, Keypoints3D] = {}
            for src in ("raw", *wanted):
                key = f"kp_s{seed}_c{n_cams}_f{n_frames}_{src}"

                def make(src: str = src, made: dict[str, Keypoints3D] = made, bout: Any = bout) -> Keypoints3D:
                    if src not in made:
                        made.update(_fit_keypoints(bout, wanted))
                    return made[src]

                kp = bout.gt if src == "gt" else _cached(cache, key, make)
                if src == "raw":
                    raw = kp
                    continue
                # Speeds from the raw triangulation (``PunchConfig.speed_source``); on
                # ground truth from itself.
                s = score(bout.truth, analyze(AnalyzeInputs(kp, raw=None if src == "gt" else raw)).events)
                tot = totals.setdefault((src, n_cams), {k: 0 for k in COUNT_KEYS} | {"speed_err_max": 0.0})
                for k in COUNT_KEYS:
                    tot[k] += s[k]
                tot["speed_err_max"] = max(tot["speed_err_max"], s["speed_err_max"])
            log.info("bench analytics: seed %d, %d cameras: %.1f s", seed, n_cams, time.perf_counter() - t0)
    rows: list[dict[str, Any]] = []
    for (src, n_cams), tot in totals.items():
        minutes = tot["frames"] / 50.0 / 60.0
        false = tot["detected"] - tot["matched"]
        rows.append(
            {"data": f"synthetic ({src})", "cameras": n_cams, "seeds": ",".join(str(s) for s in seeds),
             "frames": tot["frames"], "gt_punches": tot["gt_punches"], "detected": tot["detected"],
             "matched": tot["matched"], **rates(tot), "feints": tot["feints"], "feint_hits": tot["feint_hits"],
             "gt_blocks": tot["gt_blocks"],
             "false_per_min": false / minutes if minutes else float("nan")}  # fmt: skip
        )
    if pose2sim:
        row = pose2sim_row(pose2sim)
        if row is not None:
            rows.append(row)
    return rows


def print_table(rows: list[dict[str, Any]]) -> None:
    from rich.console import Console
    from rich.table import Table

    cols = [
        ("data", "data", "{}"), ("cameras", "cams", "{}"), ("seeds", "seeds", "{}"),
        ("gt_punches", "punches", "{}"), ("detected", "found", "{}"),
        ("precision", "precision", "{:.3f}"), ("recall", "recall", "{:.3f}"),
        ("type_acc_pct", "type acc %", "{:.1f}"), ("outcome_acc_pct", "outcome acc %", "{:.1f}"),
        ("speed_err_pct", "speed err %", "{:.1f}"), ("speed_err_max_pct", "max speed err %", "{:.1f}"),
        ("clinch_f1", "clinch F1", "{:.3f}"), ("gt_blocks", "blocks", "{}"),
        ("block_precision", "block precision", "{:.3f}"), ("block_recall", "block recall", "{:.3f}"),
        ("feint_hits", "feints as punches", "{}"),
        ("false_per_min", "false punches/min", "{:.1f}"),
    ]  # fmt: skip
    table = Table(
        title="bench analytics: synthetic bouts with varied combinations (GT identities), and the Pose2Sim sample",
        caption="targets: precision/recall >= 0.95, type and outcome accuracy >= 90 %, speed error <= 10 %, "
        "clinch F1 >= 0.9, <= 1 false punch/min without punches; punches matched by strike frame +-3, same athlete and hand; "
        "blocks: the defender's block events against the choreography's blocked punches (strikes +-3)",
    )
    for _, title, _ in cols:
        table.add_column(title, justify="right")
    for r in rows:
        table.add_row(*[fmt.format(r[k]) if k in r and r[k] == r[k] else "" for k, _, fmt in cols])
    Console(width=220).print(table)
