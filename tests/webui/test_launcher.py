"""webui.launcher: one viewer process per (session, role, user), on 127.0.0.1, reused, stopped; and stays light."""

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


def test_start_reuse_stop(tmp_path: Path) -> None:
    sdir = build_session(tmp_path, n_frames=4)
    try:
        url = launcher.start_viewer("s1", sdir, api_url="", token="t1", role="coach")
        assert url.startswith("http://127.0.0.1:")
        with urllib.request.urlopen(url, timeout=10) as r:
            assert r.status == 200 and b"<html" in r.read(2000).lower()
        assert launcher.start_viewer("s1", sdir, api_url="", token="t1", role="coach") == url  # reused
        other = launcher.start_viewer("s1", sdir, api_url="", token="t2", role="coach")  # another user
        assert other != url
        assert sorted(len(v) for v in launcher.running().values()) == [2]
        launcher.stop_viewer("s1")
        assert launcher.running() == {}
    finally:
        launcher.stop_all()


def test_owner_keyed_viewer_mints_its_token_once(tmp_path: Path) -> None:
    """With ``owner=``, the token function runs only when a viewer starts, and ``port_of`` finds it."""
    import os

    sdir = build_session(tmp_path, n_frames=4)
    minted: list[str] = []

    def mint() -> str:
        minted.append(f"cm_minted{len(minted)}")
        return minted[-1]

    try:
        assert launcher.port_of("s3", "annotator", "user:7") is None
        url = launcher.start_viewer("s3", sdir, api_url="", token=mint, role="annotator", owner="user:7")
        assert launcher.start_viewer("s3", sdir, api_url="", token=mint, role="annotator", owner="user:7") == url
        assert minted == ["cm_minted0"]  # reused without minting again
        port = launcher.port_of("s3", "annotator", "user:7")
        assert port is not None and url == f"http://127.0.0.1:{port}/"
        assert launcher.port_of("s3", "annotator", "user:8") is None  # another user has none
        v = launcher._viewers[("s3", "annotator", "user:7")]
        env = Path(f"/proc/{v.proc.pid}/environ").read_bytes().split(b"\0")
        assert b"CORNERMAN_VIEWER_TOKEN=cm_minted0" in env and os.environ.get("CORNERMAN_VIEWER_TOKEN") != "cm_minted0"
        with pytest.raises(ValueError, match="owner="):
            launcher.start_viewer("s3", sdir, api_url="", token=mint, role="annotator")
    finally:
        launcher.stop_all()


def test_failure_reports_the_log(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="did not start"):
        launcher.start_viewer("s2", tmp_path, api_url="", token="t", role="coach")  # no session.json there
    launcher.stop_all()


def test_viewer_exits_with_its_parent(tmp_path: Path) -> None:
    """A viewer started by a process that dies (even by SIGKILL) stops by itself."""
    import os
    import signal
    import time

    sdir = build_session(tmp_path, n_frames=4)
    code = (
        "import sys; from pathlib import Path; from webui import launcher; "
        f"print(launcher.start_viewer('s9', Path({str(sdir)!r}), '', 't', 'coach'), flush=True); "
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
