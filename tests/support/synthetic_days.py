"""Days for the calibration tests: recorded days made by hand (scans at the nominal point whose
window means are known exactly, lab results at chosen times), and the true parameters of the
virtual plant the calibration tests recover."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from softsensor.calibration.params_file import params_document, write_params
from softsensor.cli import main as cli_main
from softsensor.plantconfig import load_plant_config
from softsensor.recording.mcap_day import RecordedDay
from softsensor.signals import SCAN_SIGNALS

#: The virtual plant's true parameters in the calibration tests, away from the config's.
TRUTH = {"mult_D": 0.7, "mult_C": 2.0, "mult_h": 1.4, "mult_k": 2.0, "mult_p": 1.8,
         "hm_cyc": 3e-4, "hc_cyc": 50.0}
NS = 1_000_000_000
T0 = 1_767_571_200 * NS  # a multiple of 600 s


def make_day(hours: float, config, *, start_ns: int = T0, labs=None, step_at_h=None,
             scan_s: float = 10.0, path: str = "synthetic.mcap") -> RecordedDay:
    """Scans every ``scan_s`` s at the nominal point; ``m_fiber`` steps up at ``step_at_h``;
    T_dryer_out = 340 + hour of day (so window means are known exactly)."""
    n = int(round(hours * 3600 / scan_s)) + 1
    t = start_ns + (np.arange(n) * scan_s * NS).astype(np.int64)
    nom = config.nominal
    hrs = (t - start_ns) / 3.6e12
    data = {name: np.full(n, float(getattr(nom, name, 50.0))) for name in SCAN_SIGNALS}
    data["m_fiber"] = np.where(hrs >= (step_at_h if step_at_h is not None else 1e9), 6.8, 5.0)
    data["T_dryer_out"] = 340.0 + hrs
    data["T_cyclone_out"] = 338.0 + hrs
    scans = pd.DataFrame(data, index=pd.Index(t, name="log_time_ns"))
    labs = labs if labs is not None else []
    lab_df = pd.DataFrame({
        "log_time_ns": np.array([r[0] for r in labs], dtype=np.int64),
        "sample_time_ns": np.array([r[1] for r in labs], dtype=np.int64),
        "moisture_out": np.array([r[2] for r in labs], dtype=float),
        "sample_id": pd.Series([f"L{i}" for i in range(len(labs))], dtype=str)})
    return RecordedDay(path=Path(path), scans=scans, labs=lab_df, truth=None)


def labs_every(hours: float, every_h: float):
    """``(log_time_ns, sample_time_ns, moisture_out)`` of a lab result every ``every_h`` hours
    from 0.7 h on, each logged half an hour after its sample, all 0.1 kg/kg."""
    return [(T0 + int((h + 0.5) * 3.6e12), T0 + int(h * 3.6e12), 0.1)
            for h in np.arange(0.7, hours, every_h)]


def truth_days(directory: Path, seeds: tuple[int, int]) -> tuple[str, str, str]:
    """Two 16 h days of the matched plant with :data:`TRUTH` (``softsensor simulate``, day
    ``seeds``) and that plant's PARAMS.toml, written into ``directory``: ``(day, day,
    params)``."""
    true = write_params(directory / "true.toml",
                        params_document(load_plant_config(), TRUTH, {}))
    out = []
    for seed in seeds:
        day = directory / f"day{seed}.mcap"
        assert cli_main(["simulate", "--plant", "model", "--params", str(true), "--hours",
                         "16", "--seed", str(seed), "--out", str(day)]) == 0
        out.append(str(day))
    return out[0], out[1], str(true)


__all__ = ["NS", "T0", "TRUTH", "labs_every", "make_day", "truth_days"]
