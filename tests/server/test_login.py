"""Browser sign-in: /login sets an HttpOnly, SameSite=Strict cookie holding a server-side login
token; tokens are never read from URLs; logout and expiry revoke it; cross-origin posts are refused."""

from __future__ import annotations

import logging
from datetime import timedelta
from http.cookies import SimpleCookie

import httpx
from fastapi.testclient import TestClient
from sqlmodel import Session, select

from server.api.deps import SESSION_COOKIE, SESSION_LABEL
from server.core.security import RedactTokens, hash_token, redact
from server.models import ApiToken, utcnow
from tests.server.conftest import auth


def _login(client: TestClient, name: str, token: str, next_path: str = "/") -> httpx.Response:
    return client.post("/login", data={"name": name, "token": token, "next": next_path}, follow_redirects=False)


def _set_cookie(resp: httpx.Response) -> SimpleCookie:
    jar: SimpleCookie = SimpleCookie()
    jar.load(resp.headers["set-cookie"])
    return jar


def test_login_sets_an_httponly_strict_cookie_that_is_not_the_token(client: TestClient, tokens: dict) -> None:
    page = client.get("/login")
    assert page.status_code == 200 and 'name="token"' in page.text and 'type="password"' in page.text
    r = _login(client, "annotator1", tokens["annotator"], "/viewer/1/")
    assert r.status_code == 303 and r.headers["location"] == "/viewer/1/"
    morsel = _set_cookie(r)[SESSION_COOKIE]
    assert morsel["httponly"] is True and morsel["samesite"] == "strict" and morsel["path"] == "/"
    assert int(morsel["max-age"]) > 0 and not morsel["secure"]  # plain HTTP here: no Secure flag
    assert morsel.value != tokens["annotator"] and tokens["annotator"] not in r.headers["set-cookie"]
    # the cookie signs the browser in, to the pages and to the API
    assert client.get("/api/me").json()["name"] == "annotator1"
    picker = client.get("/")
    assert picker.status_code == 200 and "signed in as annotator1 (annotator)" in picker.text
    assert tokens["annotator"] not in picker.text and morsel.value not in picker.text  # no token in the page


def test_wrong_name_or_token_gets_no_cookie(client: TestClient, tokens: dict) -> None:
    for name, token in (("annotator1", "cm_wrong"), ("coach1", tokens["annotator"]), ("nobody", tokens["coach"])):
        r = _login(client, name, token)
        assert r.status_code == 401 and "Unknown user name or token" in r.text
        assert "set-cookie" not in r.headers
    assert client.get("/api/me").status_code == 401


def test_tokens_in_urls_are_ignored(client: TestClient, tokens: dict) -> None:
    r = client.get("/", params={"token": tokens["admin"]}, follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/login" and "set-cookie" not in r.headers
    assert client.get("/api/me", params={"token": tokens["admin"]}).status_code == 401
    assert client.get("/api/me", headers=auth(tokens["admin"])).json()["role"] == "admin"  # scripts: bearer


def test_logout_revokes_the_login_token(client: TestClient, tokens: dict) -> None:
    r = _login(client, "coach1", tokens["coach"])
    value = _set_cookie(r)[SESSION_COOKIE].value
    assert client.get("/api/me").status_code == 200
    out = client.post("/logout", follow_redirects=False)
    assert out.status_code == 303 and out.headers["location"] == "/login"
    assert SESSION_COOKIE in out.headers["set-cookie"] and "Max-Age=0" in out.headers["set-cookie"]
    client.cookies.clear()
    client.cookies.set(SESSION_COOKIE, value)  # a copy of the cookie kept from before the logout
    assert client.get("/api/me").status_code == 401  # revoked server-side
    client.cookies.clear()
    assert client.get("/api/me", headers=auth(tokens["coach"])).status_code == 200  # the user's token still works


def test_login_token_expires(client: TestClient, tokens: dict, app) -> None:  # noqa: ANN001
    value = _set_cookie(_login(client, "coach1", tokens["coach"]))[SESSION_COOKIE].value
    assert client.get("/api/me").status_code == 200
    with Session(app.state.engine) as db:
        row = db.exec(select(ApiToken).where(ApiToken.token_hash == hash_token(value))).one()
        assert row.label == SESSION_LABEL
        row.created_at = utcnow() - timedelta(seconds=app.state.settings.session_max_age_s + 5)
        db.add(row)
        db.commit()
    assert client.get("/api/me").status_code == 401
    assert client.get("/", follow_redirects=False).headers["location"] == "/login"


def test_a_login_token_cannot_sign_in_again(client: TestClient, tokens: dict) -> None:
    value = _set_cookie(_login(client, "coach1", tokens["coach"]))[SESSION_COOKIE].value
    client.cookies.clear()
    assert _login(client, "coach1", value).status_code == 401


def test_cross_origin_posts_with_the_cookie_are_refused(client: TestClient, tokens: dict) -> None:
    evil = {"Origin": "http://evil.example"}
    r = client.post("/login", data={"name": "admin1", "token": tokens["admin"]}, headers=evil, follow_redirects=False)
    assert r.status_code == 403 and "set-cookie" not in r.headers
    _login(client, "admin1", tokens["admin"])
    r = client.post("/api/users", json={"name": "mallory", "role": "admin"}, headers=evil)
    assert r.status_code == 403 and "cross-origin" in r.json()["detail"]
    r = client.post("/api/users", json={"name": "alice", "role": "coach"}, headers={"Origin": "http://testserver"})
    assert r.status_code == 201  # same origin (the picker's own scripts) is fine


def test_next_is_a_local_path_only(client: TestClient, tokens: dict) -> None:
    for bad in ("//evil.example/x", "https://evil.example/", "javascript:alert(1)"):
        r = _login(client, "coach1", tokens["coach"], bad)
        assert r.status_code == 303 and r.headers["location"] == "/"


def test_redaction_of_log_records() -> None:
    assert redact('GET /?token=cm_abcdefgh123456 HTTP/1.1') == "GET /?token=*** HTTP/1.1"
    assert redact("a=1&access_token=xyz&b=2") == "a=1&access_token=***&b=2"
    assert redact("Bearer cm_AbC-dEf_0123456789") == "Bearer cm_***"
    assert redact("GET /api/sessions?limit=5") == "GET /api/sessions?limit=5"
    # uvicorn's access formatter unpacks the record's args: they keep their shape
    rec = logging.LogRecord("uvicorn.access", logging.INFO, "", 0, '%s - "%s %s HTTP/%s" %d',
                            ("127.0.0.1:5", "GET", "/?token=cm_secret123456", "1.1", 303), None)
    assert RedactTokens().filter(rec)
    assert rec.args == ("127.0.0.1:5", "GET", "/?token=***", "1.1", 303)
    assert "cm_secret" not in rec.getMessage()
