"""Start (or reuse) one viewer process per session on a free loopback port.

Used by the server, which serves the viewer to every signed-in user under
``/viewer/{session}/`` (``server.api.routes.viewer_proxy``); the one process serves every
client of the session, each with its own view, and learns who a client is from the token
the proxy puts in that connection's handshake (``webui.clients``). The viser port binds to
127.0.0.1 only: browsers reach a viewer through the app, never directly. A viewer started
with ``idle_s`` exits after that long without a client; the next ``start_viewer`` starts a
new one. This module imports neither torch nor viser: the viewer runs in its own process
(``python -m webui.app``), which also keeps the body model and MuJoCo out of the server.
"""

from __future__ import annotations

import atexit
import logging
import os
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

START_TIMEOUT_S = float(os.environ.get("CORNERMAN_VIEWER_START_TIMEOUT_S", "90"))
HOST = "127.0.0.1"
"""The only address viewers listen on."""


@dataclass
class _Viewer:
    proc: subprocess.Popen
    port: int
    host: str
    log_path: Path


_viewers: dict[str, _Viewer] = {}
_lock = threading.Lock()


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _listening(host: str, port: int) -> bool:
    """Whether the viewer answers HTTP (a bare connect-and-close would log a traceback in viser's log)."""
    try:
        with urllib.request.urlopen(f"http://{host}:{port}/", timeout=2.0) as r:
            return bool(r.status == 200)
    except OSError:
        return False


def _local_url(port: int) -> str:
    return f"http://{HOST}:{port}/"


def _live(session_id: str) -> _Viewer | None:
    v = _viewers.get(str(session_id))
    return v if v is not None and v.proc.poll() is None else None


def port_of(session_id: str) -> int | None:
    """Port of the live viewer of ``session_id``, or None (never started, stopped, or exited when idle)."""
    with _lock:
        v = _live(session_id)
        return v.port if v is not None else None


def pid_of(session_id: str) -> int | None:
    """Process id of the live viewer of ``session_id``, or None."""
    with _lock:
        v = _live(session_id)
        return v.proc.pid if v is not None else None


def start_viewer(session_id: str, session_dir: Path, api_url: str, idle_s: float = 0.0) -> str:
    """Local URL (``http://127.0.0.1:PORT/``) of the running viewer of ``session_dir``; starts one if
    none runs (or the last one exited, e.g. after ``idle_s`` seconds without a client).

    ``api_url``: the API the viewer identifies its clients with (empty: every client read-only);
    ``idle_s`` > 0: the viewer exits after that long without a client. Waits until the viewer
    accepts connections (``START_TIMEOUT_S``); raises ``ValueError`` (with the tail of its
    log) if it exits or does not start in time.
    """
    if idle_s < 0:
        raise ValueError(f"start_viewer: idle_s must be >= 0 (0: never stop), got {idle_s}")
    key = str(session_id)
    with _lock:
        v = _viewers.get(key)
        if v is not None and v.proc.poll() is None:
            return _local_url(v.port)
        if v is not None:
            log.info("viewer of session %s exited (%s): starting a new one", key, v.proc.returncode)
            _stop(v)
            del _viewers[key]
        port = free_port(HOST)
        log_dir = Path(session_dir) / "logs"
        log_dir.mkdir(parents=True, exist_ok=True)
        log_path = log_dir / "viewer.log"
        cmd = [
            sys.executable, "-m", "webui.app",
            "--session-dir", str(Path(session_dir).resolve()),
            "--api-url", api_url,
            "--port", str(port),
            "--host", HOST,
            "--session-id", key,
            "--parent-pid", str(os.getpid()),
            "--idle-s", f"{idle_s:g}",
        ]  # fmt: skip
        env = {k: val for k, val in os.environ.items() if k != "CORNERMAN_VIEWER_TOKEN"}
        env.setdefault("OMP_NUM_THREADS", "1")
        # viser answers on a pool of threads: two malloc arenas instead of one per thread keep
        # the resident size down (measured by ``cornerman bench viewer``).
        env.setdefault("MALLOC_ARENA_MAX", "2")
        with open(log_path, "ab") as logf:
            proc = subprocess.Popen(cmd, stdout=logf, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        v = _Viewer(proc, port, HOST, log_path)
        t0 = time.monotonic()
        while not _listening(HOST, port):
            if proc.poll() is not None or time.monotonic() - t0 > START_TIMEOUT_S:
                _stop(v)
                tail = log_path.read_text(errors="replace")[-2000:] if log_path.exists() else ""
                raise ValueError(f"viewer of session {session_id} did not start (see {log_path}):\n{tail}")
            time.sleep(0.1)
        _viewers[key] = v
        log.info("viewer of session %s on port %d (pid %d)", key, port, proc.pid)
        return _local_url(port)


def _stop(v: _Viewer, timeout_s: float = 5.0) -> None:
    if v.proc.poll() is not None:
        return
    v.proc.terminate()
    try:
        v.proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        v.proc.kill()
        v.proc.wait(timeout_s)


def running() -> dict[str, int]:
    """Session id -> port of each live viewer."""
    with _lock:
        return {sid: v.port for sid, v in _viewers.items() if v.proc.poll() is None}


def stop_viewer(session_id: str) -> None:
    """Stop the viewer of a session (e.g. when it is deleted)."""
    with _lock:
        v = _viewers.pop(str(session_id), None)
        if v is not None:
            _stop(v)


def stop_all() -> None:
    """Stop every viewer this process started."""
    with _lock:
        for v in _viewers.values():
            _stop(v)
        _viewers.clear()


atexit.register(stop_all)
