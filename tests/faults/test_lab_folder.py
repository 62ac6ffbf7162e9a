"""Fault injection (issue 14, items 3 and 4): the lab drop folder is a boundary.

Before: a file raising anything but ``IngestError`` (a 5000-digit time, ``1e400``, JSON nested
deeply) was never rejected and was retried every poll; a 183 MB file was read whole; a
symbolic link to ``/etc/passwd`` was followed and its first line copied into ``rejected/``
and the log; and a sample id seen before a restart was accepted again. Each case is checked
here through the watcher the daemon runs, with a real folder.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import pytest
from paths import REPLAY

from softsensor.ingest.lab_files import MAX_BYTES, MAX_ROWS
from softsensor.ingest.lab_input import LabFolderWatcher, LabInput

NOW_NS = 1_750_000_000 * 10**9
SECRET = "root:x:0:0:the-secret-first-line"


def _watcher(folder: Path, got: list) -> LabFolderWatcher:
    return LabFolderWatcher(folder, LabInput(got.append, clock=lambda: NOW_NS), settle_s=0.0)


def _row(i: int, digits: str | None = None) -> str:
    t = digits or str(NOW_NS - 3600 * 10**9)
    return f"{t},0.11,S{i}\n"


def _poll(w: LabFolderWatcher) -> object:
    return w.poll_once(now=time.time() + 10)


BAD_FILES = {
    "huge-number.csv": "sample_time,moisture_out,sample_id\n" + _row(1, "9" * 5000),
    "inf.json": f'{{"sample_time_ns": {NOW_NS - 10**12}, "moisture_out": 1e400, '
                '"sample_id": "X"}',
    "nested.json": "[" * 100_000 + "]" * 100_000,
    "too-many-rows.csv": "sample_time,moisture_out,sample_id\n"
                         + "".join(_row(i) for i in range(MAX_ROWS + 1)),
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_any_failure_rejects_the_file_once(tmp_path: Path, name: str, caplog):
    (tmp_path / name).write_text(BAD_FILES[name])
    got: list = []
    w = _watcher(tmp_path, got)
    with caplog.at_level(logging.WARNING):
        first = _poll(w)
        second = _poll(w)
    assert not got
    assert first.rejected or first.processed, first  # handled on the first poll
    assert not (tmp_path / name).exists()  # not left in the folder to be retried
    assert not second.rejected and not second.processed and not second.reasons
    for reason_file in (tmp_path / "rejected").glob("*.reason.txt"):
        for line in reason_file.read_text().splitlines():
            assert len(line) <= 300 and "9" * 400 not in line


def test_a_file_over_the_size_limit_is_rejected_unread(tmp_path: Path):
    big = tmp_path / "big.csv"
    with open(big, "w") as f:
        f.write("sample_time,moisture_out,sample_id\n")
        f.write("x" * (MAX_BYTES + 10))
    got: list = []
    report = _poll(_watcher(tmp_path, got))
    assert not got and report.rejected and "more than" in report.reasons[0]


def test_a_symbolic_link_is_refused_and_its_target_never_read(tmp_path: Path, caplog):
    secret = tmp_path / "outside" / "passwd"
    secret.parent.mkdir()
    secret.write_text(SECRET + "\n")
    drop = tmp_path / "drop"
    drop.mkdir()
    os.symlink(secret, drop / "labs.csv")
    got: list = []
    with caplog.at_level(logging.DEBUG):
        report = _poll(_watcher(drop, got))
    assert not got and len(report.rejected) == 1
    moved = report.rejected[0]
    assert moved.is_symlink()  # the link itself was moved, the target untouched
    assert secret.read_text() == SECRET + "\n"
    texts = [p.read_text() for p in (drop / "rejected").glob("*.reason.txt")]
    assert texts and "symbolic link" in texts[0]
    assert all("secret" not in t for t in texts) and "secret" not in caplog.text


def test_a_fifo_does_not_block_the_watcher(tmp_path: Path):
    os.mkfifo(tmp_path / "pipe.csv")
    os.symlink(tmp_path / "pipe.csv", tmp_path / "via-link.csv")
    got: list = []
    t0 = time.perf_counter()
    report = _poll(_watcher(tmp_path, got))
    # never opened for reading (an open would block for ever; 30 s: a loaded machine's margin)
    assert time.perf_counter() - t0 < 30 and not got
    assert [p.name for p in report.rejected] == ["via-link.csv"]


def test_sample_ids_are_remembered_across_a_restart(tmp_path: Path):
    body = "sample_time,moisture_out,sample_id\n" + _row(1)
    (tmp_path / "a.csv").write_text(body)
    got: list = []
    assert len(_poll(_watcher(tmp_path, got)).accepted) == 1
    (tmp_path / "again.csv").write_text(body)  # the same result dropped after a restart
    got2: list = []
    report = _poll(_watcher(tmp_path, got2))  # a new watcher and lab input: a new process
    assert not got2 and report.duplicates == ["S1"], report


def test_a_reason_file_planted_as_a_link_is_not_written_through(tmp_path: Path):
    target = tmp_path / "victim.txt"
    target.write_text("keep\n")
    drop = tmp_path / "drop"
    (drop / "rejected").mkdir(parents=True)
    os.symlink(target, drop / "rejected" / "bad.csv.reason.txt")
    (drop / "bad.csv").write_text("not,a,lab\n1,2,3\n")
    report = _poll(_watcher(drop, []))
    assert report.rejected and target.read_text() == "keep\n"


# --- issue 25, item 7 and issue 24, item 2 ----------------------------------------------------


def test_a_bone_dry_result_is_refused_and_the_file_rejected_whole(tmp_path: Path):
    (tmp_path / "a.csv").write_text("sample_time,moisture_out,sample_id\n"
                                    + _row(1) + f"{NOW_NS - 10**12},0.0,S2\n")
    got: list = []
    report = _poll(_watcher(tmp_path, got))
    assert not got and [p.name for p in report.rejected] == ["a.csv"]
    assert not (tmp_path / "processed" / "a.csv").exists()  # rejected/ only
    reason = (tmp_path / "rejected" / "a.csv.reason.txt").read_text()
    assert reason.startswith("a.csv row 2: moisture_out is 0: a bone-dry sample is a LIMS "
                             "default or a typing slip"), reason
    assert not (tmp_path / ".seen-ids").exists()  # S1 not marked seen: the file can come back


def test_a_rejected_files_content_is_never_echoed(tmp_path: Path, caplog):
    """A hard link to a root-only file (not a symbolic link, so it is read): its first line
    must reach neither the reason file nor the log, whatever fails."""
    secret = tmp_path / "shadow"
    drop = tmp_path / "drop"
    drop.mkdir()
    cases = {
        "header.csv": SECRET + "\n1,2\n",
        "cell.csv": f"sample_time,moisture_out,sample_id\n{SECRET},0.1,A\n",
        "value.csv": f"sample_time,moisture_out,sample_id\n{NOW_NS - 10**12},{SECRET},A\n",
        "fields.csv": f"sample_time,moisture_out,sample_id\n{SECRET}\n",
        "entry.json": f'[{{"sample_time": "{SECRET}", "moisture_out": 0.1, "sample_id": "A"}}]',
        "broken.json": f'[{{"{SECRET}": ',
    }
    for name, text in cases.items():
        secret.write_text(text)
        os.link(secret, drop / name)
        secret.unlink()
    got: list = []
    with caplog.at_level(logging.DEBUG):
        report = _poll(_watcher(drop, got))
    assert not got and sorted(p.name for p in report.rejected) == sorted(cases)
    texts = [p.read_text() for p in (drop / "rejected").glob("*.reason.txt")]
    assert len(texts) == len(cases)
    for text in [*texts, caplog.text]:
        assert "secret" not in text and "root:x" not in text, text


def test_a_file_beyond_what_the_estimator_takes_at_once_is_refused_not_lost(tmp_path: Path):
    """A valid 10,000-row file went to processed/ and into .seen-ids while the rate limit
    dropped 9,871 of its rows. Now it is refused whole, nothing marked seen."""
    from softsensor.ingest.lab_input import BURST

    rows = "".join(_row(i) for i in range(10_000))
    (tmp_path / "all.csv").write_text("sample_time,moisture_out,sample_id\n" + rows)
    got: list = []
    report = _poll(_watcher(tmp_path, got))
    assert not got and [p.name for p in report.rejected] == ["all.csv"]
    assert f"10000 new results, more than the {BURST} the estimator takes at once" \
        in report.reasons[0]
    assert not (tmp_path / ".seen-ids").exists()


def test_files_beyond_the_rate_wait_in_the_folder(tmp_path: Path):
    from softsensor.ingest.lab_input import BURST

    for i in range(BURST + 5):
        (tmp_path / f"r{i:03d}.csv").write_text("sample_time,moisture_out,sample_id\n"
                                               + _row(i))
    got: list = []
    w = LabFolderWatcher(tmp_path, LabInput(got.append, clock=lambda: NOW_NS), settle_s=0.0,
                         rate_per_s=1e-9)
    first = _poll(w)
    assert len(got) == BURST and len(first.processed) == BURST and not first.rejected
    assert len(first.waiting) == 5 and len(list(tmp_path.glob("r*.csv"))) == 5
    seen = (tmp_path / ".seen-ids").read_text().splitlines()
    assert len(seen) == BURST  # only what was handed on is marked seen
    w.budget.tokens = 5.0  # the rate allows five more
    _poll(w)
    assert len(got) == BURST + 5 and not list(tmp_path.glob("r*.csv"))


def test_the_daemon_reads_the_lims_file_and_applies_every_result_of_a_flood(tmp_path: Path,
                                                                          caplog):
    """The daemon's lab folder, laid out by the plant config's [lab] table (the historian
    map's own section): the LIMS file of ``softsensor import`` is read as it is (% wet basis,
    day-first Madrid time), its lab line is on the plant's clock in % (issue 24, items 2 and
    7); then 120 one-result files, more than the estimator holds for one tick, are handed on
    at the rate it takes: every one applied, none dropped or refused (issue 25, item 7)."""
    import asyncio
    from datetime import UTC, datetime
    from zoneinfo import ZoneInfo

    from daemon_harness import running_daemon

    map_lab = (REPLAY / "historian-map.toml"
               ).read_text().split("[lab]", 1)[1]
    extra = '[display]\ntime_zone = "Europe/Madrid"\n\n[lab]' + map_lab
    n_flood = 120
    got: dict = {}

    async def main() -> None:
        async with running_daemon(tmp_path, ticks=2, config_extra=extra) as run:
            d = run.daemon
            lab_dir = tmp_path / "lab"
            now = d.clock.now_ns()

            def local(ns: int) -> str:
                return datetime.fromtimestamp(ns / 1e9, UTC).astimezone(
                    ZoneInfo("Europe/Madrid")).strftime("%d/%m/%Y %H:%M:%S")

            sample = now - 300 * 10**9
            (lab_dir / "lims.csv").write_text(
                "Sample ID,Sample Time,Result Time,Moisture\n"
                f"L-1,{local(sample)},{local(now)},9.500\n")
            loop = asyncio.get_running_loop()
            deadline = loop.time() + 30
            while d.lab_input.n_accepted < 1:
                assert loop.time() < deadline, "the LIMS file was not taken"
                await asyncio.sleep(0.05)
            got["lims_sample"] = sample
            base = d.clock.now_ns() - 120 * 10**9
            for i in range(n_flood):
                (lab_dir / f"flood-{i:03d}.csv").write_text(
                    "Sample ID,Sample Time,Result Time,Moisture\n"
                    f"F-{i},{local(base - i * 10**9)},{local(base)},9.{i % 10}\n")
            stats = d.worker.service.stats
            deadline = loop.time() + 90
            while stats.labs_accepted + stats.labs_refused < 1 + n_flood:
                assert loop.time() < deadline, (stats, d.worker.dropped)
                await asyncio.sleep(0.1)
            got["stats"] = (stats.labs_accepted, stats.labs_refused)
            got["dropped"] = dict(d.worker.dropped)
            got["left"] = sorted(p.name for p in lab_dir.glob("*.csv"))
            got["rejected"] = sorted(p.name for p in (lab_dir / "rejected").iterdir())
            got["seen"] = (lab_dir / ".seen-ids").read_text().splitlines()

    # the daemon's own logger: a replay verb run earlier in this process quiets its parents
    with caplog.at_level(logging.INFO, logger="softsensor.service.daemon"):
        asyncio.run(asyncio.wait_for(main(), 240))
    assert got["stats"] == (1 + n_flood, 0), got
    assert got["dropped"]["rate"] == 0 and got["dropped"]["queue_full"] == 0, got["dropped"]
    assert got["left"] == [] and got["rejected"] == [] and len(got["seen"]) == 1 + n_flood
    lab = next(r for r in caplog.records if r.getMessage() == "lab"
               and r.softsensor_fields["sample_id"] == "L-1").softsensor_fields
    # 9.5 % wet basis, on the plant's clock (Madrid, +01:00 in winter)
    assert lab["moisture_out"] == 9.5 and lab["unit"] == "% wb", lab
    when = datetime.fromtimestamp(got["lims_sample"] // 10**9, UTC).astimezone(
        ZoneInfo("Europe/Madrid")).isoformat(timespec="seconds")
    assert lab["sample_time"] == when and when.endswith("+01:00"), (lab, when)


def test_a_folder_that_cannot_be_listed_is_said_once_in_a_while(tmp_path: Path, caplog):
    """Issue 49 (fifth probe): "cannot list folder: Too many open files" came once a poll,
    1,064 lines (156 kB) a minute; now once per throttle period with a count."""
    caplog.set_level(logging.INFO)
    folder = tmp_path / "lab"
    w = _watcher(folder, [])
    w.poll_s = 0.0
    for sub in (w.processed_dir, w.rejected_dir):
        sub.rmdir()
    folder.rmdir()  # (as root a chmod cannot take it away)
    w.run(max_polls=500)
    said = [r for r in caplog.records if "cannot list folder" in r.getMessage()]
    assert 1 <= len(said) <= 2, len(said)
    folder.mkdir()
    w.run(max_polls=1)


def test_a_flood_of_bad_files_is_a_few_lines(tmp_path: Path, caplog):
    """Issue 49 (every repeated line throttled): 200 unusable files dropped at once are each
    rejected, with one line for the lot, not one each."""
    caplog.set_level(logging.INFO)
    folder = tmp_path / "lab"
    w = _watcher(folder, [])
    for i in range(200):
        (folder / f"bad{i:03d}.json").write_text("not json")
    _poll(w)
    assert len(list(w.rejected_dir.glob("bad*.json"))) == 200
    said = [r for r in caplog.records if "lab file rejected" in r.getMessage()]
    assert 1 <= len(said) <= 2, len(said)
