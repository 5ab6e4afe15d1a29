"""The analytics as the viewer shows them (pure: no viser): punch marks per athlete, the
filtered event list, next / previous punch, and the per-athlete summary cards."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.schema.analytics import AthleteSeries, BoutEvents
from pipeline.stages.analyze.summary import summarize

ALL = "All"
MAX_MARKS = 60
"""Marks per athlete row at most (evenly thinned beyond)."""
MAX_LISTED = 40
"""Rows of the event list at most."""
TYPE_ABBREV: dict[str, str] = {
    "jab": "J", "cross": "C", "lead_hook": "LH", "rear_hook": "RH",
    "lead_uppercut": "LU", "rear_uppercut": "RU", "body_shot": "B",
}  # fmt: skip
OUTCOME_MARK: dict[str, str] = {"landed": "✓", "blocked": "▪", "missed": "·"}
"""Outcome symbol on a mark and in the list (marks carry text only, no colour)."""
HUMAN_MARK = "✎"
"""Suffix of a punch an annotator corrected or added (``BoutEvents.punch_source``)."""


@dataclass(frozen=True)
class EventsView:
    """The events of one session with the athletes' display names (``names``: id -> name)."""

    events: BoutEvents | None
    series: AthleteSeries | None
    names: dict[int, str]

    @property
    def n_punches(self) -> int:
        return 0 if self.events is None else self.events.n_punches

    def name(self, pid: int) -> str:
        return self.names.get(int(pid), f"P{int(pid)}")

    def human(self, i: int) -> str:
        """``HUMAN_MARK`` when punch ``i`` was corrected or added by an annotator, else ""."""
        ev = self.events
        return HUMAN_MARK if ev is not None and ev.punch_source[i] != "detector" else ""

    def label(self, i: int) -> str:
        """One line describing punch ``i``: time, athlete, type, outcome, speed."""
        ev = self.events
        assert ev is not None
        f = int(ev.punch_peak_frame[i])
        return (
            f"#{i + 1} {f / ev.fps:6.2f}s {self.name(ev.punch_person[i])} {str(ev.punch_type[i]).replace('_', ' ')} "
            f"{OUTCOME_MARK[str(ev.punch_outcome[i])]} {ev.punch_outcome[i]} {ev.punch_peak_speed_mps[i]:.1f} m/s"
            f"{' ' + self.human(i) if self.human(i) else ''}"
        )

    def matching(self, athlete: str = ALL, punch_type: str = ALL, outcome: str = ALL) -> np.ndarray:
        """Rows of the punches passing the filters (display names and vocabulary values, or ``ALL``)."""
        ev = self.events
        if ev is None:
            return np.zeros(0, dtype=np.int64)
        keep = np.ones(ev.n_punches, dtype=bool)
        if athlete != ALL:
            keep &= np.array([self.name(p) == athlete for p in ev.punch_person], dtype=bool)
        if punch_type != ALL:
            keep &= ev.punch_type == punch_type.replace(" ", "_")
        if outcome != ALL:
            keep &= ev.punch_outcome == outcome
        return np.flatnonzero(keep)

    def next_after(self, frame: int, rows: np.ndarray) -> int | None:
        """Strike frame of the first punch of ``rows`` after ``frame`` (wrapping); None without any."""
        if self.events is None or rows.size == 0:
            return None
        peaks = np.sort(self.events.punch_peak_frame[rows])
        later = peaks[peaks > frame]
        return int(later[0] if later.size else peaks[0])

    def prev_before(self, frame: int, rows: np.ndarray) -> int | None:
        """Strike frame of the last punch of ``rows`` before ``frame`` (wrapping)."""
        if self.events is None or rows.size == 0:
            return None
        peaks = np.sort(self.events.punch_peak_frame[rows])
        earlier = peaks[peaks < frame]
        return int(earlier[-1] if earlier.size else peaks[-1])

    def marks(self, pid: int, rows: np.ndarray | None = None) -> tuple[tuple[int, str], ...]:
        """(strike frame, label) of athlete ``pid``'s punches (of ``rows`` when given), e.g.
        ``"J✓"`` a jab that landed (``"J✓✎"`` as an annotator set it); at most ``MAX_MARKS`` (evenly thinned)."""
        ev = self.events
        if ev is None:
            return ()
        sel = np.flatnonzero(ev.punch_person == pid)
        if rows is not None:
            sel = np.intersect1d(sel, rows)
        if sel.size > MAX_MARKS:
            sel = sel[np.linspace(0, sel.size - 1, MAX_MARKS).astype(int)]
        return tuple(
            (
                int(ev.punch_peak_frame[i]),
                TYPE_ABBREV[str(ev.punch_type[i])] + OUTCOME_MARK[str(ev.punch_outcome[i])] + self.human(i),
            )
            for i in sel.tolist()
        )

    def listing(self, rows: np.ndarray) -> str:
        """Markdown table of the punches ``rows`` (at most ``MAX_LISTED``)."""
        ev = self.events
        if ev is None:
            return "No analytics yet: the analyze stage has not run."
        if rows.size == 0:
            return "No punch matches the filters."
        lines = ["| # | time s | athlete | type | outcome | target | m/s |", "|---:|---:|---|---|---|---|---:|"]
        for i in rows[:MAX_LISTED].tolist():
            lines.append(
                f"| {i + 1} | {ev.punch_peak_frame[i] / ev.fps:.2f} | {self.name(ev.punch_person[i])} | "
                f"{str(ev.punch_type[i]).replace('_', ' ')}{' ' + self.human(i) if self.human(i) else ''} | {OUTCOME_MARK[str(ev.punch_outcome[i])]} {ev.punch_outcome[i]} | "
                f"{ev.punch_target[i]} | {ev.punch_peak_speed_mps[i]:.1f} |"
            )
        more = f"\n\n…and {rows.size - MAX_LISTED} more." if rows.size > MAX_LISTED else ""
        if any(self.human(i) for i in rows[:MAX_LISTED].tolist()):
            more += f"\n\n{HUMAN_MARK} set or added by an annotator."
        return "\n".join(lines) + more

    def summary_cards(self) -> str:
        """Markdown: one card per athlete (thrown / landed / blocked / missed, speed, work rate, defence)."""
        if self.events is None or self.series is None:
            return ""
        s = summarize(self.events, self.series, self.names)
        cards = []
        for a in s["athletes"]:
            speed = f"{a['peak_speed_mean_mps']} m/s mean, {a['peak_speed_max_mps']} max" if a["punches"] else "–"
            cards.append(
                f"**{a['name']}** — {a['punches']} punches: {a['punches_landed']} landed, {a['punches_blocked']} "
                f"blocked, {a['punches_missed']} missed; {a['punches_per_min']} / min; speed {speed}; "
                f"{a['slips']} slips, {a['ducks']} ducks; stance {a.get('stance', '–')}"
            )
        return "\n\n".join(cards) + f"\n\nClinches: {s['clinches']}."
