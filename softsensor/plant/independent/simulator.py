"""The independent plant's day loop: disturbances, flow, walls, delays, sensors, PI, lab.

Every plant step (the scan period, 10 s) the loop:

1. mixes the burner gas and ambient air at the current flap position and sends the mixture
   down the hot-gas duct (it reaches the tube after the member's dead time);
2. solves the quasi-steady flow through tube, duct and cyclone for the gas now arriving at
   the tube inlet, the fibre now injected and the current wall temperatures, and stamps
   each output with its arrival time at its sensor (gas and fibre transit times of the
   flow, the cyclone's gas residence and fibre hold-up);
3. advances the walls and shells by one step;
4. reads the sensors (true value at the step time, thermocouple lags, noise, bias, the odd
   failed read) and, every control period, lets the PI move the flap command; the flap drive
   follows.

Random streams are split by purpose from the day seed (disturbances, effect, noise, failed
reads, lab), so a day with an effect has the same weather, production and noise as the
clean day of the same seeds; the plant's structure comes from the plant seed alone.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from softsensor.errors import ConfigError
from softsensor.plant.day import DEFAULT_START_NS, KnobSchedule, SimulatedDay, apply_schedule
from softsensor.plant.effects import resolve_effect
from softsensor.plant.independent import chain
from softsensor.plant.independent.commissioning import (
    Commissioned,
    commissioned_member,
    operating_point,
)
from softsensor.plant.independent.control import PV_FILTER, FlapDrive, VelocityPI, simc_tuning
from softsensor.plant.independent.disturbances import Day, UnmeasuredFlow, draw_day
from softsensor.plant.independent.effects import Injection, inject
from softsensor.plant.independent.process import Process
from softsensor.plant.independent.properties import density, dry_gas_molar_mass
from softsensor.plant.independent.sensors import (
    P_MISSING,
    DelayLine,
    FirstOrderLag,
    lab_results,
)
from softsensor.plant.settings import VirtualPlantSettings, virtual_plant_settings
from softsensor.plantconfig import PlantConfig
from softsensor.signals import SCAN_SIGNALS

#: Scan signals that a failed read can blank (the PLC's own values never fail).
_READ_SIGNALS = tuple(n for n in SCAN_SIGNALS if n not in ("flap_cmd", "T_sp"))
#: Columns of the truth frame beyond the contract's six.
TRUTH_EXTRA = ("moisture_tube_out", "flap_position", "m_air", "T_amb")
#: Column of each scan signal in a scan row.
_COL = {name: i for i, name in enumerate(SCAN_SIGNALS)}


def _check_arguments(hours: float, plant_seed: int) -> None:
    if not (isinstance(hours, (int, float)) and math.isfinite(hours) and 0 < hours <= 24 * 60):
        raise ConfigError(f"--hours must be in (0, 1440], got {hours!r}")
    if isinstance(plant_seed, bool) or not isinstance(plant_seed, (int, np.integer)) \
            or plant_seed < 0:
        raise ConfigError(f"--plant-seed must be a non-negative integer, got {plant_seed!r}")


def loop_tuning(member: Commissioned, s: VirtualPlantSettings) -> tuple[float, float]:
    """SIMC PI settings of the member's outlet loop (see :mod:`.control`)."""
    st = member.structure
    tau_sensor = st.sensor_tau["T_dryer_out"]
    tau = max(tau_sensor, s.actuator_tau)
    theta = (st.dead_time + member.nominal["fibre_residence_tube"]
             + 0.5 * min(tau_sensor, s.actuator_tau) + 0.5 * PV_FILTER
             + 0.5 * s.control_period)
    return simc_tuning(max(member.nominal["loop_gain"], 0.05), tau, theta)


class _Plant:
    """The process with its delay lines, in the day loop."""

    def __init__(self, member: Commissioned, config: PlantConfig, day: Day,
                 inj: Injection, moisture_in: np.ndarray, m_gas: np.ndarray) -> None:
        self.process = Process(member.structure, config)
        self.st = member.structure
        self.day = day
        self.inj = inj
        self.moisture_in = moisture_in
        self.cyclone_volume = float(config.cyclone.volume)
        self.pressure = float(config.environment.pressure)

        # every input but the gas arriving at the tube, per step (chain.U_* columns)
        d = day
        U = np.empty((len(d.t), chain.N_U))
        U[:, chain.U_M_FIBER] = d.m_fiber
        U[:, chain.U_X_IN] = moisture_in
        U[:, chain.U_T_FIBER] = d.T_fiber_in
        U[:, chain.U_M_STEAM] = d.m_steam
        U[:, chain.U_M_GAS] = m_gas  # the fan's true flow (the day's, or a surge's)
        U[:, chain.U_T_AMB] = d.T_amb
        U[:, chain.U_H_AMB] = d.H_amb
        U[:, chain.U_WIND] = d.wind
        U[:, chain.U_CLOUD] = d.cloud
        # a chip batch scales the drying rate by inj.batch: half of it (on a log scale)
        # through the fibre's open surface, half through its kinetics
        batch = np.sqrt(inj.batch)
        U[:, chain.U_XFER] = inj.xfer * batch
        U[:, chain.U_SURFACE] = batch
        U[:, chain.U_KAPPA_MULT] = batch
        U[:, chain.U_LOSS_MULT] = [inj.loss_mult(T) for T in d.T_amb]
        self.U = U

    def inputs(self, k: int, e_gas: float, Y_gas: float, w_co2: float) -> np.ndarray:
        """The process inputs of step ``k`` with the gas now arriving at the tube."""
        u = self.U[k].copy()
        u[chain.U_E_GAS] = e_gas
        u[chain.U_Y_GAS] = Y_gas
        u[chain.U_W_CO2] = w_co2
        return u

    def mixed(self, k: int, pos: float) -> tuple[float, float, float]:
        d = self.day
        return self.process.mixed_gas(self.process.hot_fraction(pos), float(d.T_hot[k]),
                                      float(d.Y_hot[k]), float(d.T_amb[k]), float(d.H_amb[k]))

    def cyclone_gas_time(self, res) -> float:
        """Gas residence in the cyclones [s]: volume over volume flow at the outlet."""
        o = res.out
        w = res.u[chain.U_W_CO2] * res.u[chain.U_M_GAS] / o[chain.O_M_CYC]
        rho = density(o[chain.O_T_CYC], o[chain.O_Y_CYC], dry_gas_molar_mass(w), self.pressure)
        return self.cyclone_volume * rho / (o[chain.O_M_CYC] * (1.0 + o[chain.O_Y_CYC]))


@dataclass
class _Loop:
    """The closed loop's state between scans: transport delays of the mixed gas and of the
    outputs, the controller, the flap drive, the sensors' lags and the PI's filtered PV."""

    gas: list[DelayLine]
    lines: dict[str, DelayLine]
    pid: VelocityPI
    drive: FlapDrive
    lags: dict[str, FirstOrderLag]
    pv_filter: FirstOrderLag
    pv: float
    kc: float
    ti: float


def _start_loop(plant: _Plant, member: Commissioned, s: VirtualPlantSettings, day: Day,
                inj: Injection) -> _Loop:
    """The plant at rest, the loop holding the *measured* outlet at the set point."""
    process, st = plant.process, member.structure
    frac0, res0 = operating_point(
        process, lambda f: plant.inputs(0, *process.mixed_gas(
            f, float(day.T_hot[0]), float(day.Y_hot[0]), float(day.T_amb[0]),
            float(day.H_amb[0]))), float(day.T_sp[0]) - inj.bias["T_dryer_out"],
        member.nominal["hot_gas_share"])
    pos0 = process.flap_position(frac0)
    e0, Y0, w0 = plant.mixed(0, pos0)
    T_in0 = process.gas_temperature(e0, Y0, w0)
    lines = {"T_dryer_out": DelayLine(res0.T_dryer_out),
             "T_cyclone_out": DelayLine(res0.T_cyclone_out),
             "moisture_out": DelayLine(res0.moisture_out),
             "moisture_tube_out": DelayLine(res0.moisture_tube_out)}
    kc, ti = loop_tuning(member, s)
    tau = st.sensor_tau
    lags = {"T_air_in": FirstOrderLag(tau["T_air_in"], T_in0),
            "T_air_in_extra": FirstOrderLag(inj.input_lag, T_in0),
            "T_dryer_out": FirstOrderLag(tau["T_dryer_out"], res0.T_dryer_out),
            "T_cyclone_out": FirstOrderLag(tau["T_cyclone_out"], res0.T_cyclone_out),
            "T_fiber_in": FirstOrderLag(tau["T_fiber_in"], float(day.T_fiber_in[0])),
            "T_amb": FirstOrderLag(tau["T_amb"], float(day.T_amb[0]))}
    return _Loop([DelayLine(v) for v in (e0, Y0, w0)], lines,
                 VelocityPI(kc, ti, output=pos0), FlapDrive(s.actuator_tau, s.actuator_rate, pos0),
                 lags, FirstOrderLag(PV_FILTER, float(day.T_sp[0])), float(day.T_sp[0]), kc, ti)


def _step_process(plant: _Plant, loop: _Loop, st: Any, k: int, t: float, dt: float,
                  truth_k: np.ndarray, moisture_in: float, day: Day) -> tuple[float, float, float]:
    """One scan period of the process: the mixed gas through its dead time, the instant
    profile, the outputs into their transport delays; fills the truth row. Returns the true
    ``T_air_in`` and the delayed outlet temperatures."""
    process = plant.process
    pos = loop.drive.position
    for line, v in zip(loop.gas, plant.mixed(k, pos), strict=True):
        line.push(t + st.dead_time, v)
    e_in, Y_in, w_in = (line.at(t) for line in loop.gas)
    res = process.instant(plant.inputs(k, e_in, Y_in, w_in))
    o, lines = res.out, loop.lines
    tg_tube, tg_duct = o[chain.O_TAUG_TUBE], o[chain.O_TAUG_DUCT]
    lines["T_dryer_out"].push(t + tg_tube, res.T_dryer_out)
    lines["T_cyclone_out"].push(t + tg_tube + tg_duct + plant.cyclone_gas_time(res),
                                res.T_cyclone_out)
    lines["moisture_out"].push(t + o[chain.O_TAUP_TUBE] + o[chain.O_TAUP_DUCT] + st.t_hold,
                               res.moisture_out)
    lines["moisture_tube_out"].push(t + o[chain.O_TAUP_TUBE], res.moisture_tube_out)
    process.advance(res, dt)
    T_air = process.gas_temperature(e_in, Y_in, w_in)
    T_do = lines["T_dryer_out"].at(t)
    T_co = lines["T_cyclone_out"].at(t)
    truth_k[:6] = (moisture_in, lines["moisture_out"].at(t), T_air, T_do, T_co, day.m_fiber[k])
    truth_k[6:] = (lines["moisture_tube_out"].at(t), pos, plant.U[k, chain.U_M_GAS],
                   day.T_amb[k])
    return T_air, T_do, T_co


def _measure(row: np.ndarray, z: np.ndarray, missing: np.ndarray, lags: dict[str, FirstOrderLag],
             truth: tuple[float, float, float], day: Day, k: int, inj: Injection,
             s: VirtualPlantSettings, dt: float) -> None:
    """One scan's sensor readings in ``row`` (SCAN_SIGNALS order): lagged, biased under
    ``sensor_bias``, noisy (``z``), NaN where the read failed."""
    col = _COL
    T_air, T_do, T_co = truth
    nt = s.noise_temperature
    air = lags["T_air_in_extra"].update(lags["T_air_in"].update(T_air, dt), dt)
    row[col["T_air_in"]] = air + nt * z[col["T_air_in"]]
    row[col["T_dryer_out"]] = (lags["T_dryer_out"].update(T_do, dt)
                               + inj.bias["T_dryer_out"] + nt * z[col["T_dryer_out"]])
    row[col["T_cyclone_out"]] = (lags["T_cyclone_out"].update(T_co, dt)
                                 + inj.bias["T_cyclone_out"] + nt * z[col["T_cyclone_out"]])
    row[col["T_fiber_in"]] = (lags["T_fiber_in"].update(float(day.T_fiber_in[k]), dt)
                              + nt * z[col["T_fiber_in"]])
    row[col["T_amb"]] = lags["T_amb"].update(float(day.T_amb[k]), dt) + nt * z[col["T_amb"]]
    row[col["m_air"]] = day.m_air[k] * (1.0 + s.noise_flow * z[col["m_air"]])
    row[col["m_fiber"]] = day.m_fiber[k] * (1.0 + s.noise_flow * z[col["m_fiber"]])
    row[col["m_steam"]] = day.m_steam[k] * (1.0 + s.noise_flow * z[col["m_steam"]])
    row[col["H_amb"]] = day.H_amb[k] * (1.0 + s.noise_humidity * z[col["H_amb"]])
    for j, name in enumerate(_READ_SIGNALS):
        if missing[j]:
            row[col[name]] = math.nan


def _control(row: np.ndarray, loop: _Loop, k: int, per_control: int, day: Day,
             dt: float) -> None:
    """The PI on the filtered measured outlet (a failed read holds the filter), every
    ``per_control`` scans; the flap command and set point into ``row``; the drive moves."""
    col = _COL
    if not math.isnan(row[col["T_dryer_out"]]):
        loop.pv = loop.pv_filter.update(row[col["T_dryer_out"]], dt)
    if k % per_control == 0:
        loop.pid.update(float(day.T_sp[k]), loop.pv, dt * per_control)
    row[col["flap_cmd"]] = loop.pid.output
    row[col["T_sp"]] = day.T_sp[k]
    loop.drive.update(loop.pid.output, dt)


def simulate_independent_day(config: PlantConfig, hours: float, seed: int,
                             effect: str | None = None, magnitude: float | None = None, *,
                             plant_seed: int = 0, start_ns: int = DEFAULT_START_NS,
                             schedule: KnobSchedule | None = None,
                             unmeasured_flow: UnmeasuredFlow | None = None) -> SimulatedDay:
    """Run the independent plant for ``hours`` and return the recorded day.

    ``config``: geometry (``tube``, ``cyclone``), nominal point, ambient pressure and the
    ``[virtual_plant]`` settings (its fibre, hot gas and parameters are not used). ``seed``:
    the day (disturbances, effect timing, noise, failed reads, lab). ``effect``,
    ``magnitude``: one effect of :data:`softsensor.plant.effects.EFFECTS` (default magnitude
    when omitted; ``None``: a clean day). ``plant_seed``: the plant, which family member
    (:mod:`.family`), commissioned once and cached. ``start_ns``: time of the first scan
    [ns since the Unix epoch, UTC]. ``schedule``: knob moves ``(t [s], T_sp [K], m_air
    [kg/s])`` in place of the day's set point and fan flow (a designed experiment).
    ``unmeasured_flow``: a surge of the fan's flow that its meter does not see (the recorded
    ``m_air`` keeps the day's own; the truth's ``m_air`` has the surge): a cause outside
    CONTRACT section 5 that the soft sensor's model cannot explain.
    """
    _check_arguments(hours, plant_seed)
    effect, magnitude = resolve_effect(effect, magnitude)
    s = virtual_plant_settings(config)
    member = commissioned_member(int(plant_seed), config)
    st = member.structure
    dt = s.scan_period
    rng_day, rng_eff, rng_noise, rng_miss, rng_lab = (np.random.default_rng([seed, 10 + i])
                                                       for i in range(5))
    day = draw_day(config, s, st, hours, dt, rng_day)
    if schedule is not None:
        T_sp, m_air = apply_schedule(day.t, day.m_air, config.nominal.m_air, schedule)
        day = dataclasses.replace(day, T_sp=T_sp, m_air=m_air)
    inj = inject(effect, magnitude, rng_eff, day.t, seed)
    moisture_in = np.clip(day.moisture_in + inj.moisture_dev, 0.8, 1.3)
    m_gas = day.m_air if unmeasured_flow is None else unmeasured_flow.applied(day.t, day.m_air)
    plant = _Plant(member, config, day, inj, moisture_in, m_gas)
    n = len(day.t)
    loop = _start_loop(plant, member, s, day, inj)
    noise = rng_noise.standard_normal((n, len(SCAN_SIGNALS)))
    missing = rng_miss.random((n, len(_READ_SIGNALS))) < P_MISSING
    per_control = max(1, int(round(s.control_period / dt)))
    scans = np.empty((n, len(SCAN_SIGNALS)))
    truth = np.empty((n, 6 + len(TRUTH_EXTRA)))
    for k in range(n):
        true = _step_process(plant, loop, st, k, float(day.t[k]), dt, truth[k],
                             moisture_in[k], day)
        _measure(scans[k], noise[k], missing[k], loop.lags, true, day, k, inj, s, dt)
        _control(scans[k], loop, k, per_control, day, dt)

    index = pd.Index(start_ns + np.round(day.t * 1e9).astype(np.int64), name="log_time_ns")
    scan_frame = pd.DataFrame(scans, columns=list(SCAN_SIGNALS), index=index)
    truth_frame = pd.DataFrame(truth, columns=["moisture_in", "moisture_out", "T_air_in",
                                               "T_dryer_out", "T_cyclone_out", "m_fiber",
                                               *TRUTH_EXTRA], index=index.copy())
    labs = lab_results(rng_lab, s, hours, start_ns, loop.lines["moisture_out"].at,
                       inj.lab_shift, f"IP{plant_seed}-D{seed}")
    info: dict[str, Any] = dict(inj.info)
    if unmeasured_flow is not None:
        info["unmeasured_flow"] = dataclasses.asdict(unmeasured_flow)
    info.update(plant="independent", plant_seed=int(plant_seed),
                structure=member.describe(),
                loop={"kc_pct_per_K": round(loop.kc, 5), "ti_s": round(loop.ti, 3)})
    return SimulatedDay(scans=scan_frame, labs=labs, truth=truth_frame, effect=info)
