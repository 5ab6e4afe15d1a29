"""The export formats: one table the CLI, the REST API and the viewer all read."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass

from pipeline.io.export.selection import ExportSelection

Files = dict[str, bytes]
"""File name (no folders) -> contents; several files are written as one ZIP."""


@dataclass(frozen=True)
class ExportFormat:
    """One export format.

    Fields:
        name: the ``--format`` value.
        suffix: file suffix of one written file (without the dot).
        media_type: HTTP content type of one file.
        summary: one line for ``--help`` and the API docs.
        builder: ``"module:function"`` taking an ``ExportSelection`` and returning ``Files``
            (imported on first use, so a format's library loads only when it is asked for).
    """

    name: str
    suffix: str
    media_type: str
    summary: str
    builder: str

    def build(self, sel: ExportSelection) -> Files:
        """The files of this format for ``sel``; ``LookupError`` when its stage has not run,
        ``ValueError`` for a selection it cannot write."""
        module, func = self.builder.split(":")
        fn: Callable[[ExportSelection], Files] = getattr(importlib.import_module(module), func)
        return fn(sel)


FORMATS: dict[str, ExportFormat] = {
    f.name: f
    for f in (
        ExportFormat("json", "json", "application/json",
                     "3D keypoints as the README's JSON (metres, world z-up)",
                     "pipeline.io.export.keypoints:build_json"),
        ExportFormat("npz", "npz", "application/octet-stream",
                     "3D keypoints as NumPy arrays (the Keypoints3D fields)",
                     "pipeline.io.export.keypoints:build_npz"),
        ExportFormat("bvh", "bvh", "text/plain",
                     "body fit as BVH per athlete: anny rig, fitted rotations (centimetres, y-up, ZXY Euler)",
                     "pipeline.io.export.bvh:build_bvh"),
        ExportFormat("params", "npz", "application/octet-stream",
                     "body-model parameters of the fit (anny phenotypes + pose, or SMPL/SMPL-X betas/pose/transl)",
                     "pipeline.io.export.params:build_params"),
        ExportFormat("csv", "csv", "text/csv",
                     "3D keypoints as a long table: one row per frame, athlete and joint (metres, world z-up)",
                     "pipeline.io.export.tables:build_csv"),
        ExportFormat("trc", "trc", "text/plain",
                     "3D keypoints as OpenSim/Pose2Sim TRC markers (metres, y-up)",
                     "pipeline.io.export.trc:build_trc"),
        ExportFormat("c3d", "c3d", "application/octet-stream",
                     "3D keypoints as C3D labelled points (millimetres, world z-up; empty analog block)",
                     "pipeline.io.export.c3d_export:build_c3d"),
        ExportFormat("mujoco", "zip", "application/zip",
                     "physics: scene.xml + qpos/qvel/ctrl per frame (motion.npz) + replay.py, as a ZIP",
                     "pipeline.io.export.mjcf:build_mujoco"),
        ExportFormat("gltf", "glb", "model/gltf-binary",
                     "body fit as a GLB: skinned, animated anny mesh per athlete (decimated), floor, cameras (metres, y-up)",
                     "pipeline.io.export.gltf:build_gltf"),
        ExportFormat("gltf-full", "glb", "model/gltf-binary",
                     "as gltf, with anny's full 13,718-vertex body mesh",
                     "pipeline.io.export.gltf:build_gltf_full"),
    )
}


def format_names() -> list[str]:
    """Every ``--format`` value, in table order."""
    return list(FORMATS)


def get_format(name: str) -> ExportFormat:
    """The format called ``name``; ``ValueError`` listing the choices otherwise."""
    try:
        return FORMATS[name]
    except KeyError:
        raise ValueError(f"unknown export format {name!r}; choose one of {', '.join(FORMATS)}") from None


def export_files(sel: ExportSelection, fmt: str) -> Files:
    """The files of format ``fmt`` for ``sel`` (see ``ExportFormat.build``)."""
    return get_format(fmt).build(sel)
