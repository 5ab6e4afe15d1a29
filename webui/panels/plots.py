"""Per-athlete plots (uPlot): wrist speed, distance between the athletes, reprojection error,
and the physics residual root force when physics ran."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import viser
import viser.uplot as vup

from webui.analysis import PlotSeries, fill_gaps
from webui.colors import IdentityPalette


@dataclass
class PlotsHandles:
    wrist_speed: viser.GuiUplotHandle
    distance: viser.GuiUplotHandle
    reproj: viser.GuiUplotHandle
    residual: viser.GuiUplotHandle
    """Residual root force (BW): shown only when the physics stage ran."""
    note: viser.GuiMarkdownHandle


def _series(names: list[str], colors: list[str], unit: str) -> tuple[vup.Series, ...]:
    out: list[vup.Series] = [vup.Series(label="time (s)")]
    for n, c in zip(names, colors, strict=True):
        out.append(vup.Series(label=f"{n} ({unit})", stroke=c, width=2))
    return tuple(out)


RESIDUAL_TITLE = "Residual root force (BW)"


def _residual(s: PlotSeries) -> tuple[tuple[np.ndarray, ...], tuple[vup.Series, ...]]:
    """The residual curve and its flag threshold as a dashed line."""
    assert s.residual_frac_bw is not None
    cap = np.full(s.time_s.shape, s.residual_cap_frac_bw)
    series = (
        vup.Series(label="time (s)"),
        vup.Series(label="worst athlete (BW)", stroke="#c0392b", width=2),
        vup.Series(label="flag threshold (BW)", stroke="#888888", width=1, dash=(6.0, 4.0)),
    )
    return (s.time_s, fill_gaps(s.residual_frac_bw), cap), series


def _curves(s: PlotSeries | None, palette: IdentityPalette) -> dict[str, tuple[tuple[np.ndarray, ...], tuple[vup.Series, ...]]]:
    if s is None or s.frames.size < 2:
        t = np.array([0.0, 1.0])
        z = np.zeros(2)
        units = (("w", "m/s"), ("d", "m"), ("r", "px"), ("res", "BW"))
        return {k: ((t, z), _series(["no data"], ["#888888"], u)) for k, u in units}
    pids = [int(p) for p in s.person_ids]
    names = [palette.name(p) for p in pids]
    cols = [ident.color_hex if (ident := palette.get(p)) is not None else "#888888" for p in pids]
    w = tuple(fill_gaps(s.wrist_speed_mps[:, i]) for i in range(len(pids)))
    r = tuple(fill_gaps(s.reproj_err_px[:, i]) for i in range(len(pids)))
    return {
        "w": ((s.time_s, *w), _series(names, cols, "m/s")),
        "d": ((s.time_s, fill_gaps(s.distance_m)), _series(["distance"], ["#444444"], "m")),
        "r": ((s.time_s, *r), _series(names, cols, "px")),
        "res": _residual(s) if s.residual_frac_bw is not None else ((s.time_s, np.zeros_like(s.time_s)), _series(["no physics"], ["#888888"], "BW")),
    }


def has_residual(s: PlotSeries | None) -> bool:
    """Whether the residual plot has something to show (the physics stage ran)."""
    return s is not None and s.frames.size >= 2 and s.residual_frac_bw is not None


def make_plots(server: viser.ViserServer, s: PlotSeries | None, palette: IdentityPalette) -> PlotsHandles:
    c = _curves(s, palette)
    # x is seconds from the start of the bout, not a UNIX timestamp.
    sc = {"x": vup.Scale(time=False)}
    wrist = server.gui.add_uplot(c["w"][0], c["w"][1], title="Wrist speed", aspect=2.0, scales=sc)
    dist = server.gui.add_uplot(c["d"][0], c["d"][1], title="Distance between athletes", aspect=2.0, scales=sc)
    reproj = server.gui.add_uplot(c["r"][0], c["r"][1], title="Reprojection error (filtered)", aspect=2.0, scales=sc)
    residual = server.gui.add_uplot(
        c["res"][0], c["res"][1], title=RESIDUAL_TITLE, aspect=2.0, scales=sc, visible=has_residual(s)
    )
    note = server.gui.add_markdown("Gaps (frames without an estimate) are interpolated for display.")
    return PlotsHandles(wrist, dist, reproj, residual, note)


def update_plots(h: PlotsHandles, s: PlotSeries | None, palette: IdentityPalette) -> None:
    c = _curves(s, palette)
    for handle, key in ((h.wrist_speed, "w"), (h.distance, "d"), (h.reproj, "r"), (h.residual, "res")):
        handle.series = c[key][1]
        handle.data = c[key][0]
    h.residual.visible = has_residual(s)
