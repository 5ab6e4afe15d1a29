"""The event chart in a real browser: each punch is a point of its outcome's colour on its
athlete's row at its strike time, and the chart follows the Events filters.

A viser server in this process (as ``cornerman view`` runs it) with the viewer on a small
session holding three punches (``tests.webui.fixtures.sample_events``: Red's landed jab at 6
and landed rear hook at 28, Blue's blocked cross at 15), and Debian's Chromium through
Playwright (see ``test_browser.py``).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import viser

from pipeline.schema.analytics import OUTCOME_COLORS
from tests.webui.fixtures import build_session, sample_events, write_events
from webui.app import ViewerApp
from webui.colors import hex_to_rgb
from webui.launcher import free_port
from webui.panels.event_chart import CHART_TITLE

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(300)]

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run"]
TOL = 40
"""Per-channel distance (0-255) at which a pixel has a series' colour (antialiased edges apart)."""


@pytest.fixture
def viewer(tmp_path: Path) -> Iterator[tuple[ViewerApp, int]]:
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} missing: apt-get install -y chromium chromium-driver")
    pytest.importorskip("playwright.sync_api")
    sdir = build_session(tmp_path, n_frames=40)
    write_events(sdir, *sample_events(40))
    port = free_port()
    server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    app = ViewerApp(server, sdir, role="coach", max_image_width=160)
    try:
        yield app, port
    finally:
        app.close()
        server.stop()


def _pixels(png: bytes, hex_color: str) -> np.ndarray:
    """(n, 2) x, y of the pixels of ``png`` within ``TOL`` of ``hex_color``."""
    import cv2

    img = cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    near = np.all(np.abs(img.astype(int) - np.array(hex_to_rgb(hex_color))) <= TOL, axis=-1)
    ys, xs = np.nonzero(near)
    return np.stack([xs, ys], axis=1)


def _shot(page, want: object, timeout_s: float = 30.0) -> bytes:  # noqa: ANN001
    """A screenshot of the chart once ``want(png)`` holds (the browser redraws asynchronously,
    and rebuilds the chart's element when its data change)."""
    from playwright.sync_api import Error

    chart = page.locator(".uplot", has_text=CHART_TITLE)
    t_end = time.monotonic() + timeout_s
    while True:
        try:
            png = chart.screenshot(timeout=5_000)
        except Error:  # detached while being rebuilt: take the next one
            if time.monotonic() > t_end:
                raise
            continue
        if want(png) or time.monotonic() > t_end:  # type: ignore[operator]
            return png
        time.sleep(0.3)


def test_punches_are_coloured_by_outcome_on_their_athletes_rows(viewer: tuple[ViewerApp, int]) -> None:
    from playwright.sync_api import sync_playwright

    app, port = viewer
    landed, blocked = OUTCOME_COLORS["landed"], OUTCOME_COLORS["blocked"]
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.goto(f"http://127.0.0.1:{port}/")
            page.locator(".uplot", has_text=CHART_TITLE).wait_for(timeout=60_000)
            png = _shot(page, lambda b: len(_pixels(b, landed)) > 0 and len(_pixels(b, blocked)) > 0)
            g, y = _pixels(png, landed), _pixels(png, blocked)
            assert len(g) > 20 and len(y) > 10, (len(g), len(y))
            # Red's two landed punches (0.24 s, 1.12 s) on the lower row, Blue's blocked cross
            # (0.60 s) on the upper row, between them in time.
            left, right = g[g[:, 0] < g[:, 0].mean()], g[g[:, 0] >= g[:, 0].mean()]
            assert left[:, 0].max() < y[:, 0].min() and y[:, 0].max() < right[:, 0].min()
            assert y[:, 1].mean() < g[:, 1].mean() - 10

            app.events.outcome.value = "landed"  # the Events filter: the blocked cross leaves the chart
            png = _shot(page, lambda b: len(_pixels(b, blocked)) == 0)
            assert len(_pixels(png, blocked)) == 0 and len(_pixels(png, landed)) > 20
        finally:
            browser.close()
