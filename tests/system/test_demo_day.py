"""The committed demo day is what its documented command produces."""

import shlex

import numpy as np
import pandas as pd
from paths import REPO

from softsensor.apps.virtual_plant import load_plant, simulate_plant
from softsensor.cli import build_parser
from softsensor.recording.mcap_day import read_day
from softsensor.signals import TOPIC_TRUTH

ROOT = REPO
DEMO = ROOT / "replay" / "demo-day.mcap"

# The file rounds values to 1e-6 (lab results to 1e-5); the closed loop may amplify
# floating-point differences between machines (numba, libm). Tolerances per unit, far below
# what would change the demo (inlet moisture steps of 0.15 kg/kg, lab noise 0.003 kg/kg).
ATOL = {"T_air_in": 0.05, "T_fiber_in": 0.05, "T_amb": 0.05, "T_sp": 0.05,
        "T_dryer_out": 0.05, "T_cyclone_out": 0.05,                       # K
        "m_air": 0.05, "m_fiber": 0.005, "m_steam": 0.001,                # kg/s
        "H_amb": 1e-5, "flap_cmd": 0.1,                                   # kg/kg, %
        "moisture_in": 1e-4, "moisture_out": 1e-4}                        # kg/kg


def _documented_args():
    """The ``softsensor simulate`` command of replay/README.md, parsed by the CLI's parser."""
    text = (ROOT / "replay" / "README.md").read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("softsensor simulate "))
    return build_parser().parse_args(shlex.split(line)[1:])


def _close(recorded: pd.DataFrame, again: pd.DataFrame, what: str) -> None:
    assert list(recorded.columns) == list(again.columns), f"{what}: other columns"
    for col in recorded.columns:
        np.testing.assert_allclose(recorded[col].to_numpy(float), again[col].to_numpy(float),
                                   rtol=0, atol=ATOL[col], err_msg=f"{what} {col}")


def test_demo_day_regenerates_from_its_command():
    args = _documented_args()
    # the documented command writes this file from the matched plant (the model itself)
    assert args.plant == "model" and (ROOT / args.out).resolve() == DEMO.resolve()
    assert DEMO.stat().st_size < 4 * 2**20, "demo day must stay below 4 MB"
    day = read_day(DEMO)
    again = simulate_plant(load_plant(args), args)  # what `softsensor simulate` runs
    assert day.topic("/truth/effect")[0][1] == again.effect
    np.testing.assert_array_equal(day.scans.index.to_numpy(), again.scans.index.to_numpy())
    _close(day.scans, again.scans, "/plant/scan")
    # the truth the replay's summary scores against: the inlet moisture's steps and drift
    truth = ["moisture_in", "moisture_out"]
    np.testing.assert_array_equal(day.truth.index.to_numpy(), again.truth.index.to_numpy())
    _close(day.truth[truth], again.truth[truth], TOPIC_TRUTH)
    assert list(day.labs.sample_id) == list(again.labs.sample_id)
    np.testing.assert_array_equal(day.labs.sample_time_ns, again.labs.sample_time_ns)
    np.testing.assert_allclose(day.labs.moisture_out, again.labs.moisture_out, rtol=0,
                               atol=ATOL["moisture_out"] + 1e-5)
