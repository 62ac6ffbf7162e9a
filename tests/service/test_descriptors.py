"""Open descriptors watched against the process limit (``softsensor/service/descriptors.py``,
issue 40): near the limit health says ``degraded`` with the count (it said ``ok`` while
checkpoints failed with ``Too many open files``), and clears with a margin."""

from __future__ import annotations

import subprocess
import sys

from softsensor.estimate import Health, Reason
from softsensor.service.descriptors import DescriptorWatch


def test_the_watch_speaks_from_80_percent_and_clears_below_70():
    n = [100]
    watch = DescriptorWatch(count=lambda: n[0], limit=lambda: 1000)
    said = []
    for n[0] in (100, 799, 800, 750, 701, 699, 800):
        said.append(watch.check())
    assert [s is not None for s in said] == [False, False, True, True, True, False, True]
    assert said[2].startswith("800 of 1000 file descriptors open (80 %): near the process limit")
    assert DescriptorWatch(count=lambda: None, limit=lambda: 10).check() is None


def test_health_near_the_limit_is_degraded_says_why_and_reads_back():
    ok = Health(5, "dryer1", "ukf", Reason("ok", "fit"), Reason("ok", ""), Reason("ok", ""))
    short = ok.at(6, resources="900 of 1000 file descriptors open (90 %): near the limit")
    assert (ok.status, short.status) == ("ok", "degraded")
    assert short.detail == "resources: 900 of 1000 file descriptors open (90 %): near the limit"
    body = short.to_body()
    assert Health.from_body(body, 6).to_body() == body


_CHILD = """
import resource, socket
from softsensor.service.descriptors import DescriptorWatch
resource.setrlimit(resource.RLIMIT_NOFILE, (200, 200))
watch = DescriptorWatch()
before = watch.check()
held = [socket.socket() for _ in range(170)]
print(before is None, watch.check())
"""


def test_the_process_own_descriptors_are_counted_against_its_limit():
    r = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    first, said = r.stdout.strip().split(" ", 1)
    assert first == "True" and " of 200 file descriptors open" in said, r.stdout


_EXHAUSTED = """
import errno, resource, socket
from softsensor.service.descriptors import DescriptorWatch
resource.setrlimit(resource.RLIMIT_NOFILE, (64, 64))
watch = DescriptorWatch()
held = []
while True:  # every descriptor taken, as a flood of clients takes them
    try:
        held.append(socket.socket())
    except OSError as exc:
        assert exc.errno == errno.EMFILE, exc
        break
print(watch.check())
"""


def test_descriptors_all_taken_is_a_fault_not_silence():
    """Issue 49 (fifth probe): at the limit, listing /proc/self/fd needs a descriptor, the
    count failed and health said ``ok`` for 55 s while checkpoints failed."""
    r = subprocess.run([sys.executable, "-c", _EXHAUSTED], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    said = r.stdout.strip()
    assert said != "None", "health would say ok with every descriptor taken"
    assert "of 64 file descriptors open" in said, said


def test_a_count_that_fails_even_with_the_reserve_is_said_in_health():
    import errno

    from softsensor.service.descriptors import CountFailed

    def fails():
        raise CountFailed(errno.EMFILE, "Too many open files")

    watch = DescriptorWatch(count=fails, limit=lambda: 1000)
    said = watch.check()
    watch.close()
    assert said is not None and said.startswith("Too many open files while counting the open "
                                                "file descriptors (limit 1000)"), said
    ok = Health(5, "dryer1", "ukf", Reason("ok", "fit"), Reason("ok", ""), Reason("ok", ""))
    assert ok.at(6, resources=said).status == "degraded"


def test_a_dropped_watch_gives_its_reserve_back():
    import gc
    import os

    before = len(os.listdir("/proc/self/fd"))
    watches = [DescriptorWatch() for _ in range(50)]
    assert len(os.listdir("/proc/self/fd")) >= before + 50
    del watches
    gc.collect()
    assert len(os.listdir("/proc/self/fd")) <= before + 2
