"""The independent plant's own physics run open loop on a day's measured inputs: the floor.

A virtual sensor is measured against what a *perfect* model of the same plant could do with
the same measurements. This module runs the plant's effect-free process (its structure,
commissioned as :func:`~.commissioning.commissioned_member` does for the day loop) on the
scans a day recorded, with every unmeasured disturbance at its plant's nominal value:

* the gas at the tube inlet: the burner gas (the member's nominal temperature and humidity,
  its CO2 share) mixed with the *measured* ambient air in the share that gives the
  *measured* ``T_air_in`` (so the measured temperature is honoured, its composition is the
  nominal one; the burner's unmeasured wander is not known);
* the inlet moisture: ``config.nominal.moisture_in`` (not measured; its day level and wander
  are what the virtual sensor must find);
* wind at the site's median, half cloud cover; no effect (fouling, batches, extra loss).

The measured signals are averaged over ``step_s`` (60 s) bins (a failed read is left out;
a bin without a good value holds the previous one); the walls are stepped with the bin's
inputs. Thermocouple lags and transport delays are not modelled (they matter at seconds, not
at the minutes compared here).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from softsensor.plant.independent import chain
from softsensor.plant.independent.commissioning import commissioned_member
from softsensor.plant.independent.process import Process
from softsensor.plantconfig import PlantConfig

#: Measured scan signals the open-loop run reads.
MEASURED = ("T_air_in", "m_air", "m_fiber", "T_fiber_in", "m_steam", "T_amb", "H_amb")


def _hot_share(process: Process, T_air_in: float, T_hot: float, Y_hot: float, T_amb: float,
               H_amb: float) -> float:
    """Hot-gas share of the dry gas [-] whose mixture with ambient air is at ``T_air_in``
    [K] (bisection: the mixture's temperature rises monotonically with the share)."""
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        T = process.gas_temperature(*process.mixed_gas(mid, T_hot, Y_hot, T_amb, H_amb))
        if T < T_air_in:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def binned_inputs(scans: pd.DataFrame, step_s: float) -> pd.DataFrame:
    """Mean of each measured signal per ``step_s`` bin (bins labelled by their end [ns]),
    a bin without a good value holding the previous bin's."""
    step = int(round(step_s * 1e9))
    t = scans.index.to_numpy(np.int64)
    ends = (t // step + 1) * step
    means = scans[list(MEASURED)].groupby(ends).mean()
    return means.ffill().bfill()


def open_loop_day(scans: pd.DataFrame, config: PlantConfig, plant_seed: int,
                  step_s: float = 60.0) -> pd.DataFrame:
    """The plant's effect-free outputs on the measured inputs of ``scans`` (module
    docstring): a frame indexed by bin end [ns] with ``moisture_out`` [kg/kg dry],
    ``T_dryer_out`` and ``T_cyclone_out`` [K]."""
    member = commissioned_member(int(plant_seed), config)
    st = member.structure
    process = Process(st, config)
    U = binned_inputs(scans, step_s)
    x_in = float(config.nominal.moisture_in)
    out = np.empty((len(U), 3))
    for k, row in enumerate(U.itertuples(index=False)):
        r = row._asdict()
        share = _hot_share(process, r["T_air_in"], st.T_hot, st.Y_hot, r["T_amb"], r["H_amb"])
        e, Y, w = process.mixed_gas(share, st.T_hot, st.Y_hot, r["T_amb"], r["H_amb"])
        u = np.zeros(chain.N_U)
        u[chain.U_M_FIBER] = r["m_fiber"]
        u[chain.U_X_IN] = x_in
        u[chain.U_T_FIBER] = r["T_fiber_in"]
        u[chain.U_M_STEAM] = r["m_steam"]
        u[chain.U_M_GAS] = r["m_air"]
        u[chain.U_E_GAS], u[chain.U_Y_GAS], u[chain.U_W_CO2] = e, Y, w
        u[chain.U_T_AMB] = r["T_amb"]
        u[chain.U_H_AMB] = r["H_amb"]
        u[chain.U_WIND] = st.wind_median
        u[chain.U_CLOUD] = 0.5
        u[chain.U_XFER] = u[chain.U_SURFACE] = u[chain.U_KAPPA_MULT] = 1.0
        u[chain.U_LOSS_MULT] = 1.0
        if k == 0:
            res = process.instant(u)
            process.advance(res, 0.0)  # the walls at their steady state for the first bin
        res = process.instant(u)
        process.advance(res, step_s)
        out[k] = (res.moisture_out, res.T_dryer_out, res.T_cyclone_out)
    if not np.all(np.isfinite(out)):
        bad = int(np.flatnonzero(~np.isfinite(out).all(1))[0])
        raise ArithmeticError(f"open-loop plant: non-finite output at bin {bad}")
    return pd.DataFrame(out, index=U.index, columns=["moisture_out", "T_dryer_out",
                                                     "T_cyclone_out"])


__all__ = ["MEASURED", "binned_inputs", "open_loop_day"]
