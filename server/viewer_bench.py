"""Memory of one session's viewer serving several clients (``cornerman bench viewer``).

Starts the server (uvicorn, no worker) on a temporary home with one session, signs in, opens
the session's viewer through the app (``/viewer/{id}/``) and connects ``n_clients``
websocket clients to it through the proxy, each as viser's browser client does (the
subprotocol, then a camera message, after which the viewer builds that client's view). It
reports the viewer process's resident memory (``VmRSS``) with no client, one client and all
of them, the memory per client, the peak of its child processes (the body mesh worker) and
its CPU while the clients are paused, while one and then all of them play (and how many frames
each playing client gets per second), and after they all left while playing (Play must stop with
its client). Target: ≤ 400 MB per viewer with 5 clients. ``feedback=true``: the latency rows of
``server.feedback_bench`` instead (scrub, identity edit -> re-triangulated view, playback rate).

``session``: an already-run session folder to serve (e.g. the demo bout with fit and physics,
whose body meshes dominate); default: a synthetic bout with the 2D/3D stages only.
"""

from __future__ import annotations

import importlib.metadata
import os
import re
import shutil
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

from server.loadtest import running_server

TARGET_RSS_MB = 400.0
"""Issue 40's budget for one session's viewer with 5 clients."""
VISER_PROTOCOL = f"viser-v{importlib.metadata.version('viser')}"


def camera_message() -> bytes:
    """The first message viser's browser client sends (its 3D camera); the viewer counts a client from it."""
    import msgspec
    from viser._messages import ViewerCameraMessage

    msg = ViewerCameraMessage(wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, -5.0, 2.0), fov=1.0, near=0.01, far=100.0,
                              image_height=720, image_width=1280, look_at=(0.0, 0.0, 1.0), up_direction=(0.0, 0.0, 1.0))
    return msgspec.msgpack.encode(msg.as_serializable_dict())


def decode_window(raw: bytes) -> list[dict[str, Any]]:
    """The messages of one websocket frame viser sent (``viser.infra._infra._message_producer``'s wire
    format: sizes, zstd-compressed msgpack, then raw array buffers, which are not decoded here)."""
    import msgspec
    import zstandard

    n_inner, n_comp = int.from_bytes(raw[:8], "little"), int.from_bytes(raw[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(raw[16:16 + n_comp], max_output_size=n_inner)
    return list(msgspec.msgpack.decode(inner).get("messages", ()))


@dataclass
class WsClient:
    """A viser websocket client that reads everything the viewer sends and keeps the GUI's labels
    (label -> uuid) and markdown texts, so it can press Play and read the frame line."""

    conn: Any
    received_bytes: int = 0
    messages: int = 0
    uuids: dict[str, str] = field(default_factory=dict)
    markdown: dict[str, str] = field(default_factory=dict)
    frame_updates: int = 0
    """Frame lines received that differ from the previous one (frames drawn for this client)."""
    _thread: threading.Thread | None = field(default=None, repr=False)

    def _drain(self) -> None:
        try:
            while True:
                data = self.conn.recv()
                self.received_bytes += len(data)
                for msg in decode_window(data):
                    self.messages += 1
                    self._take(msg)
        except Exception:  # noqa: BLE001  (closed either way: by us, the proxy or the viewer)
            return

    def _take(self, msg: dict[str, Any]) -> None:
        kind, props = msg.get("type", ""), msg.get("props") or {}
        if kind.startswith("Gui") and "uuid" in msg and isinstance(props, dict):
            if props.get("label"):
                self.uuids.setdefault(str(props["label"]), str(msg["uuid"]))
            if "_markdown" in props:
                self.markdown[str(msg["uuid"])] = str(props["_markdown"])
        if kind == "GuiUpdateMessage" and "_markdown" in (msg.get("updates") or {}):
            text = str(msg["updates"]["_markdown"])
            if text.startswith("frame ") and text != self.markdown.get(str(msg["uuid"])):
                self.frame_updates += 1
            self.markdown[str(msg["uuid"])] = text

    def frame(self) -> int | None:
        """The frame in the timeline's info line (``frame N / LAST``), None before it arrives."""
        for text in list(self.markdown.values()):
            m = re.match(r"frame (\d+) / \d+", text)
            if m:
                return int(m.group(1))
        return None

    def set_value(self, label: str, value: Any) -> None:
        """Change the GUI input labelled ``label`` as a browser would (``KeyError`` when there is none)."""
        import msgspec
        from viser._messages import GuiUpdateMessage

        msg = GuiUpdateMessage(uuid=self.uuids[label], updates={"value": value})
        self.conn.send(msgspec.msgpack.encode(msg.as_serializable_dict()))

    def close(self) -> None:
        self.conn.close()
        if self._thread is not None:
            self._thread.join(5.0)


def open_client(ws_url: str, headers: dict[str, str] | None = None, timeout_s: float = 120.0) -> WsClient:
    """Connect to a viser websocket (directly or through ``/viewer/{id}``), announce a camera, keep reading."""
    from websockets.sync.client import connect
    from websockets.typing import Subprotocol

    conn = connect(ws_url, subprotocols=[Subprotocol(VISER_PROTOCOL)], additional_headers=headers or {},
                   open_timeout=timeout_s, max_size=None)
    conn.send(camera_message())
    c = WsClient(conn)
    c._thread = threading.Thread(target=c._drain, daemon=True)
    c._thread.start()
    return c


CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync")


@dataclass
class BrowserClient:
    """A headless Chromium page on the viewer (``clients=browser``): it renders the 3D view too."""

    context: Any
    page: Any
    received_bytes: int = 0  # not measured for a browser
    frame_updates: int = 0

    def frame(self) -> int | None:
        m = re.search(r"frame (\d+) / \d+", self.page.get_by_text(re.compile(r"frame \d+ / \d+")).inner_text())
        return int(m.group(1)) if m else None

    def set_value(self, label: str, value: Any) -> None:
        if label != "Play" or value is not True:
            raise ValueError(f"BrowserClient.set_value: only ('Play', True), got ({label!r}, {value!r})")
        self.page.get_by_text("Play", exact=True).click(timeout=180_000)  # 2 cores: software WebGL is slow

    def close(self) -> None:
        self.context.close()


def open_browser_client(browser: Any, base_url: str, session_id: int, cookie: str) -> BrowserClient:
    ctx = browser.new_context(viewport={"width": 1100, "height": 760})
    ctx.add_cookies([{"name": "cornerman_session", "value": cookie, "url": base_url}])
    page = ctx.new_page()
    page.goto(f"{base_url}/viewer/{session_id}/")
    page.get_by_text(re.compile(r"frame \d+ / \d+")).wait_for(timeout=180_000)
    return BrowserClient(ctx, page)


def viewer_pids(session_dir: Path) -> list[int]:
    """Live ``webui.app`` processes serving ``session_dir`` (from /proc)."""
    out = []
    want = str(Path(session_dir).resolve())
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            args = (d / "cmdline").read_bytes().decode().split("\0")
        except OSError:
            continue
        if "webui.app" in args and want in args:
            out.append(int(d.name))
    return out


def rss_mb(pid: int) -> float:
    """Resident memory of ``pid`` in MB (``VmRSS``); 0 when it is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def children(pid: int) -> list[int]:
    """Child processes of ``pid`` (started by any of its threads)."""
    out: list[int] = []
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            out += [int(p) for p in (task / "children").read_text().split()]
    except OSError:
        pass
    return out


def cpu_s(pid: int) -> float:
    """User + system CPU seconds used by ``pid`` so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _settle(pid: int, seconds: float, peak: list[float]) -> float:
    """Wait ``seconds`` sampling the process and its children; RSS at the end."""
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        peak[0] = max(peak[0], rss_mb(pid) + sum(rss_mb(c) for c in children(pid)))
        time.sleep(0.25)
    return rss_mb(pid)


def run_bench(n_clients: int = 5, session: str = "", settle_s: float = 4.0, mesh_timeout_s: float = 300.0,
              clients: str = "ws", home: Path | None = None, feedback: bool = False, n_scrub: int = 50,
              play_s: float = 10.0, chromium: bool = True) -> list[dict[str, Any]]:
    """Start a server with one session, connect ``n_clients`` to its viewer, report memory rows.

    ``clients``: ``ws`` (websocket clients, light enough for 5 on 2 cores) or ``browser`` (headless
    Chromium pages, ``/usr/bin/chromium`` and playwright; frames per second are not counted then).
    ``feedback``: instead, the latency rows of ``server.feedback_bench`` (scrub over ``n_scrub``
    frames, identity edit, ``play_s`` s of playback in Chromium unless ``chromium`` is false) on ``session``.
    """
    from server.cli import create_user
    from server.demo import make_session

    if feedback:
        from server.feedback_bench import run_feedback

        return run_feedback(session, n_scrub=n_scrub, play_s=play_s, browser=chromium, home=home)

    if n_clients < 1:
        raise ValueError(f"bench viewer: n_clients must be >= 1, got {n_clients}")
    if clients not in ("ws", "browser"):
        raise ValueError(f"bench viewer: clients must be 'ws' or 'browser', got {clients!r}")
    if clients == "browser" and not Path(CHROMIUM).exists():
        raise ValueError(f"bench viewer: clients=browser needs {CHROMIUM} (apt-get install chromium)")
    if session and not (Path(session) / "session.json").is_file():
        raise ValueError(f"bench viewer: session={session}: no session.json there")
    tmp = Path(tempfile.mkdtemp(prefix="cornerman-viewer-bench-")) if home is None else home
    try:
        data = tmp / "data"
        if session:
            src = Path(session).resolve()  # the server copies it into its home
            data = src.parent
        else:
            src = make_session(data / "bout", n_frames=150, n_cameras=3, stages=("detect2d", "track", "associate", "triangulate"))
        server_home = tmp / "home"
        token = create_user("bench", "admin", home=server_home)
        # A cold start (the first visit): the body meshes are posed, not read from an earlier run's cache.
        cold = {"CORNERMAN_VIEWER_MESH_CACHE_DIR": str(tmp / "mesh-cache")}
        with running_server(server_home, n_workers=0, allowed_roots=[data], extra_env=cold) as srv:
            api = httpx.Client(base_url=srv.url + "/api", headers={"Authorization": f"Bearer {token}"}, timeout=60)
            r = api.post("/sessions/from-folder", json={"path": str(src), "name": "bench"})
            if r.status_code != 201:
                raise ValueError(f"bench viewer: session not created: {r.status_code} {r.text[:300]}")
            sid, folder = int(r.json()["id"]), Path(r.json()["folder"])
            if session:  # the server's copy has the inputs only: bring the results the viewer shows
                shutil.copytree(src / "artifacts", folder / "artifacts", dirs_exist_ok=True)
            web = httpx.Client(base_url=srv.url, timeout=300)
            r = web.post("/login", data={"name": "bench", "token": token}, follow_redirects=False)
            if r.status_code != 303:
                raise ValueError(f"bench viewer: sign-in failed: {r.status_code}")
            cookie = web.cookies.get("cornerman_session") or ""
            t0 = time.monotonic()
            if web.get(f"/viewer/{sid}/").status_code != 200:
                raise ValueError("bench viewer: the viewer page did not load")
            start_s = time.monotonic() - t0
            (pid,) = viewer_pids(folder)
            peak = [0.0]
            t_end = time.monotonic() + mesh_timeout_s
            while children(pid) and time.monotonic() < t_end:  # the body mesh worker, when there is a fit
                _settle(pid, 0.5, peak)
            rss0 = _settle(pid, settle_s, peak)
            ws_url = srv.url.replace("http://", "ws://") + f"/viewer/{sid}"
            headers = {"Cookie": f"cornerman_session={cookie}", "Origin": srv.url}
            pw = browser = None
            if clients == "browser":
                from playwright.sync_api import sync_playwright

                pw = sync_playwright().start()
                browser = pw.chromium.launch(executable_path=CHROMIUM, args=list(CHROMIUM_ARGS))

            def connect() -> WsClient | BrowserClient:
                if browser is not None:
                    return open_browser_client(browser, srv.url, sid, cookie)
                return open_client(ws_url, headers)

            conns = [connect()]
            rss1 = _settle(pid, settle_s, peak)
            conns += [connect() for _ in range(n_clients - 1)]
            rss_n = _settle(pid, settle_s, peak)
            c0 = cpu_s(pid)
            rss_n = max(rss_n, _settle(pid, settle_s, peak))
            cpu_pct = 100.0 * (cpu_s(pid) - c0) / settle_s
            received = sum(c.received_bytes for c in conns) / len(conns) / 1e6
            # Play: one client, then all of them (each at 1x), then they all leave while playing
            play_rows: list[dict[str, Any]] = []
            for starting, playing in ((conns[:1], conns[:1]), (conns[1:], conns)):
                for c in starting:
                    c.set_value("Play", True)
                _settle(pid, 1.0, peak)
                c0, u0 = cpu_s(pid), [c.frame_updates for c in playing]
                rss_n = max(rss_n, _settle(pid, settle_s, peak))
                rate = sum(c.frame_updates - u for c, u in zip(playing, u0, strict=True)) / len(playing) / settle_s
                play_rows += [
                    {"measure": f"viewer CPU, {len(playing)} playing (% of a core)",
                     "value": round(100.0 * (cpu_s(pid) - c0) / settle_s, 1)},
                    {"measure": f"frames drawn per second per playing client ({len(playing)} playing)",
                     "value": round(rate, 1) if clients == "ws" else None},
                ]  # fmt: skip
            log_path = folder / "logs" / "viewer.log"
            t_close = time.monotonic()
            for c in conns:
                c.close()
            # Under load a closing browser can take seconds to drop its websocket: wait for the viewer to see them go.
            t_end = time.monotonic() + 120
            while log_path.read_text(errors="replace").count(" left") < n_clients and time.monotonic() < t_end:
                _settle(pid, 0.25, peak)
            gone_s = time.monotonic() - t_close
            if browser is not None and pw is not None:
                browser.close()
                pw.stop()
            _settle(pid, 1.0, peak)
            c0 = cpu_s(pid)
            rss_after = _settle(pid, settle_s, peak)
            play_rows.append({"measure": "seconds until the viewer saw every client leave", "value": round(gone_s, 1)})
            play_rows.append({"measure": "viewer CPU after they left while playing (% of a core)",
                              "value": round(100.0 * (cpu_s(pid) - c0) / settle_s, 1)})
            api.close()
            web.close()
        rows: list[dict[str, Any]] = [
            {"measure": "clients", "value": clients},
            {"measure": "viewer start (first page, s)", "value": round(start_s, 1)},
            {"measure": "viewer RSS, no client (MB)", "value": round(rss0, 1)},
            {"measure": "viewer RSS, 1 client (MB)", "value": round(rss1, 1)},
            {"measure": f"viewer RSS, {n_clients} clients (MB, max while paused and playing)", "value": round(rss_n, 1),
             "target": f"<= {TARGET_RSS_MB:g}",
             "ok": rss_n <= TARGET_RSS_MB},
            {"measure": "RSS per client (MB)", "value": round((rss_n - rss0) / n_clients, 1)},
            {"measure": "peak RSS with child processes (MB)", "value": round(peak[0], 1)},
            {"measure": f"viewer CPU, {n_clients} paused clients (% of a core)", "value": round(cpu_pct, 1)},
            {"measure": "sent per client at connect (MB)", "value": round(received, 2)},
            *play_rows,
            {"measure": "viewer RSS after the clients left (MB)", "value": round(rss_after, 1)},
        ]
        return rows
    finally:
        if home is None:
            shutil.rmtree(tmp, ignore_errors=True)
