"""Timeline: frame slider with problem marks, play/pause, speed and "next problem" (of any
kind, or of the kind chosen in the dropdown, ``FLAG_KINDS``)."""

from __future__ import annotations

from dataclasses import dataclass

import viser
from viser._messages import GuiSliderMark

from pipeline.stages.evaluate import FLAG_KINDS
from webui.analysis import FrameProblems

SPEEDS: tuple[str, ...] = ("0.25x", "0.5x", "1x", "2x")
MAX_MARKS = 40
ANY_PROBLEM = "any problem"


@dataclass
class TimelineHandles:
    frame: viser.GuiSliderHandle[int]
    play: viser.GuiCheckboxHandle
    speed: viser.GuiDropdownHandle[str]
    next_problem: viser.GuiButtonHandle
    problem_kind: viser.GuiDropdownHandle[str]
    """Which problems "Next problem" visits: ``ANY_PROBLEM`` or one kind (``kind_options``)."""
    info: viser.GuiMarkdownHandle

    @property
    def speed_factor(self) -> float:
        return float(self.speed.value.rstrip("x"))

    @property
    def kind(self) -> str | None:
        """The ``FlagKind.key`` chosen in ``problem_kind``; None for any problem."""
        opts = list(self.problem_kind.options)
        i = opts.index(self.problem_kind.value) if self.problem_kind.value in opts else 0
        return None if i == 0 else FLAG_KINDS[i - 1].key


def kind_options(problems: FrameProblems | None) -> tuple[str, ...]:
    """Dropdown labels: ``ANY_PROBLEM``, then each kind's label with its count of flagged frames."""
    counts = problems.counts() if problems is not None else {}
    return (ANY_PROBLEM, *(f"{k.label} ({counts.get(k.key, 0)})" for k in FLAG_KINDS))


def problem_marks(problems: FrameProblems) -> tuple[tuple[int, str], ...]:
    """Slider marks at the start of each run of flagged frames (at most ``MAX_MARKS``)."""
    segs = problems.segments()
    if len(segs) > MAX_MARKS:
        step = len(segs) / MAX_MARKS
        segs = [segs[int(i * step)] for i in range(MAX_MARKS)]
    return tuple((int(s), "!") for s, _ in segs)


def make_timeline(server: viser.ViserServer, n_frames: int) -> TimelineHandles:
    frame = server.gui.add_slider("Frame", min=0, max=max(1, n_frames - 1), step=1, initial_value=0)
    play = server.gui.add_checkbox("Play", initial_value=False)
    speed = server.gui.add_dropdown("Speed", SPEEDS, initial_value="1x")
    next_problem = server.gui.add_button("Next problem", hint="Jump to the next frame flagged as suspicious")
    kind = server.gui.add_dropdown(
        "Problem kind", kind_options(None), initial_value=ANY_PROBLEM,
        hint="Which flags \"Next problem\" visits (flagged frames of each kind in brackets)",
    )  # fmt: skip
    info = server.gui.add_markdown("")
    return TimelineHandles(frame, play, speed, next_problem, kind, info)


def set_problems(h: TimelineHandles, problems: FrameProblems, n_frames: int) -> None:
    h.frame.max = max(1, n_frames - 1)
    marks = problem_marks(problems)
    # viser 1.1 exposes marks only at creation (``add_slider(marks=...)``); the prop itself is
    # assignable and synced like every other, so results reloaded later update it here.
    h.frame._marks = tuple(GuiSliderMark(value=float(v), label=lab) for v, lab in marks) or None
    h.next_problem.disabled = not bool(problems.any.any())
    # Same position in the new list: the counts in the labels change on reload, the kinds do not.
    old = list(h.problem_kind.options)
    i = old.index(h.problem_kind.value) if h.problem_kind.value in old else 0
    opts = kind_options(problems)
    h.problem_kind.options = opts
    h.problem_kind.value = opts[i]  # type: ignore[misc]
