"""The web page's HTTP server (``softsensor/outputs/deadline_http.py``, issue 31 item 3) read
by real clients (http.client and raw sockets on 127.0.0.1): ``/healthz`` never waits behind a
page being drawn, a header has a size limit, only GET and HEAD are served, a handler that fails
answers 500 and the server goes on, and a busy port is an ``OSError`` before any thread."""

from __future__ import annotations

import http.client
import socket
import threading
import time

import pytest

from softsensor.outputs.deadline_http import DeadlineHTTPServer, Response


def _server(**kw) -> tuple[DeadlineHTTPServer, threading.Event]:
    release = threading.Event()

    def handler(target: str) -> Response:
        if target == "/slow":  # a page that takes long to draw
            release.wait(10)
            return Response(200, "text/plain", "drawn\n")
        if target == "/fail":
            raise ValueError("cannot draw")
        if target == "/healthz":
            return Response(200, "text/plain", "ok\n")
        return Response(404, "text/plain", "not found\n")

    server = DeadlineHTTPServer("127.0.0.1", 0, handler, inline=("/healthz",), **kw)
    server.start()
    return server, release


def _request(port: int, method: str, path: str, timeout: float = 5.0) -> tuple[int, bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    try:
        conn.request(method, path)
        r = conn.getresponse()
        return r.status, r.read()
    finally:
        conn.close()


def test_healthz_does_not_wait_behind_pages_being_drawn():
    server, release = _server(workers=1, max_connections=8)
    slow: list[tuple[int, bytes]] = []
    drawing = [threading.Thread(target=lambda: slow.append(_request(server.port, "GET",
                                                                      "/slow")))
               for _ in range(2)]  # the one worker busy, one more page waiting for it
    try:
        for t in drawing:
            t.start()
        time.sleep(0.3)
        t0 = time.monotonic()
        assert _request(server.port, "GET", "/healthz", timeout=2) == (200, b"ok\n")
        assert time.monotonic() - t0 < 0.5
        assert not slow  # the pages were still being drawn
        release.set()
        for t in drawing:
            t.join(10)
        assert slow == [(200, b"drawn\n")] * 2
    finally:
        release.set()
        server.stop()


def test_bad_requests_get_one_clear_status_and_the_server_goes_on():
    server, _release = _server(workers=2, max_connections=8, max_header_bytes=1024)
    try:
        assert _request(server.port, "POST", "/healthz")[0] == 405
        assert _request(server.port, "GET", "/fail") == (500, b"internal error\n")
        status, body = _request(server.port, "HEAD", "/healthz")
        assert status == 200 and body == b""
        with socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
            s.sendall(b"GET / HTTP/1.1\r\nX: " + b"y" * 2000 + b"\r\n\r\n")
            assert s.recv(100).startswith(b"HTTP/1.1 431 ")
        with socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
            s.sendall(b"nonsense\r\n\r\n")
            assert s.recv(100).startswith(b"HTTP/1.1 400 ")
        assert _request(server.port, "GET", "/healthz") == (200, b"ok\n")
    finally:
        server.stop()


def test_a_busy_port_is_an_oserror_and_leaves_no_thread():
    with socket.create_server(("127.0.0.1", 0)) as taken:
        threads = threading.active_count()
        server = DeadlineHTTPServer("127.0.0.1", taken.getsockname()[1],
                                    lambda _t: Response(200, "text/plain", ""))
        with pytest.raises(OSError):
            server.start()
        server.stop()  # harmless after a failed start
        assert threading.active_count() == threads
