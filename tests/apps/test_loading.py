"""The tables beyond the plant's own (issue 23, item 2): built once, at start, errors naming the
key whichever verb runs, one key per rule."""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
from pathlib import Path

import pytest

import softsensor.configfile as configfile
from softsensor.apps.loading import TABLES, load_config_and_params
from softsensor.cli import main as cli_main
from softsensor.errors import ConfigError
from softsensor.estimation.settings import estimator_settings
from softsensor.estimation.state_space import ErrorPriors
from softsensor.outputs.settings import output_settings
from softsensor.plantconfig import (
    EXTRA_SECTIONS,
    DiscrepancyPrior,
    default_config_path,
    discrepancy_of,
    load_parameters,
    load_plant_config,
)
from softsensor.service.build import make_service
from softsensor.service.settings import service_settings


def _config(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "plant.toml"
    p.write_text(default_config_path().read_text() + "\n" + text)
    return p


def _load(config: Path | None = None, params: Path | None = None):
    return load_config_and_params(argparse.Namespace(config=config, params=params))


def test_every_table_is_built_at_the_load_point():
    assert set(TABLES) == {*EXTRA_SECTIONS, "discrepancy", "model_error"}


@pytest.mark.parametrize("table, key", [
    ("[calibration]\ntrails = 3\n", "calibration.trails"),
    ("[display]\ntime_zone = \"Europe/Stockholm\"\nbasis = \"dry\"\n", "display.basis"),
    ("[outputs.web]\nenabeld = true\n", "outputs.web.enabeld"),
    ("[plausibility.T_air_in]\nhihg = 650.0\n", "plausibility.T_air_in.hihg"),
    ("[virtual_plant]\nlab_intervall_min = 30.0\n", "virtual_plant.lab_intervall_min"),
])
def test_a_misspelt_key_in_any_table_stops_any_verb_at_start(tmp_path, capsys, table, key):
    """Each table used to be parsed when its owner first needed it: ``softsensor health`` (or
    ``replay``) never read ``[calibration]``, so a typo there went unnoticed until a
    calibration ran days later. Now every verb builds every table when it loads the config."""
    p = _config(tmp_path, table)
    with pytest.raises(ConfigError, match=re.escape(f"{p}: {key} is not a known key")):
        _load(p)
    rc = cli_main(["health", "--config", str(p), "--connect", "tcp/127.0.0.1:9",
                   "--timeout", "0.2"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and key in err, err


def test_a_misspelt_discrepancy_key_names_the_params_file(tmp_path):
    """``[discrepancy]`` used to bypass build_section: a misspelt key was silently ignored and
    the estimator ran on its defaults."""
    params = tmp_path / "params.toml"
    params.write_text("[parameters.mult_D]\nvalue = 1.0\n[discrepancy]\ncomon_std = 0.4\n")
    with pytest.raises(ConfigError, match=rf"{params}: discrepancy\.comon_std is not a known "
                                          r"key \(known: common_std, "):
        load_parameters(params, load_plant_config())
    params.write_text("[parameters.mult_D]\nvalue = 1.0\n[discrepancy]\ntau_s = -5.0\n")
    with pytest.raises(ConfigError, match=r"discrepancy\.tau_s must be > 0, got -5\.0"):
        load_parameters(params, load_plant_config())
    params.write_text("[parameters.mult_D]\nvalue = 1.0\n[discrepancy]\ncommon_std = 0.4\n"
                      "tau_s = 7200\nn_windows = 12\n")
    cfg = load_parameters(params, load_plant_config())
    assert discrepancy_of(cfg) == DiscrepancyPrior(common_std=0.4, tau_s=7200.0, n_windows=12.0)
    priors = ErrorPriors.from_config(cfg, estimator_settings(cfg), heat_gain=1.0)
    assert priors.source == "calibration [discrepancy]" and priors.sigma[0] == 0.4


def test_a_calibration_in_memory_may_leave_unknown_numbers_as_nan():
    """A calibration that could not estimate a number leaves it NaN in memory (its PARAMS.toml
    leaves it out): not known, like an absent key."""
    cfg = load_plant_config()
    mem = dataclasses.replace(cfg, extra={**cfg.extra, "discrepancy": {
        "common_std": math.nan, "dryer_std": 0.3, "tau_s": 3600.0}})
    assert discrepancy_of(mem) == DiscrepancyPrior(dryer_std=0.3, tau_s=3600.0)
    assert discrepancy_of(cfg) is None


def test_tables_are_built_once_per_config(tmp_path, monkeypatch):
    """Built at the load point, then only read: building the daemon's service builds no table
    again (each owner used to parse its raw table at every call)."""
    params = tmp_path / "params.toml"
    params.write_text("[parameters.mult_D]\nvalue = 0.9\n")
    base, cfg = _load(_config(tmp_path, "[estimator]\nhistory_hours = 6.0\n"), params)
    assert cfg is not base and estimator_settings(cfg) is estimator_settings(cfg)
    # --params changes no table of the plant config: what the load point built is kept
    assert output_settings(cfg) is output_settings(base)
    assert estimator_settings(cfg) is estimator_settings(base)
    calls = []
    real = configfile.build_section

    def counting(cls, *args, **kwargs):
        calls.append(cls.__name__)
        return real(cls, *args, **kwargs)

    monkeypatch.setattr(configfile, "build_section", counting)
    for module in ("softsensor.plantconfig", "softsensor.service.settings",
                   "softsensor.windows.plausibility", "softsensor.estimation.model_error"):
        monkeypatch.setattr(f"{module}.build_section", counting, raising=False)
    service = make_service(cfg, service_settings(cfg), scan_period_s=10.0)
    assert service.estimator.settings.history_hours == 6.0
    assert calls == [], calls
    changed = dataclasses.replace(cfg, extra={**cfg.extra, "estimator": {"history_hours": 4.0}})
    assert estimator_settings(changed).history_hours == 4.0  # a new table: built anew


def test_one_key_sets_the_estimators_kind(tmp_path):
    base, cfg = _load(_config(tmp_path, "[estimator]\nkind = \"openloop\"\n"))
    assert make_service(cfg, service_settings(base), scan_period_s=10.0).kind == "openloop"
    assert make_service(cfg, service_settings(base), "ukf", 10.0).kind == "ukf"  # --estimator
    with pytest.raises(ConfigError, match=r"service\.estimator is not a key any more: set "
                                          r"estimator\.kind \(or --estimator\)"):
        _load(_config(tmp_path, "[service]\nestimator = \"openloop\"\n"))
