"""The ``mbpoll`` command lines the README and docs/interface.md give a plant engineer, run as
written (only the port and host replaced by the test's) against the daemon's Modbus output
(issue 24, item 4: the documented command asked for 24 registers where 17 exist)."""

from __future__ import annotations

import re
import shlex
import shutil
import struct
import subprocess
from pathlib import Path

import pytest

from softsensor.outputs.modbus_server import N_REGISTERS, EstimateModbusServer
from softsensor.outputs.settings import ModbusOutputSettings
from softsensor.presentation.display import DisplaySettings
from tests.test_outputs import BODY, T_NS, _Loop, _read

ROOT = Path(__file__).resolve().parents[1]
DOCS = (ROOT / "README.md", ROOT / "docs" / "interface.md")


def documented_commands(path: Path) -> list[str]:
    """Every line of a fenced code block that starts with ``mbpoll``."""
    text = path.read_text(encoding="utf-8")
    blocks = re.findall(r"^```[a-z]*\n(.*?)^```", text, re.M | re.S)
    return [line.split("#")[0].strip() for b in blocks for line in b.splitlines()
            if line.strip().startswith("mbpoll ")]


def _at(command: str, port: int) -> list[str]:
    """The documented command with its port and host replaced (nothing else touched)."""
    argv = shlex.split(command)
    assert argv[0] == "mbpoll" and "-p" in argv, command
    argv[argv.index("-p") + 1] = str(port)
    argv[-1] = "127.0.0.1"
    return argv


def test_both_documents_give_the_same_mbpoll_commands():
    readme, interface = (documented_commands(p) for p in DOCS)
    assert readme and readme == interface, (readme, interface)


@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll is not installed "
                    "(apt-get install mbpoll)")
def test_the_documented_mbpoll_commands_read_every_register():
    server = EstimateModbusServer(ModbusOutputSettings(enabled=True, port=0),
                                  DisplaySettings(moisture_basis="wet"))
    with _Loop() as lp:
        lp.run(server.start())
        try:
            server.publish(BODY, T_NS)
            for _ in range(100):  # bounded: the store is handed to the server's loop
                words, _, _ = lp.run(_read(server.port))
                if words[15] == 1:
                    break
            got: dict[int, float] = {}
            for command in documented_commands(DOCS[1]):
                r = subprocess.run(_at(command, server.port), capture_output=True, text=True,
                                   timeout=20)
                assert r.returncode == 0 and "Illegal" not in r.stdout + r.stderr, \
                    (command, r.stdout[-500:], r.stderr[-500:])
                got.update({int(a): float(v) for a, v in
                            re.findall(r"^\[(\d+)\]:\s+(\S+)\s*$", r.stdout, re.M)})
        finally:
            lp.run(server.stop())
    f32 = [struct.unpack(">f", struct.pack(">HH", *words[a:a + 2]))[0] for a in range(0, 12, 2)]
    for i, value in enumerate(f32):
        assert got[2 * i] == pytest.approx(value, rel=1e-6), got
    assert got[12] == T_NS // 10**9
    assert (got[14], got[15], got[16]) == (1, 1, 1)  # degraded, first estimate, lab applied
    assert max(got) < N_REGISTERS
