"""Fault injection (issue 14, item 6): a hostile peer on the bus, against a real daemon.

Before: any peer could inject lab results, publish on ``softsensor/dryer1/estimate`` (and the
recorder filed the spoofed estimates as the daemon's), send 5 MB messages, and read Zenoh's
admin space. Now the daemon can require Zenoh user/password authentication, refuses puts on
its own output keys from any other session (Zenoh access control), drops messages over
``max_message_bytes``, and keeps the admin space off; ``softsensor health`` asks it how it is.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

from daemon_harness import running_daemon

from softsensor.bus.zenoh_bus import Publisher, open_session
from softsensor.cli import main
from softsensor.plantconfig import default_config_path
from softsensor.recording.mcap_day import read_day
from softsensor.signals import TOPIC_ESTIMATE

PASSWORD = "s3cret-plc"


def _peer_puts(endpoint: str, user: str | None, password: str | None, now_ns: int,
               sample_id: str, *, spoof: bool = False, padding: int = 0) -> None:
    """Open a peer session (with or without credentials) and put one lab result, and
    optionally a spoofed estimate."""
    auth = {} if user is None else {"user": user, "password": password}
    with open_session(port=None, connect=[endpoint], **auth) as s:
        time.sleep(1.0)  # the link (if the daemon accepts it) comes up
        pub = Publisher(s, "dryer1")
        pub.declare(("lab", "estimate"))
        time.sleep(0.3)
        body = {"sample_time_ns": now_ns - 60 * 10**9, "moisture_out": 0.1,
                "sample_id": sample_id}
        if padding:
            body["note"] = "x" * padding
        pub.put("lab", body, now_ns)
        if spoof:
            for _ in range(5):
                pub.put("estimate", {"moisture_out": 9.99, "status": "ok"}, now_ns)
        time.sleep(0.5)
        pub.close()


def _admin_space_replies(endpoint: str) -> int:
    # this session's own admin space off too: any reply would come from the daemon
    with open_session(port=None, connect=[endpoint], user="plc", password=PASSWORD,
                      adminspace=False) as s:
        time.sleep(1.0)
        own = f"@/{s.info.zid()}/"  # a session always answers about its own links
        return sum(1 for r in s.get("@/**", timeout=2.0)
                   if r.ok is None or not str(r.ok.key_expr).startswith(own))


def _config_with_credentials(tmp_path: Path, password: str) -> Path:
    (tmp_path / "plc.pw").write_text(password + "\n")
    cfg = tmp_path / "dryer1.toml"
    cfg.write_text(default_config_path().read_text() + '\n[service]\nzenoh_user = "plc"\n'
                   'zenoh_password_file = "plc.pw"\n')
    return cfg


def test_only_authenticated_peers_get_in_and_nobody_speaks_for_the_daemon(tmp_path: Path):
    users = tmp_path / "users.txt"
    users.write_text(f"plc:{PASSWORD}\n")
    got: dict = {}

    async def run() -> None:
        async with running_daemon(tmp_path, zenoh_users_file=str(users)) as r:
            stats, now = r.daemon.worker.service.stats, r.daemon.clock.now_ns
            ep = r.endpoint
            await asyncio.to_thread(_peer_puts, ep, None, None, now(), "anonymous")
            await asyncio.to_thread(_peer_puts, ep, "plc", "wrong", now(), "wrong-password")
            got["after_intruders"] = stats.labs_received
            await asyncio.to_thread(_peer_puts, ep, "plc", PASSWORD, now(), "too-big",
                                    padding=200_000)
            got["after_big"] = stats.labs_received
            await asyncio.to_thread(_peer_puts, ep, "plc", PASSWORD, now(), "good",
                                    spoof=True)
            await asyncio.sleep(0.5)
            got["after_good"] = stats.labs_received
            got["admin"] = await asyncio.to_thread(_admin_space_replies, ep)
            cfg = _config_with_credentials(tmp_path, PASSWORD)
            out = tmp_path / "health.json"
            got["health"] = await asyncio.to_thread(
                main, ["health", "--config", str(cfg), "--connect", ep, "--json", str(out)])
            got["health_doc"] = json.loads(out.read_text())
            (tmp_path / "plc.pw").write_text("not-it\n")
            got["health_wrong"] = await asyncio.to_thread(
                main, ["health", "--config", str(cfg), "--connect", ep, "--timeout", "2"])

    asyncio.run(asyncio.wait_for(run(), 150))
    assert got["after_intruders"] == 0, got  # no session without the password got a lab in
    assert got["after_big"] == 0, got  # 200 kB message dropped
    assert got["after_good"] == 1, got  # the authenticated peer's lab arrived
    assert got["admin"] == 0, got  # admin space off
    assert got["health"] == 0 and got["health_doc"]["stalled"] is False, got
    assert got["health_doc"]["unit"] == "dryer1" and "pending" in got["health_doc"]
    assert got["health_wrong"] == 1, got  # refused by authentication: no answer
    rec = read_day(sorted((tmp_path / "rec").glob("*.mcap"))[0])
    estimates = [b for _t, b in rec.topic(TOPIC_ESTIMATE)]
    assert estimates and all(b.get("moisture_out") != 9.99 for b in estimates)
