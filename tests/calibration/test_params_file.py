"""PARAMS.toml (``softsensor/calibration/params_file.py``): written and read back, and the TOML
writer round-tripping through tomllib."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from softsensor.calibration.params_file import dumps, params_document, read_fit, write_params
from softsensor.configfile import read_toml
from softsensor.errors import ConfigError
from softsensor.plantconfig import PARAMETER_NAMES, load_parameters


def test_params_file_round_trip(tmp_path, config):
    values = dict(zip(PARAMETER_NAMES, [0.7, 2.0, 1.4, 2.0, 1.8, 3e-4, 50.0], strict=True))
    fit = {"cost": 0.0123, "trials": 200, "seed": 7, "windows": ["a [x .. y]"],
           "rmse": {"T_dryer_out": 0.1, "T_cyclone_out": 0.2, "moisture_out": 0.004},
           "big": float("inf")}
    doc = params_document(config, values, fit, {"mult_D": "identifiable"})
    path = write_params(tmp_path / "PARAMS.toml", doc, "a comment\nline two")
    raw = read_toml(path)
    assert raw["parameters"]["mult_D"] == {"value": 0.7, "low": 0.01, "high": 5.0, "log": True,
                                           "verdict": "identifiable"}
    assert raw["fit"]["rmse"]["moisture_out"] == 0.004 and raw["fit"]["big"] == math.inf
    loaded = load_parameters(path, config)
    np.testing.assert_allclose(loaded.parameter_vector(), list(values.values()))
    assert read_fit(path)["trials"] == 200
    with pytest.raises(ConfigError, match="does not exist"):
        write_params(tmp_path / "nope" / "P.toml", doc)


def test_dumps_round_trips_through_tomllib():
    doc = {"a": {"s": 'quote " and \\ back\nnew line', "i": 3, "f": 0.1 + 0.2, "b": False,
                 "inf": -math.inf, "list": ["x", "y"], "nums": [1.5, 2.0], "gone": None,
                 "sub": {"deep": 1e-300, "none": None}},
           "empty": {}}
    text = dumps(doc, "head\n\ntail")
    assert text.startswith("# head\n#\n# tail\n")
    back = tomllib.loads(text)
    expected = {"a": {k: v for k, v in doc["a"].items() if k != "gone"}, "empty": {}}
    expected["a"]["sub"] = {"deep": 1e-300}
    assert back == expected
    assert math.isnan(tomllib.loads(dumps({"x": math.nan}))["x"])
    with pytest.raises(TypeError, match="cannot write to TOML"):
        dumps({"x": object()})
