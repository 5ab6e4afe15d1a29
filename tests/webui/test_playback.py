"""Playback keeps real time: the frame follows the (fake) wall clock whatever the render speed;
while playing the camera images are smaller and the 3D casts no shadows, paused frames are
exact and full size, and a frame drawn again sends nothing new."""

from __future__ import annotations

import dataclasses
import threading
import time
from functools import partial
from pathlib import Path
from typing import Any

import pytest
import viser

from tests.webui.fixtures import build_session, wait_for
from webui.app import ViewerApp
from webui.launcher import free_port
from webui.playback import PLAY_IMAGE_SCALE, PlaybackClock
from webui.scene.session_data import load_session_data


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_playback_clock_follows_time_and_wraps() -> None:
    clock = FakeClock()
    pb = PlaybackClock(50.0, 120, clock)
    with pytest.raises(ValueError, match="stopped"):
        pb.frame()
    pb.start(10, 1.0)
    clock.t = 1.0
    assert pb.frame() == 60  # 50 frames in 1 s at 1x
    pb.start(pb.frame(), 2.0)
    clock.t = 1.5
    assert pb.frame() == (60 + 50) % 120  # 0.5 s at 2x
    clock.t = 2.0
    assert pb.frame() == (60 + 100) % 120  # wrapped past the last frame
    pb.start(5, 0.25)
    clock.t = 3.0
    assert pb.frame() == 5 + 12 and pb.speed == 0.25
    pb.stop()
    assert not pb.running
    with pytest.raises(ValueError, match="speed"):
        pb.start(0, 0.0)
    with pytest.raises(ValueError, match="fps"):
        PlaybackClock(0.0, 10)


_wait = partial(wait_for, timeout_s=15.0)


@pytest.fixture
def app(tmp_path: Path) -> Any:
    sdir = build_session(tmp_path, n_frames=120)
    data = load_session_data(sdir)
    data.rig = dataclasses.replace(data.rig, fps=50.0)  # a 50 fps bout
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    a = ViewerApp(server, sdir, role="coach", max_image_width=160, data=data)
    yield a
    a.close()
    server.stop()


def test_slow_renders_skip_frames_and_pausing_draws_the_exact_frame_full_size(app: ViewerApp) -> None:
    view = app.shared
    assert view is not None and app.data.fps == 50.0
    full_hw = view.views.images["cam1"].image.shape[:2]
    assert _wait(lambda: view.images_shown == (0, True))
    clock = FakeClock()
    view.playback.clock = clock
    render = view.render
    during: list[tuple[int, tuple[int, ...], bool]] = []
    lock = threading.Lock()

    def slow_render(frame: int, playing: bool = False) -> None:
        render(frame, playing)
        with lock:
            if playing:
                during.append((frame, view.views.images["cam1"].image.shape[:2], view.shadows))
            clock.t = min(
                1.0, clock.t + 0.25
            )  # each render takes 0.25 s of the (fake) clock; it stops at 1 s

    view.render = slow_render  # type: ignore[method-assign]
    app.timeline.play.value = True
    # 1 s at 1x on a 50 fps bout: frame 50, though only about 4 frames could be drawn in that time.
    assert _wait(lambda: view.frame == 50), f"frame {view.frame} after 1 s of playback"
    app.timeline.play.value = False
    assert _wait(lambda: view.images_shown == (50, True))
    with lock:
        drawn = list(during)
    assert 2 <= len(drawn) <= 8 and drawn[-1][0] == 50, drawn
    half = tuple(round(n * PLAY_IMAGE_SCALE) for n in full_hw)
    assert any(hw == half for _, hw, _ in drawn) and all(hw in (half, full_hw) for _, hw, _ in drawn)
    assert not any(sh for _, _, sh in drawn)  # no shadows while playing
    # Paused: the exact frame, full-size images, shadows back; it stays there.
    assert view.views.images["cam1"].image.shape[:2] == full_hw and view.shadows
    assert "frame 50 /" in app.timeline.info.content
    time.sleep(0.2)
    assert view.frame == 50


def test_scrubbing_while_playing_continues_from_the_new_frame(app: ViewerApp) -> None:
    view = app.shared
    assert view is not None
    clock = FakeClock()
    view.playback.clock = clock
    app.timeline.play.value = True
    assert _wait(lambda: view.playback.running)
    app.timeline.frame.value = 100  # the user drags the slider while playing
    assert _wait(lambda: view.playback.running and view._play_frame == 100)
    clock.t += 0.5  # 25 frames later, wrapping at 120
    assert _wait(lambda: view.frame == (100 + 25) % 120), view.frame
    app.timeline.play.value = False


def test_drawing_the_same_frame_again_sends_nothing_new(app: ViewerApp) -> None:
    view = app.shared
    assert view is not None
    assert _wait(lambda: view.images_shown == (0, True))  # the first frame drawn by the view's thread
    ws = app.server._websock_server
    sent: list[str] = []
    queue = ws.queue_message

    def counting(message: Any) -> None:
        sent.append(type(message).__name__)
        queue(message)

    ws.queue_message = counting  # type: ignore[method-assign]
    view.render(7)
    assert "SceneNodeUpdateMessage" in sent and "GuiUpdateMessage" in sent  # 3D and images of frame 7
    sent.clear()
    view.render(7)
    assert sent == []  # the same frame again: nothing re-sent
    view.render(8)
    assert sent.count("SceneNodeUpdateMessage") >= 2 and "GuiUpdateMessage" in sent
