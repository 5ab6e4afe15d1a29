"""The viewer behind the login, end to end: real uvicorn (access log captured), real SQLite, real
viser viewer processes started by the app and reached only through ``/viewer/{id}/``.

Checks: no cookie, no viewer (page redirects to /login, files 401, websocket handshake 403);
after sign-in the page loads through the proxy and its websocket relays viser's messages; one
viewer per session listens on 127.0.0.1 only and serves every user, each connection with a token
of its signed-in user minted for it (coach and annotator clients of the same viewer join with
their own names and roles) and revoked when it closes; no token ever appears in the server's log.
"""

from __future__ import annotations

import importlib.metadata
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import closing
from dataclasses import dataclass
from http.cookies import SimpleCookie
from pathlib import Path

import httpx
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import ClientConnection, connect
from websockets.typing import Subprotocol

from server.api.deps import SESSION_COOKIE
from server.cli import create_user
from server.loadtest import free_port
from server.viewer_bench import camera_message
from tests.live_server import stop_server, wait_until_healthy
from tests.webui.fixtures import build_session

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(300)]

VISER_PROTOCOL = f"viser-v{importlib.metadata.version('viser')}"
ROLES = ("coach", "annotator", "admin")


@dataclass
class Server:
    base: str
    log_path: Path
    tokens: dict[str, str]
    session_id: int
    other_session_id: int
    session_dir: Path
    other_dir: Path
    home: Path = Path()

    def api(self, role: str) -> httpx.Client:
        return httpx.Client(base_url=self.base + "/api", headers={"Authorization": f"Bearer {self.tokens[role]}"},
                            timeout=30)

    def login(self, role: str) -> tuple[httpx.Client, SimpleCookie]:
        """A browser-like client signed in as ``role`` and the Set-Cookie header it got."""
        c = httpx.Client(base_url=self.base, timeout=150)
        r = c.post("/login", data={"name": f"u-{role}", "token": self.tokens[role]}, follow_redirects=False)
        assert r.status_code == 303, r.text
        jar: SimpleCookie = SimpleCookie()
        jar.load(r.headers["set-cookie"])
        return c, jar

    def ws(self, cookie: str | None, origin: str | None = None) -> ClientConnection:
        headers = {"Origin": origin or self.base}
        if cookie is not None:
            headers["Cookie"] = f"{SESSION_COOKIE}={cookie}"
        return connect(self.base.replace("http://", "ws://") + f"/viewer/{self.session_id}", subprotocols=[Subprotocol(VISER_PROTOCOL)],
                       additional_headers=headers, open_timeout=150, max_size=None)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    root = tmp_path_factory.mktemp("proxy")
    home, data = root / "home", root / "data"
    sdir = build_session(data / "a", n_frames=6)
    other = build_session(data / "b", n_frames=6)
    tokens = {role: create_user(f"u-{role}", role, home=home) for role in ROLES}
    port = free_port()
    env = dict(os.environ, CORNERMAN_HOME=str(home), CORNERMAN_ALLOWED_ROOTS=f'["{data}"]', OMP_NUM_THREADS="1",
               CORNERMAN_VIEWER_START_TIMEOUT_S="120")
    log_path = root / "uvicorn.log"
    with open(log_path, "wb") as logf:
        proc = subprocess.Popen(
            [sys.executable, "-m", "uvicorn", "--factory", "server.app:_app_from_env", "--host", "127.0.0.1",
             "--port", str(port), "--log-level", "info"],
            env=env, stdout=logf, stderr=subprocess.STDOUT, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        wait_until_healthy(base, proc, log_path)
        srv = Server(base, log_path, tokens, 0, 0, sdir, other, home)
        with srv.api("admin") as api:
            made = []
            for folder, name in ((sdir, "a"), (other, "b")):
                r = api.post("/sessions/from-folder", json={"path": str(folder), "name": name})
                assert r.status_code == 201, r.text
                made.append((int(r.json()["id"]), Path(r.json()["folder"])))  # the server's copy
        (srv.session_id, srv.session_dir), (srv.other_session_id, srv.other_dir) = made
        yield srv
    finally:
        stop_server(proc)  # SIGINT: serve stops its workers, viewers exit with their parent


def _viewer_procs(session_dir: Path) -> list[dict]:
    """{pid, args, env} of the live viewer processes of ``session_dir`` (from /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            args = (d / "cmdline").read_bytes().decode().split("\0")
            if "webui.app" not in args or str(session_dir.resolve()) not in args:
                continue
            env = dict(kv.split("=", 1) for kv in (d / "environ").read_bytes().decode().split("\0") if "=" in kv)
        except OSError:
            continue
        out.append({"pid": int(d.name), "args": args, "env": env})
    return out


def _viewer_tokens(home: Path) -> list[tuple[str, str]]:
    """(user name, label) of the live viewer-connection tokens in the server's database."""
    from sqlmodel import Session, col, select

    from server.db import make_engine
    from server.models import ApiToken, User

    engine = make_engine(home / "cornerman.db")
    try:
        with Session(engine) as db:
            rows = db.exec(select(User.name, ApiToken.label).join(ApiToken, col(ApiToken.user_id) == col(User.id))
                           .where(col(ApiToken.label).startswith("viewer:"))).all()
            return sorted((str(n), str(lab)) for n, lab in rows)
    finally:
        engine.dispose()


def _listen_addresses(port: int) -> set[str]:
    """Local IPv4/IPv6 addresses (hex, as in /proc/net/tcp*) with a socket listening on ``port``."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            addr, hex_port = fields[1].rsplit(":", 1)
            if int(hex_port, 16) == port and fields[3] == "0A":  # 0A: LISTEN
                found.add(addr)
    return found


def test_no_cookie_no_viewer(server: Server) -> None:
    sid = server.other_session_id
    with httpx.Client(base_url=server.base, timeout=30) as c:
        r = c.get(f"/viewer/{sid}/", follow_redirects=False)
        assert r.status_code == 303 and r.headers["location"] == f"/login?next=/viewer/{sid}/"
        assert c.get(f"/viewer/{sid}/assets/app.js").status_code == 401
        r = c.get(f"/viewer/{sid}", follow_redirects=False)  # viser derives its websocket URL from the page's
        assert r.status_code == 308 and r.headers["location"] == f"/viewer/{sid}/"
        bearer = {"Authorization": f"Bearer {server.tokens['admin']}"}  # the API's scheme does not open viewers
        assert c.get(f"/viewer/{sid}/", headers=bearer, follow_redirects=False).status_code == 303
        c.cookies.set(SESSION_COOKIE, server.tokens["admin"] + "x")
        assert c.get(f"/viewer/{sid}/", follow_redirects=False).status_code == 303  # unknown cookie
    for cookie in (None, "cm_forged", server.tokens["admin"] + "x"):
        with pytest.raises(InvalidStatus) as e:
            server.ws(cookie).close()
        assert e.value.response.status_code == 403
    assert _viewer_procs(server.other_dir) == []  # nothing was started for anyone


def test_signed_in_viewer_loads_and_its_websocket_relays(server: Server) -> None:
    c, jar = server.login("annotator")
    with closing(c):
        morsel = jar[SESSION_COOKIE]
        assert morsel["httponly"] is True and morsel["samesite"] == "strict"
        page = c.get(f"/viewer/{server.session_id}/")
        assert page.status_code == 200, page.text[:500]
        assert '<div id="root">' in page.text and "<title>Viser</title>" in page.text
        assert page.headers["content-type"].startswith("text/html")
        with server.ws(morsel.value) as ws:
            assert ws.subprotocol == VISER_PROTOCOL
            first = ws.recv(timeout=60)
            assert isinstance(first, bytes) and len(first) > 0  # viser's scene and GUI, relayed
        # the same cookie from another site's page is refused
        with pytest.raises(InvalidStatus) as e:
            server.ws(morsel.value, origin="http://evil.example").close()
        assert e.value.response.status_code == 403
    (viewer,) = _viewer_procs(server.session_dir)
    port = int(viewer["args"][viewer["args"].index("--port") + 1])
    assert _listen_addresses(port) == {"0100007F"}  # 127.0.0.1 only


def test_one_viewer_serves_each_user_with_their_own_connection_token(server: Server) -> None:
    cookies = {}
    for role in ("coach", "annotator"):
        c, jar = server.login(role)
        with closing(c):
            assert c.get(f"/viewer/{server.session_id}/").status_code == 200
        cookies[role] = jar[SESSION_COOKIE].value
    (viewer,) = _viewer_procs(server.session_dir)  # one process for both users
    assert "--role" not in viewer["args"] and "CORNERMAN_VIEWER_TOKEN" not in viewer["env"]
    before = _viewer_tokens(server.home)
    label = f"viewer:{server.session_id}"
    with server.ws(cookies["coach"]) as coach, server.ws(cookies["annotator"]) as annotator:
        for ws in (coach, annotator):
            ws.send(camera_message())  # viser's client announces its camera first; then the viewer builds its view
            ws.recv(timeout=60)
        assert _viewer_tokens(server.home) == sorted([*before, ("u-annotator", label), ("u-coach", label)])
        log_path = server.session_dir / "logs" / "viewer.log"
        t_end = time.monotonic() + 60
        while time.monotonic() < t_end:
            text = log_path.read_text()
            if "(u-coach) joined as coach" in text and "(u-annotator) joined as annotator" in text:
                break
            time.sleep(0.2)
        assert "(u-coach) joined as coach" in text and "(u-annotator) joined as annotator" in text, text[-2000:]
    t_end = time.monotonic() + 10
    while _viewer_tokens(server.home) != before and time.monotonic() < t_end:
        time.sleep(0.1)
    assert _viewer_tokens(server.home) == before  # revoked when the connections closed
    assert [p["pid"] for p in _viewer_procs(server.session_dir)] == [viewer["pid"]]  # still the same process


def test_no_token_in_the_server_log(server: Server) -> None:
    c, jar = server.login("admin")
    with closing(c):
        assert c.get(f"/viewer/{server.session_id}/").status_code == 200
        with server.ws(jar[SESSION_COOKIE].value) as ws:
            ws.recv(timeout=60)
        # an old-style link: refused, and its token must not reach the log either
        assert c.get("/", params={"token": server.tokens["coach"]}, follow_redirects=False).status_code == 200
    with server.api("annotator") as api:
        assert api.get("/me").status_code == 200
    time.sleep(0.5)
    log = server.log_path.read_text()
    assert "POST /login" in log and f"GET /viewer/{server.session_id}/" in log and "WebSocket /viewer/" in log
    assert "/?token=***" in log  # the access log line is there, redacted
    assert "Traceback" not in log  # and the relay closed every websocket cleanly
    secrets = list(server.tokens.values()) + [jar[SESSION_COOKIE].value]
    leaked = [s[:6] + "…" for s in secrets if s in log]
    assert not leaked and "cm_" not in log.replace("cm_***", ""), f"tokens in the server log: {leaked}"
