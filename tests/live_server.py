"""Waiting for a real server process that a test started (uvicorn or ``cornerman serve``)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import httpx


def wait_until_healthy(base: str, proc: subprocess.Popen, log_path: Path, timeout_s: float = 60.0) -> None:
    """Return once ``base``/api/health answers 200; ``AssertionError`` with the log's tail when
    the process exits first or ``timeout_s`` passes."""
    t_end = time.monotonic() + timeout_s
    while True:
        try:
            if httpx.get(base + "/api/health", timeout=1).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        if proc.poll() is not None or time.monotonic() > t_end:
            raise AssertionError(f"the server at {base} did not start:\n{log_path.read_text()[-3000:]}")
        time.sleep(0.2)


def stop_server(proc: subprocess.Popen) -> None:
    """Stop a server started with ``start_new_session=True``: SIGINT (uvicorn shuts down cleanly,
    ``cornerman serve`` stops its workers, viewers exit once their parent is gone), then kill
    the process group if it has not exited within 30 s."""
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)
