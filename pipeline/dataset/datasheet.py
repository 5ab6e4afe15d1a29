"""``datasheet.md``: what a release holds, how it was made and labelled, and its counts.

Generated from the sessions' ``meta.json``, ``events.json`` and ``annotations.json`` documents;
the licence, motivation and consent sections are placeholders for the publisher to fill.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from pipeline.dataset.annotations import annotation_counts
from pipeline.schema.analytics import EVADE_KINDS

TODO = "**TO FILL IN**"
DEFENCE_COUNTS: dict[str, str] = {"slip": "slips", "duck": "ducks", "block": "blocks", "parry": "parries"}
"""Row of the counts table for each defence kind (``events.json`` ``evades[].kind``)."""


def _table(header: list[str], rows: list[list[Any]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return [*out, ""]


def datasheet(
    release: dict[str, Any],
    metas: list[dict[str, Any]],
    events: dict[str, dict[str, Any]],
    annotations: dict[str, dict[str, Any]],
    licence: str = "",
) -> str:
    """The markdown text. ``events`` and ``annotations`` map a session id to its document
    (``events`` only for sessions where the analyze stage ran); ``licence`` = "" leaves a placeholder."""
    lines = [
        f"# Datasheet: cornerman dataset release ({release['format']})",
        "",
        f"Created {release['created_utc']} with cornerman {release['cornerman_version']}. "
        f"{len(metas)} session(s). Layout: `{release['format']}` (cornerman's docs/design/dataset_release.md); "
        "JSON Schemas in `schemas/`, NPZ arrays in `schemas/npz_layouts.json`. "
        "`cornerman dataset validate DIR` checks a copy against them and `checksums.sha256`.",
        "",
        "## Licence",
        "",
        licence
        or f"{TODO}: the licence of this release (e.g. CC BY 4.0) and its terms of use "
        "(`cornerman dataset export --licence TEXT` writes it here).",
        "",
        "## Motivation and consent",
        "",
        f"{TODO}: why the bouts were recorded, who funded it, and the consent the athletes gave "
        "(recording, publication, identifiability).",
        "",
        "## What was recorded",
        "",
    ]
    rows = []
    for m in metas:
        athletes = ", ".join(f"{a['name'] or '?'} ({a['id']})" for a in m["athletes"])
        rows.append([m["id"], m["name"], m["source"], len(m["cameras"]), f"{m['fps']:g}", m["n_frames"],
                     f"{m['n_frames'] / m['fps']:.1f}", athletes])  # fmt: skip
    lines += _table(
        ["session", "name", "input", "cameras", "fps", "frames", "seconds", "athletes (id)"], rows
    )
    lines += [
        "Conventions: " + "; ".join(f"{k}: {v}" for k, v in release["conventions"].items()) + ".",
        "",
        "## How it was labelled",
        "",
        "2D keypoints, tracks and identities, 3D keypoints, body parameters and events come from the "
        "cornerman pipeline. Human edits (identity swaps and assignments, track splits and merges, "
        "invalid detections, keypoint fixes, contact labels) are typed overlays the stages applied when "
        "they re-ran; they are listed per session below and in each session's annotations.json. "
        "Stages and their code versions:",
        "",
    ]
    for m in metas:
        lines += [f"### {m['id']}", ""]
        lines += _table(
            ["stage", "status", "code version", "run at (UTC)"],
            [[s["stage"], s["status"], f"`{s['code_version']}`", s["created_utc"]] for s in m["stages"]],
        )
        stale = [s["stage"] for s in m["stages"] if s["status"] != "fresh"]
        if stale:
            lines += [
                f"Warning: stale when released (inputs, config or code changed since they ran): {', '.join(stale)}.",
                "",
            ]
        doc = annotations[m["id"]]
        counts = annotation_counts(doc)
        if counts:
            lines += _table(
                ["edit kind", "author", "active edits"], [[k, a, n] for (k, a), n in sorted(counts.items())]
            )
        else:
            lines += ["No human edits.", ""]
        lines += [f"Annotation provenance: {doc['note']}", ""]
    lines += ["## Counts", ""]
    totals: Counter[str] = Counter()
    for m in metas:
        totals["frames"] += m["n_frames"]
        totals["camera-frames"] += m["n_frames"] * len(m["cameras"])
        totals["2D detections"] += m["n_detections"]
        totals["2D detections with an athlete identity"] += m["n_detections_identified"]
        totals["athletes (per session, summed)"] += len(m["athletes"])
        totals["3D keypoint results"] += sum(f["kind"] == "keypoints3d" for f in m["files"])
        totals["sessions with body parameters"] += any(f["kind"] == "bodyfit" for f in m["files"])
        totals["sessions with physics"] += any(f["kind"] == "physics" for f in m["files"])
        totals["human edits in force"] += sum(annotation_counts(annotations[m["id"]]).values())
        ev = events.get(m["id"])
        if ev is not None:
            totals["sessions with events"] += 1
            totals["punches"] += len(ev["punches"])
            for kind in EVADE_KINDS:
                totals[DEFENCE_COUNTS[kind]] += 0  # every kind gets a row, 0 included
            for e in ev["evades"]:
                totals[DEFENCE_COUNTS.get(e["kind"], f"defence '{e['kind']}'")] += 1
            totals["clinches"] += len(ev["clinches"])
    lines += _table(["what", "count"], [["sessions", len(metas)], *[[k, v] for k, v in totals.items()]])
    return "\n".join(lines)
