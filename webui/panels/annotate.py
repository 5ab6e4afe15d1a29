"""Annotation panel: pick a view and a track, then assign / swap (from this frame, optionally
until a later one) / split / invalidate; undo and redo; the edit history with undo of any entry.

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
    swap_until: viser.GuiNumberHandle[int]
    until_here: viser.GuiButtonHandle
    swap: viser.GuiButtonHandle
    split: viser.GuiButtonHandle
    invalid: viser.GuiButtonHandle
    undo: viser.GuiButtonHandle
    redo: viser.GuiButtonHandle
    status: viser.GuiMarkdownHandle
    progress: GuiProgressBarHandle
    history: viser.GuiMarkdownHandle
    entry: viser.GuiDropdownHandle[str]
    undo_entry: viser.GuiButtonHandle
    goto_entry: viser.GuiButtonHandle


NO_ENTRY = "(no active edit)"


def track_label(track: int, person_name: str) -> str:
    """Dropdown label of a track (stable over frames while its identity does not change)."""
    return f"#{track} {person_name}"


def parse_track_label(label: str) -> int | None:
    """Track id of a dropdown label made by :func:`track_label` (None for ``NO_TRACK``)."""
    if not label.startswith("#"):
        return None
    return int(label[1:].split(" ", 1)[0])


def entry_label(entry: dict) -> str:
    """Dropdown label of an edit-history entry (``GET .../annotations/history`` row)."""
    return f"#{entry['id']} {entry.get('summary') or entry.get('kind', '')}"[:80]


def parse_entry_label(label: str) -> int | None:
    """Annotation id of a label made by :func:`entry_label` (None for ``NO_ENTRY``)."""
    if not label.startswith("#"):
        return None
    return int(label[1:].split(" ", 1)[0])


def history_markdown(entries: list[dict], limit: int = 12) -> str:
    """The newest ``limit`` entries, one line each: id, summary, author, time and state."""
    if not entries:
        return "*No edits yet.*"
    lines = []
    for e in entries[:limit]:
        when = str(e.get("created_at", ""))[11:16]
        state = e.get("state", "")
        mark = "" if state == "active" else f" *({state})*"
        lines.append(f"- #{e['id']} {e.get('summary', e.get('kind', ''))} — {e.get('author', '')} {when}{mark}")
    more = f"\n\n… and {len(entries) - limit} older" if len(entries) > limit else ""
    return "**Edit history** (newest first)\n\n" + "\n".join(lines) + more


def make_annotate(server: Scope, camera_names: tuple[str, ...], athletes: list[tuple[int, str]], n_frames: int = 1) -> AnnotateHandles:
    """``athletes``: (person id, display name) of the first two persons (A and B); ``n_frames``: the
    bout's length (bound of the swap's end frame)."""
    view = server.gui.add_dropdown("View", camera_names, initial_value=camera_names[0])
    track = server.gui.add_dropdown("Detection", (NO_TRACK,), initial_value=NO_TRACK)
    selection = server.gui.add_markdown("")
    assign: dict[int, viser.GuiButtonHandle] = {}
    for pid, name in athletes:
        assign[pid] = server.gui.add_button(f"Assign to {name}", hint=f"The selected track is {name}")
    from_here = server.gui.add_checkbox("Only from this frame on", initial_value=False)
    swap_scope = server.gui.add_dropdown("Swap in", SCOPES, initial_value=SCOPES[0])
    names = " and ".join(n for _, n in athletes[:2])
    swap_until = server.gui.add_number("Swap until frame", initial_value=0, min=0, max=max(1, n_frames), step=1,
                                       hint="The swap covers this frame up to (not including) this one; 0: to the end")
    until_here = server.gui.add_button("Swap until = this frame", hint="Set the end of the swap to the current frame")
    swap = server.gui.add_button(f"Swap {names} from this frame", hint="Identities swap from the current frame (until the frame above)")
    split = server.gui.add_button("Split track here", hint="The selected track is a new person from this frame on")
    invalid = server.gui.add_button("Mark detection invalid", hint="Ignore the selected detection at this frame")
    undo = server.gui.add_button("Undo last edit")
    redo = server.gui.add_button("Redo")
    status = server.gui.add_markdown("")
    progress = server.gui.add_progress_bar(0.0, visible=False)
    history = server.gui.add_markdown("")
    entry = server.gui.add_dropdown("History entry", (NO_ENTRY,), initial_value=NO_ENTRY)
    undo_entry = server.gui.add_button("Undo this entry", hint="Revert the chosen edit (any active one, not only the last)")
    goto_entry = server.gui.add_button("Go to its frame")
    return AnnotateHandles(view, track, selection, assign, from_here, swap_scope, swap_until, until_here, swap, split,
                           invalid, undo, redo, status, progress, history, entry, undo_entry, goto_entry)


def rename_annotate(h: AnnotateHandles, names: dict[int, str]) -> None:
    """Relabel the per-athlete buttons after identities were renamed (``names``: person id -> name)."""
    for pid, button in h.assign.items():
        if pid in names:
            button.label = f"Assign to {names[pid]}"
            button.hint = f"The selected track is {names[pid]}"
    pair = [names[p] for p in list(h.assign)[:2] if p in names]
    if len(pair) == 2:
        h.swap.label = f"Swap {pair[0]} and {pair[1]} from this frame"
