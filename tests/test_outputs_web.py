"""The live page (``[outputs.web]``, issue 13): its HTML and JSON fetched over HTTP, and the
page rendered by headless Chromium, whose screenshot must show the trend, the band and the lab
results (and not show them when there is no history)."""

from __future__ import annotations

import json
import shutil
import subprocess
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread

from softsensor.display import DisplaySettings
from softsensor.outputs.settings import WebSettings
from softsensor.outputs.web import BAND, LAB, LINE, LivePage

T0 = 1_767_571_200 * 10**9  # 2026-01-05T00:00Z
W_NS = 600 * 10**9


def _page(history: bool = True) -> LivePage:
    page = LivePage(WebSettings(enabled=True, port=0),
                    DisplaySettings(time_zone="Europe/Stockholm", moisture_basis="wet"))
    if history:
        for k in range(288):
            x = 0.10 + 0.01 * np.sin(k / 20)
            page.add_estimate(T0 + (k + 1) * W_NS, {
                "moisture_out": x, "moisture_out_std": 0.004, "moisture_in": 1.0,
                "moisture_in_std": 0.03, "status": "ok", "lab_updated": k % 20 == 0,
                "T_dryer_out_model": 348.15, "T_cyclone_out_model": 345.65})
        for k in range(0, 288, 20):
            page.add_lab(T0 + k * W_NS, 0.103 + 0.01 * np.sin(k / 20), f"L{k}")
    page.set_health({"status": "degraded", "detail": "innovation <b>high</b>"})
    page.set_diagnosis("The dryer outlet thermometer reads 2.9 °C high: check it & <i>it</i>.")
    return page


def _get(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=5) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read().decode()


def test_page_and_api_over_http():
    empty = _page(history=False)
    empty.start()
    try:
        assert _get(f"http://127.0.0.1:{empty.port}/healthz")[0] == 503
    finally:
        empty.stop()
    page = _page()
    page.start()
    try:
        base = f"http://127.0.0.1:{page.port}"
        code, text = _get(base + "/")
        assert code == 200
        # the last estimate in % on a wet basis: X = 0.10 + 0.01 sin(287/20)
        x = 0.10 + 0.01 * np.sin(287 / 20)
        assert f"{100 * x / (1 + x):.2f}" in text and "% wb" in text
        assert "50.00" in text  # inlet X = 1.0 is 50 % wet basis
        assert "dryer 75.0 °C, cyclone 72.5 °C" in text
        assert "2026-01-07T01:00:00+01:00" in text  # the last window end, Stockholm time
        assert "<b>high</b>" not in text and "&lt;b&gt;high&lt;/b&gt;" in text
        assert "&lt;i&gt;it&lt;/i&gt;" in text and "<script" not in text
        code, latest = _get(base + "/api/latest.json")
        doc = json.loads(latest)
        assert doc["estimate"]["moisture_out"] == pytest.approx(x)
        assert doc["estimate"]["window_end_ns"] == T0 + 288 * W_NS
        assert doc["health"]["status"] == "degraded"
        assert _get(base + "/healthz")[0] == 200 and _get(base + "/nope")[0] == 404
    finally:
        page.stop()


def _colour_pixels(png: np.ndarray, hex_colour: str, box: tuple[int, int, int, int]) -> int:
    rgb = np.array([int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)]) / 255.0
    y0, y1, x0, x1 = box
    region = png[y0:y1, x0:x1, :3]
    return int(np.sum(np.all(np.abs(region - rgb) < 0.02, axis=-1)))


def _screenshot(page: LivePage, path: Path) -> np.ndarray:
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        pytest.skip("headless Chromium is not installed (apt install chromium)")
    r = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu",
                        "--hide-scrollbars", "--window-size=1050,1000",
                        f"--screenshot={path}", f"http://127.0.0.1:{page.port}/"],
                       capture_output=True, text=True, timeout=90)
    assert path.is_file(), r.stderr[-2000:]
    return imread(path)


def test_chromium_shows_the_trend_band_and_labs(tmp_path):
    """The outlet chart lies in the page's first 600 px: with a history its line, band and
    lab squares are drawn there; without one, none of the three colours appears."""
    shots = {}
    for name, history in (("full", True), ("empty", False)):
        page = _page(history)
        page.start()
        try:
            shots[name] = _screenshot(page, tmp_path / f"{name}.png")
        finally:
            page.stop()
    box = (200, 600, 80, 1000)
    full = {c: _colour_pixels(shots["full"], c, box) for c in (LINE, BAND, LAB)}
    empty = {c: _colour_pixels(shots["empty"], c, box) for c in (LINE, BAND, LAB)}
    assert full[LINE] > 1500 and full[BAND] > 20_000 and full[LAB] > 14 * 60, full
    assert empty == {LINE: 0, BAND: 0, LAB: 0}, empty


def test_the_page_shows_the_verdict_of_the_diagnosis_report_file(tmp_path):
    report = tmp_path / "latest.json"
    page = LivePage(WebSettings(enabled=True, port=0, diagnosis=str(report)), DisplaySettings())
    assert "none yet" in page.page()
    report.write_text(json.dumps({
        "cause": "sensor_bias", "channel": "T_cyclone_out", "gain": 0.4, "day": "d.mcap",
        "ranking": [{"cause": "sensor_bias", "params": {"offset_K": -2.9}}]}))
    text = page.page()
    assert "cyclone outlet thermometer (T_cyclone_out) reads 2.9 °C low" in text
    assert "cause sensor_bias" in text
    report.write_text("<script>not json")
    text = page.page()
    assert "cannot be read (JSONDecodeError)" in text and "<script>" not in text
