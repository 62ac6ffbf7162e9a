"""What a plant value may physically be: inputs judged at the edge, estimates at publication.

The tag map's valid ranges catch broken sensors (``T_air_in`` 300 to 700 K); a value inside
them can still be nonsense for this dryer, and one such window used to make an ``ok`` estimate
of 37.5 % moisture and then lose the model for hours. So every scan value is judged here
*before* a window sums it (:class:`InputJudge`, used by
:mod:`softsensor.windows.accumulator`):

* **range**: outside ``[low, high]`` of its signal (the plant's operating envelope of CONTRACT
  section 6 with a margin, :data:`DEFAULT_LIMITS`), or beyond :data:`MAX_MAGNITUDE` for any
  signal, a value is refused. Nothing refused is ever summed, so no value can overflow a
  window's sum or reach the checkpoint as a mean.
* **rate of change**: a value further from the signal's last accepted one than ``max_step +
  max_rate * dt`` is a jump (a thermocouple does not move 200 K in 10 s). The signal is then
  *suspect*: its values are refused until either a jump brings it back near the last
  accepted value, or the new level has stayed steady (no further jump) for ``hold_s`` (then it
  is taken as real: a process that really moved, a sensor replaced). After an outage longer
  than ``hold_s`` the first value in range is taken as it is.

A window whose required input lost more than half its values this way is stale (the model
holds that input), so an implausible stretch reaches the estimator as held, never as data.
Limits are per plant: a ``[plausibility]`` table overrides any of them
(:func:`plausibility_from_config`).

At publication :func:`estimate_problems` names every value of an estimate body outside its
physical range (:class:`EstimateRanges`: outlet moisture within 0 to 1 kg/kg dry basis, inlet
moisture within the estimator's range, outlet temperatures within their input limits); the
service never publishes such an estimate as ``ok``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from softsensor.configfile import build_section, num
from softsensor.errors import EstimationError
from softsensor.plantconfig import PlantConfig, built_table
from softsensor.signals import SCAN_SIGNALS

NS = 10**9
#: No plant value is larger in magnitude than this, in any SI unit; judged even without
#: limits, so that a window's sum can never overflow (``fsum`` of two 1e308 does).
MAX_MAGNITUDE = 1e9


@dataclass(frozen=True)
class SignalLimits:
    """Plausibility of one scan signal (a ``[plausibility.<signal>]`` table). SI units.

    Attributes
    ----------
    low, high : float
        Plausible range [signal unit].
    max_rate : float
        Fastest plausible change [signal unit / s]; 0: no rate check (a set point, a
        controller output, which move in steps).
    max_step : float
        Change allowed on top of ``max_rate * dt`` (scan noise) [signal unit].
    """

    low: float = num()
    high: float = num()
    max_rate: float = num(0.0, ge=0)
    max_step: float = num(0.0, ge=0)

    def check(self) -> str | None:
        if not self.low < self.high:
            return f"high must be > low ({self.low:g}), got {self.high:g}"
        if max(abs(self.low), abs(self.high)) > MAX_MAGNITUDE:
            return f"low and high must be within +-{MAX_MAGNITUDE:g}"
        return None


#: The reference plant's limits: CONTRACT section 6's envelope with a margin (the tag map's
#: ranges are wider still: they catch broken sensors). Rates only for the temperatures: a
#: thermocouple's own lag bounds how fast it can move, while a flow, a humidity reading, a set
#: point or a controller output may step (a production change, a damper, a valve). They are
#: well above anything the two virtual plants show between 10 s scans (at most 3.7 K).
DEFAULT_LIMITS: dict[str, SignalLimits] = {
    "T_air_in": SignalLimits(400.0, 620.0, max_rate=5.0, max_step=10.0),
    "m_air": SignalLimits(40.0, 130.0),
    "m_fiber": SignalLimits(2.0, 10.0),
    "T_fiber_in": SignalLimits(300.0, 420.0, max_rate=2.0, max_step=5.0),
    "m_steam": SignalLimits(0.0, 2.0),
    "T_amb": SignalLimits(230.0, 330.0, max_rate=0.5, max_step=5.0),
    "H_amb": SignalLimits(0.0, 0.04),
    "flap_cmd": SignalLimits(0.0, 100.0),
    "T_sp": SignalLimits(320.0, 380.0),
    "T_dryer_out": SignalLimits(300.0, 420.0, max_rate=2.0, max_step=6.0),
    "T_cyclone_out": SignalLimits(300.0, 420.0, max_rate=2.0, max_step=6.0),
}
#: How long a suspect signal's new level must hold steady before it is believed [s].
HOLD_S = 600.0


@dataclass(frozen=True)
class Plausibility:
    """Limits of every scan signal and the hold time (module docstring)."""

    limits: Mapping[str, SignalLimits] = field(default_factory=lambda: dict(DEFAULT_LIMITS))
    hold_s: float = HOLD_S


#: The ``[plausibility]`` table: ``hold_s`` and one ``[plausibility.<signal>]`` sub-table per
#: scan signal, kept as read: its keys replace the default's and the result is built and
#: checked as one :class:`SignalLimits` (:func:`plausibility_from_config`).
PlausibilityTable = dataclasses.make_dataclass(
    "PlausibilityTable",
    [("hold_s", float, num(HOLD_S, gt=0, le=86_400)),
     *((name, dict[str, Any] | None, field(default=None)) for name in SCAN_SIGNALS)],
    frozen=True)


def plausibility_from_config(cfg: PlantConfig) -> Plausibility:
    """The ``[plausibility]`` table of ``cfg`` over :data:`DEFAULT_LIMITS` (built once):
    ``hold_s`` and one sub-table per signal whose keys replace the default's
    (``[plausibility.T_air_in] high = 650.0``)."""
    return built_table(cfg, "plausibility", _plausibility)


def _plausibility(cfg: PlantConfig) -> Plausibility:
    table = build_section(PlausibilityTable, cfg.extra.get("plausibility", {}), "plausibility",
                          cfg.source)
    limits = dict(DEFAULT_LIMITS)
    for name in SCAN_SIGNALS:
        change = getattr(table, name)
        if change is not None:
            merged = {**dataclasses.asdict(limits[name]), **change}
            limits[name] = build_section(SignalLimits, merged, f"plausibility.{name}",
                                         cfg.source)
    return Plausibility(limits, table.hold_s)


def _g(x: float) -> str:
    return f"{x:.4g}"


class _Track:
    """What the judge remembers of one signal: the last accepted value, the last value seen
    in range, and since when the signal is suspect. Times [ns]."""

    __slots__ = ("t_acc", "t_raw", "v_acc", "v_raw", "suspect_ns")

    def __init__(self, t_acc: int | None = None, v_acc: float | None = None,
                 t_raw: int | None = None, v_raw: float | None = None,
                 suspect_ns: int | None = None) -> None:
        self.t_acc, self.v_acc = t_acc, v_acc
        self.t_raw, self.v_raw = t_raw, v_raw
        self.suspect_ns = suspect_ns


class InputJudge:
    """Judges each scan value before a window sums it (module docstring).

    :meth:`judge` returns None for a value to use, else the one-line reason it is refused.
    The judge is a function of the values and times it was given, so a window re-fed from a
    checkpoint with the :meth:`state` saved at its start is judged exactly as it was live.
    """

    def __init__(self, plausibility: Plausibility | None = None) -> None:
        self.plausibility = plausibility or Plausibility()
        self.hold_ns = int(self.plausibility.hold_s * NS)
        self._tracks: dict[str, _Track] = {}

    def judge(self, name: str, t_ns: int, value: float) -> str | None:
        """None when ``value`` of signal ``name`` at ``t_ns`` is plausible, else why not."""
        if not abs(value) <= MAX_MAGNITUDE:
            return f"{value:.3g} is not a plant value"
        lim = self.plausibility.limits.get(name)
        if lim is None:
            return None
        if not lim.low <= value <= lim.high:
            return f"{_g(value)} outside {_g(lim.low)}..{_g(lim.high)}"
        if lim.max_rate <= 0:
            return None
        tr = self._tracks.get(name)
        if tr is None:
            tr = self._tracks[name] = _Track()
        t = int(t_ns)
        verdict = self._rate(tr, lim, t, value)
        tr.t_raw, tr.v_raw = t, value
        if verdict is None:
            tr.t_acc, tr.v_acc, tr.suspect_ns = t, value, None
        return verdict

    def _rate(self, tr: _Track, lim: SignalLimits, t: int, v: float) -> str | None:
        outage = t - (tr.t_raw if tr.t_raw is not None else t) > self.hold_ns
        if tr.t_acc is None or tr.v_acc is None or (t - tr.t_acc > self.hold_ns and outage):
            return None  # nothing to compare with, or after an outage: take it
        dt_acc = abs(t - tr.t_acc) / NS
        near_accepted = abs(v - tr.v_acc) <= lim.max_step + lim.max_rate * dt_acc
        if tr.suspect_ns is None:
            if near_accepted:
                return None
            tr.suspect_ns = t
            return (f"moved {_g(v - tr.v_acc)} in {dt_acc:.0f} s (at most "
                    f"{_g(lim.max_step)} + {_g(lim.max_rate)}/s)")
        assert tr.t_raw is not None and tr.v_raw is not None
        jumped = abs(v - tr.v_raw) > lim.max_step + lim.max_rate * abs(t - tr.t_raw) / NS
        if jumped and near_accepted:
            return None  # back where it was before the jump
        if jumped:
            tr.suspect_ns = t  # yet another level: its hold starts again
        elif t - tr.suspect_ns >= self.hold_ns:
            return None  # the new level held steady: the process (or sensor) really moved
        return (f"held: {_g(v)} since a jump {(t - tr.suspect_ns) / NS:.0f} s ago (last "
                f"plausible {_g(tr.v_acc)}; believed after {self.plausibility.hold_s:.0f} s "
                f"steady)")

    # -------------------------------------------------------------- checkpoints
    def state(self) -> dict[str, list[Any]]:
        """JSON-able memory of the judge (restored by :meth:`restore`)."""
        return {name: [tr.t_acc, tr.v_acc, tr.t_raw, tr.v_raw, tr.suspect_ns]
                for name, tr in self._tracks.items()}

    def restore(self, state: Mapping[str, Any]) -> None:
        """Continue from :meth:`state`; :class:`EstimationError` when it is malformed (a
        checkpoint must not carry a value the judge would never have accepted)."""
        tracks: dict[str, _Track] = {}
        if not isinstance(state, Mapping):
            raise EstimationError("input judge state is not a mapping")
        for name, row in state.items():
            if name not in SCAN_SIGNALS or not isinstance(row, list) or len(row) != 5:
                raise EstimationError(f"input judge state of {str(name)[:40]!r} is malformed")
            ints = [row[0], row[2], row[4]]
            floats = [row[1], row[3]]
            if any(x is not None and (isinstance(x, bool) or not isinstance(x, int))
                   for x in ints) or any(
                    x is not None and (isinstance(x, bool) or not isinstance(x, (int, float))
                                       or not abs(x) <= MAX_MAGNITUDE) for x in floats):
                raise EstimationError(f"input judge state of {name} holds a non-value")
            tracks[name] = _Track(row[0], None if row[1] is None else float(row[1]), row[2],
                                  None if row[3] is None else float(row[3]), row[4])
        self._tracks = tracks


# ------------------------------------------------------------------ estimates at publication
@dataclass(frozen=True)
class EstimateRanges:
    """Physical range of each published estimate field (module docstring). SI units."""

    ranges: Mapping[str, tuple[float, float]] = field(default_factory=lambda: {
        "moisture_out": (0.0, 1.0), "moisture_out_std": (0.0, 1.0),
        "moisture_in": (0.3, 2.5), "moisture_in_std": (0.0, 2.5),
        "T_dryer_out_model": (DEFAULT_LIMITS["T_dryer_out"].low,
                              DEFAULT_LIMITS["T_dryer_out"].high),
        "T_cyclone_out_model": (DEFAULT_LIMITS["T_cyclone_out"].low,
                                DEFAULT_LIMITS["T_cyclone_out"].high)})


def estimate_ranges(plausibility: Plausibility, moisture_in: tuple[float, float]
                    ) -> EstimateRanges:
    """The ranges of a plant: the inlet moisture within the estimator's range
    ``moisture_in`` [kg/kg], the model's outlet temperatures within the limits of the
    measured ones."""
    lim = plausibility.limits
    lo, hi = moisture_in
    return EstimateRanges({
        "moisture_out": (0.0, 1.0), "moisture_out_std": (0.0, 1.0),
        "moisture_in": (lo, hi), "moisture_in_std": (0.0, hi),
        "T_dryer_out_model": (lim["T_dryer_out"].low, lim["T_dryer_out"].high),
        "T_cyclone_out_model": (lim["T_cyclone_out"].low, lim["T_cyclone_out"].high)})


#: What an estimate is for: without these it is no estimate, whatever its status says.
REQUIRED_ESTIMATES: tuple[str, ...] = ("moisture_out", "moisture_in")


def estimate_problems(body: Mapping[str, Any], ranges: EstimateRanges) -> list[str]:
    """Why the estimate ``body`` is not physical: one short text per field outside its range
    or not a number, and per field of :data:`REQUIRED_ESTIMATES` that is missing (empty when
    all are well). The others may be missing (a model output the estimator did not give)."""
    out = []
    for key, (lo, hi) in ranges.ranges.items():
        v = body.get(key)
        if v is None:
            if key in REQUIRED_ESTIMATES:
                out.append(f"{key} is missing")
        elif isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            out.append(f"{key} is not a number")
        elif not lo <= v <= hi:
            out.append(f"{key} {_g(float(v))} outside {_g(lo)}..{_g(hi)}")
    return out


__all__ = [
    "DEFAULT_LIMITS",
    "EstimateRanges",
    "HOLD_S",
    "InputJudge",
    "MAX_MAGNITUDE",
    "Plausibility",
    "REQUIRED_ESTIMATES",
    "SignalLimits",
    "estimate_problems",
    "estimate_ranges",
    "plausibility_from_config",
]
