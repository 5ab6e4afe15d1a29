"""A stage's code version follows the code it runs (pipeline.runner.code_version)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from pipeline.runner import code_version as cv
from pipeline.runner import run, stage_status
from pipeline.runner.registry import STAGE_ORDER

_READ_TEXT = Path.read_text


@pytest.fixture(autouse=True)
def _fresh_caches() -> None:
    for f in (cv._module_digest, cv.stage_code_hash, cv._source_path):
        f.cache_clear()


def test_the_closure_reaches_the_lazily_imported_backends() -> None:
    physics = cv.module_closure("pipeline.runner.steps.physics")
    assert {"pipeline.stages.physics", "pipeline.backends.mujoco.ilqr", "pipeline.backends.mujoco.tracking"} <= set(physics)
    fit = cv.module_closure("pipeline.runner.steps.fit")
    assert "pipeline.backends.anny.fit" in fit and "pipeline.backends.mujoco.ilqr" not in fit
    assert len({cv.stage_code_hash(s) for s in STAGE_ORDER}) == len(STAGE_ORDER)


def _patched_reader(monkeypatch: pytest.MonkeyPatch, module: str, edit: str) -> None:
    """Make ``module``'s source read as if ``edit`` were appended to it."""
    path = cv._source_path(module)
    assert path is not None
    def read_text(self: Path, *a: object, **k: object) -> str:
        text = _READ_TEXT(self, *a, **k)  # type: ignore[arg-type]
        return text + edit if self == path else text

    monkeypatch.setattr(Path, "read_text", read_text)
    for f in (cv._module_digest, cv.stage_code_hash):
        f.cache_clear()


def test_code_changes_and_only_code_changes_change_the_version(monkeypatch: pytest.MonkeyPatch) -> None:
    before = {s: cv.stage_code_hash(s) for s in ("triangulate", "physics")}
    _patched_reader(monkeypatch, "pipeline.backends.mujoco.ilqr", "\n# a comment\n")
    assert cv.stage_code_hash("physics") == before["physics"]
    _patched_reader(monkeypatch, "pipeline.backends.mujoco.ilqr", '\n\ndef _f() -> None:\n    """A docstring."""\n')
    with_doc = cv.stage_code_hash("physics")
    _patched_reader(monkeypatch, "pipeline.backends.mujoco.ilqr", '\n\ndef _f() -> None:\n    """Other words."""\n')
    assert cv.stage_code_hash("physics") == with_doc  # docstrings do not count
    _patched_reader(monkeypatch, "pipeline.backends.mujoco.ilqr", "\nMU_INIT_SCALE = 2.0\n")
    assert cv.stage_code_hash("physics") != before["physics"]  # code does
    assert cv.stage_code_hash("triangulate") == before["triangulate"]  # not its module


def test_a_code_change_makes_the_stage_stale(tiny_session: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    run(tiny_session)
    assert set(stage_status(tiny_session).values()) == {"fresh"}
    _patched_reader(monkeypatch, "pipeline.stages.track", "\nEXTRA = 1\n")
    st = stage_status(tiny_session)
    assert st["detect2d"] == "fresh" and st["track"] == "stale"
    reports = run(tiny_session)
    assert [r.action for r in reports] == ["skipped", "ran"]


def test_relative_imports_are_followed() -> None:
    tree = ast.parse("from .b import c\nfrom .. import d\n")
    assert cv._imports(tree, "pipeline.stages.a", False) >= {"pipeline.stages.b", "pipeline"}
