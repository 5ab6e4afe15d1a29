"""Start (or reuse) one viewer process per (session, role, owner) on a free loopback port.

Used by the server, which serves each viewer to its signed-in owner under
``/viewer/{session}/`` (``server.api.routes.viewer_proxy``). The viser port binds to
127.0.0.1 only: browsers reach a viewer through the app, never directly. This module
imports neither torch nor viser: the viewer runs in its own process (``python -m
webui.app``), which also keeps the body model and MuJoCo out of the server. The token goes
to the child through its environment, not its command line.
"""

from __future__ import annotations

import atexit
import hashlib
import logging
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
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


_viewers: dict[tuple[str, str, str], _Viewer] = {}
_lock = threading.Lock()


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _listening(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=0.5):
            return True
    except OSError:
        return False


def _local_url(port: int) -> str:
    return f"http://{HOST}:{port}/"


def port_of(session_id: str, role: str, owner: str) -> int | None:
    """Port of the live viewer of ``session_id`` for ``(role, owner)``, or None."""
    with _lock:
        v = _viewers.get((str(session_id), role, owner))
        return v.port if v is not None and v.proc.poll() is None else None


def start_viewer(
    session_id: str,
    session_dir: Path,
    api_url: str,
    token: str | Callable[[], str],
    role: str,
    owner: str | None = None,
) -> str:
    """Local URL (``http://127.0.0.1:PORT/``) of a running viewer of ``session_dir`` for
    ``(role, owner)``; starts one if needed.

    ``token`` is the API token the viewer acts with, or a function that makes one (called
    only when a viewer is started). ``owner`` keys the viewer to one user (default: a hash
    of ``token``, which must then be a string). Waits until the viewer accepts connections
    (``START_TIMEOUT_S``); raises ``ValueError`` (with the tail of its log) if it exits or
    does not start in time.
    """
    if owner is None:
        if not isinstance(token, str):
            raise ValueError("start_viewer: pass owner= when the token is made by a function")
        owner = hashlib.sha256(token.encode()).hexdigest()[:16]
    # One viewer per (session, role) and user: edits made in a viewer are authored with
    # its token, so two users never share one.
    key = (str(session_id), role, owner)
    with _lock:
        v = _viewers.get(key)
        if v is not None and v.proc.poll() is None:
            return _local_url(v.port)
        if v is not None:
            _stop(v)
            del _viewers[key]
        port = free_port(HOST)
        log_dir = Path(session_dir) / "logs"
        log_dir.mkdir(parents=True, exist_ok=True)
        log_path = log_dir / f"viewer-{role}.log"
        cmd = [
            sys.executable, "-m", "webui.app",
            "--session-dir", str(Path(session_dir).resolve()),
            "--api-url", api_url,
            "--role", role,
            "--port", str(port),
            "--host", HOST,
            "--session-id", str(session_id),
            "--parent-pid", str(os.getpid()),
        ]  # fmt: skip
        env = dict(os.environ, CORNERMAN_VIEWER_TOKEN=token if isinstance(token, str) else token())
        env.setdefault("OMP_NUM_THREADS", "1")
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
        log.info("viewer of session %s (%s) on port %d (pid %d)", session_id, role, port, proc.pid)
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


def running() -> dict[tuple[str, str], list[int]]:
    """(session id, role) -> ports of the live viewers."""
    out: dict[tuple[str, str], list[int]] = {}
    with _lock:
        for (sid, role, _), v in _viewers.items():
            if v.proc.poll() is None:
                out.setdefault((sid, role), []).append(v.port)
    return out


def stop_viewer(session_id: str, role: str | None = None) -> None:
    """Stop the viewers of a session (all roles, or one); e.g. when it is deleted."""
    with _lock:
        for key in [k for k in _viewers if k[0] == str(session_id) and (role is None or k[1] == role)]:
            _stop(_viewers.pop(key))


def stop_all() -> None:
    """Stop every viewer this process started."""
    with _lock:
        for v in _viewers.values():
            _stop(v)
        _viewers.clear()


atexit.register(stop_all)
