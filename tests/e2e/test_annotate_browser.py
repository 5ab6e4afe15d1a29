"""The annotate page in a real browser (`cornerman serve`: uvicorn + one worker; Debian's Chromium
through Playwright, nothing downloaded), on a small bout whose track and associate stages ran.

An annotator signs in, steps frames with the hotkeys, clicks a detection (the selection names its
track, person and confidence), swaps the two athletes over a frame range from the page (the stored
edit has that ``frame_end``; the worker re-runs associate and the page redraws the selected track
with the other athlete), sees the API's reason for an impossible range, and undoes the swap with
``u`` (the history lists it as undone; ``ctrl+y`` and ``ctrl+z`` redo and undo it again). A coach
gets the page without edit controls and the API refuses a coach's edit from that page.

Screenshot: ``annotate.png`` in ``$CORNERMAN_E2E_ARTIFACTS`` (default: the test's tmp folder);
with ``CORNERMAN_UPDATE_DOCS=1`` also ``docs/img/annotate.png`` (the README's).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.e2e.test_browser import CHROMIUM, CHROMIUM_ARGS, _free_port, _wait_jobs_done
from tests.live_server import stop_server, wait_until_healthy

pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.timeout(300)]
STAGES = ("detect2d", "track", "associate")
FRAME, SWAP_END = 20, 35
DOCS_IMG = Path(__file__).resolve().parents[2] / "docs" / "img" / "annotate.png"


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} missing: apt-get install -y chromium chromium-driver")
    pytest.importorskip("playwright.sync_api")
    from pipeline.runner.core import run
    from server.cli import create_user
    from server.demo import make_session

    root = tmp_path_factory.mktemp("annotate")
    out_dir = Path(os.environ.get("CORNERMAN_E2E_ARTIFACTS", str(root)))
    out_dir.mkdir(parents=True, exist_ok=True)
    home, data = root / "home", root / "data"
    src = make_session(data / "sparring", n_frames=60, n_cameras=3, seed=0, stages=STAGES, use_synthetic=False)
    tokens = {role: create_user(f"e2e-{role}", role, home=home) for role in ("coach", "annotator", "admin")}
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
        r = httpx.post(f"{base}/api/sessions/from-folder", json={"path": str(src), "name": "sparring"},
                       headers={"Authorization": f"Bearer {tokens['admin']}"}, timeout=30)
        assert r.status_code == 201, r.text
        run(r.json()["folder"])  # track + associate, in this process: the page has detections and identities
        yield {"base": base, "tokens": tokens, "sid": r.json()["id"], "out_dir": out_dir}
    finally:
        stop_server(proc)


def _api(served: dict, role: str) -> httpx.Client:
    return httpx.Client(base_url=served["base"] + "/api", headers={"Authorization": f"Bearer {served['tokens'][role]}"},
                        timeout=30)


def _sign_in(page, served: dict, role: str) -> None:  # noqa: ANN001  (a Playwright Page)
    url = f"{served['base']}/sessions/{served['sid']}/annotate"
    page.goto(url)
    page.wait_for_url(re.compile(r"/login\?next="), timeout=30_000)
    page.fill("#name", f"e2e-{role}")
    page.fill("#token", served["tokens"][role])
    page.click("button[type=submit]")
    page.wait_for_url(url, timeout=30_000)


def _click_detection(page, det: dict, others: list[dict], modifiers: list[str] | None = None) -> None:  # noqa: ANN001
    """Click a point of ``det``'s box that no smaller box covers (the page picks the smallest)."""
    x0, y0, x1, y1 = det["box_xyxy_px"]
    area = (x1 - x0) * (y1 - y0)
    smaller = [o["box_xyxy_px"] for o in others if (o["box_xyxy_px"][2] - o["box_xyxy_px"][0])
               * (o["box_xyxy_px"][3] - o["box_xyxy_px"][1]) < area]  # fmt: skip
    for fx in (0.5, 0.2, 0.8, 0.1, 0.9):
        for fy in (0.5, 0.2, 0.8):
            x, y = x0 + fx * (x1 - x0), y0 + fy * (y1 - y0)
            if not any(b[0] <= x <= b[2] and b[1] <= y <= b[3] for b in smaller):
                break
        else:
            continue
        break
    else:
        raise AssertionError(f"track {det['track']}'s box is covered by smaller boxes everywhere")
    x, y = _on_page(page, x, y)
    for key in modifiers or []:
        page.keyboard.down(key)
    page.mouse.click(x, y)
    for key in modifiers or []:
        page.keyboard.up(key)


def _on_page(page, x_px: float, y_px: float) -> tuple[float, float]:  # noqa: ANN001
    """Page (CSS px) position of image pixel ``(x_px, y_px)`` of the shown camera (1280 px wide)."""
    box = page.locator("#view").bounding_box()
    assert box is not None and box["width"] > 0
    s = box["width"] / 1280  # CSS px per image px
    return box["x"] + x_px * s, box["y"] + y_px * s


def test_annotator_selects_swaps_a_range_and_undoes_with_hotkeys(served: dict) -> None:
    from playwright.sync_api import expect, sync_playwright

    sid = served["sid"]
    with _api(served, "annotator") as api:
        info = api.get(f"/sessions/{sid}/frames").json()
        assert info["cameras"][0]["width_px"] == 1280
        cam = info["cameras"][1]["name"]  # the athletes stand apart in this camera
        dets = api.get(f"/sessions/{sid}/detections", params={"view": cam, "frame": FRAME}).json()["detections"]
    det = next(d for d in dets if d["person"] == 0)
    names = {p["id"]: p["name"] for p in info["persons"]}
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_context(viewport={"width": 1400, "height": 1000}).new_page()
            _sign_in(page, served, "annotator")
            root = page.locator("#annotate")
            expect(root).to_have_attribute("data-frame", "0", timeout=30_000)
            page.select_option("#camera", cam)
            expect(root).to_have_attribute("data-view", cam)
            page.keyboard.press("Shift+ArrowRight")
            page.keyboard.press("Shift+ArrowRight")
            page.keyboard.press("ArrowRight")
            page.keyboard.press("ArrowLeft")
            expect(root).to_have_attribute("data-frame", str(FRAME), timeout=15_000)
            expect(page.locator("#frame-num")).to_have_text(str(FRAME))

            _click_detection(page, det, [d for d in dets if d is not det])
            expect(page.locator("#sel-track")).to_have_text(f"track #{det['track']}")
            expect(page.locator("#sel-person")).to_contain_text(names[0])
            expect(page.locator("#sel-conf")).to_have_text(f"{det['confidence']:.2f}")

            # an impossible range: the API's reason shows on the page, nothing is stored
            page.fill("#swap-to", "5")
            page.click("#swap")
            expect(page.locator("#error")).to_contain_text(f"frame_end 5 must be after frame {FRAME}")
            # the range swap: from = the current frame (the default), to = SWAP_END
            expect(page.locator("#swap-from")).to_have_value(str(FRAME))
            page.fill("#swap-to", str(SWAP_END))
            page.click("#swap")
            first = page.locator("#history li").first
            expect(first).to_contain_text("swap", timeout=15_000)
            expect(first).to_have_attribute("data-state", "active")
            expect(page.locator("#error")).to_be_hidden()
            with _api(served, "annotator") as api:
                active = api.get(f"/sessions/{sid}/annotations").json()
            swaps = [a for a in active if a["kind"] == "swap_identities"]
            assert len(swaps) == 1 and swaps[0]["author"] == "e2e-annotator"
            assert swaps[0]["payload"] == {"kind": "swap_identities", "frame": FRAME, "frame_end": SWAP_END,
                                           "person_a": 0, "person_b": 1, "view": ""}
            swap_id = swaps[0]["id"]
            # the worker re-runs associate; the page follows the job and redraws the selection
            expect(page.locator("#job")).to_contain_text("done", timeout=90_000)
            expect(page.locator("#sel-person")).to_contain_text(names[1], timeout=15_000)

            page.keyboard.press("u")
            expect(page.locator(f"#h{swap_id}")).to_have_attribute("data-state", "undone", timeout=15_000)
            expect(page.locator(f"#h{swap_id}")).to_contain_text("undone by e2e-annotator")
            expect(page.locator("#history li").first).to_contain_text(f"undo of #{swap_id}")
            with _api(served, "annotator") as api:
                assert not [a for a in api.get(f"/sessions/{sid}/annotations").json() if a["kind"] == "swap_identities"]
            page.keyboard.press("Control+y")
            expect(page.locator("#history li").first).to_have_attribute("data-state", "active", timeout=15_000)
            expect(page.locator("#history li").first).to_contain_text("swap")
            page.keyboard.press("Control+z")
            expect(page.locator("#history li").first).to_contain_text("undo of", timeout=15_000)
            with _api(served, "annotator") as api:
                assert not [a for a in api.get(f"/sessions/{sid}/annotations").json() if a["kind"] == "swap_identities"]
            expect(page.locator("#sel-person")).to_contain_text(names[0], timeout=90_000)  # after the last re-run
            page.screenshot(path=str(served["out_dir"] / "annotate.png"))
            if os.environ.get("CORNERMAN_UPDATE_DOCS") == "1":
                shutil.copyfile(served["out_dir"] / "annotate.png", DOCS_IMG)
        finally:
            browser.close()


def _newest(served: dict, kind: str) -> dict:
    with _api(served, "annotator") as api:
        rows = [a for a in api.get(f"/sessions/{served['sid']}/annotations").json() if a["kind"] == kind]
    assert rows, f"no active {kind}"
    return rows[-1]["payload"]  # type: ignore[no-any-return]


def test_every_track_edit_from_the_page(served: dict) -> None:
    """Fix a keypoint by dragging it and by click-then-click, assign with ``2`` + ``a``, merge a
    shift-clicked track with ``m``, mark invalid with ``x``, split with ``k``, label a contact."""
    from playwright.sync_api import expect, sync_playwright

    sid = served["sid"]
    with _api(served, "annotator") as api:
        info = api.get(f"/sessions/{sid}/frames").json()
        cam = info["cameras"][1]["name"]
        dets = api.get(f"/sessions/{sid}/detections", params={"view": cam, "frame": FRAME}).json()["detections"]
    det, other = sorted(dets, key=lambda d: d["person"])[:2]
    joints = info["joint_names"]
    kps = det["keypoints_px"]

    def lone(j: int) -> bool:  # no other keypoint of the detection within 12 px: a click picks this one
        return kps[j] is not None and all(
            k == j or p is None or abs(p[0] - kps[j][0]) + abs(p[1] - kps[j][1]) > 12 for k, p in enumerate(kps))

    j_drag, j_click = [j for j in range(len(kps)) if lone(j)][:2]
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_context(viewport={"width": 1400, "height": 1000}).new_page()
            _sign_in(page, served, "annotator")
            root, status = page.locator("#annotate"), page.locator("#status")
            expect(root).to_have_attribute("data-frame", "0", timeout=30_000)
            page.select_option("#camera", cam)
            page.fill("#frame", str(FRAME))  # the slider
            expect(root).to_have_attribute("data-frame", str(FRAME), timeout=15_000)
            expect(root).to_have_attribute("data-view", cam)
            _click_detection(page, det, [other])
            expect(page.locator("#sel-track")).to_have_text(f"track #{det['track']}")

            x, y = _on_page(page, *kps[j_drag])
            page.mouse.move(x, y)
            page.mouse.down()
            page.mouse.move(x + 20, y + 10, steps=4)
            page.mouse.up()
            expect(status).to_contain_text("(fix_keypoint)", timeout=15_000)
            fix = _newest(served, "fix_keypoint")
            s = page.locator("#view").bounding_box()["width"] / 1280  # type: ignore[index]
            assert fix["joint"] == joints[j_drag] and fix["track"] == det["track"] and fix["frame"] == FRAME
            assert fix["view"] == cam
            assert abs(fix["x_px"] - (kps[j_drag][0] + 20 / s)) < 2 and abs(fix["y_px"] - (kps[j_drag][1] + 10 / s)) < 2

            page.mouse.click(*_on_page(page, *kps[j_click]))  # pick the joint...
            expect(status).to_contain_text(f"joint {joints[j_click]} picked")
            page.mouse.click(*_on_page(page, kps[j_click][0] - 25, kps[j_click][1]))  # ...and its new position
            expect(page.locator("#history li").first).to_contain_text(joints[j_click], timeout=15_000)
            fix = _newest(served, "fix_keypoint")
            assert fix["joint"] == joints[j_click] and abs(fix["x_px"] - (kps[j_click][0] - 25)) < 2

            page.keyboard.press("2")
            page.keyboard.press("a")
            expect(status).to_contain_text("(assign_identity)", timeout=15_000)
            assert _newest(served, "assign_identity") == {
                "kind": "assign_identity", "view": cam, "track": det["track"], "frame_start": det["track_frames"][0],
                "frame_end": det["track_frames"][1], "person": info["persons"][1]["id"]}

            _click_detection(page, other, [det], modifiers=["Shift"])
            expect(page.locator("#merge-b")).to_have_value(str(other["track"]))
            page.keyboard.press("m")
            expect(status).to_contain_text("(merge_tracks)", timeout=15_000)
            assert _newest(served, "merge_tracks") == {"kind": "merge_tracks", "view": cam, "track_a": det["track"],
                                                       "track_b": other["track"]}
            page.keyboard.press("x")
            expect(status).to_contain_text("(mark_invalid)", timeout=15_000)
            assert _newest(served, "mark_invalid") == {"kind": "mark_invalid", "view": cam, "frame": FRAME,
                                                       "track": det["track"]}
            page.keyboard.press("k")
            expect(status).to_contain_text("(split_track)", timeout=15_000)
            assert _newest(served, "split_track") == {"kind": "split_track", "view": cam, "track": det["track"],
                                                      "frame": FRAME}
            page.fill("#contact-part-a", "left_glove")
            page.fill("#contact-part-b", "head")
            page.fill("#contact-to", str(FRAME + 3))
            page.click("#contact")
            expect(status).to_contain_text("(label_contact)", timeout=15_000)
            assert _newest(served, "label_contact") == {
                "kind": "label_contact", "frame_start": FRAME, "frame_end": FRAME + 3, "person_a": 0,
                "part_a": "left_glove", "person_b": 1, "part_b": "head"}
            expect(page.locator("#error")).to_be_hidden()
        finally:
            browser.close()


def test_coach_sees_no_edit_controls_and_cannot_edit(served: dict) -> None:
    from playwright.sync_api import expect, sync_playwright

    sid = served["sid"]
    with _api(served, "annotator") as api:  # an edit in the history, so that its buttons could show
        r = api.post(f"/sessions/{sid}/annotations", json={"annotation": {
            "kind": "label_contact", "frame_start": 3, "frame_end": 4, "person_a": 0, "part_a": "left_glove",
            "person_b": 1, "part_b": "head"}, "rerun": False})
        assert r.status_code == 201, r.text
        n_before = len(api.get(f"/sessions/{sid}/annotations/history").json())
        # The other tests' page edits queue re-runs; on 2 cores the coach's page load could wait on them.
        _wait_jobs_done(api, sid, timeout_s=900, min_jobs=0)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_context(viewport={"width": 1400, "height": 1000}).new_page()
            _sign_in(page, served, "coach")
            expect(page.locator("#annotate")).to_have_attribute("data-frame", "0", timeout=30_000)
            expect(page.locator("#readonly")).to_be_visible()
            expect(page.locator("#history li").first).to_contain_text("contact")
            for control in ("#edit-controls", "#assign", "#swap", "#merge", "#joint", "#contact", ".undo-btn",
                            ".redo-btn"):
                assert page.locator(control).count() == 0, control
            assert page.locator("#hotkeys tr.edit").first.is_hidden()
            page.keyboard.press("u")  # no undo for a coach
            page.keyboard.press("ArrowRight")
            expect(page.locator("#annotate")).to_have_attribute("data-frame", "1")
            page.keyboard.press(" ")  # play...
            expect(page.locator("#annotate")).to_have_attribute("data-frame", re.compile(r"^([4-9]|\d\d)$"))
            page.keyboard.press(" ")  # ...and pause
            expect(page.locator("#play")).to_contain_text("play")
            page.wait_for_timeout(300)  # a frame already requested still lands
            paused = page.locator("#annotate").get_attribute("data-frame")
            page.wait_for_timeout(600)
            assert page.locator("#annotate").get_attribute("data-frame") == paused
            status = page.evaluate(
                """async (sid) => (await fetch(`/api/sessions/${sid}/annotations`, {method: 'POST',
                    headers: {'Content-Type': 'application/json'}, body: JSON.stringify({annotation:
                    {kind: 'swap_identities', frame: 5, person_a: 0, person_b: 1}})})).status""", sid)
            assert status == 403
        finally:
            browser.close()
    with _api(served, "coach") as api:
        assert len(api.get(f"/sessions/{sid}/annotations/history").json()) == n_before
