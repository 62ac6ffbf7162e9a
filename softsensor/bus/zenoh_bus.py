"""The live bus: Zenoh sessions, a JSON publisher and subscriber helpers (CONTRACT section 3).

Keys are ``plant/<unit>/scan``, ``plant/<unit>/lab``, ``softsensor/<unit>/estimate`` and
``softsensor/<unit>/health`` (:func:`softsensor.signals.zenoh_key`); payloads are the JSON
bodies of the matching MCAP topics plus ``time_ns``, the event time [ns since epoch, UTC].

Sessions are configured explicitly (:func:`make_config`): peer mode by default, listening on
``127.0.0.1`` only, multicast scouting off, optional ``connect`` endpoints (e.g. a router).
Zenoh runs subscriber callbacks on its own threads; :func:`subscribe` decodes there and calls
the user's callback (which must not block: hand the message on, as the estimator's worker
queues it for its thread). Nothing uses a FIFO channel that could fill up and stall the
session. Always close sessions (``with open_session(...) as s:``): a session left open keeps
the process alive.

:class:`ZenohInput` and :class:`Publisher` are the estimator worker's input and output sides
on Zenoh (:mod:`softsensor.bus.transport`, where the message type and the key kinds live).
"""

from __future__ import annotations

import json
import logging
import re
import socket
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import zenoh

from softsensor.bus.transport import (
    INPUT_KINDS,
    KINDS,
    OUTPUT_KINDS,
    BusMessage,
    Receive,
    encode_payload,
)
from softsensor.errors import ConfigError, IngestError
from softsensor.log_throttle import Throttle, outside_text
from softsensor.signals import zenoh_key

log = logging.getLogger(__name__)

MODES: tuple[str, ...] = ("peer", "client", "router")
DEFAULT_HOST = "127.0.0.1"


# ----------------------------------------------------------------------------------------------
# Configuration and sessions


def output_guard_acl(unit: str) -> dict[str, Any]:
    """Zenoh access control that refuses, from every other session, a ``put``/``delete``
    on ``softsensor/<unit>/**`` (the daemon is the only publisher of its estimates and health
    that it and its recorder accept) and a queryable or reply declared there (a peer answering
    ``softsensor health`` in the daemon's name; the access rules of puts do not stop replies).
    Inputs, subscriptions and queries stay open."""
    return {
        "enabled": True,
        "default_permission": "allow",
        "rules": [{"id": "outputs-are-ours", "permission": "deny", "flows": ["ingress"],
                   "messages": ["put", "delete", "declare_queryable", "reply"],
                   "key_exprs": [f"softsensor/{unit}/**"]}],
        "subjects": [{"id": "every-remote-session"}],
        "policies": [{"rules": ["outputs-are-ours"], "subjects": ["every-remote-session"]}],
    }


def _endpoints(mode: str, port: int | None, host: str, listen: Sequence[str] | None,
               connect: Sequence[str]) -> list[str]:
    """The listen endpoints of :func:`make_config`'s arguments, checked with the connect
    ones (:class:`ConfigError` naming the ``bus`` key that is wrong)."""
    if mode not in MODES:
        raise ConfigError(f"bus.mode must be one of {', '.join(MODES)}, got {mode!r}")
    if listen is None:
        if mode == "client" or port is None:
            listen = []
        else:
            if not 0 <= int(port) <= 65535:
                raise ConfigError(f"bus.port must be in 0..65535, got {port}")
            listen = [f"tcp/{host}:{int(port)}"]
    elif mode == "client" and listen:
        raise ConfigError("bus.listen must be empty in client mode")
    if mode == "client" and not connect:
        raise ConfigError("bus.connect must name a router or peer endpoint in client mode")
    for ep in [*listen, *connect]:
        if "/" not in ep:
            raise ConfigError(f"bus endpoint {ep!r} must look like tcp/127.0.0.1:7447")
    return list(listen)


def make_config(*, mode: str = "peer", port: int | None = 0, host: str = DEFAULT_HOST,
                listen: Sequence[str] | None = None, connect: Sequence[str] = (),
                multicast_scouting: bool = False, adminspace: bool = True,
                user: str | None = None, password: str | None = None,
                users_file: str | None = None, acl: dict[str, Any] | None = None,
                max_message_bytes: int | None = None,
                open_timeout_s: float | None = None) -> zenoh.Config:
    """Build a Zenoh 1.x configuration.

    Parameters
    ----------
    mode : {"peer", "client", "router"}
        Session mode. A ``router`` session routes between ``client`` sessions.
    port : int or None
        TCP port to listen on at ``host`` (0 = any free port); ``None`` = do not listen.
        Ignored when ``listen`` is given; a client never listens.
    host : str
        Listen address; loopback by default (a peer would otherwise listen on every interface).
    listen, connect : sequence of str
        Explicit endpoints such as ``"tcp/127.0.0.1:7447"``.
    multicast_scouting : bool
        Off by default: peers find each other through ``connect`` only.
    adminspace : bool
        Expose the read-only admin space (used by :func:`listening_endpoints`).
    user, password : str, optional
        Zenoh user/password authentication of this session towards the ones it connects to.
    users_file : str, optional
        Zenoh's dictionary file (``user:password`` lines): sessions connecting to this one
        must authenticate as one of them, or are refused.
    acl : dict, optional
        Zenoh's ``access_control`` section (e.g. :func:`output_guard_acl`).
    max_message_bytes : int, optional
        Messages larger than this are dropped by Zenoh on receipt.
    open_timeout_s : float, optional
        Longest wait for a connect endpoint's handshake (Zenoh's default is 10 s, which a
        port that accepts and never answers costs in full).
    """
    listen = _endpoints(mode, port, host, listen, connect)
    keys = [*_session_keys(mode, listen, connect, multicast_scouting, adminspace),
            *_guard_keys(user, password, users_file, acl, max_message_bytes, open_timeout_s)]
    cfg = zenoh.Config()
    try:
        for key, value in keys:
            cfg.insert_json5(key, value)
    except zenoh.ZError as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConfigError(f"bus config rejected by zenoh: {first}") from exc
    return cfg


def _session_keys(mode: str, listen: Sequence[str], connect: Sequence[str],
                  multicast_scouting: bool, adminspace: bool) -> list[tuple[str, str]]:
    """Where a session listens and connects and what it shows (:func:`make_config`): Zenoh
    configuration keys and their JSON5 values, in the order they are inserted."""
    keys = [("mode", json.dumps(mode)),
            ("listen/endpoints", json.dumps(list(listen))),
            ("connect/endpoints", json.dumps(list(connect))),
            ("scouting/multicast/enabled", json.dumps(bool(multicast_scouting))),
            ("adminspace/enabled", json.dumps(bool(adminspace)))]
    if adminspace:
        keys.append(("adminspace/permissions", '{"read": true, "write": false}'))
    # a peer that cannot reach its connect endpoints (refused, wrong password) still
    # opens, and keeps trying, rather than blocking the caller
    if mode == "peer":
        keys += [("connect/timeout_ms", "5000"), ("connect/exit_on_failure", "false")]
    return keys


def _guard_keys(user: str | None, password: str | None, users_file: str | None,
                acl: dict[str, Any] | None, max_message_bytes: int | None,
                open_timeout_s: float | None) -> list[tuple[str, str]]:
    """Who may connect and what a connection may cost (:func:`make_config`): authentication,
    access control, the largest message, the handshake's timeout (after
    :func:`_session_keys`, whose connect timeout it overrides)."""
    keys = []
    auth = {k: v for k, v in (("user", user), ("password", password),
                              ("dictionary_file", users_file)) if v is not None}
    if auth:
        keys.append(("transport/auth/usrpwd", json.dumps(auth)))
    if acl is not None:
        keys.append(("access_control", json.dumps(acl)))
    if max_message_bytes is not None:
        keys.append(("transport/link/rx/max_message_size", str(int(max_message_bytes))))
    if open_timeout_s is not None:
        ms = str(max(1, int(open_timeout_s * 1000)))
        keys += [("transport/unicast/open_timeout", ms), ("connect/timeout_ms", ms)]
    return keys


def open_session(config: zenoh.Config | None = None, **kwargs: Any) -> zenoh.Session:
    """Open a Zenoh session (use it as a context manager so it is always closed).

    Either pass a :class:`zenoh.Config` or the keyword arguments of :func:`make_config`.
    A session that cannot open (port taken, no router reachable) raises :class:`ConfigError`.
    """
    if config is None:
        config = make_config(**kwargs)
    elif kwargs:
        raise TypeError("pass either a zenoh.Config or make_config() keywords, not both")
    try:
        return zenoh.open(config)
    except zenoh.ZError as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        first = re.sub(r"\s+at \S+\.rs:\d+\.?$", "", first)  # zenoh's source location
        raise ConfigError(f"zenoh session could not open: {first}") from exc


def free_port(host: str = DEFAULT_HOST) -> int:
    """A TCP port on ``host`` that was free a moment ago (for tests and ad-hoc routers)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def listening_endpoints(session: zenoh.Session, timeout: float = 2.0) -> list[str]:
    """Endpoints the session listens on (e.g. to learn the port chosen for ``port=0``).

    Needs the admin space (``make_config(adminspace=True)``, the default).
    """
    zid = str(session.zid())
    for reply in session.get(f"@/{zid}/*", timeout=timeout):
        ok = reply.ok
        if ok is None or str(ok.key_expr).count("/") != 2:
            continue
        try:
            info = json.loads(ok.payload.to_bytes())
        except ValueError:
            continue
        if isinstance(info, dict) and "locators" in info:
            return [str(loc) for loc in info["locators"]]
    return []


def wait_for_peers(session: zenoh.Session, n: int = 1, timeout: float = 5.0,
                   *, routers: bool = False) -> bool:
    """Wait up to ``timeout`` [s] until ``n`` peers (or routers) are connected; True if so."""
    deadline = time.monotonic() + timeout
    while True:
        found = session.info.routers_zid() if routers else session.info.peers_zid()
        if len(found) >= n:
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)


# ----------------------------------------------------------------------------------------------
# Payloads (pure)


def decode_payload(data: bytes, key: str = "payload") -> dict[str, Any]:
    """Decode a bus payload into a dict; :class:`IngestError` naming ``key`` if it is not one."""
    try:
        body = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise IngestError(f"{outside_text(key)}: payload is not valid JSON") from exc
    if not isinstance(body, dict):
        raise IngestError(f"{outside_text(key)}: payload is a JSON {type(body).__name__}, "
                          f"not an object")
    return body


def kind_of_key(key: str, unit: str = "dryer1") -> str:
    """Key kind (scan/lab/estimate/health) of a CONTRACT key; :class:`IngestError` otherwise."""
    for kind in KINDS:
        if key == zenoh_key(kind, unit):
            return kind
    raise IngestError(f"{outside_text(key)}: not a softsensor key of unit {unit!r}")


def to_message(key: str, data: bytes, unit: str = "dryer1") -> BusMessage:
    """Decode a sample's key and payload (pure; :class:`IngestError` if malformed)."""
    kind = kind_of_key(key, unit)
    body = decode_payload(data, key)
    t = body.get("time_ns")
    if t is not None and (not isinstance(t, int) or isinstance(t, bool)):
        raise IngestError(f"{outside_text(key)}: time_ns must be an integer, got "
                          f"{outside_text(repr(t))}")
    return BusMessage(kind, key, body, t, len(data))


# ----------------------------------------------------------------------------------------------
# Publishing


class Publisher:
    """Publishes JSON bodies on the CONTRACT keys of one unit (also a worker's output side on
    Zenoh, :class:`~softsensor.bus.transport.OutputSide`).

    ``put(kind, body, time_ns)`` adds ``time_ns`` (the event time [ns since epoch]; the wall
    clock when omitted) and sends the body on ``zenoh_key(kind, unit)``. Close it (or use it as
    a context manager) to undeclare its Zenoh publishers; the session stays open.
    """

    def __init__(self, session: zenoh.Session, unit: str = "dryer1",
                 clock: Callable[[], int] = time.time_ns) -> None:
        self.session = session
        self.unit = unit
        self._clock = clock
        self._pubs: dict[str, zenoh.Publisher] = {}
        self.n_published = 0

    def _pub(self, kind: str) -> zenoh.Publisher:
        pub = self._pubs.get(kind)
        if pub is None:
            key = zenoh_key(kind, self.unit)
            pub = self.session.declare_publisher(
                key, encoding=zenoh.Encoding.APPLICATION_JSON,
                congestion_control=zenoh.CongestionControl.BLOCK)
            self._pubs[kind] = pub
        return pub

    def declare(self, kinds: Iterable[str] = KINDS) -> None:
        """Declare the publishers of ``kinds`` now (so subscribers can be matched early)."""
        for kind in kinds:
            self._pub(kind)

    def put(self, kind: str, body: dict[str, Any], time_ns: int | None = None) -> None:
        """Publish ``body`` on the key of ``kind``, with ``time_ns`` [ns since epoch]."""
        t = self._clock() if time_ns is None else int(time_ns)
        self._pub(kind).put(encode_payload(body, t))
        self.n_published += 1

    def matched(self, kind: str) -> bool:
        """True when some subscriber matches the key of ``kind``."""
        return bool(self._pub(kind).matching_status)

    def wait_matched(self, kinds: Iterable[str] = KINDS, timeout: float = 5.0,
                     settle: float = 0.1) -> bool:
        """Wait up to ``timeout`` [s] until every key of ``kinds`` has a subscriber.

        Zenoh 1.10 reports a match slightly before the route carries data (a put at once is
        lost about every other time on loopback), so this sleeps ``settle`` [s] after the match.
        """
        kinds = list(kinds)
        deadline = time.monotonic() + timeout
        while not all(self.matched(k) for k in kinds):
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        time.sleep(settle)
        return True

    def close(self) -> None:
        """Undeclare the Zenoh publishers (idempotent)."""
        pubs, self._pubs = self._pubs, {}
        for pub in pubs.values():
            try:
                pub.undeclare()
            except zenoh.ZError:  # session already closed
                pass

    def __enter__(self) -> Publisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ----------------------------------------------------------------------------------------------
# Subscribing


class Subscription:
    """Zenoh subscribers of one or more keys; :meth:`close` undeclares them all.

    ``n_received`` counts decoded messages, ``n_errors`` malformed payloads and callback
    failures (each also logged, and passed to ``on_error`` when given).
    """

    def __init__(self) -> None:
        self._subs: list[zenoh.Subscriber[None]] = []
        self._lock = threading.Lock()
        self.n_received = 0
        self.n_errors = 0
        self.throttle = Throttle()  # a flood of bad messages is a few lines, with counts

    def _count(self, ok: bool) -> None:
        with self._lock:
            if ok:
                self.n_received += 1
            else:
                self.n_errors += 1

    def close(self) -> None:
        """Undeclare every subscriber (idempotent)."""
        subs, self._subs = self._subs, []
        for sub in subs:
            try:
                sub.undeclare()
            except zenoh.ZError:  # session already closed
                pass

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def subscribe(session: zenoh.Session, callback: Callable[[BusMessage], None], *,
              unit: str = "dryer1", kinds: Iterable[str] = KINDS,
              on_error: Callable[[str, str], None] | None = None) -> Subscription:
    """Deliver decoded messages of ``kinds`` to ``callback`` (called on a Zenoh thread).

    A malformed payload or an exception in ``callback`` is counted, logged (rate-limited, the
    key cut short) and passed to ``on_error(key, message)``; it never reaches Zenoh.
    """
    subscription = Subscription()

    def _error(key: str, msg: str) -> None:
        subscription._count(False)
        text = msg if msg.startswith(outside_text(key)) else f"{outside_text(key)}: {msg}"
        subscription.throttle.log(log, "bad message", logging.WARNING, "%s",
                                  outside_text(text))
        if on_error is not None:
            try:
                on_error(key, msg)
            except Exception:  # noqa: BLE001 - must not escape into zenoh's thread
                log.exception("on_error callback failed")

    def _on_sample(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            message = to_message(key, sample.payload.to_bytes(), unit)
        except IngestError as exc:
            _error(key, str(exc))
            return
        try:
            callback(message)
        except Exception as exc:  # noqa: BLE001 - must not escape into zenoh's thread
            _error(key, f"callback failed: {type(exc).__name__}: {exc}")
            return
        subscription._count(True)

    for kind in kinds:
        key = zenoh_key(kind, unit)
        subscription._subs.append(session.declare_subscriber(key, _on_sample))
    return subscription


class ZenohInput:
    """A worker's input side on a Zenoh session
    (:class:`~softsensor.bus.transport.InputSide`): one subscriber on ``plant/<unit>/*``
    delivering decoded scan and lab messages.

    A single subscriber, rather than one per key, keeps the messages of one publishing session
    in the order they were put: Zenoh runs the callbacks of different subscribers on different
    threads, which can let a lab result overtake (or fall behind) the scans around it.
    Malformed payloads and other keys are logged and counted in ``n_errors``; a payload over
    ``max_bytes`` is refused before it is decoded (a 5 MB "scan" must not cost a JSON parse).
    ``receive`` runs on Zenoh's thread.
    """

    def __init__(self, session: zenoh.Session, unit: str = "dryer1") -> None:
        self.session = session
        self.unit = unit
        self.n_received = 0
        self.n_errors = 0
        self.max_bytes: int | None = None
        self._on_too_large: Callable[[], None] | None = None
        self._throttle = Throttle()
        self._receive: Receive | None = None
        self._sub: zenoh.Subscriber[None] | None = None

    def open(self, receive: Receive, *, max_bytes: int | None = None,
             on_too_large: Callable[[], None] | None = None, sized: bool = False) -> None:
        """Declare the subscriber (``sized`` costs nothing here: a payload has a length)."""
        if self._receive is not None:
            raise RuntimeError("this input side is open already")
        self.max_bytes, self._on_too_large = max_bytes, on_too_large
        self._receive = receive
        self._sub = self.session.declare_subscriber(f"plant/{self.unit}/*", self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if self.max_bytes is not None and len(sample.payload) > self.max_bytes:
            if self._on_too_large is not None:
                self._on_too_large()
            return
        assert self._receive is not None  # (declared by open, after it is set)
        try:
            message = to_message(key, sample.payload.to_bytes(), self.unit)
            if message.kind not in INPUT_KINDS:
                raise IngestError(f"{outside_text(key)}: not an input key")
            self._receive(message)
        except Exception as exc:  # noqa: BLE001 - must not escape into zenoh's thread
            self.n_errors += 1  # (a flood of them is a few lines, with counts)
            self._throttle.log(log, "bad input", logging.WARNING, "%s", outside_text(exc))
            return
        self.n_received += 1

    def close(self) -> None:
        """Undeclare the subscriber (idempotent)."""
        sub, self._sub = self._sub, None
        if sub is not None:
            try:
                sub.undeclare()
            except zenoh.ZError:  # session already closed
                pass


def zenoh_sides(session: zenoh.Session, unit: str = "dryer1") -> tuple[ZenohInput, Publisher]:
    """A worker's input and output sides on ``session`` for ``unit``; the output keys are
    declared at once, so that subscribers (the recorder, a peer) are matched early."""
    publisher = Publisher(session, unit)
    publisher.declare(OUTPUT_KINDS)
    return ZenohInput(session, unit), publisher


__all__ = [
    "output_guard_acl",
    "Publisher",
    "Subscription",
    "ZenohInput",
    "decode_payload",
    "free_port",
    "kind_of_key",
    "listening_endpoints",
    "make_config",
    "open_session",
    "subscribe",
    "to_message",
    "wait_for_peers",
    "zenoh_sides",
]
