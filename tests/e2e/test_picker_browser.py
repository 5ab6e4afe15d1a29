"""The session picker in a real browser: an admin signs in, creates a session from a server
folder with the page's form, runs it, and follows the job to its detail page (status, stages,
log). `cornerman serve` runs for real (uvicorn + a worker); Debian's Chromium, no download.
Screenshots go to ``$CORNERMAN_E2E_ARTIFACTS`` (default: the test's tmp folder).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.e2e.test_browser import CHROMIUM, CHROMIUM_ARGS, _free_port
from tests.live_server import stop_server, wait_until_healthy

pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.timeout(400)]
STAGES = ("detect2d", "track", "associate", "triangulate")


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} missing: apt-get install -y chromium chromium-driver")
    pytest.importorskip("playwright.sync_api")
    from server.cli import create_user
    from server.demo import make_session

    root = tmp_path_factory.mktemp("picker")
    out_dir = Path(os.environ.get("CORNERMAN_E2E_ARTIFACTS", str(root)))
    out_dir.mkdir(parents=True, exist_ok=True)
    home, data = root / "home", root / "data"
    bout = make_session(data / "bouts" / "sparring", n_frames=40, n_cameras=3, seed=0, stages=STAGES,
                        use_synthetic=False)
    token = create_user("e2e-admin", "admin", home=home)
    port = _free_port()
    code = f"from pathlib import Path; from server.cli import serve; serve(port={port}, workers=1, home=Path({str(home)!r}))"
    env = dict(os.environ, OMP_NUM_THREADS="1", CORNERMAN_ALLOWED_ROOTS=f'["{data}"]')
    log_path = root / "serve.log"
    with open(log_path, "wb") as logf:
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=logf, stderr=subprocess.STDOUT, env=env,
                                start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        wait_until_healthy(base, proc, log_path)
        yield {"base": base, "token": token, "bout": bout, "out_dir": out_dir}
    finally:
        stop_server(proc)  # SIGINT: serve stops its workers, viewers exit with their parent


def test_create_from_folder_run_and_open_the_job(server: dict) -> None:
    from playwright.sync_api import expect, sync_playwright

    base, out_dir = server["base"], server["out_dir"]
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_context(viewport={"width": 1300, "height": 1000}).new_page()
            page.goto(f"{base}/")
            page.wait_for_url(re.compile(r"/login"), timeout=30_000)
            page.fill("#name", "e2e-admin")
            page.fill("#token", server["token"])
            page.click("button[type=submit]")
            page.wait_for_url(f"{base}/", timeout=30_000)
            # the folder is among the suggestions under the allowed root
            assert page.locator(f'#folders option[value="{server["bout"]}"]').count() == 1
            page.fill("#folder-path", str(server["bout"]))
            page.fill("#folder-name", "sparring (picker)")
            page.fill("#folder-date", "2026-11-26")
            page.click("#create-folder")
            msg = page.locator("#msg")
            expect(msg).to_contain_text("created session", timeout=30_000)
            sid = int(re.search(r"created session (\d+)", msg.inner_text()).group(1))  # type: ignore[union-attr]
            row = page.locator(f"#s{sid}")
            expect(row).to_contain_text("sparring (picker)")
            expect(row).to_contain_text(time.strftime("%Y-%m-%d", time.gmtime()))  # the created date
            page.screenshot(path=str(out_dir / "picker.png"), full_page=True)

            page.click(f"#run{sid}")
            page.wait_for_url(re.compile(rf"{base}/jobs/\d+$"), timeout=30_000)
            job_id = int(page.url.rsplit("/", 1)[1])
            # the page reloads itself until the job ends
            expect(page.locator("#job-status")).to_have_text("done", timeout=240_000)
            stages = page.locator("#stages")
            for stage in STAGES:
                expect(stages).to_contain_text(stage)
            assert page.locator("#stages td.ran").count() == len(STAGES)
            assert page.locator("#job-log").inner_text().strip() not in ("", "(empty)")
            assert page.locator("#job-error").count() == 0 and page.locator("#cancel").count() == 0
            page.screenshot(path=str(out_dir / "job.png"), full_page=True)

            # back on the list, the job links to the same page
            page.goto(f"{base}/")
            expect(page.locator(f"#s{sid}")).to_contain_text(f"#{job_id} done")
            page.locator(f"#s{sid} a[href='/jobs/{job_id}']").click()
            page.wait_for_url(f"{base}/jobs/{job_id}", timeout=30_000)
        finally:
            browser.close()
    with httpx.Client(base_url=base + "/api", headers={"Authorization": f"Bearer {server['token']}"}) as api:
        job = api.get(f"/jobs/{job_id}").json()
        assert job["status"] == "done" and job["requested_by"] == "e2e-admin" and job["session_id"] == sid
        assert api.get(f"/sessions/{sid}").json()["date"] == "2026-11-26"
