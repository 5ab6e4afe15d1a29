"""Several browsers on one session's viewer (real Chromium, uvicorn, the viewer process it starts).

Three signed-in browsers (a coach and two annotator windows) share one viewer process, each with its
own frame (moved with the keyboard on its own slider) and its own Play; the coach gets no Edit tab
while the annotators do; a browser that leaves while playing stops its playback (the viewer says so;
the CPU it then uses is a `cornerman bench viewer` row); with every browser gone the viewer exits after ``CORNERMAN_VIEWER_IDLE_S``
and the next visit starts a new one.

Needs Debian's Chromium and the python ``playwright`` package (see ``test_browser.py``).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest

from server.viewer_bench import viewer_pids
from tests.live_server import stop_server, wait_until_healthy
from tests.webui.fixtures import build_session

pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.timeout(600)]

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]  # fmt: skip
IDLE_S = 6.0


@dataclass
class Served:
    base: str
    tokens: dict[str, str]
    session_id: int
    session_dir: Path

    def cookie(self, user: str) -> str:
        with httpx.Client(base_url=self.base, timeout=30) as c:
            r = c.post("/login", data={"name": user, "token": self.tokens[user]}, follow_redirects=False)
            assert r.status_code == 303, r.text
            return str(c.cookies["cornerman_session"])

    @property
    def log_path(self) -> Path:
        return self.session_dir / "logs" / "viewer.log"


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} missing: apt-get install -y chromium chromium-driver")
    pytest.importorskip("playwright.sync_api")
    from server.cli import create_user
    from server.loadtest import free_port

    root = tmp_path_factory.mktemp("clients")
    home, data = root / "home", root / "data"
    src = build_session(data / "bout", n_frames=40)
    tokens = {u: create_user(u, role, home=home) for u, role in (("e2e-coach", "coach"), ("e2e-annotator", "annotator"),
                                                                   ("e2e-admin", "admin"))}  # fmt: skip
    port = free_port()
    env = dict(os.environ, CORNERMAN_HOME=str(home), CORNERMAN_ALLOWED_ROOTS=f'["{data}"]', OMP_NUM_THREADS="1",
               CORNERMAN_VIEWER_IDLE_S=str(IDLE_S))
    with open(root / "uvicorn.log", "wb") as logf:
        proc = subprocess.Popen(
            [sys.executable, "-m", "uvicorn", "--factory", "server.app:_app_from_env", "--host", "127.0.0.1",
             "--port", str(port), "--log-level", "warning"],
            env=env, stdout=logf, stderr=subprocess.STDOUT, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        wait_until_healthy(base, proc, root / "uvicorn.log")
        headers = {"Authorization": f"Bearer {tokens['e2e-admin']}"}
        r = httpx.post(base + "/api/sessions/from-folder", json={"path": str(src), "name": "clients"}, headers=headers)
        assert r.status_code == 201, r.text
        folder = Path(r.json()["folder"])
        shutil.copytree(src / "artifacts", folder / "artifacts", dirs_exist_ok=True)  # results as if the stages ran
        yield Served(base, tokens, int(r.json()["id"]), folder)
    finally:
        stop_server(proc)  # SIGINT: serve stops its workers, viewers exit with their parent


def _open(browser: Any, served: Served, user: str) -> tuple[Any, Any]:
    ctx = browser.new_context(viewport={"width": 1100, "height": 760})
    ctx.add_cookies([{"name": "cornerman_session", "value": served.cookie(user), "url": served.base}])
    page = ctx.new_page()
    page.goto(f"{served.base}/viewer/{served.session_id}/")
    page.get_by_text(re.compile(r"frame 0 / 39")).wait_for(timeout=120_000)
    return ctx, page


def _frame(page: Any) -> int:
    m = re.search(r"frame (\d+) / 39", page.get_by_text(re.compile(r"frame \d+ / 39")).inner_text())
    assert m, "no frame line"
    return int(m.group(1))


def _step(page: Any, n: int) -> None:
    slider = page.get_by_role("slider").first  # the timeline's frame slider comes first
    slider.focus()
    for _ in range(n):
        slider.press("ArrowRight")
    page.get_by_text(re.compile(rf"frame {n} / 39")).wait_for(timeout=30_000)


def _wait_log(served: Served, text: str, timeout_s: float = 30.0) -> str:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        log = served.log_path.read_text()
        if text in log:
            return log
        time.sleep(0.2)
    raise AssertionError(f"{text!r} not in the viewer log:\n{served.log_path.read_text()[-3000:]}")


def test_browsers_share_one_viewer_with_their_own_frame_play_and_role(served: Served) -> None:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            (ca, coach), (cb, ann), (cc, ann2) = (_open(browser, served, u) for u in
                                                   ("e2e-coach", "e2e-annotator", "e2e-annotator"))  # fmt: skip
            (pid,) = viewer_pids(served.session_dir)  # one process for the three browsers
            _step(coach, 5)
            _step(ann, 12)
            assert (_frame(coach), _frame(ann), _frame(ann2)) == (5, 12, 0)
            # roles per client on the same process
            assert coach.get_by_role("tab", name="Edit").count() == 0
            assert ann.get_by_role("tab", name="Edit").count() == 1 and ann2.get_by_role("tab", name="Edit").count() == 1
            # Play in the third window: it moves, the other two stay where they are
            ann2.get_by_text("Play", exact=True).click()
            t_end = time.monotonic() + 30
            while _frame(ann2) == 0 and time.monotonic() < t_end:
                time.sleep(0.2)
            assert _frame(ann2) > 0
            time.sleep(1.0)
            assert (_frame(coach), _frame(ann)) == (5, 12)
            # it leaves while playing: the viewer stops its playback and goes quiet
            cc.close()
            _wait_log(served, "(e2e-annotator) left; its playback stopped")
            time.sleep(1.0)  # the CPU it then uses is measured by `cornerman bench viewer`, not here
            assert (_frame(coach), _frame(ann)) == (5, 12)
            ca.close()
            cb.close()
            # nobody left: the viewer exits after its idle time, and the next visit starts a new one
            _wait_log(served, "no client for", timeout_s=IDLE_S + 20)
            t_end = time.monotonic() + 10
            while viewer_pids(served.session_dir) and time.monotonic() < t_end:
                time.sleep(0.2)
            assert viewer_pids(served.session_dir) == []
            cd, again = _open(browser, served, "e2e-coach")
            (new_pid,) = viewer_pids(served.session_dir)
            assert new_pid != pid and _frame(again) == 0
            cd.close()
        finally:
            browser.close()
