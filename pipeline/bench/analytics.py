"""``cornerman bench analytics``: the analyze stage against the synthetic bout's choreography.

For each seed and camera count the bout is generated with the varied script
(``SyntheticConfig(variety=True)``: random combinations of every punch type, intended
outcomes, feints, counters; ``pipeline.synthetic.combos``), identities come from ground
truth (as in ``bench fit``, to isolate the 3D and the analytics from association errors),
then triangulation and the fit run and the analytics run on the fit's keypoints, with
the raw triangulation for the glove speeds, the filtered one for the punches the fit
flattened (``pipeline.stages.analyze.motion``) and the bout's 2D tracks with their true
identities for the 2D evidence of such punches (``pipeline.stages.analyze.evidence2d``) (the
physics stage is left out: minutes per bout). Scores (``pipeline.bench.analytics_score``):
punch precision / recall (strikes matched within 3 frames, same athlete and hand), type
and outcome accuracy among the matched, peak-speed error, clinch-frame F1, and the
feints taken for punches, and the blocks' precision / recall (the defender's ``block``
events against the choreography's blocked punches). Rows per camera count sum the seeds; ``source="gt"`` adds rows
on the ground-truth joints (the analytics alone) and ``"filtered"`` on the triangulation.

A last row counts the punches found on the Pose2Sim sample (two people moving, no
punches) as false punches per minute: the analytics on the fit (else physics, else
filtered) keypoints of the session ``cornerman bench footage`` runs on it (its folder in the
system temp dir; created, and its stages run up to the fit, when missing or stale;
``pose2sim_session``), or of a session folder given as ``pose2sim`` (read as it is). The row
is skipped, with the reason logged, when the shared data or the 2D models are absent.

The thresholds were tuned on ``TUNING_SEEDS``; the default seeds (``HELD_OUT_SEEDS``) are others.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.bench.analytics_score import rates, score
from pipeline.schema.association import Association
from pipeline.schema.detections import Tracks2D
from pipeline.schema.keypoints3d import Keypoints3D

log = logging.getLogger(__name__)

TUNING_SEEDS: tuple[int, ...] = (0, 1, 2, 3, 4, 5, 6, 7, 10, 11, 12, *range(20, 32))
"""Seeds the analytics' thresholds were tuned on, or whose errors a rule was written after
(10-12, once the held-out set), and 20-31, added so that a rule is judged on more bouts than
the eleven it was written on (docs/design/analytics.md)."""
HELD_OUT_SEEDS: tuple[int, ...] = (13, 14, 15, 16, 17, 18, 19)
"""The default seeds: never looked at while tuning."""
FOOTAGE = "footage"
"""``pose2sim`` value: the session of ``cornerman bench footage`` (``pose2sim_session``)."""
POSE2SIM_STAGE = "fit"
"""The Pose2Sim row needs the stages up to this one (physics is left out, as for the synthetic rows)."""
COUNT_KEYS = ("gt_punches", "detected", "matched", "type_correct", "outcome_correct", "speed_err_sum",
              "feints", "feint_hits", "clinch_tp", "clinch_gt", "clinch_pred", "frames",
              "gt_blocks", "blocks_detected", "blocks_matched", "gt_parries", "parries_detected", "parries_matched")  # fmt: skip


def _fit_keypoints(bout: Any, sources: tuple[str, ...]) -> dict[str, Keypoints3D]:
    from pipeline.stages.triangulate import TriangulateConfig
    from pipeline.stages.triangulate import run as run_triangulate

    assoc = bout.gt_association()
    raw, tri = run_triangulate(bout.tracks, assoc, bout.rig, TriangulateConfig())
    out: dict[str, Keypoints3D] = {"raw": raw, "filtered": tri}
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


def footage_work_dir() -> Path:
    """The folder ``cornerman bench footage`` runs the Pose2Sim sample in by default."""
    from pipeline.bench import footage

    return footage.default_work_dir()


def _missing_models(folder: Path) -> list[str]:
    """Registry names of the 2D models the session in ``folder`` needs and cannot find."""
    from pipeline.registry.download import find_model
    from pipeline.runner import get_specs
    from pipeline.runner.core import resolve_config
    from pipeline.schema.session import SessionConfig

    session = SessionConfig.load(folder)
    cfg = resolve_config(get_specs()["detect2d"], session)
    models_dir = cfg.models_dir
    if models_dir and not Path(models_dir).is_absolute():
        models_dir = str(folder / models_dir)
    names = [cfg.detector, cfg.pose_model] + ([cfg.foot_model] if cfg.foot_model != "none" else [])
    return [n for n in names if find_model(n, models_dir) is None]


def pose2sim_session(pose2sim: str = FOOTAGE) -> tuple[Path | None, str]:
    """(session folder, "") of the Pose2Sim row, or (None, why it is skipped).

    ``pose2sim``: ``"footage"`` = the ``bench footage`` folder (``footage_work_dir``): created
    when missing (``footage.footage_session`` of the shared sample), its missing or stale stages
    run up to ``POSE2SIM_STAGE``, reusing the session.json found there; skipped when the shared
    data, or the 2D models a stage to run needs, are absent. Any other value is a session folder
    read as it is. ``ValueError`` when that folder holds no session, or when the footage folder
    holds another bench's session or other files (nothing there is overwritten)."""
    from pipeline.bench import footage
    from pipeline.runner import run, stage_status
    from pipeline.schema.session import SessionConfig
    from pipeline.shared import dataset_dir

    if pose2sim != FOOTAGE:
        path = Path(pose2sim).expanduser()
        if not (path / "session.json").is_file():
            raise ValueError(f"bench analytics: pose2sim={pose2sim!r}: no session.json in {path}")
        return path, ""
    folder = footage_work_dir()
    try:
        data = dataset_dir(footage.DATASET)
    except ValueError as e:
        return None, f"the Pose2Sim sample is absent: {e}"
    if not (folder / "session.json").is_file():
        footage.prepare_work_dir(folder, footage.footage_session(data), fresh=False)
    elif (name := SessionConfig.load(folder).name) != footage.SESSION_NAME:
        raise ValueError(f"bench analytics: {folder} holds session {name!r}, not bench footage's; move it away")
    status = stage_status(folder)
    todo = [s for s, st in status.items() if st != "fresh"]
    to_stage = POSE2SIM_STAGE if POSE2SIM_STAGE in status else "triangulate"
    order = list(status)
    todo = [s for s in todo if to_stage in order and order.index(s) <= order.index(to_stage)]
    if todo:
        if "detect2d" in todo and (missing := _missing_models(folder)):
            return None, f"the 2D models {missing} are absent (`cornerman models list` says where they are looked for)"
        log.info("bench analytics: running %s in %s (missing or stale)", ", ".join(todo), folder)
        run(folder, to_stage=to_stage)
    return folder, ""


def _config(views: bool | None) -> Any:
    """The analyze config of the bench: the stage's defaults, with the 2D evidence
    (``ViewEvidenceConfig.enabled``) set when ``views`` is not None."""
    from dataclasses import replace

    from pipeline.stages.analyze import AnalyzeConfig

    cfg = AnalyzeConfig()
    return cfg if views is None else replace(cfg, views=replace(cfg.views, enabled=bool(views)))


def pose2sim_row(session_dir: str | Path, views: bool | None = None) -> dict[str, Any] | None:
    """Punches found on a session's 3D result (fit, else physics, else filtered; speeds from its
    raw triangulation; 2D evidence from its track and associate artifacts when present, as
    ``views`` says: ``_config``); None when it has none of them."""
    from pipeline.artifacts import ArtifactStore
    from pipeline.io.session_rig import session_rig
    from pipeline.schema.session import SessionConfig
    from pipeline.schema.sources import RESULT_ARTIFACTS
    from pipeline.stages.analyze import AnalyzeInputs
    from pipeline.stages.analyze import run as analyze

    store = ArtifactStore(Path(session_dir))
    raw_stage, raw_art = RESULT_ARTIFACTS["raw"]
    raw = store.load(raw_stage, raw_art, Keypoints3D) if store.has(raw_stage, f"{raw_art}.npz") else None
    f_stage, f_art = RESULT_ARTIFACTS["filtered"]
    filtered = store.load(f_stage, f_art, Keypoints3D) if store.has(f_stage, f"{f_art}.npz") else None
    tracks, assoc = None, None
    if store.has("track", "tracks.npz") and store.has("associate", "association.npz"):
        tracks = store.load("track", "tracks", Tracks2D)
        assoc = store.load("associate", "association", Association)
    for name in ("fit", "physics", "filtered"):
        stage, art = RESULT_ARTIFACTS[name]
        if store.has(stage, f"{art}.npz"):
            kp = store.load(stage, art, Keypoints3D)
            inp = AnalyzeInputs(kp, raw=raw, filtered=filtered, tracks=tracks, association=assoc)
            ev = analyze(inp, _config(views)).events
            minutes = kp.n_frames / kp.fps / 60.0
            return {
                "data": f"Pose2Sim sample ({name})",
                "cameras": session_rig(Path(session_dir), SessionConfig.load(Path(session_dir))).n_views,
                "seeds": "-", "frames": kp.n_frames, "detected": ev.n_punches,
                "false_per_min": ev.n_punches / minutes if minutes else float("nan"),
                "clinch_frames": int(sum(int(e - s + 1) for s, e in zip(ev.clinch_start_frame, ev.clinch_end_frame, strict=True))),
            }  # fmt: skip
    log.warning("bench analytics: %s has no fit, physics or filtered keypoints; Pose2Sim row skipped", session_dir)
    return None


@dataclass(frozen=True)
class Stance:
    """How the bench's bouts of one stance are made (``SyntheticConfig`` flags) and named."""

    southpaw: bool
    """``SyntheticConfig.southpaw``: the whole bout mirrored (the cameras see other sides)."""
    mixed_stance: bool
    """``SyntheticConfig.mixed_stance``: boxer 1 southpaw, boxer 0 orthodox."""
    label: str
    """Added to a row's ``data`` ("" for the plain orthodox bouts)."""
    cache_tag: str
    """Added to the ``cache_dir`` keys of its 3D results."""


STANCES: dict[str, Stance] = {
    "orthodox": Stance(False, False, "", ""),
    "southpaw": Stance(True, False, ", southpaw", "_sp"),
    "mixed": Stance(False, True, ", orthodox vs southpaw", "_mx"),
}
"""The stances ``run_bench`` scores the same seeds in, by name (all of them by default)."""


def run_bench(
    seeds: list[int] | tuple[int, ...] = HELD_OUT_SEEDS,
    n_frames: int = 300,
    cameras: list[int] | tuple[int, ...] | int = (4, 2),
    sources: str = "fit",
    cache_dir: str = "",
    pose2sim: str = FOOTAGE,
    views: bool | None = None,
    parry_prob: float = 0.0,
    stances: str = ",".join(STANCES),
    camera_step_deg: float | None = None,
) -> list[dict[str, Any]]:
    """Rows: one per (stance, 3D source, camera count) over ``seeds``, then the Pose2Sim row.

    ``sources``: comma-separated among ``fit``, ``filtered``, ``gt``. ``cache_dir``: keep
    the 3D results there and reuse them (for tuning; they are keyed by seed, cameras,
    frames, ``parry_prob`` and source only, so empty it when the generator changes). ``pose2sim``: the
    session of the last row: ``"footage"`` = ``bench footage``'s, run up to the fit when
    missing or stale; a session folder; "" skips the row (``pose2sim_session``). ``views``:
    None keeps the analyze stage's default for the 2D evidence of flattened punches, True /
    False turns it on / off (``ViewEvidenceConfig.enabled``). ``parry_prob``: the bouts'
    ``SyntheticConfig.parry_prob`` (0 to 1; > 0 scripts parries, scored in the parry columns,
    and makes other bouts than the default seeds' usual ones). ``stances``: comma-separated
    among ``STANCES`` (rows say which in ``data``). ``camera_step_deg``: the bouts'
    ``SyntheticConfig.camera_step_deg`` (degrees from one camera to the next around the ring,
    at most 360 / cameras; None spreads them evenly, so two cameras face each other; 90 puts
    them a quarter turn apart; rows say it in ``data``).
    """
    from pipeline.stages.analyze import AnalyzeInputs
    from pipeline.stages.analyze import run as analyze
    from pipeline.synthetic import SyntheticConfig, make_bout

    wanted = tuple(s.strip() for s in sources.split(",") if s.strip())
    bad = [s for s in wanted if s not in ("fit", "filtered", "gt")]
    if bad or not wanted:
        raise ValueError(f"bench analytics: sources must be among fit, filtered, gt; got {sources!r}")
    cams = (cameras,) if isinstance(cameras, int) else tuple(cameras)
    names = [s.strip() for s in stances.split(",") if s.strip()]
    if not names or set(names) - set(STANCES):
        raise ValueError(f"bench analytics: stances must be among {', '.join(STANCES)}; got {stances!r}")
    try:
        step = None if camera_step_deg is None else float(camera_step_deg)
    except (TypeError, ValueError):
        raise ValueError(f"bench analytics: camera_step_deg must be a number of degrees, got {camera_step_deg!r}") from None
    for n_cams in cams:  # before minutes of work: SyntheticConfig checks the range
        SyntheticConfig(n_cameras=n_cams, camera_step_deg=step)
    layout = "" if step is None else f", cameras {step:g} deg apart"
    cache = Path(cache_dir) if cache_dir else None
    cfg = _config(views)
    p2s_dir, why = pose2sim_session(pose2sim) if pose2sim else (None, "pose2sim is empty")
    if p2s_dir is None:  # before the synthetic bouts: say it now, not after minutes
        log.warning("bench analytics: Pose2Sim row skipped: %s", why)
    totals: dict[tuple[str, str, int], dict[str, Any]] = {}
    for stance, n_cams in ((st, c) for st in names for c in cams):
        st = STANCES[stance]
        for seed in seeds:
            t0 = time.perf_counter()
            bout = make_bout(SyntheticConfig(seed=int(seed), n_frames=int(n_frames), n_cameras=n_cams, variety=True,
                                             parry_prob=float(parry_prob), southpaw=st.southpaw,
                                             mixed_stance=st.mixed_stance, camera_step_deg=step))  # fmt: skip
            made: dict[str, Keypoints3D] = {}
            tri: dict[str, Keypoints3D] = {}
            for src in ("raw", "filtered", *[w for w in wanted if w != "filtered"]):
                tag = (f"_pp{float(parry_prob):g}" if parry_prob else "") + st.cache_tag + (f"_cs{step:g}" if step else "")
                key = f"kp_s{seed}_c{n_cams}_f{n_frames}{tag}_{src}"

                def make(src: str = src, made: dict[str, Keypoints3D] = made, bout: Any = bout) -> Keypoints3D:
                    if src not in made:  # the triangulation alone unless the fit is asked for
                        made.update(_fit_keypoints(bout, wanted if src == "fit" else ("filtered",)))
                    return made[src]

                kp = bout.gt if src == "gt" else _cached(cache, key, make)
                if src in ("raw", "filtered"):
                    tri[src] = kp
                    if src not in wanted:
                        continue
                # Speeds from the raw triangulation (``PunchConfig.speed_source``), punches the fit
                # flattened from the filtered one (``PunchConfig.flattened``) and the 2D tracks
                # (``AnalyzeConfig.views``); on ground truth none of them.
                real = src != "gt"
                inp = AnalyzeInputs(
                    kp, raw=tri["raw"] if real else None, filtered=tri["filtered"] if real else None,
                    tracks=bout.tracks if real else None, association=bout.gt_association() if real else None,
                )  # fmt: skip
                s = score(bout.truth, analyze(inp, cfg).events)
                tot = totals.setdefault((stance, src, n_cams), {k: 0 for k in COUNT_KEYS} | {"speed_err_max": 0.0})
                for k in COUNT_KEYS:
                    tot[k] += s[k]
                tot["speed_err_max"] = max(tot["speed_err_max"], s["speed_err_max"])
            log.info("bench analytics: seed %d, %d cameras%s%s: %.1f s", seed, n_cams, layout, st.label, time.perf_counter() - t0)
    rows: list[dict[str, Any]] = []
    for (stance, src, n_cams), tot in totals.items():
        minutes = tot["frames"] / 50.0 / 60.0
        false = tot["detected"] - tot["matched"]
        rows.append(
            {"data": f"synthetic{STANCES[stance].label} ({src}){layout}", "cameras": n_cams,
             "camera_step_deg": step,
             "seeds": ",".join(str(s) for s in seeds),
             "frames": tot["frames"], "gt_punches": tot["gt_punches"], "detected": tot["detected"],
             "matched": tot["matched"], **rates(tot), "feints": tot["feints"], "feint_hits": tot["feint_hits"],
             "gt_blocks": tot["gt_blocks"], "gt_parries": tot["gt_parries"],
             "false_per_min": false / minutes if minutes else float("nan")}  # fmt: skip
        )
    if p2s_dir is not None:
        row = pose2sim_row(p2s_dir, views)
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
        ("gt_parries", "parries", "{}"), ("parry_precision", "parry precision", "{:.3f}"),
        ("parry_recall", "parry recall", "{:.3f}"),
        ("feint_hits", "feints as punches", "{}"),
        ("false_per_min", "false punches/min", "{:.1f}"),
    ]  # fmt: skip
    table = Table(
        title="bench analytics: synthetic bouts with varied combinations (GT identities), and the Pose2Sim sample",
        caption="targets: precision/recall >= 0.95, type and outcome accuracy >= 90 %, speed error <= 10 %, "
        "clinch F1 >= 0.9, <= 1 false punch/min without punches; punches matched by strike frame +-3, same athlete and hand; "
        "blocks: the defender's block events against the choreography's blocked punches (strikes +-3); "
        "parries (bouts with parry_prob > 0): the defender's parry events against the scripted parries (strikes +-3)",
    )
    for _, title, _ in cols:
        table.add_column(title, justify="right")
    for r in rows:
        table.add_row(*[fmt.format(r[k]) if k in r and r[k] == r[k] else "" for k, _, fmt in cols])
    Console(width=220).print(table)
