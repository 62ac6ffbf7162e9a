"""The hidden effects of the virtual plant (``softsensor/plant/effects.py``), each simulated and
checked against what it must do to the day: the inlet moisture, a sensor's bias, the lab's
stamps, an input's lag, fouling, ambient heat loss, alternating chip batches; and the effects
and magnitudes refused."""

import numpy as np
import pytest

from softsensor.errors import ConfigError
from softsensor.plant.effects import EFFECTS
from softsensor.plant.simulator import simulate_day


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


def test_bad_effect_and_hours(cfg):
    with pytest.raises(ConfigError, match="unknown effect 'smoke'"):
        simulate_day(cfg, 1.0, 0, effect="smoke")
    with pytest.raises(ConfigError, match="outside the valid range"):
        simulate_day(cfg, 1.0, 0, effect="input_lag", magnitude=-1.0)
    with pytest.raises(ConfigError, match="--hours"):
        simulate_day(cfg, -2.0, 0)
    assert set(EFFECTS) == {"inlet_moisture", "sensor_bias", "lab_delay", "fouling_drift",
                            "input_lag", "ambient_heat_loss", "unexplained"}
