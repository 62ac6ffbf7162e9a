"""What every verb loads first: the plant config with its parameters, and recorded days.

The core takes data already read; these helpers are the one place the verbs read them, so
every verb treats ``--config``, ``--params`` and a DAY.mcap alike. Light on purpose (no
model, no optuna): ``simulate`` and ``plant-server`` import it too.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import NamedTuple

from softsensor.estimation.model_error import model_error_of
from softsensor.plantconfig import PlantConfig, load_parameters, load_plant_config
from softsensor.recording.mcap_day import RecordedDay, read_day
from softsensor.signals import TOPIC_LAB, TOPIC_SCAN


class LoadedConfig(NamedTuple):
    """``base``: the plant config as written (``--config``, else the packaged ``dryer1``);
    ``config``: ``base`` with ``--params`` applied (``base`` itself without ``--params``)."""

    base: PlantConfig
    config: PlantConfig


def load_config_and_params(args: argparse.Namespace) -> LoadedConfig:
    """The plant config of ``args.config`` and the parameters of ``args.params`` on it
    (either attribute may be absent or None). Raises
    :class:`~softsensor.errors.ConfigError` naming the file and key for a bad file."""
    base = load_plant_config(getattr(args, "config", None))
    params = getattr(args, "params", None)
    current = load_parameters(params, base) if params else base
    model_error_of(current)  # a bad [model_error] stops here, naming its key
    return LoadedConfig(base, current)


def read_day_inputs(path: str | Path) -> RecordedDay:
    """A recorded day's scans and lab results (never its ``/truth`` topic)."""
    return read_day(path, topics=[TOPIC_SCAN, TOPIC_LAB])


__all__ = ["LoadedConfig", "load_config_and_params", "read_day_inputs"]
