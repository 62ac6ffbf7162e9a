"""A plant with a history, its calibration's [model_error] and its plant normal
(:mod:`softsensor.diagnosis.plant_normal`), as the plant-normal tests use them.

The plant is the independent virtual plant (:mod:`softsensor.plant.independent`, shares no
equation with the model) with plant seed :data:`PLANT`, on which no threshold or constant of
the diagnosis was set; its history is :data:`HISTORY_SEEDS` days of :data:`HOURS` h, clean.
:func:`build` writes, for the whole history and for its first three days, the PARAMS.toml
(the config's parameters and the [model_error] learned from those days) and the plant normal
beside it, learned by ``learn_plant_normal`` exactly as ``softsensor learn-normal`` does.

Learning the normal diagnoses every history day (minutes), so the default suite reads the
copy kept in ``tests/fixtures/plant_normal/`` (written by ``python tests/support/
plant_normal_fixture.py``) and the slow test builds it afresh and asserts the same.
"""

from __future__ import annotations

import sys
from pathlib import Path

from softsensor.calibration.dataset import segment_from_day
from softsensor.calibration.model_error_fit import fit_model_error
from softsensor.calibration.params_file import params_document, write_params
from softsensor.diagnosis.plant_normal import learn_plant_normal
from softsensor.model.dryer import DryerModel
from softsensor.plant.independent import simulate_independent_day
from softsensor.plantconfig import load_parameters, load_plant_config

PLANT = 8203
HOURS = 12.0
HISTORY_SEEDS = (100, 101, 102, 103, 104, 105, 106)
#: The short history: its first three days.
SHORT = 3
FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "plant_normal"


def history_days(cfg, seeds=HISTORY_SEEDS):
    return [simulate_independent_day(cfg, HOURS, s, plant_seed=PLANT) for s in seeds]


def params_for(cfg, days, path: Path) -> Path:
    """PARAMS.toml at ``path``: the config's parameters and the [model_error] of ``days``."""
    segs = [segment_from_day(d, cfg, source=f"history day {i}") for i, d in enumerate(days)]
    me = fit_model_error(DryerModel(cfg), segs, cfg.parameter_vector(),
                         float(cfg.nominal.moisture_in))
    values = {n: cfg.parameters[n].value for n in cfg.parameters}
    return write_params(path, params_document(cfg, values, {}, model_error=me.to_table()))


def build(out: Path) -> dict[str, Path]:
    """Write ``params_{n}.toml`` and its plant normal for the whole history and its first
    :data:`SHORT` days into ``out``; the PARAMS.toml paths by ``"full"`` and ``"short"``."""
    out.mkdir(parents=True, exist_ok=True)
    cfg = load_plant_config()
    days = history_days(cfg)
    paths = {}
    for name, n in (("full", len(days)), ("short", SHORT)):
        path = params_for(cfg, days[:n], out / f"params_{n}.toml")
        normal = learn_plant_normal(load_parameters(path, cfg), days[:n], path,
                                    sources=[f"seed {s}" for s in HISTORY_SEEDS[:n]])
        normal.write(path)
        paths[name] = path
    return paths


if __name__ == "__main__":
    print(build(Path(sys.argv[1]) if len(sys.argv) > 1 else FIXTURES))
