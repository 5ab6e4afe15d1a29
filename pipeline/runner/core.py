"""``run(session, from_stage, to_stage)``: execute stale stages in order, skip fresh ones."""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pipeline import __version__
from pipeline.artifacts import ArtifactStore, FileHashCache, Manifest, config_hash
from pipeline.io.session_rig import calibration_path, check_multiview, session_rig
from pipeline.runner.code_version import stage_code_hash
from pipeline.runner.registry import STAGE_ORDER, get_specs
from pipeline.runner.spec import NullProgress, PreviousRun, StageContext, StageSpec
from pipeline.schema.annotations import annotations_for, annotations_hash, load_annotations
from pipeline.schema.config_types import build_config
from pipeline.schema.session import SessionConfig

log = logging.getLogger(__name__)

StageStatus = Literal["fresh", "stale", "missing"]

FIRST_MULTIVIEW_STAGE = "associate"
"""The first stage that needs two or more cameras; a run reaching it checks the rig up front."""


@dataclass(frozen=True)
class StageReport:
    stage: str
    action: Literal["ran", "skipped"]
    duration_s: float
    metrics: dict[str, Any]


def enabled_stages(session: SessionConfig, where: str = "session.json") -> list[str]:
    """The session's stages in run order; ``ValueError`` (starting with ``where``, the file the
    session came from) for an unknown stage in ``stages`` or ``stage_config``."""
    specs = get_specs()
    wanted = session.stages or tuple(specs)
    unknown = [s for s in wanted if s not in STAGE_ORDER]
    if unknown:
        raise ValueError(f"{where}: unknown stages {unknown}; known: {list(STAGE_ORDER)}")
    unknown = [s for s in session.stage_config if s not in STAGE_ORDER]
    if unknown:
        raise ValueError(f"{where}: stage_config has unknown stages {unknown}; known: {list(STAGE_ORDER)}")
    return [s for s in STAGE_ORDER if s in wanted]


def resolve_config(spec: StageSpec, session: SessionConfig, where: str = "session.json") -> Any:
    """Build the stage config from defaults + session.json overrides; every error names the
    file (``where``), the key and its type or range problem (``pipeline.schema.config_types.build_config``)."""
    return build_config(spec.config_cls, session.stage_config.get(spec.name, {}), f"{where}: stage_config.{spec.name}")


def check_stage_configs(session: SessionConfig) -> None:
    """``ValueError`` unless every enabled stage's ``stage_config`` builds (run before queueing
    a job, so that a bad value is reported at submission rather than mid-run)."""
    specs = get_specs()
    for name in enabled_stages(session):
        resolve_config(specs[name], session)


def _config_dict(cfg: Any) -> dict[str, Any]:
    return dataclasses.asdict(cfg)


def _deps_in_use(spec: StageSpec, enabled: list[str]) -> list[str]:
    return list(spec.deps) + [d for d in spec.optional_deps if d in enabled]


def fingerprint(ctx: StageContext, spec: StageSpec, cfg: Any, enabled: list[str], hashes: FileHashCache) -> dict[str, str]:
    """Input hashes of a stage: upstream outputs, input files, consumed annotations, and the
    session's camera selection when it has one."""
    inputs: dict[str, str] = {}
    for dep in _deps_in_use(spec, enabled):
        m = ctx.store.manifest(dep)
        inputs[f"artifact:{dep}"] = m.outputs_hash if m else "missing"
    for p in spec.input_files(ctx):
        try:
            rel = str(p.relative_to(ctx.session_dir))
        except ValueError:
            rel = str(p)
        inputs[f"file:{rel}"] = hashes.sha256(p)
    if spec.uses_rig_fps:
        inputs["rig_fps"] = repr(float(ctx.rig.fps))
    if ctx.session.cameras:  # which cameras, in which order, defines the views of every stage
        inputs["cameras"] = ",".join(ctx.session.cameras)
    if spec.consumes_annotations:
        inputs["annotations"] = annotations_hash(annotations_for(ctx.all_annotations, spec.name))
    return inputs


def _code_version(spec: StageSpec) -> str:
    """The stage's code version: a hash of the code of every module it can run
    (``pipeline.runner.code_version``), so a code change makes its artifacts stale."""
    return f"cornerman {__version__} / {spec.name} {stage_code_hash(spec.name)}"


def previous_run(m: Manifest | None, chash: str, code_version: str, force: bool) -> PreviousRun | None:
    """A stage's previous artifacts as a step sees them, with why they may not be reused
    (a forced run recomputes; another config or code version gave other results)."""
    if m is None:
        return None
    why = ""
    if force:
        why = "forced re-run"
    elif m.config_hash != chash:
        why = "the stage config changed"
    elif m.code_version != code_version:
        why = f"the code changed ({m.code_version} -> {code_version})"
    return PreviousRun(m, why)


def stage_status(session_dir: Path) -> dict[str, StageStatus]:
    """Per enabled stage: fresh, stale or missing (no side effects beyond the hash cache)."""
    session_dir = Path(session_dir)
    session = SessionConfig.load(session_dir)
    where = str(session_dir / "session.json")
    store = ArtifactStore(session_dir)
    specs = get_specs()
    enabled = enabled_stages(session, where)
    hashes = FileHashCache(store.root / ".hashcache.json")
    out: dict[str, StageStatus] = {}
    upstream_stale: set[str] = set()
    for name in enabled:
        spec = specs[name]
        m = store.manifest(name)
        if m is None:
            out[name] = "missing"
            continue
        ctx = StageContext(session_dir, session, store, name)
        cfg = resolve_config(spec, session, where)
        fp = fingerprint(ctx, spec, cfg, enabled, hashes)
        deps_bad = any(d in upstream_stale or out.get(d) in ("missing", "stale") for d in _deps_in_use(spec, enabled))
        same = fp == m.inputs and config_hash(_config_dict(cfg)) == m.config_hash and m.code_version == _code_version(spec)
        out[name] = "fresh" if same and not deps_bad else "stale"
        if out[name] != "fresh":
            upstream_stale.add(name)
    hashes.save()
    return out


def first_stale_stage(session_dir: Path) -> str | None:
    for name, st in stage_status(session_dir).items():
        if st != "fresh":
            return name
    return None


def stage_range(enabled: list[str], from_stage: str | None, to_stage: str | None) -> tuple[int, int]:
    """Indices into ``enabled`` of the first forced stage (``len(enabled)``: none) and of the
    last stage to run. ``ValueError`` for a stage that is not enabled, or a ``from_stage``
    after ``to_stage`` (nothing would run)."""
    for s, label in ((from_stage, "from-stage"), (to_stage, "to-stage")):
        if s is not None and s not in enabled:
            raise ValueError(f"{label} {s!r} is not an enabled stage of this session: {enabled}")
    last = enabled.index(to_stage) if to_stage else len(enabled) - 1
    first_forced = enabled.index(from_stage) if from_stage else len(enabled)
    if from_stage is not None and first_forced > last:
        raise ValueError(
            f"from-stage {from_stage!r} comes after to-stage {to_stage!r} in this session's stage order "
            f"{enabled}: nothing would run (swap them?)"
        )
    return first_forced, last


def run(
    session_dir: str | Path,
    from_stage: str | None = None,
    to_stage: str | None = None,
    force: bool = False,
    progress: Any = None,
) -> list[StageReport]:
    """Run the session's stages in order up to ``to_stage``.

    A stage runs when it is missing or stale, or when it is at or after ``from_stage``;
    otherwise it is skipped. ``force`` runs in full (no reuse of the previous run) every stage
    from ``from_stage`` on, or every stage without ``from_stage``. Each stage's outputs are
    written atomically, so an exception (or a kill) mid-stage leaves all earlier
    artifacts intact and a later ``run`` resumes from the first incomplete stage.
    """
    session_dir = Path(session_dir)
    session = SessionConfig.load(session_dir)
    store = ArtifactStore(session_dir)
    specs = get_specs()
    where = str(session_dir / "session.json")
    enabled = enabled_stages(session, where)
    sink = progress or NullProgress()
    first_forced, last = stage_range(enabled, from_stage, to_stage)
    load_annotations(session_dir / "annotations.json")  # fail early on a malformed overlay
    if any(STAGE_ORDER.index(s) >= STAGE_ORDER.index(FIRST_MULTIVIEW_STAGE) for s in enabled[: last + 1]):
        # one camera: say so now, not after the 2D stages have run
        check_multiview(session_rig(session_dir, session), str(calibration_path(session_dir, session)))
    # Every config up to ``to_stage`` first: a bad value in a late stage must not surface
    # only after the early stages have run.
    cfgs = {name: resolve_config(specs[name], session, where) for name in enabled[: last + 1]}
    hashes = FileHashCache(store.root / ".hashcache.json")
    reports: list[StageReport] = []
    for i, name in enumerate(enabled[: last + 1]):
        spec = specs[name]
        ctx = StageContext(session_dir, session, store, name, progress_sink=sink)
        cfg = cfgs[name]
        chash = config_hash(_config_dict(cfg))
        fp = fingerprint(ctx, spec, cfg, enabled, hashes)
        m = store.manifest(name)
        fresh = (
            m is not None
            and m.inputs == fp
            and m.config_hash == chash
            and m.code_version == _code_version(spec)
        )
        forced = force and (from_stage is None or i >= first_forced)
        if fresh and not forced and i < first_forced:
            sink.stage_finished(name, "skipped", 0.0, m.metrics if m else {})
            reports.append(StageReport(name, "skipped", 0.0, m.metrics if m else {}))
            continue
        missing = [d for d in _deps_in_use(spec, enabled) if store.manifest(d) is None]
        if missing:
            raise ValueError(f"stage {name!r} needs {missing}, which have no artifacts")
        log.info("running stage %s", name)
        sink.stage_started(name, None)
        ctx.previous = previous_run(m, chash, _code_version(spec), forced)
        t0 = time.perf_counter()
        outputs = spec.execute(ctx, cfg)
        dt = time.perf_counter() - t0
        manifest = Manifest(
            stage=name,
            code_version=_code_version(spec),
            config=_config_dict(cfg),
            config_hash=chash,
            inputs=fp,
            duration_s=dt,
            metrics=dict(ctx.metrics),
        )
        store.write(manifest, outputs)
        hashes.save()
        sink.stage_finished(name, "ran", dt, dict(ctx.metrics))
        reports.append(StageReport(name, "ran", dt, dict(ctx.metrics)))
    hashes.save()
    return reports
