"""The analytics as the viewer shows them (pure: no viser): punch and defence marks per athlete,
the filtered event list, next / previous punch, and the per-athlete summary cards.

Defence rows (slips, ducks, blocks, parries: ``BoutEvents.evade_*``) belong to the defender;
the filters apply to them as: athlete = the defender, type = the defence kind, outcome = the
outcome of the punch defended.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.schema.analytics import EVADE_KINDS, OUTCOMES, AthleteSeries, BoutEvents
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
DEFENCE_MARK = "◇"
"""Prefix of a defence mark (on the defender's row), e.g. ``◇Bk`` a block."""
DEFENCE_ABBREV: dict[str, str] = {"slip": "S", "duck": "D", "block": "Bk", "parry": "P"}
DEFENCE_ID = "D"
"""Prefix of a defence row's number in the list and the picker (``D2``; punches are ``#2``)."""
LEGEND = (
    "Marks: " + ", ".join(f"{a} {t.replace('_', ' ')}" for t, a in TYPE_ABBREV.items())
    + " + " + ", ".join(f"{m} {o}" for o, m in OUTCOME_MARK.items())
    + f"; defence {DEFENCE_MARK}: " + ", ".join(f"{DEFENCE_MARK}{a} {k}" for k, a in DEFENCE_ABBREV.items())
    + f"; {HUMAN_MARK} set or added by an annotator."
)  # fmt: skip
"""The legend of the marks, shown in the Events tab and the rows' hints."""
DEFENCE_SERIES = "defence"
"""The event chart's series of defence events (beside one series per punch outcome)."""
DEFENCE_COLOR = "#6a3d9a"
"""Colour (CSS hex) of defence points on the event chart."""


def _none(rows: np.ndarray | None) -> np.ndarray:
    return np.zeros(0, dtype=np.int64) if rows is None else rows


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

    @property
    def n_defence(self) -> int:
        return 0 if self.events is None else self.events.n_evades

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

    def human_defence(self, j: int) -> str:
        """``HUMAN_MARK`` when defence row ``j`` was corrected or added by an annotator, else ""."""
        ev = self.events
        return HUMAN_MARK if ev is not None and ev.evade_source[j] != "detector" else ""

    def defence_label(self, j: int) -> str:
        """One line describing defence row ``j``: time, defender, kind, the punch defended."""
        ev = self.events
        assert ev is not None
        k, p = str(ev.evade_kind[j]), int(ev.evade_punch[j])
        f = int(ev.evade_peak_frame[j])
        return (
            f"{DEFENCE_ID}{j + 1} {f / ev.fps:6.2f}s {self.name(ev.evade_person[j])} {k} {DEFENCE_MARK}{DEFENCE_ABBREV[k]} "
            f"vs {self.name(ev.punch_person[p])}'s {str(ev.punch_type[p]).replace('_', ' ')} #{p + 1}"
            f"{' ' + self.human_defence(j) if self.human_defence(j) else ''}"
        )

    def matching(self, athlete: str = ALL, punch_type: str = ALL, outcome: str = ALL) -> np.ndarray:
        """Rows of the punches passing the filters (display names and vocabulary values, or ``ALL``;
        a defence kind as ``punch_type`` matches no punch)."""
        ev = self.events
        if ev is None or punch_type in EVADE_KINDS:
            return np.zeros(0, dtype=np.int64)
        keep = np.ones(ev.n_punches, dtype=bool)
        if athlete != ALL:
            keep &= np.array([self.name(p) == athlete for p in ev.punch_person], dtype=bool)
        if punch_type != ALL:
            keep &= ev.punch_type == punch_type.replace(" ", "_")
        if outcome != ALL:
            keep &= ev.punch_outcome == outcome
        return np.flatnonzero(keep)

    def defence_matching(self, athlete: str = ALL, kind: str = ALL, outcome: str = ALL) -> np.ndarray:
        """Rows of the defence events passing the filters: ``athlete`` the defender, ``kind`` a
        defence kind (a punch type matches none), ``outcome`` that of the punch defended."""
        ev = self.events
        if ev is None or (kind != ALL and kind not in EVADE_KINDS):
            return np.zeros(0, dtype=np.int64)
        keep = np.ones(ev.n_evades, dtype=bool)
        if athlete != ALL:
            keep &= np.array([self.name(p) == athlete for p in ev.evade_person], dtype=bool)
        if kind != ALL:
            keep &= ev.evade_kind == kind
        if outcome != ALL:
            keep &= ev.punch_outcome[ev.evade_punch] == outcome
        return np.flatnonzero(keep)

    def jump_frames(self, rows: np.ndarray, defence: np.ndarray) -> np.ndarray:
        """Frames "next / previous" visits: the strikes of the punches ``rows``, or, when no punch
        matches (the type filter is a defence kind), the peaks of the defence rows ``defence``."""
        if self.events is None:
            return np.zeros(0, dtype=np.int64)
        if rows.size:
            return self.events.punch_peak_frame[rows]
        return self.events.evade_peak_frame[defence]

    def next_after(self, frame: int, rows: np.ndarray, defence: np.ndarray | None = None) -> int | None:
        """First frame of ``jump_frames(rows, defence)`` after ``frame`` (wrapping); None without any."""
        frames = np.sort(self.jump_frames(rows, _none(defence)))
        if frames.size == 0:
            return None
        later = frames[frames > frame]
        return int(later[0] if later.size else frames[0])

    def prev_before(self, frame: int, rows: np.ndarray, defence: np.ndarray | None = None) -> int | None:
        """Last frame of ``jump_frames(rows, defence)`` before ``frame`` (wrapping); None without any."""
        frames = np.sort(self.jump_frames(rows, _none(defence)))
        if frames.size == 0:
            return None
        earlier = frames[frames < frame]
        return int(earlier[-1] if earlier.size else frames[-1])

    def marks(
        self, pid: int, rows: np.ndarray | None = None, defence: np.ndarray | None = None
    ) -> tuple[tuple[int, str], ...]:
        """(frame, label) of athlete ``pid``'s punches (of ``rows`` when given) at their strike, e.g.
        ``"J✓"`` a jab that landed (``"J✓✎"`` as an annotator set it), and of the defence rows
        where ``pid`` defended (of ``defence`` when given) at their peak, e.g. ``"◇Bk"`` a block;
        in frame order, at most ``MAX_MARKS`` (evenly thinned)."""
        ev = self.events
        if ev is None:
            return ()
        sel = np.flatnonzero(ev.punch_person == pid)
        if rows is not None:
            sel = np.intersect1d(sel, rows)
        dsel = np.flatnonzero(ev.evade_person == pid)
        if defence is not None:
            dsel = np.intersect1d(dsel, defence)
        out = [
            (int(ev.punch_peak_frame[i]),
             TYPE_ABBREV[str(ev.punch_type[i])] + OUTCOME_MARK[str(ev.punch_outcome[i])] + self.human(i))
            for i in sel.tolist()
        ] + [
            (int(ev.evade_peak_frame[j]),
             DEFENCE_MARK + DEFENCE_ABBREV[str(ev.evade_kind[j])] + self.human_defence(j))
            for j in dsel.tolist()
        ]  # fmt: skip
        out.sort(key=lambda m: m[0])
        if len(out) > MAX_MARKS:
            out = [out[k] for k in np.linspace(0, len(out) - 1, MAX_MARKS).astype(int).tolist()]
        return tuple(out)

    def chart_rows(
        self, pids: list[int], n_frames: int, rows: np.ndarray | None = None, defence: np.ndarray | None = None
    ) -> dict[str, np.ndarray]:
        """The event chart's points: for each outcome of ``OUTCOMES`` and for ``DEFENCE_SERIES``, an
        (n_frames,) array holding the row of the athlete (1 for ``pids[0]``, 2 for ``pids[1]``, …) at
        the strike frame of each of his punches with that outcome (of ``rows`` when given), and at
        the peak of each defence row where he defended (of ``defence``), NaN elsewhere."""
        out = {k: np.full(max(int(n_frames), 0), np.nan) for k in (*OUTCOMES, DEFENCE_SERIES)}
        ev = self.events
        if ev is None:
            return out
        row_of = {int(p): k + 1.0 for k, p in enumerate(pids)}
        sel = np.arange(ev.n_punches) if rows is None else rows
        for i in sel.tolist():
            f, r = int(ev.punch_peak_frame[i]), row_of.get(int(ev.punch_person[i]))
            if r is not None and 0 <= f < n_frames:
                out[str(ev.punch_outcome[i])][f] = r
        for j in (np.arange(ev.n_evades) if defence is None else defence).tolist():
            f, r = int(ev.evade_peak_frame[j]), row_of.get(int(ev.evade_person[j]))
            if r is not None and 0 <= f < n_frames:
                out[DEFENCE_SERIES][f] = r
        return out

    def picker_labels(self, rows: np.ndarray, defence: np.ndarray) -> tuple[str, ...]:
        """Labels of the punches ``rows`` and the defence rows ``defence`` in frame order (the picker)."""
        ev = self.events
        if ev is None:
            return ()
        items = [(int(ev.punch_peak_frame[i]), 0, self.label(int(i))) for i in rows.tolist()]
        items += [(int(ev.evade_peak_frame[j]), 1, self.defence_label(int(j))) for j in defence.tolist()]
        return tuple(lab for _, _, lab in sorted(items))

    def frame_of_label(self, label: str) -> int | None:
        """The frame a picker label (``label`` / ``defence_label``) points at; None for anything else."""
        ev = self.events
        head = label.split(" ", 1)[0]
        if ev is None or len(head) < 2 or not head[1:].isdigit():
            return None
        i = int(head[1:]) - 1
        if head[0] == "#" and 0 <= i < ev.n_punches:
            return int(ev.punch_peak_frame[i])
        if head[0] == DEFENCE_ID and 0 <= i < ev.n_evades:
            return int(ev.evade_peak_frame[i])
        return None

    def listing(self, rows: np.ndarray, defence: np.ndarray | None = None) -> str:
        """Markdown tables of the punches ``rows`` and of the defence rows ``defence`` (None: none),
        at most ``MAX_LISTED`` rows each."""
        ev = self.events
        if ev is None:
            return "No analytics yet: the analyze stage has not run."
        defence = _none(defence)
        if rows.size == 0 and defence.size == 0:
            return "No event matches the filters."
        text = self._punch_table(rows) if rows.size else ""
        if defence.size:
            text += ("\n\n" if text else "") + self._defence_table(defence)
        human = any(self.human(i) for i in rows[:MAX_LISTED].tolist()) or any(
            self.human_defence(j) for j in defence[:MAX_LISTED].tolist()
        )
        return text + (f"\n\n{HUMAN_MARK} set or added by an annotator." if human else "")

    def _defence_table(self, defence: np.ndarray) -> str:
        ev = self.events
        assert ev is not None
        lines = ["| D# | time s | defender | defence | against | punch outcome | m |", "|---:|---:|---|---|---|---|---:|"]
        for j in defence[:MAX_LISTED].tolist():
            k, p = str(ev.evade_kind[j]), int(ev.evade_punch[j])
            h = self.human_defence(j)
            lines.append(
                f"| {DEFENCE_ID}{j + 1} | {ev.evade_peak_frame[j] / ev.fps:.2f} | {self.name(ev.evade_person[j])} | "
                f"{DEFENCE_MARK}{DEFENCE_ABBREV[k]} {k}{' ' + h if h else ''} | "
                f"#{p + 1} {self.name(ev.punch_person[p])}'s {str(ev.punch_type[p]).replace('_', ' ')} | "
                f"{OUTCOME_MARK[str(ev.punch_outcome[p])]} {ev.punch_outcome[p]} | {ev.evade_displacement_m[j]:.2f} |"
            )
        more = f"\n\n…and {defence.size - MAX_LISTED} more defence rows." if defence.size > MAX_LISTED else ""
        return "\n".join(lines) + more

    def _punch_table(self, rows: np.ndarray) -> str:
        ev = self.events
        assert ev is not None
        lines = ["| # | time s | athlete | type | outcome | target | m/s |", "|---:|---:|---|---|---|---|---:|"]
        for i in rows[:MAX_LISTED].tolist():
            lines.append(
                f"| {i + 1} | {ev.punch_peak_frame[i] / ev.fps:.2f} | {self.name(ev.punch_person[i])} | "
                f"{str(ev.punch_type[i]).replace('_', ' ')}{' ' + self.human(i) if self.human(i) else ''} | {OUTCOME_MARK[str(ev.punch_outcome[i])]} {ev.punch_outcome[i]} | "
                f"{ev.punch_target[i]} | {ev.punch_peak_speed_mps[i]:.1f} |"
            )
        more = f"\n\n…and {rows.size - MAX_LISTED} more." if rows.size > MAX_LISTED else ""
        return "\n".join(lines) + more

    def summary_cards(self) -> str:
        """Markdown: one card per athlete (thrown / landed / blocked / missed, speed, work rate, defence
        by kind: slips, ducks, blocks, parries)."""
        if self.events is None or self.series is None:
            return ""
        s = summarize(self.events, self.series, self.names)
        cards = []
        for a in s["athletes"]:
            speed = f"{a['peak_speed_mean_mps']} m/s mean, {a['peak_speed_max_mps']} max" if a["punches"] else "–"
            cards.append(
                f"**{a['name']}** — {a['punches']} punches: {a['punches_landed']} landed, {a['punches_blocked']} "
                f"blocked, {a['punches_missed']} missed; {a['punches_per_min']} / min; speed {speed}; "
                f"defence: {a['slips']} slips, {a['ducks']} ducks, {a['blocks']} blocks, {a['parries']} parries; "
                f"stance {a.get('stance', '–')}"
            )
        return "\n\n".join(cards) + f"\n\nClinches: {s['clinches']}."
