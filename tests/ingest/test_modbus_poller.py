"""The poller against the simulated PLC on 127.0.0.1 (free ports chosen at run time).

Every test runs under ``asyncio.wait_for`` with a deadline, so a hang fails instead of blocking.
"""

import ast
import asyncio
import json
from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTcpClient

from softsensor.ingest import modbus_poller
from softsensor.ingest.modbus_poller import ModbusPoller, Scan
from softsensor.ingest.registers import resolution
from softsensor.ingest.tagmap import TagMap, load_tagmap, parse_tagmap
from softsensor.plant.plc_server import NOMINAL_VALUES, PlcServer, constant_values

FAST = {"poll_period_s": 0.05, "timeout_s": 0.3, "retries": 0, "reconnect_delay_s": 0.05,
        "reconnect_delay_max_s": 0.2, "frozen_after_s": 3600.0}


def run(coro, timeout: float = 20.0):
    """Run ``coro`` in a fresh event loop, failing after ``timeout`` seconds."""
    return asyncio.run(asyncio.wait_for(coro, timeout))


async def wait_until(predicate, timeout: float, what: str) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not predicate():
        if loop.time() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.01)


def fast(tm: TagMap, server: PlcServer, **changes) -> TagMap:
    return tm.with_endpoint("127.0.0.1", server.port).with_settings(**{**FAST, **changes})


async def no_sink(time_ns, body, quality) -> None:
    return None


def assert_close(body, tm: TagMap, expected: dict[str, float]) -> None:
    for sig, si in expected.items():
        assert body[sig] is not None, sig
        assert abs(body[sig] - si) <= resolution(tm.tag(sig), si), (sig, body[sig], si)


def test_default_tagmap_arrives_in_si():
    async def main():
        tm = load_tagmap()
        async with PlcServer(tm, constant_values(NOMINAL_VALUES)) as plc:
            poller = ModbusPoller(fast(tm, plc), no_sink)
            scan = await poller.scan_once()
            poller.close()
        assert isinstance(scan, Scan) and scan.quality == {}
        assert list(scan.body) == list(tm.signals)
        assert_close(scan.body, tm, NOMINAL_VALUES)
        assert poller.stats.reads == 3
        assert plc.write_requests == 0 and plc.requests == 3

    run(main())


def _all_types_map(word: str, byte: str) -> TagMap:
    def tag(unit_id, table, address, dtype, unit, scale=1.0, offset=0.0, lo=-1e6, hi=1e6):
        return {"unit_id": unit_id, "table": table, "address": address, "type": dtype,
                "word_order": word, "byte_order": byte, "scale": scale, "offset": offset,
                "unit": unit, "valid_min": lo, "valid_max": hi}

    tags = {
        "T_air_in": tag(1, "input", 0, "float32", "degC"),
        "T_sp": tag(1, "input", 2, "float64", "K"),
        "T_amb": tag(1, "input", 8, "int16", "degC", 0.1),  # negative raw
        "T_dryer_out": tag(1, "input", 9, "int32", "degF", 0.01, 300.0),  # negative raw
        "m_air": tag(1, "holding", 0, "int32", "kg/h"),
        "m_fiber": tag(1, "holding", 2, "uint16", "t/h", 0.01),
        "m_steam": tag(2, "holding", 40, "int16", "kg/s", 0.001),
        "H_amb": tag(2, "input", 7, "uint32", "g/kg", 0.001),
        "T_cyclone_out": tag(2, "input", 20, "float64", "degF"),
    }
    return parse_tagmap({"modbus": {"host": "127.0.0.1", "port": 1}, "tags": tags}, "test")


ALL_TYPES_VALUES = {"T_air_in": 512.34, "T_sp": 348.15, "T_amb": 268.0, "T_dryer_out": 348.0,
                    "m_air": 82.5, "m_fiber": 6.1, "m_steam": 0.512, "H_amb": 0.0081,
                    "T_cyclone_out": 338.2}


@pytest.mark.parametrize(("word", "byte"), [("big", "big"), ("little", "big"),
                                            ("big", "little"), ("little", "little")])
def test_every_data_type_and_order_arrives(word, byte):
    async def main():
        tm = _all_types_map(word, byte)
        async with PlcServer(tm, constant_values(ALL_TYPES_VALUES)) as plc:
            poller = ModbusPoller(fast(tm, plc), no_sink)
            scan = await poller.scan_once()
            poller.close()
        assert scan.quality == {}
        assert_close(scan.body, tm, ALL_TYPES_VALUES)
        assert plc.write_requests == 0

    run(main())


def test_bad_values_are_none_with_a_reason():
    async def main():
        tm = load_tagmap()
        values = dict(NOMINAL_VALUES, T_dryer_out=500.0)  # above valid_max 450 K
        async with PlcServer(tm, constant_values(values)) as plc:
            await plc.set_raw("T_air_in", [0x7FC0, 0x0000])  # float32 NaN, ABCD
            await plc.set_raw("T_cyclone_out", [0x0000, 0x7F80])  # float32 +inf, CDAB
            plc.inject_fault("m_fiber")  # its reads answer exception 4
            poller = ModbusPoller(fast(tm, plc), no_sink)
            scan = await poller.scan_once()
            poller.close()
        q = scan.quality
        assert set(q) == {"T_air_in", "T_cyclone_out", "T_dryer_out", "m_fiber"}
        assert all(scan.body[s] is None for s in q)
        assert q["T_air_in"] == "not_finite: nan"
        assert q["T_cyclone_out"] == "not_finite: inf"
        assert q["T_dryer_out"] == "out_of_range: 500 K outside [280, 450]"
        assert q["m_fiber"].startswith("exception_reply: code 4 (device failure)")
        # the failed group read was retried tag by tag: neighbours of m_fiber are fine
        good = {s: v for s, v in NOMINAL_VALUES.items() if s not in q}
        assert_close(scan.body, tm, good)
        assert "null" in json.dumps(scan.body)
        assert plc.write_requests == 0

    run(main())


def test_frozen_values_are_flagged_after_the_limit():
    async def main():
        tm = load_tagmap()
        now = [1000.0]
        async with PlcServer(tm, constant_values(NOMINAL_VALUES)) as plc:
            poller = ModbusPoller(fast(tm, plc, frozen_after_s=300.0), no_sink,
                                  monotonic=lambda: now[0])
            first = await poller.scan_once()
            now[0] += 299.0
            within = await poller.scan_once()
            now[0] += 2.0
            frozen = await poller.scan_once()
            await plc.set_values({"T_air_in": 501.0})  # moves: good again at once
            moved = await poller.scan_once()
            poller.close()
        assert first.quality == {} and within.quality == {}
        # every signal froze except the set point, whose check is disabled in the tag map
        assert set(frozen.quality) == set(tm.signals) - {"T_sp"}
        assert frozen.quality["m_air"] == "frozen: unchanged for 301 s (limit 300 s)"
        assert frozen.body["m_air"] is None and frozen.body["T_sp"] is not None
        assert "T_air_in" not in moved.quality and moved.body["T_air_in"] == pytest.approx(501.0)

    run(main())


def test_unknown_unit_id_is_an_exception_reply():
    async def main():
        tm = load_tagmap()
        async with PlcServer(tm, constant_values(NOMINAL_VALUES)) as plc:
            data = {"modbus": {"host": "127.0.0.1", "port": plc.port},
                    "tags": {"H_amb": {"unit_id": 9, "table": "input", "address": 2,
                                       "type": "uint32", "unit": "g/kg", "scale": 0.001,
                                       "valid_min": 0.0, "valid_max": 0.05}}}
            poller = ModbusPoller(parse_tagmap(data).with_settings(**FAST), no_sink)
            scan = await poller.scan_once()
            poller.close()
        assert scan.body == {"H_amb": None}
        assert scan.quality["H_amb"].startswith("exception_reply: code ")

    run(main())


def test_server_restart_mid_run_is_a_marked_gap():
    async def main():
        tm = load_tagmap()
        tick = [0]

        def moving():  # values that change every update, so nothing looks frozen
            tick[0] += 1
            return dict(NOMINAL_VALUES, T_air_in=500.0 + 0.01 * (tick[0] % 100))

        plc = PlcServer(tm, moving, period_s=0.05)
        await plc.start()
        scans: list[Scan] = []

        async def sink(time_ns, body, quality):
            scans.append(Scan(time_ns, body, quality))

        poller = ModbusPoller(fast(tm, plc), sink)
        stop = asyncio.Event()
        task = asyncio.create_task(poller.run(stop))
        try:
            await wait_until(lambda: len(scans) >= 3, 5, "first scans")
            await plc.stop()
            n_stop = len(scans)
            await wait_until(lambda: len(scans) >= n_stop + 4, 5, "scans during the outage")
            await plc.start()  # same port
            n_restart = len(scans)
            await wait_until(lambda: any(not s.quality for s in scans[n_restart:]), 5,
                             "reconnection")
            await wait_until(lambda: len(scans) >= n_restart + 8, 5, "scans after restart")
            stop.set()
            await asyncio.wait_for(task, 2)
        finally:
            stop.set()
            await plc.stop()
        assert task.done() and task.exception() is None
        assert all(not s.quality for s in scans[:n_stop - 1])
        gap = [s for s in scans[n_stop:n_restart] if s.quality]
        assert len(gap) >= 3
        for s in gap:  # the whole scan is marked, never a stale number
            assert all(v is None for v in s.body.values())
            assert set(s.quality) == set(tm.signals)
            assert all(r.split(":")[0] in ("not_connected", "no_response")
                       for r in s.quality.values())
        assert not scans[-1].quality
        assert_close(scans[-1].body, tm, {k: v for k, v in NOMINAL_VALUES.items()
                                          if k != "T_air_in"})
        times = [s.time_ns for s in scans]
        assert times == sorted(times)
        assert poller.stats.connects >= 2 and poller.stats.sink_failures == 0
        assert plc.write_requests == 0 and plc.requests > 0

    run(main(), timeout=30)


def test_unreachable_plc_backs_off_then_connects():
    async def main():
        tm = load_tagmap()
        plc = PlcServer(tm, constant_values(NOMINAL_VALUES))
        await plc.start()
        await plc.stop()  # a port nobody listens on now
        now = [0.0]
        poller = ModbusPoller(fast(tm, plc, reconnect_delay_s=1.0, reconnect_delay_max_s=4.0),
                              no_sink, monotonic=lambda: now[0])
        attempts = []
        for t in (0.0, 0.5, 1.0, 2.0, 3.0, 7.0, 10.0, 11.0, 15.0):
            now[0] = t
            scan = await poller.scan_once()
            attempts.append(poller.stats.connect_attempts)
            assert all(v is None for v in scan.body.values())
            assert all(r.startswith("not_connected: ") for r in scan.quality.values())
        # attempts at 0, 1 (+1 s), 3 (+2 s), 7 (+4 s), 11 (+4 s, capped), 15
        assert attempts == [1, 1, 2, 2, 3, 4, 4, 5, 6]
        await plc.start()
        try:
            now[0] = 19.0
            scan = await poller.scan_once()
        finally:
            poller.close()
            await plc.stop()
        assert scan.quality == {}
        assert_close(scan.body, tm, NOMINAL_VALUES)

    run(main())


def test_run_survives_a_failing_sink_and_stops_promptly():
    async def main():
        tm = load_tagmap()
        calls = []

        async def bad_sink(time_ns, body, quality):
            calls.append(time_ns)
            raise RuntimeError("sink broken")

        async with PlcServer(tm, constant_values(NOMINAL_VALUES)) as plc:
            poller = ModbusPoller(fast(tm, plc), bad_sink)
            stop = asyncio.Event()
            task = asyncio.create_task(poller.run(stop))
            await wait_until(lambda: len(calls) >= 3, 5, "three scans")
            stop.set()
            await asyncio.wait_for(task, 1.0)
        assert poller.stats.sink_failures == len(calls)
        assert not poller.connected

    run(main())


def test_plc_counts_and_refuses_write_requests():
    """The write counter the other tests rely on does see writes (FC 5, 6, 15, 16, 22, 23)."""
    async def main():
        tm = load_tagmap()
        async with PlcServer(tm, constant_values(NOMINAL_VALUES)) as plc:
            client = AsyncModbusTcpClient("127.0.0.1", port=plc.port, timeout=1, retries=0)
            await client.connect()
            replies = [
                await client.write_register(102, 1, device_id=1),
                await client.write_registers(100, [1, 2], device_id=1),
                await client.write_coil(0, True, device_id=1),
                await client.write_coils(0, [True], device_id=1),
                await client.mask_write_register(address=103, and_mask=0, or_mask=1,
                                                 device_id=1),
                await client.readwrite_registers(read_address=100, read_count=1,
                                                 write_address=100, values=[1], device_id=1),
            ]
            client.close()
            poller = ModbusPoller(fast(tm, plc), no_sink)
            scan = await poller.scan_once()
            poller.close()
        assert all(r.isError() and r.exception_code == 1 for r in replies)
        assert plc.write_requests == 6
        assert_close(scan.body, tm, NOMINAL_VALUES)  # nothing was overwritten

    run(main())


def test_poller_source_calls_only_read_functions():
    """Structural guarantee: the poller module never calls a Modbus write method."""
    tree = ast.parse(Path(modbus_poller.__file__).read_text())
    client_calls = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            target = node.func.value
            if isinstance(target, ast.Attribute) and target.attr == "_client":
                client_calls.add(node.func.attr)
        if isinstance(node, ast.Attribute):
            assert "write" not in node.attr.lower(), node.attr
    assert client_calls == {"read_holding_registers", "read_input_registers", "connect",
                            "close"}
