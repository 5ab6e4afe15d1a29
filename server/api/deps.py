"""``Annotated`` dependencies: database session, settings, current user (bearer token or login cookie), role checks."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from datetime import UTC, datetime
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
SESSION_COOKIE = "cornerman_session"
"""The browser login cookie (HttpOnly, SameSite=Strict): a server-side token labelled ``SESSION_LABEL``."""
SESSION_LABEL = "session"
"""``ApiToken.label`` of the tokens ``POST /login`` mints; they expire after ``Settings.session_max_age_s``."""
VIEWER_LABEL_PREFIX = "viewer:"
"""``ApiToken.label`` prefix of the tokens the viewer proxy mints per websocket connection (expire like login tokens)."""
SAFE_METHODS = ("GET", "HEAD", "OPTIONS")


def get_settings(request: Request) -> Settings:
    return request.app.state.settings  # type: ignore[no-any-return]


def get_db(request: Request) -> Iterator[Session]:
    with Session(request.app.state.engine, expire_on_commit=False) as session:
        yield session


SettingsDep = Annotated[Settings, Depends(get_settings)]
SessionDep = Annotated[Session, Depends(get_db)]


def same_origin(headers: Mapping[str, str], scheme: str) -> bool:
    """False when the request names an ``Origin`` other than the host it was sent to (a cross-site form
    post or websocket); True without an ``Origin`` header (curl, scripts) or when it matches."""
    origin = headers.get("origin")
    if origin is None:
        return True
    host = headers.get("host", "")
    return origin in (f"{scheme}://{host}", f"{scheme.replace('ws', 'http')}://{host}")


def get_token(request: Request, creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]) -> str:
    """The bearer token, or for browsers the login cookie. Never a query parameter: tokens stay out of
    URLs (and so out of access logs and browser history)."""
    if creds is not None and creds.scheme.lower() == "bearer" and creds.credentials:
        return creds.credentials
    token = request.cookies.get(SESSION_COOKIE)
    if token:
        if request.method not in SAFE_METHODS and not same_origin(request.headers, request.url.scheme):
            raise HTTPException(status_code=status.HTTP_403_FORBIDDEN,
                                detail="cross-origin request with the login cookie refused")
        return token
    raise HTTPException(
        status_code=status.HTTP_401_UNAUTHORIZED,
        detail="missing API token: send 'Authorization: Bearer <token>' (browsers: sign in at /login)",
        headers={"WWW-Authenticate": "Bearer"},
    )


TokenDep = Annotated[str, Depends(get_token)]


def user_of_token(db: Session, token: str, settings: Settings) -> User | None:
    """The user a token (API token or login-cookie token) belongs to; None when it is unknown or is a
    login token or a viewer connection's token (label ``viewer:<session>``, revoked when the connection
    ends; this bounds one a crash left behind) older than ``settings.session_max_age_s`` (then deleted)."""
    found = crud.get_token_owner(db, token=token)
    if found is None:
        return None
    user, row = found
    if row.label == SESSION_LABEL or row.label.startswith(VIEWER_LABEL_PREFIX):
        created = row.created_at if row.created_at.tzinfo else row.created_at.replace(tzinfo=UTC)
        if (datetime.now(UTC) - created).total_seconds() > settings.session_max_age_s:
            crud.revoke_token(db, token=token)
            return None
    return user


def get_current_user(db: SessionDep, settings: SettingsDep, token: TokenDep) -> User:
    user = user_of_token(db, token, settings)
    if user is None:
        raise HTTPException(
            status_code=status.HTTP_401_UNAUTHORIZED,
            detail="invalid API token",
            headers={"WWW-Authenticate": "Bearer"},
        )
    return user


CurrentUser = Annotated[User, Depends(get_current_user)]


def get_cookie_user(request: Request, db: SessionDep, settings: SettingsDep) -> User | None:
    """The signed-in browser user (login cookie only), or None: HTML pages redirect to ``/login`` then."""
    token = request.cookies.get(SESSION_COOKIE)
    return user_of_token(db, token, settings) if token else None


CookieUser = Annotated[User | None, Depends(get_cookie_user)]


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
