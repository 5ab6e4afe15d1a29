"""Markdown tables of the benches' ``--json`` rows, and the README's results section.

``render(name, rows)`` turns one bench's rows (as ``cornerman bench NAME --json rows.json``
writes them) into a markdown table with the columns that matter for that bench;
``update_readme(readme, {name: json_path})`` replaces the text between the README's
markers ``<!-- bench:NAME -->`` and ``<!-- /bench:NAME -->`` with it, and with the line
saying what it was measured with when the JSON has its ``rows.env.json`` beside it
(``pipeline.bench.environment``). From the shell::

    python -m pipeline.bench.report README.md shelf=shelf.json footage=footage.json \\
        fit=fit.json physics=physics.json triangulation=triangulation.json analytics=analytics.json

Pure string work (no numpy, no pipeline imports), so it runs anywhere. Every problem is a
``ValueError`` naming the file: a missing or repeated marker, a JSON file that cannot be
read or is not a list of row objects, rows without the bench's table rows. Nothing is
written unless every table could be made; the README is replaced atomically.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.bench import environment as bench_env
from pipeline.stages.evaluate import FLAG_KINDS

Row = Mapping[str, Any]


@dataclass(frozen=True)
class Column:
    """One table column: a header (with its unit) and the row keys it shows.

    Several keys make one cell joined by " / " (e.g. max / mean); ``fmts`` gives one
    format per key. ``text`` columns are left-aligned, the others right-aligned.
    """

    head: str
    keys: tuple[str, ...]
    fmts: tuple[str, ...]
    text: bool = False

    def __post_init__(self) -> None:
        if not self.keys or len(self.keys) != len(self.fmts):
            raise ValueError(f"Column {self.head!r}: {len(self.keys)} keys but {len(self.fmts)} formats")


def col(head: str, *spec: str, text: bool = False) -> Column:
    """``col("pen max / mean mm", "a_mm", "{:.1f}", "b_mm", "{:.2f}")``: keys and formats alternate."""
    if len(spec) % 2:
        raise ValueError(f"col({head!r}): keys and formats must alternate, got {spec}")
    return Column(head, tuple(spec[0::2]), tuple(spec[1::2]), text)


def _value(v: Any, fmt: str) -> str:
    """A cell value: "" when missing or NaN, yes/no for booleans, else ``fmt``."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, float)):
        out = fmt.format(v) if fmt != "{}" else f"{v:g}"
        # -0.4 at "{:+.0f}" is "-0": a sign on a zero says nothing.
        return out.lstrip("+-") if out.lstrip("+-").strip("0.") == "" else out
    return str(v)


def cell(row: Row, column: Column) -> str:
    parts = [_value(row.get(k), f) for k, f in zip(column.keys, column.fmts, strict=True)]
    if not any(parts):
        return ""
    return " / ".join(p or "–" for p in parts).replace("|", "\\|")


def markdown_table(columns: Sequence[Column], rows: Sequence[Row]) -> str:
    """A markdown table of ``rows``; columns empty in every row are left out."""
    shown = [c for c in columns if any(cell(r, c) for r in rows)]
    if not shown:
        raise ValueError("no column has a value in any row")
    lines = [
        "| " + " | ".join(c.head for c in shown) + " |",
        "|" + "|".join("---" if c.text else "---:" for c in shown) + "|",
    ]
    lines += ["| " + " | ".join(cell(r, c) for c in shown) + " |" for r in rows]
    return "\n".join(lines)


# ------------------------------------------------------------------ the benches' tables
SHELF = (
    col("output", "output", "{}", text=True),
    col("PCP actor 0 %", "pcp_actor0", "{:.1f}"),
    col("PCP actor 1 %", "pcp_actor1", "{:.1f}"),
    col("PCP actor 2 %", "pcp_actor2", "{:.1f}"),
    col("PCP avg %", "pcp_avg", "{:.1f}"),
    col("MPJPE mm", "mpjpe_mm", "{:.1f}"),
    col("lower arms PCP %", "pcp_lower_arms", "{:.1f}"),
    col(
        "wrong limbs: all / 2D near us / 2D near GT",
        "wrong_limb_parts",
        "{}",
        "wrong_det_agree_output",
        "{}",
        "wrong_det_agree_gt",
        "{}",
    ),
    col("hips dz mm", "hip_dz_mm", "{:+.0f}"),
    col("stage s", "stage_s", "{:.1f}"),
    col("total s", "pipeline_s", "{:.1f}"),
    col("residual / floor Fz bw", "residual_mean_frac_bw", "{:.2f}", "grf_z_mean_frac_bw", "{:.2f}"),
    col("τ > human %", "torque_over_pct_any", "{:.0f}"),
    col("target", "target", "{}", text=True),
    col("met", "target_met", "{}"),
)
"""``pipeline.bench.shelf`` rows (measured, anchor and published; the timing row is left out)."""

FOOTAGE = (
    col("output", "output", "{}", text=True),
    col("reproj. median / p95 px", "reproj_median_px", "{:.1f}", "reproj_p95_px", "{:.0f}"),
    col("valid 3D %", "coverage_pct", "{:.1f}"),
    col("bone std mm", "bone_length_std_mm", "{:.1f}"),
    col("overlap max mm", "overlap_max_mm", "{:.1f}"),
    col("skate mm/frame", "foot_skate_mm_per_frame", "{:.2f}"),
    col("ground max mm", "ground_penetration_max_mm", "{:.1f}"),
    col("accel. mm/frame²", "accel_mm_per_frame2", "{:.2f}"),
    col(
        "residual force mean / max bw",
        "residual_force_mean_frac_bw",
        "{:.2f}",
        "residual_force_max_frac_bw",
        "{:.2f}",
    ),
    col("floor Fz bw", "grf_z_mean_frac_bw", "{:.2f}"),
    col("τ > human %", "torque_over_pct_any", "{:.0f}"),
)
"""``pipeline.bench.footage`` output rows (raw, filtered, fit, physics)."""

FIT = (
    col("cameras", "cameras", "{:.0f}"),
    col("method", "method", "{}", text=True),
    col("MPJPE mm", "mpjpe_mm", "{:.1f}"),
    col("accel. error mm/frame²", "accel_err_mm", "{:.2f}"),
    col("Δaccel. vs filtered %", "accel_vs_tri_pct", "{:+.0f}"),
    col("bone std mm", "bone_std_mm", "{:.1f}"),
    col("lowest foot z mm", "min_foot_z_mm", "{:.1f}"),
    col("reproj. px", "reproj_px", "{:.1f}"),
    col("frames/s per person", "fps_per_person", "{:.1f}"),
)
"""``pipeline.bench.fit`` rows (raw and filtered triangulation, fit, per camera count)."""

PHYSICS = (
    col("scene", "scene", "{}", text=True),
    col("method", "method", "{}", text=True),
    col("seed", "seed", "{}", text=True),
    col("pen. max / mean mm", "inter_penetration_max_mm", "{:.1f}", "inter_penetration_mean_mm", "{:.2f}"),
    col("body pen. max / mean mm", "body_pen_max_mm", "{:.1f}", "body_pen_mean_mm", "{:.2f}"),
    col("ground max mm", "ground_penetration_max_mm", "{:.1f}"),
    col("skate mm/frame", "foot_skate_mm_per_frame", "{:.2f}"),
    col("MPJPE mm", "mpjpe_mm", "{:.1f}"),
    col("Δbody pen. max %", "d_body_pen_max_pct", "{:+.0f}"),
    col("Δskate %", "d_skate_pct", "{:+.0f}"),
    col("ΔMPJPE %", "d_mpjpe_pct", "{:+.0f}"),
    col("residual bw", "residual_mean_frac_bw", "{:.2f}"),
    col("floor Fz bw", "grf_z_mean_frac_bw", "{:.2f}"),
    col("τ > human %", "torque_over_pct_any", "{:.0f}"),
    col("RTF ×", "realtime_factor", "{:.1f}"),
    col("× mj_step", "x_plain_step", "{:.0f}"),
)
"""``pipeline.bench.physics`` rows: the means over seeds when the rows have them, else every row."""

TRIANGULATION = (
    col("scenario", "scenario", "{}", text=True),
    col("method", "method", "{}", text=True),
    col("PCP %", "pcp_pct", "{:.2f}"),
    col("MPJPE mm", "mpjpe_mm", "{:.1f}"),
    col("identity acc. %", "id_acc_pct", "{:.2f}"),
    col("frames/s (all)", "fps", "{:.0f}"),
    col("frames/s (triangulation)", "tri_fps", "{:.0f}"),
)
"""``pipeline.bench.triangulation`` rows (cornerman and the baselines per scenario)."""


ANALYTICS = (
    col("data", "data", "{}", text=True),
    col("cameras", "cameras", "{}"),
    col("precision", "precision", "{:.3f}"),
    col("recall", "recall", "{:.3f}"),
    col("type acc. %", "type_acc_pct", "{:.1f}"),
    col("outcome acc. %", "outcome_acc_pct", "{:.1f}"),
    col("peak-speed error %", "speed_err_pct", "{:.1f}"),
    col("clinch-frame F1", "clinch_f1", "{:.3f}"),
    col("block precision / recall", "block_precision", "{:.3f}", "block_recall", "{:.3f}"),
    col("false punches / min", "false_per_min", "{:.1f}"),
)
"""``pipeline.bench.analytics`` rows (synthetic bouts per camera count, the Pose2Sim sample)."""


def _shelf(rows: Sequence[Row]) -> tuple[list[Row], list[str]]:
    return [r for r in rows if r.get("kind") != "timing"], []


def _footage(rows: Sequence[Row]) -> tuple[list[Row], list[str]]:
    outs = [r for r in rows if r.get("kind") == "output"]
    session = next((r for r in rows if r.get("kind") == "session"), None)
    notes = []
    if session is not None and "flag_any_pct" in session:
        shown = [(k, _value(session.get(f"flag_{k.key}_pct"), "{:.0f}")) for k in FLAG_KINDS]
        # A kind the run could not raise (e.g. untrackable with an always-on residual) is left out.
        kinds = ", ".join(f"{k.label} {v} %" for k, v in shown if v)
        notes.append(
            f"Frames flagged by the evaluate stage: {_value(session['flag_any_pct'], '{:.0f}')} % "
            f"of {session.get('flag_frames', '?')}, tracking flags {_value(session.get('flag_tracking_pct'), '{:.0f}')} % "
            f"({kinds})."
        )
    return outs, notes


def _physics(rows: Sequence[Row]) -> tuple[list[Row], list[str]]:
    means = [r for r in rows if str(r.get("seed", "")).startswith("mean of")]
    if not means:
        return list(rows), []
    n = str(means[0]["seed"])[len("mean of") :].strip()
    return [{k: v for k, v in r.items() if k != "seed"} for r in means], [f"Means over {n} seeds per scene."]


def _all(rows: Sequence[Row]) -> tuple[list[Row], list[str]]:
    return list(rows), []


TABLES: dict[str, tuple[tuple[Column, ...], Callable[[Sequence[Row]], tuple[list[Row], list[str]]]]] = {
    "shelf": (SHELF, _shelf),
    "footage": (FOOTAGE, _footage),
    "fit": (FIT, _all),
    "physics": (PHYSICS, _physics),
    "triangulation": (TRIANGULATION, _all),
    "analytics": (ANALYTICS, _all),
}
"""Bench name -> (columns, row selection returning the rows shown and generated note lines)."""


def render(name: str, rows: Sequence[Row]) -> str:
    """Markdown table (and generated note lines) for the rows of bench ``name``.

    ``ValueError`` for an unknown bench, rows that are not objects, or no row to show.
    """
    if name not in TABLES:
        raise ValueError(f"no table for bench {name!r}; known: {sorted(TABLES)}")
    if (
        not isinstance(rows, Sequence)
        or isinstance(rows, (str, bytes))
        or not all(isinstance(r, Mapping) for r in rows)
    ):
        raise ValueError(f"bench {name}: expected a list of row objects, got {type(rows).__name__}")
    columns, select = TABLES[name]
    shown, notes = select(rows)
    if not shown:
        raise ValueError(f"bench {name}: none of the {len(rows)} rows is a table row")
    try:
        table = markdown_table(columns, shown)
    except ValueError as e:
        raise ValueError(f"bench {name}: {e} (are these {name} rows?)") from e
    return "\n\n".join([table, *notes])


# ------------------------------------------------------------------ the README
def markers(name: str) -> tuple[str, str]:
    return f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"


def load_rows(json_path: str | Path) -> list[dict[str, Any]]:
    """The rows of a bench's ``--json`` file; ``ValueError`` naming the file when it cannot be used."""
    path = Path(json_path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise ValueError(f"{path}: cannot read the bench rows: {e.strerror or e}") from e
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: malformed JSON: {e}") from e
    if not isinstance(data, list) or not all(isinstance(r, dict) for r in data):
        raise ValueError(
            f"{path}: expected a JSON list of row objects (cornerman bench NAME --json), got {type(data).__name__}"
        )
    return data


def replace_between(text: str, name: str, body: str, where: str) -> str:
    """``text`` with the part between bench ``name``'s markers replaced by ``body``."""
    start, end = markers(name)
    n_start, n_end = text.count(start), text.count(end)
    if n_start != 1 or n_end != 1:
        raise ValueError(f"{where}: needs exactly one {start} and one {end}, found {n_start} and {n_end}")
    i, j = text.index(start) + len(start), text.index(end)
    if j < i:
        raise ValueError(f"{where}: {end} comes before {start}")
    return text[:i] + "\n" + body.strip("\n") + "\n" + text[j:]


def update_readme(readme_path: str | Path, sources: Mapping[str, str | Path]) -> str:
    """Replace each bench's table in ``readme_path`` by one made from its JSON rows.

    ``sources`` maps bench names to ``--json`` files. Every table is made before anything
    is written; the file is then replaced atomically. Returns the new text.
    """
    readme = Path(readme_path)
    if not sources:
        raise ValueError(f"{readme}: no bench given (NAME=rows.json)")
    try:
        text = readme.read_text(encoding="utf-8")
    except OSError as e:
        raise ValueError(f"{readme}: cannot read: {e.strerror or e}") from e
    for name, json_path in sources.items():
        try:
            table = render(name, load_rows(json_path))
            env = bench_env.load(json_path)
            if env is not None:
                table += "\n\n" + bench_env.describe(env)
        except ValueError as e:
            msg = str(e)
            named = msg.startswith((str(json_path), str(bench_env.sidecar_path(json_path))))
            raise ValueError(msg if named else f"{json_path}: {msg}") from e
        text = replace_between(text, name, table, str(readme))
    _write_atomic(readme, text)
    return text


def _write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        if path.exists():
            os.chmod(tmp, path.stat().st_mode & 0o777)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m pipeline.bench.report",
        description="Regenerate the README's bench tables from `cornerman bench NAME --json rows.json` files.",
    )
    p.add_argument(
        "readme",
        type=Path,
        help="the markdown file with <!-- bench:NAME --> ... <!-- /bench:NAME --> markers",
    )
    p.add_argument(
        "sources", nargs="+", metavar="NAME=JSON", help=f"bench rows, NAME one of {', '.join(TABLES)}"
    )
    args = p.parse_args(argv)
    sources: dict[str, str] = {}
    for item in args.sources:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            p.error(f"expected NAME=JSON, got {item!r}")
        sources[name] = path
    try:
        update_readme(args.readme, sources)
    except ValueError as e:
        sys.stderr.write(f"error: {e}\n")
        return 2
    sys.stderr.write(f"updated {args.readme}: {', '.join(sources)}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
