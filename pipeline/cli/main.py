"""The ``cornerman`` command line (typer)."""

from __future__ import annotations

import importlib
import json
import logging
import os
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from pipeline.cli.dataset import app as dataset_app
from pipeline.cli.summaries import one_line_summaries
from pipeline.io.export.write import check_out as _check_out

app = typer.Typer(
    name="cornerman",
    help="Physics-based multi-person 3D motion capture for combat sports.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)
console = Console()

BENCHES = {
    "triangulation": "pipeline.bench.triangulation",
    "fit": "pipeline.bench.fit",
    "physics": "pipeline.bench.physics",
    "video": "pipeline.bench.video",
    "shelf": "pipeline.bench.shelf",
    "footage": "pipeline.bench.footage",
    "analytics": "pipeline.bench.analytics",
    "incremental": "pipeline.bench.incremental",
    "server": "server.loadtest",
    "viewer": "server.viewer_bench",
}


def _home() -> Path:
    return Path(os.environ.get("CORNERMAN_HOME", "data/server"))


def _setup_logging(verbose: bool) -> None:
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )


def _fail(msg: str) -> None:
    console.print(f"[bold red]error:[/] {msg}", soft_wrap=True)
    raise typer.Exit(code=2)


def _run_with_progress(session: Path, from_stage: str | None, to_stage: str | None, force: bool) -> list[Any]:
    from pipeline.cli.progress import progress_for, summary_table
    from pipeline.runner import run

    with progress_for(console) as prog:
        reports = run(session, from_stage=from_stage, to_stage=to_stage, force=force, progress=prog)
    console.print(summary_table(reports))
    return reports


@app.command()
def demo(
    no_serve: Annotated[bool, typer.Option("--no-serve", help="Stop after the pipeline; do not start the app.")] = False,
    session_dir: Annotated[Path | None, typer.Option(help="Where to create the demo session.")] = None,
    frames: Annotated[int, typer.Option(help="Frames of the synthetic bout (50 fps).")] = 300,
    cameras: Annotated[int, typer.Option(help="Number of cameras (2-8).")] = 4,
    seed: Annotated[int, typer.Option(help="Random seed of the bout.")] = 0,
    host: Annotated[str, typer.Option(help="Host to serve on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="API port.")] = 8000,
    verbose: Annotated[bool, typer.Option("--verbose", "-v")] = False,
) -> None:
    """Generate the built-in synthetic sparring bout, run every stage, then serve the app."""
    _setup_logging(verbose)
    if not no_serve:  # a busy port must stop the demo before minutes of compute, not after
        from server.cli import check_port

        try:
            check_port(host, port)
        except ValueError as e:
            _fail(str(e))
    from pipeline.synthetic import SyntheticConfig, make_demo_session

    session = session_dir or (_home() / "sessions" / "demo")
    session.parent.mkdir(parents=True, exist_ok=True)
    console.print(f"[bold]demo bout[/]: {frames} frames, {cameras} cameras, seed {seed} -> {session}")
    try:
        make_demo_session(session, SyntheticConfig(seed=seed, n_frames=frames, n_cameras=cameras))
        _run_with_progress(session, None, None, False)
    except ValueError as e:
        _fail(str(e))
    if no_serve:
        console.print(f"session ready: {session}  (serve it with `cornerman serve`)")
        return
    from server.cli import serve as serve_app

    try:
        serve_app(host=host, port=port, workers=1, home=_home(), demo_session=session, open_tokens_print=True)
    except ValueError as e:
        _fail(f"{e} (the computed demo session stays in {session})")


@app.command("run")
def run_cmd(
    session: Annotated[Path, typer.Argument(help="Session folder (with session.json).")],
    from_stage: Annotated[str | None, typer.Option("--from-stage", help="Re-run from this stage on.")] = None,
    to_stage: Annotated[str | None, typer.Option("--to-stage", help="Stop after this stage.")] = None,
    force: Annotated[bool, typer.Option(help="Re-run in full, reusing nothing of the previous run: every stage, or with --from-stage that stage and the later ones.")] = False,
    body_model: Annotated[
        str | None, typer.Option("--body-model", help="fit: anny, smpl or smplx (saved in session.json).")
    ] = None,
    body_model_path: Annotated[
        Path | None,
        typer.Option("--body-model-path", help="fit: folder with smpl/SMPL_*.pkl or smplx/SMPLX_*.npz (yours)."),
    ] = None,
    models_dir: Annotated[
        Path | None,
        typer.Option("--models-dir", help="detect2d: folder searched first for the ONNX models (saved in session.json)."),
    ] = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v")] = False,
) -> None:
    """Run a session's stages, skipping the fresh ones."""
    _setup_logging(verbose)
    try:
        _check_stage_range(session, from_stage, to_stage)  # before anything is saved
        if body_model is not None or body_model_path is not None:
            _set_fit_body_model(session, body_model, body_model_path)
        if models_dir is not None:
            _set_models_dir(session, models_dir)
        _run_with_progress(session, from_stage, to_stage, force)
    except ValueError as e:
        _fail(str(e))


def _check_stage_range(session: Path, from_stage: str | None, to_stage: str | None) -> None:
    """``ValueError`` for an unknown stage or ``--from-stage`` after ``--to-stage``."""
    from pipeline.runner.core import enabled_stages, stage_range
    from pipeline.schema.session import SessionConfig

    stage_range(enabled_stages(SessionConfig.load(session), str(session / "session.json")), from_stage, to_stage)


def _set_models_dir(session: Path, models_dir: Path) -> None:
    """Store ``--models-dir`` (absolute) in ``session.json``'s ``stage_config.detect2d.models_dir``."""
    import dataclasses

    from pipeline.runner.core import resolve_config
    from pipeline.runner.registry import get_specs
    from pipeline.schema.session import SessionConfig

    if not models_dir.expanduser().is_dir():
        raise ValueError(f"--models-dir {models_dir}: not a folder")
    cfg = SessionConfig.load(session)
    d2d = {**cfg.stage_config.get("detect2d", {}), "models_dir": str(models_dir.expanduser().resolve())}
    new = dataclasses.replace(cfg, stage_config={**cfg.stage_config, "detect2d": d2d})
    resolve_config(get_specs()["detect2d"], new)
    if new != cfg:
        new.save(session)


def _set_fit_body_model(session: Path, body_model: str | None, body_model_path: Path | None) -> None:
    """Store ``--body-model`` / ``--body-model-path`` in ``session.json``'s ``stage_config.fit``
    (so the fit stage goes stale and re-runs, and the viewer finds the files for the meshes)."""
    import dataclasses

    from pipeline.schema.config_types import build_config
    from pipeline.schema.session import SessionConfig
    from pipeline.stages.fit_config import FitConfig

    cfg = SessionConfig.load(session)
    fit = dict(cfg.stage_config.get("fit", {}))
    if body_model is not None:
        fit["body_model"] = body_model
    if body_model_path is not None:
        fit["body_model_path"] = str(body_model_path.expanduser().resolve())
    if body_model is not None and body_model not in ("anny", "smpl", "smplx"):
        raise ValueError(f"--body-model must be anny, smpl or smplx, got {body_model!r}")
    build_config(FitConfig, fit, f"{session / 'session.json'}: stage_config.fit")
    if fit.get("body_model", "anny") != "anny":
        # Check the files before saving: a wrong path must not end up in session.json.
        from pipeline.backends.smpl.body import check_smpl_available

        check_smpl_available(fit["body_model"], fit.get("body_model_path", ""))
    dataclasses.replace(cfg, stage_config={**cfg.stage_config, "fit": fit}).save(session)


@app.command()
def status(session: Annotated[Path, typer.Argument(help="Session folder.")]) -> None:
    """Per stage: fresh, stale or missing."""
    from pipeline.artifacts import ArtifactStore
    from pipeline.runner import stage_status

    try:
        st = stage_status(session)
    except ValueError as e:
        _fail(str(e))
        return
    store = ArtifactStore(session)
    table = Table(title=f"status of {session}")
    for c in ("stage", "status", "last run", "time [s]"):
        table.add_column(c)
    colours = {"fresh": "green", "stale": "yellow", "missing": "red"}
    import datetime as dt

    for stage, s in st.items():
        m = store.manifest(stage)
        when = dt.datetime.fromtimestamp(m.created_unix_s).isoformat(timespec="seconds") if m else ""
        table.add_row(stage, f"[{colours[s]}]{s}[/]", when, f"{m.duration_s:.2f}" if m else "")
    console.print(table)


def _format_help() -> str:
    from pipeline.io.export import FORMATS

    return "; ".join(f"{f.name}: {f.summary}" for f in FORMATS.values())


_FORMAT_HELP = _format_help()


@app.command()
def export(
    session: Annotated[Path, typer.Argument(help="Session folder.")],
    format: Annotated[str, typer.Option("--format", "-f", help=_FORMAT_HELP)] = "json",
    source: Annotated[str, typer.Option(help="best (fit, else filtered), latest (physics, else fit, else filtered), raw, filtered, fit or physics.")] = "best",
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Output file; a .zip when the export is several files (e.g. BVH of two athletes).")] = None,
    athlete: Annotated[
        list[str], typer.Option("--athlete", "-a", help="Athlete name or person id, repeated; default every athlete.")
    ] = [],  # noqa: B006
    frames: Annotated[
        str | None, typer.Option("--frames", help="Video frames FIRST:STOP (STOP excluded), e.g. 100:400; default all.")
    ] = None,
    calibration: Annotated[
        bool,
        typer.Option(
            "--calibration",
            help="Export the camera calibration the later stages used (refined by the calibrate stage when "
            "it was adopted) as a Pose2Sim/anipose TOML, instead of keypoints.",
        ),
    ] = False,
    events: Annotated[
        str | None,
        typer.Option("--events", help="Export the analyze stage's events (punches, slips, ducks, clinches) as csv or json."),
    ] = None,
) -> None:
    """Export results in another tool's format (--format, see the README's Formats), with --calibration the
    calibration (TOML), or with --events csv|json the boxing events."""
    from pipeline.schema import SessionConfig

    try:
        cfg = SessionConfig.load(session)
        if calibration and events is not None:
            raise ValueError("--calibration and --events export different things; give one")
        if events is not None:
            path = _export_events(session, cfg, events, out)
            return
        if calibration:
            path = out or (session / "calibration_refined.toml")
            _check_out(path)
            _export_calibration(session, cfg, path)
            return
        from pipeline.io.export import (
            ExportSelection,
            default_out,
            export_files,
            get_format,
            parse_frames,
            write_files,
        )

        fmt = get_format(format)
        if out is not None:
            _check_out(out)
        names = {i: n for i, n in enumerate(cfg.athletes)}
        sel = ExportSelection(session, source, _athlete_ids(athlete, names), parse_frames(frames), names)
        files = export_files(sel, fmt.name)
        path = out or default_out(session, files, f"export_{fmt.name}")
        write_files(files, path)
    except (ValueError, LookupError) as e:
        _fail(str(e))
        return
    what = ", ".join(files) if len(files) > 1 else fmt.summary
    console.print(f"wrote {path} ({what})", soft_wrap=True)


def _athlete_ids(given: list[str], names: dict[int, str]) -> tuple[int, ...]:
    """Person ids for ``--athlete`` values (names, case-insensitive, or ids); ``ValueError`` otherwise."""
    by_name = {n.lower(): i for i, n in names.items()}
    ids = []
    for a in given:
        if a.lower() in by_name:
            ids.append(by_name[a.lower()])
        elif a.isdigit():
            ids.append(int(a))
        else:
            raise ValueError(f"--athlete {a!r}: no athlete of that name (athletes: {', '.join(names.values()) or 'none named'})")
    return tuple(dict.fromkeys(ids))


def _export_events(session: Path, cfg: Any, fmt: str, out: Path | None) -> Path:
    from pipeline.io.events_export import export_events, load_analytics

    if fmt not in ("csv", "json"):
        raise ValueError(f"--events must be csv or json, got {fmt!r}")
    path = out or (session / f"events.{fmt}")
    _check_out(path)
    ev, _, source = load_analytics(session)
    names = {i: n for i, n in enumerate(cfg.athletes)}
    path.write_text(export_events(ev, fmt, names, source))  # type: ignore[arg-type]
    console.print(f"wrote {path} ({ev.n_punches} punches, {ev.n_evades} slips/ducks, {ev.n_clinches} clinches; {source})")
    return path


@app.command()
def analyze(
    session: Annotated[Path, typer.Argument(help="Session folder.")],
    run_stages: Annotated[
        bool, typer.Option("--run/--no-run", help="First run the stages up to analyze that are missing or stale.")
    ] = True,
    json_out: Annotated[Path | None, typer.Option("--json", help="Also write the summary to this JSON file.")] = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v")] = False,
) -> None:
    """Print the per-athlete boxing summary: punches by type and outcome, speeds, work rate,
    slips, ducks, blocks and parries, clinch time, stance, guard, distance, time at the ring's
    centre, ropes and corners (when session.json gives the ring), and the fatigue indicators
    per round (or minute) with their trends."""
    _setup_logging(verbose)
    from pipeline.cli.analytics import fatigue_table, summary_table
    from pipeline.io.events_export import load_analytics
    from pipeline.schema import SessionConfig
    from pipeline.stages.analyze import summarize

    try:
        if json_out is not None:
            _check_out(json_out)
        cfg = SessionConfig.load(session)
        if run_stages:
            _check_stage_range(session, None, "analyze")
            _run_with_progress(session, None, "analyze", False)
        ev, series, source = load_analytics(session)
    except (ValueError, LookupError) as e:
        _fail(str(e))
        return
    summary = summarize(ev, series, {i: n for i, n in enumerate(cfg.athletes)},
                        ring_xy_m=cfg.ring_xy_m or None, rounds_s=cfg.rounds_s)  # fmt: skip
    summary["source"] = source
    console.print(summary_table(summary, f"{cfg.name or session}: boxing summary ({source})"))
    console.print(fatigue_table(summary, f"fatigue indicators per {'round' if summary['period_kind'] == 'rounds' else 'minute'}"))
    if json_out is not None:
        json_out.write_text(json.dumps(summary, indent=1))
        console.print(f"summary written to {json_out}")


@app.command()
def report(
    session: Annotated[Path, typer.Argument(help="Session folder (the analyze stage must have run).")],
    out: Annotated[Path | None, typer.Option("--out", "-o", help="HTML file to write (default: SESSION/report.html).")] = None,
    period_s: Annotated[float, typer.Option("--period-s", help="Summary period when session.json gives no rounds (s).")] = 60.0,
    bin_s: Annotated[float, typer.Option("--bin-s", help="Work-rate timeline bin (s).")] = 10.0,
) -> None:
    """Write the bout report: one self-contained HTML page (summary per athlete and per round,
    punch maps, ring-position heatmaps, speed histograms, work-rate timeline) to print or save as PDF."""
    from pipeline.report import ReportOptions, load_report_data, render_report

    path = out or session / "report.html"
    try:
        _check_out(path)
        html = render_report(load_report_data(session), ReportOptions(period_s=period_s, bin_s=bin_s))
    except (ValueError, LookupError) as e:
        _fail(str(e))
        return
    path.write_text(html, encoding="utf-8")
    console.print(f"wrote {path} ({len(html) // 1024} KiB); open it in a browser to print or save as PDF")


def _export_calibration(session: Path, cfg: Any, path: Path) -> None:
    from pipeline.artifacts import ArtifactStore
    from pipeline.io.calibration import save_toml
    from pipeline.runner.rig import CALIBRATE, rig_for

    rig = rig_for("downstream", session, cfg)
    m = ArtifactStore(session).manifest(CALIBRATE)
    save_toml(rig, path)
    if m is None:
        how = "the calibrate stage has not run: this is the input calibration"
    else:
        how = str(m.metrics.get("reason", "calibrate stage result"))
        for key in ("level", "floor"):
            if m.metrics.get(key):
                how += f"; {m.metrics[key]}"
    console.print(f"wrote {path} ({len(rig.names)} cameras; {how})", soft_wrap=True)


@app.command()
def new(
    session: Annotated[Path, typer.Argument(help="Session folder to create.")],
    calibration: Annotated[Path, typer.Option(help="Calibration file (.toml, .qca.txt, .json), EasyMocap folder, or a folder holding one .toml or .qca.txt.")],
    video: Annotated[list[str], typer.Option(help="CAM=PATH, repeated, one per camera; or one folder of videos named after the cameras (cam01.mp4 ...).")] = [],  # noqa: B006
    keypoints: Annotated[list[str], typer.Option(help="CAM=PATH of 2D keypoints, repeated; or one folder of per-camera inputs named after the cameras.")] = [],  # noqa: B006
    keypoint_format: Annotated[str, typer.Option(help="openpose or coco.")] = "openpose",
    name: Annotated[str, typer.Option(help="Bout name.")] = "",
    fps: Annotated[float, typer.Option(help="Frame rate (0 = from calibration/video).")] = 0.0,
    cameras: Annotated[
        str, typer.Option(help="Comma-separated calibrated cameras to use, e.g. cam01,cam03 (default: all).")
    ] = "",
    athlete: Annotated[
        list[str], typer.Option(help="Athlete name, repeated, one per person (sets the person count).")
    ] = [],  # noqa: B006
    models_dir: Annotated[
        Path | None, typer.Option("--models-dir", help="Folder searched first for the ONNX models (video sessions).")
    ] = None,
) -> None:
    """Create a session folder from videos or 2D keypoints + a calibration (every input is checked first)."""
    from pipeline.cli.new_session import plan_new_session, print_summary

    try:
        with console.status("checking the calibration and the inputs"):
            plan = plan_new_session(
                session, calibration, video, keypoints, keypoint_format, name, fps, cameras, athlete, models_dir
            )
    except ValueError as e:
        _fail(str(e))
        return
    session.mkdir(parents=True, exist_ok=True)
    plan.config.save(session)
    print_summary(console, plan)
    console.print(f"created {session}; run it with `cornerman run {session}`", soft_wrap=True)


def _parse_opt(items: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for it in items:
        if "=" not in it:
            raise ValueError(f"--opt expects KEY=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


@app.command()
def bench(
    name: Annotated[str, typer.Argument(help=f"One of: {', '.join(BENCHES)}.")],
    opt: Annotated[list[str], typer.Option(help="KEY=VALUE options passed to the benchmark.")] = [],  # noqa: B006
    json_out: Annotated[Path | None, typer.Option("--json", help="Also write the table's rows to this JSON file.")] = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v")] = False,
) -> None:
    """Run a benchmark and print its table (speed and accuracy targets live here, not in tests)."""
    _setup_logging(verbose)
    if name not in BENCHES:
        _fail(f"unknown benchmark {name!r}; choose one of {list(BENCHES)}")
    if json_out is not None and json_out.is_dir():
        _fail(f"--json {json_out}: is a folder; give a file name, e.g. {json_out / (name + '.json')}")
    if json_out is not None and not json_out.parent.is_dir():
        _fail(f"--json {json_out}: folder {json_out.parent} does not exist")
    try:
        mod = importlib.import_module(BENCHES[name])
    except ModuleNotFoundError as e:
        _fail(f"benchmark {name!r} is not available in this build ({e})")
        return
    try:
        rows = mod.run_bench(**_parse_opt(opt))
    except ValueError as e:
        _fail(str(e))
        return
    if hasattr(mod, "print_table"):
        mod.print_table(rows)
    else:
        from pipeline.cli.progress import rows_table

        console.print(rows_table(f"bench {name}", rows))
    if json_out is not None:  # after the table: a failed write must not hide the results
        from pipeline.bench.environment import environment, sidecar_path

        env_out = sidecar_path(json_out)
        for path, text, what in (
            (json_out, json.dumps(rows, indent=1, default=_json_default), "the rows"),
            (env_out, json.dumps(environment(), indent=1), "what they were measured with"),
        ):
            try:
                path.write_text(text)
            except OSError as e:
                _fail(f"--json {json_out}: could not write {what} to {path} ({e.strerror or e}); the table above has the rows")
        console.print(f"rows written to {json_out}, what they were measured with to {env_out}")


def _json_default(o: Any) -> Any:
    """numpy scalars and arrays as plain JSON values; anything else as its text."""
    return o.tolist() if hasattr(o, "tolist") else str(o)


@app.command()
def serve(
    host: Annotated[str, typer.Option(help="Host to bind.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="API port.")] = 8000,
    workers: Annotated[int, typer.Option(help="Worker processes to start with the API.")] = 1,
    home: Annotated[Path | None, typer.Option(help="Server home (database + sessions); env CORNERMAN_HOME.")] = None,
    print_tokens: Annotated[bool, typer.Option("--print-tokens", help="Issue and print fresh tokens for admin/annotator/coach.")] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v")] = False,
) -> None:
    """Start the API server (FastAPI + uvicorn) and job workers."""
    _setup_logging(verbose)
    from server.cli import serve as serve_app

    try:
        serve_app(host=host, port=port, workers=workers, home=home or _home(), demo_session=None,
                  open_tokens_print=print_tokens)
    except ValueError as e:
        _fail(str(e))


user_app = typer.Typer(help="Server users and API tokens.", no_args_is_help=True)
app.add_typer(user_app, name="user")


@user_app.command("create")
def user_create(
    name: Annotated[str, typer.Argument(help="User name.")],
    role: Annotated[str, typer.Option(help="coach (read), annotator (read + annotate) or admin.")] = "coach",
    home: Annotated[Path | None, typer.Option(help="Server home; env CORNERMAN_HOME.")] = None,
) -> None:
    """Create a user (if needed) and print a new API token for it."""
    from server.cli import create_user

    if role not in ("coach", "annotator", "admin"):
        _fail(f"--role must be coach, annotator or admin, got {role!r}")
    try:
        token = create_user(name, role, home=home or _home())
    except ValueError as e:
        _fail(str(e))
        return
    console.print(f"user {name} ({role}) token: {token}", soft_wrap=True)


@app.command()
def worker(
    home: Annotated[Path | None, typer.Option(help="Server home; env CORNERMAN_HOME.")] = None,
    executor: Annotated[str, typer.Option(help="local or ray.")] = "local",
    ray_address: Annotated[str | None, typer.Option(help="Ray cluster address (with --executor ray).")] = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v")] = False,
) -> None:
    """Start one more job worker (claims queued jobs from the server's database)."""
    _setup_logging(verbose)
    from server.cli import worker as worker_main

    worker_main(home=home or _home(), executor=executor, ray_address=ray_address)


priors_app = typer.Typer(help="Pose priors shipped with cornerman.", no_args_is_help=True)
app.add_typer(priors_app, name="priors")
app.add_typer(dataset_app, name="dataset")


@priors_app.command("build")
def priors_build(
    out: Annotated[Path | None, typer.Option(help="Output npz (default: the shipped builtin prior).")] = None,
    seed: Annotated[int, typer.Option(help="Random seed of the GMM fit.")] = 0,
    components: Annotated[int, typer.Option(help="Mixture components.")] = 4,
    poses_out: Annotated[Path | None, typer.Option(help="Also save the retargeted poses (npz).")] = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v")] = False,
) -> None:
    """Rebuild anny's GMM pose prior from the DeepMimic clips in pybullet (the `priors`
    extra; a few minutes): retarget every clip to anny, fit the mixture."""
    _setup_logging(verbose)
    from pipeline.backends.anny.priors import BUILTIN_PRIOR
    from pipeline.priors.build import build_pose_prior

    target = out or BUILTIN_PRIOR
    try:
        with console.status(f"retargeting DeepMimic clips and fitting the prior -> {target}"):
            summary = build_pose_prior(target, seed=seed, n_components=components, poses_out=poses_out)
    except (ImportError, ValueError) as e:
        _fail(str(e))
        return
    for k, v in summary.items():
        console.print(f"{k}: {v}", soft_wrap=True)


def _mount_subapps() -> None:
    try:
        from pipeline.cli.models import app as models_app
    except ModuleNotFoundError:
        return
    app.add_typer(models_app, name="models", help="Model registry: list (the default: which models a session needs, where they are looked up, how to get them), download, verify.")


_mount_subapps()
one_line_summaries(app)


def main() -> None:  # pragma: no cover - entry point
    sys.exit(app())
