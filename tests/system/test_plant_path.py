"""A plant engineer's path: a 1-minute historian export to estimates (README "Bring your own
plant").

The shipped example (``replay/historian-example.csv``: 12 h of the demo day, one row per
minute, local time Europe/Stockholm, plant units, a few bad cells; ``replay/lims-example.csv``:
the lab results in % on a wet basis, local time) goes through ``import``, ``calibrate``,
``replay`` and ``diagnose``. The oracle is the same 12 h recorded at 10 s
(``replay/demo-day.mcap``): replayed with the same parameters, the 1-minute day's
``moisture_out`` must lie within the 10 s estimate's 95 % band at every window. The scan period
is measured from each day, so nothing here tells any verb that the export is 1-minute data.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from paths import REPO

from softsensor.cli import main as cli_main
from softsensor.recording.mcap_day import iter_messages
from softsensor.signals import TOPIC_ESTIMATE
from softsensor.windows.accumulator import measured_scan_period

REPLAY = REPO / "replay"
S = 10**9
#: The causes of docs/interface.md section 5: each extension's, and the two verdicts of the
#: model alone (``none``, or ``unexplained`` when its residuals are structured).
CONTRACT_CAUSES = {"none", "inlet_moisture", "sensor_bias", "lab_delay", "fouling_drift",
                   "input_lag", "ambient_heat_loss", "unexplained"}


def _estimates(path: Path) -> dict[int, dict]:
    return {t: b for _topic, t, b in iter_messages(path, topics=[TOPIC_ESTIMATE])}


@pytest.fixture(scope="module")
def imported(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("plant") / "historian-day.mcap"
    rc = cli_main(["import", "--map", str(REPLAY / "historian-map.toml"),
                   "--scans", str(REPLAY / "historian-example.csv"),
                   "--lab", str(REPLAY / "lims-example.csv"), "--out", str(out)])
    assert rc == 0
    return out


def test_one_minute_day_estimates_match_the_ten_second_day(imported, tmp_path, capsys):
    est1 = tmp_path / "est-1min.mcap"
    est10 = tmp_path / "est-10s.mcap"
    assert cli_main(["replay", str(imported), "--out", str(est1)]) == 0
    line = capsys.readouterr().err
    assert "scan period 60 s" in line and "73 ticks (1 stale)" in line, line
    assert cli_main(["replay", str(REPLAY / "demo-day.mcap"), "--end",
                     "2026-01-05T12:00:00Z", "--out", str(est10)]) == 0
    assert "scan period 10 s" in capsys.readouterr().err
    a, b = _estimates(est1), _estimates(est10)
    common = sorted(set(a) & set(b))
    assert len(common) == 73
    pairs = [(a[t], b[t]) for t in common
             if a[t]["moisture_out"] is not None and b[t]["moisture_out"] is not None]
    assert len(pairs) >= 72
    diff = np.array([x["moisture_out"] - y["moisture_out"] for x, y in pairs])
    band = np.array([1.96 * y["moisture_out_std"] for _x, y in pairs])
    assert np.all(np.abs(diff) <= band), (np.abs(diff) / band).max()
    # the wet-basis % lab results came in as dry-basis kg/kg: the four updates are applied
    assert sum(1 for x, _y in pairs if x["lab_updated"]) == 4


def test_calibrate_and_diagnose_run_on_the_one_minute_day(imported, tmp_path, capsys):
    params = tmp_path / "params.toml"
    rc = cli_main(["calibrate", str(imported), "--trials", "8", "--out", str(params),
                   "--no-identify", "--no-polish", "--quiet", "--force"])
    assert rc == 0 and params.is_file()
    capsys.readouterr()
    report = tmp_path / "diag.json"
    rc = cli_main(["diagnose", str(imported), "--params", str(params), "--json", str(report)])
    assert rc == 0
    doc = json.loads(report.read_text())
    # the report of CONTRACT section 5: the named cause heads a ranking of every cause, once
    # each (the model alone as "none" or "unexplained", not both), scores summing to one
    ranking = [r["cause"] for r in doc["ranking"]]
    assert doc["cause"] == ranking[0], ranking
    assert len(ranking) == len(set(ranking)) == len(CONTRACT_CAUSES) - 1, ranking
    assert set(ranking) | {"none", "unexplained"} == CONTRACT_CAUSES, ranking
    scores = [r["score"] for r in doc["ranking"]]
    assert sum(scores) == pytest.approx(1.0, abs=1e-12)  # round-off of a softmax
    assert scores == sorted(scores, reverse=True), scores
    assert doc["gain"] == pytest.approx(1.0 - doc["extended_cost"] / doc["baseline_cost"],
                                        abs=1e-12)
    assert (doc["channel"] is not None) == (doc["cause"] == "sensor_bias")
    # scored on 600 s windows of the 1-minute scans (12 h of them: 71 measured, where one
    # per scan would be 720) and on the four LIMS results the import wrote
    held = doc["held_out"]["samples"]
    assert 70 <= held["T_dryer_out"] == held["T_cyclone_out"] <= 72, held
    assert held["moisture_out"] == 4, held
    err = capsys.readouterr().err
    # a phase line as each of the minutes-long phases starts, then the verdict
    assert "diagnose: baseline" in err and "diagnose: extension 6 of 6" in err, err
    assert f"cause {doc['cause']}" in err.splitlines()[-1]


def test_a_day_with_no_estimate_from_data_exits_2(imported, tmp_path, capsys):
    """Forcing a 1 s scan period on 1-minute data leaves every window short of scans: the
    replay says so and exits 2, keeping what it recorded."""
    cfg = (REPLAY.parent / "config" / "dryer1.toml").read_text()
    cfg = cfg.replace("# scan_period = 10.0", "scan_period = 1.0")
    assert "scan_period = 1.0" in cfg
    path = tmp_path / "forced.toml"
    path.write_text(cfg)
    out = tmp_path / "est.mcap"
    # --quiet: no progress lines, whose number depends on how fast the machine replays (one
    # every 5 s of wall time; a loaded machine printed one here, issue 49)
    rc = cli_main(["replay", str(imported), "--out", str(out), "--config", str(path),
                   "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    # the summary line, then the one-line error saying why
    assert len(err) == 2 and err[1].startswith("softsensor: "), err
    assert "nothing estimated from data" in err[1] and "scan period 1 s" in err[1], err
    assert out.is_file()


def test_a_csv_given_as_a_day_names_the_import_verb(tmp_path, capsys):
    rc = cli_main(["replay", str(REPLAY / "historian-example.csv"), "--out",
                   str(tmp_path / "x.mcap")])
    err = capsys.readouterr().err
    assert rc == 2 and "softsensor import" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("step_s", [1, 10, 60, 300])
def test_measured_scan_period_ignores_gaps_and_jitter(step_s):
    rng = np.random.default_rng(step_s)
    t = np.arange(0, 6 * 3600, step_s) * S
    t = t + rng.integers(-step_s * S // 20, step_s * S // 20 + 1, size=t.size)
    t = np.delete(t, np.s_[100:400])  # an outage
    t = np.concatenate([t, t[:50]])   # duplicated rows
    assert measured_scan_period(t) == pytest.approx(step_s, rel=0.05)
    assert measured_scan_period([5]) is None
