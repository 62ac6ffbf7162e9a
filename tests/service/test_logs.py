"""Library loggers behind the daemon's handlers (``softsensor/service/logs.py``, issue 40):
pymodbus' error lines with their frame dumps and asyncio's accept failures cut to one line and
throttled to one per 30 s with the count, the project's own lines untouched."""

from __future__ import annotations

import io
import logging

import pytest
from pymodbus.logging import Log

from softsensor.service.logs import LibraryLines


@pytest.fixture
def captured():
    """A handler behind :class:`LibraryLines` on a clock the test moves; its stream and clock."""
    now = [0.0]
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setFormatter(logging.Formatter("%(name)s %(levelname)s %(message)s"))
    handler.addFilter(LibraryLines(30.0, clock=lambda: now[0]))
    root = logging.getLogger()
    root.addHandler(handler)
    yield stream, now
    root.removeHandler(handler)


def test_pymodbus_errors_lose_their_frame_dump_and_repeat_once_per_30_s(captured):
    stream, now = captured
    for unit in range(500):  # as 500 requests to an absent unit did, each with its frames
        Log.transport_dump(Log.RECV_DATA, bytes([0, 1, 0, 0, 0, 6, unit % 256, 4, 0, 0, 0, 2]),
                           b"")
        Log.build_msg("reset")  # pymodbus drops a line equal to its last; this one differs
        Log.error("requested device id does not exist: {}", unit)
    lines = stream.getvalue().splitlines()
    assert lines == ["pymodbus.logging ERROR requested device id does not exist: 0"]
    now[0] = 31.0
    Log.build_msg("reset")
    Log.error("requested device id does not exist: {}", 255)
    last = stream.getvalue().splitlines()[-1]
    assert last == ("pymodbus.logging ERROR requested device id does not exist: 255 "
                    "(499 more like it in the last 30 s not logged)")
    assert ">>>>>" not in stream.getvalue()


def test_tracebacks_of_libraries_are_dropped_and_the_projects_lines_pass(captured):
    stream, _ = captured
    try:
        raise OSError(24, "Too many open files")
    except OSError:
        for _ in range(1000):
            logging.getLogger("asyncio").error("socket.accept() out of system resource",
                                               exc_info=True)
    for i in range(3):
        logging.getLogger("softsensor.test").warning("own line %d", i)
    lines = stream.getvalue().splitlines()
    assert lines == ["asyncio ERROR socket.accept() out of system resource",
                     "softsensor.test WARNING own line 0", "softsensor.test WARNING own line 1",
                     "softsensor.test WARNING own line 2"]
