"""The plots' current-frame cursor: on every chart at the view's frame time after a scrub or a
jump and when paused, moved at most ``PLAY_CURSOR_HZ`` times per (fake) second while playing,
and each client gets only its own cursor over the wire."""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import pytest
import viser

from server.viewer_bench import VISER_PROTOCOL, WsClient, camera_message
from tests.webui.fixtures import build_session, wait_for
from webui.app import ViewerApp
from webui.client_view import ClientView
from webui.launcher import free_port
from webui.panels.plot_cursor import PLAY_CURSOR_HZ, PlotCursor, cursor_axes, cursor_time_s, plot_charts
from webui.scene.session_data import load_session_data

FPS = 50.0


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


_wait = partial(wait_for, timeout_s=15.0)


def _cursors(view: ClientView) -> list[float | None]:
    return [cursor_time_s(c) for c in plot_charts(view.plots)]


@pytest.fixture(scope="module")
def app(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ViewerApp]:
    sdir = build_session(tmp_path_factory.mktemp("cursor"), n_frames=120)
    data = load_session_data(sdir)
    data.rig = dataclasses.replace(data.rig, fps=FPS)
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    a = ViewerApp(server, sdir, role="coach", max_image_width=160, data=data)
    yield a
    a.close()
    server.stop()


def test_cursor_axes_put_one_line_at_the_time() -> None:
    axes = cursor_axes(1.25)
    assert len(axes) == 3 and axes[2]["scale"] == "x" and axes[2]["splits"] == (1.25,)
    assert axes[2]["grid"]["show"] and axes[2]["size"] == 0
    with pytest.raises(ValueError, match="finite"):
        cursor_axes(float("nan"))
    with pytest.raises(ValueError, match="play_hz"):
        PlotCursor((), play_hz=0.0)


def test_cursor_is_at_the_frame_after_a_scrub_a_jump_and_when_paused(app: ViewerApp) -> None:
    view = app.shared
    assert view is not None
    charts = plot_charts(view.plots)
    assert len(charts) == 4  # wrist speed, distance, reprojection error, residual
    assert _wait(lambda: _cursors(view) == [0.0] * 4), _cursors(view)
    app.timeline.frame.value = 37  # the user drags the slider
    assert _wait(lambda: _cursors(view) == [37 / FPS] * 4), _cursors(view)
    view.set_frame(83)  # what "next punch", event rows and "next problem" call
    assert _wait(lambda: _cursors(view) == [83 / FPS] * 4), _cursors(view)
    assert view.plot_cursor.time_s == 83 / FPS and "frame 83 /" in app.timeline.info.content
    moves = view.plot_cursor.moves
    view.render(83)  # the same frame again: the cursor is not re-sent
    assert view.plot_cursor.moves == moves


def test_cursor_moves_are_throttled_while_playing_and_exact_when_paused(app: ViewerApp) -> None:
    view = app.shared
    assert view is not None
    view.set_frame(0)
    assert _wait(lambda: _cursors(view) == [0.0] * 4)
    clock = FakeClock()
    view.playback.clock = clock
    view.plot_cursor = PlotCursor(plot_charts(view.plots), clock=clock)
    render = view.render
    during: list[tuple[float, int, bool]] = []  # (fake time, frame, cursor moved) of renders while playing
    lock = threading.Lock()

    def timed_render(frame: int, playing: bool = False) -> None:
        moves = view.plot_cursor.moves
        render(frame, playing)
        with lock:
            if playing:
                during.append((clock.t, frame, view.plot_cursor.moves > moves))
            clock.t = min(1.0, clock.t + 0.04)  # each render takes 40 ms of the (fake) clock; it stops at 1 s

    view.render = timed_render  # type: ignore[method-assign]
    try:
        app.timeline.play.value = True
        assert _wait(lambda: view.frame == 50), f"frame {view.frame} after 1 s of playback"
        app.timeline.play.value = False
        assert _wait(lambda: not view.playing and _cursors(view) == [50 / FPS] * 4), _cursors(view)
    finally:
        view.render = render  # type: ignore[method-assign]
    with lock:
        drawn = list(during)
    moved_at = [t for t, _, moved in drawn if moved]
    # Frames were drawn 25 times per (fake) second; the cursor moved at most PLAY_CURSOR_HZ times.
    assert len(drawn) >= 10, drawn
    assert 2 <= len(moved_at) <= 1.0 * PLAY_CURSOR_HZ + 1, drawn
    gaps = [b - a for a, b in zip(moved_at, moved_at[1:], strict=False)]
    assert all(g >= 1.0 / PLAY_CURSOR_HZ - 1e-9 for g in gaps), gaps
    assert view.plot_cursor.time_s == view.frame / FPS  # paused: the exact frame


@dataclass
class CursorClient(WsClient):
    """A websocket client keeping the cursor time each of its charts received last."""

    charts: dict[str, float | None] = field(default_factory=dict)
    cursor_updates: int = 0

    def _take(self, msg: dict[str, Any]) -> None:
        super()._take(msg)
        if msg.get("type") == "GuiUplotMessage":
            self.charts[str(msg["uuid"])] = None
        axes = (msg.get("updates") or {}).get("axes") if msg.get("type") == "GuiUpdateMessage" else None
        if axes and str(msg["uuid"]) in self.charts:
            self.charts[str(msg["uuid"])] = float(axes[-1]["splits"][0])
            self.cursor_updates += 1


def _connect(port: int) -> CursorClient:
    from websockets.sync.client import connect
    from websockets.typing import Subprotocol

    url, protocol = f"ws://127.0.0.1:{port}/", Subprotocol(VISER_PROTOCOL)
    conn = connect(url, subprotocols=[protocol], open_timeout=60, max_size=None)
    conn.send(camera_message())
    c = CursorClient(conn)
    c._thread = threading.Thread(target=c._drain, daemon=True)
    c._thread.start()
    return c


def test_two_clients_keep_their_own_cursors(tmp_path: Path) -> None:
    sdir = build_session(tmp_path, n_frames=60)
    port = free_port()
    server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    app = ViewerApp(server, sdir, max_image_width=160)
    app.serve_clients()
    fps = app.data.fps
    ca, cb = _connect(port), _connect(port)
    try:
        assert _wait(lambda: len(app.clients) == 2 and "Frame" in ca.uuids and "Frame" in cb.uuids, timeout_s=60)
        assert _wait(lambda: len(ca.charts) == len(cb.charts) == 5)  # the 4 plots and the event chart
        assert set(ca.charts).isdisjoint(cb.charts)  # each client has its own charts
        ca.set_value("Frame", 30)  # as each browser moves its slider
        cb.set_value("Frame", 10)
        assert _wait(lambda: set(ca.charts.values()) == {30 / fps} and set(cb.charts.values()) == {10 / fps}), (
            ca.charts, cb.charts)  # fmt: skip
        a = next(v for v in app.clients.values() if v.frame == 30)
        b_updates = cb.cursor_updates
        ca.set_value("Play", True)
        assert _wait(lambda: set(ca.charts.values()) - {None, 30 / fps} != set())  # a's cursor moves ...
        ca.set_value("Play", False)
        time.sleep(0.3)
        assert cb.cursor_updates == b_updates and set(cb.charts.values()) == {10 / fps}  # ... b's does not
        # Paused: a's cursor is at its exact frame.
        assert _wait(lambda: set(ca.charts.values()) == {a.frame / fps}), (a.frame, ca.charts)
    finally:
        ca.close()
        cb.close()
        app.close()
        server.stop()
