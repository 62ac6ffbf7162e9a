"""Ambient humidity as plants measure it (relative humidity, dew point) to the contract's
humidity ratio ``H_amb`` [kg water / kg dry air] (CONTRACT section 1).

Vectorised over scans; the psychrometrics are the model's own
(:mod:`softsensor.model.humid_air`: Hyland-Wexler saturation pressure over liquid water,
ASHRAE 2017 ch. 1 eq. 6, and the humidity ratio of eq. 20), so an imported day and the model
agree on what a humidity means. Below 0 °C the saturation pressure is still the one over
liquid water, as most humidity transmitters report (WMO convention); over ice it would be up to
about 10 % lower at -20 °C, well inside an ambient humidity's effect on the dryer.
"""

from __future__ import annotations

import numpy as np

from softsensor.model.humid_air import humidity_ratio, p_sat

#: What a humidity column may hold (the map's ``signals.H_amb.quantity``).
HUMIDITY_QUANTITIES: tuple[str, ...] = ("humidity_ratio", "relative_humidity", "dew_point")
#: Sea-level standard pressure [Pa], the default ambient pressure.
P_STANDARD = 101_325.0


def ratio_from_relative_humidity(phi: np.ndarray, T: np.ndarray,
                                 P: float = P_STANDARD) -> np.ndarray:
    """Humidity ratio [kg/kg] of air at relative humidity ``phi`` [-, 0..1], temperature
    ``T`` [K] and pressure ``P`` [Pa]: p_w = phi p_ws(T), then ASHRAE eq. 20. NaN where an
    input is NaN or the vapour pressure reaches ``P``."""
    phi, T = np.asarray(phi, dtype=float), np.asarray(T, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        p_w = phi * p_sat(T)
        return np.where(p_w < P, humidity_ratio(p_w, P), np.nan)


def ratio_from_dew_point(T_dew: np.ndarray, P: float = P_STANDARD) -> np.ndarray:
    """Humidity ratio [kg/kg] of air whose dew point is ``T_dew`` [K] at pressure ``P`` [Pa]:
    the vapour pressure is the saturation pressure at the dew point."""
    T_dew = np.asarray(T_dew, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        p_w = p_sat(T_dew)
        return np.where(p_w < P, humidity_ratio(p_w, P), np.nan)


__all__ = ["HUMIDITY_QUANTITIES", "P_STANDARD", "ratio_from_dew_point",
           "ratio_from_relative_humidity"]
