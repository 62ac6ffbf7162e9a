"""Settings of the estimator daemon: the ``[service]`` table of the plant config.

One frozen dataclass validated by :func:`softsensor.configfile.build_section` (unknown keys
rejected, ranges checked, errors naming ``service.<key>`` and the file). Every field has a
default, so a plant config without the table runs the daemon on loopback with the packaged tag
map (or the ``tagmap_<unit>.toml`` beside the config file). A relative ``tagmap`` is taken
relative to the config file; the other relative paths relative to the working directory of
the daemon (``/data`` in the container). Command-line options of ``softsensor run`` override
single fields (:meth:`ServiceSettings.with_overrides`; ``--tagmap`` relative to the working
directory, as any command-line path).

Example ``config/dryer1.toml`` fragment::

    [service]
    data_dir = "recordings"               # daily MCAP files <unit>-YYYYMMDD.mcap
    checkpoint = "state/checkpoint.json"  # estimator state, rewritten atomically every tick
    lab_dir = "lab-drop"                  # watched folder for lab CSV/JSON files
    zenoh_listen = ["tcp/127.0.0.1:7447"]
    zenoh_connect = []                    # e.g. ["tcp/10.0.0.5:7447"], a router
    time_scale = 1.0                      # > 1: accelerated demos against plant-server --speed

Time in the daemon is plant time: with ``time_scale = N`` the daemon's clock runs N times
faster than the wall clock from ``clock_start`` (default: now), the poller polls N times as
often, and windows of 600 plant seconds last 600 / N wall seconds. Durations below are in
plant seconds unless they say "wall".
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from softsensor.configfile import build_section, num
from softsensor.plantconfig import PlantConfig, built_table

ZENOH_MODES: tuple[str, ...] = ("peer", "client")
#: A unit name: it is a Zenoh key chunk and part of file names, so no ``/``, ``..``, ``*``.
UNIT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")
UNIT_RULE = "must be 1 to 64 letters, digits, '_' or '-' (it names keys and files)"
LOG_FORMATS: tuple[str, ...] = ("kv", "json")
#: Zenoh's link limit in multiples of ``max_message_bytes`` (see :func:`bus_options`).
LINK_LIMIT_FACTOR = 4
#: ``clock_start`` value: start at the PLC's clock (the tag map's ``[clock]`` registers).
PLC_CLOCK = "plc"
#: Where a daemon's clock may start [ns since the epoch]: 2000-01-01 to 2200-01-01.
CLOCK_START_RANGE: tuple[int, int] = (946_684_800 * 10**9, 7_258_118_400 * 10**9)


@dataclass(frozen=True)
class ServiceSettings:
    """The ``[service]`` table (module docstring).

    Attributes
    ----------
    unit : str or None
        Unit name in Zenoh keys and file names; default the config's ``unit.name``.
    tagmap : str or None
        Modbus tag map (TOML), relative to the config file; default the
        ``tagmap_<unit>.toml`` beside the config file, else the packaged ``tagmap_dryer1.toml``.
    plc_host, plc_port : str, int or None
        Override the tag map's ``[modbus]`` endpoint.
    data_dir : str
        Folder of the recorded day files.
    record : bool
        Record every topic into ``data_dir`` (the recorder).
    chunk_size : int
        Uncompressed MCAP chunk size of the recorder [bytes]; bounds what a crash loses.
    flush_interval_s : float
        Longest time a recorded message waits in an open chunk [s, wall].
    record_reserve_bytes : int
        Recording pauses (files finished, messages kept in memory, health says ``recording:
        disk full``) when less than this is free in ``data_dir``, and resumes once twice as
        much is [bytes].
    record_topic_bytes_per_day : int
        Most JSON bytes one topic adds to a day file; beyond, its messages are counted in
        health (``recording``), not recorded, until the next day. The inputs are recorded as
        the estimator admits them (``max_message_bytes``, ``max_scan_rate_hz``,
        ``max_lab_rate_per_h``), whoever sends them [bytes]; the PLC's own scans count
        against a cap of their own.
    plc_scans_first : bool
        While the daemon's own PLC scans arrive, another sender's scans on the bus are
        dropped, neither recorded nor estimated (``inputs_dropped`` ``other_sender``); false:
        every sender's scans go into the windows, as before issue 40.
    checkpoint : str
        Estimator checkpoint file (JSON, replaced atomically).
    checkpoint_every : int
        Write the checkpoint every this many ticks (and at shutdown).
    lab_dir : str or None
        Watched lab drop folder (``processed/`` and ``rejected/`` inside); None = no folder.
    lab_poll_s : float
        Poll period of the lab folder [s, plant time; at least 0.05 s wall].
    lab_settle_s : float
        A lab file changed less than this long ago waits for the next poll [s, wall].
    zenoh_mode : str
        ``peer`` (embedded peer, default) or ``client`` (needs ``zenoh_connect``).
    zenoh_listen, zenoh_connect : list of str
        Zenoh endpoints; listening on loopback by default, connect e.g. to a router.
    time_scale : float
        Speed of the daemon's clock relative to the wall clock [-].
    clock_start : str or None
        Start of the scaled clock, ISO-8601 or ns since the epoch (default: now); a restart
        continues from the checkpoint's time when that is later. ``"plc"``: the PLC's own
        clock, read at start from the tag map's ``[clock]`` registers (the virtual PLC serves
        its plant's there), so a demo's plant and daemon share one clock.
    tick_delay_s : float
        A window is ticked once a scan this much past its end has arrived, so a lab result
        logged before the window's end is always applied first, live and in replay [s].
    gap_after_s : float
        With no scans at all, a window is closed (stale) this long after its end [s].
    max_future_s, max_past_s : float
        A scan or lab result stamped more than this ahead of, or behind, the daemon's clock is
        refused, counted (``refused_time``) and not recorded [s].
    status_every_s : float
        Period of the daemon's status log line [s, wall].
    zenoh_user, zenoh_password_file : str or None
        Zenoh user/password authentication towards the sessions the daemon connects to (the
        password read from the file, relative to the config file, so the config carries none).
    zenoh_users_file : str or None
        Zenoh's dictionary file (``user:password`` lines, relative to the config file): every
        session connecting to the daemon must authenticate as one of them.
    zenoh_adminspace : bool
        Expose Zenoh's (read-only) admin space; off: it tells any peer the daemon's links.
    zenoh_guard_outputs : bool
        Zenoh access control refusing ``put`` on ``softsensor/<unit>/**`` from other sessions:
        no peer can publish estimates or health in the daemon's name into it or its recorder.
    max_message_bytes : int
        Larger bus messages are dropped before decoding and counted (``too_large``); above
        four times this Zenoh drops them on the link, uncounted (nothing of them reaches
        the daemon, which holds at most that much per link).
    max_queue, max_queue_bytes : int
        Input messages, and their payload bytes, waiting for the estimator thread; beyond
        either, more are dropped and counted (``queue_full``). The bytes bound keeps a flood
        of large messages from holding ``max_queue`` times ``max_message_bytes`` (640 MB).
    max_lab_silence_h : float
        Health turns ``degraded`` when no lab result was accepted for this long (since the
        last accepted one, or since the first scan) [h, plant time]; 0: never. A lab sends a
        few results a day: 12 h without one that the estimator took means the estimate runs
        uncorrected (a wrong ``[lab]`` table, a LIMS that stopped, every file refused).
    max_scan_rate_hz, max_lab_rate_per_h : float
        Rate limits per input kind (all scans, all lab results, whoever publishes them)
        [per plant second, per plant hour]; above them messages are dropped and counted (a
        scan every 10 s is 0.1 Hz; a lab sends a few results a day).
    log_format : str
        ``kv`` (key=value) or ``json``, one line per event.
    """

    unit: str | None = None
    tagmap: str | None = None
    plc_host: str | None = None
    plc_port: int | None = num(None, ge=1, le=65535)
    data_dir: str = "recordings"
    record: bool = True
    chunk_size: int = num(16 * 1024, ge=1024, le=64 * 1024 * 1024)
    flush_interval_s: float = num(30.0, gt=0, le=3600)
    record_reserve_bytes: int = num(16 * 1024 * 1024, ge=0, le=2**40)
    # a day of 10 s scans is about 4 MB of JSON: 64 MB leaves room for a faster PLC
    record_topic_bytes_per_day: int = num(64 * 1024 * 1024, ge=1024, le=2**40)
    checkpoint: str = "state/checkpoint.json"
    checkpoint_every: int = num(1, ge=1, le=10_000)
    lab_dir: str | None = "lab-drop"
    lab_poll_s: float = num(2.0, gt=0, le=3600)
    lab_settle_s: float = num(1.0, ge=0, le=3600)
    zenoh_mode: str = "peer"
    zenoh_listen: Any = ("tcp/127.0.0.1:7447",)
    zenoh_connect: Any = ()
    # below 0.01 no window ever ends and the folder's poll waits overflow (1e-300 killed the
    # lab thread)
    time_scale: float = num(1.0, ge=0.01, le=100_000)
    clock_start: str | None = None
    tick_delay_s: float = num(10.0, ge=0, le=3600)
    gap_after_s: float = num(60.0, gt=0, le=86_400)
    max_future_s: float = num(300.0, gt=0, le=86_400)
    max_past_s: float = num(6 * 3600.0, gt=0, le=30 * 86_400)
    status_every_s: float = num(60.0, gt=0, le=86_400)
    log_format: str = "kv"
    zenoh_user: str | None = None
    zenoh_password_file: str | None = None
    zenoh_users_file: str | None = None
    zenoh_adminspace: bool = False
    zenoh_guard_outputs: bool = True
    max_message_bytes: int = num(65_536, ge=1024, le=64 * 1024 * 1024)
    max_queue: int = num(10_000, ge=10, le=10_000_000)
    max_queue_bytes: int = num(4 * 1024 * 1024, ge=64 * 1024, le=1024**3)
    max_scan_rate_hz: float = num(10.0, gt=0, le=100_000)
    max_lab_rate_per_h: float = num(600.0, gt=0, le=1e9)
    max_lab_silence_h: float = num(12.0, ge=0, le=24 * 365)
    plc_scans_first: bool = True

    #: One rule, one key: the estimator's kind and a window's good share are set where the
    #: estimator and the windowing read them (these keys once set them a second time).
    MOVED_KEYS: ClassVar[Mapping[str, str]] = {
        "estimator": "set estimator.kind (or --estimator)",
        "min_good_fraction": "set solver.min_good_fraction"}

    def check(self) -> str | None:
        """Cross-field and list rules (called by ``build_section``); message names the key."""
        for key in ("zenoh_listen", "zenoh_connect"):
            value = getattr(self, key)
            if not isinstance(value, (list, tuple)):
                return f"{key} must be a list of endpoints, got {value!r}"
            for ep in value:
                if not isinstance(ep, str) or "/" not in ep:
                    return f"{key} entry {ep!r} must look like tcp/127.0.0.1:7447"
        if self.zenoh_mode not in ZENOH_MODES:
            return f"zenoh_mode must be one of {', '.join(ZENOH_MODES)}, got {self.zenoh_mode!r}"
        if self.zenoh_mode == "client" and not self.zenoh_connect:
            return "zenoh_connect must name a router endpoint when zenoh_mode is client"
        if self.unit is not None and not UNIT_NAME.fullmatch(self.unit):
            return f"unit {self.unit!r} {UNIT_RULE}"
        if (self.zenoh_user is None) != (self.zenoh_password_file is None):
            return "zenoh_user and zenoh_password_file go together (both or neither)"
        if self.log_format not in LOG_FORMATS:
            return f"log_format must be one of {', '.join(LOG_FORMATS)}, got {self.log_format!r}"
        if self.clock_start is not None and self.clock_start != PLC_CLOCK:
            from softsensor.errors import ConfigError
            from softsensor.service.day_replay import parse_time
            try:
                start = parse_time(self.clock_start, "clock_start")
            except ConfigError as exc:
                return str(exc)
            # the time gate refuses every message before 2000, so a clock there hears none
            if start is not None and not CLOCK_START_RANGE[0] <= start < CLOCK_START_RANGE[1]:
                return (f"clock_start must be between 2000-01-01 and 2200-01-01, got "
                        f"{self.clock_start!r}")
        return None

    @property
    def listen(self) -> tuple[str, ...]:
        """Zenoh listen endpoints (none in client mode)."""
        return () if self.zenoh_mode == "client" else tuple(self.zenoh_listen)

    @property
    def connect(self) -> tuple[str, ...]:
        """Zenoh connect endpoints."""
        return tuple(self.zenoh_connect)

    def with_overrides(self, source: str = "command line", **changes: Any) -> ServiceSettings:
        """A copy with the non-None ``changes`` applied and validated like the file."""
        table = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        table.update({k: (list(v) if isinstance(v, tuple) else v)
                      for k, v in changes.items() if v is not None})
        table = {k: v for k, v in table.items() if v is not None}
        return build_section(ServiceSettings, table, "service", source)


def service_settings(cfg: PlantConfig) -> ServiceSettings:
    """The validated ``[service]`` table of ``cfg`` (defaults when absent).

    The tag map is looked for beside the config file: a relative ``tagmap`` is taken
    relative to it, and without the key a ``tagmap_<unit>.toml`` there is used (else the
    packaged one). So a copied config folder (``dryer1.toml`` beside its edited
    ``tagmap_dryer1.toml``) runs with its own tag map wherever the daemon starts; the data
    paths stay relative to the working directory. Built once per config.
    """
    return built_table(cfg, "service", _service_settings)


def _service_settings(cfg: PlantConfig) -> ServiceSettings:
    table = cfg.extra.get("service", {})
    if isinstance(table, dict) and Path(cfg.source).is_file():
        here = Path(cfg.source).parent
        tagmap = table.get("tagmap")
        beside = here / f"tagmap_{table.get('unit') or cfg.unit.name}.toml"
        if isinstance(tagmap, str) and not Path(tagmap).is_absolute():
            table = {**table, "tagmap": str(here / tagmap)}
        elif tagmap is None and beside.is_file():
            table = {**table, "tagmap": str(beside)}
        for key in ("zenoh_password_file", "zenoh_users_file"):  # files beside the config
            value = table.get(key)
            if isinstance(value, str) and not Path(value).is_absolute():
                table = {**table, key: str(here / value)}
    return build_section(ServiceSettings, table, "service", cfg.source)


def resolve_unit(settings: ServiceSettings, cfg: PlantConfig) -> str:
    """The unit name: ``service.unit``, else the config's ``unit.name`` (checked as one)."""
    unit = settings.unit or cfg.unit.name
    if not UNIT_NAME.fullmatch(unit):
        from softsensor.errors import ConfigError

        raise ConfigError(f"{cfg.source}: unit.name {unit!r} {UNIT_RULE}")
    return unit


def bus_options(settings: ServiceSettings, unit: str) -> dict[str, Any]:
    """Keyword arguments of :func:`softsensor.bus.zenoh_bus.make_config` for the daemon's
    session and its clients (``softsensor health``): authentication, access control, the
    message size limit and the admin space. The password is read from its file here."""
    from softsensor.bus.zenoh_bus import output_guard_acl
    from softsensor.errors import ConfigError

    # Zenoh's own limit is a few times the daemon's: what lies between reaches the daemon,
    # which drops and counts it (too_large) before decoding; beyond it Zenoh drops the message
    # on the link, unseen (no counter reaches Python), so that a peer can never make the
    # daemon hold more than this per link while a message is reassembled
    kwargs: dict[str, Any] = {"adminspace": settings.zenoh_adminspace,
                              "max_message_bytes": LINK_LIMIT_FACTOR * settings.max_message_bytes}
    if settings.zenoh_password_file is not None:
        try:
            with open(settings.zenoh_password_file, encoding="utf-8") as f:
                password = f.readline().strip()
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"service.zenoh_password_file: cannot read "
                              f"{settings.zenoh_password_file}: "
                              f"{getattr(exc, 'strerror', None) or exc}") from exc
        if not password:
            raise ConfigError(f"service.zenoh_password_file: {settings.zenoh_password_file} "
                              f"is empty")
        kwargs.update(user=settings.zenoh_user, password=password)
    if settings.zenoh_users_file is not None:
        if not Path(settings.zenoh_users_file).is_file():
            raise ConfigError(f"service.zenoh_users_file: no such file "
                              f"{settings.zenoh_users_file}")
        kwargs["users_file"] = settings.zenoh_users_file
    if settings.zenoh_guard_outputs:
        kwargs["acl"] = output_guard_acl(unit)
    return kwargs
