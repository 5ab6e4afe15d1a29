"""webui.launcher: one viewer process per session, on 127.0.0.1, reused, stopped, exits when idle and
starts again on the next visit; and stays light."""

from __future__ import annotations

import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

from tests.webui.fixtures import build_session
from webui import launcher


def test_import_is_light() -> None:
    code = "import sys, webui.launcher; bad = [m for m in ('torch', 'viser', 'mujoco', 'cv2') if m in sys.modules]; print(bad)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]"


def test_one_viewer_per_session_reused_and_stopped(tmp_path: Path) -> None:
    sdir = build_session(tmp_path / "a", n_frames=4)
    other = build_session(tmp_path / "b", n_frames=4)
    try:
        url = launcher.start_viewer("s1", sdir, api_url="")
        assert url.startswith("http://127.0.0.1:")
        with urllib.request.urlopen(url, timeout=10) as r:
            assert r.status == 200 and b"<html" in r.read(2000).lower()
        assert launcher.start_viewer("s1", sdir, api_url="") == url  # every user shares it
        assert launcher.port_of("s1") == int(url.rsplit(":", 1)[1].rstrip("/"))
        pid = launcher.pid_of("s1")
        assert pid is not None and b"CORNERMAN_VIEWER_TOKEN" not in Path(f"/proc/{pid}/environ").read_bytes()
        other_url = launcher.start_viewer("s2", other, api_url="")
        assert other_url != url and sorted(launcher.running()) == ["s1", "s2"]
        launcher.stop_viewer("s1")
        assert launcher.port_of("s1") is None and list(launcher.running()) == ["s2"]
        with pytest.raises(ValueError, match="idle_s"):
            launcher.start_viewer("s3", sdir, api_url="", idle_s=-1)
    finally:
        launcher.stop_all()
    assert launcher.running() == {}


def test_an_idle_viewer_exits_and_the_next_visit_starts_another(tmp_path: Path) -> None:
    import time

    sdir = build_session(tmp_path, n_frames=4)
    try:
        launcher.start_viewer("s4", sdir, api_url="", idle_s=1.0)
        pid = launcher.pid_of("s4")
        assert pid is not None
        t_end = time.monotonic() + 20
        while launcher.pid_of("s4") is not None and time.monotonic() < t_end:
            time.sleep(0.2)
        assert launcher.pid_of("s4") is None, "viewer still running 20 s after its idle time of 1 s"
        assert "no client for" in (sdir / "logs" / "viewer.log").read_text()
        url = launcher.start_viewer("s4", sdir, api_url="", idle_s=1.0)  # the next visit
        new_pid = launcher.pid_of("s4")
        assert new_pid is not None and new_pid != pid
        with urllib.request.urlopen(url, timeout=10) as r:
            assert r.status == 200
    finally:
        launcher.stop_all()


def test_failure_reports_the_log(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="did not start"):
        launcher.start_viewer("s2", tmp_path, api_url="")  # no session.json there
    launcher.stop_all()


def test_viewer_exits_with_its_parent(tmp_path: Path) -> None:
    """A viewer started by a process that dies (even by SIGKILL) stops by itself."""
    import os
    import signal
    import time

    sdir = build_session(tmp_path, n_frames=4)
    code = (
        "import sys; from pathlib import Path; from webui import launcher; "
        f"print(launcher.start_viewer('s9', Path({str(sdir)!r}), ''), flush=True); "
        "import time; time.sleep(600)"
    )
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        url = parent.stdout.readline().strip()
        assert url.startswith("http://")
        urllib.request.urlopen(url, timeout=10).close()
    finally:
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(10)
    t_end = time.monotonic() + 15
    while time.monotonic() < t_end:
        try:
            urllib.request.urlopen(url, timeout=1).close()
        except OSError:
            return  # the viewer is gone
        time.sleep(0.5)
    raise AssertionError(f"viewer at {url} still up 15 s after its parent was killed")
