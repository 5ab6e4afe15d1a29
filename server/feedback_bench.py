"""Feedback latency of the review app (``cornerman bench viewer --opt feedback=true``): issue 40's targets.

Starts the server (uvicorn and one worker) on a temporary home with one already-run session,
opens its viewer through the app (``/viewer/{id}/``) and measures, in this order:

- scrub: a websocket client (``server.viewer_bench.WsClient``, through the proxy) sets the
  frame slider and waits for that frame's info line, which the viewer sends after the frame's
  3D and camera images: median and p95 over ``n_scrub`` random frames, after a warm-up pass
  over the same frames (their camera images cached);
- identity edit: ``POST /annotations`` swapping athletes 0 and 1 from a frame in the last third
  with a re-run, until the re-triangulated artifact is written, and until the viewer shows the
  3D layer up to date again (its "Layers after the edit" block); the re-run is then cancelled
  (fit and physics would take minutes);
- playback without a browser: the websocket client plays at 1x for ``play_s`` s: the frame
  updates the viewer sends per second, the bout frames they advance per second and the bytes
  per update (the server side alone);
- playback: a headless Chromium page (software WebGL: ``--disable-gpu``) plays at 1x; the
  frame lines it displays per second are counted in the page, and the bout frames they advance
  per second (over the bout's fps: the real-time factor of playback).
"""

from __future__ import annotations

import json
import random
import re
import shutil
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx

from server.loadtest import running_server
from server.viewer_bench import CHROMIUM, CHROMIUM_ARGS, WsClient, children, open_client, viewer_pids

TARGET_EDIT_S = 10.0
"""Issue 40: identity edit -> re-triangulated view (s)."""
TARGET_SCRUB_MS = 150.0
"""Issue 40: scrub latency with cached frames (ms)."""
TARGET_PLAY_HZ = 15.0
"""Issue 40: playback updates per second at 1x, with hardware WebGL."""

LAYER_3D = "3D (filtered)"

# Counts the distinct "frame N / M" lines the page displays (a MutationObserver on the page) and
# the bout frames they advance (modulo the bout's length: playback wraps): [lines, frames].
_COUNT_JS = """([ms, nFrames]) => new Promise((resolve) => {
  let last = null, n = 0, advanced = 0;
  const read = () => { const m = document.body.innerText.match(/frame (\\d+) \\/ \\d+/); return m ? m[1] : null; };
  const el = [...document.querySelectorAll('p, span, div')].find(e => /^frame \\d+ \\/ \\d+/.test(e.textContent.trim()));
  const get = el ? () => { const m = el.textContent.match(/frame (\\d+) \\/ \\d+/); return m ? m[1] : read(); } : read;
  const obs = new MutationObserver(() => {
    const f = get();
    if (f !== null && f !== last) {
      if (last !== null) advanced += ((parseInt(f) - parseInt(last)) % nFrames + nFrames) % nFrames;
      last = f; n += 1;
    }
  });
  obs.observe(document.body, {subtree: true, childList: true, characterData: true});
  setTimeout(() => { obs.disconnect(); resolve([n, advanced]); }, ms);
})"""


def _wait(cond: Any, timeout_s: float, step_s: float = 0.001) -> float | None:
    """Seconds until ``cond()`` is true, or None after ``timeout_s``."""
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout_s:
        if cond():
            return time.perf_counter() - t0
        time.sleep(step_s)
    return None


def _layer_line(c: WsClient, layer: str) -> str:
    """The viewer's current line for ``layer`` in its "Layers after the edit" block ("" when hidden)."""
    for text in list(c.markdown.values()):
        m = re.search(rf"\*\*{re.escape(layer)}\*\*: ([^\n]*)", text)
        if m:
            return m.group(1)
    return ""


def scrub_latency_ms(c: WsClient, frames: list[int], timeout_s: float = 30.0) -> list[float]:
    """Milliseconds from setting each frame to its info line arriving (NaN on a timeout)."""
    out = []
    for f in frames:
        t = _wait(lambda f=f: c.frame() == f, 0.0)  # already there: move away first
        if t is not None:
            c.set_value("Frame", (f + 1) % (max(frames) + 2))
            _wait(lambda f=f: c.frame() != f, timeout_s)
        c.set_value("Frame", f)
        dt = _wait(lambda f=f: c.frame() == f, timeout_s)
        out.append(float("nan") if dt is None else 1000.0 * dt)
    return out


def _fps_of(c: WsClient) -> float:
    """The bout's fps from the info line (``frame N / LAST (T s)``) when session.json has none."""
    for text in list(c.markdown.values()):
        m = re.match(r"frame (\d+) / \d+ \(([\d.]+) s\)", text)
        if m and float(m.group(2)) > 0:
            return int(m.group(1)) / float(m.group(2))
    raise ValueError("bench viewer feedback: no fps in session.json and none readable from the viewer")


def play_rows_ws(c: WsClient, n_frames: int, fps: float, play_s: float) -> list[dict[str, Any]]:
    """Rows of ``play_s`` s of playback at 1x seen by the websocket client (no browser): frame
    updates per second, bout frames advanced per second, bytes per update."""
    frames: list[int] = []
    stop = time.perf_counter() + 1.0 + play_s
    c.set_value("Play", True)
    time.sleep(1.0)
    b0, u0 = c.received_bytes, c.frame_updates
    while time.perf_counter() < stop:
        f = c.frame()
        if f is not None and (not frames or frames[-1] != f):
            frames.append(f)
        time.sleep(0.002)
    updates, sent = c.frame_updates - u0, c.received_bytes - b0
    c.set_value("Play", False)
    advanced = sum((b - a) % n_frames for a, b in zip(frames[:-1], frames[1:], strict=True))
    return [
        {"measure": "playback at 1x, websocket client without a browser (frame updates/s)",
         "value": round(updates / play_s, 1)},
        {"measure": f"  bout frames advanced per second there (real-time factor at {fps:g} fps)",
         "value": f"{advanced / play_s:.1f} ({advanced / play_s / fps:.2f}x)"},
        {"measure": "  sent per frame update while playing (KB)", "value": round(sent / max(1, updates) / 1e3, 1)},
    ]  # fmt: skip


def _pct(xs: list[float], q: float) -> float:
    ys = sorted(x for x in xs if x == x)
    if not ys:
        return float("nan")
    return ys[min(len(ys) - 1, int(round(q * (len(ys) - 1))))]


def run_feedback(session: str, n_scrub: int = 50, play_s: float = 10.0, seed: int = 0, browser: bool = True,
                 edit_timeout_s: float = 120.0, home: Path | None = None) -> list[dict[str, Any]]:
    """The rows described in the module docstring, on ``session`` (an already-run session folder)."""
    from server.cli import create_user

    if not session or not (Path(session) / "session.json").is_file():
        raise ValueError(f"bench viewer feedback: session={session!r}: give an already-run session folder "
                         "(with session.json and artifacts/, e.g. the demo bout)")
    if n_scrub < 5:
        raise ValueError(f"bench viewer feedback: n_scrub must be >= 5, got {n_scrub}")
    if browser and not Path(CHROMIUM).exists():
        raise ValueError(f"bench viewer feedback: the playback row needs {CHROMIUM} (or browser=false)")
    src = Path(session).resolve()
    tmp = Path(tempfile.mkdtemp(prefix="cornerman-feedback-bench-")) if home is None else home
    rows: list[dict[str, Any]] = []
    try:
        token = create_user("bench", "admin", home=tmp / "home")
        with running_server(tmp / "home", n_workers=1, allowed_roots=[src.parent]) as srv:
            api = httpx.Client(base_url=srv.url + "/api", headers={"Authorization": f"Bearer {token}"}, timeout=60)
            r = api.post("/sessions/from-folder", json={"path": str(src), "name": "bench", "auto_rerun": False})
            if r.status_code != 201:
                raise ValueError(f"bench viewer feedback: session not created: {r.status_code} {r.text[:300]}")
            sid, folder = int(r.json()["id"]), Path(r.json()["folder"])
            shutil.copytree(src / "artifacts", folder / "artifacts", dirs_exist_ok=True)
            web = httpx.Client(base_url=srv.url, timeout=300)
            if web.post("/login", data={"name": "bench", "token": token}, follow_redirects=False).status_code != 303:
                raise ValueError("bench viewer feedback: sign-in failed")
            cookie = web.cookies.get("cornerman_session") or ""
            if web.get(f"/viewer/{sid}/").status_code != 200:
                raise ValueError("bench viewer feedback: the viewer page did not load")
            (pid,) = viewer_pids(folder)
            t_end = time.monotonic() + 300
            while children(pid) and time.monotonic() < t_end:  # the body mesh worker, when there is a fit
                time.sleep(0.5)
            headers = {"Cookie": f"cornerman_session={cookie}", "Origin": srv.url}
            c = open_client(srv.url.replace("http://", "ws://") + f"/viewer/{sid}", headers)
            if _wait(lambda: c.frame() is not None and "Frame" in c.uuids, 120.0, 0.05) is None:
                raise ValueError("bench viewer feedback: the viewer sent no frame line")
            n_frames = int(re.search(r"frame \d+ / (\d+)", next(t for t in c.markdown.values()
                                                                  if t.startswith("frame "))).group(1)) + 1  # type: ignore[union-attr]
            fps = float(json.loads((folder / "session.json").read_text()).get("fps") or 0.0) or _fps_of(c)
            rng = random.Random(seed)
            frames = rng.sample(range(n_frames), min(n_scrub, n_frames))
            scrub_latency_ms(c, frames)  # warm-up: the camera images of these frames are cached now
            rng.shuffle(frames)
            ms = scrub_latency_ms(c, frames)
            rows += [
                {"measure": f"scrub latency, cached, median of {len(ms)} frames (ms)", "value": round(statistics.median(ms), 1),
                 "target": f"<= {TARGET_SCRUB_MS:g}", "ok": statistics.median(ms) <= TARGET_SCRUB_MS},
                {"measure": "scrub latency, cached, p95 (ms)", "value": round(_pct(ms, 0.95), 1)},
            ]  # fmt: skip

            # identity edit: swap the athletes from a frame in the last third
            frame = int(n_frames * 0.8)
            tri = folder / "artifacts" / "triangulate" / "manifest.json"
            tri_before = tri.stat().st_mtime_ns
            t0 = time.perf_counter()
            r = api.post(f"/sessions/{sid}/annotations", json={
                "annotation": {"kind": "swap_identities", "frame": frame, "person_a": 0, "person_b": 1}, "rerun": True})
            if r.status_code != 201 or not r.json().get("job"):
                raise ValueError(f"bench viewer feedback: the swap was not accepted with a re-run: {r.status_code} {r.text[:300]}")
            job_id = r.json()["job"]["id"]
            t_written: float | None = None
            saw_stale: float | None = None
            t_shown: float | None = None
            t_end = time.perf_counter() + edit_timeout_s
            while t_shown is None and time.perf_counter() < t_end:
                now, line = time.perf_counter() - t0, _layer_line(c, LAYER_3D)
                if t_written is None and tri.exists() and tri.stat().st_mtime_ns != tri_before:
                    t_written = now
                if saw_stale is None and line.startswith("⚠"):
                    saw_stale = now
                elif saw_stale is not None and not line.startswith("⚠"):  # "✓", or the block hidden: all fresh
                    t_shown = now
                time.sleep(0.005)
            stale_lines = {k: _layer_line(c, k) for k in ("fit", "physics")}
            api.post(f"/jobs/{job_id}/cancel")
            rows += [
                {"measure": f"identity edit (swap at frame {frame}/{n_frames}) -> re-triangulated artifact written (s)",
                 "value": None if t_written is None else round(t_written, 1)},
                {"measure": "identity edit -> viewer shows the re-triangulated 3D up to date (s)",
                 "value": None if t_shown is None else round(t_shown, 1), "target": f"<= {TARGET_EDIT_S:g}",
                 "ok": t_shown is not None and t_shown <= TARGET_EDIT_S},
                {"measure": "fit / physics layers at that moment", "value": " | ".join(f"{k}: {v}" for k, v in stale_lines.items())},
            ]  # fmt: skip
            _wait(lambda: api.get(f"/jobs/{job_id}").json()["status"] in ("cancelled", "done", "failed"), 60.0, 0.2)
            rows += play_rows_ws(c, n_frames, fps, play_s)
            c.close()

            if browser:
                from playwright.sync_api import sync_playwright

                from server.viewer_bench import open_browser_client

                with sync_playwright() as pw:
                    b = pw.chromium.launch(executable_path=CHROMIUM, args=list(CHROMIUM_ARGS))
                    bc = open_browser_client(b, srv.url, sid, cookie)
                    bc.set_value("Play", True)
                    time.sleep(2.0)
                    n, advanced = bc.page.evaluate(_COUNT_JS, [int(play_s * 1000), n_frames])
                    bc.close()
                    b.close()
                rows += [
                    {"measure": "playback at 1x in headless Chromium, software WebGL (frame updates/s)",
                     "value": round(int(n) / play_s, 1), "target": f">= {TARGET_PLAY_HZ:g} with hardware WebGL"},
                    {"measure": f"  bout frames advanced per second there (real-time factor at {fps:g} fps)",
                     "value": f"{int(advanced) / play_s:.1f} ({int(advanced) / play_s / fps:.2f}x)"},
                ]  # fmt: skip
            api.close()
            web.close()
        return rows
    finally:
        if home is None:
            shutil.rmtree(tmp, ignore_errors=True)
