"""HTML sign-in: ``GET/POST /login`` and ``POST /logout`` (the browser side of authentication).

A user signs in with their name and one of their API tokens (``cornerman user create``,
or the tokens ``cornerman serve`` prints on its first start). The server then mints a
login token (``ApiToken`` labelled ``SESSION_LABEL``, expiring after
``Settings.session_max_age_s``) and sets it as the ``cornerman_session`` cookie:
HttpOnly (page scripts cannot read it), SameSite=Strict (other sites' pages, forms and
websockets never carry it) and Secure over HTTPS. The typed token itself never goes into a
URL or a cookie. Scripts keep using ``Authorization: Bearer``.
"""

from __future__ import annotations

from html import escape
from typing import Annotated, Any

from fastapi import APIRouter, Form, HTTPException, Request, status
from fastapi.responses import HTMLResponse, RedirectResponse

from server import crud
from server.api.deps import (
    SESSION_COOKIE,
    SESSION_LABEL,
    CookieUser,
    SessionDep,
    SettingsDep,
    same_origin,
)
from server.core.config import Settings

router = APIRouter(tags=["login"], include_in_schema=False)

LOGIN_CSS = """
body{font-family:system-ui,sans-serif;margin:3rem auto;max-width:24rem;color:#222;background:#fafafa}
h1{font-size:1.4rem}label{display:block;margin:.8rem 0 .2rem}input{width:100%;padding:.4rem;box-sizing:border-box}
button{margin-top:1rem;padding:.4rem 1.2rem;cursor:pointer}.err{color:#c62828}.note{color:#666;font-size:.85rem}
"""


def safe_next(target: str | None) -> str:
    """``target`` when it is a path on this server (``/…``, not ``//host``), else ``/``: no open redirect."""
    if not target or not target.startswith("/") or target.startswith("//") or "\\" in target:
        return "/"
    return target


def _form(next_path: str, error: str = "", name: str = "", who: str = "") -> str:
    err = f'<p class="err">{escape(error)}</p>' if error else ""
    signed = f'<p class="note">Currently signed in as {escape(who)}.</p>' if who else ""
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>cornerman sign in</title>
<style>{LOGIN_CSS}</style></head><body><h1>cornerman — sign in</h1>{signed}{err}
<form method="post" action="/login">
<label for="name">User name</label><input id="name" name="name" autocomplete="username" required value="{escape(name)}">
<label for="token">Token</label><input id="token" name="token" type="password" autocomplete="current-password" required>
<input type="hidden" name="next" value="{escape(next_path)}">
<button type="submit">Sign in</button></form>
<p class="note">The token is the one printed by <code>cornerman serve</code> or <code>cornerman user create</code>.</p>
</body></html>"""


def set_session_cookie(response: Any, request: Request, settings: Settings, value: str) -> None:
    """The login cookie: HttpOnly, SameSite=Strict, Secure over HTTPS (or ``cookie_secure``), path ``/``.

    Strict is enough for this redirect flow: the 303 after the form post and the pages it
    leads to are same-site navigations, which carry Strict cookies.
    """
    response.set_cookie(
        SESSION_COOKIE, value, max_age=int(settings.session_max_age_s), path="/", httponly=True, samesite="strict",
        secure=settings.cookie_secure or request.url.scheme == "https",
    )


@router.get("/login", response_class=HTMLResponse)
def login_page(user: CookieUser, next: str = "/") -> Any:  # noqa: A002  (the query parameter's name)
    return HTMLResponse(_form(safe_next(next), who=f"{user.name} ({user.role})" if user else ""))


@router.post("/login")
def login(
    request: Request,
    db: SessionDep,
    settings: SettingsDep,
    name: Annotated[str, Form(max_length=64)],
    token: Annotated[str, Form(max_length=200)],
    next: Annotated[str, Form(max_length=2000)] = "/",  # noqa: A002
) -> Any:
    """Check ``name`` + ``token``; on success set the login cookie and redirect (303) to ``next``."""
    if not same_origin(request.headers, request.url.scheme):
        raise HTTPException(status_code=status.HTTP_403_FORBIDDEN, detail="cross-origin sign-in refused")
    found = crud.get_token_owner(db, token=token.strip())
    # A login token cannot mint another one: sign-in needs a token the user was given.
    if found is None or found[0].name != name.strip() or found[1].label == SESSION_LABEL:
        return HTMLResponse(_form(safe_next(next), error="Unknown user name or token.", name=name),
                            status_code=status.HTTP_401_UNAUTHORIZED)
    session_token = crud.issue_token(db, user=found[0], label=SESSION_LABEL)
    resp = RedirectResponse(safe_next(next), status_code=status.HTTP_303_SEE_OTHER)
    set_session_cookie(resp, request, settings, session_token)
    return resp


@router.post("/logout")
def logout(request: Request, db: SessionDep) -> Any:
    """Revoke the login token of this browser, delete its cookie, go back to ``/login``."""
    if not same_origin(request.headers, request.url.scheme):
        raise HTTPException(status_code=status.HTTP_403_FORBIDDEN, detail="cross-origin sign-out refused")
    token = request.cookies.get(SESSION_COOKIE)
    if token:
        found = crud.get_token_owner(db, token=token)
        if found is not None and found[1].label == SESSION_LABEL:
            crud.revoke_token(db, token=token)
    resp = RedirectResponse("/login", status_code=status.HTTP_303_SEE_OTHER)
    resp.delete_cookie(SESSION_COOKIE, path="/", httponly=True, samesite="strict")
    return resp
