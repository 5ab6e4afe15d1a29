"""Small SVG building blocks for the report's static charts: a plot frame with linear
scales, ticks and axis labels, and escaped text. Plain strings, no dependencies (the
report must stay one self-contained HTML file that prints without fetching anything).

SVG coordinates: pixels of the chart's viewBox, y down; data are mapped by ``Frame.x``/``Frame.y``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from html import escape

FONT = 'font-family="system-ui,sans-serif" font-size="11"'


def esc(s: object) -> str:
    return escape(str(s), quote=True)


def fmt(v: float) -> str:
    """A coordinate or a tick value, short (no trailing zeros)."""
    return f"{v:.2f}".rstrip("0").rstrip(".") if math.isfinite(v) else "0"


def nice_ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    """About ``n`` round tick values covering [lo, hi] (steps of 1, 2 or 5 x 10^k)."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo]
    raw = (hi - lo) / max(n, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    out = []
    k = 0
    while first + k * step <= hi + 1e-9 * step:
        out.append(round(first + k * step, 10))
        k += 1
    return out


def count_ticks(top: int) -> list[float]:
    """Whole-number ticks from 0 to at least ``top`` (a count axis); the last is the axis' top."""
    ticks = nice_ticks(0.0, float(max(top, 1)), 4)
    step = max(1.0, ticks[1] - ticks[0] if len(ticks) > 1 else 1.0)
    n = math.ceil(max(top, 1) / step - 1e-9)
    return [k * step for k in range(n + 1)]


@dataclass(frozen=True)
class Frame:
    """A plot area inside a ``width`` x ``height`` chart: data x in [x0, x1] and y in
    [y0, y1] map to the area left of the margins (``left``, ``right``, ``top``, ``bottom`` px)."""

    width: float
    height: float
    x0: float
    x1: float
    y0: float
    y1: float
    left: float = 52.0
    right: float = 14.0
    top: float = 14.0
    bottom: float = 40.0

    def x(self, v: float) -> float:
        span = (self.x1 - self.x0) or 1.0
        return self.left + (v - self.x0) / span * (self.width - self.left - self.right)

    def y(self, v: float) -> float:
        span = (self.y1 - self.y0) or 1.0
        return self.height - self.bottom - (v - self.y0) / span * (self.height - self.top - self.bottom)

    def axes(self, x_label: str, y_label: str, x_ticks: list[float] | None = None, y_ticks: list[float] | None = None,
             x_tick_text: dict[float, str] | None = None, grid: bool = True) -> str:  # fmt: skip
        """Axis lines, ticks with values and the axis labels (with units)."""
        xt = nice_ticks(self.x0, self.x1) if x_ticks is None else x_ticks
        yt = nice_ticks(self.y0, self.y1, 4) if y_ticks is None else y_ticks
        xb, yl = self.height - self.bottom, self.left
        out = [f'<g class="axes" {FONT} fill="#333">']
        for v in yt:
            py = fmt(self.y(v))
            if grid:
                out.append(
                    f'<line x1="{fmt(yl)}" x2="{fmt(self.width - self.right)}" y1="{py}" y2="{py}" stroke="#e4e4e4"/>'
                )
            out.append(
                f'<text x="{fmt(yl - 4)}" y="{py}" text-anchor="end" dominant-baseline="middle">{esc(fmt(v))}</text>'
            )
        for v in xt:
            px = fmt(self.x(v))
            label = (x_tick_text or {}).get(v, fmt(v))
            out.append(f'<line x1="{px}" x2="{px}" y1="{fmt(xb)}" y2="{fmt(xb + 4)}" stroke="#333"/>')
            out.append(f'<text x="{px}" y="{fmt(xb + 15)}" text-anchor="middle">{esc(label)}</text>')
        out.append(
            f'<line x1="{fmt(yl)}" x2="{fmt(self.width - self.right)}" y1="{fmt(xb)}" y2="{fmt(xb)}" stroke="#333"/>'
        )
        out.append(f'<line x1="{fmt(yl)}" x2="{fmt(yl)}" y1="{fmt(self.top)}" y2="{fmt(xb)}" stroke="#333"/>')
        mid_x = (self.left + self.width - self.right) / 2
        mid_y = (self.top + xb) / 2
        out.append(
            f'<text class="xlabel" x="{fmt(mid_x)}" y="{fmt(xb + 30)}" text-anchor="middle">{esc(x_label)}</text>'
        )
        out.append(f'<text class="ylabel" x="12" y="{fmt(mid_y)}" text-anchor="middle" '
                   f'transform="rotate(-90 12 {fmt(mid_y)})">{esc(y_label)}</text>')  # fmt: skip
        out.append("</g>")
        return "".join(out)


def svg(kind: str, width: float, height: float, body: str, title: str, athlete: int | None = None) -> str:
    """An inline ``<svg class="chart" data-chart=kind>`` with an accessible title; scales to its container."""
    who = f' data-athlete="{athlete}"' if athlete is not None else ""
    return (
        f'<svg class="chart" data-chart="{esc(kind)}"{who} viewBox="0 0 {fmt(width)} {fmt(height)}" '
        f'width="{fmt(width)}" height="{fmt(height)}" role="img"><title>{esc(title)}</title>{body}</svg>'
    )


def legend(items: list[tuple[str, str]], x: float, y: float, step: float = 78.0) -> str:
    """A row of (colour, label) swatches starting at (x, y)."""
    out = [f'<g class="legend" {FONT} fill="#333">']
    for k, (color, label) in enumerate(items):
        px = x + k * step
        out.append(f'<rect x="{fmt(px)}" y="{fmt(y - 8)}" width="10" height="10" fill="{esc(color)}"/>')
        out.append(f'<text x="{fmt(px + 14)}" y="{fmt(y)}">{esc(label)}</text>')
    out.append("</g>")
    return "".join(out)
