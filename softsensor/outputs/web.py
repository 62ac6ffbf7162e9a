"""A live page for the control room (``[outputs.web]``): the soft sensor as a DCS faceplate.

``GET /`` (and ``HEAD /``) is one self-contained HTML page (no script, no external resources:
plant networks are closed), drawn on the server as inline SVG and reloaded by the browser every
``refresh_s``:

* the health in plain words (:func:`softsensor.presentation.verdicts.health_words`), the technical
  detail beside it in small type;
* the outlet and inlet moisture now, with their 95 % band, the target and acceptable band of
  the ``[display]`` table, the last lab result taken (a result the estimator refused is not
  it, issue 49: a 0.30 kg/kg outlier refused at 32.5 sigma was shown as the last lab
  result), and the age of each value; the last lab result refused, marked so, and the last
  lab result or lab file refused, with why and when (the health's ``last_lab_refusal``);
* trends of the outlet moisture (95 % band, lab results at their sample times, refused ones
  drawn apart and named so in the legend, the target line
  and the acceptable band), the outlet temperatures measured beside the model's, and the inlet
  moisture; the time axis spans the data, or the range chosen with ``?range=2h|8h|48h`` (links
  on the page), with ticks on round clock times and round values (:mod:`.web_charts`);
* the last diagnosis when a report exists (the ``diagnosis`` key: a ``softsensor diagnose
  --json`` file, re-read when it changes).

What a person reads is in plant units (:mod:`softsensor.presentation.display`: % on the display
basis, °C, the plant's local clock). ``GET /api/latest.json`` gives the latest estimate and health
as the bus carries them (SI, docs/interface.md section 3), ``GET /healthz`` answers 200 while
estimates arrive and 503 when none came for three windows (a container's health check).

The server (:class:`~softsensor.outputs.deadline_http.DeadlineHTTPServer`) reads every
request's header on one loop thread with a deadline of ``timeout_s`` for the whole header, keeps
at most ``workers + backlog`` connections (a new one closes the oldest still sending its header)
and draws pages on ``workers`` threads; ``/healthz`` is answered on the loop thread, so it never
waits behind a slow client or a page being drawn. The history is fed from the
daemon (:meth:`LivePage.on_estimate`, :meth:`~LivePage.on_lab`, :meth:`~LivePage.on_health`)
and read by the server's threads under one lock; it is bounded by ``history_h``. Every string
that reaches the page is escaped.
"""

from __future__ import annotations

import html
import json
import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any
from urllib.parse import parse_qs, urlsplit

import numpy as np

from softsensor.errors import ConfigError
from softsensor.estimate import Estimate, Health
from softsensor.jsonable import dumps
from softsensor.messages import LabResult
from softsensor.outputs.deadline_http import DeadlineHTTPServer, Response
from softsensor.outputs.settings import WebSettings
from softsensor.outputs.web_charts import Chart, Series, legend, svg
from softsensor.presentation.display import (
    DisplaySettings,
    local_clock,
    moisture_band,
    moisture_pct,
    moisture_pct_points,
)
from softsensor.presentation.verdicts import diagnosis_verdict, health_words

log = logging.getLogger(__name__)

NS = 10**9
WINDOW_NS = 600 * NS
#: Colours of the page; the tests look for them in a screenshot.
LINE = "#1f77b4"
BAND = "#c6dbef"
LAB = "#2ca02c"
LAB_REFUSED = "#d62728"
#: Refused sample ids the page remembers (a few a day; a flood keeps the latest).
MAX_REFUSED_IDS = 1000
INLET = "#d62728"
MEASURED = "#ff7f0e"
MODEL = "#6a3d9a"
HEALTH_COLOURS = {"ok": "#2ca02c", "degraded": "#ff7f0e", "stale": "#d62728"}
#: The ranges an operator can choose (``?range=``), in hours; without one the axis fits the
#: data (at least :data:`MIN_SPAN_H`).
RANGES_H: dict[str, float] = {"2h": 2.0, "8h": 8.0, "48h": 48.0}
MIN_SPAN_H = 1.0


class LivePage:
    """The page's history and its HTTP server (module docstring), an
    :class:`~softsensor.outputs.operator_output.OperatorOutput`. ``clock``: the plant's clock
    [ns] (the daemon's, scaled in demos); ``time_scale``: plant seconds per wall second (an
    accelerated demo's estimates come that much faster)."""

    name = "web"

    def __init__(self, settings: WebSettings, display: DisplaySettings, unit: str = "dryer1",
                 clock: Callable[[], int] = time.time_ns, time_scale: float = 1.0) -> None:
        self.settings, self.display, self.unit = settings, display, unit
        self.clock = clock
        self._lock = threading.Lock()
        self._est: deque[tuple[int, dict[str, Any]]] = deque()
        self._labs: deque[tuple[int, float, str]] = deque()
        #: sample ids the estimator refused (:meth:`on_lab_refused`), the latest kept
        self._refused: deque[str] = deque(maxlen=MAX_REFUSED_IDS)
        self._health: dict[str, Any] = {"status": "stale", "detail": "no estimate yet"}
        self._diagnosis: str | None = None
        self._advice: dict[str, Any] | None = None  #: the set-point advisor's latest body
        self._last_arrival: float | None = None
        self._server: DeadlineHTTPServer | None = None
        self.port = settings.port
        self.time_scale = float(time_scale)
        self._report_cache: tuple[int, str] | None = None

    # -- feeding (estimator thread) --------------------------------------------------------
    def _trim(self, now_ns: int) -> None:
        keep = now_ns - int(self.settings.history_h * 3600 * NS)
        while self._est and self._est[0][0] < keep:
            self._est.popleft()
        while self._labs and self._labs[0][0] < keep:
            self._labs.popleft()

    def on_estimate(self, estimate: Estimate) -> None:
        with self._lock:
            self._est.append((estimate.time_ns, estimate.to_body()))
            self._last_arrival = time.monotonic()
            self._trim(estimate.time_ns)

    def on_lab(self, lab: LabResult) -> None:
        with self._lock:
            self._labs.append((int(lab.sample_time_ns), float(lab.moisture_out),
                               str(lab.sample_id)))
            self._labs = deque(sorted(self._labs))

    def on_lab_refused(self, sample_id: str) -> None:
        """The estimator refused the lab result ``sample_id`` (the daemon wires the
        service's ``on_lab_refused`` here): it is no longer the last result taken."""
        with self._lock:
            self._refused.append(str(sample_id))

    def on_health(self, health: Health) -> None:
        with self._lock:
            self._health = health.to_body()

    def on_advice(self, advice: Any) -> None:
        """The set-point advisor's latest (an :class:`~softsensor.advisor.advice.Advice`),
        shown under the charts and in /api/latest.json. Advisory only."""
        with self._lock:
            self._advice = advice.to_body()

    def set_diagnosis(self, text: str | None) -> None:
        with self._lock:
            self._diagnosis = text

    # -- reading (server threads) ----------------------------------------------------------
    def snapshot(self) -> tuple[list, list, dict, str | None]:
        """The estimates, the lab results ``(sample_time_ns, moisture_out, sample_id,
        refused)``, the health and the diagnosis line."""
        with self._lock:
            diag = self._diagnosis
            est, health, refused = list(self._est), dict(self._health), set(self._refused)
            labs = [(t, x, sid, sid in refused) for t, x, sid in self._labs]
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
                      "diagnosis": diag, "advice": self._advice})

    def healthy(self) -> bool:
        """Estimates arrive: the last came within three windows of wall time."""
        if self._last_arrival is None:
            return False
        return time.monotonic() - self._last_arrival < 3 * WINDOW_NS / NS / self.time_scale

    def page(self, range_key: str | None = None) -> str:
        est, labs, health, diag = self.snapshot()
        text = render_page(est, labs, health, diag, self.display, self.settings, self.unit,
                           now_ns=self.clock(), range_key=range_key)
        adv = self._advice
        if adv is None:
            return text
        line = ("advice: " if adv.get("advised") else "no advice: ") + str(adv.get("reason"))
        return text.replace("</body>", "<h2>Set-point advice (advisory only)</h2><p id='advice'>"
                            f"{html.escape(line)}</p></body>", 1)

    # -- serving ---------------------------------------------------------------------------
    def answer(self, target: str) -> Response:
        """The answer to a GET of ``target`` (path and query)."""
        url = urlsplit(target)
        if url.path == "/":
            choice = parse_qs(url.query).get("range", [None])[0]
            return Response(200, "text/html; charset=utf-8", self.page(choice))
        if url.path == "/api/latest.json":
            return Response(200, "application/json", self.latest_json())
        if url.path == "/healthz":  # on the server's loop thread: no lock, no wait
            ok = self.healthy()
            return Response(200 if ok else 503, "text/plain", "ok\n" if ok else "stale\n")
        return Response(404, "text/plain", "not found\n")

    async def start(self) -> str:
        """Serve the page; what it serves: its URL."""
        s = self.settings
        server = DeadlineHTTPServer(s.host, s.port, self.answer, inline=("/healthz",),
                                    workers=s.workers, max_connections=s.workers + s.backlog,
                                    header_timeout_s=s.timeout_s)
        try:
            server.start()
        except OSError as exc:
            raise ConfigError(f"outputs.web: cannot listen on {s.host}:{s.port}: "
                              f"{exc.strerror or exc}") from exc
        self._server = server
        self.port = server.port
        return f"http://{s.host}:{self.port}/"

    @property
    def refused(self) -> int:
        """Connections closed unanswered because every slot was taken (the oldest one still
        sending its header gave way)."""
        return 0 if self._server is None else self._server.refused

    @property
    def expired(self) -> int:
        """Connections closed because their header missed its deadline."""
        return 0 if self._server is None else self._server.expired

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.stop()


# -- the page ----------------------------------------------------------------------------------


def age(now_ns: int, t_ns: int) -> str:
    """How long ago ``t_ns`` was, as a person says it ("7 min ago", "2 h 05 min ago")."""
    s = max((now_ns - t_ns) / NS, 0.0)
    if s < 60:
        return "just now"
    m = int(s // 60)
    if m < 60:
        return f"{m} min ago"
    h, m = divmod(m, 60)
    return f"{h} h {m:02d} min ago" if h < 48 else f"{h // 24} d {h % 24} h ago"


def _num(v: Any) -> float:
    return math.nan if v is None else float(v)


def _series(est: list, key: str) -> np.ndarray:
    return np.array([_num(b.get(key)) for _t, b in est], dtype=float)


def span(est: list, now_ns: int, range_key: str | None, history_h: float) -> tuple[int, int]:
    """The time axis: the chosen range up to the last estimate, or the data's own span."""
    t1 = est[-1][0] if est else now_ns
    if range_key in RANGES_H:
        return t1 - int(RANGES_H[range_key] * 3600 * NS), t1
    t0 = est[0][0] if est else t1
    t0 = max(min(t0, t1 - int(MIN_SPAN_H * 3600 * NS)), t1 - int(history_h * 3600 * NS))
    return t0, t1


def _now_block(est: list, labs: list, display: DisplaySettings, now_ns: int) -> str:
    basis, unit = display.moisture_basis, html.escape(display.moisture_unit)
    target = (f"target {moisture_pct(display.moisture_target, basis):.1f} {unit}, acceptable "
              f"{moisture_pct(display.moisture_low, basis):.1f} to "
              f"{moisture_pct(display.moisture_high, basis):.1f} {unit}")
    if not est:
        return f"<p class='big' id='now'>No estimate yet.</p><p>Outlet moisture {target}.</p>"
    t, b = est[-1]

    def pct(key: str) -> str:
        v, sd = b.get(key), b.get(key + "_std")
        if v is None:
            return "n/a"
        if sd is None:
            return f"{float(moisture_pct(float(v), basis)):.2f} {unit}"
        half = moisture_pct_points(1.96 * float(sd), float(v), basis)
        # the +- says which band it is: an operator reads it as a tolerance otherwise
        return (f"{float(moisture_pct(float(v), basis)):.2f} &plusmn; {half:.2f} {unit} "
                f"<span class='age'>(95 % band)</span>")

    def deg(key: str) -> str:
        v = b.get(key)
        return "n/a" if v is None else f"{float(v) - 273.15:.1f} °C"

    when = html.escape(local_clock(t, display))

    def said(item: tuple) -> str:
        ts, x, sid = item[:3]
        return (f"{moisture_pct(x, basis):.2f} {unit} ({html.escape(sid)}), sampled "
                f"{html.escape(local_clock(ts, display))}, <span class='age'>"
                f"{age(now_ns, ts)}</span>")

    taken = [item for item in labs if not _refused(item)]
    lab = said(taken[-1]) if taken else "no lab result taken yet"
    refused = ""
    if labs and _refused(labs[-1]):  # the latest result was refused: said, and marked
        refused = (f"<p id='last-lab-refused' class='refusal'>Last lab result refused by the "
                   f"estimator (not used): {said(labs[-1])}</p>")
    return (f"<p class='big' id='now'>Outlet moisture <b id='moisture-out'>"
            f"{pct('moisture_out')}</b> &nbsp; Inlet moisture <b id='moisture-in'>"
            f"{pct('moisture_in')}</b></p>"
            + _source_line(b)
            + f"<p>Window ending {when} <span class='age' id='estimate-age'>({age(now_ns, t)})"
            f"</span>{' &middot; lab result applied' if b.get('lab_updated') else ''}. "
            f"Outlet moisture {target}.</p>"
            f"<p id='temperatures'>Outlet temperatures, measured / model: dryer "
            f"{deg('T_dryer_out_measured')} / {deg('T_dryer_out_model')}, cyclone "
            f"{deg('T_cyclone_out_measured')} / {deg('T_cyclone_out_model')}</p>"
            f"<p id='last-lab'>Last lab result: {lab}</p>" + refused)


def _refused(item: tuple) -> bool:
    """Whether a lab item of :meth:`LivePage.snapshot` was refused (a 3-tuple: not known)."""
    return len(item) > 3 and bool(item[3])


#: How an operator reads the blend's sources (softsensor.estimation.peer_blend).
SOURCE_WORDS: dict[str, str] = {"physics": "the model (physics)",
                                "hold": "the last lab result held",
                                "regression": "the lab regression"}


def _source_line(body: Mapping[str, Any]) -> str:
    """Where the published outlet moisture comes from: the leading source and each one's
    weight (the estimate body's ``source`` and ``sources``; /api/latest.json has them too)."""
    sources = body.get("sources")
    if not isinstance(sources, Mapping) or not sources:
        return ""
    parts = []
    for name, s in sorted(sources.items(), key=lambda kv: -float(kv[1].get("weight") or 0)):
        weight = float(s.get("weight") or 0)
        parts.append(f"{html.escape(SOURCE_WORDS.get(name, str(name)))} {100 * weight:.0f} %")
    lead = str(body.get("source", ""))
    return (f"<p id='moisture-source'>Outlet moisture from "
            f"<b>{html.escape(SOURCE_WORDS.get(lead, lead))}</b> "
            f"<span class='age'>(weights: {', '.join(parts)})</span></p>")


def _refusal_block(health: Mapping[str, Any], display: DisplaySettings, now_ns: int) -> str:
    """The last lab result or file refused, why and when: a LIMS setting that is wrong must
    show where the operator looks, not only in the log and ``rejected/``."""
    reason = health.get("last_lab_refusal")
    if not reason:
        return ""
    at = health.get("last_lab_refusal_ns")
    when = ("" if not isinstance(at, int) else
            f", {html.escape(local_clock(at, display))} <span class='age'>"
            f"{age(now_ns, at)}</span>")
    n = health.get("labs_refused")
    count = f" ({int(n)} refused so far)" if isinstance(n, int) else ""
    return (f"<p id='last-lab-refusal' class='refusal'>Last lab refusal{when}{count}: "
            f"{html.escape(str(reason))}</p>")


def _charts(est: list, labs: list, display: DisplaySettings, t0: int, t1: int) -> str:
    basis, unit = display.moisture_basis, display.moisture_unit
    t = np.array([x for x, _b in est], dtype=np.int64)
    mo, mo_sd = _series(est, "moisture_out"), _series(est, "moisture_out_std")
    mi, mi_sd = _series(est, "moisture_in"), _series(est, "moisture_in_std")
    taken = [x for x in labs if not _refused(x)]
    refused = [x for x in labs if _refused(x)]
    t_lab = np.array([x[0] for x in taken], dtype=np.int64)
    v_lab = np.array([x[1] for x in taken], dtype=float)
    t_ref = np.array([x[0] for x in refused], dtype=np.int64)
    v_ref = np.array([x[1] for x in refused], dtype=float)

    def pct(x: np.ndarray) -> np.ndarray:
        return np.asarray(moisture_pct(x, basis), dtype=float)

    outlet = Chart("outlet", unit, t0, t1, target=float(moisture_pct(display.moisture_target,
                                                                     basis)),
                   limits=(float(moisture_pct(display.moisture_low, basis)),
                           float(moisture_pct(display.moisture_high, basis))), floor=0.0)
    mo_low, mo_high = moisture_band(mo, mo_sd)  # clipped at bone dry, not below 0 %
    mi_low, mi_high = moisture_band(mi, mi_sd)
    outlet.series += [
        Series("band", t, pct(mo_low), BAND, "band", pct(mo_high)),
        Series("moisture_out", t, pct(mo), LINE),
        Series("lab", t_lab, pct(v_lab), LAB, "points"),
        Series("lab_refused", t_ref, pct(v_ref), LAB_REFUSED, "points")]
    temps = Chart("temperatures", "°C", t0, t1)
    for name, dashed in (("T_dryer_out", False), ("T_cyclone_out", True)):
        temps.series += [
            Series(f"{name}_measured", t, _series(est, f"{name}_measured") - 273.15, MEASURED,
                   dashed=dashed, width=2.0),
            Series(f"{name}_model", t, _series(est, f"{name}_model") - 273.15, MODEL,
                   dashed=dashed, width=2.0)]
    inlet = Chart("inlet", unit, t0, t1, floor=0.0)
    inlet.series += [
        Series("band", t, pct(mi_low), BAND, "band", pct(mi_high)),
        Series("moisture_in", t, pct(mi), INLET)]
    return ("<h2>Outlet moisture</h2>" + svg(outlet, display)
            + legend([("estimate", LINE), ("95 % band", BAND), ("lab result at its sample "
                                                                 "time", LAB),
                      *([("lab result refused (not used)", LAB_REFUSED)] if refused else []),
                      ("target", "#238b45"), ("acceptable", "#e5f5e0")])
            + "<h2>Outlet temperatures</h2>" + svg(temps, display)
            + legend([("measured", MEASURED), ("model", MODEL),
                      ("solid: dryer outlet, dashed: cyclone outlet", "#ffffff")])
            + "<h2>Inlet moisture (estimated)</h2>" + svg(inlet, display)
            + legend([("estimate", INLET), ("95 % band", BAND)]))


def render_page(est: list, labs: list, health: Mapping[str, Any], diagnosis: str | None,
                display: DisplaySettings, settings: WebSettings, unit: str, *,
                now_ns: int | None = None, range_key: str | None = None) -> str:
    """The whole page (module docstring)."""
    now_ns = time.time_ns() if now_ns is None else now_ns
    t0, t1 = span(est, now_ns, range_key, settings.history_h)
    status = str(health.get("status", "stale"))
    colour = HEALTH_COLOURS.get(status, "#888")
    chosen = range_key if range_key in RANGES_H else "fit"
    links = " ".join(
        f"<a class='range{' chosen' if key == chosen else ''}' href='?range={key}'>"
        f"{html.escape(label)}</a>"
        for key, label in (("2h", "2 h"), ("8h", "8 h"), ("48h", "48 h"), ("fit", "all")))
    diag = ("" if diagnosis is None else
            f"<h2>Last diagnosis</h2><p id='diagnosis'>{html.escape(diagnosis)}</p>")
    return (
        f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<meta http-equiv='refresh' content='{settings.refresh_s:g}'>"
        f"<title>softsensor {html.escape(unit)}</title><style>"
        "body{font-family:sans-serif;margin:1em 2em;color:#222} .big{font-size:1.4em}"
        ".health{display:inline-block;padding:.2em .6em;color:white;border-radius:4px}"
        ".detail,.age{color:#777;font-size:.85em} h2{font-size:1.1em;margin:.8em 0 .2em}"
        ".range{margin-right:.8em} .chosen{font-weight:bold;text-decoration:none;color:#222}"
        ".legend{font-size:.85em;margin:0 0 .5em} .refusal{color:#b35806}"
        "</style></head><body>"
        f"<h1>softsensor {html.escape(unit)}: fibre moisture</h1>"
        f"<p id='health'><span class='health' style='background:{colour}'>"
        f"{html.escape(status)}</span> <span id='health-words'>"
        f"{html.escape(health_words(health))}</span><br><span class='detail'>Detail: "
        f"{html.escape(str(health.get('detail', '')))}</span></p>"
        + _now_block(est, labs, display, now_ns)
        + _refusal_block(health, display, now_ns)
        + f"<p id='ranges'>Show: {links}</p>"
        + _charts(est, labs, display, t0, t1)
        + diag
        + f"<p class='detail'>Times: {html.escape(display.time_zone)}. Moisture: % on a "
        f"{html.escape(display.moisture_basis)} basis. Reloads every {settings.refresh_s:g} "
        "s. Data: <a href='/api/latest.json'>/api/latest.json</a></p></body></html>")


__all__ = ["LivePage", "RANGES_H", "age", "render_page", "span"]
