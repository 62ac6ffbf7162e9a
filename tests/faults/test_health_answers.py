"""Fault injection (issue 25, items 2 and 8): who may answer ``softsensor health``, and how
long it waits, against a real daemon and a real port.

Before: a peer that declared a queryable on ``softsensor/dryer1/health`` and replied
``{"status": "ok"}`` made ``softsensor health`` print its answer with exit 0 in 11 of 12
tries (Zenoh's default consolidation kept one reply, usually the stranger's); and with
``--timeout 1`` the command waited 11.5 s on a port that accepts and never answers. Now the
daemon's access control refuses other sessions' queryables and replies on its keys, the
client takes every reply and gives an answer only when the daemon's session alone answered
(else it says it cannot tell, exit 1), and ``--timeout`` bounds the connection too.
"""

from __future__ import annotations

import asyncio
import json
import socket
import threading
import time
from pathlib import Path

from daemon_harness import running_daemon

from softsensor.bus.zenoh_bus import open_session, wait_for_peers
from softsensor.cli import main

SPOOF = {"status": "ok", "detail": "spoofed by a peer"}


def _ask_with_a_liar(endpoint: str, tries: int, tmp_path: Path) -> list[tuple[int, str]]:
    """A peer answering health in the daemon's name while ``softsensor health`` is asked
    ``tries`` times; each try's exit code and JSON answer ('' for none)."""
    out = []
    with open_session(port=None, connect=[endpoint]) as liar:
        assert wait_for_peers(liar, timeout=10)
        q = liar.declare_queryable("softsensor/dryer1/health",
                                   lambda query: query.reply("softsensor/dryer1/health",
                                                             json.dumps(SPOOF)))
        time.sleep(0.5)  # the declaration reaches the daemon (or is refused there)
        for i in range(tries):
            path = tmp_path / f"health-{i}.json"
            path.unlink(missing_ok=True)
            code = main(["health", "--connect", endpoint, "--timeout", "3",
                         "--json", str(path)])
            out.append((code, path.read_text() if path.exists() else ""))
        q.undeclare()
    return out


def test_only_the_daemon_answers_health(tmp_path: Path):
    got: dict = {}

    async def run() -> None:
        async with running_daemon(tmp_path, ticks=0) as r:
            got["guarded"] = await asyncio.to_thread(_ask_with_a_liar, r.endpoint, 4, tmp_path)

    asyncio.run(asyncio.wait_for(run(), 150))
    for code, text in got["guarded"]:
        assert "spoofed" not in text, got
        assert code == 0 and json.loads(text)["unit"] == "dryer1"


def test_health_says_it_cannot_tell_when_another_session_answers_too(tmp_path: Path, capsys):
    """A daemon without the access rules (``zenoh_guard_outputs = false``): the stranger's
    reply reaches the client beside the daemon's; the client refuses to choose."""
    got: dict = {}

    async def run() -> None:
        async with running_daemon(tmp_path, ticks=0, zenoh_guard_outputs=False) as r:
            got["open"] = await asyncio.to_thread(_ask_with_a_liar, r.endpoint, 2, tmp_path)

    asyncio.run(asyncio.wait_for(run(), 150))
    assert all(code == 1 and text == "" for code, text in got["open"]), got
    assert "cannot tell which is the daemon" in capsys.readouterr().err


def test_health_on_a_silent_port_gives_up_within_its_timeout(capsys):
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(4)
        held: list = []
        threading.Thread(target=lambda: held.append(srv.accept()), daemon=True).start()
        t0 = time.monotonic()
        code = main(["health", "--connect", f"tcp/127.0.0.1:{srv.getsockname()[1]}",
                     "--timeout", "1"])
        took = time.monotonic() - t0
        for conn, _ in held:
            conn.close()
    assert code == 1
    assert took < 3.0, took  # 11.5 s before
    assert capsys.readouterr().err.startswith("softsensor health: dryer1: ")
