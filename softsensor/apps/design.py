"""``softsensor design``: a closed-loop experiment that makes the calibration identifiable.

The search is :mod:`softsensor.calibration.experiment_design` (no I/O); this module supplies what
the core may not import: the plant's outlet-temperature loop (:mod:`softsensor.plant.controller`:
PI, flap drive, hot-gas mixing) around the calibrated model, the operating point of a recorded day
or of the config, a virtual plant to "record" a designed period on (``--rounds``), and the
files an operator follows: ``schedule.csv`` and ``schedule.json`` (time, ``T_sp`` [K],
``m_air`` [kg/s]), ``prediction.csv``, ``design.png`` and ``design.svg`` (schedule and
predicted outputs with the limits drawn), ``design.json`` (the information gain over the same
hours of natural operation, and the rounds). Errors are one line and exit status 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from softsensor.apps.loading import load_config_and_params, read_day_inputs
from softsensor.apps.verb_output import say, write_json
from softsensor.calibration.dataset import DayLike, Segment, segment_from_day
from softsensor.calibration.experiment_design import (
    CRITERIA,
    DesignLimits,
    DesignProblem,
    DesignResult,
    Information,
    Prediction,
    Schedule,
    gain,
    information,
    optimise,
    sequential,
)
from softsensor.calibration.identifiability import prior_sd
from softsensor.calibration.params_file import read_fit
from softsensor.calibration.settings import CalibrationSettings, calibration_settings
from softsensor.errors import ConfigError, require_packages
from softsensor.files import writing
from softsensor.ingest.tables import write_table
from softsensor.model import DryerModel
from softsensor.model.geometry import N_AUX
from softsensor.plant.controller import OutletLoop
from softsensor.plant.day import DEFAULT_START_NS
from softsensor.plant.settings import virtual_plant_settings
from softsensor.plant.simulator import initial_operating_point
from softsensor.plantconfig import PARAMETER_NAMES, PlantConfig
from softsensor.presentation.display import C0, T_H_PER_KG_S
from softsensor.signals import INPUT_NAMES, OUTPUT_NAMES

I_T_AIR, I_M_AIR = INPUT_NAMES.index("T_air_in"), INPUT_NAMES.index("m_air")
I_T_AMB, I_H_AMB = INPUT_NAMES.index("T_amb"), INPUT_NAMES.index("H_amb")
#: Channel noise [K, K, kg/kg] when the params file has no fit: the virtual plant's sensor
#: noise (0.5 K) and lab noise (0.003 kg/kg), CONTRACT section 6.
DEFAULT_NOISE = np.array([0.5, 0.5, 0.003])
#: Hours the plant is recorded past a designed period, so that the lab results of samples
#: taken near its end (reported 20 to 90 min later) are in the record.
LAB_TAIL_HOURS = 1.5


class ModelLoop:
    """The plant's outlet-temperature loop around the model
    (:class:`~softsensor.calibration.experiment_design.ClosedLoop`).

    Disturbances are held at the operating point ``u0`` (8,) (``INPUT_NAMES`` order, SI);
    every ``dt`` [s] (the virtual plant's control period) the PI (``kp`` [%/K], ``ti`` [s] of
    ``[virtual_plant]``) moves the flap command from the *noise-free* outlet temperature, the
    flap drive follows and the mixing of hot gas with ambient air gives ``T_air_in``: the
    :class:`~softsensor.plant.controller.OutletLoop` the virtual plant steps, without its
    noise and disturbances.
    """

    def __init__(self, config: PlantConfig, u0: np.ndarray, T_sp0: float) -> None:
        self.config = config
        self.model = DryerModel(config)
        self.settings = virtual_plant_settings(config)
        self.dt = float(self.settings.control_period)
        self.u0 = np.asarray(u0, float).copy()
        self.T_sp0 = float(T_sp0)
        self.m_air0 = float(self.u0[I_M_AIR])

    def run(self, schedule: Schedule, theta: np.ndarray) -> Prediction:
        """Predict ``schedule`` at parameters ``theta`` (7,); raises SolverError."""
        theta = np.asarray(theta, float)
        aux = np.zeros(N_AUX)
        u = self.u0.copy()
        u[I_M_AIR] = schedule.m_air[0]
        T_sp0 = float(schedule.T_sp[0])
        # steady state holding T_sp0, the loop bumpless at the flaps that give it
        state, T_air = initial_operating_point(self.model, u, theta, aux, T_sp0)
        T_amb, H_amb = u[I_T_AMB], u[I_H_AMB]  # ambient held at the operating point
        loop = OutletLoop(self.config.hot_gas, self.settings, T_air, T_amb, H_amb, T_sp0)
        stepper = self.model.control_stepper(self.dt)
        n = len(schedule.t)
        U, Y, flap = np.empty((n, len(INPUT_NAMES))), np.empty((n, 3)), np.empty(n)
        for k in range(n):
            u = self.u0.copy()
            u[I_T_AIR], u[I_M_AIR] = T_air, schedule.m_air[k]
            Y[k] = stepper.advance(state, u, theta, aux)
            U[k], flap[k] = u, loop.cmd
            T_air = loop.step(float(schedule.T_sp[k]), float(Y[k, 0]), self.dt, T_amb, H_amb)
        return Prediction(t=schedule.t, U=U, Y=Y, flap=flap)


@dataclasses.dataclass(frozen=True)
class OperatingPoint:
    """Where the design starts: model inputs ``u`` (8,) and set point ``T_sp`` [K], the start
    of the designed period [ns], and the natural segment of the same hours (None without a
    recorded day)."""

    u: np.ndarray
    T_sp: float
    start_ns: int
    natural: Segment | None
    source: str


def operating_point(config: PlantConfig, day: str | None, hours: float) -> OperatingPoint:
    """The median inputs and set point of a recorded ``day`` (its first ``hours`` are the
    natural reference), else the config's nominal point."""
    if day is None:
        return OperatingPoint(config.nominal_inputs(), float(config.nominal.T_sp),
                              DEFAULT_START_NS, None, "config nominal point")
    return operating_point_of(read_day_inputs(day), config, hours, str(day))


def operating_point_of(rec: DayLike, config: PlantConfig, hours: float,
                       source: str) -> OperatingPoint:
    """The operating point of a recorded (or simulated) day: median inputs and set point,
    the designed period starting at its end, its first ``hours`` the natural reference."""
    seg = segment_from_day(rec, config, source=source)
    u = np.nanmedian(seg.U, axis=0)
    T_sp = float(np.nanmedian(rec.scans["T_sp"].to_numpy(float)))
    k = min(seg.n_windows, max(1, int(round(hours * 3600.0 / seg.window))))
    return OperatingPoint(u, T_sp, seg.end_ns, seg.slice(0, k), f"median of {source}")


def channel_noise(params: str | None) -> np.ndarray:
    """Per-channel noise [K, K, kg/kg]: the RMSE the calibration left (``[fit] rmse`` of the
    params file), else :data:`DEFAULT_NOISE`."""
    if params:
        rmse = read_fit(params).get("rmse")
        if isinstance(rmse, dict) and all(isinstance(rmse.get(c), (int, float))
                                          for c in OUTPUT_NAMES):
            return np.maximum([float(rmse[c]) for c in OUTPUT_NAMES], [0.01, 0.01, 1e-4])
    return DEFAULT_NOISE.copy()


def build_problem(base: PlantConfig, config: PlantConfig, op: OperatingPoint,
                  limits: DesignLimits, calibration: CalibrationSettings, noise: np.ndarray,
                  kind: str = "D", names: Sequence[str] = ()) -> DesignProblem:
    """The design problem at ``config``'s parameters (checked: one-line ConfigError)."""
    from softsensor.calibration.calibration_run import objective_spec  # Optuna: the offline extra

    msg = limits.check(op.T_sp, float(op.u[I_M_AIR]))
    if msg:
        raise ConfigError(msg)
    loop = ModelLoop(config, op.u, op.T_sp)
    model = loop.model
    theta = config.parameter_vector()
    probe = _natural_probe(loop, limits, theta, op)
    spec = objective_spec(model, [probe], base, calibration)
    problem = DesignProblem(model=model, loop=loop, theta=theta, spec=spec, limits=limits,
                            noise=np.asarray(noise, float), prior_sd=prior_sd(spec, base.bounds()),
                            window=float(config.solver.window), start_ns=op.start_ns,
                            kind=kind, names=tuple(names))
    problem.check()
    return problem


def _natural_probe(loop: ModelLoop, limits: DesignLimits, theta: np.ndarray,
                   op: OperatingPoint) -> Segment:
    """The constant schedule's predicted segment (sets the objective's prior scale)."""
    from softsensor.calibration.experiment_design import (
        constant_levels,
        prediction_segment,
        schedule_from_levels,
    )

    sched = schedule_from_levels(constant_levels(limits, loop.T_sp0, loop.m_air0), limits,
                                 loop.T_sp0, loop.m_air0, loop.dt)
    return prediction_segment(loop.run(sched, theta), loop.config.solver.window,
                              limits.lab_minutes, op.start_ns)


# ------------------------------------------------------------------ recording on a plant
def record_schedule(truth: PlantConfig, schedule: Schedule, limits: DesignLimits, seed: int,
                    plant: str = "model", plant_seed: int = 0,
                    start_ns: int = DEFAULT_START_NS) -> Segment:
    """Run ``schedule`` on a virtual plant (``"model"``: the matched plant with ``truth``'s
    parameters; ``"independent"``) with a lab sample every ``lab_minutes``, and return the
    designed period as a calibration segment (recorded :data:`LAB_TAIL_HOURS` longer so the
    last samples' results arrive, then cut to the period)."""
    vp = {**truth.extra.get("virtual_plant", {}), "lab_interval_min": 60.0 * limits.lab_minutes,
          "lab_interval_max": 60.0 * limits.lab_minutes}
    cfg = dataclasses.replace(truth, extra={**truth.extra, "virtual_plant": vp})
    knobs = (schedule.t, schedule.T_sp, schedule.m_air)
    hours = limits.hours + LAB_TAIL_HOURS
    if plant == "independent":
        from softsensor.plant.independent import simulate_independent_day

        day = simulate_independent_day(cfg, hours, seed, plant_seed=plant_seed,
                                       start_ns=start_ns, schedule=knobs)
    elif plant == "model":
        from softsensor.plant.simulator import simulate_day

        day = simulate_day(cfg, hours, seed, start_ns=start_ns, schedule=knobs)
    else:
        raise ConfigError(f"--plant must be model or independent, got {plant!r}")
    seg = segment_from_day(day, cfg, source=f"designed {plant} plant seed {seed}")
    k = min(seg.n_windows, int(round(limits.hours * 3600.0 / seg.window)))
    return seg.slice(0, k)


def recalibrator(base: PlantConfig, calibration: CalibrationSettings, trials: int, seed: int
                 ) -> Callable[[list[Segment], np.ndarray], np.ndarray]:
    """``softsensor calibrate``'s fit (study, polish; no hold-out, no identify) as a function
    of the recorded segments; the current estimate is what the result must beat."""
    from softsensor.calibration.calibration_run import calibrate
    from softsensor.calibration.optimize import StudySettings

    def fit(segments: list[Segment], theta: np.ndarray) -> np.ndarray:
        study = StudySettings(n_trials=trials, seed=seed, progress=False)
        res = calibrate(segments, base, study, calibration, validation_segments=[],
                        current_theta=theta, identify_result=False)
        return np.asarray(res.theta, float)

    return fit


def assessor(base: PlantConfig, calibration: CalibrationSettings
             ) -> Callable[[list[Segment], np.ndarray], Information]:
    """Standard errors on recorded segments at an estimate, with the noise the fit leaves
    (as ``softsensor identify`` takes it)."""
    model = DryerModel(base)

    def assess(segments: list[Segment], theta: np.ndarray) -> Information:
        from softsensor.calibration.calibration_run import objective_spec

        spec = objective_spec(model, segments, base, calibration)
        return information(model, segments, theta, spec, None, prior_sd(spec, base.bounds()))

    return assess


# ------------------------------------------------------------------ files
def schedule_rows(schedule: Schedule, start_ns: int, step_s: float = 60.0
                  ) -> list[dict[str, Any]]:
    """The schedule every ``step_s`` [s] (one row a minute by default) for the operator."""
    from softsensor.messages import iso_utc

    t = np.arange(0.0, schedule.t[-1] + 1e-9, step_s)
    T = np.interp(t, schedule.t, schedule.T_sp)
    m = np.interp(t, schedule.t, schedule.m_air)
    # SI for programs, and what the operator types into the DCS: °C and t/h
    return [{"time_s": float(ti), "time_utc": iso_utc(start_ns + int(ti * 1e9)),
             "T_sp_K": round(float(a), 3), "m_air_kg_s": round(float(b), 4),
             "T_sp_degC": round(float(a) - C0, 2), "m_air_t_h": round(float(b) * T_H_PER_KG_S, 2)}
            for ti, a, b in zip(t, T, m, strict=True)]


def prediction_rows(pred: Prediction) -> list[dict[str, Any]]:
    """Per control step: time [s], knobs, ``T_air_in`` [K], flap command [%], outputs."""
    return [{"time_s": float(t), "T_air_in_K": round(float(u[I_T_AIR]), 3),
             "m_air_kg_s": round(float(u[I_M_AIR]), 4), "flap_cmd_pct": round(float(f), 3),
             "T_dryer_out_K": round(float(y[0]), 3), "T_cyclone_out_K": round(float(y[1]), 3),
             "moisture_out_kg_kg": round(float(y[2]), 5)}
            for t, u, y, f in zip(pred.t, pred.U, pred.Y, pred.flap, strict=True)]


def design_figure(result: DesignResult, limits: DesignLimits, directory: Path) -> list[Path]:
    """Schedule and predicted outputs, designed and natural, with the limits drawn (PNG and
    SVG). Hours from the start; in plant units, as the options: temperatures in °C, the air
    flow in t/h, moisture in kg/kg (dry basis)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    best, nat = result.best, result.natural
    h = best.schedule.t / 3600.0
    fig, axes = plt.subplots(5, 1, figsize=(11, 11), sharex=True)
    series = [("T_sp [°C]", best.schedule.T_sp - C0, nat.schedule.T_sp - C0,
               tuple(v - C0 for v in limits.T_sp_band)),
              ("m_air [t/h]", best.schedule.m_air * T_H_PER_KG_S, nat.schedule.m_air * T_H_PER_KG_S,
               tuple(v * T_H_PER_KG_S for v in limits.m_air_band)),
              ("T_dryer_out [°C]", best.prediction.Y[:, 0] - C0,
               nat.prediction.Y[:, 0] - C0, None),
              ("T_air_in [°C]", best.prediction.U[:, I_T_AIR] - C0,
               nat.prediction.U[:, I_T_AIR] - C0, None),
              ("moisture_out [kg/kg]", best.prediction.Y[:, 2], nat.prediction.Y[:, 2],
               (result.baseline - limits.moisture_excursion,
                result.baseline + limits.moisture_excursion))]
    for ax, (label, y, y0, band) in zip(axes, series, strict=True):
        ax.plot(h, y0, "-", color="tab:gray", lw=1.0, label="natural (constant)")
        ax.plot(h, y, "-", color="tab:red", lw=1.3, label="designed")
        if band is not None:
            for v in band:
                ax.axhline(v, color="k", ls="--", lw=0.8)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for lab in best.segment.lab_time_ns:
        axes[4].axvline((lab - best.segment.start_ns) / 3.6e12, color="tab:green", lw=0.6,
                        alpha=0.5)
    axes[0].legend(fontsize=8, loc="upper right")
    axes[0].set_title("Designed experiment: schedule and predicted closed-loop outputs "
                      "(dashed: limits; green: lab samples)")
    axes[-1].set_xlabel("hours from the start of the designed period")
    fig.tight_layout()
    out = [directory / "design.png", directory / "design.svg"]
    fig.savefig(out[0], dpi=110)
    fig.savefig(out[1])
    plt.close(fig)
    return out


def write_outputs(directory: Path, result: DesignResult, limits: DesignLimits,
                  start_ns: int, doc: dict[str, Any]) -> dict[str, str]:
    """Every file of the verb in ``directory``; returns their paths by kind."""
    rows = schedule_rows(result.best.schedule, start_ns)
    files = {"schedule_csv": directory / "schedule.csv",
             "prediction_csv": directory / "prediction.csv"}
    for key, table in (("schedule_csv", rows),
                       ("prediction_csv", prediction_rows(result.best.prediction))):
        with writing(files[key]) as tmp:
            write_table(pd.DataFrame(table), tmp)
    write_json({"start_utc": rows[0]["time_utc"], "limits": dataclasses.asdict(limits),
                "schedule": rows}, directory / "schedule.json")
    files["schedule_json"] = directory / "schedule.json"
    png, svg = design_figure(result, limits, directory)
    files.update(figure_png=png, figure_svg=svg, summary_json=directory / "design.json")
    doc["files"] = {k: str(v) for k, v in files.items()}
    write_json(doc, directory / "design.json")
    return doc["files"]


# ------------------------------------------------------------------ the verb
def add_design_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the files")
    p.add_argument("--params", default=None, metavar="PARAMS.toml",
                   help="calibrated parameters (default: the config's values)")
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")
    p.add_argument("--day", default=None, metavar="DAY.mcap",
                   help="recorded day: its median inputs are the operating point and its "
                        "first --hours the natural reference (default: the config's nominal)")
    p.add_argument("--hours", type=float, default=6.0, help="designed period [h] (default 6)")
    p.add_argument("--T-sp-band", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
                   help="set-point band [°C] (default: operating point +-2 °C)")
    p.add_argument("--T-sp-rate", type=float, default=0.5,
                   help="largest set-point rate [°C/min] (default 0.5)")
    p.add_argument("--m-air-band", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
                   help="air-flow band [t/h] (default: operating point +-5 %%)")
    p.add_argument("--m-air-rate", type=float, default=7.2,
                   help="largest air-flow rate [t/h per min] (default 7.2, i.e. 2 kg/s)")
    p.add_argument("--quiet", action="store_true",
                   help="no progress lines on stderr (the last line stays)")
    p.add_argument("--max-moisture-excursion", type=float, default=0.01,
                   help="bound on the predicted outlet moisture's distance from the operating "
                        "point's [kg/kg] (default 0.01)")
    p.add_argument("--move-minutes", type=float, default=30.0,
                   help="shortest hold of a level [min] (default 30)")
    p.add_argument("--lab-minutes", type=float, default=30.0,
                   help="lab sampling interval during the period [min] (default 30)")
    p.add_argument("--criterion", choices=CRITERIA, default="D",
                   help="D: ln det of the weighted FIM (default); A: trace of the covariance "
                        "of the --names parameters")
    p.add_argument("--names", default="", help="parameters of the A criterion, comma-separated "
                                               "(default: all seven)")
    p.add_argument("--budget", type=int, default=30, help="evaluations of the search")
    p.add_argument("--random", type=int, default=6, help="random PRBS candidates first")
    p.add_argument("--seed", type=int, default=0, help="search (and plant day) seed")
    p.add_argument("--rounds", type=int, default=0,
                   help="sequential design: record, re-calibrate and re-design this many "
                        "rounds on a virtual plant (default 0: design only)")
    p.add_argument("--plant", choices=("model", "independent"), default="model",
                   help="the virtual plant of --rounds (default model: the config's values)")
    p.add_argument("--plant-seed", type=int, default=0, help="independent plant seed")
    p.add_argument("--trials", type=int, default=40, help="study trials per re-calibration")


def limits_from_args(args: argparse.Namespace, op: OperatingPoint) -> DesignLimits:
    """The limits of the command line (°C and t/h, as the plant speaks), in SI; defaults
    around the operating point. A band is checked in the units it was given in."""
    m0 = float(op.u[I_M_AIR])
    for flag, band, at, unit in (("--T-sp-band", args.T_sp_band, op.T_sp - C0, "°C"),
                                 ("--m-air-band", args.m_air_band, m0 * T_H_PER_KG_S, "t/h")):
        if band is None:
            continue
        lo, hi = band
        if not lo < hi:
            raise ConfigError(f"{flag} must be LOW < HIGH [{unit}], got {lo:g} {hi:g}")
        if not lo <= at <= hi:
            raise ConfigError(f"{flag} {lo:g} {hi:g} [{unit}]: the operating point's "
                              f"{at:.4g} {unit} lies outside its band")
    T_band = (tuple(v + C0 for v in args.T_sp_band) if args.T_sp_band
              else (op.T_sp - 2.0, op.T_sp + 2.0))
    m_band = (tuple(v / T_H_PER_KG_S for v in args.m_air_band) if args.m_air_band
              else (0.95 * m0, 1.05 * m0))
    limits = DesignLimits(T_sp_band=T_band, m_air_band=m_band, T_sp_rate=args.T_sp_rate,
                          m_air_rate=args.m_air_rate / T_H_PER_KG_S,
                          moisture_excursion=args.max_moisture_excursion, hours=args.hours,
                          move_minutes=args.move_minutes, lab_minutes=args.lab_minutes)
    msg = limits.check(op.T_sp, m0)
    if msg:
        raise ConfigError(msg)
    return limits


def _names(args: argparse.Namespace) -> tuple[str, ...]:
    """The parameters of ``--names`` (the A criterion)."""
    return tuple(n.strip() for n in args.names.split(",") if n.strip())


def _check_args(args: argparse.Namespace) -> None:
    for flag, v, lo, hi in (("--budget", args.budget, 0, 100_000),
                            ("--random", args.random, 0, 100_000),
                            ("--rounds", args.rounds, 0, 20), ("--trials", args.trials, 1, 10_000)):
        if not lo <= v <= hi:  # a typo of a few digits must not mean a search of days
            raise ConfigError(f"{flag} must be in {lo}..{hi}, got {v}")
    if not (math.isfinite(args.hours) and 0 < args.hours <= 48):
        raise ConfigError(f"--hours must be in (0, 48], got {args.hours:g}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: exists and is not a directory")


def design_main(args: argparse.Namespace) -> int:
    """``softsensor design``: search, files, and optionally sequential rounds."""
    require_packages("design", "optuna", "matplotlib")
    _check_args(args)
    base, config = load_config_and_params(args)
    op = operating_point(config, args.day, args.hours)
    limits = limits_from_args(args, op)
    names = _names(args)
    calibration = calibration_settings(base)
    noise = channel_noise(args.params)
    problem = build_problem(base, config, op, limits, calibration, noise, args.criterion, names)
    quiet = args.quiet or not sys.stderr
    if not quiet:
        say("design", f"operating point: {op.source} (T_sp {op.T_sp - C0:.1f} °C, m_air "
                      f"{float(op.u[I_M_AIR]) * T_H_PER_KG_S:.0f} t/h); {limits.n_moves} moves of "
                      f"{limits.move_minutes:g} min per knob, budget {args.budget}")
    result = optimise(problem, seed=args.seed, n_random=args.random, budget=args.budget,
                      say=None if quiet else (lambda s: say("design", s)))
    natural = result.natural.info
    if op.natural is not None:  # the same hours of the recorded day, as they were
        natural = information(problem.model, [op.natural], problem.theta, problem.spec,
                              noise, problem.prior_sd)
    doc: dict[str, Any] = {
        "operating_point": {"source": op.source, "T_sp_K": op.T_sp,
                            "inputs": dict(zip(INPUT_NAMES, map(float, op.u), strict=True))},
        "limits": dataclasses.asdict(limits), "criterion": args.criterion, "names": names,
        "noise": dict(zip(OUTPUT_NAMES, map(float, noise), strict=True)),
        "natural_reference": "recorded day" if op.natural is not None else "constant schedule",
        "design": {"criterion": result.best.score, "excursion": result.best.excursion,
                   "shrink": result.best.shrink, "levels": result.best.schedule.levels,
                   **result.best.info.as_dict()},
        "natural": natural.as_dict(), "gain": gain(result.best.info, natural),
        "evaluations": len(result.history)}
    if args.rounds:
        doc["rounds"] = run_rounds(args, base, config, op, limits, calibration, noise)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_outputs(out, result, limits, op.start_ns, doc)
    g = doc["gain"]
    say("design", f"wrote {out}: ln det ratio {g['logdet_ratio_weighted_fim']:.2f} (weighted "
                  f"FIM), condition number {result.best.info.condition:.3g} vs "
                  f"{natural.condition:.3g} natural; largest predicted moisture excursion "
                  f"{result.best.excursion:.4f} kg/kg")
    return 0


def run_rounds(args: argparse.Namespace, base: PlantConfig, config: PlantConfig,
               op: OperatingPoint, limits: DesignLimits, calibration: CalibrationSettings,
               noise: np.ndarray) -> list[dict[str, Any]]:
    """``--rounds``: sequential design on a virtual plant, standard errors after each."""
    def design_at(theta: np.ndarray) -> DesignResult:
        at = config.with_parameters(np.asarray(theta, float))
        prob = build_problem(base, at, op, limits, calibration, noise, args.criterion,
                             _names(args))
        return optimise(prob, seed=args.seed, n_random=args.random, budget=args.budget)

    def record(schedule: Schedule, r: int) -> Segment:
        start = op.start_ns + int(r * (limits.hours + LAB_TAIL_HOURS) * 3600 * 1e9)
        return record_schedule(base, schedule, limits, args.seed + 1 + r, args.plant,
                               args.plant_seed, start)

    rounds = sequential(design_at, record, recalibrator(base, calibration, args.trials,
                                                        args.seed),
                        assessor(base, calibration), config.parameter_vector(), args.rounds)
    out = []
    for r in rounds:
        if args.quiet:
            continue
        say("design", f"round {r.index + 1}: s.e. " + ", ".join(
            f"{n} {100 * s:.0f} %" for n, s in zip(PARAMETER_NAMES, r.se, strict=True)))
        out.append({"round": r.index + 1, "criterion": r.criterion,
                    "condition_number": r.condition,
                    "theta": dict(zip(PARAMETER_NAMES, map(float, r.theta), strict=True)),
                    "relative_se": dict(zip(PARAMETER_NAMES, map(float, r.se), strict=True))})
    return out


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``design`` on the ``softsensor`` parser."""
    p = sub.add_parser("design", help="a closed-loop experiment (T_sp and m_air moves) that "
                                      "makes the calibration identifiable")
    add_design_arguments(p)
    p.set_defaults(func=design_main)


__all__ = ["ModelLoop", "add_commands", "add_design_arguments", "build_problem",
           "design_main", "operating_point", "operating_point_of", "record_schedule",
           "run_rounds"]
