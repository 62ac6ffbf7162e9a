"""A small read-only HTTP/1.1 server that slow clients cannot silence (issue 31 item 3).

The stdlib's ``HTTPServer`` hands a connection to a thread before its request has arrived, and
its socket timeout restarts with every byte: eight clients sending one header byte every 8 s
held all eight threads, and ``/healthz`` timed out behind them. Here one event-loop thread
reads every request's header, and only a complete request reaches a worker:

* a request's whole header must arrive within ``header_timeout_s`` of the connection's accept
  (a deadline, not an idle timeout: trickling bytes does not extend it) and within
  ``max_header_bytes``;
* at most ``max_connections`` are open; a new connection when all are taken closes the oldest
  one still sending its header (a real client sends its header in one packet, so only a slow
  one is ever that old), or is closed itself when every connection is already being answered;
* paths in ``inline`` (``/healthz``) are answered on the loop thread at once, so a container's
  health check never waits behind a slow client nor behind a page being drawn; every other
  answer is computed by one of ``workers`` threads;
* a response not taken by the client within ``header_timeout_s`` is dropped.

One request per connection (``Connection: close``): the page reloads every tens of seconds,
so keeping connections alive would only let idle ones hold slots. Why not uvicorn: its only
timeout is the keep-alive one, restarted by every received byte (Kludex/uvicorn#157 lists a
header deadline as not done), which is the fault this module removes.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import threading
import time
from collections.abc import Callable, Collection
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from http import HTTPStatus
from urllib.parse import urlsplit

from softsensor.log_throttle import Throttle, outside_text

log = logging.getLogger(__name__)

#: The kernel's queue before accept: a burst of connections waits there to be sorted.
LISTEN_BACKLOG = 128


@dataclass(frozen=True)
class Response:
    """What a handler answers: status, content type and body (UTF-8 text or bytes)."""

    code: int
    kind: str
    text: str | bytes


#: ``handler(path_with_query) -> Response``: called for GET and HEAD alike.
Handler = Callable[[str], Response]


class _Conn:
    """One accepted connection: its writer, task and whether its header is still awaited."""

    __slots__ = ("reading", "sock", "task", "writer")

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.reading = True
        self.task: asyncio.Task | None = None
        self.writer: asyncio.StreamWriter | None = None


class DeadlineHTTPServer:
    """Serve ``handler`` on ``host:port`` (module docstring); :meth:`start`, :meth:`stop`.

    Parameters
    ----------
    host, port : str, int
        Where to listen; port 0 takes any free port (then read ``port``).
    handler : callable
        ``handler(target) -> Response`` for a GET or HEAD of ``target`` (path and query).
    inline : collection of str
        Paths answered on the loop thread (cheap, lock-free answers such as ``/healthz``).
    workers : int
        Threads computing the other answers.
    max_connections : int
        Connections open at once.
    header_timeout_s : float
        Deadline for a request's whole header, and for the client taking the response [s].
    max_header_bytes : int
        Longest request header accepted (431 beyond it).
    """

    def __init__(self, host: str, port: int, handler: Handler, *,
                 inline: Collection[str] = (), workers: int = 8, max_connections: int = 40,
                 header_timeout_s: float = 10.0, max_header_bytes: int = 8192) -> None:
        self.host, self.port, self.handler = host, port, handler
        self.inline = frozenset(inline)
        self.workers, self.max_connections = workers, max_connections
        self.header_timeout_s, self.max_header_bytes = header_timeout_s, max_header_bytes
        self.refused = 0  #: connections closed unanswered because every slot was taken
        self.expired = 0  #: connections closed because their header missed the deadline
        self.answered = 0  #: responses sent
        self._open: dict[_Conn, None] = {}  # insertion order: the oldest first
        self._sock: socket.socket | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._pool: ThreadPoolExecutor | None = None
        self._stop: asyncio.Event | None = None
        self._throttle = Throttle()

    # -- life cycle (caller's thread) ------------------------------------------------------
    def start(self) -> None:
        """Bind (an ``OSError`` such as a busy port is raised here, before any thread) and
        serve from a loop thread."""
        self._sock = socket.create_server((self.host, self.port), backlog=LISTEN_BACKLOG)
        self._sock.setblocking(False)
        self.port = self._sock.getsockname()[1]
        self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix="web")
        self._loop = asyncio.new_event_loop()
        ready = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(ready,), name="web-page",
                                        daemon=True)
        self._thread.start()
        ready.wait(10.0)

    def stop(self) -> None:
        """Close the listener and every connection; wait for the loop thread (5 s at most)."""
        loop, thread = self._loop, self._thread
        if loop is not None and thread is not None and thread.is_alive():
            with contextlib.suppress(RuntimeError):  # the loop already ended
                loop.call_soon_threadsafe(self._request_stop)
            thread.join(5.0)
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
        if self._sock is not None:
            self._sock.close()
        self._loop = self._thread = self._pool = self._sock = None

    def _request_stop(self) -> None:
        if self._stop is not None:
            self._stop.set()

    # -- the loop thread -------------------------------------------------------------------
    def _run(self, ready: threading.Event) -> None:
        loop = self._loop
        assert loop is not None
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._serve(ready))
        finally:
            ready.set()
            loop.close()

    async def _serve(self, ready: threading.Event) -> None:
        self._stop = asyncio.Event()
        accept = asyncio.create_task(self._accept())
        ready.set()
        await self._stop.wait()
        accept.cancel()
        tasks = [c.task for c in self._open if c.task is not None]
        for conn in list(self._open):
            self._drop(conn)
        with contextlib.suppress(asyncio.CancelledError):
            await accept
        if tasks:
            await asyncio.wait(tasks, timeout=2.0)

    async def _accept(self) -> None:
        loop = asyncio.get_running_loop()
        assert self._sock is not None
        while True:
            try:
                sock, _addr = await loop.sock_accept(self._sock)
            except OSError as exc:  # EMFILE and the like: wait, do not spin
                self._throttle.log(log, "accept", logging.WARNING,
                                   "web page: accept failed: %s", exc)
                await asyncio.sleep(0.5)
                continue
            if len(self._open) >= self.max_connections and not self._evict_oldest_reader():
                self.refused += 1
                sock.close()
                continue
            conn = _Conn(sock)
            self._open[conn] = None
            conn.task = loop.create_task(self._client(conn))
            # an accept that finds a connection waiting does not yield: let the new task and
            # the closing of evicted ones run before the next accept
            await asyncio.sleep(0)

    def _evict_oldest_reader(self) -> bool:
        """Close the oldest connection still sending its header; False when there is none."""
        for conn in self._open:
            if conn.reading:
                self.refused += 1
                self._drop(conn)
                return True
        return False

    def _drop(self, conn: _Conn) -> None:
        self._close(conn)
        if conn.task is not None:
            conn.task.cancel()

    def _close(self, conn: _Conn) -> None:
        self._open.pop(conn, None)
        if conn.writer is not None:
            conn.writer.transport.abort()  # the socket closes before the next accept
        else:  # its task has not wrapped the socket yet (and may never run)
            conn.sock.close()

    async def _client(self, conn: _Conn) -> None:
        deadline = time.monotonic() + self.header_timeout_s
        try:
            reader, conn.writer = await asyncio.open_connection(
                sock=conn.sock, limit=self.max_header_bytes)
            try:
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"),
                                              deadline - time.monotonic())
            except TimeoutError:
                self.expired += 1
                return
            except asyncio.LimitOverrunError:
                await self._send(conn.writer, Response(431, "text/plain", "header too long\n"),
                                 True)
                return
            except (asyncio.IncompleteReadError, ConnectionError):
                return
            conn.reading = False
            await self._answer(conn.writer, head)
        except (ConnectionError, TimeoutError, OSError):
            pass  # a client that went away or never took its answer
        finally:
            self._close(conn)

    async def _answer(self, writer: asyncio.StreamWriter, head: bytes) -> None:
        line = head.split(b"\r\n", 1)[0]
        parts = line.split(b" ")
        if len(parts) != 3 or not parts[2].startswith(b"HTTP/1."):
            await self._send(writer, Response(400, "text/plain", "bad request\n"), True)
            return
        method, target = parts[0], parts[1].decode("latin-1")
        if method not in (b"GET", b"HEAD"):
            await self._send(writer, Response(405, "text/plain", "only GET and HEAD\n"), True,
                             extra="Allow: GET, HEAD\r\n")
            return
        try:
            if urlsplit(target).path in self.inline:
                response = self.handler(target)
            else:
                loop = asyncio.get_running_loop()
                assert self._pool is not None
                response = await loop.run_in_executor(self._pool, self.handler, target)
        except Exception:  # noqa: BLE001 - a page that cannot be drawn must not end the server
            self._throttle.log(log, "answer", logging.ERROR, "web page: answering %s failed",
                               outside_text(target), exc_info=True)
            response = Response(500, "text/plain", "internal error\n")
        await self._send(writer, response, method == b"GET")

    async def _send(self, writer: asyncio.StreamWriter, r: Response, body: bool,
                    extra: str = "") -> None:
        data = r.text.encode("utf-8") if isinstance(r.text, str) else r.text
        try:
            reason = HTTPStatus(r.code).phrase
        except ValueError:
            reason = ""
        head = (f"HTTP/1.1 {r.code} {reason}\r\nContent-Type: {r.kind}\r\n"
                f"Content-Length: {len(data)}\r\nCache-Control: no-store\r\n"
                f"Connection: close\r\n{extra}\r\n").encode("latin-1")
        writer.write(head + data if body else head)
        await asyncio.wait_for(writer.drain(), self.header_timeout_s)
        self.answered += 1


__all__ = ["DeadlineHTTPServer", "Handler", "Response"]
