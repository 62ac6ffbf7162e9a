"""The virtual plant's day (``softsensor/plant/simulator.py``): the closed loop holding its set
point, the lab schedule, the same seed giving the same day, the written day passing the
contract's check. Its effects: ``test_effects.py``; the ``simulate`` verb's refusals:
``tests/apps/test_virtual_plant.py``."""

import subprocess
import sys

import numpy as np
import pytest
from paths import CHECK_DAY

from softsensor.plant.simulator import simulate_day
from softsensor.recording.mcap_day import read_day
from softsensor.signals import SCAN_SIGNALS


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


def test_a_written_day_reads_back(clean, tmp_path):
    path = clean.write(tmp_path / "day.mcap")
    day = read_day(path)
    np.testing.assert_allclose(day.scans.to_numpy(), clean.scans.to_numpy(), atol=1e-5)
    assert list(day.labs.sample_id) == list(clean.labs.sample_id)
    assert day.truth is not None and "moisture_in" in day.truth
    assert day.topic("/truth/effect")[0][1]["effect"] == "none"


@pytest.mark.skipif(not CHECK_DAY.exists(), reason="shared/tools/check_day.py not found")
def test_a_written_day_passes_the_contract_check(clean, tmp_path):
    path = clean.write(tmp_path / "day.mcap")
    r = subprocess.run([sys.executable, str(CHECK_DAY), str(path), "--hours", "12"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout


