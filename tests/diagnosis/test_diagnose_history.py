"""Hide an effect in days of the independent plant and require the diagnosis to find it
against the plant's normal learned from its history (issue 22).

The independent plant (:mod:`softsensor.plant.independent`) shares no equation with the
model, so the calibrated model misses it on every day; a clean day of it must read as normal
and an effect day must stand out. Here, as a process engineer would hand it over: four clean
days of one plant (plant seed 8101, day seeds 100 to 103) give the model error
(:func:`~softsensor.calibration.model_error_fit.fit_model_error`, PARAMS.toml's
``[model_error]``) at the config's parameters, and ``diagnose`` judges fresh days of the same
plant against it. The seeds are fixed (the default suite is deterministic); the magnitudes
are in the upper half of each effect's detectable range (:data:`softsensor.plant.effects.
EFFECTS`), where the benchmark names them on every tuning plant. The plant is fresh (issue
39 item 4): no threshold of the diagnosis was set on it. The thresholds of the
probabilities below were set on the tuning plants 11 and 12 (``benchmarks/
diagnosis_temperature.py``, ``benchmarks/results/diagnosis_calibration.json``) and are
asserted here on another plant, at the shipped temperature and contamination.

What this checks is the part of the capability that holds on every plant measured
(``benchmarks/open_world.py --parts diagnosis``, docs/results/diagnosis.md): an
inlet-moisture excursion and a lagging ``T_air_in`` sensor are named with a positive
held-out gain, and this clean day is ``none``; and each cause whose model extension fails on
this plant's form of it (ambient heat loss, a lab delay, an offset, fouling) is named by the
shape it leaves on the residuals (``SHAPE_CASES``). It does not show what the history adds:
on these 16 h days the three cases are also named without it (the config's floors), and the
clean days are where a short history hurts. Measured on plant 11 with this history
(``_plant_with_history`` below, then ``diagnose`` on clean day seeds 201 to 206): with the
history's normal 2 of 6 clean 16 h days are ``none`` (the others ``unexplained`` or
``ambient_heat_loss``), with the config's floors 5 of 6; on 48 h days with four 48 h history
days 5 of 6, and on the benchmark's seven 48 h history days every clean day (7 of 7, fresh
and tuning plants). The normal's day level stays put within the day
(:func:`~softsensor.diagnosis.calibration_error.normal_states`), which on short records
reads the wander the history could not size as structure. The randomised version (fresh
plant and day seeds, 48 h records, ``-m slow``) therefore fails now and then on its clean
day; that is the capability's true rate, not noise in the test. """

from __future__ import annotations

import os
import random

import pytest

from softsensor.calibration.dataset import segment_from_day
from softsensor.calibration.model_error_fit import fit_model_error
from softsensor.calibration.params_file import params_document, write_params
from softsensor.diagnosis.diagnose_day import diagnose
from softsensor.model.dryer import DryerModel
from softsensor.plant.independent import simulate_independent_day
from softsensor.plantconfig import load_parameters, load_plant_config

#: Record length of every day [h] (the benchmark's are 48 h; 16 h keeps the suite short).
HOURS = 16.0
PLANT = 8101
#: The probability of a ``none`` verdict below which a right one on this fresh plant fails:
#: just under the least a right ``none`` got on the 32 tuning days (plants 11 and 12, with
#: the shapes: 0.59 to 0.74).
RIGHT_NONE = 0.55
HISTORY_SEEDS = (100, 101, 102, 103)
#: (cause, magnitude, day seed): magnitudes in the upper half of the detectable range.
CASES = (("none", None, 201), ("inlet_moisture", 0.2, 201), ("input_lag", 15.0, 202))


def _plant_with_history(plant: int, seeds, hours: float, tmp_path):
    cfg = load_plant_config()
    days = [simulate_independent_day(cfg, hours, s, plant_seed=plant) for s in seeds]
    segs = [segment_from_day(d, cfg, source=f"history day {s}")
            for d, s in zip(days, seeds, strict=True)]
    me = fit_model_error(DryerModel(cfg), segs, cfg.parameter_vector(),
                         float(cfg.nominal.moisture_in))
    values = {n: cfg.parameters[n].value for n in cfg.parameters}
    path = write_params(tmp_path / "params.toml",
                        params_document(cfg, values, {}, model_error=me.to_table()))
    return cfg, load_parameters(path, cfg)


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    return _plant_with_history(PLANT, HISTORY_SEEDS, HOURS, tmp_path_factory.mktemp("hist"))


@pytest.mark.parametrize(("cause", "magnitude", "seed"), CASES, ids=[c[0] for c in CASES])
def test_hidden_effect_is_named_against_the_plants_normal(plant, cause, magnitude, seed):
    cfg, with_history = plant
    effect = None if cause == "none" else cause
    day = simulate_independent_day(cfg, HOURS, seed, effect, magnitude, plant_seed=PLANT)
    doc = diagnose(with_history, day, source=f"independent plant {PLANT} day {seed}").to_json()
    why = f"{cause} {magnitude} seed {seed}: named {doc['cause']} ({doc['structure']})"
    assert doc["cause"] == cause, why
    if cause != "none":
        assert doc["gain"] > 0.05, why
    # issue 33: a probability for every cause; the cause is the most probable one. Four
    # history days and no plant normal learned from them (issue 48): too little history to
    # know the plant's normal, so a cause leads at the cap and no more; none as probable
    # as a right none was on the tuning plants (RIGHT_NONE)
    probs = doc["probabilities"]
    assert sum(p["probability"] for p in probs) == pytest.approx(1.0, abs=1e-5)
    assert probs[0]["cause"] == doc["cause"], probs
    assert doc["plant_normal"]["enough"] is False
    if cause == "none":
        assert probs[0]["probability"] > RIGHT_NONE, probs
    else:
        assert probs[0]["probability"] == pytest.approx(doc["plant_normal"]["cap"]), probs
    assert {p["cause"] for p in probs} >= {"none", "unexplained", "lab_delay"}
    assert doc["cannot_tell"] == [], doc["cannot_tell"]


#: Record length of the randomised version [h]: the benchmark's.
SLOW_HOURS = 48.0


@pytest.mark.slow
def test_randomised_plants_and_days():
    """Fresh plant and day seeds (printed); the same three cases on 48 h records."""
    import tempfile
    from pathlib import Path

    base = os.environ.get("SOFTSENSOR_DIAG_SEED")
    rng = random.Random(int(base) if base and base.isdigit() else None)
    plant_seed = rng.randrange(1000, 10**6)
    history = tuple(rng.randrange(10**6) for _ in HISTORY_SEEDS)
    print(f"plant seed {plant_seed}, history {history}")
    with tempfile.TemporaryDirectory() as tmp:
        cfg, with_history = _plant_with_history(plant_seed, history, SLOW_HOURS, Path(tmp))
        named = []
        for cause, magnitude, _ in CASES:
            seed = rng.randrange(10**6)
            day = simulate_independent_day(cfg, SLOW_HOURS, seed,
                                           None if cause == "none" else cause, magnitude,
                                           plant_seed=plant_seed)
            named.append((cause, seed, diagnose(with_history, day).to_json()["cause"]))
    assert all(c == n for c, _, n in named), named


#: (cause, magnitude, day seed, thermometer) of the causes named by their shape on the
#: residuals (:mod:`softsensor.diagnosis.shapes`, issue 39 item 1): days of this fresh plant
#: on which the cause leaves a trace the normal can see (a cold day for the ambient loss, lab
#: samples while the moisture moves for the delay), magnitudes at or above the virtual
#: plant's default size of the effect. On each, the model's own extension does not name the
#: cause: with that shape left out (``diagnose(..., shapes=...)``) these days were named
#: ``inlet_moisture``, ``unexplained``, ``unexplained`` and ``lab_delay``.
SHAPE_CASES = (("ambient_heat_loss", 0.8, 204, None), ("lab_delay", 55.0, 207, None),
               ("sensor_bias", 4.5, 201, "T_dryer_out"), ("fouling_drift", 0.3, 204, None))


@pytest.mark.parametrize(("cause", "magnitude", "seed", "channel"), SHAPE_CASES,
                         ids=[c[0] for c in SHAPE_CASES])
def test_a_cause_is_named_by_the_shape_it_leaves(plant, cause, magnitude, seed, channel):
    cfg, with_history = plant
    day = simulate_independent_day(cfg, HOURS, seed, cause, magnitude, plant_seed=PLANT)
    assert day.effect.get("channel") == channel
    doc = diagnose(with_history, day, source=f"independent plant {PLANT} day {seed}").to_json()
    probs = doc["probabilities"]
    why = f"{cause} {magnitude} seed {seed}: named {doc['cause']}; {probs[:3]}"
    assert doc["cause"] == cause, why
    assert doc["channel"] == channel, why
    assert probs[0]["cause"] == cause and probs[0]["source"] == "shape", why
    assert probs[0]["probability"] == pytest.approx(doc["plant_normal"]["cap"]), why
    assert doc["shape"]["cause"] == cause, why
