"""What the runner needs to know about a stage, and what a stage step gets to see.

A *step* (``pipeline/runner/steps/<stage>.py``) is the I/O adapter around a pure
stage function: it loads inputs through the ``StageContext``, calls
``pipeline.stages.<stage>.run(...)`` and returns the outputs to store. The runner
does all file I/O, hashing and manifest bookkeeping.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Protocol

from pipeline.artifacts import ArtifactStore, Manifest
from pipeline.schema.annotations import Annotation, annotations_for, load_annotations
from pipeline.schema.camera import CameraRig
from pipeline.schema.session import SessionConfig


class ProgressSink(Protocol):
    """Receives progress events; the CLI shows bars, the worker writes the database.

    ``stage_progress`` may raise (e.g. ``JobCancelled``) to stop a stage early; the
    stage's previous artifacts stay as they were.
    """

    def stage_started(self, stage: str, total: float | None) -> None: ...

    def stage_progress(self, stage: str, done: float, total: float | None, message: str) -> None: ...

    def stage_finished(self, stage: str, status: str, duration_s: float, metrics: dict[str, Any]) -> None: ...


class NullProgress:
    def stage_started(self, stage: str, total: float | None) -> None:
        pass

    def stage_progress(self, stage: str, done: float, total: float | None, message: str) -> None:
        pass

    def stage_finished(self, stage: str, status: str, duration_s: float, metrics: dict[str, Any]) -> None:
        pass


@dataclass(frozen=True)
class PreviousRun:
    """The stage's artifacts from its last run, still in place while it re-runs (the runner
    swaps the new ones in only after the step returns).

    manifest: their manifest; refusal: why they must not be reused ("" when they may: the
    same config hash and code version, and no forced run). Whether the frames and persons
    still match is the stage's to check."""

    manifest: Manifest
    refusal: str = ""


@dataclass
class StageContext:
    """Everything a step may read. Steps never glob or guess paths."""

    session_dir: Path
    session: SessionConfig
    store: ArtifactStore
    stage: str
    progress_sink: Any = field(default_factory=NullProgress)
    metrics: dict[str, Any] = field(default_factory=dict)
    previous: PreviousRun | None = None
    """This stage's previous artifacts (set by the runner; None when there are none)."""

    def resolve(self, rel: str) -> Path:
        """Resolve a path from session.json (relative to the session folder)."""
        p = Path(rel)
        return p if p.is_absolute() else self.session_dir / p

    @cached_property
    def input_rig(self) -> CameraRig:
        """The session's calibration file at the session's frame rate (``pipeline.io.session_rig``)."""
        from pipeline.io.session_rig import session_rig

        return session_rig(self.session_dir, self.session)

    @cached_property
    def rig(self) -> CameraRig:
        """The rig this stage works with: after ``calibrate``, the one it chose
        (``pipeline.runner.rig``); before, the input calibration."""
        from pipeline.runner.rig import rig_for

        return rig_for(self.stage, self.session_dir, self.session, self.input_rig)

    @cached_property
    def all_annotations(self) -> list[Annotation]:
        return load_annotations(self.session_dir / "annotations.json")

    @property
    def annotations(self) -> list[Annotation]:
        """The active edits consumed by this stage."""
        return annotations_for(self.all_annotations, self.stage)

    def progress(self, done: float, total: float | None = None, message: str = "") -> None:
        self.progress_sink.stage_progress(self.stage, done, total, message)

    def reusable_previous(self, enabled: bool) -> PreviousRun | None:
        """The previous run to build an incremental re-run on, or None; when None, the
        metric ``incremental`` says why (``enabled``: the stage config's ``incremental``)."""
        why = ""
        if not enabled:
            why = "incremental is off"
        elif self.previous is None:
            why = "no previous run"
        else:
            why = self.previous.refusal
        if why:
            self.metrics["incremental"] = f"full run: {why}"
            return None
        return self.previous

    def reusable_with(self, enabled: bool, output: str, what: str) -> PreviousRun | None:
        """``reusable_previous``, and also None when that run did not store ``output`` (a file
        name); the metric ``incremental`` then says it stored no ``what``."""
        prev = self.reusable_previous(enabled)
        if prev is not None and output not in prev.manifest.outputs:
            self.metrics["incremental"] = f"full run: the previous run stored no {what}"
            return None
        return prev

    def load_previous(self, name: str, cls: type) -> Any:
        """``<name>.npz`` of this stage's previous run as schema type ``cls``."""
        return self.store.load(self.stage, name, cls)

    def read_previous_text(self, name: str) -> str:
        """Text file ``name`` of this stage's previous run."""
        return self.store.path(self.stage, name).read_text()

    def load(self, stage: str, name: str, cls: type) -> Any:
        return self.store.load(stage, name, cls)

    def has(self, stage: str, name: str) -> bool:
        return self.store.has(stage, name)


@dataclass(frozen=True)
class StageSpec:
    """Registration of one stage.

    Fields:
        name: stage name (also the artifact folder name).
        deps: upstream stages whose artifacts this stage reads (run first).
        config_cls: the stage's frozen Config dataclass (defaults in one place).
        execute: ``(ctx, cfg) -> {output_name: object}`` (see ``ArtifactStore.write``).
        input_files: ``ctx -> [paths]`` of session inputs hashed into the manifest.
        optional_deps: upstream stages used when enabled and present.
        consumes_annotations: whether annotation edits are part of its inputs.
        uses_rig_fps: whether the session's resolved frame rate is part of its inputs (it
            can change without any file changing: ``pipeline.io.session_rig``).
    """

    name: str
    deps: tuple[str, ...]
    config_cls: type
    execute: Callable[[StageContext, Any], dict[str, Any]]
    input_files: Callable[[StageContext], list[Path]] = lambda ctx: []
    optional_deps: tuple[str, ...] = ()
    consumes_annotations: bool = False
    uses_rig_fps: bool = False
    description: str = ""
