"""Hide an effect in a virtual-plant day and require the diagnosis to find it (issue 6).

Each case draws, from its seed, a magnitude uniformly from the effect's documented detectable
range (:data:`softsensor.plant.effects.EFFECTS`); the seed, magnitude and a command that
replays the day are printed and repeated in every assertion message. The default suite is
deterministic: the base seed is 20261121 (:data:`DEFAULT_BASE_SEED`) unless
``SOFTSENSOR_DIAG_SEED`` sets another number, or ``random`` for a fresh draw to explore (the
printed seed replays a failure). Fresh-seed days run in the ``slow`` suite
(``test_hidden_effect_is_named_on_fresh_days``), a new base on every run.

The per-cause cases diagnose a 72 h day with the plant's true parameters (and a
``[discrepancy]`` at the estimator's floors: the model is right) and require the right cause,
the right channel for ``sensor_bias`` and a positive held-out gain; one case runs the whole
``softsensor diagnose --calibrate-on`` command; one is issue 11's model that is off (the
model's ``mult_D`` 15 % away from the plant's, nothing said about it): ``none``; one checks
the report's numbers (cross-fitted over the whole day, eq. 4 recomputed) on the diagnosis
tests' clean 14 h day with a sensor offset added. The ``slow`` case calibrates once on a clean
day of a plant whose true parameters are away from the config's and diagnoses 24 days across
all causes.

This is the matched plant, the floor: the open-world numbers come from
``benchmarks/open_world.py`` (docs/results/diagnosis.md). Measured with base seeds 20261121 (CI),
777 and 31337: 19 of the 21 effect days right (7, 6, 6), every named cause with a positive
gain. The misses: base 777's inlet-moisture day named ``sensor_bias`` (the inlet filter's
estimate, replayed one window late, leaves window-to-window errors that the calibration-error
model, at its floors, charges more than the slow error the extension removes), base 31337's
59 min lab delay named ``unexplained``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import random
import subprocess
import sys

import numpy as np
import pytest

from softsensor.calibration.cost import Fit
from softsensor.diagnosis.diagnose_day import Diagnosis, after_shapes, diagnose
from softsensor.diagnosis.posterior import posterior
from softsensor.diagnosis.shapes import ShapeFit
from softsensor.diagnosis.verdict import Score, verdict
from softsensor.estimation.settings import estimator_settings
from softsensor.plant.effects import EFFECTS
from softsensor.plant.simulator import simulate_day
from softsensor.signals import OUTPUT_NAMES

HOURS = 72.0
SLOW_HOURS = 30.0
#: Causes with an extension in the diagnosis; ``unexplained`` (alternating chip batches) is
#: what no extension explains, measured by ``benchmarks/diagnose.py``, not required here.
EXTENDED = tuple(c for c in EFFECTS if c != "unexplained")
CASES = ("none", *EXTENDED)
#: True parameters of the slow case's plant, away from the config's (as in
#: ``benchmarks/calibrate.py``): the calibration must find them.
SHIFTED = {"mult_D": 0.7, "mult_C": 2.0, "mult_h": 1.4, "mult_k": 2.0, "mult_p": 1.8,
           "hm_cyc": 3e-4, "hc_cyc": 50.0}


#: The base seed of the default suite (the one the figures in this docstring were measured
#: with): the suite is the same on every run without any environment.
DEFAULT_BASE_SEED = 20261121


def fresh_seed() -> int:
    return random.SystemRandom().randrange(1, 10**6)


def _seed() -> int:
    """``SOFTSENSOR_DIAG_SEED``: unset for :data:`DEFAULT_BASE_SEED`, a number, or ``random``
    for a fresh draw."""
    env = os.environ.get("SOFTSENSOR_DIAG_SEED", "").strip()
    if not env:
        return DEFAULT_BASE_SEED
    if env == "random":
        return fresh_seed()
    try:
        return int(env)
    except ValueError:
        raise pytest.UsageError(f"SOFTSENSOR_DIAG_SEED={env!r} is neither an integer nor "
                                f"'random'") from None


BASE_SEED = _seed()


def draw(cause: str, seed: int) -> float | None:
    """The magnitude of ``cause`` for ``seed``: uniform in its detectable range."""
    if cause == "none":
        return None
    lo, hi = EFFECTS[cause].detectable
    return float(np.random.default_rng([seed, 7]).uniform(lo, hi))


def replay(cause: str, seed: int, mag: float | None, hours: float = HOURS,
           base: int = BASE_SEED) -> str:
    effect = "" if cause == "none" else f" --effect {cause} --magnitude {mag!r}"
    return (f"seed {seed}, magnitude {mag}: replay with SOFTSENSOR_DIAG_SEED={base} or "
            f"`softsensor simulate --plant model --hours {hours:g} --seed {seed}{effect} "
            f"--out DAY.mcap`")


def check(cause: str, day, report: dict) -> list[str]:
    """What is wrong with ``report`` for a day hiding ``cause`` (empty when right)."""
    problems = []
    if report["cause"] != cause:
        problems.append(f"named {report['cause']!r}, expected {cause!r}")
    if cause == "sensor_bias" and report["channel"] != day.effect["channel"]:
        problems.append(f"channel {report['channel']!r}, expected {day.effect['channel']!r}")
    if cause != "none" and not report["gain"] > 0:
        problems.append(f"held-out gain {report['gain']} is not positive")
    return problems


def exact(config):
    """``config`` saying its model is right up to the estimator's floors (a ``[discrepancy]``
    of 0.2 K and 0.003 kg/kg, what a calibration on a day of this plant would leave): the
    per-cause cases diagnose with the plant's true parameters."""
    s = estimator_settings(config)
    t, m = s.T_std_floor, s.moisture_std_floor
    disc = {"common_std": t, "dryer_std": t, "cyclone_std": t, "moisture_std": m}
    return dataclasses.replace(config, extra={**config.extra, "discrepancy": disc})


#: Causes whose default-suite day runs under ``-m slow`` only, to keep the default suite within
#: ten minutes on two cores (each about a minute; the fresh-seed version covers all).
SLOW_CASES = ("fouling_drift", "ambient_heat_loss")


@pytest.mark.parametrize("cause", [pytest.param(c, marks=pytest.mark.slow)
                                   if c in SLOW_CASES else c for c in CASES])
def test_hidden_effect_is_named(cfg, cause):
    _hidden_effect_is_named(cfg, cause, BASE_SEED)


@pytest.mark.slow
@pytest.mark.parametrize("cause", CASES)
def test_hidden_effect_is_named_on_fresh_days(cfg, cause):
    """The same check on a base seed drawn afresh on every run (printed, to replay)."""
    _hidden_effect_is_named(cfg, cause, fresh_seed())


def _hidden_effect_is_named(cfg, cause: str, base: int) -> None:
    seed = base + CASES.index(cause)
    mag = draw(cause, seed)
    print(replay(cause, seed, mag, base=base))
    day = simulate_day(cfg, HOURS, seed, None if cause == "none" else cause, mag)
    report = diagnose(exact(cfg), day).to_json()
    ranking = [(r["cause"], r["score"]) for r in report["ranking"]]
    assert not check(cause, day, report), (f"{check(cause, day, report)}; "
                                           f"{replay(cause, seed, mag, base=base)}; "
                                           f"ranking {ranking}")
    # the numbers of CONTRACT section 5 are consistent with each other
    assert report["gain"] == pytest.approx(1 - report["extended_cost"] / report["baseline_cost"])
    if cause != "none":
        top = report["ranking"][0]
        assert top["cause"] == cause and top["score"] > 0.5 and top["eligible"]
        assert report["extended_cost"] < report["baseline_cost"]
    else:
        assert report["extended_rmse"] == report["baseline_rmse"] and report["gain"] == 0.0


def test_a_model_that_is_off_is_not_blamed_on_a_cause(cfg):
    """Issue 11's case: the matched plant with the model's ``mult_D`` 15 % off, a clean 30 h
    day, the config's parameters with nothing said about how far off they are. Both outlet
    temperatures move together (the model's heat balance is off), which one sensor's offset
    cannot do; it is calibration error, not a cause."""
    plant = cfg.with_parameters({"mult_D": cfg.parameters["mult_D"].value * 0.85})
    day = simulate_day(plant, 30.0, 1)
    d = diagnose(cfg, day)
    assert d.cause == "none", {k: round(v.penalised, 1) for k, v in d.scores.items()}
    # told that the model is exact, the same day shows the error (the test can fail)
    assert diagnose(exact(cfg), day).cause != "none"


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "softsensor.cli", *args], capture_output=True,
                          text=True, timeout=900)


def test_diagnose_command_calibrates_on_cal_and_writes_the_report(cfg, tmp_path):
    """The whole verb: calibrate on a clean day, diagnose a day with a sensor offset."""
    seed = BASE_SEED + 100
    mag = draw("sensor_bias", seed)
    print(replay("sensor_bias", seed, mag, 24.0))
    cal = simulate_day(cfg, 24.0, seed + 1).write(tmp_path / "cal.mcap")
    day = simulate_day(cfg, 24.0, seed, "sensor_bias", mag)
    path = day.write(tmp_path / "day.mcap")
    out = tmp_path / "REPORT.json"
    r = _cli("diagnose", "--calibrate-on", str(cal), str(path), "--json", str(out),
             "--report", str(tmp_path / "page"), "--trials", "12", "--window-hours", "24",
             "--save-params", str(tmp_path / "params.toml"))
    assert r.returncode == 0, r.stderr[-2000:]
    rep = json.loads(out.read_text())
    assert r.stdout == ""  # JSON only where --json says; the verdict line on stderr
    assert r.stderr.rstrip().splitlines()[-1].startswith(f"diagnose: {path}: cause ")
    for key in ("cause", "ranking", "channel", "baseline_rmse", "extended_rmse",
                "baseline_cost", "extended_cost", "gain"):
        assert key in rep
    assert set(rep["baseline_rmse"]) == {"T_dryer_out", "T_cyclone_out", "moisture_out"}
    assert all(isinstance(e["evidence"], str) and e["evidence"] for e in rep["ranking"])
    assert {e["cause"] for e in rep["ranking"]} >= set(EXTENDED)
    assert not check("sensor_bias", day, rep), (check("sensor_bias", day, rep),
                                                replay("sensor_bias", seed, mag, 24.0))
    assert rep["calibration"]["trials"] == 12 and (tmp_path / "params.toml").is_file()
    page = tmp_path / "page"
    for name in ("index.html", "residuals.png", "trajectories.png", "gain.png"):
        assert (page / name).stat().st_size > 1000, name
    html = (page / "index.html").read_text()
    assert "sensor_bias" in html and html.count("data:image/png;base64,") == 3
    # the verdict first, in plant language: which thermometer, how far, which way
    verdict = html[html.index('<p class="verdict">'):]
    verdict = verdict[:verdict.index("</p>")]
    # (the loop's own thermometer is named with what the loop does: "(T_dryer_out), the one
    # the outlet-temperature loop holds at its set point, reads 5.7 °C low", issue 48)
    assert f"({rep['channel']})" in verdict and " reads " in verdict and "°C" in verdict, \
        verdict
    assert ("high" if day.effect["sign"] > 0 else "low") in verdict, verdict
    # the calibrated parameters reproduce the report through --params
    out2 = tmp_path / "REPORT2.json"
    r2 = _cli("diagnose", "--params", str(tmp_path / "params.toml"), str(path), "--json",
              str(out2))
    assert r2.returncode == 0, r2.stderr[-2000:]
    rep2 = json.loads(out2.read_text())
    assert rep2["cause"] == rep["cause"] and rep2["gain"] == pytest.approx(rep["gain"])


@pytest.mark.slow
def test_randomised_days_are_named_correctly(cfg):
    """24 random days (3 per cause, 6 clean) of a plant with shifted true parameters, one
    calibration (40 trials and the polish) on a clean 48 h day of it: at least 90 % named
    right and at most one false alarm (a clean day given a cause).

    The calibration's draw matters: none of the seven parameters is pinned to 15 % by one day
    (issue 4), and a calibration that fits its day to the noise but extrapolates badly makes an
    error on other days that depends on the ambient conditions. Measured at base 20261121 with
    the diagnosis against the calibration error (stop 17): 17 of 24 right, one clean day
    named ``unexplained``; the three lab delays were named ``input_lag``: the undone lag took
    the air's slope at the lab times between neighbouring one-minute bins, which put the
    sensor's noise into the model's outlet moisture there, as a stamp error does (the test
    was ``xfail(strict=True)`` until they were told apart). With the slope over one window
    either side (issue 39, :func:`~softsensor.diagnosis.day_windows.delagged_air`) the same
    base gives 24 of 24 again, and the marker is gone. A day counts as right
    only when :func:`check` finds nothing: the cause, the channel and a positive held-out
    gain.
    """
    from softsensor.calibration.calibration_run import calibrate
    from softsensor.calibration.dataset import segment_from_day
    from softsensor.calibration.optimize import StudySettings
    from softsensor.calibration.settings import calibration_settings

    base = BASE_SEED
    plant = cfg.with_parameters(SHIFTED)
    cal_day = simulate_day(plant, 48.0, base)
    seg = segment_from_day(cal_day, cfg, source="cal")
    res = calibrate([seg], cfg, StudySettings(n_trials=40, seed=0, progress=False),
                    calibration_settings(cfg), identify_result=False)
    cal_cfg = res.calibrated_config()
    cases = list(CASES) * 3 + ["none"] * 3  # 24 days, 6 of them clean
    results = []
    for i, cause in enumerate(cases):
        seed = base + 1 + i
        mag = draw(cause, seed)
        day = simulate_day(plant, SLOW_HOURS, seed, None if cause == "none" else cause, mag)
        rep = diagnose(cal_cfg, day).to_json()
        wrong = check(cause, day, rep)
        how = replay(cause, seed, mag, SLOW_HOURS, base) + " --params <SHIFTED>"
        results.append((cause, rep["cause"], wrong, how))
        print(cause, "->", rep["cause"], rep["channel"], f"gain {rep['gain']:+.3f}", wrong, how,
              flush=True)
    right = sum(not w for _, _, w, _ in results)
    false_alarms = [r for r in results if r[0] == "none" and r[1] != "none"]
    summary = "\n".join(f"{c} -> {g}: {w} ({rp})" for c, g, w, rp in results if w)
    assert right >= 0.9 * len(results), f"{right}/{len(results)} right:\n{summary}"
    assert len(false_alarms) <= 1, summary


def test_the_reported_gain_is_cross_fitted_over_the_whole_day(cfg, offset_diagnosis):
    """A sensor offset on the whole day: the report's numbers cover every window and lab
    result, each predicted by the fit on the other part."""
    d = offset_diagnosis
    rep = d.to_json()
    assert rep["cause"] == "sensor_bias" and rep["channel"] == "T_dryer_out"
    w = d.problem.windows
    assert rep["held_out"]["samples"]["T_dryer_out"] == int(np.isfinite(w.Y[:, 0]).sum())
    assert rep["held_out"]["samples"]["moisture_out"] == len(w.lab_value)
    r = d.problem.residuals(d.cross_fitted("sensor_bias"))
    assert rep["extended_rmse"]["T_dryer_out"] == pytest.approx(
        float(np.sqrt(np.nanmean(r.T[:, 0] ** 2))))
    # eq. 4 recomputed here from the whole day's residuals
    weights = cfg.cost.weights()

    def eq4(res):
        return sum(wc * np.sqrt(np.nanmean(x ** 2))
                   for wc, x in zip(weights, (res.T[:, 0], res.T[:, 1], res.lab), strict=True))

    base = eq4(d.problem.residuals(d.problem.baseline))
    assert rep["baseline_cost"] == pytest.approx(base)
    assert rep["extended_cost"] == pytest.approx(eq4(r))
    assert rep["gain"] == pytest.approx(1 - eq4(r) / base)
    assert rep["gain"] > 0 and rep["held_out"]["split_gain"] > 0
    assert rep["extension"]["params_other_fold"]["offset_K"] == pytest.approx(3.0, abs=0.1)


def _stub_score(cause: str, penalised: float, gain: float) -> Score:
    """A made-up held-out score (eligible when ``penalised`` exceeds the verdict's charge
    and ``gain`` is positive), as tests/diagnosis/test_posterior.py makes them."""
    fit = Fit(rmse={n: 1.0 for n in OUTPUT_NAMES}, n={n: 10 for n in OUTPUT_NAMES}, cost=0.1)
    return Score(cause, None, 1, fit, fit, gain, fit, fit, gain,
                 {n: penalised / 3 for n in OUTPUT_NAMES}, penalised, (), 30.0, 1e-6)


def _shape_named(scores: list[Score], shape: ShapeFit, skipped: tuple[str, ...] = ()
                 ) -> Diagnosis:
    """What :func:`diagnose` makes of ``scores``, the ``skipped`` causes and one cause's
    ``shape`` on a day with unstructured residuals: the verdict after the shapes, with the
    candidates (no day behind them: only the verdict, the candidates and the shapes are
    read)."""
    v = verdict(scores, None)
    cands = posterior(v, scores, skipped, -5.0, shapes=[shape])
    assert cands[0].cause == shape.cause and cands[0].source == "shape"
    by_cause = {s.cause: s for s in scores}
    return Diagnosis(None, None, {}, by_cause, {}, after_shapes(v, cands, by_cause, skipped),  # type: ignore[arg-type]
                     np.ones(3), skipped={c: "ruled out" for c in skipped},
                     candidates=cands, shapes={shape.cause: shape})


def test_a_larger_shape_of_the_winning_extensions_cause_keeps_the_extension():
    """Review of issue 39: a shape larger than the winning extension of its own cause used
    to drop the winner (gain 0, no extension, "did not improve the held-out part") on 8 of
    96 stored benchmark days; the winner and its held-out gain stay."""
    scores = [_stub_score("fouling_drift", 40.0, 0.23), _stub_score("lab_delay", 2.0, 0.01)]
    d = _shape_named(scores, ShapeFit("fouling_drift", None, 200.0, -5.0,
                                      {"loss_by_end": 0.2}, "ramp"))
    assert d.verdict.winner is scores[0] and d.verdict.winner.gain == 0.23
    assert d.cause == "fouling_drift" and d.shape is None


def test_a_shape_of_a_cause_without_an_eligible_extension_names_it():
    scores = [_stub_score("fouling_drift", 40.0, 0.23), _stub_score("lab_delay", 2.0, 0.01),
              _stub_score("ambient_heat_loss", 3.0, -0.02)]
    assert not scores[2].eligible
    shape = ShapeFit("ambient_heat_loss", None, 200.0, -5.0, {}, "cold")
    d = _shape_named(scores, shape)
    assert d.cause == "ambient_heat_loss" and d.verdict.winner is None and d.shape is shape


def test_a_cause_named_by_its_shape_ranks_every_cause_by_one_posterior():
    """Review of issue 39: the named cause took its posterior probability while the others
    kept the verdict's softmax weights (summing to 1.9 on one day); every entry, the
    skipped causes' too, now scores its probability in the same posterior."""
    scores = [_stub_score("fouling_drift", 40.0, 0.23), _stub_score("lab_delay", 2.0, 0.01),
              _stub_score("ambient_heat_loss", 3.0, -0.02)]
    d = _shape_named(scores, ShapeFit("ambient_heat_loss", None, 200.0, -5.0, {}, "cold"),
                     skipped=("inlet_moisture",))
    weights = {c: w for c, w, _ in d.verdict.ranking}
    assert sum(weights.values()) == pytest.approx(1.0, abs=1e-9)
    assert weights == {c.cause: c.probability for c in d.candidates}
    assert max(weights, key=weights.__getitem__) == d.verdict.ranking[0][0] == d.cause
