"""Exports of a session's results in the formats other tools open.

One registry (``FORMATS``) serves the CLI (``cornerman export --format F``), the REST download
endpoint and the viewer's download button. Each format turns an ``ExportSelection`` (session,
source, athletes, frames) into named files; one file is written as is, several as a ZIP.
Units and axes are stated in each format's own module docstring and in the file it writes.
"""

from __future__ import annotations

from pipeline.io.export.keypoints import (
    JSON_FORMAT_ID,
    KEYPOINTS3D_ARTIFACTS,
    SOURCE_ORDER,
    KeypointSource,
    export_keypoints3d,
    find_keypoints3d,
    keypoints3d_to_json,
    write_export,
)
from pipeline.io.export.registry import FORMATS, ExportFormat, export_files, format_names, get_format
from pipeline.io.export.selection import ExportSelection, parse_frames
from pipeline.io.export.write import default_out, write_files

__all__ = [
    "FORMATS",
    "JSON_FORMAT_ID",
    "KEYPOINTS3D_ARTIFACTS",
    "SOURCE_ORDER",
    "ExportFormat",
    "ExportSelection",
    "KeypointSource",
    "default_out",
    "export_files",
    "export_keypoints3d",
    "find_keypoints3d",
    "format_names",
    "get_format",
    "keypoints3d_to_json",
    "parse_frames",
    "write_export",
    "write_files",
]
