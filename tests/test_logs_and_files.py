"""Logs and files a person meets (issue 24, item 7): library loggers quiet unless asked,
files written with the user's umask, ``plant-server`` refusing a busy port at once."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from softsensor.files import atomic_path

_OPCUA_START = """
import asyncio, logging, socket, sys
from softsensor.cli import setup_logging
setup_logging(verbose=sys.argv[1] == "verbose")
from softsensor.presentation.display import DisplaySettings
from softsensor.outputs.opcua_server import EstimateOpcUaServer
from softsensor.outputs.settings import OpcUaSettings
with socket.socket() as s:
    s.bind(("127.0.0.1", 0)); port = s.getsockname()[1]
async def main():
    server = EstimateOpcUaServer(OpcUaSettings(enabled=True, port=port), DisplaySettings())
    await server.start()
    await server.stop()
asyncio.run(main())
logging.getLogger("softsensor.test").info("done")
"""


@pytest.mark.parametrize("mode", ["quiet", "verbose"])
def test_library_loggers_are_quiet_unless_asked(mode):
    """An OPC UA server start logged about a thousand asyncua INFO lines into the daemon's
    log; the project's own INFO lines stay."""
    r = subprocess.run([sys.executable, "-c", _OPCUA_START, mode], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = r.stderr.splitlines()
    library = [ln for ln in lines if " asyncua" in ln and (" INFO " in ln or " DEBUG " in ln)]
    assert any("softsensor.test: done" in ln for ln in lines), r.stderr[-2000:]
    if mode == "quiet":
        assert library == [], library[:5]
    else:
        assert len(library) > 20


def _mode(path: Path) -> int:
    return path.stat().st_mode & 0o777


@pytest.fixture
def umask():
    """Set the process umask for one test, restored after."""
    old = os.umask(0o022)
    os.umask(old)
    yield os.umask
    os.umask(old)


def test_files_replaced_whole_get_the_users_umask(tmp_path, umask):
    from softsensor.calibration.params_file import write_params
    from softsensor.presentation.calibration_figures import write_page

    umask(0o022)
    params = write_params(tmp_path / "params.toml", {"fit": {"cost": 0.1}})
    page = write_page(tmp_path, "Report", [("A", "text")])
    assert _mode(params) == 0o644 and _mode(page) == 0o644
    umask(0o077)
    with atomic_path(tmp_path / "private.txt") as tmp:
        tmp.write_text("x")
    assert _mode(tmp_path / "private.txt") == 0o600
    os.chmod(params, 0o640)  # a file that exists keeps its mode, as open(..., "w") would
    write_params(params, {"fit": {"cost": 0.2}})
    assert _mode(params) == 0o640 and "0.2" in params.read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["index.html", "params.toml",
                                                          "private.txt"]


def test_plant_server_refuses_a_busy_port_before_it_simulates():
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        t0 = time.monotonic()
        r = subprocess.run([sys.executable, "-m", "softsensor.cli", "plant-server", "--port",
                            str(port), "--hours", "48"], capture_output=True, text=True,
                           timeout=60)
        took = time.monotonic() - t0
    assert r.returncode == 2, (r.returncode, r.stderr[-1000:])
    assert r.stderr.strip().splitlines() == [
        f"softsensor: plant-server cannot listen on 127.0.0.1:{port}: Address already in use "
        "(another --port?)"], r.stderr
    assert took < 15, took  # the 48 h day took 30 s to simulate before the refusal
