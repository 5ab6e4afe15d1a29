"""The viewer's Export panel against a real viser server (no browser): it offers every registry
format, and Download sends exactly the bytes the export registry builds for the session."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path
from typing import Any

import pytest
import viser

from pipeline.io.export import FORMATS, ExportSelection, export_files
from pipeline.io.export.write import bundle
from tests.webui.fixtures import build_session
from webui.app import ViewerApp


def _press(
    app: ViewerApp, server: viser.ViserServer, monkeypatch: pytest.MonkeyPatch, fmt: str, frames: str = ""
) -> list[tuple[str, bytes]]:
    sent: list[tuple[str, bytes]] = []

    def capture(filename: str, content: bytes, **_: Any) -> None:
        sent.append((filename, content))

    monkeypatch.setattr(server, "send_file_download", capture)
    app.export.format.value = fmt
    app.export.frames.value = frames
    app.export.download.value = True  # a press without a client goes to every client
    return sent


def test_download_sends_the_registry_bytes(
    tmp_path: Path, server: viser.ViserServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    sdir = build_session(tmp_path, n_frames=10, physics=True)
    app = ViewerApp(server, sdir, role="coach", max_image_width=160)
    try:
        assert app.export.format.options == tuple(FORMATS)
        assert {"json", "csv", "trc", "c3d", "mujoco"} <= set(app.export.format.options)
        names = {0: "Red", 1: "Blue"}
        # The fixture's physics scene is two balls, not humanoids: a C3D of the physics source
        # (which carries the floor forces of the humanoids) cannot be built from it.
        app.display.source.value = "Filtered"
        for fmt, frames in (("csv", ""), ("trc", ""), ("c3d", "3:7"), ("json", "")):
            sent = _press(app, server, monkeypatch, fmt, frames)
            sel = ExportSelection(sdir, app.opts.source, (), (3, 7) if frames else None, names)
            want = export_files(sel, fmt)
            assert sent == [(next(iter(want)), next(iter(want.values())))], fmt
            assert "Sent" in app.export.status.content
        sent = _press(app, server, monkeypatch, "mujoco")
        assert len(sent) == 1 and sent[0][0] == f"{sdir.name}_mujoco.zip"
        assert sent[0][1] == bundle(export_files(ExportSelection(sdir, names=names), "mujoco"))
        assert sorted(zipfile.ZipFile(io.BytesIO(sent[0][1])).namelist()) == [
            "motion.npz",
            "replay.py",
            "scene.xml",
        ]
        # The display's source decides what keypoint formats write.
        app.display.source.value = "Physics"
        sent = _press(app, server, monkeypatch, "csv")
        assert sent[0][0] == "keypoints3d_physics.csv"
    finally:
        app.close()


def test_download_reports_what_cannot_be_exported(
    tmp_path: Path, server: viser.ViserServer, monkeypatch: pytest.MonkeyPatch
) -> None:
    sdir = build_session(tmp_path, n_frames=8, physics=False)
    app = ViewerApp(server, sdir, role="coach", max_image_width=160)
    try:
        assert _press(app, server, monkeypatch, "mujoco") == []
        assert "Cannot export mujoco" in app.export.status.content and "physics" in app.export.status.content
        assert _press(app, server, monkeypatch, "csv", frames="7") == []
        assert "FIRST:STOP" in app.export.status.content
    finally:
        app.close()
