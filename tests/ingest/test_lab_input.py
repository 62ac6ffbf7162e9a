"""Lab results from bus bodies and dropped files: the lab-result contract, deduplication,
the folder watcher."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from softsensor.errors import IngestError
from softsensor.estimation.interface import LabResult
from softsensor.ingest.lab_files import parse_lab_csv
from softsensor.ingest.lab_input import LabFolderWatcher, LabInput, PollReport, _Budget
from softsensor.messages import make_lab_result

T_S = 1_750_000_000  # 2025-06-15T15:06:40Z
T_NS = T_S * 10**9
NOW_NS = T_NS + 3600 * 10**9
OLD = time.time() - 60  # mtime of a settled file [s]


def _drop(folder: Path, name: str, text: str, mtime: float = OLD) -> Path:
    p = folder / name
    p.write_text(text)
    os.utime(p, (mtime, mtime))
    return p


def _settle(watcher: LabFolderWatcher) -> PollReport:
    """Two polls ``settle_s`` apart: a file is read only once it kept its size, time and
    inode over the settle interval (issue 31 item 4); the second poll's report."""
    t = time.time()
    first = watcher.poll_once(now=t)
    assert not first.processed and not first.rejected  # never read at first sight
    return watcher.poll_once(now=t + watcher.settle_s + 0.1)


@pytest.fixture
def inbox(tmp_path: Path) -> tuple[LabFolderWatcher, list[LabResult]]:
    got: list[LabResult] = []
    lab_input = LabInput(got.append, clock=lambda: NOW_NS)
    return LabFolderWatcher(tmp_path, lab_input, poll_s=0.05, settle_s=1.0), got


# --- pure parsing ---------------------------------------------------------------------------


def test_one_lab_result_contract_for_every_path() -> None:
    """One range and one tolerance (softsensor.messages): the bus, the lab folder, the import
    and the estimator hold a result to the same rules, because a LabResult cannot be made
    that breaks them. A sample time after its arrival is refused, even by a minute (it was
    accepted up to an hour late here, and then refused by the estimator); 1.7 kg/kg is
    possible for a lab to report (it reaches the estimator's statistical gate)."""
    assert make_lab_result(T_NS, 1.7, "L1", log_time_ns=T_NS).moisture_out == 1.7
    for make in (lambda: make_lab_result(T_NS + 60 * 10**9, 0.1, "L1", log_time_ns=T_NS),
                 lambda: LabResult(T_NS + 60 * 10**9, 0.1, "L1", T_NS)):
        with pytest.raises(IngestError, match="lies 1.0 min after the result arrived"):
            make()
    with pytest.raises(IngestError, match="is 0: a bone-dry sample"):
        LabResult(T_NS, 0.0, "L1")
    lab = LabResult(T_NS, 0.1, "L1", T_NS)
    with pytest.raises(IngestError, match="outside the plausible range 0..2"):
        dataclasses.replace(lab, moisture_out=2.01)
    late = "sample_time,moisture_out,sample_id\n2025-06-15T15:07:40Z,0.1,F1\n"
    # the arrival is the daemon's clock: the hint names that clock first (issue 30)
    with pytest.raises(IngestError, match=r"f.csv row 1: sample_time lies 1.0 min after the "
                                          r"result arrived \(at 2025-06-15T15:06:40Z by the "
                                          r"daemon's clock: is that clock the plant's\? against "
                                          r"plant-server start the daemon with --clock-start "
                                          r"plc; else is lab.time_zone right\?\)"):
        parse_lab_csv(late, log_time_ns=T_NS, where="f.csv")


def test_one_lab_parser_for_live_and_recorded_bodies() -> None:
    import softsensor.ingest.lab_input
    import softsensor.messages
    import softsensor.recording.mcap_day

    assert softsensor.ingest.lab_input.lab_from_body is softsensor.messages.lab_from_body
    assert softsensor.recording.mcap_day.lab_from_body is softsensor.messages.lab_from_body


def test_lab_input_dedup_and_reasons() -> None:
    got: list[LabResult] = []
    li = LabInput(got.append, known_ids=["OLD"], clock=lambda: NOW_NS)
    body = {"sample_time_ns": T_NS, "moisture_out": 0.1, "sample_id": "L1"}
    assert li.from_body(body) is None
    assert got[0].log_time_ns == NOW_NS  # no time_ns: the arrival time
    assert "duplicate sample_id 'L1'" in li.from_body(body)
    assert "duplicate" in li.from_body({**body, "sample_id": "OLD"})
    assert "moisture_out" in li.from_body({**body, "sample_id": "L2", "moisture_out": 9.0})
    assert len(got) == 1 and (li.n_accepted, li.n_duplicates, li.n_rejected) == (1, 2, 1)


def test_failed_sink_does_not_swallow_the_result() -> None:
    calls: list[LabResult] = []

    def flaky(lab: LabResult) -> None:
        calls.append(lab)
        if len(calls) == 1:
            raise RuntimeError("estimator busy")

    li = LabInput(flaky)
    lab = LabResult(T_NS, 0.1, "L1", NOW_NS)
    with pytest.raises(RuntimeError):
        li.submit(lab)
    assert li.submit(lab) is None and len(calls) == 2


# --- folder watcher -------------------------------------------------------------------------


def test_good_files_are_processed(inbox, tmp_path: Path) -> None:
    watcher, got = inbox
    _drop(tmp_path, "a.csv", "sample_time,moisture_out,sample_id\n2025-06-15T15:06:40Z,0.1,A1\n")
    _drop(tmp_path, "b.json", json.dumps([{"sample_time_ns": T_NS, "moisture_out": 0.11,
                                           "sample_id": "B1"}]))
    report = _settle(watcher)
    assert [lab.sample_id for lab in got] == ["A1", "B1"]
    assert all(lab.log_time_ns == NOW_NS for lab in got)
    assert sorted(p.name for p in (tmp_path / "processed").iterdir()) == ["a.csv", "b.json"]
    assert not list((tmp_path / "rejected").iterdir())
    assert len(report.processed) == 2 and not report.reasons
    assert sorted(p.name for p in tmp_path.iterdir()) == [".seen-ids", "processed", "rejected"]


def test_malformed_file_is_rejected_with_reason(inbox, tmp_path: Path) -> None:
    watcher, got = inbox
    _drop(tmp_path, "bad.json", "{not json")
    _drop(tmp_path, "notes.txt", "hello")
    _drop(tmp_path, "hdr.csv", "when,value\n1,2\n")
    report = _settle(watcher)
    assert got == []
    rej = tmp_path / "rejected"
    assert sorted(p.name for p in rej.iterdir()) == [
        "bad.json", "bad.json.reason.txt", "hdr.csv", "hdr.csv.reason.txt",
        "notes.txt", "notes.txt.reason.txt"]
    assert "bad.json: not valid JSON" in (rej / "bad.json.reason.txt").read_text()
    assert "unsupported file type '.txt'" in (rej / "notes.txt.reason.txt").read_text()
    assert "column 'sample_time' of lab.sample_time_column is not in the file; nothing of " \
        "the file was applied" in (rej / "hdr.csv.reason.txt").read_text()
    assert (rej / "bad.json").read_text() == "{not json"  # moved intact
    assert len(report.rejected) == 3


def test_a_partly_bad_file_is_rejected_whole_and_only_rejected(inbox, tmp_path: Path) -> None:
    """Issue 24 item 2: such a file also landed in processed/ with the reason "1 of 1 entries
    rejected; the others were accepted". Now nothing of it is applied, it is in rejected/
    only, and its reason quotes none of its content."""
    watcher, got = inbox
    _drop(tmp_path, "mix.csv", "sample_time,moisture_out,sample_id\n"
          "2025-06-15T15:06:40Z,0.1,M1\n"
          "2025-06-15T15:06:40Z,nan,M2\n"
          "2025-06-15T15:06:40Z,5,M3\n")
    report = _settle(watcher)
    assert got == [] and not report.processed and not (tmp_path / "processed" / "mix.csv").exists()
    assert sorted(p.name for p in (tmp_path / "rejected").iterdir()) == ["mix.csv",
                                                                         "mix.csv.reason.txt"]
    reason = (tmp_path / "rejected" / "mix.csv.reason.txt").read_text()
    assert reason == "mix.csv row 3: moisture_out read as kg/kg on a dry basis is outside the " \
        "plausible range 0..2 kg/kg dry basis (set lab.unit = \"%\" and lab.basis); " \
        "nothing of the file was applied\n", reason
    # fixed and dropped again, it is taken (M1 was never marked seen)
    _drop(tmp_path, "mix.csv", "sample_time,moisture_out,sample_id\n"
          "2025-06-15T15:06:40Z,0.1,M1\n2025-06-15T15:06:40Z,0.11,M3\n")
    _settle(watcher)
    assert [lab.sample_id for lab in got] == ["M1", "M3"]


def test_duplicates_across_files_and_same_name_again(inbox, tmp_path: Path) -> None:
    watcher, got = inbox
    text = "sample_time,moisture_out,sample_id\n2025-06-15T15:06:40Z,0.1,D1\n"
    _drop(tmp_path, "d.csv", text)
    _settle(watcher)
    _drop(tmp_path, "d.csv", text + "2025-06-15T16:06:40Z,0.12,D2\n")
    report = _settle(watcher)
    assert [lab.sample_id for lab in got] == ["D1", "D2"]
    assert report.duplicates == ["D1"]
    assert sorted(p.name for p in (tmp_path / "processed").iterdir()) == ["d.1.csv", "d.csv"]


def test_file_being_written_waits(inbox, tmp_path: Path) -> None:
    watcher, got = inbox
    p = _drop(tmp_path, "w.csv", "sample_time,moisture_out,sample_id\n", mtime=time.time())
    _drop(tmp_path, ".hidden.csv", "x")
    _drop(tmp_path, "x.csv.part", "x")
    t = time.time()
    report = watcher.poll_once(now=t)
    assert report.waiting == [p] and got == []
    with open(p, "a") as f:
        f.write("2025-06-15T15:06:40Z,0.1,W1\n")
    os.utime(p, (OLD, OLD))
    assert watcher.poll_once(now=t + 2).waiting == [p]  # size changed since the last poll
    assert watcher.poll_once(now=t + 2.5).waiting == [p]  # not yet stable for settle_s
    watcher.poll_once(now=t + 3.1)
    assert [lab.sample_id for lab in got] == ["W1"]
    assert (tmp_path / ".hidden.csv").exists() and (tmp_path / "x.csv.part").exists()


def test_background_watcher_is_stoppable(tmp_path: Path) -> None:
    got: list[LabResult] = []
    event = threading.Event()

    def sink(lab: LabResult) -> None:
        got.append(lab)
        event.set()

    with LabFolderWatcher(tmp_path, LabInput(sink), poll_s=0.02, settle_s=0.0):
        _drop(tmp_path, "bg.json", json.dumps({"sample_time_ns": T_NS, "moisture_out": 0.1,
                                               "sample_id": "BG"}))
        assert event.wait(5.0)
    t = time.monotonic()
    watcher = LabFolderWatcher(tmp_path, LabInput(sink), poll_s=10.0)
    stop = threading.Event()
    th = threading.Thread(target=watcher.run, args=(stop,))
    th.start()
    stop.set()
    th.join(5.0)
    # before its first 10 s poll wait ends (the margin is for a loaded machine)
    assert not th.is_alive() and time.monotonic() - t < 8.0
    assert [lab.sample_id for lab in got] == ["BG"]


_PAUSING_WRITER = """
import sys, time
path, pause = sys.argv[1], float(sys.argv[2])
rows = ["sample_time,moisture_out,sample_id", "2025-06-15T14:06:40Z,0.100,P1",
        "2025-06-15T14:36:40Z,0.110,P2", "2025-06-15T15:06:40Z,0.120,P3"]
with open(path, "w") as f:  # a LIMS export written row by row, kept open throughout
    f.write(rows[0] + "\\n" + rows[1] + "\\n")
    f.flush()
    print("paused", flush=True)
    time.sleep(pause)  # at a row boundary, longer than the settle interval
    for row in rows[2:]:
        f.write(row + "\\n")
        f.flush()
        time.sleep(0.05)
print("done", flush=True)
"""


def test_a_lab_file_written_with_a_pause_loses_no_row(tmp_path: Path) -> None:
    """Issue 31 item 4: a LIMS export written row by row with a pause of more than 1 s was
    read at the pause: the first row applied, the file moved to processed/ while still open,
    and the rows written after it never applied, never in .seen-ids, never logged. Now the
    file taken is watched, read again when it changed, and every row is applied once."""
    got: list[LabResult] = []
    watcher = LabFolderWatcher(tmp_path, LabInput(got.append, clock=lambda: NOW_NS),
                               poll_s=0.1, settle_s=0.5)
    writer = subprocess.Popen([sys.executable, "-c", _PAUSING_WRITER, str(tmp_path / "p.csv"),
                               "2.0"], stdout=subprocess.PIPE, text=True)
    try:
        assert writer.stdout.readline().strip() == "paused"
        with watcher:
            deadline = time.monotonic() + 15
            while len(got) < 3 and time.monotonic() < deadline:
                time.sleep(0.1)
            assert writer.stdout.readline().strip() == "done"
            time.sleep(1.0)  # and nothing twice
    finally:
        writer.kill()
        writer.wait(10)
        writer.stdout.close()
    assert [lab.sample_id for lab in got] == ["P1", "P2", "P3"], got
    assert [lab.moisture_out for lab in got] == [0.100, 0.110, 0.120]
    assert (tmp_path / "processed" / "p.csv").read_text().count("\n") == 4
    assert (tmp_path / ".seen-ids").read_text().split() == ['"P1"', '"P2"', '"P3"']


def test_the_lab_folder_reads_its_lab_tables_delimiter_and_names_it(tmp_path):
    """The daemon's lab folder split every CSV at ',' whatever [lab] delimiter said; a ';'
    file is read with delimiter ';', and without it refused naming lab.delimiter."""
    from softsensor.ingest.historian_map import LabMap
    from softsensor.ingest.lab_input import LabFolderWatcher, LabInput

    got: list = []
    body = ("sample_time;moisture;sample_id\n2026-01-05T08:00:00Z;9,957;L1\n")
    for delimiter in (";", ","):
        folder = tmp_path / f"lab{delimiter == ';'}"
        folder.mkdir()
        (folder / "lims.csv").write_text(body)
        lab = LabMap(sample_time_column="sample_time", moisture_column="moisture", unit="%",
                     basis="wet", sample_id_column="sample_id", delimiter=delimiter,
                     decimal=",")
        clock = lambda: 1_767_603_600 * 10**9  # noqa: E731 - 2026-01-05T09:00Z
        w = LabFolderWatcher(folder, LabInput(got.append, clock=clock), lab_map=lab,
                             settle_s=0.0)
        report = w.poll_once(now=2e9)
        if delimiter == ";":
            assert [r.sample_id for r in report.accepted] == ["L1"], report.reasons
            assert got[0].moisture_out == pytest.approx(0.09957 / (1 - 0.09957))
        else:
            assert "set lab.delimiter = ';'" in report.reasons[0], report.reasons


def test_a_refused_result_frees_its_id_and_the_corrected_file_is_taken(inbox, tmp_path):
    """Issue 40: a lab result the estimator refused (outside the envelope, an outlier) kept
    its sample id seen, so the corrected file with the same id was dropped as a duplicate.
    The estimator's refusal frees it (``forget``), across a restart too."""
    watcher, got = inbox
    _drop(tmp_path, "typo.csv", "sample_time,moisture_out,sample_id\n"
                                "2025-06-15T15:06:40Z,0.45,S7\n2025-06-15T15:16:40Z,0.1,S8\n")
    _settle(watcher)
    watcher.forget("S7")  # as the daemon's estimator service does when it refuses 0.45
    watcher.forget("from-the-bus")  # never seen here: nothing to free, nothing written
    restarted = LabFolderWatcher(tmp_path, LabInput(got.append, clock=lambda: NOW_NS),
                                 poll_s=0.05, settle_s=1.0)
    assert not restarted.lab_input.seen("S7") and restarted.lab_input.seen("S8")
    _drop(tmp_path, "fixed.csv", "sample_time,moisture_out,sample_id\n"
                                 "2025-06-15T15:06:40Z,0.095,S7\n")
    report = _settle(restarted)
    assert [(lab.sample_id, lab.moisture_out) for lab in got] == \
        [("S7", 0.45), ("S8", 0.1), ("S7", 0.095)]
    assert not report.duplicates
    assert "from-the-bus" not in (tmp_path / ".seen-ids").read_text()
    again = LabFolderWatcher(tmp_path, LabInput(got.append), poll_s=0.05, settle_s=1.0)
    assert again.lab_input.seen("S7")  # the corrected result taken: a duplicate from now on


def test_rows_appended_beyond_the_burst_are_applied_later_and_said(inbox, tmp_path, caplog):
    """Issue 40: more than 25 rows appended to a file already taken (a LIMS writer that kept
    it open) were lost without a line or a count; now the re-read takes at most the burst
    per poll, says what it deferred, and takes the rest at the next polls."""
    watcher, got = inbox
    head = "sample_time,moisture_out,sample_id\n2025-06-15T15:06:40Z,0.1,R0\n"
    _drop(tmp_path, "open.csv", head)
    _settle(watcher)
    taken = tmp_path / "processed" / "open.csv"
    rows = "".join(f"2025-06-15T15:{10 + k:02d}:00Z,0.1,R{k + 1}\n" for k in range(40))
    taken.write_text(head + rows)
    os.utime(taken, (OLD, OLD))
    t = time.time() + 10
    watcher.poll_once(now=t)  # the change seen
    first = watcher.poll_once(now=t + 2)
    assert len(first.accepted) == 25 and taken in first.waiting
    assert "read again, 25 new results applied, 15 deferred to later polls" in caplog.text
    second = watcher.poll_once(now=t + 4)
    assert len(second.accepted) == 15 and not second.waiting
    assert [lab.sample_id for lab in got] == [f"R{k}" for k in range(41)]


def test_a_refused_row_read_again_does_not_starve_the_rows_after_it(tmp_path):
    """A file with rows deferred is read again at every poll; a result the estimator refused
    (its id freed by ``forget``) was handed on again unchanged at each one, taking the poll's
    token first, so the rows after it never came. Now a row handed on from the file is not
    handed on again unchanged; a corrected value under the same id is."""
    got: list[LabResult] = []

    def estimator(lab: LabResult) -> None:  # refuses 0.45, as the daemon's service does
        got.append(lab)
        if lab.moisture_out == 0.45:
            watcher.forget(lab.sample_id)

    watcher = LabFolderWatcher(tmp_path, LabInput(estimator, clock=lambda: NOW_NS),
                               poll_s=0.05, settle_s=1.0)
    head = "sample_time,moisture_out,sample_id\n2025-06-15T15:06:40Z,0.1,R0\n"
    _drop(tmp_path, "open.csv", head)
    _settle(watcher)
    wall = [0.0]
    watcher.budget = _Budget(1.0, burst=1, clock=lambda: wall[0])  # one result a poll
    taken = tmp_path / "processed" / "open.csv"

    def rows(r1: str) -> str:
        return head + f"2025-06-15T15:10:00Z,{r1},R1\n" + "".join(
            f"2025-06-15T15:{10 + k:02d}:00Z,0.1,R{k}\n" for k in (2, 3, 4))

    taken.write_text(rows("0.45"))
    os.utime(taken, (OLD, OLD))
    t = time.time() + 10
    watcher.poll_once(now=t)  # the change seen
    for k in range(1, 7):
        wall[0] += 1.0
        watcher.poll_once(now=t + 2 * k)
    assert [(lab.sample_id, lab.moisture_out) for lab in got] == \
        [("R0", 0.1), ("R1", 0.45), ("R2", 0.1), ("R3", 0.1), ("R4", 0.1)]
    taken.write_text(rows("0.095"))  # the typo corrected under the same id
    os.utime(taken, (OLD, OLD))
    watcher.poll_once(now=t + 20)
    wall[0] += 1.0
    report = watcher.poll_once(now=t + 22)
    assert [(lab.sample_id, lab.moisture_out) for lab in report.accepted] == [("R1", 0.095)]
    assert watcher.lab_input.seen("R1") and len(got) == 6
