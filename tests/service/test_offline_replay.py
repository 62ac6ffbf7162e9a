"""``softsensor replay DAY.mcap --out EST.mcap``: the streaming path offline, via the CLI."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import estimate_digest as ed
import pytest
from paths import REPO
from stored_numbers import differences

from softsensor.cli import main as cli_main
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_plant_config
from softsensor.recording.mcap_day import iter_messages, read_day
from softsensor.signals import TOPIC_ESTIMATE, TOPIC_HEALTH, TOPIC_LAB, TOPIC_SCAN

H = 3600 * 10**9
#: The figures of the replay's summary line that the README's quick start quotes.
FIGURES = re.compile(r"(?P<ticks>\d+) ticks \((?P<stale>\d+) stale\), (?P<labs>\d+) lab updates "
                     r".*RMSE against /truth/plant \(reporting only\): moisture_out "
                     r"(?P<rmse_out>[\d.]+), moisture_in (?P<rmse_in>[\d.]+) kg/kg")


@pytest.fixture(scope="module")
def day_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("day") / "day.mcap"
    simulate_day(load_plant_config(), 4.0, 7, "inlet_moisture", 0.2).write(path)
    return path


def replay(capsys, *args: str) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = cli_main(["replay", *args])
    got = capsys.readouterr()
    # the verb's summary is its one line on stderr; stdout stays empty (no JSON was asked)
    assert got.out == "", got.out
    return rc, got.err if rc == 0 else "", got.err


def test_replay_writes_inputs_estimates_and_health_and_is_deterministic(day_file, tmp_path,
                                                                        capsys) -> None:
    rc, out, err = replay(capsys, str(day_file), "--out", str(tmp_path / "a.mcap"))
    assert rc == 0, err
    m = re.search(r"ukf: (\d+) ticks \((\d+) stale\), (\d+) lab updates", out)
    assert m, out
    ticks, stale, lab_updates = map(int, m.groups())
    assert ticks == 25 and lab_updates >= 1  # 4 h of 600 s windows, plus the first scan's
    # the scores against the truth are printed (the README's figures are checked on the demo
    # day, test_the_readme_quick_start_prints_the_demo_figures)
    assert FIGURES.search(out), out
    day, est = read_day(day_file), read_day(tmp_path / "a.mcap")
    assert set(est.topics) == {TOPIC_SCAN, TOPIC_LAB, TOPIC_ESTIMATE, TOPIC_HEALTH}
    assert est.truth is None  # ground truth is never published
    assert est.scans.equals(day.scans)
    assert est.labs["sample_id"].tolist() == day.labs["sample_id"].tolist()
    estimates = est.topic(TOPIC_ESTIMATE)
    assert len(estimates) == ticks and sum(b["stale"] for _, b in estimates) == stale
    assert len(est.topic(TOPIC_HEALTH)) >= ticks
    assert all(b["estimator"] == "ukf" and 0.5 < b["moisture_in"] < 2.0 for _, b in estimates)

    rc, out2, _ = replay(capsys, str(day_file), "--out", str(tmp_path / "b.mcap"),
                         "--estimator", "ukf")
    assert rc == 0
    assert read_day(tmp_path / "b.mcap").topic(TOPIC_ESTIMATE) == estimates


def test_the_estimator_is_warmed_up_before_the_first_message(day_file, tmp_path, capsys,
                                                             monkeypatch) -> None:
    """A first tick that compiles holds the estimator thread for tens of seconds (cold numba
    cache), which the replay calls a stall: the real filter ticks, with a lab, beforehand."""
    import softsensor.service.offline_replay as offline

    order: list[str] = []
    warmed = []

    def warm(make, cfg):
        order.append("warm-up")
        warmed.append(offline_warm_up(make, cfg))
        return warmed[-1]

    def stream(*args, **kwargs):
        order.append("stream")
        return offline_replay_messages(*args, **kwargs)

    offline_warm_up, offline_replay_messages = offline.warm_up, offline.replay_messages
    monkeypatch.setattr(offline, "warm_up", warm)
    monkeypatch.setattr(offline, "replay_messages", stream)
    start = int(read_day(day_file).scans.index[0])
    rc, out, err = replay(capsys, str(day_file), "--out", str(tmp_path / "w.mcap"),
                          "--end", str(start + H))
    assert rc == 0, err
    assert order == ["warm-up", "stream"]
    (w,) = warmed
    assert w.error is None and w.stats.failed_ticks == 0 and w.stats.lab_updates == 1
    assert re.search(r"after a \d+\.\d s warm-up", out), out


def test_time_range_rate_params_and_the_open_loop_estimator(day_file, tmp_path, capsys):
    start = int(read_day(day_file).scans.index[0]) + H
    rng = ["--start", str(start), "--end", str(start + H // 2), "--estimator", "openloop"]
    t0 = time.monotonic()
    rc, out, err = replay(capsys, str(day_file), "--out", str(tmp_path / "o.mcap"), *rng,
                          "--rate", "3600")
    wall = time.monotonic() - t0
    assert rc == 0, err
    assert wall >= 0.45  # 30 minutes of the day at 3600 times real time
    est = read_day(tmp_path / "o.mcap")
    assert est.scans.index.min() >= start and est.scans.index.max() < start + H // 2
    base = [b for _, b in est.topic(TOPIC_ESTIMATE)]
    assert [b["estimator"] for b in base] == ["openloop"] * len(base) and len(base) >= 3

    params = tmp_path / "params.toml"
    params.write_text("[parameters.mult_p]\nvalue = 2.0\n")
    rc, _, err = replay(capsys, str(day_file), "--out", str(tmp_path / "p.mcap"), *rng,
                        "--params", str(params))
    assert rc == 0, err
    hot = [b for _, b in read_day(tmp_path / "p.mcap").topic(TOPIC_ESTIMATE)]
    # twice the heat loss: the model's outlet air is colder
    assert all(h["T_dryer_out_model"] < b["T_dryer_out_model"] - 0.1
               for h, b in zip(hot[1:], base[1:], strict=True))


def test_the_day_file_is_opened_once(day_file, tmp_path, monkeypatch) -> None:
    """The scan period, the first-scan check, the replay and the truth come from one read of
    the day (it was opened four times: each a decompression and CRC check of the file)."""
    import softsensor.recording.mcap_day as mcap_day
    from softsensor.service.offline_replay import replay_to_file

    opened: list[Path] = []
    real = mcap_day._open

    def counting(path: Path):
        opened.append(Path(path))
        return real(path)

    monkeypatch.setattr(mcap_day, "_open", counting)
    summary = replay_to_file(day_file, tmp_path / "once.mcap", load_plant_config())
    assert opened.count(day_file) == 1, opened
    assert summary.ticks == 25 and summary.rmse is not None


def test_bad_input_gives_one_line_and_no_output(day_file, tmp_path, capsys) -> None:
    data = day_file.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    corrupt = tmp_path / "corrupt.mcap"
    mid = len(data) // 3
    corrupt.write_bytes(data[:mid] + bytes(b ^ 0x5A for b in data[mid:mid + 64])
                        + data[mid + 64:])
    params = tmp_path / "bad.toml"
    params.write_text("[parameters.mult_q]\nvalue = 1.0\n")
    cases = [
        ([str(cut)], r"cut\.mcap: truncated or corrupt MCAP file"),
        ([str(corrupt)], r"corrupt\.mcap: corrupt MCAP file"),
        ([str(tmp_path / "nope.mcap")], r"nope\.mcap: no such file"),
        ([str(day_file), "--params", str(tmp_path / "none.toml")], r"none\.toml: no such"),
        ([str(day_file), "--params", str(params)], r"parameters\.mult_q is not one of"),
        ([str(day_file), "--rate", "0"], r"rate must be a positive number or 'max'"),
        ([str(day_file), "--start", "noon"], r"--start must be ns since the epoch or an ISO"),
    ]
    out = tmp_path / "out.mcap"
    for args, pattern in cases:
        rc, _, err = replay(capsys, *args, "--out", str(out))
        assert rc == 2, args
        assert err.count("\n") == 1 and err.startswith("softsensor: "), err
        assert re.search(pattern, err), err
        assert not out.exists(), args

    rc, summary, err = replay(capsys, str(cut), "--allow-truncated", "--out", str(out))
    assert rc == 0, err
    kept = read_day(out)
    assert 0 < len(kept.scans) < len(read_day(day_file).scans)
    assert kept.topic(TOPIC_ESTIMATE)


@pytest.fixture(scope="module")
def demo_replay(tmp_path_factory) -> tuple[str, Path]:
    """The README's first quick-start command, ``softsensor replay replay/demo-day.mcap --out
    estimates.mcap``, run once: its summary line and its output file."""
    out = tmp_path_factory.mktemp("demo") / "estimates.mcap"
    return ed.replay_demo(out), out


def test_the_readme_quick_start_prints_the_demo_figures(demo_replay) -> None:
    """The quick start prints the figures the README quotes: ticks, stale ticks and lab
    updates exactly, and both RMSEs against the truth to the 4 decimals the README prints
    (the same digits: within 5e-5 kg/kg)."""
    readme = " ".join((REPO / "README.md").read_text().split())
    quick = readme[readme.index("## Quick start"):readme.index("## How data flows")]
    claimed = FIGURES.search(quick)
    assert claimed, "the README's quick start no longer quotes the replay's figures"
    out, _ = demo_replay
    got = FIGURES.search(out)
    assert got, out
    assert got.groupdict() == claimed.groupdict(), (out, claimed.groupdict())


@pytest.fixture(scope="module")
def demo_replay_zenoh(tmp_path_factory) -> tuple[str, Path]:
    """The same, ``--via-zenoh``: over two Zenoh sessions on loopback."""
    out = tmp_path_factory.mktemp("demo-zenoh") / "estimates.mcap"
    return ed.replay_demo(out, "--via-zenoh"), out


def test_the_demo_day_over_zenoh_is_bit_identical_to_in_memory(demo_replay,
                                                               demo_replay_zenoh) -> None:
    """The transport must not move a bit: in memory and over Zenoh, in one run on one
    machine, every number of every estimate of the demo day is the same
    (``tests/support/estimate_digest.py``'s digest)."""
    memory, zenoh = (ed.estimates(r[1]) for r in (demo_replay, demo_replay_zenoh))
    assert len(memory) == len(zenoh) > 0
    assert ed.digest(memory) == ed.digest(zenoh)


@pytest.mark.parametrize("path", ["demo_replay", "demo_replay_zenoh"])
def test_the_demo_estimates_match_the_stored_numbers(path, request) -> None:
    """Every number of every estimate of the demo day against the stored reference
    (``tests/fixtures/demo_estimates_digest.json``) within 1e-9 relative
    (``tests/support/stored_numbers.py``: another machine's compiled code differs in the last
    bits, the estimator does not), in memory and over Zenoh: a change of the service's
    wiring, its transport, its config or its lab handling must not move one. When the
    estimator changes on purpose, regenerate with ``python tests/support/estimate_digest.py
    --write`` and say in the commit why the numbers moved."""
    stored = json.loads(ed.STORED.read_text())
    messages = ed.estimates(request.getfixturevalue(path)[1])
    assert len(messages) == len(stored["numbers"]["@log_time"]) == 289
    moved = differences(ed.numbers(messages), stored["numbers"])
    assert not moved, ("the demo day's estimates changed: " + "; ".join(moved)
                       + "; if on purpose, run `python tests/support/estimate_digest.py "
                         "--write`")


def _recorded(path: Path) -> dict[str, list[tuple[int, dict]]]:
    """Each topic's messages in ``path``, in the order the file gives them."""
    out: dict[str, list[tuple[int, dict]]] = {}
    for topic, t, body in iter_messages(path):
        out.setdefault(topic, []).append((t, body))
    return out


def test_memory_and_zenoh_give_the_same_estimates_and_recording(day_file, tmp_path) -> None:
    """The transport conformance test: one recorded day (4 h, lab results within it) through
    the in-process memory pair and through the Zenoh pair on loopback gives the same
    estimates, bit for bit, the same summary counts, the same checkpoint after the last
    message, and records the same messages under every topic (scans and labs as replayed,
    every estimate and health), each topic in the same order."""
    from softsensor.service.offline_replay import replay_to_file

    cfg = load_plant_config()
    got = {}
    for via_zenoh in (False, True):
        name = "zenoh" if via_zenoh else "memory"
        got[name] = replay_to_file(day_file, tmp_path / f"{name}.mcap", cfg,
                                   checkpoint_out=tmp_path / f"{name}.ckpt",
                                   via_zenoh=via_zenoh)
    memory, zenoh = got["memory"], got["zenoh"]
    assert memory.ticks == 25 and memory.lab_updates >= 1, memory.line()
    assert ed.digest(memory.estimates) == ed.digest(zenoh.estimates)
    assert memory.estimates == zenoh.estimates
    counts = ("n_replayed", "n_recorded", "ticks", "stale_ticks", "lab_updates",
              "labs_accepted", "labs_refused", "span_s", "rmse")
    assert {k: getattr(memory, k) for k in counts} == {k: getattr(zenoh, k) for k in counts}
    a, b = _recorded(tmp_path / "memory.mcap"), _recorded(tmp_path / "zenoh.mcap")
    assert set(a) == {TOPIC_SCAN, TOPIC_LAB, TOPIC_ESTIMATE, TOPIC_HEALTH}
    assert a == b
    assert sum(len(v) for v in a.values()) == memory.n_recorded
    ckpt_a = json.loads((tmp_path / "memory.ckpt").read_text())
    ckpt_b = json.loads((tmp_path / "zenoh.ckpt").read_text())
    assert ckpt_a["service"] == ckpt_b["service"]
