"""``pipeline.bench.report``: markdown tables from bench rows, and the README's marked sections."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pipeline.bench.environment import environment, sidecar_path
from pipeline.bench.report import load_rows, main, render, update_readme


def _table(md: str) -> list[list[str]]:
    """The cells of the first markdown table in ``md`` (header first, separator left out)."""
    lines = [ln for ln in md.splitlines() if ln.startswith("|")]
    rows = [[c.strip() for c in ln.strip("|").split("|")] for ln in lines]
    return [rows[0], *rows[2:]]


def _physics_rows() -> list[dict]:
    kin = {
        "method": "kinematic (fit)",
        "inter_penetration_max_mm": 1.04,
        "inter_penetration_mean_mm": 0.039,
        "foot_skate_mm_per_frame": 1.1855,
        "mpjpe_mm": 10.3455,
        "body_pen_max_mm": 36.54,
        "body_pen_mean_mm": 5.06,
    }
    multi = {
        "method": "physics (multi, bodyfit mesh)",
        "inter_penetration_max_mm": 12.67,
        "inter_penetration_mean_mm": 0.378,
        "foot_skate_mm_per_frame": 0.3238,
        "mpjpe_mm": 11.3008,
        "body_pen_max_mm": 3.67,
        "body_pen_mean_mm": 0.056,
        "d_skate_pct": -72.86,
        "d_mpjpe_pct": 9.27,
        "d_body_pen_max_pct": -0.4,
        "realtime_factor": 18.43,
        "residual_mean_frac_bw": 0.8307,
    }
    per_seed = [{**kin, "seed": 0, "mpjpe_mm": 99.0}, {**multi, "seed": 0, "mpjpe_mm": 98.0}]
    return per_seed + [{**kin, "seed": "mean of 4"}, {**multi, "seed": "mean of 4"}]


def test_physics_table_shows_the_means_with_units_and_signed_changes() -> None:
    md = render("physics", _physics_rows())
    head, kin, multi = _table(md)
    assert head[0] == "method" and "seed" not in head  # mean rows: the seed column says nothing
    assert "pen. max / mean mm" in head and "skate mm/frame" in head and "RTF ×" in head
    assert kin[0] == "kinematic (fit)" and multi[0] == "physics (multi, bodyfit mesh)"
    assert multi[head.index("pen. max / mean mm")] == "12.7 / 0.38"
    assert multi[head.index("skate mm/frame")] == "0.32"
    assert multi[head.index("MPJPE mm")] == "11.3"  # the mean row's, not seed 0's 98.0
    assert multi[head.index("ΔMPJPE %")] == "+9" and multi[head.index("Δskate %")] == "-73"
    assert multi[head.index("Δbody pen. max %")] == "0"  # -0.4 rounds to an unsigned 0
    assert kin[head.index("ΔMPJPE %")] == "" and kin[head.index("RTF ×")] == ""
    assert "Means over 4 seeds per scene." in md
    assert "ground max mm" not in head  # no row has it: the column is left out


def test_physics_table_without_means_shows_every_seed() -> None:
    rows = _physics_rows()[:2]
    head, kin, _ = _table(render("physics", rows))
    assert head[1] == "seed" and kin[1] == "0" and kin[head.index("MPJPE mm")] == "99.0"


def test_shelf_table_leaves_out_the_timing_row_and_keeps_the_references() -> None:
    rows = [
        {"output": "stage times", "kind": "timing", "fit_s": 31.1},
        {
            "output": "fit",
            "kind": "measured",
            "pcp_actor0": 99.318,
            "pcp_actor1": 94.054,
            "pcp_actor2": 98.385,
            "pcp_avg": 97.2527,
            "mpjpe_mm": 51.637,
            "stage_s": 31.14,
            "pipeline_s": 36.3,
            "target": "PCP >= 98.5",
            "target_met": False,
        },
        {"output": "paper: physics (published)", "kind": "published", "pcp_avg": 98.3},
    ]
    head, fit, paper = _table(render("shelf", rows))
    assert head[:6] == ["output", "PCP actor 0 %", "PCP actor 1 %", "PCP actor 2 %", "PCP avg %", "MPJPE mm"]
    assert fit[:6] == ["fit", "99.3", "94.1", "98.4", "97.3", "51.6"]
    assert fit[head.index("met")] == "no" and fit[head.index("stage s")] == "31.1"
    assert paper[0] == "paper: physics (published)" and paper[head.index("PCP avg %")] == "98.3"
    assert paper[head.index("MPJPE mm")] == ""


def test_footage_table_joins_median_and_p95_and_notes_the_flags() -> None:
    rows = [
        {
            "kind": "output",
            "output": "fit",
            "reproj_median_px": 10.695,
            "reproj_p95_px": 148.8,
            "coverage_pct": 100.0,
            "bone_length_std_mm": 7.69,
            "foot_skate_mm_per_frame": 8.405,
        },
        {
            "kind": "output",
            "output": "physics",
            "reproj_median_px": 15.47,
            "reproj_p95_px": 146.9,
            "residual_force_mean_frac_bw": 1.2836,
        },
        {
            "kind": "session",
            "output": "session",
            "flag_frames": 100,
            "flag_any_pct": 57.0,
            "flag_tracking_pct": 56.0,
            "flag_identity_low_pct": 12.0,
            "flag_reprojection_high_pct": 57.0,
            "flag_penetration_high_pct": 0.0,
            "flag_residual_high_pct": 3.0,
            "flag_torque_high_pct": 41.0,
        },
        {
            "kind": "target",
            "output": "target",
            "target": "fit bone-length std",
            "value": 7.7,
            "limit": 10.0,
            "ok": True,
        },
    ]
    md = render("footage", rows)
    head, fit, phys = _table(md)
    assert [fit[0], phys[0]] == ["fit", "physics"]  # session and target rows are not table rows
    assert fit[head.index("reproj. median / p95 px")] == "10.7 / 149"
    assert phys[head.index("residual force mean / max bw")] == "1.28 / –"
    assert fit[head.index("residual force mean / max bw")] == ""
    assert (
        "57 % of 100, tracking flags 56 % (identity confidence low 12 %, reprojection error high 57 %, penetration high 0 %, "
        "residual root force high 3 %, joint torque over human limit 41 %)"
    ) in md


def test_fit_and_triangulation_tables() -> None:
    fit = [
        {
            "cameras": 4,
            "method": "fit (anny)",
            "mpjpe_mm": 8.94,
            "accel_err_mm": 2.9327,
            "accel_vs_tri_pct": -30.27,
            "fps_per_person": 34.64,
        }
    ]
    head, row = _table(render("fit", fit))
    assert row[:4] == ["4", "fit (anny)", "8.9", "2.93"] and row[head.index("Δaccel. vs filtered %")] == "-30"
    tri = [
        {
            "scenario": "2 cams",
            "method": "plain DLT",
            "pcp_pct": 55.372,
            "mpjpe_mm": 56.24,
            "id_acc_pct": 100.0,
            "tri_fps": 7460.2,
        }
    ]
    head, row = _table(render("triangulation", tri))
    assert row == ["2 cams", "plain DLT", "55.37", "56.2", "100.00", "7460"] and "frames/s (all)" not in head


def test_render_refuses_unknown_benches_and_foreign_rows() -> None:
    with pytest.raises(ValueError, match="no table for bench 'nope'"):
        render("nope", [{}])
    with pytest.raises(ValueError, match="bench footage: none of the 1 rows"):
        render("footage", [{"method": "fit (anny)", "mpjpe_mm": 9.0}])
    with pytest.raises(ValueError, match="are these fit rows"):
        render("fit", [{"scenario": 1}])
    with pytest.raises(ValueError, match="list of row objects"):
        render("fit", ["cameras"])  # type: ignore[list-item]


README = """# title

intro text | with a pipe
<!-- bench:fit -->
old fit table
<!-- /bench:fit -->
between
<!-- bench:physics -->
<!-- /bench:physics -->
tail line
"""


def _json(path: Path, rows: object) -> Path:
    path.write_text(json.dumps(rows))
    return path


def test_update_readme_replaces_only_the_marked_text(tmp_path: Path) -> None:
    readme = tmp_path / "README.md"
    readme.write_text(README)
    fit = _json(tmp_path / "fit.json", [{"cameras": 2, "method": "fit (anny)", "mpjpe_mm": 23.04}])
    phys = _json(tmp_path / "phys.json", _physics_rows())
    text = update_readme(readme, {"fit": fit, "physics": phys})
    assert readme.read_text() == text
    assert "old fit table" not in text and "| 2 | fit (anny) | 23.0 |" in text
    before, rest = text.split("<!-- bench:fit -->\n")
    assert before == "# title\n\nintro text | with a pipe\n"
    assert rest.split("<!-- /bench:fit -->")[1].startswith("\nbetween\n<!-- bench:physics -->\n| method |")
    assert text.endswith("<!-- /bench:physics -->\ntail line\n")
    # rerunnable: the same rows give the same file
    assert update_readme(readme, {"fit": fit, "physics": phys}) == text
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "README.md",
        "fit.json",
        "phys.json",
    ]  # no temp file left


def test_missing_marker_names_the_readme_and_writes_nothing(tmp_path: Path) -> None:
    readme = tmp_path / "README.md"
    readme.write_text(README)
    fit = _json(tmp_path / "fit.json", [{"cameras": 2, "method": "fit (anny)", "mpjpe_mm": 23.04}])
    tri = _json(tmp_path / "tri.json", [{"scenario": "2 cams", "method": "cornerman", "pcp_pct": 97.9}])
    with pytest.raises(ValueError, match=r"README\.md: needs exactly one <!-- bench:triangulation -->"):
        update_readme(readme, {"fit": fit, "triangulation": tri})
    assert readme.read_text() == README  # the fit table made first was not written either
    readme.write_text(
        README.replace("<!-- /bench:fit -->\n", "") + "<!-- /bench:fit -->\n<!-- /bench:fit -->\n"
    )
    with pytest.raises(ValueError, match="found 1 and 2"):
        update_readme(readme, {"fit": fit})
    readme.write_text("<!-- /bench:fit -->\n<!-- bench:fit -->\n")
    with pytest.raises(ValueError, match="comes before"):
        update_readme(readme, {"fit": fit})


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ('[{"cameras": 4,', "malformed JSON"),
        ('{"cameras": 4}', "expected a JSON list of row objects"),
        ("[1, 2]", "expected a JSON list of row objects"),
        ('[{"kind": "session"}]', "none of the 1 rows"),
    ],
)
def test_bad_json_names_the_file(tmp_path: Path, content: str, message: str) -> None:
    readme = tmp_path / "README.md"
    readme.write_text(README)
    bad = tmp_path / "rows.json"
    bad.write_text(content)
    with pytest.raises(ValueError, match=message) as e:
        update_readme(readme, {"footage" if "session" in content else "fit": bad})
    assert str(e.value).startswith(str(bad))
    assert readme.read_text() == README


def test_the_table_says_what_it_was_measured_with(tmp_path: Path) -> None:
    """With ``rows.env.json`` beside the rows (as ``cornerman bench --json`` writes it) the
    table ends with the versions and CPUs; without it, it does not; a broken one is an
    error naming it, and nothing is written."""
    readme = tmp_path / "README.md"
    readme.write_text(README)
    fit = _json(tmp_path / "fit.json", [{"cameras": 2, "method": "fit (anny)", "mpjpe_mm": 23.04}])
    assert "Measured with" not in update_readme(readme, {"fit": fit})
    env = environment()
    env["packages"]["mujoco"] = "9.9.9"
    side = sidecar_path(fit)
    assert side.name == "fit.env.json"
    side.write_text(json.dumps(env))
    text = update_readme(readme, {"fit": fit})
    line = f"Measured with Python {env['python']}, "
    table = text.split("<!-- bench:fit -->\n")[1].split("<!-- /bench:fit -->")[0]
    assert line in table and "mujoco 9.9.9" in table and f"; {env['cpus']} CPUs." in table
    side.write_text('{"python": "3.11"}')
    with pytest.raises(ValueError, match="not a bench environment") as e:
        update_readme(readme, {"fit": fit})
    assert str(e.value).startswith(f"{side}: ")
    side.write_text("[1,")
    with pytest.raises(ValueError, match=r"fit\.env\.json: cannot read the bench environment") as e:
        update_readme(readme, {"fit": fit})
    assert str(e.value).startswith(f"{side}: ")
    assert readme.read_text() == text


def test_missing_json_names_the_file(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"nowhere\.json: cannot read the bench rows"):
        load_rows(tmp_path / "nowhere.json")


def test_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    readme = tmp_path / "README.md"
    readme.write_text(README)
    fit = _json(tmp_path / "fit.json", [{"cameras": 4, "method": "fit (anny)", "mpjpe_mm": 8.94}])
    assert main([str(readme), f"fit={fit}"]) == 0
    assert "| 4 | fit (anny) | 8.9 |" in readme.read_text()
    assert main([str(readme), f"fit={tmp_path / 'missing.json'}"]) == 2
    assert "missing.json: cannot read" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(readme), "fit"])  # not NAME=JSON
