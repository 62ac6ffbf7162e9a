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

from softsensor.ingest.lab_input import MAX_BYTES, MAX_ROWS, LabFolderWatcher, LabInput

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
    assert time.perf_counter() - t0 < 5 and not got  # never opened for reading
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
