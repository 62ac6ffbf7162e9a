"""What every verb loads first: the plant config with its parameters, and recorded days.

The core takes data already read; these helpers are the one place the verbs read them, so
every verb treats ``--config``, ``--params`` and a DAY.mcap alike. Every table of the config
and of PARAMS.toml is built here, once (:data:`TABLES`), whichever verb runs: a misspelt key
in any of them stops the start with one line naming the file and the key. Light on purpose
(no model, no optuna): ``simulate`` and ``plant-server`` import it too.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from softsensor.advisor.settings import advisor_settings
from softsensor.calibration.settings import calibration_settings
from softsensor.diagnosis.settings import diagnosis_settings
from softsensor.estimation.model_error import model_error_of
from softsensor.estimation.settings import estimator_settings
from softsensor.outputs.settings import output_settings
from softsensor.plant.settings import virtual_plant_settings
from softsensor.plantconfig import (
    EXTRA_SECTIONS,
    PlantConfig,
    discrepancy_of,
    load_parameters,
    load_plant_config,
)
from softsensor.presentation.display import display_settings
from softsensor.recording.mcap_day import RecordedDay, read_day
from softsensor.service.settings import service_settings
from softsensor.signals import TOPIC_LAB, TOPIC_SCAN
from softsensor.windows.plausibility import plausibility_from_config


def _lab_map(cfg: PlantConfig) -> object:
    """:func:`~softsensor.ingest.historian_map.plant_lab_map`, imported when a config has a
    ``[lab]`` table (its units need pint, its humidity the model's psychrometrics)."""
    if "lab" not in cfg.extra:
        return None
    from softsensor.ingest.historian_map import plant_lab_map

    return plant_lab_map(cfg)


#: Every table a plant config or a PARAMS.toml may hold beyond the plant's own sections, with
#: the function its owner reads it by (each builds its frozen dataclass once per config).
TABLES: dict[str, Callable[[PlantConfig], object]] = {
    "service": service_settings, "estimator": estimator_settings,
    "calibration": calibration_settings, "display": display_settings,
    "outputs": output_settings, "virtual_plant": virtual_plant_settings,
    "plausibility": plausibility_from_config, "lab": _lab_map,
    "discrepancy": discrepancy_of, "model_error": model_error_of,
    "advisor": advisor_settings,
    "diagnosis": diagnosis_settings,
}
assert set(TABLES) == {*EXTRA_SECTIONS, "discrepancy", "model_error"}


def build_tables(cfg: PlantConfig) -> PlantConfig:
    """``cfg`` with every table built (:data:`TABLES`); ConfigError naming the file and the
    dotted key of the first bad one."""
    for build in TABLES.values():
        build(cfg)
    return cfg


class LoadedConfig(NamedTuple):
    """``base``: the plant config as written (``--config``, else the packaged ``dryer1``);
    ``config``: ``base`` with ``--params`` applied (``base`` itself without ``--params``)."""

    base: PlantConfig
    config: PlantConfig


def load_config_and_params(args: argparse.Namespace) -> LoadedConfig:
    """The plant config of ``args.config`` and the parameters of ``args.params`` on it
    (either attribute may be absent or None). Raises
    :class:`~softsensor.errors.ConfigError` naming the file and key for a bad file."""
    base = build_tables(load_plant_config(getattr(args, "config", None)))
    params = getattr(args, "params", None)
    current = build_tables(load_parameters(params, base)) if params else base
    return LoadedConfig(base, current)


def read_day_inputs(path: str | Path) -> RecordedDay:
    """A recorded day's scans and lab results (never its ``/truth`` topic)."""
    return read_day(path, topics=[TOPIC_SCAN, TOPIC_LAB])


__all__ = ["TABLES", "LoadedConfig", "build_tables", "load_config_and_params",
           "read_day_inputs"]
