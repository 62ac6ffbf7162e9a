"""Fault injection (issue 40, the fourth probe): the Modbus output's connections kept in
bounds, probed with raw sockets on 127.0.0.1.

Before: idle connections were never closed and had no limit (2,000 idle clients held 2,036
descriptors), two requests in one TCP segment got one answer (1,000 pipelined: none within
5 s), a bad count or a truncated PDU got ``80 01``, and a read addressed to unit 0 or 255
logged a pymodbus traceback with a frame dump of the daemon's own PLC polling.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import struct
import threading
import time

from softsensor.outputs.modbus_protocol import frame
from softsensor.outputs.modbus_server import N_REGISTERS, EstimateModbusServer
from softsensor.outputs.settings import ModbusOutputSettings
from softsensor.presentation.display import DisplaySettings


@contextlib.contextmanager
def _server(**settings):
    server = EstimateModbusServer(ModbusOutputSettings(enabled=True, port=0, **settings),
                                  DisplaySettings())
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    try:
        asyncio.run_coroutine_threadsafe(server.start(), loop).result(10)
        yield server
    finally:
        asyncio.run_coroutine_threadsafe(server.stop(), loop).result(10)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
        loop.close()


def _read(tid: int, count: int = N_REGISTERS, unit: int = 1) -> bytes:
    return frame(tid, unit, struct.pack(">BHH", 4, 0, count))


def _answers(s: socket.socket, n: int) -> list[tuple[int, bytes]]:
    out = []
    for _ in range(n):
        head = s.recv(7, socket.MSG_WAITALL)
        assert len(head) == 7, f"{len(out)} answers of {n}"
        tid, _proto, length, _unit = struct.unpack(">HHHB", head)
        out.append((tid, s.recv(length - 1, socket.MSG_WAITALL)))
    return out


def _closed_by_peer(s: socket.socket, within_s: float) -> bool:
    s.settimeout(within_s)
    try:
        return s.recv(1) == b""
    except TimeoutError:
        return False
    except ConnectionResetError:
        return True


def test_pipelined_requests_in_one_segment_are_all_answered_in_order():
    with _server() as server, socket.create_connection(("127.0.0.1", server.port),
                                                       timeout=5) as s:
        s.sendall(b"".join(_read(tid) for tid in range(1, 1001)))
        started = time.monotonic()
        got = _answers(s, 1000)
        assert time.monotonic() - started < 5
    assert [tid for tid, _ in got] == list(range(1, 1001))
    assert all(pdu[:2] == bytes([4, 2 * N_REGISTERS]) for _, pdu in got)


def test_bad_counts_truncated_pdus_and_other_units_get_their_codes_without_a_log_line(caplog):
    caplog.set_level(logging.DEBUG)
    with _server() as server, socket.create_connection(("127.0.0.1", server.port),
                                                       timeout=5) as s:
        s.sendall(_read(1, count=0) + _read(2, count=2000)
                  + frame(3, 1, bytes([4, 0, 0, 0])) + _read(4, unit=0) + _read(5, unit=2)
                  + _read(6, unit=255))
        got = dict(_answers(s, 6))
    assert got.pop(6)[:2] == bytes([4, 2 * N_REGISTERS])  # 255: the device addressed by IP
    assert got == {1: b"\x84\x03", 2: b"\x84\x03", 3: b"\x84\x03", 4: b"\x84\x0b",
                   5: b"\x84\x0b"}
    assert server.refused == 5
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_an_idle_connection_is_closed_and_a_polling_one_kept():
    with _server(idle_timeout_s=0.4) as server:
        idle = socket.create_connection(("127.0.0.1", server.port), timeout=5)
        polling = socket.create_connection(("127.0.0.1", server.port), timeout=5)
        with idle, polling:
            for tid in range(12):  # 1.2 s of polls, three idle timeouts
                polling.sendall(_read(tid))
                assert _answers(polling, 1)[0][0] == tid
                time.sleep(0.1)
            assert _closed_by_peer(idle, 1.0)
            assert server.idle_closed == 1 and server.connections == 1


def test_connections_beyond_the_cap_close_the_idlest_and_the_dcs_keeps_reading():
    with _server(max_connections=8) as server:
        dcs = socket.create_connection(("127.0.0.1", server.port), timeout=5)
        idle = []
        with dcs:
            for i in range(200):
                idle.append(socket.create_connection(("127.0.0.1", server.port), timeout=5))
                if i % 20 == 0:  # the DCS polls through the flood
                    dcs.sendall(_read(i))
                    assert _answers(dcs, 1)[0][0] == i
            time.sleep(0.2)
            assert server.connections <= 8
            assert server.evicted >= 192
            dcs.sendall(_read(999))
            assert _answers(dcs, 1)[0][0] == 999
            assert _closed_by_peer(idle[0], 1.0)
        for s in idle:
            s.close()


def _from(address: str, port: int) -> socket.socket:
    """A connection from ``address`` (any of 127.0.0.0/8 on Linux's loopback)."""
    return socket.create_connection(("127.0.0.1", port), timeout=5,
                                    source_address=(address, 0))


def _still_open(s: socket.socket) -> bool:
    """Whether the server has not closed ``s`` (closed ones are closed here too)."""
    closed = _closed_by_peer(s, 0.05)
    s.settimeout(5)
    if closed:
        s.close()
    return not closed


def test_a_peer_holding_busy_connections_evicts_its_own_not_the_dcs():
    """Issue 49 (fifth probe): a peer keeping 31 busy connections and opening one every 0.5 s
    got the DCS evicted before every poll (the DCS had waited longest); now the address
    with the most connections gives one up."""
    with _server(max_connections=8) as server:
        dcs = _from("127.0.0.2", server.port)
        peer: list[socket.socket] = []
        answered = 0
        try:
            for tid in range(1, 11):
                dcs.sendall(_read(tid))
                answered += _answers(dcs, 1)[0][0] == tid
                for s in peer:  # the peer's connections busy after the DCS's poll
                    s.sendall(_read(tid))
                    _answers(s, 1)
                for _ in range(8 - len(peer) if tid == 1 else 2):  # then new ones
                    peer.append(_from("127.0.0.1", server.port))
                    peer[-1].sendall(_read(tid))
                    _answers(peer[-1], 1)
                peer = [s for s in peer if _still_open(s)]
            assert answered == 10
            assert server.evicted >= 18 and server.connections <= 8
        finally:
            dcs.close()
            for s in peer:
                s.close()


def test_the_plant_clients_are_never_evicted_for_a_stranger():
    with _server(max_connections=4, plant_clients=("127.0.0.2",)) as server:
        plant = [_from("127.0.0.2", server.port) for _ in range(3)]
        stranger = _from("127.0.0.3", server.port)
        try:
            for s in (*plant, stranger):
                s.sendall(_read(1))
                _answers(s, 1)
            with _from("127.0.0.4", server.port) as other:  # the stranger's slot
                other.sendall(_read(2))
                assert _answers(other, 1)[0][0] == 2
                assert _closed_by_peer(stranger, 1.0)
                for s in plant:
                    s.sendall(_read(3))
                    assert _answers(s, 1)[0][0] == 3
                plant.append(_from("127.0.0.2", server.port))  # a plant client: other goes
                assert _closed_by_peer(other, 1.0)
            with _from("127.0.0.5", server.port) as late:  # only plant clients: refused
                assert _closed_by_peer(late, 1.0)
            for s in plant:
                s.sendall(_read(4))
                assert _answers(s, 1)[0][0] == 4
        finally:
            stranger.close()
            for s in plant:
                s.close()


def test_bytes_that_never_make_a_request_do_not_keep_a_connection_open():
    """Issue 49 (fifth probe): the idle timeout was reset by any byte, so a client trickling
    one byte of a never-finished frame every few seconds held its slot for ever; idle is now
    measured from the last request."""
    with _server(idle_timeout_s=0.4) as server, \
            socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
        s.sendall(struct.pack(">HHHB", 1, 0, 254, 1))  # a header promising 253 bytes
        closed_at = None
        t0 = time.monotonic()
        while time.monotonic() - t0 < 2.0:
            try:
                s.sendall(b"\x00")
            except OSError:
                closed_at = time.monotonic() - t0
                break
            if _closed_by_peer(s, 0.1):
                closed_at = time.monotonic() - t0
                break
        assert closed_at is not None and closed_at < 1.5, closed_at
        assert server.idle_closed == 1


def test_the_abuse_counters_are_in_metrics_and_health(tmp_path):
    """Issue 49 (fifth probe): the counters of refused requests, framing errors, evictions
    and idle closes were exported nowhere."""
    import asyncio as aio

    from clients import scrape_metrics
    from daemon_harness import running_daemon

    got: dict = {}
    outputs = ("[outputs.modbus]\nenabled = true\nport = 0\nmax_connections = 2\n"
               "[outputs.prometheus]\nenabled = true\nport = 0\n")

    def abuse(port: int) -> None:
        with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
            s.sendall(frame(1, 1, struct.pack(">BHH", 6, 0, 1)))  # a write: exception 1
            assert _answers(s, 1)[0][1] == b"\x86\x01"
        with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
            s.sendall(struct.pack(">HHHB", 1, 9, 6, 1))  # protocol id 9: closed
            assert _closed_by_peer(s, 2.0)
        held = [socket.create_connection(("127.0.0.1", port), timeout=5) for _ in range(3)]
        time.sleep(0.3)  # the third evicted one of the first two
        for s in held:
            s.close()

    async def run() -> None:
        async with running_daemon(tmp_path, ticks=0, config_extra=outputs) as r:
            out = r.daemon.outputs
            await aio.to_thread(abuse, out["modbus"].port)
            got["metrics"] = await aio.to_thread(scrape_metrics, out["prometheus"].port)
            got["health"] = r.daemon._health_answer()["abuse"]

    aio.run(aio.wait_for(run(), 120))
    m = got["metrics"]
    assert m["softsensor_modbus_refused_total"] == 1.0, m
    assert m["softsensor_modbus_framing_errors_total"] == 1.0
    assert m["softsensor_modbus_evicted_total"] >= 1.0
    assert "softsensor_modbus_idle_closed_total" in m
    assert got["health"]["modbus"]["refused"] == 1 and got["health"]["modbus"]["evicted"] >= 1
