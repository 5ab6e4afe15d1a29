"""``Annotated`` dependencies: database session, settings, current user, role checks."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlmodel import Session

from server import crud
from server.core.config import Settings
from server.core.security import role_at_least
from server.models import Bout, User

bearer = HTTPBearer(auto_error=False, description="API token (`cornerman user create NAME --role ROLE`)")
TOKEN_COOKIE = "cornerman_token"


def get_settings(request: Request) -> Settings:
    return request.app.state.settings  # type: ignore[no-any-return]


def get_db(request: Request) -> Iterator[Session]:
    with Session(request.app.state.engine, expire_on_commit=False) as session:
        yield session


SettingsDep = Annotated[Settings, Depends(get_settings)]
SessionDep = Annotated[Session, Depends(get_db)]


def get_token(request: Request, creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]) -> str:
    """The bearer token (HTML pages may also pass ``?token=`` or the ``cornerman_token`` cookie)."""
    if creds is not None and creds.scheme.lower() == "bearer" and creds.credentials:
        return creds.credentials
    token = request.query_params.get("token") or request.cookies.get(TOKEN_COOKIE)
    if token:
        return token
    raise HTTPException(
        status_code=status.HTTP_401_UNAUTHORIZED,
        detail="missing API token: send 'Authorization: Bearer <token>'",
        headers={"WWW-Authenticate": "Bearer"},
    )


TokenDep = Annotated[str, Depends(get_token)]


def get_current_user(db: SessionDep, token: TokenDep) -> User:
    user = crud.get_user_by_token(db, token=token)
    if user is None:
        raise HTTPException(
            status_code=status.HTTP_401_UNAUTHORIZED,
            detail="invalid API token",
            headers={"WWW-Authenticate": "Bearer"},
        )
    return user


CurrentUser = Annotated[User, Depends(get_current_user)]


def _require(role: str):  # noqa: ANN202  (returns a FastAPI dependency)
    def check(user: CurrentUser) -> User:
        if not role_at_least(user.role, role):
            raise HTTPException(
                status_code=status.HTTP_403_FORBIDDEN,
                detail=f"this needs the {role!r} role; user {user.name!r} is {user.role!r}",
            )
        return user

    return check


AnnotatorUser = Annotated[User, Depends(_require("annotator"))]
AdminUser = Annotated[User, Depends(_require("admin"))]


def get_bout_or_404(db: Session, bout_id: int) -> Bout:
    bout = crud.get_bout(db, bout_id=bout_id)
    if bout is None:
        raise HTTPException(status_code=status.HTTP_404_NOT_FOUND, detail=f"session {bout_id} not found")
    return bout


def bout_dir(bout: Bout) -> Path:
    return Path(bout.folder)
