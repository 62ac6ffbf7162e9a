"""The independent plant (softsensor.plant.independent): independence from the model,
determinism, balances, the contract envelope, each effect where it should show, the loop,
the cyclone and the sensors.

Days are short (6 h, one 24 h day for the contract check) so that the default suite stays
fast; the sweep over plant seeds and effects and the speed measurement are ``slow``.
"""

from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from paths import CHECK_DAY, REPO
from scipy.signal import lfilter

from softsensor.errors import ConfigError
from softsensor.plant.effects import EFFECTS
from softsensor.plant.independent import UnmeasuredFlow, simulate_independent_day
from softsensor.plant.independent.balances import steady_balances
from softsensor.plant.independent.commissioning import (
    commissioned_member,
    nominal_inputs,
    operating_point,
)
from softsensor.plant.independent.disturbances import draw_day
from softsensor.plant.independent.process import Process
from softsensor.plant.settings import virtual_plant_settings
from softsensor.plantconfig import load_plant_config
from softsensor.signals import INJECTABLE_EFFECTS, SCAN_SIGNALS

PACKAGE = REPO / "softsensor" / "plant" / "independent"
HOURS = 6.0
PLANT = 0
#: One plant seed per kinetics variant (rea, cdc, two_resistance).
VARIANT_SEEDS = (0, 1, 3)


@pytest.fixture(scope="module")
def cfg():
    return load_plant_config()


@pytest.fixture(scope="module")
def seed(cfg):
    """A day seed whose ambient is cold for a while (the ambient_heat_loss test needs it)."""
    s = virtual_plant_settings(cfg)
    st = commissioned_member(PLANT, cfg).structure
    for candidate in range(100):
        day = draw_day(cfg, s, st, HOURS, s.scan_period, np.random.default_rng([candidate, 10]))
        if (day.T_amb < 276.0).mean() > 0.5:
            return candidate
    raise AssertionError("no cold day among 100 seeds")


@pytest.fixture(scope="module")
def clean(cfg, seed):
    return simulate_independent_day(cfg, HOURS, seed, plant_seed=PLANT)


def _day(cfg, seed, effect, magnitude, hours=HOURS):
    d = simulate_independent_day(cfg, hours, seed, effect, magnitude, plant_seed=PLANT)
    info = d.effect
    assert info["effect"] == effect and info["magnitude"] == magnitude
    assert info["unit"] == EFFECTS[effect].unit and info["seed"] == seed
    assert info["plant"] == "independent" and info["plant_seed"] == PLANT
    assert info["structure"]["variant"] in ("rea", "cdc", "two_resistance")
    return d


def _lag(u: np.ndarray, tau: float, dt: float = 10.0) -> np.ndarray:
    """First-order lag of a sampled signal (exact for a piecewise-constant input)."""
    if tau <= 0:
        return u.copy()
    a = np.exp(-dt / tau)
    y, _ = lfilter([1 - a], [1, -a], u, zi=[a * u[0]])
    return y


# -- independence -------------------------------------------------------------------------

def test_the_package_never_imports_the_model(tmp_path):
    code = (
        "import sys\n"
        "import softsensor.plant.independent as ip\n"
        "from softsensor.plantconfig import load_plant_config\n"
        "day = ip.simulate_independent_day(load_plant_config(), 0.5, 1, plant_seed=0)\n"
        "day.write(sys.argv[1])\n"
        "print(sorted(m for m in sys.modules if m.startswith('softsensor.model')))\n")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "d.mcap")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip().splitlines()[-1] == "[]"
    # nor does any of its sources name the model, or the matched plant's modules that do
    pattern = re.compile(r"^\s*(from|import)\s+softsensor\.(model|plant\.(simulator|controller"
                         r"|scenario))\b", re.M)
    for path in PACKAGE.glob("*.py"):
        assert not pattern.search(path.read_text()), path.name


# -- determinism and the family -----------------------------------------------------------

def test_same_seeds_same_day_and_the_structure_belongs_to_the_plant_seed(cfg):
    a = simulate_independent_day(cfg, 1.0, 3, plant_seed=1)
    b = simulate_independent_day(cfg, 1.0, 3, plant_seed=1)
    assert a.scans.equals(b.scans) and a.truth.equals(b.truth) and a.labs.equals(b.labs)
    assert a.effect == b.effect
    other_day = simulate_independent_day(cfg, 1.0, 4, plant_seed=1)
    assert other_day.effect["structure"] == a.effect["structure"]
    assert not np.allclose(other_day.truth.m_fiber, a.truth.m_fiber)
    other_plant = simulate_independent_day(cfg, 1.0, 3, plant_seed=3)
    sa, sb = a.effect["structure"], other_plant.effect["structure"]
    assert sa != sb and sa["t_hold"] != sb["t_hold"]
    # the disturbances of the day are the day seed's, apart from the plant's own statistics
    np.testing.assert_allclose(other_plant.truth.m_fiber, a.truth.m_fiber)


def test_bad_arguments_are_one_line_config_errors(cfg):
    with pytest.raises(ConfigError, match="--hours"):
        simulate_independent_day(cfg, 0.0, 1)
    with pytest.raises(ConfigError, match="--plant-seed"):
        simulate_independent_day(cfg, 1.0, 1, plant_seed=-1)
    with pytest.raises(ConfigError, match="unknown effect"):
        simulate_independent_day(cfg, 1.0, 1, effect="smoke")
    assert set(EFFECTS) == set(INJECTABLE_EFFECTS) and "unexplained" in EFFECTS


# -- balances -----------------------------------------------------------------------------

@pytest.mark.parametrize("plant_seed", VARIANT_SEEDS)
def test_water_and_energy_close_at_steady_state(cfg, plant_seed):
    for overrides in ({}, {"m_fiber": 4.8, "X_in": 1.1, "T_amb": 262.0, "H_amb": 0.0015,
                           "m_steam": 0.3, "wind": 8.0, "hot_gas_share": 0.25}):
        b = steady_balances(cfg, plant_seed, **overrides)
        assert b.water_closure < 1e-12, (overrides, b.water_in, b.water_out)
        assert b.energy_closure < 1e-8, (overrides, b.energy_in, b.energy_out)
        assert b.water_in["leak_air"] > 0 and b.energy_in["leak_air"] != 0  # negative below 0 °C
        losses = [b.energy_out[k] for k in ("tube_wall", "duct_wall", "cyclone_shell_a",
                                            "cyclone_shell_b")]
        assert all(q > 0 for q in losses)
        # heat lost through the walls is a few percent of what the gas brings
        assert 0.005 < sum(losses) / b.energy_in["burner_gas"] < 0.1


# -- contract envelope, loop, lab ---------------------------------------------------------

def _check_day(path: Path, hours: float) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(CHECK_DAY), str(path), "--hours", str(hours)],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.skipif(not CHECK_DAY.exists(), reason="shared/tools/check_day.py not found")
def test_a_clean_day_passes_the_contract_check_and_the_loop_holds(cfg, tmp_path):
    d = simulate_independent_day(cfg, 24.0, 21, plant_seed=PLANT)
    r = _check_day(d.write(tmp_path / "day.mcap"), 24.0)
    assert r.returncode == 0 and "0 findings" in r.stdout, r.stdout
    s, labs = d.scans, d.labs
    assert list(s.columns) == list(SCAN_SIGNALS)
    assert np.allclose(np.diff(s.index.to_numpy()) / 1e9, 10.0)
    for col in ("moisture_in", "moisture_out", "T_air_in", "T_dryer_out", "T_cyclone_out",
                "m_fiber"):
        assert d.truth[col].notna().all()
    err = s.T_dryer_out - s.T_sp
    assert abs(err.mean()) < 0.5 and err.std() < 1.5
    assert abs((d.truth.T_dryer_out - s.T_sp).mean()) < 0.5
    # lab: every 2-4 h, reported 20-90 min later, the instantaneous truth plus lab noise
    assert labs.sample_id.is_unique and len(labs) >= 5
    gaps_h = np.diff(labs.sample_time_ns) / 3.6e12
    assert ((gaps_h >= 2) & (gaps_h <= 4)).all()
    delay_min = (labs.log_time_ns - labs.sample_time_ns) / 6e10
    assert delay_min.between(20, 90).all()
    truth_at = np.interp(labs.sample_time_ns, d.truth.index, d.truth.moisture_out)
    assert np.abs(labs.moisture_out - truth_at).max() < 0.012
    assert 0.06 <= d.truth.moisture_out.mean() <= 0.16


def test_thermocouples_lag_the_truth(clean):
    """The outlet readings follow the truth through each sensor's drawn lag (within 15 s: the
    transport delay to the cyclone outlet adds to the first-order lag a fit sees)."""
    tau = clean.effect["structure"]["sensor_tau"]
    for ch in ("T_dryer_out", "T_cyclone_out", "T_air_in"):
        meas = clean.scans[ch].to_numpy()
        true = clean.truth[ch].to_numpy()
        ok = np.isfinite(meas)
        taus = np.arange(0.0, 151.0, 5.0)
        rms = [np.sqrt(np.mean((meas - _lag(true, t))[ok] ** 2)) for t in taus]
        best = taus[int(np.argmin(rms))]
        assert best > 5.0, ch  # slower than the truth
        assert abs(best - tau[ch]) <= 15.0, (ch, best, tau[ch])


# -- effects ------------------------------------------------------------------------------

def test_sensor_bias_offsets_the_drawn_channel(cfg, seed):
    d = _day(cfg, seed, "sensor_bias", 4.0, hours=4.0)
    ch, sign = d.effect["channel"], d.effect["sign"]
    other = "T_cyclone_out" if ch == "T_dryer_out" else "T_dryer_out"
    assert (d.scans[ch] - d.truth[ch]).mean() == pytest.approx(sign * 4.0, abs=0.15)
    assert abs((d.scans[other] - d.truth[other]).mean()) < 0.15
    if ch == "T_dryer_out":  # the loop holds the biased reading: the truth moves the other way
        assert (d.truth.T_dryer_out - d.scans.T_sp).mean() == pytest.approx(-sign * 4.0,
                                                                           abs=0.5)


def test_input_lag_slows_the_T_air_in_reading(cfg, seed):
    d = _day(cfg, seed, "input_lag", 10.0)
    tau_tc = d.effect["structure"]["sensor_tau"]["T_air_in"]
    meas = d.scans.T_air_in.to_numpy()
    true = d.truth.T_air_in.to_numpy()
    ok = np.isfinite(meas)
    taus = [0.0, 5.0, 8.0, 10.0, 12.0, 15.0, 20.0]
    rms = [np.sqrt(np.mean((meas - _lag(_lag(true, tau_tc), 60.0 * t))[ok] ** 2))
           for t in taus]
    assert taus[int(np.argmin(rms))] == 10.0
    assert min(rms) < 0.6  # what is left is the 0.5 K sensor noise


def test_an_unmeasured_flow_surge_moves_the_truth_and_not_the_meter(cfg):
    surge = UnmeasuredFlow(0.08, 5400.0, 0.3)
    plain = simulate_independent_day(cfg, 3.0, 5, plant_seed=PLANT)
    d = simulate_independent_day(cfg, 3.0, 5, plant_seed=PLANT, unmeasured_flow=surge)
    t = (d.truth.index.to_numpy() - d.truth.index[0]) / 1e9
    # the meter reads the day's own flow, scan for scan; the fan's true flow has the surge
    assert d.scans.m_air.equals(plain.scans.m_air)
    np.testing.assert_allclose(d.truth.m_air / plain.truth.m_air,
                               1.0 + 0.08 * np.sin(2 * np.pi * t / 5400.0 + 0.3), rtol=1e-12)
    assert d.effect["unmeasured_flow"] == {"amplitude": 0.08, "period_s": 5400.0, "phase": 0.3}
    # and the process feels it: the outlet moisture moves with the flow
    swing = (d.truth.moisture_out - plain.truth.moisture_out).std()
    assert swing > 0.003, swing
    with pytest.raises(ValueError, match="amplitude"):
        UnmeasuredFlow(0.7, 5400.0)


def test_lab_delay_shifts_the_stamped_sample_times(cfg, seed, clean):
    d = _day(cfg, seed, "lab_delay", 45.0)
    n = min(len(d.labs), len(clean.labs))
    assert n >= 1
    shift_min = (d.labs.sample_time_ns[:n] - clean.labs.sample_time_ns[:n]) / 6e10
    assert np.allclose(shift_min, d.effect["sign"] * 45.0, atol=1e-6)
    delay_min = (d.labs.log_time_ns - d.labs.sample_time_ns) / 6e10
    assert delay_min.between(15, 95).all()
    # only the stamp is off: the process, the true sample times and the lab noise are the
    # clean day's, so the results are too
    assert d.truth.equals(clean.truth)
    np.testing.assert_allclose(d.labs.moisture_out[:n], clean.labs.moisture_out[:n],
                               rtol=0, atol=1e-12)


def test_inlet_moisture_deviates_by_up_to_the_magnitude(cfg, seed, clean):
    d = _day(cfg, seed, "inlet_moisture", 0.2)
    dev = (d.truth.moisture_in - clean.truth.moisture_in).to_numpy()
    assert 0.12 <= np.abs(dev).max() <= 0.2 + 1e-9
    # the loop burns more to evaporate the extra water
    extra_heat = (d.truth.T_air_in - clean.truth.T_air_in).to_numpy()
    assert np.corrcoef(dev, extra_heat)[0, 1] > 0.8


def test_fouling_leaves_the_fibre_wetter_late_in_the_day(cfg, seed, clean):
    d = _day(cfg, seed, "fouling_drift", 0.4)
    first, last = slice(0, 60), slice(-360, None)  # first 10 min, last hour
    diff = (d.truth.moisture_out - clean.truth.moisture_out).to_numpy()
    assert abs(diff[first].mean()) < 0.002
    assert diff[last].mean() > 0.005


def test_ambient_heat_loss_costs_heat_when_cold(cfg, seed, clean):
    d = _day(cfg, seed, "ambient_heat_loss", 1.0)
    cold = (clean.truth.T_amb < 276.0).to_numpy()
    assert cold.sum() > 100
    more_heat = (d.truth.T_air_in - clean.truth.T_air_in).to_numpy()
    assert more_heat[cold].mean() > 0.3
    colder_cyclone = (d.truth.T_cyclone_out - clean.truth.T_cyclone_out).to_numpy()
    assert colder_cyclone[cold].mean() < -0.1


def test_unexplained_batches_alternate_the_drying(cfg, seed, clean):
    d = _day(cfg, seed, "unexplained", 0.3)
    edges = [0.0, *d.effect["switch_times_s"], np.inf]
    assert len(edges) >= 3
    t = (d.truth.index - d.truth.index[0]).to_numpy() / 1e9
    diff = (d.truth.moisture_out - clean.truth.moisture_out).to_numpy()
    for i, (a, b) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        # skip the first 10 min of a block, where the walls still carry the last one
        block = (t >= a + 600.0) & (t < b)
        if block.sum() < 60:
            continue
        faster = d.effect["sign"] * (1 if i % 2 == 0 else -1) > 0
        mean = diff[block].mean()
        assert (mean < -0.003) if faster else (mean > 0.003), (i, mean)


# -- process: cyclone, commissioning ------------------------------------------------------

@pytest.mark.parametrize("plant_seed", VARIANT_SEEDS)
def test_the_cyclone_holds_fibre_dries_it_and_loses_heat(cfg, plant_seed):
    member = commissioned_member(plant_seed, cfg)
    nom = member.nominal
    assert 0.07 <= nom["moisture_out"] <= 0.14 and 450.0 <= nom["T_air_in"] <= 550.0
    assert nom["moisture_out"] == pytest.approx(member.structure.target_moisture, abs=1e-4)
    assert nom["moisture_out"] < nom["moisture_tube_out"]
    assert nom["T_cyclone_out"] < nom["T_dryer_out"] - 1.0

    def settle(**change):
        process = Process(dataclasses.replace(member.structure, **change), cfg)
        frac, res = operating_point(process, lambda f: nominal_inputs(process, cfg, f),
                                    cfg.nominal.T_sp, nom["hot_gas_share"])
        return res

    short, long_ = settle(t_hold=3.0), settle(t_hold=20.0)
    assert long_.moisture_out < short.moisture_out - 1e-3  # the hold-up keeps drying
    tight, leaky = settle(leak=0.0), settle(leak=0.03)
    assert leaky.T_cyclone_out < tight.T_cyclone_out - 0.5  # false air cools the outlet


def test_cli_names_the_plant_and_refuses_params_for_the_independent_plant(tmp_path, capsys,
                                                                          monkeypatch):
    from softsensor import cli

    # (a verb imports its own module only: the others would import and compile the model)
    out = tmp_path / "d.mcap"
    assert cli.main(["simulate", "--hours", "0.5", "--seed", "2", "--plant-seed", "1",
                     "--out", str(out)]) == 0
    assert "plant independent, plant seed 1" in capsys.readouterr().err
    assert out.stat().st_size > 1000
    for verb in (["simulate", "--out", str(out)], ["plant-server", "--once"]):
        assert cli.main([*verb, "--hours", "0.5", "--params", str(tmp_path / "p.toml")]) == 2
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and "--params applies to --plant model only" in lines[0]


# -- slow: the sweep and the speed --------------------------------------------------------

@pytest.mark.slow
@pytest.mark.skipif(not CHECK_DAY.exists(), reason="shared/tools/check_day.py not found")
def test_every_effect_on_several_plants_passes_the_contract_check(cfg, tmp_path):
    failures = []
    for plant_seed in (0, 1, 2, 3):
        for i, effect in enumerate((None, *EFFECTS)):
            day_seed = 100 + 10 * plant_seed + i
            d = simulate_independent_day(cfg, 24.0, day_seed, effect, plant_seed=plant_seed)
            r = _check_day(d.write(tmp_path / "day.mcap"), 24.0)
            if r.returncode != 0:
                failures.append((plant_seed, day_seed, effect, r.stdout))
    assert not failures, failures


@pytest.mark.slow
def test_a_48_hour_day_takes_at_most_about_20_seconds(cfg):
    simulate_independent_day(cfg, 0.2, 0, plant_seed=5)  # compile and commission
    t0 = time.perf_counter()
    simulate_independent_day(cfg, 48.0, 9, plant_seed=5)
    assert time.perf_counter() - t0 < 25.0
