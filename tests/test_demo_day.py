"""The committed demo day is what its documented command produces."""

from pathlib import Path

import numpy as np

from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_plant_config
from softsensor.recording.mcap_day import read_day

DEMO = Path(__file__).resolve().parents[1] / "replay" / "demo-day.mcap"


def test_demo_day_regenerates_from_its_command():
    day = read_day(DEMO)
    assert DEMO.stat().st_size < 4 * 2**20
    again = simulate_day(load_plant_config(), 48.0, 1, "inlet_moisture")
    assert day.topic("/truth/effect")[0][1]["effect"] == "inlet_moisture"
    assert len(day.scans) == len(again.scans) == 17281
    # values are rounded to 1e-6 in the file; allow for floating-point differences between
    # machines in the closed loop (K, kg/s, kg/kg)
    np.testing.assert_allclose(day.scans.to_numpy(), again.scans.to_numpy(), atol=0.05)
    np.testing.assert_allclose(day.labs.moisture_out, again.labs.moisture_out, atol=2e-3)
    assert list(day.labs.sample_id) == list(again.labs.sample_id)
