"""``softsensor replay day1.mcap day2.mcap ... --out EST.mcap``: several days as one stream, as
the daemon lives them (issue 28 item 3): the estimator's state carries across the day
boundaries, a gap between days is a gap in the scans, days out of order are refused in one
line naming both files, and ``--checkpoint-in`` / ``--checkpoint-out`` start from and leave
the estimator's checkpoint in the daemon's format (:mod:`softsensor.service.checkpoint`).

One simulated 6 h record is cut into two files at 2 h 05 min (inside a window, so the
boundary window holds scans of both files): replaying the two files gives every estimate of
replaying the whole record, bit for bit; replaying the first with ``--checkpoint-out`` and
then the second with ``--checkpoint-in`` gives the second's estimates of one replay of both,
bit for bit, also with an hour missing between them.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from softsensor.cli import main as cli_main
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_plant_config
from softsensor.recording.day_writer import DayWriter
from softsensor.recording.mcap_day import iter_messages
from softsensor.signals import TOPIC_ESTIMATE

H = 3600 * 10**9
CUT = 2 * H + 5 * 60 * 10**9


def _copy(src: Path, dst: Path, lo: int | None, hi: int | None) -> Path:
    with DayWriter(dst) as w:
        for topic, t, body in iter_messages(src):
            if (lo is None or t >= lo) and (hi is None or t < hi):
                w.write(topic, t, body)
    return dst


@pytest.fixture(scope="module")
def days(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("days")
    whole = d / "whole.mcap"
    simulate_day(load_plant_config(), 6.0, 7, "inlet_moisture", 0.2).write(whole)
    t0 = next(iter_messages(whole))[1]
    return {"whole": whole, "a": _copy(whole, d / "a.mcap", None, t0 + CUT),
            "b": _copy(whole, d / "b.mcap", t0 + CUT, None),
            "b_late": _copy(whole, d / "b_late.mcap", t0 + CUT + H, None)}


def _estimates(path: Path) -> list[tuple[int, str]]:
    return [(t, json.dumps(b, sort_keys=True))
            for _, t, b in iter_messages(path, topics=[TOPIC_ESTIMATE])]


def _replay(capsys, *args) -> str:
    capsys.readouterr()
    rc = cli_main(["replay", *map(str, args), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 0, err
    return err.strip().splitlines()[-1]


def test_two_files_replay_as_the_whole_record(days, tmp_path, capsys):
    _replay(capsys, days["whole"], "--out", tmp_path / "w.mcap")
    whole = _estimates(tmp_path / "w.mcap")
    line = _replay(capsys, days["a"], days["b"], "--out", tmp_path / "ab.mcap")
    assert _estimates(tmp_path / "ab.mcap") == whole
    assert len(whole) >= 30
    assert f"per day: {days['a']}: " in line and f"; {days['b']}: " in line, line


@pytest.mark.parametrize("second", ["b", "b_late"])
def test_a_checkpoint_carries_the_state_to_the_next_day(days, second, tmp_path, capsys):
    _replay(capsys, days["a"], days[second], "--out", tmp_path / "ab.mcap")
    both = _estimates(tmp_path / "ab.mcap")
    ck = tmp_path / "ck.json"
    _replay(capsys, days["a"], "--out", tmp_path / "a.mcap", "--checkpoint-out", ck)
    doc = json.loads(ck.read_text())
    assert doc["format"] == "softsensor-checkpoint" and doc["sha256"]
    _replay(capsys, days[second], "--out", tmp_path / "b.mcap", "--checkpoint-in", ck)
    alone = _estimates(tmp_path / "b.mcap")
    ticked = doc["service"]["ticked_end_ns"]   # the last window day a ticked
    assert alone and alone == [e for e in both if e[0] > ticked]
    # without the checkpoint the second day starts afresh: other estimates
    _replay(capsys, days[second], "--out", tmp_path / "fresh.mcap")
    fresh = dict(_estimates(tmp_path / "fresh.mcap"))
    assert any(fresh.get(t) not in (None, b) for t, b in alone)


def test_days_out_of_order_and_a_bad_checkpoint_are_refused_in_one_line(days, tmp_path, capsys):
    capsys.readouterr()
    assert cli_main(["replay", str(days["b"]), str(days["a"]), "--out",
                     str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(days["a"]) in err[0] and str(days["b"]) in err[0], err
    assert "time order" in err[0]
    assert not (tmp_path / "x.mcap").exists()
    ck = tmp_path / "ck.json"
    _replay(capsys, days["a"], "--out", tmp_path / "a.mcap", "--checkpoint-out", ck)
    doc = json.loads(ck.read_text())
    doc["service"]["now_ns"] += 1   # an edited state fails the daemon's SHA-256 check
    ck.write_text(json.dumps(doc))
    capsys.readouterr()
    assert cli_main(["replay", str(days["b"]), "--out", str(tmp_path / "y.mcap"),
                     "--checkpoint-in", str(ck)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "checksum does not match" in err[0], err


def test_a_checkpoint_from_after_the_day_is_refused_in_one_line(days, tmp_path, capsys):
    """Issue 40: ``replay DAY --checkpoint-in CK`` with CK saved 34 h after DAY took 720 scans
    in, gave 1 tick out and exit 0 without a word; now exit 2 and one line, as the daemon
    sets such a checkpoint aside."""
    ck = tmp_path / "ck.json"
    _replay(capsys, days["a"], "--out", tmp_path / "a.mcap", "--checkpoint-out", ck)
    capsys.readouterr()
    assert cli_main(["replay", str(days["a"]), "--out", str(tmp_path / "again.mcap"),
                     "--checkpoint-in", str(ck)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"softsensor: --checkpoint-in {ck}: checkpoint "
                                               f"from after the day: "), err
    assert "2.1 h after the first scan of a.mcap" in err[0], err
    assert not (tmp_path / "again.mcap").exists()
