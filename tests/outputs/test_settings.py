"""The ``[outputs]`` tables (``softsensor/outputs/settings.py``): defaults, values and unknown keys
refused with the dotted key named."""

from __future__ import annotations

import pytest

from softsensor.errors import ConfigError
from softsensor.outputs.settings import output_settings
from softsensor.plantconfig import default_config_path, load_plant_config


def test_output_tables_are_validated(tmp_path):
    def cfg(text: str):
        p = tmp_path / "plant.toml"
        p.write_text(default_config_path().read_text() + "\n" + text)
        return load_plant_config(p)

    o = output_settings(load_plant_config())
    assert not o.modbus.enabled and not o.prometheus.enabled and o.modbus.host == "127.0.0.1"
    o = output_settings(cfg("[outputs.modbus]\nenabled = true\nport = 1503\n"))
    assert o.modbus.enabled and o.modbus.port == 1503
    with pytest.raises(ConfigError, match=r"outputs\.modbus\.port must be"):
        output_settings(cfg("[outputs.modbus]\nport = 70000\n"))
    with pytest.raises(ConfigError, match=r"outputs\.scada is not a known key \(known: modbus, "):
        output_settings(cfg("[outputs.scada]\nenabled = true\n"))
    with pytest.raises(ConfigError, match=r"outputs\.prometheus\.colour is not a known key"):
        output_settings(cfg("[outputs.prometheus]\ncolour = 1\n"))
