"""Routes: results: exports in every format, 3D keypoints download (JSON/NPZ), raw artifacts, metrics."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query, status
from fastapi.responses import FileResponse, Response

from pipeline.io.export import KeypointSource
from server import crud
from server.api.deps import CurrentUser, SessionDep, bout_dir, get_bout_or_404
from server.storage import safe_filename

router = APIRouter(prefix="/sessions/{session_id}", tags=["results"])

Source = KeypointSource  # the same choices as ``cornerman export --source``


def find_keypoints3d(session_dir: Path, source: str) -> tuple[Any, str]:
    """The ``Keypoints3D`` of ``source`` and the source chosen (see ``pipeline.io.export``)."""
    from pipeline.io.export import find_keypoints3d as find

    return find(session_dir, source)


@router.get("/results/keypoints3d")
def download_keypoints3d(
    db: SessionDep,
    _: CurrentUser,
    session_id: int,
    source: Annotated[Source, Query(description="best = fit, else filtered; latest = physics, else fit, else filtered")] = "best",
    format: Annotated[Literal["json", "npz"], Query()] = "json",
) -> Response:
    """3D keypoints of every athlete (metres, world z-up) as the README's JSON or an NPZ."""
    from pipeline.io.export import export_keypoints3d

    bout = get_bout_or_404(db, session_id)
    try:
        kp, chosen = find_keypoints3d(bout_dir(bout), source)
    except LookupError as e:
        raise HTTPException(status_code=status.HTTP_404_NOT_FOUND, detail=str(e)) from e
    names = {i.person_id: i.name for i in crud.list_identities(db, bout_id=session_id)}
    data = export_keypoints3d(kp, format, names)
    media = "application/json" if format == "json" else "application/octet-stream"
    fname = f"session{session_id}_keypoints3d_{chosen}.{format}"
    return Response(content=data, media_type=media,
                    headers={"Content-Disposition": f'attachment; filename="{fname}"', "X-Cornerman-Source": chosen})


@router.get("/export")
def download_export(
    db: SessionDep,
    _: CurrentUser,
    session_id: int,
    format: Annotated[str, Query(description="an export format: json, npz, ... (GET /api/export-formats lists them)")] = "json",
    source: Annotated[Source, Query(description="3D source for keypoint formats (as `cornerman export --source`)")] = "best",
    athlete: Annotated[list[int] | None, Query(description="person ids, repeated; default every athlete")] = None,
    frames: Annotated[str | None, Query(description="video frames FIRST:STOP, STOP excluded")] = None,
) -> Response:
    """The session's results in one export format (a ZIP when the format writes several files),
    exactly as ``cornerman export --format`` writes them."""
    from pipeline.io.export import ExportSelection, export_files, get_format, parse_frames
    from pipeline.io.export.write import bundle

    bout = get_bout_or_404(db, session_id)
    names = {i.person_id: i.name for i in crud.list_identities(db, bout_id=session_id)}
    try:
        fmt = get_format(format)
        sel = ExportSelection(bout_dir(bout), source, tuple(athlete or ()), parse_frames(frames), names)
        files = export_files(sel, fmt.name)
    except LookupError as e:
        raise HTTPException(status_code=status.HTTP_404_NOT_FOUND, detail=str(e)) from e
    except ValueError as e:
        raise HTTPException(status_code=status.HTTP_422_UNPROCESSABLE_CONTENT, detail=str(e)) from e
    if len(files) == 1:
        fname, media = next(iter(files)), fmt.media_type
    else:
        fname, media = f"session{session_id}_{fmt.name}.zip", "application/zip"
    return Response(content=bundle(files), media_type=media,
                    headers={"Content-Disposition": f'attachment; filename="{fname}"'})


@router.get("/results/{stage}/{artifact}")
def download_artifact(db: SessionDep, _: CurrentUser, session_id: int, stage: str, artifact: str) -> FileResponse:
    """A raw artifact file of a complete stage (one listed in its manifest, or the manifest)."""
    from pipeline.artifacts import ArtifactStore
    from pipeline.runner.registry import STAGE_ORDER

    if stage not in STAGE_ORDER:
        raise HTTPException(status_code=status.HTTP_404_NOT_FOUND, detail=f"unknown stage {stage!r}; known: {list(STAGE_ORDER)}")
    try:
        artifact = safe_filename(artifact, "artifact name")
    except ValueError as e:
        raise HTTPException(status_code=status.HTTP_400_BAD_REQUEST, detail=str(e)) from e
    bout = get_bout_or_404(db, session_id)
    store = ArtifactStore(bout_dir(bout))
    m = store.manifest(stage)
    if m is None:
        raise HTTPException(status_code=status.HTTP_404_NOT_FOUND, detail=f"stage {stage!r} has no complete artifacts")
    if artifact != "manifest.json" and artifact not in m.outputs:
        raise HTTPException(status_code=status.HTTP_404_NOT_FOUND,
                            detail=f"stage {stage!r} has no artifact {artifact!r}; it has {sorted(m.outputs)}")
    return FileResponse(store.stage_dir(stage) / artifact, filename=f"{stage}_{artifact}")


@router.get("/metrics")
def metrics(db: SessionDep, _: CurrentUser, session_id: int) -> dict[str, Any]:
    """``{stage: manifest.metrics}`` for each stage with complete artifacts."""
    from pipeline.artifacts import ArtifactStore
    from pipeline.runner.registry import STAGE_ORDER

    bout = get_bout_or_404(db, session_id)
    store = ArtifactStore(bout_dir(bout))
    out: dict[str, Any] = {}
    for stage in STAGE_ORDER:
        m = store.manifest(stage)
        if m is not None:
            out[stage] = {**m.metrics, "duration_s": round(m.duration_s, 3)}
    return out
