"""The virtual plant: closed loop, sensors, lab, effects, MCAP output, CLI errors."""

import subprocess
import sys

import numpy as np
import pytest
from paths import REPO

from softsensor.errors import ConfigError
from softsensor.plant.controller import fraction_for_temperature, mixed_air
from softsensor.plant.effects import EFFECTS
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_plant_config
from softsensor.recording.mcap_day import read_day
from softsensor.signals import SCAN_SIGNALS

CHECK_DAY = REPO.parent / "shared" / "tools" / "check_day.py"


@pytest.fixture(scope="module")
def cfg():
    return load_plant_config()


@pytest.fixture(scope="module")
def clean(cfg):
    return simulate_day(cfg, 12.0, seed=11)


def test_loop_holds_the_set_point_and_lab_schedule(clean):
    s, labs = clean.scans, clean.labs
    assert list(s.columns) == list(SCAN_SIGNALS)
    dt = np.diff(s.index.to_numpy()) / 1e9
    assert np.allclose(dt, 10.0)
    err = s.T_dryer_out - s.T_sp
    assert abs(err.mean()) < 0.3 and err.std() < 1.5
    assert 440 <= s.T_air_in.min() and s.T_air_in.max() <= 560
    assert 0.06 <= clean.truth.moisture_out.mean() <= 0.16
    delay_min = (labs.log_time_ns - labs.sample_time_ns) / 6e10
    assert len(labs) >= 2 and delay_min.between(20, 90).all()
    gaps_h = np.diff(labs.sample_time_ns) / 3.6e12
    assert ((gaps_h >= 2) & (gaps_h <= 4)).all()
    # lab = truth at the sample time plus lab noise (0.003 kg/kg)
    truth_at = np.interp(labs.sample_time_ns, clean.truth.index, clean.truth.moisture_out)
    assert np.abs(labs.moisture_out - truth_at).max() < 0.012


def test_same_seed_same_day_and_effects_keep_disturbances(cfg, clean):
    again = simulate_day(cfg, 12.0, seed=11)
    assert again.scans.equals(clean.scans) and again.labs.equals(clean.labs)
    other = simulate_day(cfg, 12.0, seed=12)
    assert not np.allclose(other.scans.m_fiber, clean.scans.m_fiber)
    biased = simulate_day(cfg, 12.0, seed=11, effect="sensor_bias")
    np.testing.assert_allclose(biased.truth.m_fiber, clean.truth.m_fiber)


def test_written_day_reads_back_and_passes_the_contract_check(clean, tmp_path):
    path = clean.write(tmp_path / "day.mcap")
    day = read_day(path)
    np.testing.assert_allclose(day.scans.to_numpy(), clean.scans.to_numpy(), atol=1e-5)
    assert list(day.labs.sample_id) == list(clean.labs.sample_id)
    assert day.truth is not None and "moisture_in" in day.truth
    assert day.topic("/truth/effect")[0][1]["effect"] == "none"
    if CHECK_DAY.exists():
        r = subprocess.run([sys.executable, str(CHECK_DAY), str(path), "--hours", "12"],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stdout


def test_inlet_moisture_effect(cfg):
    d = simulate_day(cfg, 12.0, seed=5, effect="inlet_moisture", magnitude=0.2)
    dev = d.truth.moisture_in - cfg.nominal.moisture_in
    assert 0.14 <= np.abs(dev).max() <= 0.2 + 1e-9
    # the loop moves T_air_in to evaporate the extra water: correlated with moisture_in
    assert np.corrcoef(d.truth.moisture_in, d.truth.T_air_in)[0, 1] > 0.8


def test_sensor_bias_effect(cfg):
    d = simulate_day(cfg, 6.0, seed=4, effect="sensor_bias", magnitude=4.0)
    ch = d.effect["channel"]
    off = (d.scans[ch] - d.truth[ch]).mean()
    assert off == pytest.approx(d.effect["sign"] * 4.0, abs=0.1)
    other = "T_cyclone_out" if ch == "T_dryer_out" else "T_dryer_out"
    assert abs((d.scans[other] - d.truth[other]).mean()) < 0.1


def test_lab_delay_effect_shifts_stamps(cfg):
    d = simulate_day(cfg, 24.0, seed=8, effect="lab_delay", magnitude=45.0)
    clean = simulate_day(cfg, 24.0, seed=8)
    shift_min = (d.labs.sample_time_ns - clean.labs.sample_time_ns) / 6e10
    assert np.allclose(shift_min, d.effect["sign"] * 45.0, atol=1e-6)
    delay_min = (d.labs.log_time_ns - d.labs.sample_time_ns) / 6e10
    assert delay_min.between(15, 95).all()


def test_input_lag_effect(cfg):
    d = simulate_day(cfg, 12.0, seed=9, effect="input_lag", magnitude=10.0)
    meas = d.scans.T_air_in.to_numpy()
    true = d.truth.T_air_in.to_numpy()

    def lagged(tau_min):
        out = np.empty_like(true)
        out[0] = true[0]
        a = 1.0 - np.exp(-10.0 / (tau_min * 60.0)) if tau_min > 0 else 1.0
        for i in range(1, len(true)):
            out[i] = out[i - 1] + a * (true[i - 1] - out[i - 1])
        return out

    taus = [0.0, 3.0, 6.0, 10.0, 15.0, 25.0]
    rms = [np.sqrt(np.mean((meas - lagged(t)) ** 2)) for t in taus]
    assert taus[int(np.argmin(rms))] == 10.0
    assert min(rms) < 0.6  # what is left is the 0.5 K sensor noise


def test_fouling_and_ambient_effects_move_the_plant_the_right_way(cfg):
    clean = simulate_day(cfg, 12.0, seed=6)
    fouled = simulate_day(cfg, 12.0, seed=6, effect="fouling_drift", magnitude=0.4)
    tail = slice(-360, None)  # last hour
    assert (fouled.truth.moisture_out.iloc[tail].mean()
            > clean.truth.moisture_out.iloc[tail].mean() + 0.005)
    lossy = simulate_day(cfg, 12.0, seed=6, effect="ambient_heat_loss", magnitude=1.0)
    cold = clean.scans.T_amb < 283.15
    assert cold.any()
    assert (lossy.truth.T_air_in[cold] - clean.truth.T_air_in[cold]).mean() > 0.3


def test_bad_effect_and_hours(cfg):
    with pytest.raises(ConfigError, match="unknown effect 'smoke'"):
        simulate_day(cfg, 1.0, 0, effect="smoke")
    with pytest.raises(ConfigError, match="outside the valid range"):
        simulate_day(cfg, 1.0, 0, effect="input_lag", magnitude=-1.0)
    with pytest.raises(ConfigError, match="--hours"):
        simulate_day(cfg, -2.0, 0)
    assert set(EFFECTS) == {"inlet_moisture", "sensor_bias", "lab_delay", "fouling_drift",
                            "input_lag", "ambient_heat_loss", "unexplained"}


def test_unexplained_effect_alternates_the_kinetics(cfg):
    """Chip batches: mult_D switches between 1 +- X in blocks of 1.5 to 3 h."""
    clean = simulate_day(cfg, 8.0, seed=6)
    d = simulate_day(cfg, 8.0, seed=6, effect="unexplained", magnitude=0.3)
    assert d.effect["effect"] == "unexplained" and d.effect["sign"] in (-1.0, 1.0)
    np.testing.assert_allclose(d.truth.m_fiber, clean.truth.m_fiber)
    diff = (d.truth.moisture_out - clean.truth.moisture_out).to_numpy()
    # the first block (1.5 h at least) dries faster when the sign is +, slower when -
    first = slice(180, 540)  # 30 to 90 min
    assert d.effect["sign"] * diff[first].mean() < -0.003
    assert diff.max() > 0.003 and diff.min() < -0.003  # both levels occur


def test_mixing_inverse():
    T, Y = mixed_air(0.4, 900.0, 0.06, 280.0, 0.004)
    assert 500 < T < 560 and Y == pytest.approx(0.4 * 0.06 + 0.6 * 0.004)
    assert fraction_for_temperature(T, 900.0, 0.06, 280.0, 0.004) == pytest.approx(0.4)


@pytest.mark.parametrize("args,needle", [
    (["--effect", "smoke"], "unknown effect 'smoke'"),
    (["--hours", "-1"], "--hours must be in"),
    (["--config", "/nonexistent/plant.toml"], "no such config file"),
])
def test_cli_bad_input_is_one_line(tmp_path, args, needle):
    r = subprocess.run([sys.executable, "-m", "softsensor.cli", "simulate", "--plant", "model",
                        "--hours", "1", *args, "--out", str(tmp_path / "x.mcap")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], r.stderr
