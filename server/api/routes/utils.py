"""Routes: health, current user and user/token administration."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException, status

from pipeline import __version__
from server import crud
from server.api.deps import AdminUser, CurrentUser, SessionDep
from server.models import UserCreate, UserPublic, UserWithToken

router = APIRouter(tags=["users"])


@router.get("/health", tags=["health"])
def health() -> dict[str, Any]:
    """Liveness probe (no token needed)."""
    return {"status": "ok", "version": __version__}


@router.get("/export-formats", tags=["results"])
def export_formats() -> list[dict[str, str]]:
    """The export formats ``GET /sessions/{id}/export?format=`` accepts, with suffix and summary."""
    from pipeline.io.export import FORMATS

    return [{"name": f.name, "suffix": f.suffix, "media_type": f.media_type, "summary": f.summary} for f in FORMATS.values()]


@router.get("/me", response_model=UserPublic)
def me(user: CurrentUser) -> Any:
    return user


@router.get("/users", response_model=list[UserPublic])
def list_users(db: SessionDep, _: AdminUser) -> Any:
    return crud.list_users(db)


@router.post("/users", response_model=UserWithToken, status_code=status.HTTP_201_CREATED)
def create_user(db: SessionDep, _: AdminUser, user_in: UserCreate) -> Any:
    """Create a user and return its first API token (shown only once)."""
    try:
        user = crud.create_user(db, user_in=user_in)
    except ValueError as e:
        raise HTTPException(status_code=status.HTTP_409_CONFLICT, detail=str(e)) from e
    token = crud.issue_token(db, user=user, label="created over the API")
    return UserWithToken(**UserPublic.model_validate(user).model_dump(), token=token)


@router.post("/users/{name}/tokens", response_model=UserWithToken, status_code=status.HTTP_201_CREATED)
def new_token(db: SessionDep, _: AdminUser, name: str) -> Any:
    user = crud.get_user_by_name(db, name=name)
    if user is None:
        raise HTTPException(status_code=status.HTTP_404_NOT_FOUND, detail=f"user {name!r} not found")
    token = crud.issue_token(db, user=user, label="issued over the API")
    return UserWithToken(**UserPublic.model_validate(user).model_dump(), token=token)
