"""Plant configuration: the shipped file, validation errors naming the key, parameter files."""

from pathlib import Path

import numpy as np
import pytest

from softsensor.errors import ConfigError
from softsensor.plantconfig import (
    PARAMETER_NAMES,
    default_config_path,
    load_parameters,
    load_plant_config,
)

ROOT = Path(__file__).resolve().parents[1]


def test_packaged_config_is_the_repository_config():
    assert default_config_path().read_text() == (ROOT / "config" / "dryer1.toml").read_text()


def test_reference_plant_matches_contract_section_6():
    cfg = load_plant_config(ROOT / "config" / "dryer1.toml")
    assert cfg.tube.length == 55.0 and cfg.tube.diameter == 2.6
    assert cfg.tube.wall_thickness == 0.006 and cfg.tube.n_cells == 50
    assert cfg.cyclone.count == 2 and cfg.cyclone.n_cells == 5
    assert cfg.nominal.m_fiber == 6.0 and cfg.nominal.m_air == 82.0
    assert cfg.nominal.T_sp == 348.0
    # the paper's Table 1 bounds and eq. 4 weights
    b = dict(zip(PARAMETER_NAMES, cfg.bounds().tolist(), strict=True))
    for name in ("mult_D", "mult_C", "mult_h", "mult_k", "mult_p"):
        assert b[name] == [0.01, 5.0]
        assert cfg.parameters[name].value == 1.0
    assert b["hm_cyc"] == [1e-7, 1e-3] and b["hc_cyc"] == [1.0, 200.0]
    np.testing.assert_array_equal(cfg.cost.weights(), [0.003, 0.003, 5.0])


def _write(tmp_path, text, name="plant.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("old,new,message", [
    ("m_fiber = 6.0", "m_fiber = -6.0", "nominal.m_fiber must be > 0, got -6.0"),
    ("length = 55.0", "length = \"long\"", "tube.length must be a number"),
    ("n_cells = 50", "n_cells = 50\nwidth = 3", "tube.width is not a known key"),
    ("[cost]", "[costs]", "[costs] is not a known section"),
    ("low = 1.0e-7", "low = 2.0e-3", "parameters.hm_cyc.high must be > low"),
    ("value = 20.0", "value = 500.0", "parameters.hc_cyc.value must lie within"),
])
def test_bad_config_names_the_key(tmp_path, old, new, message):
    text = default_config_path().read_text()
    assert old in text
    p = _write(tmp_path, text.replace(old, new, 1))
    with pytest.raises(ConfigError) as err:
        load_plant_config(p)
    assert message in str(err.value)
    assert str(p) in str(err.value)
    assert "\n" not in str(err.value)


def test_missing_key_and_section(tmp_path):
    text = default_config_path().read_text()
    p = _write(tmp_path, text.replace("diameter = 2.6 ", "", 1).replace(
        "diameter = 2.6", "", 1))
    with pytest.raises(ConfigError, match=r"tube\.diameter is missing"):
        load_plant_config(p)
    start = text.index("[fiber]")
    end = text.index("[hot_gas]")
    p = _write(tmp_path, text[:start] + text[end:], "nofiber.toml")
    with pytest.raises(ConfigError, match=r"section \[fiber\] is missing"):
        load_plant_config(p)


def test_malformed_and_missing_file(tmp_path):
    p = _write(tmp_path, "[tube\nlength = 3")
    with pytest.raises(ConfigError, match="malformed TOML"):
        load_plant_config(p)
    with pytest.raises(ConfigError, match="no such config file"):
        load_plant_config(tmp_path / "absent.toml")


def test_parameter_file_overrides_values_within_bounds(tmp_path):
    cfg = load_plant_config()
    p = _write(tmp_path, "[parameters.mult_D]\nvalue = 0.5\n[parameters.hc_cyc]\nvalue = 55.0\n")
    cal = load_parameters(p, cfg)
    assert cal.parameters["mult_D"].value == 0.5 and cal.parameters["hc_cyc"].value == 55.0
    assert cal.parameters["mult_h"].value == cfg.parameters["mult_h"].value
    bad = _write(tmp_path, "[parameters.mult_D]\nvalue = 9.0\n", "bad.toml")
    with pytest.raises(ConfigError, match="mult_D.value must lie within"):
        load_parameters(bad, cfg)
    unknown = _write(tmp_path, "[parameters.mult_X]\nvalue = 1.0\n", "unknown.toml")
    with pytest.raises(ConfigError, match="mult_X is not one of the paper's Table 1"):
        load_parameters(unknown, cfg)


def test_packaged_tagmap_is_the_repository_tagmap():
    from softsensor.ingest.tagmap import DEFAULT_TAGMAP

    assert DEFAULT_TAGMAP.read_text() == (ROOT / "config" / "tagmap_dryer1.toml").read_text()
