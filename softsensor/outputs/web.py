"""A live page for the control room (``[outputs.web]``): the last 48 h on one screen.

``GET /`` is one self-contained HTML page (no script, no external resources: plant networks
are closed), drawn on the server as inline SVG and reloaded by the browser every
``refresh_s``: the outlet moisture with its 95 % band and the lab results at their sample
times, the inlet moisture with its band, the health with its detail, and the last diagnosis
(the plain-language verdict of the ``diagnosis`` report file, re-read when it changes).
What a person reads is in plant units (:mod:`softsensor.display`: % on the
display basis, the plant's local clock). ``GET /api/latest.json`` gives the latest estimate
and health as the bus carries them (SI, docs/interface.md section 3), ``GET /healthz`` answers
200 while estimates arrive and 503 when none came for three windows (a container's health
check).

The history is fed from the daemon's estimator thread (:meth:`LivePage.add_estimate`,
:meth:`add_lab`, :meth:`set_health`) and read by the server's threads under one lock; it is
bounded by ``history_h``. Every string that reaches the page is escaped.
"""

from __future__ import annotations

import html
import json
import math
import os
import threading
import time
from collections import deque
from collections.abc import Mapping
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import numpy as np

from softsensor.display import (
    DisplaySettings,
    local_clock,
    local_times,
    moisture_pct,
    moisture_pct_points,
)
from softsensor.errors import ConfigError
from softsensor.jsonable import dumps
from softsensor.outputs.settings import WebSettings
from softsensor.verdicts import diagnosis_verdict

NS = 10**9
WINDOW_NS = 600 * NS
#: Colours of the page; the tests look for the line colours in a screenshot.
LINE = "#1f77b4"
BAND = "#c6dbef"
LAB = "#2ca02c"
INLET = "#d62728"
HEALTH_COLOURS = {"ok": "#2ca02c", "degraded": "#ff7f0e", "stale": "#d62728"}


class LivePage:
    """The page's history and its HTTP server (module docstring)."""

    def __init__(self, settings: WebSettings, display: DisplaySettings, unit: str = "dryer1"
                 ) -> None:
        self.settings, self.display, self.unit = settings, display, unit
        self._lock = threading.Lock()
        self._est: deque[tuple[int, dict[str, Any]]] = deque()
        self._labs: deque[tuple[int, float, str]] = deque()
        self._health: dict[str, Any] = {"status": "stale", "detail": "no estimate yet"}
        self._diagnosis: str | None = None
        self._last_arrival: float | None = None
        self._server: ThreadingHTTPServer | None = None
        self.port = settings.port
        self.time_scale = 1.0  #: plant seconds per wall second (accelerated demos)
        self._report_cache: tuple[int, str] | None = None

    # -- feeding (estimator thread) --------------------------------------------------------
    def _trim(self, now_ns: int) -> None:
        keep = now_ns - int(self.settings.history_h * 3600 * NS)
        while self._est and self._est[0][0] < keep:
            self._est.popleft()
        while self._labs and self._labs[0][0] < keep:
            self._labs.popleft()

    def add_estimate(self, time_ns: int, body: Mapping[str, Any]) -> None:
        with self._lock:
            self._est.append((int(time_ns), dict(body)))
            self._last_arrival = time.monotonic()
            self._trim(int(time_ns))

    def add_lab(self, sample_time_ns: int, moisture_out: float, sample_id: str) -> None:
        with self._lock:
            self._labs.append((int(sample_time_ns), float(moisture_out), str(sample_id)))
            self._labs = deque(sorted(self._labs))

    def set_health(self, body: Mapping[str, Any]) -> None:
        with self._lock:
            self._health = dict(body)

    def set_diagnosis(self, text: str | None) -> None:
        with self._lock:
            self._diagnosis = text

    # -- reading (server threads) ----------------------------------------------------------
    def snapshot(self) -> tuple[list, list, dict, str | None]:
        with self._lock:
            diag = self._diagnosis
            est, labs, health = list(self._est), list(self._labs), dict(self._health)
        return est, labs, health, diag if diag is not None else self._report()

    def _report(self) -> str | None:
        """The verdict of the diagnosis report file (``diagnosis``), read when it changed."""
        path = self.settings.diagnosis
        if path is None:
            return None
        try:
            st = os.stat(path)
            if self._report_cache is None or self._report_cache[0] != st.st_mtime_ns:
                with open(path, "rb") as f:
                    doc = json.loads(f.read(1_000_000))
                when = local_clock(st.st_mtime_ns, self.display)
                text = (f"{diagnosis_verdict(doc)} (cause {doc.get('cause')}, "
                        f"{doc.get('day', 'day')}, report of {when})")
                self._report_cache = (st.st_mtime_ns, text)
            return self._report_cache[1]
        except FileNotFoundError:
            return None
        except (OSError, ValueError, AttributeError) as exc:  # never the file's content
            return f"the diagnosis report {path} cannot be read ({type(exc).__name__})"

    def latest_json(self) -> str:
        est, _labs, health, diag = self.snapshot()
        last = None if not est else {"window_end_ns": est[-1][0], **est[-1][1]}
        return dumps({"unit": self.unit, "estimate": last, "health": health,
                      "diagnosis": diag})

    def healthy(self) -> bool:
        """Estimates arrive: the last came within three windows of wall time."""
        if self._last_arrival is None:
            return False
        return time.monotonic() - self._last_arrival < 3 * WINDOW_NS / NS / self.time_scale

    def page(self) -> str:
        est, labs, health, diag = self.snapshot()
        return render_page(est, labs, health, diag, self.display, self.settings, self.unit)

    # -- serving ---------------------------------------------------------------------------
    def start(self) -> None:
        s, page = self.settings, self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 - the stdlib's name
                path = self.path.split("?")[0]
                if path == "/":
                    self._send(200, "text/html; charset=utf-8", page.page())
                elif path == "/api/latest.json":
                    self._send(200, "application/json", page.latest_json())
                elif path == "/healthz":
                    ok = page.healthy()
                    self._send(200 if ok else 503, "text/plain", "ok\n" if ok else "stale\n")
                else:
                    self._send(404, "text/plain", "not found\n")

            def _send(self, code: int, kind: str, text: str) -> None:
                data = text.encode("utf-8")
                self.send_response(code)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(data)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, *_args: Any) -> None:  # the daemon logs, not the stdlib
                pass

        try:
            self._server = ThreadingHTTPServer((s.host, s.port), Handler)
        except OSError as exc:
            raise ConfigError(f"outputs.web: cannot listen on {s.host}:{s.port}: "
                              f"{exc.strerror or exc}") from exc
        self._server.daemon_threads = True
        self.port = self._server.server_address[1]
        threading.Thread(target=self._server.serve_forever, name="web-page",
                         daemon=True).start()

    def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.shutdown()
            server.server_close()


# -- drawing -----------------------------------------------------------------------------------
W, H, PAD_L, PAD_R, PAD_T, PAD_B = 960, 300, 60, 20, 16, 34


def _scale(values: np.ndarray, lo: float, hi: float, a: float, b: float) -> np.ndarray:
    return a + (values - lo) / (hi - lo) * (b - a) if hi > lo else np.full_like(values, a)


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


def _axes(t0: int, t1: int, lo: float, hi: float, unit: str, display: DisplaySettings) -> str:
    """Frame, grid and tick labels (local clock every 6 h, moisture every step)."""
    out = [f'<rect x="{PAD_L}" y="{PAD_T}" width="{W - PAD_L - PAD_R}" '
           f'height="{H - PAD_T - PAD_B}" fill="white" stroke="#888"/>']
    step = 6 * 3600 * NS
    for t in range(-(-t0 // step) * step, t1 + 1, step):
        x = float(_scale(np.array([t]), t0, t1, PAD_L, W - PAD_R)[0])
        label = local_times(np.array([t]), display)[0].strftime("%a %H:%M")
        out.append(f'<line x1="{x:.1f}" y1="{PAD_T}" x2="{x:.1f}" y2="{H - PAD_B}" '
                   f'stroke="#eee"/><text x="{x:.1f}" y="{H - 14}" font-size="11" '
                   f'text-anchor="middle">{html.escape(label)}</text>')
    for v in np.linspace(lo, hi, 5):
        y = float(_scale(np.array([v]), lo, hi, H - PAD_B, PAD_T)[0])
        out.append(f'<line x1="{PAD_L}" y1="{y:.1f}" x2="{W - PAD_R}" y2="{y:.1f}" '
                   f'stroke="#eee"/><text x="{PAD_L - 6}" y="{y + 4:.1f}" font-size="11" '
                   f'text-anchor="end">{v:.1f}</text>')
    out.append(f'<text x="{PAD_L + 6}" y="{PAD_T + 14}" font-size="11" fill="#555">'
               f'{html.escape(unit)}</text>')
    return "".join(out)


def chart(t: np.ndarray, v: np.ndarray, sd: np.ndarray, t_lab: np.ndarray, v_lab: np.ndarray,
          t0: int, t1: int, colour: str, display: DisplaySettings) -> str:
    """One SVG chart: a value [kg/kg dry] with its 95 % band, optional lab points; in %."""
    basis = display.moisture_basis
    mid = moisture_pct(v, basis)
    lo_b, hi_b = moisture_pct(v - 1.96 * sd, basis), moisture_pct(v + 1.96 * sd, basis)
    labs = moisture_pct(v_lab, basis)
    pool = np.concatenate([lo_b[np.isfinite(lo_b)], hi_b[np.isfinite(hi_b)],
                           labs[np.isfinite(labs)]])
    lo, hi = (float(pool.min()), float(pool.max())) if pool.size else (0.0, 1.0)
    pad = max(0.1 * (hi - lo), 0.2)
    lo, hi = lo - pad, hi + pad
    x = _scale(t.astype(float), t0, t1, PAD_L, W - PAD_R)
    svg = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}">',
           _axes(t0, t1, lo, hi, display.moisture_unit, display)]
    ok = np.isfinite(lo_b) & np.isfinite(hi_b)
    if ok.sum() >= 2:
        top = [f"{a:.1f},{b:.1f}" for a, b in zip(x[ok], _scale(hi_b[ok], lo, hi, H - PAD_B,
                                                                PAD_T), strict=True)]
        bot = [f"{a:.1f},{b:.1f}" for a, b in zip(x[ok], _scale(lo_b[ok], lo, hi, H - PAD_B,
                                                                PAD_T), strict=True)]
        svg.append(f'<polygon points="{" ".join(top + bot[::-1])}" fill="{BAND}"/>')
    svg.append(f'<path d="{_path(x, _scale(mid, lo, hi, H - PAD_B, PAD_T))}" fill="none" '
               f'stroke="{colour}" stroke-width="2.5"/>')
    xl = _scale(t_lab.astype(float), t0, t1, PAD_L, W - PAD_R)
    yl = _scale(labs, lo, hi, H - PAD_B, PAD_T)
    for a, b in zip(xl, yl, strict=True):
        if math.isfinite(b) and PAD_L <= a <= W - PAD_R:
            svg.append(f'<rect x="{a - 5:.1f}" y="{b - 5:.1f}" width="10" height="10" '
                       f'fill="{LAB}"/>')
    svg.append("</svg>")
    return "".join(svg)


def _series(est: list, key: str) -> tuple[np.ndarray, np.ndarray]:
    def num(v: Any) -> float:
        return math.nan if v is None else float(v)

    return (np.array([num(b.get(key)) for _t, b in est], dtype=float),
            np.array([num(b.get(key + "_std")) for _t, b in est], dtype=float))


def _now_line(est: list, health: Mapping[str, Any], display: DisplaySettings) -> str:
    if not est:
        return "<p class='big'>No estimate yet.</p>"
    t, b = est[-1]
    basis, unit = display.moisture_basis, display.moisture_unit

    def pct(key: str) -> str:
        v, sd = b.get(key), b.get(key + "_std")
        if v is None:
            return "n/a"
        band = ("" if sd is None else
                f" &plusmn; {moisture_pct_points(1.96 * float(sd), float(v), basis):.2f}")
        return f"{float(moisture_pct(float(v), basis)):.2f}{band} {html.escape(unit)}"

    def deg(key: str) -> str:
        v = b.get(key)
        return "n/a" if v is None else f"{float(v) - 273.15:.1f} °C"

    return (f"<p class='big'>Outlet moisture <b>{pct('moisture_out')}</b> &nbsp; "
            f"Inlet moisture <b>{pct('moisture_in')}</b></p>"
            f"<p>Model outlet temperatures: dryer {deg('T_dryer_out_model')}, cyclone "
            f"{deg('T_cyclone_out_model')}</p>"
            f"<p>Window ending {html.escape(local_clock(t, display))}"
            f"{' &middot; lab result applied' if b.get('lab_updated') else ''}</p>")


def render_page(est: list, labs: list, health: Mapping[str, Any], diagnosis: str | None,
                display: DisplaySettings, settings: WebSettings, unit: str) -> str:
    """The whole page (module docstring)."""
    t1 = est[-1][0] if est else time.time_ns()
    t0 = t1 - int(settings.history_h * 3600 * NS)
    t = np.array([x for x, _b in est], dtype=np.int64)
    mo, mo_sd = _series(est, "moisture_out")
    mi, mi_sd = _series(est, "moisture_in")
    t_lab = np.array([x[0] for x in labs], dtype=np.int64)
    v_lab = np.array([x[1] for x in labs], dtype=float)
    status = str(health.get("status", "stale"))
    colour = HEALTH_COLOURS.get(status, "#888")
    return (
        f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<meta http-equiv='refresh' content='{settings.refresh_s:g}'>"
        f"<title>softsensor {html.escape(unit)}</title><style>"
        "body{font-family:sans-serif;margin:1em 2em;color:#222} .big{font-size:1.4em}"
        ".health{display:inline-block;padding:.2em .6em;color:white;border-radius:4px}"
        "</style></head><body>"
        f"<h1>softsensor {html.escape(unit)}: fibre moisture</h1>"
        f"<p><span class='health' style='background:{colour}'>{html.escape(status)}</span> "
        f"{html.escape(str(health.get('detail', '')))}</p>"
        + _now_line(est, health, display)
        + f"<h2>Outlet moisture, last {settings.history_h:g} h (band: 95 %; squares: lab "
        f"results at their sample times)</h2>"
        + chart(t, mo, mo_sd, t_lab, v_lab, t0, t1, LINE, display)
        + f"<h2>Inlet moisture, last {settings.history_h:g} h</h2>"
        + chart(t, mi, mi_sd, np.zeros(0, np.int64), np.zeros(0), t0, t1, INLET, display)
        + "<h2>Last diagnosis</h2><p>"
        + (html.escape(diagnosis) if diagnosis else "none yet")
        + f"</p><p style='color:#888'>Times: {html.escape(display.time_zone)}. Moisture: % "
        f"on a {html.escape(display.moisture_basis)} basis. Reloads every "
        f"{settings.refresh_s:g} s. Data: <a href='/api/latest.json'>/api/latest.json</a>"
        f"</p></body></html>")


__all__ = ["LivePage", "chart", "render_page"]
