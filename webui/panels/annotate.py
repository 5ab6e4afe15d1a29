"""Annotation panel: pick a view and a track, then assign / swap / split / invalidate; undo and redo.

Built only for roles that may edit (never for a coach's read-only token).
"""

from __future__ import annotations

from dataclasses import dataclass

import viser
from viser._gui_handles import GuiProgressBarHandle

from webui.scope import Scope

SCOPES: tuple[str, ...] = ("this view", "all views")
NO_TRACK = "(no detection)"


@dataclass
class AnnotateHandles:
    view: viser.GuiDropdownHandle[str]
    track: viser.GuiDropdownHandle[str]
    selection: viser.GuiMarkdownHandle
    assign: dict[int, viser.GuiButtonHandle]
    from_here: viser.GuiCheckboxHandle
    swap_scope: viser.GuiDropdownHandle[str]
    swap: viser.GuiButtonHandle
    split: viser.GuiButtonHandle
    invalid: viser.GuiButtonHandle
    undo: viser.GuiButtonHandle
    redo: viser.GuiButtonHandle
    status: viser.GuiMarkdownHandle
    progress: GuiProgressBarHandle


def track_label(track: int, person_name: str) -> str:
    """Dropdown label of a track (stable over frames while its identity does not change)."""
    return f"#{track} {person_name}"


def parse_track_label(label: str) -> int | None:
    """Track id of a dropdown label made by :func:`track_label` (None for ``NO_TRACK``)."""
    if not label.startswith("#"):
        return None
    return int(label[1:].split(" ", 1)[0])


def make_annotate(server: Scope, camera_names: tuple[str, ...], athletes: list[tuple[int, str]]) -> AnnotateHandles:
    """``athletes``: (person id, display name) of the first two persons (A and B)."""
    view = server.gui.add_dropdown("View", camera_names, initial_value=camera_names[0])
    track = server.gui.add_dropdown("Detection", (NO_TRACK,), initial_value=NO_TRACK)
    selection = server.gui.add_markdown("")
    assign: dict[int, viser.GuiButtonHandle] = {}
    for pid, name in athletes:
        assign[pid] = server.gui.add_button(f"Assign to {name}", hint=f"The selected track is {name}")
    from_here = server.gui.add_checkbox("Only from this frame on", initial_value=False)
    swap_scope = server.gui.add_dropdown("Swap in", SCOPES, initial_value=SCOPES[0])
    names = " and ".join(n for _, n in athletes[:2])
    swap = server.gui.add_button(f"Swap {names} from this frame", hint="Identities swap from the current frame on")
    split = server.gui.add_button("Split track here", hint="The selected track is a new person from this frame on")
    invalid = server.gui.add_button("Mark detection invalid", hint="Ignore the selected detection at this frame")
    undo = server.gui.add_button("Undo last edit")
    redo = server.gui.add_button("Redo")
    status = server.gui.add_markdown("")
    progress = server.gui.add_progress_bar(0.0, visible=False)
    return AnnotateHandles(view, track, selection, assign, from_here, swap_scope, swap, split, invalid, undo, redo, status, progress)


def rename_annotate(h: AnnotateHandles, names: dict[int, str]) -> None:
    """Relabel the per-athlete buttons after identities were renamed (``names``: person id -> name)."""
    for pid, button in h.assign.items():
        if pid in names:
            button.label = f"Assign to {names[pid]}"
            button.hint = f"The selected track is {names[pid]}"
    pair = [names[p] for p in list(h.assign)[:2] if p in names]
    if len(pair) == 2:
        h.swap.label = f"Swap {pair[0]} and {pair[1]}"
