"""End to end in a real browser: `cornerman serve` on a synthetic bout, the session page,
the viser viewer, an ID swap through the GUI, the re-run job, the corrected identity.

Needs Debian's Chromium (``apt-get install chromium chromium-driver``) and the python
``playwright`` package; no browser is downloaded. Run with
``pytest -m e2e tests/e2e/test_browser.py``. Screenshots go to ``$CORNERMAN_E2E_ARTIFACTS``
(default: the test's tmp folder).
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np
import pytest

from tests.live_server import stop_server, wait_until_healthy

pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.timeout(600)]  # slow: ~50 s of the fast tier

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]  # fmt: skip
STAGES = ("detect2d", "track", "associate", "triangulate")
RED, BLUE = (214, 39, 40), (31, 119, 180)
JOB_TIMEOUT_S = 180.0


@dataclass
class Served:
    base: str
    tokens: dict[str, str]
    session_id: int
    proc: subprocess.Popen
    log_path: Path
    out_dir: Path

    def api(self, role: str) -> httpx.Client:
        return httpx.Client(base_url=self.base + "/api", headers={"Authorization": f"Bearer {self.tokens[role]}"}, timeout=30)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_jobs_done(api: httpx.Client, session_id: int, timeout_s: float, min_jobs: int = 1) -> list[dict]:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        jobs = api.get("/jobs", params={"session_id": session_id}).json()
        if len(jobs) >= min_jobs and all(j["status"] in ("done", "failed", "cancelled") for j in jobs):
            return jobs
        time.sleep(0.5)
    raise AssertionError(f"jobs of session {session_id} not finished after {timeout_s} s: {jobs}")


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} missing: apt-get install -y chromium chromium-driver")
    pytest.importorskip("playwright.sync_api")
    pytest.importorskip("server.cli")
    from server.cli import create_user
    from server.demo import make_session

    root = tmp_path_factory.mktemp("e2e")
    out_dir = Path(os.environ.get("CORNERMAN_E2E_ARTIFACTS", str(root)))
    out_dir.mkdir(parents=True, exist_ok=True)
    home, data = root / "home", root / "data"
    bout = make_session(data / "bout", n_frames=60, n_cameras=3, seed=0, stages=STAGES)
    tokens = {role: create_user(f"e2e-{role}", role, home=home) for role in ("annotator", "coach")}
    port = _free_port()
    code = (
        "from pathlib import Path; from server.cli import serve; "
        f"serve(host='127.0.0.1', port={port}, workers=1, home=Path({str(home)!r}), demo_session=Path({str(bout)!r}))"
    )
    env = dict(os.environ, OMP_NUM_THREADS="1", CORNERMAN_ALLOWED_ROOTS=f'["{data}"]')
    log_path = root / "serve.log"
    with open(log_path, "wb") as logf:
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=logf, stderr=subprocess.STDOUT, env=env, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    served = Served(base, tokens, 0, proc, log_path, out_dir)
    try:
        wait_until_healthy(base, proc, log_path)
        with served.api("annotator") as api:
            sessions = api.get("/sessions").json()
            assert len(sessions) == 1, sessions
            served.session_id = int(sessions[0]["id"])
            jobs = _wait_jobs_done(api, served.session_id, JOB_TIMEOUT_S)
            assert jobs[-1]["status"] == "done", jobs[-1]
        yield served
    finally:
        stop_server(proc)  # SIGINT: serve stops its workers, viewers exit with their parent


def _colour_pixels(png: Path, rgb: tuple[int, int, int], x_max_frac: float, tol: int = 30) -> int:
    import cv2

    img = cv2.cvtColor(cv2.imread(str(png)), cv2.COLOR_BGR2RGB)
    region = img[:, : int(img.shape[1] * x_max_frac)]
    return int(np.all(np.abs(region.astype(int) - np.array(rgb)) <= tol, axis=-1).sum())


def _selection(page) -> tuple[str, int, int, str]:  # noqa: ANN001
    """(view, track, frame, person) of the edit panel's selection line."""
    txt = page.get_by_text(re.compile(r"track #\d+ @ frame \d+ is")).inner_text()
    m = re.search(r"(\S+) track #(\d+) @ frame (\d+) is (\w+)", txt)
    assert m, txt
    return m.group(1), int(m.group(2)), int(m.group(3)), m.group(4)


def _sign_in(page, served: Served, role: str) -> None:  # noqa: ANN001
    """Fill the /login form the browser was sent to."""
    page.wait_for_url(re.compile(r"/login"), timeout=30_000)
    page.fill("#name", f"e2e-{role}")
    page.fill("#token", served.tokens[role])
    page.click("button[type=submit]")


def _open_viewer(browser, served: Served, role: str):  # noqa: ANN001, ANN202
    ctx = browser.new_context(viewport={"width": 1400, "height": 900})
    page = ctx.new_page()
    page.goto(f"{served.base}/")  # not signed in: sent to /login, then back to the picker
    _sign_in(page, served, role)
    button = page.locator(f"#v{served.session_id}")
    button.wait_for(timeout=30_000)
    with ctx.expect_page(timeout=120_000) as popup:
        button.click()
    viewer = popup.value
    viewer.wait_for_selector("canvas", timeout=60_000)
    viewer.get_by_text(re.compile(r"frame 0 / \d+")).wait_for(timeout=60_000)
    return ctx, viewer


def test_review_swap_rerun_reload(served: Served) -> None:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            ctx, viewer = _open_viewer(browser, served, "annotator")
            # the camera frames are in the panel next to the 3D view
            viewer.get_by_text("View from cam01").wait_for(timeout=30_000)
            time.sleep(3)  # let the software renderer draw a few frames
            shot = served.out_dir / "viewer.png"
            viewer.screenshot(path=str(shot))
            # the athletes' identity colours are in the 3D view (left of the GUI panel)
            n_red, n_blue = _colour_pixels(shot, RED, 0.68), _colour_pixels(shot, BLUE, 0.68)
            assert n_red > 30 and n_blue > 30, f"3D view looks blank: red {n_red} px, blue {n_blue} px ({shot})"

            viewer.get_by_role("tab", name="Edit").click()
            slider = viewer.get_by_role("slider").first
            slider.focus()
            for _ in range(30):
                slider.press("ArrowRight")
            viewer.get_by_text(re.compile(r"frame 30 / \d+")).wait_for(timeout=30_000)
            viewer.get_by_text(re.compile(r"track #\d+ @ frame 30 is")).wait_for(timeout=30_000)
            view, track, frame, before = _selection(viewer)
            assert before in ("Red", "Blue")

            viewer.get_by_role("button", name="Swap Red and Blue from this frame").click()
            viewer.get_by_text(re.compile("results reloaded")).wait_for(timeout=JOB_TIMEOUT_S * 1000)

            # over the REST API: the annotation exists and a re-run job completed
            with served.api("annotator") as api:
                anns = api.get(f"/sessions/{served.session_id}/annotations").json()
                swaps = [a for a in anns if a["payload"]["kind"] == "swap_identities"]
                assert swaps and swaps[-1]["payload"] == {
                    "kind": "swap_identities", "frame": 30, "person_a": 0, "person_b": 1, "view": view,
                }  # fmt: skip
                assert swaps[-1]["author"] == "e2e-annotator" and swaps[-1]["active"]
                jobs = _wait_jobs_done(api, served.session_id, 30, min_jobs=2)
                rerun = [j for j in jobs if j["from_stage"] == "associate"]
                assert rerun and rerun[-1]["status"] == "done", jobs

            # the viewer shows the corrected identity of the same track at the same frame
            viewer.get_by_text(re.compile(rf"track #{track} @ frame 30 is")).wait_for(timeout=30_000)
            _, track2, _, after = _selection(viewer)
            assert track2 == track and after == {"Red": "Blue", "Blue": "Red"}[before]
            viewer.screenshot(path=str(served.out_dir / "viewer_after_swap.png"))

            # undo through the GUI: the edit is reverted (kept in the history) and re-run
            viewer.get_by_role("button", name="Undo last edit").click()
            viewer.get_by_text(re.compile(r"Undo of annotation .* results reloaded")).wait_for(timeout=JOB_TIMEOUT_S * 1000)
            viewer.get_by_text(re.compile(rf"track #{track} @ frame 30 is {before}")).wait_for(timeout=30_000)
            with served.api("annotator") as api:
                assert api.get(f"/sessions/{served.session_id}/annotations").json() == []
                hist = api.get(f"/sessions/{served.session_id}/annotations", params={"include_superseded": "true"}).json()
                assert any(a["payload"]["kind"] == "swap_identities" and not a["active"] for a in hist)
            ctx.close()
        finally:
            browser.close()


def test_viewer_needs_login_and_the_cookie_is_httponly(served: Served) -> None:
    """A fresh browser gets the login page instead of the viewer; after signing in there it lands in
    the viewer, whose websocket (through the app, at the page's own URL) connects."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            ctx = browser.new_context(viewport={"width": 1400, "height": 900})
            page = ctx.new_page()
            sockets: list[str] = []
            page.on("websocket", lambda ws: sockets.append(ws.url))
            page.goto(f"{served.base}/viewer/{served.session_id}/")
            assert "/login?next=" in page.url and page.locator("canvas").count() == 0
            assert sockets == []
            page.screenshot(path=str(served.out_dir / "login.png"))
            _sign_in(page, served, "annotator")
            page.wait_for_url(f"{served.base}/viewer/{served.session_id}/", timeout=120_000)
            page.wait_for_selector("canvas", timeout=60_000)
            # GUI state came over the websocket (any frame: the annotator's viewer is shared with the test above)
            page.get_by_text(re.compile(r"frame \d+ / \d+")).wait_for(timeout=60_000)
            assert sockets == [f"ws://127.0.0.1:{served.base.rsplit(':', 1)[1]}/viewer/{served.session_id}"]
            (cookie,) = [c for c in ctx.cookies() if c["name"] == "cornerman_session"]
            assert cookie["httpOnly"] and cookie["sameSite"] == "Strict"
            assert page.evaluate("document.cookie") == ""  # page scripts cannot read it
            ctx.close()
        finally:
            browser.close()
    log = served.log_path.read_text()
    assert "WebSocket /viewer/" in log and not any(t in log for t in served.tokens.values())


def test_coach_sees_no_editing_controls(served: Served) -> None:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            ctx, viewer = _open_viewer(browser, served, "coach")
            viewer.get_by_role("tab", name="Cameras").wait_for(timeout=30_000)
            assert viewer.get_by_role("tab", name="Edit").count() == 0
            assert viewer.get_by_role("button", name=re.compile("Swap")).count() == 0
            ctx.close()
        finally:
            browser.close()
