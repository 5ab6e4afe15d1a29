"""``cornerman new``: check every input of a new session before anything is written.

``plan_new_session`` reads what the options name (the calibration, each video's header or
each camera's keypoints) and returns the ``SessionConfig`` to save plus a per-camera
summary; every problem is a ``ValueError`` naming the option or file, so that a session
folder only ever holds inputs the pipeline can read.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from pipeline.schema.camera import CameraRig
from pipeline.schema.session import SessionConfig


@dataclass(frozen=True)
class CameraInput:
    """One camera of a new session as its input describes it.

    Fields:
        name: camera name (the calibration's).
        path: the video file or keypoint file/folder.
        n_frames: frames in the input (a video's header count, or the keypoints' frame span).
        fps: the video's frame rate in Hz; ``None`` for keypoints.
        detections: persons found in the keypoints over all frames; ``None`` for videos.
    """

    name: str
    path: str
    n_frames: int
    fps: float | None = None
    detections: int | None = None


@dataclass(frozen=True)
class NewSession:
    """A checked session, ready to save.

    Fields:
        config: the ``session.json`` content.
        rig: the calibration as the session uses it (its ``cameras``, its frame rate).
        fps_source: where the frame rate comes from (``pipeline.io.session_rig.session_fps``).
        cameras: the inputs of the cameras the session uses, in the rig's order.
        unused: inputs given for calibrated cameras that ``--cameras`` leaves out.
    """

    config: SessionConfig
    rig: CameraRig
    fps_source: str
    cameras: tuple[CameraInput, ...]
    unused: tuple[str, ...] = field(default_factory=tuple)


def parse_pairs(items: list[str], option: str) -> dict[str, str]:
    """``["cam01=a.mp4", ...]`` -> ``{"cam01": "/abs/a.mp4"}``; ``ValueError`` naming ``option``
    for a missing ``=``, an empty name, a camera given twice or a path that does not exist."""
    out: dict[str, str] = {}
    for it in items:
        if "=" not in it:
            raise ValueError(f"{option} expects CAM=PATH, got {it!r}")
        cam, p = (s.strip() for s in it.split("=", 1))
        if not cam:
            raise ValueError(f"{option} {it!r}: empty camera name")
        if cam in out:
            raise ValueError(f"{option} {cam}: given twice ({out[cam]} and {p}); one input per camera")
        path = Path(p).expanduser()
        if not path.exists():
            raise ValueError(f"{option} {cam}: {p} does not exist")
        out[cam] = str(path.resolve())
    return out


def parse_inputs(
    items: list[str], option: str, calibration: Path, keypoint_format: str = ""
) -> tuple[dict[str, str], Path | None]:
    """``--video`` / ``--keypoints`` values: ``CAM=PATH`` pairs (``parse_pairs``), or one folder
    holding every camera's input named after one of ``calibration``'s cameras
    (``pipeline.io.input_folders``). Returns the camera -> absolute path map and the folder
    (``None`` for pairs)."""
    from pipeline.io.calibration import load_calibration
    from pipeline.io.input_folders import EntryKind, describe, entries, match_cameras

    folders = [it for it in items if "=" not in it and Path(it).expanduser().is_dir()]
    if not folders:
        return parse_pairs(items, option), None
    if len(items) > 1:
        raise ValueError(f"{option} {folders[0]}: a folder of inputs is the only {option} value; "
                         "give either one folder or CAM=PATH pairs")  # fmt: skip
    folder = Path(folders[0]).expanduser().resolve()
    kind: EntryKind = "video" if option == "--video" else "coco" if keypoint_format == "coco" else "openpose"
    found = entries(folder, kind)
    if not found:
        raise ValueError(f"{option} {folders[0]}: no {describe(kind)} in this folder")
    return match_cameras(found, load_calibration(calibration).names, f"{option} {folder}"), folder


def parse_cameras(text: str) -> tuple[str, ...]:
    """``"cam01,cam03"`` -> ``("cam01", "cam03")`` (``""`` = every calibrated camera)."""
    return tuple(c.strip() for c in text.split(",") if c.strip())


def _check_inputs_match(
    inputs: dict[str, str], calibrated: tuple[str, ...], rig: CameraRig, option: str, folder: Path | None
) -> None:
    """``ValueError`` for an input camera the calibration lacks, or a used camera without input
    (``folder``: the folder the inputs were read from, else ``None``)."""
    unknown = [c for c in inputs if c not in calibrated]
    if unknown:
        raise ValueError(
            f"{option} for camera(s) {unknown} that the calibration does not have; its cameras are {list(calibrated)}"
        )
    missing = [c for c in rig.names if c not in inputs]
    if missing:
        given = [c for c in rig.names if c in inputs]
        hint = f", or leave them out with --cameras {','.join(given)}" if len(given) >= 2 else ""
        where = f"input in {option} {folder}" if folder is not None else f"{option} CAM=PATH; give one"
        raise ValueError(f"camera(s) {missing} of the calibration have no {where}{hint}")


def _video_inputs(inputs: dict[str, str], rig: CameraRig) -> list[CameraInput]:
    """Each used camera's video header; ``ValueError`` naming an unreadable video."""
    from pipeline.io.video import video_info

    out = []
    for cam in rig.names:
        info = video_info(Path(inputs[cam]))  # ValueError naming the file
        if info.fps <= 0:
            raise ValueError(f"{inputs[cam]}: video of camera {cam!r} reports no frame rate; give one with --fps")
        out.append(CameraInput(cam, inputs[cam], info.n_frames, fps=info.fps))
    return out


def _keypoint_inputs(inputs: dict[str, str], fmt: Any, rig: CameraRig) -> list[CameraInput]:
    """Each used camera's keypoints, parsed in full; ``ValueError`` naming a file that does not
    parse or holds no person."""
    import numpy as np

    from pipeline.io.keypoints2d import load_keypoints

    sel = {c: inputs[c] for c in rig.names}
    dets = load_keypoints(sel, fmt, rig)  # ValueError naming the file and the problem
    counts = np.bincount(dets.view, minlength=rig.n_views)
    empty = [f"{sel[c]} ({c})" for i, c in enumerate(rig.names) if counts[i] == 0]
    if empty:
        raise ValueError(f"--keypoints: no person with a valid keypoint in {', '.join(empty)}")
    return [CameraInput(c, sel[c], dets.n_frames, detections=int(counts[i])) for i, c in enumerate(rig.names)]


def plan_new_session(
    session_dir: Path,
    calibration: Path,
    videos: list[str],
    keypoints: list[str],
    keypoint_format: str,
    name: str,
    fps: float,
    cameras: str,
    athletes: list[str],
    models_dir: Path | None,
) -> NewSession:
    """Check every input of ``cornerman new`` (see the module docstring); writes nothing.

    Raises ``ValueError`` for: an existing ``session.json``; an unreadable calibration;
    unknown or too few cameras (a 3D reconstruction needs two); missing, duplicate or
    unreadable videos / keypoints; inputs whose cameras do not match the calibration;
    keypoints without any person; a bad ``--athlete`` list or ``--models-dir``."""
    from pipeline.io.calibration import load_calibration, resolve_calibration
    from pipeline.io.session_rig import check_multiview, session_fps, session_rig
    from pipeline.runner.core import check_stage_configs

    if (session_dir / "session.json").exists():
        raise ValueError(f"{session_dir / 'session.json'} exists already; choose another folder")
    calibration = resolve_calibration(calibration)  # a folder with one calibration file gives that file
    if bool(videos) == bool(keypoints):
        raise ValueError("give either --video or --keypoints (CAM=PATH ..., or one FOLDER), not both or neither")
    option, items = ("--video", videos) if videos else ("--keypoints", keypoints)
    inputs, folder = parse_inputs(items, option, calibration, keypoint_format)
    vids, kps = (inputs, {}) if videos else ({}, inputs)
    names = [a.strip() for a in athletes]
    if any(not a for a in names) or len(set(names)) != len(names):
        raise ValueError(f"--athlete names must be non-empty and different, got {athletes}")
    stage_config: dict[str, dict[str, Any]] = {}
    if models_dir is not None:
        if not models_dir.expanduser().is_dir():
            raise ValueError(f"--models-dir {models_dir}: not a folder")
        stage_config["detect2d"] = {"models_dir": str(models_dir.expanduser().resolve())}
    cfg = SessionConfig(
        name=name or session_dir.name,
        source="video" if vids else "keypoints",
        calibration=str(calibration.resolve()),
        videos=vids,
        keypoints=kps,
        keypoint_format=keypoint_format,  # type: ignore[arg-type]  # checked by SessionConfig
        fps=fps,
        cameras=parse_cameras(cameras),
        stage_config=stage_config,
    )
    if names:  # else SessionConfig's default athletes
        cfg = replace(cfg, athletes=tuple(names))
    check_stage_configs(cfg)
    rig = session_rig(session_dir, cfg)  # parses the calibration, applies --cameras
    check_multiview(rig, str(calibration))
    calibrated = load_calibration(calibration).names
    _check_inputs_match(inputs, calibrated, rig, option, folder)
    cams = _video_inputs(inputs, rig) if vids else _keypoint_inputs(inputs, cfg.keypoint_format, rig)
    _, source = session_fps(session_dir, cfg, rig.fps)
    unused = tuple(c for c in inputs if c not in rig.names)
    return NewSession(config=cfg, rig=rig, fps_source=source, cameras=tuple(cams), unused=unused)


def print_summary(console: Console, plan: NewSession) -> None:
    """Cameras, frames, frame rate and athletes of a checked ``NewSession``; advice when no two
    cameras see depth well (``pipeline.geometry.layout``); for a video session also whether the
    models are present."""
    from pipeline.geometry.layout import layout_advice

    cfg, rig = plan.config, plan.rig
    table = Table(title=f"session {cfg.name}")
    for c in ("camera", "input", "frames", "fps" if cfg.source == "video" else "persons found"):
        table.add_column(c)
    for cam in plan.cameras:
        last = f"{cam.fps:.4g}" if cam.fps is not None else str(cam.detections)
        table.add_row(cam.name, cam.path, str(cam.n_frames), last)
    console.print(table)
    frames = sorted({cam.n_frames for cam in plan.cameras})
    span = str(frames[0]) if len(frames) == 1 else f"{frames[0]}-{frames[-1]} (the cameras differ)"
    console.print(f"cameras: {', '.join(rig.names)} ({rig.n_views})", soft_wrap=True)
    if (advice := layout_advice(rig)) is not None:
        console.print(f"  [yellow]{escape(advice)}[/]", soft_wrap=True)
    if plan.unused:
        console.print(f"not used (--cameras): {', '.join(plan.unused)}", soft_wrap=True)
    source = "--fps" if plan.fps_source == "session.json fps" else f"the {plan.fps_source}"
    console.print(f"frames: {span}; fps: {rig.fps:.4g} (from {source})", soft_wrap=True)
    if plan.fps_source == "calibration default":
        console.print("  [yellow]the frame rate is a default: give the real one with --fps[/]", soft_wrap=True)
    console.print(f"athletes: {', '.join(cfg.athletes)} ({len(cfg.athletes)} persons)", soft_wrap=True)
    if cfg.source == "video":
        _print_model_check(console, cfg)


def _print_model_check(console: Console, cfg: SessionConfig) -> None:
    from pipeline.cli.models import session_models
    from pipeline.registry import find_model, get_model, how_to_get
    from pipeline.runner.core import resolve_config
    from pipeline.runner.registry import get_specs

    d2d = resolve_config(get_specs()["detect2d"], cfg)
    for role, model in session_models(d2d):
        if find_model(model, d2d.models_dir) is None:
            console.print(
                f"  [yellow]missing {role}: {model}[/]; {how_to_get(get_model(model))} (see `cornerman models`)",
                soft_wrap=True,
            )
