"""Interoperability with Modbus peers that are not pymodbus.

(a) A libmodbus C server (``tests/fixtures/modbus_server.c``, compiled here with gcc) serves
    raw register words worked out by hand; our poller must decode them to the right SI values.
(b) The ``mbpoll`` command-line client reads our simulated PLC and must see the expected
    values; its write attempt must be refused and counted.

Needs the Debian packages ``gcc``, ``libmodbus-dev`` and ``mbpoll``; each test is marked by what
it needs (``libmodbus``, ``mbpoll``: CI runs them by name after the default suite) and skipped
with the reason when its tool is missing. Every subprocess runs under a timeout.
"""

import asyncio
import contextlib
import re
import shutil
import struct
import subprocess
from pathlib import Path

import pytest
from paths import FIXTURES

from softsensor.ingest.modbus_poller import ModbusPoller
from softsensor.ingest.tagmap import load_tagmap
from softsensor.plant.plc_server import NOMINAL_VALUES, PlcServer, constant_values

FIXTURE = FIXTURES / "modbus_server.c"
MODBUS_H = Path("/usr/include/modbus/modbus.h")
FAST = {"poll_period_s": 0.05, "timeout_s": 1.0, "retries": 0, "reconnect_delay_s": 0.05,
        "reconnect_delay_max_s": 0.2}

# The default tag map's layout, filled with hand-computed words (IEEE 754 / two's complement):
# (unit, table, address, words, signal, SI value)
C_SERVER_WORDS = [
    (1, "i", 0, [0x4363, 0x0000], "T_air_in", 227.0 + 273.15),  # float32 ABCD 227.0 degC
    (1, "i", 2, [0x4296, 0x0000], "T_dryer_out", 75.0 + 273.15),  # float32 ABCD 75.0 degC
    (1, "i", 4, [0x0000, 0x4282], "T_cyclone_out", 65.0 + 273.15),  # float32 CDAB 65.0 degC
    (1, "i", 6, [0xC142, 0x0000], "T_fiber_in", 96.5 + 273.15),  # float32 BADC 96.5 degC
    (1, "i", 10, [0x4075, 0xC000, 0, 0], "T_sp", 348.0),  # float64 ABCD 348.0 K
    (1, "h", 100, [0x8120, 0x0004], "m_air", 82.0),  # int32 CDAB 295200 kg/h
    (1, "h", 102, [0x0870], "m_fiber", 6.0),  # uint16 2160 x 0.01 t/h
    (1, "h", 103, [0x01F4], "m_steam", 0.5),  # int16 500 x 0.001 kg/s
    (1, "h", 104, [0x01C7], "flap_cmd", 45.5),  # uint16 455 x 0.1 %
    (2, "i", 0, [0x0000, 0x4842], "T_amb", 283.15),  # float32 DCBA 50.0 degF
    (2, "i", 2, [0x0000, 0x1F40], "H_amb", 0.008),  # uint32 ABCD 8000 x 0.001 g/kg
]


def run(coro, timeout: float = 30.0):
    return asyncio.run(asyncio.wait_for(coro, timeout))


@pytest.fixture(scope="module")
def c_server_binary(tmp_path_factory) -> Path:
    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed (apt-get install gcc)")
    if not MODBUS_H.exists():
        pytest.skip("libmodbus headers not installed (apt-get install libmodbus-dev)")
    out = tmp_path_factory.mktemp("cmodbus") / "modbus_server"
    res = subprocess.run(["gcc", "-O1", "-Wall", "-o", str(out), str(FIXTURE),
                          f"-I{MODBUS_H.parent}", "-lmodbus"],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    return out


@pytest.mark.libmodbus
def test_poller_reads_a_libmodbus_server(c_server_binary):
    specs = [f"{u}:{t}:{a}=" + ",".join(f"0x{w:04X}" for w in words)
             for u, t, a, words, _s, _v in C_SERVER_WORDS]
    proc = subprocess.Popen([str(c_server_binary), "0", *specs], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()  # "ready PORT"; the server's alarm(60) bounds this
        m = re.fullmatch(r"ready (\d+)\n", line)
        assert m, (line, proc.stderr.read() if proc.poll() is not None else "")
        port = int(m.group(1))

        async def main():
            tm = load_tagmap().with_endpoint("127.0.0.1", port).with_settings(**FAST)
            poller = ModbusPoller(tm, _no_sink)
            try:
                return await poller.scan_once(), await poller.scan_once()
            finally:
                poller.close()

        first, second = run(main())
    finally:
        proc.terminate()
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=5)
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)
    _, stderr = proc.communicate()  # the rest of its output, and its pipes closed
    for scan in (first, second):
        assert scan.quality == {}
        for _u, _t, _a, _w, sig, si in C_SERVER_WORDS:
            assert scan.body[sig] == pytest.approx(si, rel=1e-9, abs=1e-12), sig
    assert "writes 0" in stderr or stderr == ""  # the C server counts writes too


async def _no_sink(time_ns, body, quality) -> None:
    return None


def _words(fmt: str, value: float) -> list[int]:
    """Big-endian register words of ``value`` packed with struct (an oracle for the codec)."""
    raw = struct.pack(fmt, value)
    return [int.from_bytes(raw[i:i + 2], "big") for i in range(0, len(raw), 2)]


async def _mbpoll(*args: str) -> tuple[int, str]:
    proc = await asyncio.create_subprocess_exec(
        "mbpoll", "-m", "tcp", "-0", "-1", "-o", "2", *args,
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT)
    try:
        out, _ = await asyncio.wait_for(proc.communicate(), 10)
    except TimeoutError:
        proc.kill()
        await proc.wait()
        raise
    return proc.returncode, out.decode()


def _values(out: str) -> dict[int, str]:
    return {int(a): v for a, v in re.findall(r"^\[(\d+)\]:\s+(\S+)\s*$", out, re.M)}


@pytest.mark.mbpoll
@pytest.mark.skipif(shutil.which("mbpoll") is None,
                    reason="mbpoll not installed (apt-get install mbpoll)")
def test_mbpoll_reads_the_simulated_plc():
    async def main():
        tm = load_tagmap()
        async with PlcServer(tm, constant_values(NOMINAL_VALUES)) as plc:
            p = ["-p", str(plc.port), "127.0.0.1"]
            got = {
                # float32 ABCD (mbpoll -B) and CDAB (mbpoll's default word order), degC
                "abcd": await _mbpoll("-a", "1", "-t", "3:float", "-B", "-r", "0", "-c", "2", *p),
                "cdab": await _mbpoll("-a", "1", "-t", "3:float", "-r", "4", "-c", "1", *p),
                # raw words: BADC float32, float64, DCBA float32 and uint32 on unit 2
                "hex1": await _mbpoll("-a", "1", "-t", "3:hex", "-r", "6", "-c", "8", *p),
                "hex2": await _mbpoll("-a", "2", "-t", "3:hex", "-r", "0", "-c", "4", *p),
                # int32 CDAB and 16-bit holding registers
                "int32": await _mbpoll("-a", "1", "-t", "4:int", "-r", "100", "-c", "1", *p),
                "int16": await _mbpoll("-a", "1", "-t", "4", "-r", "102", "-c", "3", *p),
            }
            write = await _mbpoll("-a", "1", "-t", "4", "-r", "102", *p, "--", "7")
            after = await _mbpoll("-a", "1", "-t", "4", "-r", "102", "-c", "1", *p)
            return got, write, after, plc.write_requests

    got, write, after, writes = run(main())
    for rc, out in got.values():
        assert rc == 0, out
    v = {k: _values(out) for k, (_rc, out) in got.items()}
    nv = NOMINAL_VALUES
    assert float(v["abcd"][0]) == pytest.approx(nv["T_air_in"] - 273.15, abs=1e-4)
    assert float(v["abcd"][2]) == pytest.approx(nv["T_dryer_out"] - 273.15, abs=1e-4)
    assert float(v["cdab"][4]) == pytest.approx(nv["T_cyclone_out"] - 273.15, abs=1e-4)
    hex1 = [int(v["hex1"][a], 16) for a in range(6, 14)]
    abcd = _words(">f", nv["T_fiber_in"] - 273.15)
    assert hex1[0:2] == [((w & 0xFF) << 8) | (w >> 8) for w in abcd]  # BADC
    assert hex1[2:4] == [0, 0]  # unused registers 8-9
    assert hex1[4:8] == _words(">d", nv["T_sp"])  # float64 ABCD, K
    hex2 = [int(v["hex2"][a], 16) for a in range(4)]
    assert hex2[0:2] == _words("<f", (nv["T_amb"] - 273.15) * 9 / 5 + 32)  # DCBA, degF
    assert hex2[2:4] == _words(">I", round(nv["H_amb"] * 1000 / 0.001))  # uint32, 0.001 g/kg
    assert int(v["int32"][100]) == round(nv["m_air"] * 3600)  # kg/h
    assert [int(v["int16"][a]) for a in (102, 103, 104)] == [
        round(nv["m_fiber"] * 3.6 / 0.01), round(nv["m_steam"] / 0.001),
        round(nv["flap_cmd"] / 0.1)]
    # mbpoll's write is refused (exception 1) and counted; the value stays
    assert write[0] != 0 and "Illegal function" in write[1]
    assert writes == 1
    assert int(_values(after[1])[102]) == round(nv["m_fiber"] * 3.6 / 0.01)
