"""Export panel: a format dropdown (every format of ``pipeline.io.export.FORMATS``), an optional
frame range and a Download button that builds the viewer session's files with the export
registry and sends them to the browser (one file as is, several as one ZIP)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import viser

from pipeline.io.export import FORMATS, KEYPOINTS3D_ARTIFACTS, ExportSelection, export_files, parse_frames
from pipeline.io.export.write import bundle
from webui.scope import Scope


@dataclass
class ExportHandles:
    format: viser.GuiDropdownHandle[str]
    frames: viser.GuiTextHandle
    download: viser.GuiButtonHandle
    status: viser.GuiMarkdownHandle


def make_export(server: Scope) -> ExportHandles:
    """The Export folder: format (``--format`` names), frames (``FIRST:STOP``, empty = all), Download."""
    with server.gui.add_folder("Export"):
        names = tuple(FORMATS)
        fmt = server.gui.add_dropdown("Format", names, initial_value=names[0])
        frames = server.gui.add_text(
            "Frames", "", hint="video frames FIRST:STOP (STOP excluded); empty = all"
        )
        download = server.gui.add_button("Download", icon=viser.Icon.DOWNLOAD)
        status = server.gui.add_markdown(FORMATS[names[0]].summary)
    fmt.on_update(lambda _: setattr(status, "content", FORMATS[fmt.value].summary))
    return ExportHandles(fmt, frames, download, status)


def export_download(
    session_dir: Path, fmt: str, names: dict[int, str], source: str = "best", frames: str = ""
) -> tuple[str, bytes]:
    """The file name and bytes the Download button sends: the registry's files of ``fmt`` for the
    whole session (every athlete), ``source`` for keypoint formats (``best`` when it is not a 3D
    result name), ``frames`` as ``FIRST:STOP``. ``LookupError`` / ``ValueError`` as the registry."""
    src = source if source in KEYPOINTS3D_ARTIFACTS else "best"
    files = export_files(ExportSelection(Path(session_dir), src, (), parse_frames(frames), names), fmt)
    name = next(iter(files)) if len(files) == 1 else f"{Path(session_dir).name}_{fmt}.zip"
    return name, bundle(files)


def wire_export(
    h: ExportHandles,
    server: Scope,
    session_dir: Path,
    names: Callable[[], dict[int, str]],
    source: Callable[[], str],
) -> None:
    """Download sends the file to the client that pressed it (to every client when none did)."""

    @h.download.on_click
    def _(event: Any) -> None:
        try:
            name, data = export_download(session_dir, h.format.value, names(), source(), h.frames.value)
        except (LookupError, ValueError) as e:
            h.status.content = f"**Cannot export {h.format.value}:** {e}"
            return
        target = event.client if getattr(event, "client", None) is not None else server
        target.send_file_download(name, data, save_immediately=True)
        h.status.content = f"Sent `{name}` ({len(data) / 1024:.0f} KiB)."
