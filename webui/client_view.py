"""One client's view of the shared viewer: its own frame, playback, speed, layers, panels and persons.

A ``ClientView`` is built for each browser that connects (``ViewerApp.connect``) on that
client's GUI and scene (``viser.ClientHandle.gui`` / ``.scene``), or on the server itself
(every client, one shared view) in tests and scripts. Session data, camera frames, body
meshes and physics geoms belong to the ``ViewerApp`` and are shared by every view. One
thread per view renders its frame and advances its playback; ``close()`` (the client left)
stops both. Playback keeps real time and sends less while playing (``webui.playback``).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import TYPE_CHECKING, Any, cast

import cv2
import viser

from pipeline.geometry.layout import layout_advice
from webui.analysis import compute_series
from webui.clients import ClientUser
from webui.colors import StalePalette
from webui.editing import (
    EditHistory,
    Selection,
    assign_edit,
    describe_selection,
    invalid_edit,
    split_edit,
    swap_edit,
)
from webui.frames import draw_overlay, overlay_for
from webui.jobs import JobWatcher, job_fraction, job_summary
from webui.panels.annotate import (
    NO_ENTRY,
    NO_TRACK,
    AnnotateHandles,
    entry_label,
    history_markdown,
    make_annotate,
    parse_entry_label,
    parse_track_label,
    rename_annotate,
    track_label,
)
from webui.panels.display import label_to_source, make_display, source_options
from webui.panels.events import follow_frame, make_event_rows, make_events, set_events, wire_events
from webui.panels.export import make_export, wire_export
from webui.panels.plot_cursor import PlotCursor, plot_charts
from webui.panels.plots import make_plots, update_plots
from webui.panels.timeline import make_timeline, set_problems
from webui.panels.views import make_views
from webui.playback import PLAY_IMAGE_SCALE, PLAY_IMAGES_HZ, PLAY_MAX_HZ, PLAY_SHADOWS, PlaybackClock
from webui.scene.persons import DisplayOptions, PersonsScene
from webui.scope import Scope
from webui.staleness import SOURCE_LAYER, layers_markdown

if TYPE_CHECKING:
    from webui.app import ViewerApp

log = logging.getLogger(__name__)

PLAY_TICK_S = 0.02
"""How often a playing view checks whether the next frame is due when none was (s)."""


class ClientView:
    """GUI, persons and playback of one client (or of every client when ``scope`` is the server)."""

    def __init__(self, app: ViewerApp, scope: Scope, user: ClientUser) -> None:
        self.app, self.scope, self.user = app, scope, user
        self.frame = 0
        self.rendered = 0
        """Frames drawn so far (tests and the bench)."""
        self.playback = PlaybackClock(app.data.fps, max(1, app.data.n_frames))
        """Which frame is due while playing (``webui.playback``)."""
        self._play_frame = -1  # the frame playback set last: another one means the user scrubbed
        self.images_shown: tuple[int, bool] | None = None
        """(frame, full size) of the camera images sent last; None before any."""
        self._images_at = -math.inf
        self._images_key: tuple = ()
        self._images_of: tuple = ()  # the palette and data those images were drawn with
        self.shadows = True
        """Whether this view's default lights cast shadows now (viser's default; off while playing)."""
        self._stop = threading.Event()
        self._render_wanted = threading.Event()
        self._lock = threading.RLock()  # render vs rebuild after a reload
        self._watchers: list[JobWatcher] = []
        can_edit = user.can_edit and app.session_id is not None
        self.history = EditHistory(user.api, app.session_id) if can_edit and user.api is not None and app.session_id else None
        data, palette = app.data, app.palette
        # timeline.py / plots.py are typed for a ViserServer but use only ``.gui``, which a client has too.
        as_server = cast(viser.ViserServer, scope)
        who = f" — signed in as **{user.name}** ({user.role})" if user.name else ""
        self._who = who
        self.header = scope.gui.add_markdown(self._header_text())
        self.layers = scope.gui.add_markdown("", visible=False)
        """One line per layer while a re-run after an edit is under way (``webui.staleness``)."""
        self.stale_layers: frozenset[str] = frozenset()
        """Layers out of date: drawn dimmed (3D) or grey (2D labels) until their stage is rewritten."""
        self.timeline = make_timeline(as_server, data.n_frames)
        everyone = [(p, palette.name(p)) for p in (data.person_ids or [0, 1])]
        event_rows = make_event_rows(scope, everyone, data.n_frames, data.fps)
        tabs = scope.gui.add_tab_group()
        with tabs.add_tab("Cameras"):
            self.views = make_views(scope, data.camera_names, app.image_sizes())
        self.annotate: AnnotateHandles | None = None
        if self.history is not None:
            with tabs.add_tab("Edit"):
                athletes = [(p, palette.name(p)) for p in (data.person_ids or [0, 1])[:2]]
                self.annotate = make_annotate(scope, data.camera_names, athletes, data.n_frames)
        with tabs.add_tab("Plots"):
            self.plots = make_plots(as_server, compute_series(data, app.default_source()), palette)
        self.plot_cursor = PlotCursor((*plot_charts(self.plots), event_rows.chart))
        """The current-frame line on this view's plots and event chart (``webui.panels.plot_cursor``)."""
        with tabs.add_tab("Events"):
            self.events = make_events(scope, [n for _, n in everyone], event_rows, layout_advice(data.rig) or "")
        with tabs.add_tab("Display"):
            self.display = make_display(scope, list(data.keypoints))
        with tabs.add_tab("Export"):
            self.export = make_export(scope)
        self.opts = DisplayOptions(source=label_to_source(self.display.source.value))
        self.persons = PersonsScene(scope, data, palette, app.body_cache, app.physics_geoms)
        self.persons.build()
        set_problems(self.timeline, app.problems, data.n_frames)
        set_events(self.events, app.events_view(), data.n_frames, data.fps)
        self.show_layers(app.layer_states(), render=False)
        self._wire()
        self._entries: list[dict] = []
        if self.annotate is not None:
            self.refresh_history()
        self._thread = threading.Thread(target=self._loop, name=f"view-{self.name}", daemon=True)
        self._thread.start()
        self.request_render()

    # ------------------------------------------------------------------ state
    def _header_text(self) -> str:
        return f"**{self.app.data.config.name}** — {self.app.legend()}{self._who}"

    @property
    def name(self) -> str:
        """For logs: the client id and user (``server`` for a view shared by every client)."""
        cid = getattr(self.scope, "client_id", None)
        return ("server" if cid is None else f"client {cid}") + (f" ({self.user.name})" if self.user.name else "")

    @property
    def playing(self) -> bool:
        return bool(self.timeline.play.value) and not self._stop.is_set()

    @property
    def alive(self) -> bool:
        """Whether the view's render / playback thread still runs."""
        return self._thread.is_alive()

    def selection(self) -> Selection:
        if self.annotate is None:
            return Selection(self.app.data.camera_names[0], None, self.frame)
        return Selection(self.annotate.view.value, parse_track_label(self.annotate.track.value), self.frame)

    def set_frame(self, frame: int) -> None:
        self.timeline.frame.value = int(frame)  # type: ignore[misc]  # its callback renders

    # ------------------------------------------------------------------ rendering
    def request_render(self) -> None:
        self._render_wanted.set()

    def _loop(self) -> None:
        """Render on request (latest wins) and, while Play is on, show the frame the wall clock
        says is due at most ``PLAY_MAX_HZ`` times per second, until closed."""
        last_render = -math.inf
        while not self._stop.is_set():
            if self.playing:
                # Wait for the next render slot (a pause pressed meanwhile is seen right after).
                if self._stop.wait(max(0.0, last_render + 1.0 / PLAY_MAX_HZ - time.monotonic())):
                    break
                if self.playing:
                    self._advance()
                    if not self._render_wanted.is_set():  # no new frame due yet (a slow speed)
                        self._stop.wait(PLAY_TICK_S)
                        continue
            else:
                self.playback.stop()
                self._render_wanted.wait(0.25)
                if self._stop.is_set():
                    break
                if self.playing:  # Play pressed: start the clock before the first frame is drawn
                    continue
            if self._render_wanted.is_set():
                self._render_wanted.clear()
                last_render = time.monotonic()  # slots are PLAY_MAX_HZ apart, render time included
                try:
                    self.render(self.frame, playing=self.playing)
                except Exception:  # keep the viewer alive; the traceback goes to the log
                    if not self._stop.is_set():
                        log.exception("%s: rendering frame %d failed", self.name, self.frame)

    def _advance(self) -> None:
        """Move to the frame playback says is due (frames are skipped when renders are slow)."""
        pb = self.playback
        n = self.app.data.n_frames
        speed = self.timeline.speed_factor
        if pb.n_frames != max(1, n):  # a reload changed the bout's length
            pb = self.playback = PlaybackClock(self.app.data.fps, max(1, n), pb.clock)
        if not pb.running or pb.speed != speed or self.frame != self._play_frame:
            pb.start(self.frame, speed)  # Play pressed, the speed changed, or the user scrubbed
            self._play_frame = self.frame
        due = pb.frame()
        if due != self.frame:
            self._play_frame = due
            self.set_frame(due)

    def render(self, frame: int, playing: bool = False) -> None:
        """Draw ``frame`` in this view: 3D persons, camera images, selection and info.

        ``playing``: the camera images go at ``PLAY_IMAGE_SCALE`` of their size and at most
        ``PLAY_IMAGES_HZ`` times per second (skipped in between), the plots' cursor at most
        ``PLAY_CURSOR_HZ`` times; otherwise full-size images and the cursor at ``frame``."""
        app = self.app
        with self._lock:
            data = self.persons.data
            shadows = PLAY_SHADOWS or not playing
            if shadows != self.shadows:
                self.scope.scene.configure_default_lights(enabled=True, cast_shadow=shadows)
                self.shadows = shadows
            self.persons.update(frame, self.opts)  # one atomic scene update
            sel_track = None
            if self.annotate is not None:
                self._refresh_track_options(frame)
                sel = self.selection()
                sel_track = sel.track
                names = {p: app.palette.name(p) for p in data.person_ids}
                self.annotate.selection.content = describe_selection(data, sel, names)
            now = time.monotonic()
            if not playing or now - self._images_at >= 1.0 / PLAY_IMAGES_HZ:
                self._draw_images(frame, sel_track, full=not playing)
                self._images_at = now
            problems = app.problems
            kinds = problems.kinds_at(frame) if frame < problems.n_frames else []
            flag = f" — ⚠ {', '.join(kinds)}" if kinds else ""
            self.timeline.info.content = f"frame {frame} / {data.n_frames - 1} ({frame / data.fps:.2f} s){flag}"
            self.plot_cursor.show(frame / data.fps, playing)  # at most PLAY_CURSOR_HZ moves/s while playing
            self.rendered += 1

    def _draw_images(self, frame: int, sel_track: int | None, full: bool) -> None:
        """Camera images of ``frame`` with their overlays (``full``: display size, else ``PLAY_IMAGE_SCALE`` of it)."""
        app, data = self.app, self.persons.data
        view = self.annotate.view.value if self.annotate is not None else ""
        key = (frame, full, sel_track, view, self.opts.source, self.stale_layers)
        of = (app.palette, data, app.provider)
        if key == self._images_key and all(a is b for a, b in zip(of, self._images_of, strict=True)):
            return  # the same images again: nothing to send
        self._images_key, self._images_of = key, of
        images = app.provider.frames(frame)
        stale = self.stale_layers
        palette = StalePalette(app.palette) if "2D labels" in stale else app.palette
        reproject = SOURCE_LAYER.get(self.opts.source, "") not in stale
        for v, name in enumerate(data.camera_names):
            img = images[v]
            ov = overlay_for(data, v, frame, self.opts.source)
            st = sel_track if (self.annotate is not None and self.annotate.view.value == name) else None
            draw_overlay(img, ov, app.provider.scale(v), palette, st, show_reprojection=reproject)
            if not full and PLAY_IMAGE_SCALE < 1.0:
                h, w = img.shape[:2]
                size = (max(1, round(w * PLAY_IMAGE_SCALE)), max(1, round(h * PLAY_IMAGE_SCALE)))
                img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
            self.views.images[name].image = img
        self.images_shown = (frame, full)

    def _refresh_track_options(self, frame: int) -> None:
        assert self.annotate is not None
        data, palette = self.persons.data, self.app.palette
        v = data.rig.index(self.annotate.view.value)
        rows = data.det_rows(v, frame)
        opts = [NO_TRACK]
        if data.tracks is not None:
            for r, p in zip(rows, data.person_of_rows(rows), strict=True):
                tid = int(data.tracks.track_id[r])
                if tid >= 0:
                    opts.append(track_label(tid, palette.name(int(p))))
        current = parse_track_label(self.annotate.track.value)
        keep = next((o for o in opts[1:] if parse_track_label(o) == current), None) if current is not None else None
        if tuple(opts) != tuple(self.annotate.track.options):
            self.annotate.track.options = tuple(opts)
        # Keep the selected track while it is visible; otherwise select the first one.
        want = keep or (opts[1] if len(opts) > 1 else NO_TRACK)
        if self.annotate.track.value != want:
            self.annotate.track.value = want  # type: ignore[misc]

    def show_layers(self, states: dict[str, str], render: bool = True) -> None:
        """Show which layers are out of date (``ViewerApp.layer_states``) and dim them."""
        stale = frozenset(k for k, why in states.items() if why)
        text = layers_markdown(states)
        with self._lock:
            if text != self.layers.content:
                self.layers.content = text
            self.layers.visible = bool(text)
            changed = stale != self.stale_layers
            self.stale_layers = stale
            self._apply_dim()
        if changed and render:
            self.request_render()

    def _apply_dim(self) -> None:
        stale = self.stale_layers
        self.opts.dim_skeleton = SOURCE_LAYER.get(self.opts.source, "") in stale
        self.opts.dim_body = "fit" in stale
        self.opts.dim_physics = "physics" in stale

    def on_palette(self) -> None:
        """Names or colours of the identities changed: legend, buttons, meshes, plots, labels."""
        app = self.app
        with self._lock, self.scope.atomic():
            self.header.content = self._header_text()
            self.persons.palette = app.palette
            self.persons.recolor()
            if self.annotate is not None:
                rename_annotate(self.annotate, {p: app.palette.name(p) for p in self.annotate.assign})
            update_plots(self.plots, compute_series(app.data, self.opts.source), app.palette)
            set_events(self.events, app.events_view(), app.data.n_frames, app.data.fps)
        self.request_render()

    def on_reload(self, states: dict[str, str] | None = None) -> None:
        """Rebuild what depends on the results after ``ViewerApp.reload`` (keeps the frame and selection);
        ``states``: the layers' states with the new results."""
        app = self.app
        data = app.data
        if states is not None:
            self.show_layers(states, render=False)
        with self._lock, self.scope.atomic():
            self.persons.data = data
            self.persons.body_cache, self.persons.physics_geoms = app.body_cache, app.physics_geoms
            self.persons.build()
            self.display.source.options = source_options(list(data.keypoints))
            set_problems(self.timeline, app.problems, data.n_frames)
            set_events(self.events, app.events_view(), data.n_frames, data.fps)
            update_plots(self.plots, compute_series(data, self.opts.source), app.palette)
        self.request_render()

    # ------------------------------------------------------------------ callbacks
    def _wire(self) -> None:
        tl, disp, app = self.timeline, self.display, self.app

        @tl.frame.on_update
        def _(_: Any) -> None:
            self.frame = int(tl.frame.value)
            follow_frame(self.events, self.frame)
            self.request_render()

        # Pausing draws the exact frame again with full-size images.
        tl.play.on_update(lambda _: self.request_render())

        wire_events(self.events, app.events_view, lambda: self.frame, self.set_frame, lambda: app.data.n_frames,
                    lambda: app.data.fps)
        wire_export(self.export, self.scope, app.session_dir,
                    lambda: {p: app.palette.name(p) for p in app.data.person_ids}, lambda: self.opts.source)

        @tl.next_problem.on_click
        def _(_: Any) -> None:
            nxt = app.problems.next_after(self.frame, tl.kind)
            if nxt is not None:
                self.set_frame(nxt)

        @disp.source.on_update
        def _(_: Any) -> None:
            self.opts.source = label_to_source(disp.source.value)
            self._apply_dim()
            update_plots(self.plots, compute_series(app.data, self.opts.source), app.palette)
            self.request_render()

        for cb in (disp.skeleton, disp.body, disp.physics):
            cb.on_update(lambda _: self._set_layers())

        @disp.reload.on_click
        def _(_: Any) -> None:
            app.reload()

        for name in app.data.camera_names:
            self.views.align[name].on_click(app.aligner(app.data.rig.index(name)))
        if self.annotate is not None:
            self._wire_annotate(self.annotate)

    def _set_layers(self) -> None:
        self.opts.show_skeleton = self.display.skeleton.value
        self.opts.show_body = self.display.body.value
        self.opts.show_physics = self.display.physics.value
        self.request_render()

    def _wire_annotate(self, a: AnnotateHandles) -> None:
        a.view.on_update(lambda _: self.request_render())
        a.track.on_update(lambda _: self.request_render())

        def assigner(pid: int) -> Any:
            def cb(_: Any) -> None:
                self._submit(lambda: assign_edit(self.app.data, self.selection(), pid, a.from_here.value))

            return cb

        for pid, button in a.assign.items():
            button.on_click(assigner(pid))
        ids = list(a.assign)

        def do_swap() -> Any:
            if len(ids) < 2:
                raise ValueError("a swap needs two athletes")
            return swap_edit(self.selection(), ids[0], ids[1], a.swap_scope.value == "all views", int(a.swap_until.value))

        @a.until_here.on_click
        def _(_: Any) -> None:
            a.swap_until.value = self.frame  # type: ignore[misc]

        a.swap.on_click(lambda _: self._submit(do_swap))
        a.undo_entry.on_click(lambda _: self._undo_entry())

        @a.goto_entry.on_click
        def _(_: Any) -> None:
            aid = parse_entry_label(a.entry.value)
            entry = next((e for e in self._entries if e["id"] == aid), None)
            payload = (entry or {}).get("payload") or {}
            frame = payload.get("frame", payload.get("frame_start"))
            if frame is not None:
                self.set_frame(min(int(frame), self.app.data.n_frames - 1))
        a.split.on_click(lambda _: self._submit(lambda: split_edit(self.selection())))
        a.invalid.on_click(lambda _: self._submit(lambda: invalid_edit(self.selection())))
        a.undo.on_click(lambda _: self._history_call("undo"))
        a.redo.on_click(lambda _: self._history_call("redo"))

    def _submit(self, make_edit: Any) -> None:
        assert self.history is not None and self.annotate is not None
        since = time.time()
        try:
            edit = make_edit()
            res = self.history.submit(edit)
        except (ValueError, RuntimeError) as e:  # ApiError is a ValueError
            self.annotate.status.content = f"Edit refused: {e}"
            return
        self._after_change(f"Saved {edit.kind} (annotation {res['annotation']['id']})", res, since)

    def _history_call(self, which: str) -> None:
        assert self.history is not None and self.annotate is not None
        since = time.time()
        try:
            res = self.history.undo() if which == "undo" else self.history.redo()
        except ValueError as e:
            self.annotate.status.content = f"{which} failed: {e}"
            return
        if res is None:
            self.annotate.status.content = f"Nothing to {which}."
            return
        self._after_change(f"{which.capitalize()} of annotation {res['annotation']['id']}", res, since)

    def _undo_entry(self) -> None:
        assert self.history is not None and self.annotate is not None
        aid = parse_entry_label(self.annotate.entry.value)
        if aid is None:
            self.annotate.status.content = "Choose an active edit in the history first."
            return
        since = time.time()
        try:
            res = self.history.undo_entry(aid)
        except ValueError as e:
            self.annotate.status.content = f"undo of #{aid} failed: {e}"
            return
        self._after_change(f"Undo of annotation {aid}", res, since)

    def refresh_history(self) -> None:
        """Re-read the edit history into the Edit tab (list and the dropdown of active entries)."""
        if self.history is None or self.annotate is None:
            return
        a = self.annotate
        try:
            entries = self.history.entries()
        except (ValueError, RuntimeError) as e:  # ApiError; RuntimeError: client closed as it left
            log.debug("%s: history not read: %s", self.name, e)
            return
        self._entries = entries
        a.history.content = history_markdown(entries)
        opts = tuple(entry_label(e) for e in entries if e.get("state") == "active") or (NO_ENTRY,)
        if opts != tuple(a.entry.options):
            keep = a.entry.value if a.entry.value in opts else opts[0]
            a.entry.options = opts
            a.entry.value = keep  # type: ignore[misc]

    def _after_change(self, msg: str, res: dict, since: float) -> None:
        assert self.annotate is not None and self.user.api is not None
        a = self.annotate
        job = res.get("job")
        stale = res.get("stale_from")
        a.status.content = f"{msg}; stale from **{stale}**." + (" Re-run queued." if job else "")
        self.app.mark_stale(stale, job, since)
        self.refresh_history()
        if not job:
            return
        weights = self.app.stage_durations()
        a.progress.visible = True
        a.progress.value = 0.0  # type: ignore[misc]

        def on_update(j: dict) -> None:
            a.progress.value = 100.0 * job_fraction(j, weights)  # type: ignore[misc]
            a.status.content = f"{msg}. {job_summary(j)}"
            self.app.on_job(j)

        def on_end(j: dict) -> None:
            a.progress.value = 100.0  # type: ignore[misc]
            if j.get("status") == "done":
                self.app.reload()
                a.status.content = f"{msg}. {job_summary(j)} — results reloaded."
            else:
                a.status.content = f"{msg}. {job_summary(j)}"

        self._watchers.append(JobWatcher(self.user.api, job["id"], on_update, on_end).start())

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop this view's playback, rendering and job watchers (its client left); waits for its thread."""
        self._stop.set()
        self._render_wanted.set()
        for w in self._watchers:
            w.stop()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)
