"""The bout report in a real browser (Debian's Chromium through Playwright): it loads without
a single network request, prints to an A4 PDF of several pages, and screenshots.

Screenshots and the PDF go to ``$CORNERMAN_E2E_ARTIFACTS`` (default: the test's tmp folder).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from pipeline.report import ReportOptions, load_report_data, render_report
from tests.report.fixtures import write_analysed_bout

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120)]

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
]
A4_PT = (595.3, 841.9)  # 210 x 297 mm in points


def test_report_prints_to_a_multi_page_a4_pdf(tmp_path: Path) -> None:
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} missing: apt-get install -y chromium")
    sync_api = pytest.importorskip("playwright.sync_api")
    out_dir = Path(os.environ.get("CORNERMAN_E2E_ARTIFACTS", str(tmp_path)))
    out_dir.mkdir(parents=True, exist_ok=True)
    write_analysed_bout(tmp_path / "bout")
    html = render_report(load_report_data(tmp_path / "bout"), ReportOptions(period_s=4.0))
    requests: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1040, "height": 1400})
            page.on("request", lambda r: requests.append(r.url))
            page.set_content(html, wait_until="load")
            n_charts = page.locator("svg.chart").count()
            widths = page.eval_on_selector_all(
                "svg.chart", "els => els.map(e => e.getBoundingClientRect().width)"
            )
            page.screenshot(path=str(out_dir / "report.png"), full_page=True)
            pdf = page.pdf(format="A4", print_background=True)
        finally:
            browser.close()
    (out_dir / "report.pdf").write_bytes(pdf)
    assert requests == [], requests  # self-contained: nothing fetched
    assert n_charts == 9 and all(w > 100 for w in widths), widths
    assert pdf.startswith(b"%PDF")
    pages = re.findall(rb"/Type\s*/Page\b(?!s)", pdf)
    assert len(pages) >= 7, len(pages)  # one section per page at least (seven sections)
    boxes = [
        tuple(float(v) for v in m.split())
        for m in re.findall(rb"/MediaBox\s*\[\s*0 0 ([\d.]+ [\d.]+)\s*\]", pdf)
    ]
    assert len(boxes) == len(pages) and all(
        abs(w - A4_PT[0]) < 1.5 and abs(h - A4_PT[1]) < 1.5 for w, h in boxes
    ), boxes
    assert (out_dir / "report.png").stat().st_size > 20_000
