"""The live page (``[outputs.web]``, issues 13 and 24 item 5) read by real clients: urllib and
http.client over HTTP, and headless Chromium, whose DOM and screenshot must show a faceplate:
an axis fitted to the data (or the chosen range) with round ticks, the target and acceptable
band, measured beside model temperatures, the health in plain words, the age of each value and
the last diagnosis. And the server's threads stay bounded under a thousand slow clients (issue
25 item 8).

``SOFTSENSOR_WRITE_DOCS=1`` saves the screenshot as ``docs/web-page.png`` (the operator's screens
page's)."""

from __future__ import annotations

import asyncio
import http.client
import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from clients import chromium, chromium_dom
from matplotlib.image import imread
from paths import REPO

from softsensor.estimate import Estimate, Health
from softsensor.messages import LabResult
from softsensor.outputs.settings import WebSettings
from softsensor.outputs.web import BAND, LAB, LINE, MEASURED, MODEL, LivePage
from softsensor.outputs.web_charts import LIMIT_BAND, TARGET, TIME_STEPS_MIN
from softsensor.presentation.display import DisplaySettings

T0 = 1_767_571_200 * 10**9  # 2026-01-05T00:00Z
W_NS = 600 * 10**9
N_TICKS = 18  # three hours of estimates: the page squashed them into 6 % of 48 h
NOW = T0 + N_TICKS * W_NS + 7 * 60 * 10**9  # seven minutes after the last window
REPORT = {"cause": "sensor_bias", "channel": "T_cyclone_out", "gain": 0.4, "day": "d.mcap",
          "ranking": [{"cause": "sensor_bias", "params": {"offset_K": -2.9}}]}
DEGRADED = {"status": "degraded",
            "detail": "innovations inconsistent (NIS 75.6 > 51.2 over 12 ticks, 24 dof) <b>x</b>"}


#: The health of the docs' screenshot: what a control room sees (DEGRADED carries a markup
#: probe, ``<b>x</b>``, which the page must escape; issue 49: the screenshot showed it).
DOCS_HEALTH = {"status": "degraded",
               "detail": "innovations inconsistent (NIS 75.6 > 51.2 over 12 ticks, 24 dof)"}
#: Where the docs' screenshot's outlet moisture comes from (the estimate's ``sources``).
DOCS_SOURCES = {"source": "physics",
                "sources": {"physics": {"weight": 0.82}, "hold": {"weight": 0.12},
                            "regression": {"weight": 0.06}}}


def _page(tmp_path: Path, history: bool = True, diagnosis: bool = True, docs: bool = False,
          **web) -> LivePage:
    report = tmp_path / "latest.json"
    if diagnosis:
        report.write_text(json.dumps(REPORT))
    page = LivePage(WebSettings(enabled=True, port=0, diagnosis=str(report), **web),
                    DisplaySettings(time_zone="Europe/Madrid", moisture_basis="wet"),
                    clock=lambda: NOW)
    if history:
        for k in range(N_TICKS):
            x = 0.10 + 0.01 * np.sin(k / 3)
            page.on_estimate(Estimate.from_body({
                "window_end_ns": T0 + (k + 1) * W_NS, "moisture_out": x,
                "moisture_out_std": 0.004, "moisture_in": 1.0, "moisture_in_std": 0.03,
                "status": "ok", "lab_updated": k == 9,
                "T_dryer_out_model": 348.15, "T_cyclone_out_model": 345.65,
                "T_dryer_out_measured": 348.65 + 0.3 * np.sin(k),
                "T_cyclone_out_measured": 345.15, **(DOCS_SOURCES if docs else {})}))
        for k in (3, 9, 15):
            page.on_lab(LabResult(T0 + k * W_NS, 0.103 + 0.01 * np.sin(k / 3), f"L{k}"))
    page.on_health(Health.from_body(DOCS_HEALTH if docs else DEGRADED, NOW))
    return page


def _get(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=5) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read().decode()


def test_page_and_api_over_http(tmp_path):
    empty = _page(tmp_path, history=False, diagnosis=False)
    asyncio.run(empty.start())
    try:
        assert _get(f"http://127.0.0.1:{empty.port}/healthz")[0] == 503
        text = _get(f"http://127.0.0.1:{empty.port}/")[1]
        assert "No estimate yet" in text and "Last diagnosis" not in text  # no report: none
    finally:
        asyncio.run(empty.stop())
    page = _page(tmp_path)
    asyncio.run(page.start())
    try:
        base = f"http://127.0.0.1:{page.port}"
        code, text = _get(base + "/")
        assert code == 200
        x = 0.10 + 0.01 * np.sin((N_TICKS - 1) / 3)
        assert f"{100 * x / (1 + x):.2f}" in text and "% wb" in text
        assert "50.00" in text  # inlet X = 1.0 is 50 % wet basis
        assert "dryer 75.2 °C / 75.0 °C, cyclone 72.0 °C / 72.5 °C" in text, text
        assert "2026-01-05T04:00:00+01:00" in text  # the last window end, Madrid time
        assert "&lt;b&gt;x&lt;/b&gt;" in text and "<b>x</b>" not in text  # escaped detail
        assert "<script" not in text
        doc = json.loads(_get(base + "/api/latest.json")[1])
        assert doc["estimate"]["moisture_out"] == pytest.approx(x)
        assert doc["estimate"]["window_end_ns"] == T0 + N_TICKS * W_NS
        assert doc["health"]["status"] == "degraded"
        assert _get(base + "/healthz")[0] == 200 and _get(base + "/nope")[0] == 404
        # HEAD / answers as GET does, without the body (it answered 501)
        conn = http.client.HTTPConnection("127.0.0.1", page.port, timeout=5)
        conn.request("HEAD", "/")
        r = conn.getresponse()
        assert r.status == 200 and int(r.getheader("Content-Length")) > 1000
        assert r.read() == b""
        conn.close()
    finally:
        asyncio.run(page.stop())


def _attr(dom: str, element: str, name: str) -> str:
    m = re.search(rf"<svg[^>]*id=\"{element}\"[^>]*{name}=\"([^\"]+)\"", dom)
    assert m, (element, name)
    return m.group(1)


def _svg(dom: str, element: str) -> str:
    return re.search(rf"<svg[^>]*id=\"{element}\".*?</svg>", dom, re.S).group(0)


@pytest.mark.chromium
def test_chromium_dom_shows_a_faceplate(tmp_path):
    page = _page(tmp_path)
    asyncio.run(page.start())
    try:
        base = f"http://127.0.0.1:{page.port}/"
        dom = chromium_dom(base)
        dom8 = _get(base + "?range=8h")[1]  # no script on the page: the HTML is its DOM
    finally:
        asyncio.run(page.stop())
    # the axis fits the three hours of data (not 48 h); ?range=8h spans 8 h
    t0, t1 = int(_attr(dom, "outlet", "data-t0")), int(_attr(dom, "outlet", "data-t1"))
    assert (t0, t1) == (T0 + W_NS, T0 + N_TICKS * W_NS), (t0, t1)
    assert int(_attr(dom8, "outlet", "data-t1")) - int(_attr(dom8, "outlet", "data-t0")) \
        == 8 * 3600 * 10**9
    assert "class='range chosen' href='?range=8h'" in dom8
    links = re.findall(r"<a class=\"range[^\"]*\" href=\"\?range=(\w+)\"", dom)
    assert links == ["2h", "8h", "48h", "fit"], links
    outlet = _svg(dom, "outlet")
    # round ticks: values a step of 1, 2, 2.5 or 5 x 10^k apart, times on round local minutes
    values = np.array([float(v) for v in re.findall(r"class=\"tick-y\"[^>]*>([^<]+)<", outlet)])
    steps = np.diff(values)
    assert len(values) >= 3 and np.allclose(steps, steps[0])
    mantissa = steps[0] / 10 ** np.floor(np.log10(steps[0]))
    assert any(np.isclose(mantissa, m) for m in (1, 2, 2.5, 5)), values
    times = [int(v) for v in re.findall(r"class=\"tick-t\"[^>]*data-ns=\"(\d+)\"", outlet)]
    labels = re.findall(r"class=\"tick-t\"[^>]*>([^<]+)<", outlet)
    step_min = (times[1] - times[0]) // (60 * 10**9)
    assert step_min in TIME_STEPS_MIN and len(times) >= 3, times
    assert all(int(lb[-2:]) % min(step_min, 60) == 0 for lb in labels), labels
    # the target and the acceptable band of [display], in % wet basis
    assert re.search(r"class=\"target\"[^>]*data-value=\"9.091\"", outlet)
    assert re.search(r"class=\"limits\"[^>]*data-low=\"5.66\" data-high=\"13.79\"", outlet)
    # measured beside model temperatures
    temps = _svg(dom, "temperatures")
    for name in ("T_dryer_out_measured", "T_dryer_out_model", "T_cyclone_out_measured",
                 "T_cyclone_out_model"):
        assert re.search(rf"data-name=\"{name}\" d=\"M[\d.,]+ L", temps), name
    # health in plain words, the filter's statistics only as the detail
    words = re.search(r"id=\"health-words\">([^<]+)<", dom).group(1)
    assert words == ("Less certain than usual: the outlet temperatures disagree with the model "
                     "more than usual."), words
    assert "NIS" not in words
    # the +- is named as the 95 % band (issue 30 item 7), in the browser's DOM
    assert re.search(r"[\d.]+ &plusmn; [\d.]+ % wb <span class=\"age\">\(95 % band\)</span>",
                     dom) or re.search(r"[\d.]+ ± [\d.]+ % wb <span class=\"age\">\(95 % "
                                       r"band\)</span>", dom), dom[:2000]
    # the age of each value, and the last diagnosis
    assert re.search(r"id=\"estimate-age\">\(7 min ago\)", dom)
    assert re.search(r"id=\"last-lab\">Last lab result: [\d.]+ % wb \(L15\), sampled "
                     r"2026-01-05T03:30:00\+01:00, <span class=\"age\">37 min ago", dom)
    assert "cyclone outlet thermometer (T_cyclone_out) reads 2.9 °C low" in \
        re.search(r"id=\"diagnosis\">([^<]+)<", dom).group(1)


def _pixels(png: np.ndarray, colour: str) -> np.ndarray:
    rgb = np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)]) / 255.0
    return np.all(np.abs(png[..., :3] - rgb) < 0.02, axis=-1)


@pytest.mark.chromium
def test_chromium_screenshot_shows_the_fitted_trend_target_band_and_temperatures(tmp_path):
    page = _page(tmp_path)
    asyncio.run(page.start())
    try:
        shot = tmp_path / "page.png"
        r = chromium(f"http://127.0.0.1:{page.port}/", f"--screenshot={shot}")
        assert shot.is_file(), r.stderr[-2000:]
    finally:
        asyncio.run(page.stop())
    png = imread(shot)
    line = _pixels(png, LINE)
    cols = np.flatnonzero(line.any(axis=0))
    # the estimate spans the plot's width (the 3 h of data were squeezed into 60 px of 48 h)
    assert cols.max() - cols.min() > 800, (cols.min(), cols.max())
    counts = {name: int(_pixels(png, c).sum()) for name, c in
              (("band", BAND), ("lab", LAB), ("target", TARGET), ("limits", LIMIT_BAND),
               ("measured", MEASURED), ("model", MODEL))}
    assert counts["band"] > 20_000 and counts["limits"] > 50_000, counts
    assert counts["lab"] > 3 * 60 and counts["target"] > 400, counts
    assert counts["measured"] > 1500 and counts["model"] > 1500, counts
    if os.environ.get("SOFTSENSOR_WRITE_DOCS") == "1":
        # the docs' picture: the same page as a control room sees it (no markup probe in the
        # health, the moisture's sources shown)
        (tmp_path / "docs").mkdir()
        docs_page = _page(tmp_path / "docs", docs=True)
        asyncio.run(docs_page.start())
        try:
            docs_shot = tmp_path / "docs.png"
            r = chromium(f"http://127.0.0.1:{docs_page.port}/", f"--screenshot={docs_shot}")
            assert docs_shot.is_file(), r.stderr[-2000:]
            dom = chromium_dom(f"http://127.0.0.1:{docs_page.port}/")
        finally:
            asyncio.run(docs_page.stop())
        assert "&lt;b&gt;" not in dom and 'id="moisture-source"' in dom, dom[:2000]
        shutil.copyfile(docs_shot, REPO / "docs" / "web-page.png")


_SLOW_CLIENTS = """
import socket, sys, time
port, n = int(sys.argv[1]), int(sys.argv[2])
held = []
for _ in range(n):
    try:
        s = socket.create_connection(("127.0.0.1", port), timeout=0.5)
        s.sendall(b"GET / HTTP/1.1\\r\\nHost: x\\r\\n")  # and never the end of the headers
        held.append(s)
    except OSError:
        pass
print(len(held), flush=True)
time.sleep(float(sys.argv[3]))
"""


def test_a_thousand_slow_clients_hold_no_more_threads_than_workers(tmp_path):
    """Issue 25 item 8: a thread per client made 1,019 threads and 1,023 descriptors; with a
    limit of 1,024 the daemon's checkpoint and lab folder failed. Issue 31 item 3: with 1,000
    such sockets ``/healthz`` timed out 6 of 6 times; it now answers at once while they hold."""
    page = _page(tmp_path, workers=4, backlog=16, timeout_s=5.0)
    fds_before = len(os.listdir("/proc/self/fd"))
    threads_before = threading.active_count()
    asyncio.run(page.start())
    child = subprocess.Popen([sys.executable, "-c", _SLOW_CLIENTS, str(page.port), "1000",
                              "8"], stdout=subprocess.PIPE, text=True)
    try:
        child.stdout.readline()  # every connection attempted
        peak_threads, peak_fds = 0, 0
        for _ in range(20):
            peak_threads = max(peak_threads, threading.active_count())
            peak_fds = max(peak_fds, len(os.listdir("/proc/self/fd")))
            time.sleep(0.05)
        assert peak_threads - threads_before <= 4 + 1, peak_threads  # workers + the loop
        # 20 connections, the listener, the loop's epoll and wake-up pair, and one accepted
        # before the oldest slow one gives way
        assert peak_fds - fds_before <= 4 + 16 + 6, peak_fds
        assert page.refused > 500
        for _ in range(5):  # within the header deadline: the slow ones still hold their slots
            t0 = time.monotonic()
            assert _get(f"http://127.0.0.1:{page.port}/healthz")[0] == 200
            # held up, it would wait for the 5 s header deadline; the margin is for a loaded
            # machine (issue 49: no test depends on the load)
            assert time.monotonic() - t0 < 3.0
            time.sleep(0.2)
        assert child.poll() is None  # the slow clients were still connected
    finally:
        child.kill()
        child.wait(10)
        child.stdout.close()
        asyncio.run(page.stop())


_TRICKLERS = """
import socket, sys, threading, time
port, n, every, run = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
header = b"GET / HTTP/1.1\\r\\nHost: 127.0.0.1\\r\\nUser-Agent: " + b"x" * 200 + b"\\r\\n\\r\\n"
lives = []

def trickle():
    s = socket.create_connection(("127.0.0.1", port), timeout=every)
    t0 = time.monotonic()
    try:
        for byte in header:  # one byte, then a pause: every byte would restart an idle timeout
            s.sendall(bytes([byte]))
            try:
                if s.recv(1) == b"":
                    break  # closed by the server
            except socket.timeout:
                pass
            if time.monotonic() - t0 > run:
                break
    except OSError:
        pass
    lives.append(time.monotonic() - t0)
    s.close()

threads = [threading.Thread(target=trickle) for _ in range(n)]
for t in threads:
    t.start()
print("started", flush=True)
for t in threads:
    t.join()
print(" ".join(f"{x:.2f}" for x in lives), flush=True)
"""


def test_clients_trickling_their_header_byte_by_byte_cannot_silence_healthz(tmp_path):
    """Issue 31 item 3: eight sockets sending one header byte every 8 s held all eight
    workers, and ``/healthz`` timed out 5 of 5 times: each byte restarted the 10 s idle
    timeout. Now the whole header has a deadline (``timeout_s`` from the connection) and
    ``/healthz`` and the page answer while the tricklers hold their connections."""
    page = _page(tmp_path, timeout_s=3.0)  # the default 8 workers, as in the issue
    asyncio.run(page.start())
    child = subprocess.Popen([sys.executable, "-c", _TRICKLERS, str(page.port), "8", "1.0",
                              "12"], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "started"
        time.sleep(0.5)  # every trickler connected and sending
        waits = []
        for _ in range(5):
            t0 = time.monotonic()
            assert _get(f"http://127.0.0.1:{page.port}/healthz")[0] == 200
            waits.append(time.monotonic() - t0)
            t0 = time.monotonic()
            assert _get(f"http://127.0.0.1:{page.port}/")[0] == 200
            waits.append(time.monotonic() - t0)
            time.sleep(0.4)
        # held up, a request waits for a trickler's 3 s deadline; the margin is for a loaded
        # machine (issue 49)
        assert max(waits) < 2.0, waits
        lives = [float(x) for x in child.stdout.readline().split()]
        child.wait(20)
        expired = page.expired
    finally:
        child.kill()
        child.wait(10)
        child.stdout.close()
        asyncio.run(page.stop())
    # each was closed at its header's deadline although it sent a byte every second
    # (not before it; well before the trickle's 12 s end, with room for a loaded machine)
    assert len(lives) == 8 and all(2.5 < x < 8.0 for x in lives), lives
    assert expired == 8


def test_the_page_shows_the_verdict_of_the_diagnosis_report_file(tmp_path):
    report = tmp_path / "latest.json"
    page = LivePage(WebSettings(enabled=True, port=0, diagnosis=str(report)), DisplaySettings())
    assert "Last diagnosis" not in page.page()  # no report yet: nothing to show
    report.write_text(json.dumps(REPORT))
    text = page.page()
    assert "cyclone outlet thermometer (T_cyclone_out) reads 2.9 °C low" in text
    assert "cause sensor_bias" in text
    report.write_text("<script>not json")
    text = page.page()
    assert "cannot be read (JSONDecodeError)" in text and "<script>" not in text


def test_the_daemon_refuses_a_busy_web_port_in_one_line(tmp_path):
    """Issue 30 item 2: ``[outputs.web]`` on a port in use ended the daemon with exit 1 and
    ``unexpected AttributeError: 'BoundedHTTPServer' object has no attribute '_pool'``. The
    the commands page promises exit 2 and one line naming the port, as the other outputs do."""
    import socket

    with socket.create_server(("127.0.0.1", 0)) as taken, socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port, zenoh_port = taken.getsockname()[1], free.getsockname()[1]
        cfg = tmp_path / "plant.toml"
        cfg.write_text((REPO / "config" / "dryer1.toml").read_text()
                       + f"\n[outputs.web]\nenabled = true\nport = {port}\n")
        free.close()
        r = subprocess.run(
            [sys.executable, "-m", "softsensor.cli", "run", "--config", str(cfg),
             "--lab-dir", str(tmp_path / "lab"), "--checkpoint", str(tmp_path / "ck.json"),
             "--no-record", "--plc", "127.0.0.1:1", "--estimator", "openloop", "--listen",
             f"tcp/127.0.0.1:{zenoh_port}", "--log-format", "json"],
            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    last = r.stderr.strip().splitlines()[-1]
    assert re.fullmatch(rf"softsensor: outputs\.web: cannot listen on 127\.0\.0\.1:{port}: "
                        r"Address already in use.*", last), r.stderr[-2000:]
    assert "Traceback" not in r.stderr and "AttributeError" not in r.stderr


@pytest.mark.chromium
def test_the_pages_outlet_axis_stops_at_zero_for_a_wide_start_up_band(tmp_path):
    """Headless Chromium reads the page of a start-up (an outlet moisture of 0.03 kg/kg with
    a standard deviation as large): the band and the axis stop at 0 %, not below."""
    from softsensor.outputs.settings import WebSettings
    from softsensor.outputs.web import LivePage

    t0 = 1_767_571_200 * 10**9
    page = LivePage(WebSettings(enabled=True, port=0), DisplaySettings(moisture_basis="wet"),
                    clock=lambda: t0 + 13 * 600 * 10**9)
    for k in range(12):
        page.on_estimate(Estimate.from_body({
            "window_end_ns": t0 + (k + 1) * 600 * 10**9,
            "moisture_out": 0.03, "moisture_out_std": 0.03 - 0.002 * k, "moisture_in": 1.0,
            "moisture_in_std": 0.05, "status": "ok", "T_dryer_out_model": 348.0,
            "T_dryer_out_measured": 348.2, "T_cyclone_out_model": 345.0,
            "T_cyclone_out_measured": 345.1}))
    asyncio.run(page.start())
    try:
        dom = chromium_dom(f"http://127.0.0.1:{page.port}/")
    finally:
        asyncio.run(page.stop())
    outlet = re.search(r"<svg[^>]*id=\"outlet\".*?</svg>", dom, re.S).group(0)
    ticks = [float(v) for v in re.findall(r"class=\"tick-y\"[^>]*>([^<]+)<", outlet)]
    assert ticks and min(ticks) >= 0.0, ticks


def test_the_page_says_which_source_the_published_moisture_comes_from(tmp_path):
    """Issue 40: ``/api/latest.json`` said which source the published moisture came from (the
    physics, the held lab, the regression, with their weights); the page did not."""
    page = _page(tmp_path, history=False, diagnosis=False)
    page.on_estimate(Estimate.from_body({
        "window_end_ns": T0 + W_NS, "moisture_out": 0.101, "moisture_out_std": 0.004,
        "moisture_in": 1.0, "moisture_in_std": 0.03, "status": "ok", "lab_updated": False,
        "moisture_out_physics": 0.097, "moisture_out_physics_std": 0.006, "source": "hold",
        "band_scale": 1.0, "band_misses": [0, 0],
        "sources": {"physics": {"weight": 0.25, "moisture_out": 0.097,
                                "moisture_out_std": 0.006},
                    "hold": {"weight": 0.6, "moisture_out": 0.103, "moisture_out_std": 0.005},
                    "regression": {"weight": 0.15, "moisture_out": 0.1,
                                   "moisture_out_std": 0.007}}}))
    html_text = page.page()
    line = re.search(r"<p id='moisture-source'>(.*?)</p>", html_text).group(1)
    text = re.sub(r"<[^>]+>", "", line)
    assert text == ("Outlet moisture from the last lab result held (weights: the last lab "
                    "result held 60 %, the model (physics) 25 %, the lab regression 15 %)")
    latest = json.loads(page.latest_json())["estimate"]
    assert latest["source"] == "hold" and latest["sources"]["hold"]["weight"] == 0.6


def test_a_refused_lab_is_not_the_last_lab_result_and_is_drawn_apart(tmp_path):
    """Issue 49: a 0.30 kg/kg outlier the estimator refused at 32.5 sigma was shown as the
    "Last lab result" (23.08 % wb) and plotted like an accepted one. The last result an
    operator reads is the last one taken; a refused one is said to be refused and drawn in
    its own colour, named in the legend."""
    from softsensor.outputs.operator_output import lab_refused

    page = _page(tmp_path)
    page.on_lab(LabResult(T0 + 16 * W_NS, 0.30, "OUTLIER"))
    forgotten: list[str] = []
    # the daemon's wiring: the service's on_lab_refused frees the id and tells the outputs
    # (an output without on_lab_refused, as Modbus, is passed over)
    tell = lab_refused(forgotten.append, {"web": page, "modbus": object()})
    html_before = page.page()
    assert re.search(r"id='last-lab'>Last lab result: 23\.08 % wb \(OUTLIER\)", html_before)
    tell("OUTLIER")
    assert forgotten == ["OUTLIER"]
    html = page.page()
    # the last one taken (L15), not the refused one
    assert re.search(r"id='last-lab'>Last lab result: [\d.]+ % wb \(L15\), sampled ", html), \
        html[:3000]
    refused = re.search(r"id='last-lab-refused' class='refusal'>Last lab result refused by the "
                        r"estimator \(not used\): 23\.08 % wb \(OUTLIER\), sampled ", html)
    assert refused, html[:3000]
    points = dict.fromkeys(("lab", "lab_refused"), 0)
    for name in re.findall(r'class="series point" data-name="(lab|lab_refused)"', html):
        points[name] += 1
    assert points == {"lab": 3, "lab_refused": 1}, points
    assert "lab result refused (not used)" in html
    # no refused result: no refusal line, no legend entry
    (tmp_path / "plain").mkdir()
    plain = _page(tmp_path / "plain").page()
    assert "last-lab-refused" not in plain and "refused (not used)" not in plain
