"""Imported values held against the estimator's operating envelope, and units a person slipped.

The import's physical ranges (:data:`~softsensor.ingest.units.PHYSICAL_RANGE`) catch what no
instrument reads; a wrong unit can still land inside them (a fibre flow in t/h declared as kg/h
is 0.006 kg/s, a possible reading of a stopped line). The estimator then refuses every value
against its plausibility limits (:mod:`softsensor.windows.plausibility`, the plant config's
``[plausibility]`` table: one rule, read here, not copied) and estimates nothing. So ``import``
holds each mapped signal against those limits (:func:`check_envelope`):

* a signal with more than :data:`REFUSE_SHARE` of its good values outside the envelope is
  refused (:func:`envelope_problem`: one line naming the signal, the declared unit and, when
  one of the usual units of its kind would put the values inside, that unit): the estimator
  would hold that input in most windows, i.e. estimate nothing from it;
* fewer outside (a start-up, a trip) pass: the estimator refuses those values itself, and the
  preview counts them.

LIMS files get a softer check (:func:`lab_unit_hints`): a column headed "%" or "wet" read as
kg/kg on a dry basis (or the reverse) is named in the preview and the import's summary; the
values themselves cannot tell a wet fraction from a dry one.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from softsensor.ingest.historian_map import LabMap, SignalMap
from softsensor.ingest.units import to_signal_si
from softsensor.signals import SCAN_SIGNALS
from softsensor.windows.plausibility import SignalLimits

#: A signal with more than this share of its good values outside the envelope is refused.
REFUSE_SHARE = 0.5
#: The units tried for a likely slip, per SI unit (pint spellings a map would use).
CANDIDATE_UNITS: dict[str, tuple[str, ...]] = {
    "K": ("K", "degC", "degF"),
    "kg/s": ("kg/s", "kg/min", "kg/h", "t/h", "lb/s", "lb/h"),
    "kg/kg": ("kg/kg", "g/kg", "%"),
    "%": ("%",),
}


@dataclass(frozen=True)
class EnvelopeCheck:
    """One signal held against its envelope: counts, and a unit that would fit better."""

    name: str
    limits: SignalLimits
    n_good: int  #: finite values (after the physical range)
    n_outside: int  #: of them outside ``[limits.low, limits.high]``
    median_si: float  #: median of the good values [SI]
    better_unit: str | None = None  #: a usual unit putting most values inside, if any
    better_median_si: float = math.nan  #: the median in SI read in ``better_unit``

    @property
    def share_outside(self) -> float:
        return self.n_outside / self.n_good if self.n_good else 0.0

    @property
    def refused(self) -> bool:
        """The estimator would refuse most of this signal (module docstring)."""
        return self.share_outside > REFUSE_SHARE


def _outside(si: np.ndarray, lim: SignalLimits) -> int:
    good = si[np.isfinite(si)]
    return int(((good < lim.low) | (good > lim.high)).sum())


def _better_unit(raw: np.ndarray, sm: SignalMap, name: str, lim: SignalLimits
                 ) -> tuple[str | None, float]:
    """The candidate unit (:data:`CANDIDATE_UNITS`) that puts the most of ``raw`` inside the
    envelope, when it puts more than half there; with its median in SI."""
    best: tuple[int, str | None, float] = (-1, None, math.nan)
    good = raw[np.isfinite(raw)]
    for unit in CANDIDATE_UNITS.get(SCAN_SIGNALS[name], ()):
        if unit == sm.unit:
            continue
        si = to_signal_si(good, unit, name)
        inside = len(good) - _outside(si, lim)
        if inside > best[0]:
            best = (inside, unit, float(np.median(si)))
    if best[1] is None or best[0] <= REFUSE_SHARE * len(good):
        return None, math.nan
    return best[1], best[2]


def check_envelope(values: Mapping[str, np.ndarray], raw: Mapping[str, np.ndarray],
                   signals: Mapping[str, SignalMap], limits: Mapping[str, SignalLimits]
                   ) -> dict[str, EnvelopeCheck]:
    """Each mapped signal's SI ``values`` (the export's ``raw`` ones beside them) held against
    ``limits`` (the plant config's plausibility limits)."""
    out: dict[str, EnvelopeCheck] = {}
    for name, sm in signals.items():
        lim = limits.get(name)
        si = values.get(name)
        if lim is None or si is None:
            continue
        good = si[np.isfinite(si)]
        n_out = _outside(si, lim)
        check = EnvelopeCheck(name, lim, len(good), n_out,
                              float(np.median(good)) if len(good) else math.nan)
        # a unit slip shows in a plain unit; humidity read as RH or dew point is converted
        # with the temperature, and a constant is what the map says
        if check.refused and sm.quantity == "humidity_ratio" and sm.constant is None:
            unit, median = _better_unit(np.asarray(raw[name], dtype=float), sm, name, lim)
            check = EnvelopeCheck(name, lim, len(good), n_out, check.median_si, unit, median)
        out[name] = check
    return out


def envelope_problem(check: EnvelopeCheck, sm: SignalMap, where: str) -> str:
    """The one line refusing ``check``'s signal: what, how many, the unit declared, the
    likely right one, and the key that sets the envelope when the plant really runs there."""
    si_unit = SCAN_SIGNALS[check.name]
    lim = check.limits
    source = sm.column or sm.tag or f"constant {sm.constant:g}"
    text = (f"{where}: {source} (signals.{check.name}) read as {sm.unit!r}: "
            f"{check.n_outside} of {check.n_good} values outside the operating envelope "
            f"{lim.low:g}..{lim.high:g} {si_unit} that the estimator accepts (median "
            f"{check.median_si:.4g} {si_unit}), so it would refuse them and estimate nothing")
    if check.better_unit is not None:
        text += (f"; in {check.better_unit!r} they fall inside (median "
                 f"{check.better_median_si:.4g} {si_unit}): set signals.{check.name}.unit = "
                 f"{check.better_unit!r}")
    else:
        text += f"; is signals.{check.name}.unit right?"
    return (text + f" (if this plant really runs there: [plausibility.{check.name}] low, high "
            "in the plant config, --config)")


_PERCENT = re.compile(r"%|percent|pct", re.I)
_WET = re.compile(r"\bw\.?b\.?\b|wet|%\s*wb|\bwb\b", re.I)
_DRY = re.compile(r"\bd\.?b\.?\b|dry|atro|%\s*db|\bdb\b", re.I)


def lab_unit_hints(lab: LabMap, raw: np.ndarray) -> list[str]:
    """What the LIMS column's header and values say against the ``[lab]`` table's unit and
    basis, one line each (empty: nothing suspicious)."""
    name, hints = lab.moisture_column, []
    good = raw[np.isfinite(raw)]
    is_percent = lab.unit.strip().lower() in ("%", "percent")
    if _PERCENT.search(name) and not is_percent:
        looks = (" and its values look like fractions, so keep the unit and check the basis"
                 if good.size and float(np.max(good)) < 1.0 else ": set lab.unit = \"%\"")
        hints.append(f"the lab column {name!r} says % but lab.unit is {lab.unit!r}{looks}")
    if is_percent and good.size and float(np.max(good)) < 1.0:
        hints.append(f"lab.unit is \"%\" but every value of {name!r} is below 1 % (fractions? "
                     f"set lab.unit = \"kg/kg\")")
    if _WET.search(name) and lab.basis == "dry":
        hints.append(f"the lab column {name!r} says wet basis but lab.basis is \"dry\" (set "
                     f"lab.basis = \"wet\")")
    elif _DRY.search(name) and lab.basis == "wet":
        hints.append(f"the lab column {name!r} says dry basis but lab.basis is \"wet\" (set "
                     f"lab.basis = \"dry\")")
    return hints


__all__ = ["CANDIDATE_UNITS", "REFUSE_SHARE", "EnvelopeCheck", "check_envelope",
           "envelope_problem", "lab_unit_hints"]
