"""Trend charts of the live page as inline SVG, drawn the way a DCS faceplate or a Grafana
panel draws them: the time axis spans the chosen range (or the data), ticks fall on round
clock times and round values, limits are drawn as a band, every element carries an ``id`` or
``class`` a test (or a person with the browser's inspector) can find.

Pure string building: values in, SVG text out; the page (:mod:`.web`) chooses what to draw.
"""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from softsensor.presentation.display import DisplaySettings, local_times

NS = 10**9
W, H, PAD_L, PAD_R, PAD_T, PAD_B = 960, 260, 64, 20, 14, 34
#: Time-axis steps [min]: round for a clock (a tick every 5 min .. every day).
TIME_STEPS_MIN: tuple[int, ...] = (5, 10, 15, 30, 60, 120, 180, 360, 720, 1440)


def nice_ticks(lo: float, hi: float, most: int = 6) -> np.ndarray:
    """Round tick values covering ``lo..hi``: a step of 1, 2, 2.5 or 5 times a power of ten,
    at most ``most`` ticks; the first and last enclose the range."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return np.array([0.0, 1.0])
    if hi <= lo:
        lo, hi = lo - 0.5, hi + 0.5
    power = 10.0 ** math.floor(math.log10((hi - lo) / max(most - 1, 1)))
    for m in (1, 2, 2.5, 5, 10, 20, 25, 50):
        step = m * power
        first = math.floor(lo / step + 1e-9) * step
        n = int(math.ceil(hi / step - 1e-9) - math.floor(lo / step + 1e-9)) + 1
        if n <= most:
            break
    return np.round(first + step * np.arange(n), 10)


def time_ticks(t0: int, t1: int, zone_offset_s: int = 0, most: int = 8) -> np.ndarray:
    """Times [ns] between ``t0`` and ``t1`` at the roundest step of :data:`TIME_STEPS_MIN`
    giving at most ``most`` ticks, round on the local clock (``zone_offset_s`` east of UTC)."""
    span_min = max((t1 - t0) / NS / 60, 1.0)
    step_min = next((s for s in TIME_STEPS_MIN if span_min / s <= most), TIME_STEPS_MIN[-1])
    step = step_min * 60 * NS
    off = zone_offset_s * NS
    first = -(-(t0 + off) // step) * step - off
    return np.arange(first, t1 + 1, step, dtype=np.int64)


@dataclass
class Series:
    """One thing drawn: ``kind`` ``line``, ``points`` or ``band`` (``y`` low, ``y2`` high)."""

    name: str
    t: np.ndarray
    y: np.ndarray
    colour: str
    kind: str = "line"
    y2: np.ndarray | None = None
    dashed: bool = False
    width: float = 2.5


@dataclass
class Chart:
    """A chart: its series, limits drawn as a band (``limits``: low, high) and a target line,
    the time span and the unit of its values."""

    id: str
    unit: str
    t0: int
    t1: int
    series: list[Series] = field(default_factory=list)
    target: float | None = None
    limits: tuple[float, float] | None = None
    #: the physical floor of the values (0 % moisture): the axis' padding stops there
    floor: float | None = None


#: Colour of the acceptable band and of the target line.
LIMIT_BAND = "#e5f5e0"
TARGET = "#238b45"


def _x(t: np.ndarray, c: Chart) -> np.ndarray:
    return PAD_L + (np.asarray(t, float) - c.t0) / max(c.t1 - c.t0, 1) * (W - PAD_L - PAD_R)


def _y(v: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return (H - PAD_B) - (np.asarray(v, float) - lo) / (hi - lo) * (H - PAD_B - PAD_T)


def _path(x: np.ndarray, y: np.ndarray) -> str:
    """SVG path of a line, broken where a value is missing."""
    parts, pen = [], "M"
    for xi, yi in zip(x, y, strict=True):
        if not math.isfinite(yi):
            pen = "M"
            continue
        parts.append(f"{pen}{xi:.1f},{yi:.1f}")
        pen = "L"
    return " ".join(parts)


def _value_range(c: Chart) -> tuple[float, float]:
    pool: list[np.ndarray] = []
    for s in c.series:
        inside = (s.t >= c.t0) & (s.t <= c.t1)
        pool.append(s.y[inside])
        if s.y2 is not None:
            pool.append(s.y2[inside])
    if c.target is not None:
        pool.append(np.array([c.target]))
    if c.limits is not None:  # the limits in view: how far the value is from them
        pool.append(np.array(c.limits, dtype=float))
    values = np.concatenate(pool) if pool else np.zeros(0)
    values = values[np.isfinite(values)]
    if not values.size:
        return 0.0, 1.0
    lo, hi = float(values.min()), float(values.max())
    pad = max(0.05 * (hi - lo), 1e-6)
    low = lo - pad if c.floor is None or lo < c.floor else max(lo - pad, c.floor)
    return low, hi + pad


def _tick_label(t: int, display: DisplaySettings) -> str:
    local = local_times(np.array([t]), display)[0]
    return local.strftime("%a %d %b") if local.hour == 0 and local.minute == 0 \
        else local.strftime("%H:%M")


def svg(c: Chart, display: DisplaySettings) -> str:
    """The chart as one ``<svg>`` element."""
    ticks_y = nice_ticks(*_value_range(c))
    lo, hi = float(ticks_y[0]), float(ticks_y[-1])
    offset = local_times(np.array([c.t1]), display)[0].utcoffset()
    ticks_t = time_ticks(c.t0, c.t1, int(offset.total_seconds()) if offset else 0)
    out = [f'<svg id="{c.id}" xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" '
           f'data-t0="{c.t0}" data-t1="{c.t1}">',
           f'<rect x="{PAD_L}" y="{PAD_T}" width="{W - PAD_L - PAD_R}" '
           f'height="{H - PAD_B - PAD_T}" fill="white" stroke="#888"/>']
    if c.limits is not None:
        a, b = (float(v) for v in _y(np.array(c.limits), lo, hi))
        top, bottom = max(min(b, a), PAD_T), min(max(a, b), H - PAD_B)
        if bottom > top:
            out.append(f'<rect class="limits" x="{PAD_L + 1}" y="{top:.1f}" '
                       f'width="{W - PAD_L - PAD_R - 2}" height="{bottom - top:.1f}" '
                       f'fill="{LIMIT_BAND}" data-low="{c.limits[0]:.4g}" '
                       f'data-high="{c.limits[1]:.4g}"/>')
    for t in ticks_t:
        x = float(_x(np.array([t]), c)[0])
        out.append(f'<line x1="{x:.1f}" y1="{PAD_T}" x2="{x:.1f}" y2="{H - PAD_B}" '
                   f'stroke="#ddd"/><text class="tick-t" x="{x:.1f}" y="{H - 14}" '
                   f'font-size="11" text-anchor="middle" data-ns="{int(t)}">'
                   f'{html.escape(_tick_label(int(t), display))}</text>')
    for v in ticks_y:
        y = float(_y(np.array([v]), lo, hi)[0])
        out.append(f'<line x1="{PAD_L}" y1="{y:.1f}" x2="{W - PAD_R}" y2="{y:.1f}" '
                   f'stroke="#ddd"/><text class="tick-y" x="{PAD_L - 6}" y="{y + 4:.1f}" '
                   f'font-size="11" text-anchor="end">{v:g}</text>')
    out.append(f'<text x="{PAD_L + 6}" y="{PAD_T + 14}" font-size="11" fill="#555">'
               f'{html.escape(c.unit)}</text>')
    for s in c.series:
        inside = (s.t >= c.t0) & (s.t <= c.t1)
        x = _x(s.t[inside], c)
        y = _y(s.y[inside], lo, hi)
        if s.kind == "band" and s.y2 is not None:
            y2 = _y(s.y2[inside], lo, hi)
            ok = np.isfinite(y) & np.isfinite(y2)
            if ok.sum() >= 2:
                pts = [f"{a:.1f},{b:.1f}" for a, b in zip(x[ok], y2[ok], strict=True)]
                pts += [f"{a:.1f},{b:.1f}" for a, b in zip(x[ok][::-1], y[ok][::-1],
                                                           strict=True)]
                out.append(f'<polygon class="series band" data-name="{s.name}" '
                           f'points="{" ".join(pts)}" fill="{s.colour}"/>')
        elif s.kind == "points":
            out += [f'<rect class="series point" data-name="{s.name}" x="{a - 5:.1f}" '
                    f'y="{b - 5:.1f}" width="10" height="10" fill="{s.colour}"/>'
                    for a, b in zip(x, y, strict=True) if math.isfinite(b)]
        else:
            dash = ' stroke-dasharray="5 3"' if s.dashed else ""
            out.append(f'<path class="series line" data-name="{s.name}" d="{_path(x, y)}" '
                       f'fill="none" stroke="{s.colour}" stroke-width="{s.width:g}"{dash}/>')
    if c.target is not None:  # on top: the band must not hide it
        y = float(_y(np.array([c.target]), lo, hi)[0])
        out.append(f'<line class="target" x1="{PAD_L}" y1="{y:.1f}" x2="{W - PAD_R}" '
                   f'y2="{y:.1f}" stroke="{TARGET}" stroke-width="1.5" stroke-dasharray="8 4" '
                   f'data-value="{c.target:.4g}"/>')
    out.append("</svg>")
    return "".join(out)


def legend(items: Sequence[tuple[str, str]]) -> str:
    """A line of coloured swatches and names under a chart."""
    return "<p class='legend'>" + " ".join(
        f"<span style='display:inline-block;width:1.6em;height:.7em;background:{c};"
        f"margin:0 .3em 0 1em'></span>{html.escape(name)}" for name, c in items) + "</p>"


__all__ = ["Chart", "LIMIT_BAND", "Series", "TARGET", "TIME_STEPS_MIN", "legend",
           "nice_ticks", "svg", "time_ticks"]
