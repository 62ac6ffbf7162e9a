"""The virtual plant: the dryer model in closed loop, with disturbances, sensors and a lab.

A PI controller moves ``flap_cmd`` to hold the measured ``T_dryer_out`` at ``T_sp``; the flap
drive (first-order lag plus rate limit) sets the hot-gas fraction, and the mixing of hot gas
with ambient air gives the true ``T_air_in``. The plant is the same :class:`DryerModel` the
estimators use, stepped every ``control_period`` (20 s by default) with its true parameters
(config values, or a ``PARAMS.toml``), so calibration on its days has a known answer.

Sensors are scanned every ``scan_period`` (10 s) with Gaussian noise (CONTRACT section 6);
the lab samples the true outlet moisture every 2 to 4 hours and reports it 20 to 90 minutes
later with lab-grade noise. One effect of :mod:`softsensor.plant.effects` may be hidden in the
day. The day carries the ground truth on ``/truth/plant`` (every scan) and what was injected on
``/truth/effect`` (once); nothing that estimates, calibrates or diagnoses may read them.

Random streams are split by purpose (scenario, effect, noise, lab), so the same seed gives
the same disturbances with and without an effect.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pandas as pd

from softsensor.errors import ConfigError, SolverError
from softsensor.model import DryerModel
from softsensor.model.geometry import BETA_AMB, N_AUX
from softsensor.plant.controller import OutletLoop
from softsensor.plant.day import (
    DEFAULT_START_NS,
    TOPIC_TRUTH_EFFECT,
    KnobSchedule,
    SimulatedDay,
    apply_schedule,
)
from softsensor.plant.effects import EFFECTS, INJECT, Injection, resolve_effect
from softsensor.plant.scenario import Scenario, make_scenario
from softsensor.plant.settings import VirtualPlantSettings, virtual_plant_settings
from softsensor.plantconfig import PARAMETER_NAMES, PlantConfig
from softsensor.signals import INPUT_NAMES, SCAN_SIGNALS

#: ``SimulatedDay`` and the day constants live in :mod:`softsensor.plant.day` (no model import);
#: they stay importable from here.
__all__ = ["DEFAULT_START_NS", "TOPIC_TRUTH_EFFECT", "SimulatedDay", "initial_operating_point",
           "simulate_day"]


def initial_operating_point(model: DryerModel, u: np.ndarray, theta: np.ndarray,
                             aux: np.ndarray, T_target: float) -> tuple[np.ndarray, float]:
    """Steady state with ``T_air_in`` such that the true ``T_dryer_out`` equals ``T_target``."""
    T = float(u[0])
    for _ in range(30):
        ua = u.copy()
        ua[0] = T
        ub = u.copy()
        ub[0] = T + 1.0
        x, y = model.steady_state(np.stack([ua, ub]), theta, aux)
        gain = y[1, 0] - y[0, 0]
        dT = float(np.clip((T_target - y[0, 0]) / max(gain, 0.05), -60.0, 60.0))
        T = float(np.clip(T + dT, 380.0, 700.0))
        if abs(dT) < 1e-4:
            break
    ua = u.copy()
    ua[0] = T
    x, _ = model.steady_state(ua, theta, aux)
    return x, T


def simulate_day(config: PlantConfig, hours: float, seed: int, effect: str | None = None,
                 magnitude: float | None = None, start_ns: int = DEFAULT_START_NS,
                 schedule: KnobSchedule | None = None) -> SimulatedDay:
    """Run the virtual plant for ``hours`` and return the recorded day.

    Parameters
    ----------
    config : PlantConfig
        Plant and true parameters (``config.parameters``), ``[virtual_plant]`` settings.
    hours : float
        Length of the record [h].
    seed : int
        Seed of every random stream.
    effect, magnitude :
        One effect of :data:`softsensor.plant.effects.EFFECTS` and its magnitude (default
        magnitude when omitted); ``None`` for a clean day.
    start_ns : int
        Time of the first scan [ns since the Unix epoch, UTC].
    schedule : (t [s], T_sp [K], m_air [kg/s]), optional
        Knob moves the operator makes (a designed experiment) in place of the day's own set
        point and fan flow (:func:`~softsensor.plant.day.apply_schedule`).
    """
    if not (isinstance(hours, (int, float)) and math.isfinite(hours) and 0 < hours <= 24 * 60):
        raise ConfigError(f"--hours must be in (0, 1440], got {hours!r}")
    effect, magnitude = resolve_effect(effect, magnitude)
    s = virtual_plant_settings(config)
    rng_scen = np.random.default_rng([seed, 0])
    rng_eff = np.random.default_rng([seed, 1])
    rng_noise = np.random.default_rng([seed, 2])
    rng_lab = np.random.default_rng([seed, 3])
    sc = make_scenario(config, s, hours, rng_scen)
    if schedule is not None:
        T_sp, m_air = apply_schedule(sc.t, sc.m_air, config.nominal.m_air, schedule)
        sc = dataclasses.replace(sc, T_sp=T_sp, m_air=m_air)
    theta = np.tile(config.parameter_vector(), (len(sc.t), 1))
    info: dict[str, Any] = {"effect": effect or "none", "magnitude": magnitude,
                            "unit": EFFECTS[effect].unit if effect else "", "seed": seed,
                            "channel": None,
                            "parameters": dict(zip(PARAMETER_NAMES, map(float, theta[0]),
                                                   strict=True))}
    inj = Injection(t=sc.t, theta=theta, moisture_in=sc.moisture_in.copy(),
                    nominal_moisture_in=config.nominal.moisture_in, info=info)
    if effect:
        INJECT[effect](inj, rng_eff, magnitude)
    true, meas_air = _closed_loop(config, s, sc, inj, rng_noise)
    scans, truth = _scans_and_truth(s, sc, inj, true, meas_air, rng_noise, hours, start_ns)
    labs = _lab_samples(rng_lab, s, hours, start_ns, sc.t, true[:, 3], inj.lab_shift, seed)
    return SimulatedDay(scans=scans, labs=labs, truth=truth, effect=info)


def _closed_loop(config: PlantConfig, s: VirtualPlantSettings, sc: Scenario, inj: Injection,
                 rng_noise: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Step the plant and its outlet-temperature loop over the scenario.

    Returns the true values per control step, columns (``T_air_in``, ``T_dryer_out``,
    ``T_cyclone_out``, ``moisture_out``, ``moisture_in``, ``flap_cmd``), and the ``T_air_in``
    sensor's noise-free reading (lagged under ``input_lag``).
    """
    n = len(sc.t)
    dt = s.control_period
    model = DryerModel(config)
    theta, bias, moisture_in = inj.theta, inj.bias, inj.moisture_in
    aux = np.zeros(N_AUX)
    aux[BETA_AMB] = inj.beta_amb
    series = {"m_air": sc.m_air, "m_fiber": sc.m_fiber, "T_fiber_in": sc.T_fiber_in,
              "m_steam": sc.m_steam, "T_amb": sc.T_amb, "H_amb": sc.H_amb,
              "moisture_in": moisture_in}

    def inputs(k: int, T_air: float) -> np.ndarray:
        return np.array([T_air if name == "T_air_in" else series[name][k]
                         for name in INPUT_NAMES])

    # start in steady state, the loop holding the measured outlet temperature at T_sp
    u0 = inputs(0, config.nominal.T_air_in)
    state, T_air = initial_operating_point(model, u0, theta[0], aux,
                                            sc.T_sp[0] - bias["T_dryer_out"])
    loop = OutletLoop(config.hot_gas, s, T_air, sc.T_amb[0], sc.H_amb[0], sc.T_sp[0])
    T_air_sensor = T_air
    plant = model.control_stepper(dt)
    true = np.empty((n, 6))  # T_air_in, T_dryer_out, T_cyclone_out, moisture_out, in, cmd
    meas_air = np.empty(n)
    for k in range(n):
        u = inputs(k, T_air)
        try:
            y = plant.advance(state, u, theta[k], aux)
        except SolverError as exc:
            raise SolverError(f"virtual plant: model failed at t={sc.t[k]:.0f} s: {exc}") from exc
        true[k] = (T_air, y[0], y[1], y[2], moisture_in[k], loop.cmd)
        if inj.lag_tau > 0:
            T_air_sensor += (T_air - T_air_sensor) * (1.0 - math.exp(-dt / inj.lag_tau))
        else:
            T_air_sensor = T_air
        meas_air[k] = T_air_sensor
        measured = y[0] + bias["T_dryer_out"] + rng_noise.normal(0.0, s.noise_temperature)
        nxt = min(k + 1, n - 1)
        T_air = loop.step(sc.T_sp[k], measured, dt, sc.T_amb[nxt], sc.H_amb[nxt])
    return true, meas_air


def _scans_and_truth(s: VirtualPlantSettings, sc: Scenario, inj: Injection, true: np.ndarray,
                     meas_air: np.ndarray, rng_noise: np.random.Generator, hours: float,
                     start_ns: int) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Scans every ``scan_period`` with sensor noise, holding the plant's last control step,
    and the ground truth at the same times."""
    dt = s.control_period
    n = len(sc.t)
    per = int(round(dt / s.scan_period)) if dt >= s.scan_period else 1
    n_scan = int(round(hours * 3600.0 / s.scan_period)) + 1
    ks = np.minimum(np.arange(n_scan) // per, n - 1)
    t_scan = start_ns + np.round(np.arange(n_scan) * s.scan_period * 1e9).astype(np.int64)
    # one column of standard normals per scan signal, in SCAN_SIGNALS order
    rn = dict(zip(SCAN_SIGNALS, rng_noise.standard_normal((n_scan, len(SCAN_SIGNALS))).T,
                  strict=True))
    nt, nf, nh = s.noise_temperature, s.noise_flow, s.noise_humidity
    columns = {
        "T_air_in": meas_air[ks] + nt * rn["T_air_in"],
        "m_air": sc.m_air[ks] * (1 + nf * rn["m_air"]),
        "m_fiber": sc.m_fiber[ks] * (1 + nf * rn["m_fiber"]),
        "T_fiber_in": sc.T_fiber_in[ks] + nt * rn["T_fiber_in"],
        "m_steam": sc.m_steam[ks] * (1 + nf * rn["m_steam"]),
        "T_amb": sc.T_amb[ks] + nt * rn["T_amb"],
        "H_amb": sc.H_amb[ks] * (1 + nh * rn["H_amb"]),
        "flap_cmd": true[ks, 5],
        "T_sp": sc.T_sp[ks],
        "T_dryer_out": true[ks, 1] + inj.bias["T_dryer_out"] + nt * rn["T_dryer_out"],
        "T_cyclone_out": true[ks, 2] + inj.bias["T_cyclone_out"] + nt * rn["T_cyclone_out"],
    }
    scans = pd.DataFrame({name: columns[name] for name in SCAN_SIGNALS},
                         index=pd.Index(t_scan, name="log_time_ns"))
    truth = pd.DataFrame({
        "moisture_in": true[ks, 4], "moisture_out": true[ks, 3], "T_air_in": true[ks, 0],
        "T_dryer_out": true[ks, 1], "T_cyclone_out": true[ks, 2],
        "m_fiber": sc.m_fiber[ks],
    }, index=scans.index.copy())
    return scans, truth


def _lab_samples(rng: np.random.Generator, s, hours: float, start_ns: int, t: np.ndarray,
                 moisture_out: np.ndarray, shift: float, seed: int) -> pd.DataFrame:
    """Lab schedule: a sample every 2-4 h, reported 20-90 min later with lab noise.

    With the ``lab_delay`` effect the stamped sample time is off by ``shift`` seconds; the
    report delay is drawn so that the stamped delay stays within 20-90 minutes.
    """
    rows = []
    end = hours * 3600.0
    ts = rng.uniform(0.5, 2.0) * 3600.0
    i = 0
    while True:
        delay_lo, delay_hi = s.lab_delay_min, s.lab_delay_max
        delay = rng.uniform(max(delay_lo, delay_lo + shift), max(delay_lo + shift + 60.0,
                                                                 delay_hi + min(shift, 0.0)))
        if ts + delay > end:
            break
        value = float(np.interp(ts, t, moisture_out)) + rng.normal(0.0, s.noise_lab)
        rows.append({"log_time_ns": start_ns + int((ts + delay) * 1e9),
                     "sample_time_ns": start_ns + int((ts + shift) * 1e9),
                     "moisture_out": max(value, 0.0), "sample_id": f"S{seed}-{i:03d}"})
        i += 1
        ts += rng.uniform(s.lab_interval_min, s.lab_interval_max)
    return pd.DataFrame(rows, columns=["log_time_ns", "sample_time_ns", "moisture_out",
                                       "sample_id"])
