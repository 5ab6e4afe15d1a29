"""Matplotlib figures as inline SVG for the report: one fixed style (text kept as ``<text>``,
fixed hash salt, no metadata, so the same data give the same bytes), and the SVG rewritten to
sit inside the HTML page: no XML prolog or namespace URLs, every id prefixed per chart (so
several charts on one page never share an id), and the tagged artists (``Marks``) given a
class, ``data-*`` attributes and a tooltip, so a test or a script can read a chart back.

Sizes: ``figure(width, height)`` takes pixels; the SVG's viewBox is in points (1/72 in) and
the page shows one viewBox unit per CSS pixel.
"""

from __future__ import annotations

import io
import re
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from html import escape
from typing import Literal

import matplotlib
from matplotlib.artist import Artist
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

STYLE: dict[str, object] = {
    "svg.fonttype": "none",  # text stays text: searchable, selectable, prints sharp
    "svg.hashsalt": "cornerman-report",  # deterministic clip-path and marker ids
    "font.family": "sans-serif",
    "font.size": 10.0,
    "axes.titlesize": 10.0,
    "axes.labelsize": 10.0,
    "xtick.labelsize": 9.0,
    "ytick.labelsize": 9.0,
    "legend.fontsize": 9.0,
    "legend.frameon": False,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.edgecolor": "#333333",
    "axes.labelcolor": "#333333",
    "xtick.color": "#333333",
    "ytick.color": "#333333",
    "text.color": "#333333",
    "figure.facecolor": "white",
}
"""The rcParams every report chart is drawn with."""

_LOCK = threading.Lock()  # rcParams are process-global: one chart at a time (the server renders in threads)


def esc(s: object) -> str:
    return escape(str(s), quote=True)


@dataclass
class Marks:
    """The tagged artists of one chart: id -> (CSS class, ``data-*`` attributes, tooltip)."""

    rows: dict[str, tuple[str, dict[str, str], str]] = field(default_factory=dict)

    def tag(self, artist: Artist, gid: str, cls: str = "mark", title: str = "", **data: object) -> None:
        """Give ``artist`` the SVG id ``gid`` (unique in the chart), ``class=cls``, ``data-<k>``
        attributes (``_`` in ``k`` becomes ``-``) and a hover tooltip."""
        if gid in self.rows:
            raise ValueError(f"Marks.tag: id {gid!r} used twice in one chart")
        artist.set_gid(gid)
        self.rows[gid] = (cls, {k.replace("_", "-"): str(v) for k, v in data.items()}, title)


@contextmanager
def figure(
    width_px: float, height_px: float, layout: Literal["constrained"] | None = "constrained"
) -> Iterator[Figure]:
    """A figure of ``width_px`` x ``height_px`` drawn in the report's style (Agg canvas, no
    pyplot state); call ``inline_svg`` inside the ``with`` block."""
    with _LOCK, matplotlib.rc_context(STYLE):  # type: ignore[arg-type]
        fig = Figure(figsize=(width_px / 72.0, height_px / 72.0), layout=layout)
        FigureCanvasAgg(fig)
        yield fig


_ROOT = re.compile(r"<svg\b[^>]*>")
_VIEWBOX = re.compile(r'viewBox="([^"]+)"')


def inline_svg(
    fig: Figure, kind: str, title: str, marks: Marks | None = None, athlete: int | None = None
) -> str:
    """``fig`` as an ``<svg class="chart" data-chart=kind [data-athlete]>`` element for an HTML page."""
    buf = io.StringIO()
    fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None, "Format": None, "Type": None})
    text = buf.getvalue()
    text = text[text.index("<svg") :]
    text = re.sub(r"\s*<metadata>.*?</metadata>", "", text, count=1, flags=re.S)
    root = _ROOT.match(text)
    box = _VIEWBOX.search(root.group(0)) if root else None
    if root is None or box is None:
        raise ValueError(f"inline_svg: matplotlib wrote no <svg viewBox> root for the {kind} chart")
    w, h = box.group(1).split()[2:]
    prefix = f"{kind}-{athlete}-" if athlete is not None else f"{kind}-"
    body = text[root.end() :]
    body = re.sub(r'\bid="', f'id="{prefix}', body)
    body = body.replace("url(#", f"url(#{prefix}").replace('xlink:href="#', f'href="#{prefix}')
    body = body.replace('xlink:href="', 'href="')  # SVG 2 href: no xlink namespace needed inline
    for gid, (cls, data, tip) in (marks.rows if marks else {}).items():
        old = f'<g id="{prefix}{gid}">'
        if body.count(old) != 1:
            raise ValueError(
                f"inline_svg: the {kind} chart drew {body.count(old)} artists with id {gid!r}, want 1"
            )
        attrs = "".join(f' data-{k}="{esc(v)}"' for k, v in data.items())
        tip_el = f"<title>{esc(tip)}</title>" if tip else ""
        body = body.replace(old, f'<g id="{prefix}{gid}" class="{esc(cls)}"{attrs}>{tip_el}')
    who = f' data-athlete="{athlete}"' if athlete is not None else ""
    return (
        f'<svg class="chart" data-chart="{esc(kind)}"{who} viewBox="0 0 {w} {h}" width="{w}" height="{h}" '
        f'role="img" aria-label="{esc(title)}"><title>{esc(title)}</title>{body.strip()}'
    )
