"""The drying-rate laws of ``fiber.drying_law`` and the structural library
(:mod:`softsensor.model.structure`).

What the alternatives are for: commissioned to the paper's nominal outlet moisture, each law
answers the inputs with another slope, which no Table 1 multiplier can do (at the commissioned
point the multipliers have no freedom left). Measured at the nominal point (central
differences of the steady outlet moisture): d moisture_out / d T_air_in -0.00338 (paper),
-0.00288 (cdc), -0.00245 (rea) kg/kg per K; d moisture_out / d moisture_in 0.534, 0.465,
0.400; the nominal outlet moisture of the commissioned laws 0.10108, 0.10117, 0.10110 kg/kg.
The balances per law are in tests/model/test_balances.py, the method-of-lines check per law in
tests/model/test_mol.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from softsensor.configfile import read_toml
from softsensor.errors import ConfigError, SolverError
from softsensor.model import DryerModel
from softsensor.model import wood as wd
from softsensor.model.structure import alternative_config, commission, structure_space
from softsensor.plantconfig import (
    DRYING_LAWS,
    default_config_path,
    load_plant_config,
    plant_config_from_dict,
)

LAWS = {a.sets["fiber.drying_law"]: a for a in structure_space() if a.family == "drying_law"}


@pytest.fixture(scope="module")
def base():
    return load_plant_config()


@pytest.fixture(scope="module")
def models(base):
    return {law: DryerModel(alternative_config(base, alt), threads=1)
            for law, alt in LAWS.items()}


def _slope(model: DryerModel, name: str, h: float) -> float:
    """Central difference of the steady ``moisture_out`` in input ``name`` at the nominal
    point."""
    nom = getattr(model.config.nominal, name)
    y = [model.steady_state(model.nominal_inputs(**{name: nom + s * h}), model.theta0)[1][2]
         for s in (1.0, -1.0)]
    return (y[0] - y[1]) / (2.0 * h)


def test_the_library_holds_every_compiled_law_with_the_paper_as_default(base):
    assert sorted(LAWS) == sorted(DRYING_LAWS)
    families = {a.family for a in structure_space()}
    for family in families:
        defaults = [a for a in structure_space() if a.family == family and a.default]
        assert len(defaults) == 1, family
    assert LAWS["double_sigmoid"].default
    for alt in structure_space():
        assert alt.source and len({r.key for r in alt.free}) == len(alt.free)
        for r in alt.free:
            section, key = r.key.split(".")
            assert getattr(getattr(base, section), key) == pytest.approx(r.default), r.key
            assert r.low <= r.default <= r.high, r.key
            # the search's corners are valid configs
            alternative_config(base, alt, {r.key: r.low})
            alternative_config(base, alt, {r.key: r.high})


def test_default_law_named_explicitly_gives_the_same_bits(base, models):
    plain = DryerModel(base, threads=1)
    u = plain.nominal_inputs()
    assert np.array_equal(plain.steady_state(u, plain.theta0)[1],
                          models["double_sigmoid"].steady_state(u, plain.theta0)[1])


def test_commissioned_laws_reach_the_papers_nominal_outlet_moisture(models):
    out = {law: m.steady_state(m.nominal_inputs(), m.theta0)[1] for law, m in models.items()}
    for law in ("cdc", "rea"):
        assert out[law][2] == pytest.approx(out["double_sigmoid"][2], abs=5e-4), law
        # the same water evaporated, so nearly the same outlet temperature
        assert out[law][0] == pytest.approx(out["double_sigmoid"][0], abs=1.0), law


@pytest.mark.parametrize("name, h", [("T_air_in", 5.0), ("moisture_in", 0.1)])
def test_each_law_answers_the_inputs_with_its_own_slope(models, name, h):
    slopes = {law: _slope(m, name, h) for law, m in models.items()}
    paper = slopes["double_sigmoid"]
    for law in ("cdc", "rea"):
        # same sign, measurably flatter (measured 13 % to 28 % flatter)
        assert 0.0 < slopes[law] / paper < 0.9, (law, slopes)
    assert abs(slopes["rea"] - slopes["cdc"]) > 0.05 * abs(paper), slopes


def test_cdc_reduction_follows_keeys_curve():
    X_eq, X_cr = 0.05, 1.25
    assert wd.cdc_reduction(1.5, X_eq, X_cr, 2.0) == 1.0  # constant-rate period
    assert wd.cdc_reduction(X_cr, X_eq, X_cr, 2.0) == 1.0  # continuous at X_cr
    assert wd.cdc_reduction(0.65, X_eq, X_cr, 1.0) == pytest.approx(0.5)
    assert wd.cdc_reduction(0.65, X_eq, X_cr, 2.0) == pytest.approx(0.25)
    assert wd.cdc_reduction(X_eq, X_eq, X_cr, 2.0) == 0.0
    # signed below equilibrium (re-adsorption), bounded by the constant rate
    assert wd.cdc_reduction(0.03, X_eq, X_cr, 2.0) == pytest.approx(-(0.02 / 1.2) ** 2)
    assert wd.cdc_reduction(0.0, 1.3, X_cr, 1.0) == -1.0


def test_rea_surface_factor_follows_chens_activation_energy():
    phi, Ta, Tf = 0.2, 380.0, 340.0
    # far above equilibrium the surface is wet (saturated)
    assert wd.rea_surface_factor(1.0, 0.05, phi, Ta, Tf, 20.0, 1.0) == pytest.approx(
        1.0, abs=1e-7)
    # at and below equilibrium dE_v = dE_v,inf = -R T_a ln(phi): psi = phi^(T_a / T_f)
    at_eq = phi ** (Ta / Tf)
    assert wd.rea_surface_factor(0.05, 0.05, phi, Ta, Tf, 5.0, 1.0) == pytest.approx(at_eq)
    assert wd.rea_surface_factor(0.01, 0.05, phi, Ta, Tf, 5.0, 1.0) == pytest.approx(at_eq)
    # in between: exp(-b (X - X_eq)^c) of that exponent
    assert wd.rea_surface_factor(0.25, 0.05, phi, Ta, Tf, 5.0, 2.0) == pytest.approx(
        phi ** (np.exp(-5.0 * 0.2**2) * Ta / Tf))
    X = np.linspace(0.05, 1.0, 20)
    psi = [wd.rea_surface_factor(x, 0.05, phi, Ta, Tf, 5.0, 1.0) for x in X]
    assert np.all(np.diff(psi) > 0)
    # supersaturated air: a wet surface, not more
    assert wd.rea_surface_factor(0.05, 0.05, 1.3, Ta, Ta, 5.0, 1.0) == 1.0


@pytest.mark.parametrize("key, value, message", [
    ("drying_law", "page",
     "fiber.drying_law must be one of double_sigmoid, cdc, rea, got 'page'"),
    ("cdc_exponent", 0.5, "fiber.cdc_exponent must be >= 1, got 0.5 (its range: 1 to 5)"),
    ("rea_b", 1000.0, "fiber.rea_b must be <= 100, got 1000.0 (its range: 0.5 to 100)"),
    ("rea_c", 0.5, "fiber.rea_c must be >= 1, got 0.5 (its range: 1 to 3)"),
])
def test_bad_law_key_is_one_line_naming_the_dotted_key(key, value, message):
    doc = read_toml(default_config_path())
    doc["fiber"][key] = value
    with pytest.raises(ConfigError) as err:
        plant_config_from_dict(doc, "plant.toml")
    assert str(err.value) == f"plant.toml: {message}"
    assert "\n" not in str(err.value)


def test_alternative_config_refuses_what_the_alternative_does_not_have(base):
    with pytest.raises(ConfigError, match=r"fiber\.rea_b is not a free key of drying_law\.cdc"):
        alternative_config(base, LAWS["cdc"], {"fiber.rea_b": 3.0})
    with pytest.raises(ConfigError, match=r"fiber\.cdc_exponent must be <= 5"):
        alternative_config(base, LAWS["cdc"], {"fiber.cdc_exponent": 7.0})
    with pytest.raises(ConfigError, match=r"bogus is not a plant key"):
        base.with_keys({"bogus": 1.0})


def test_alternative_config_sets_the_law_its_keys_and_its_commissioning(base):
    cfg = alternative_config(base, LAWS["cdc"], {"fiber.cdc_exponent": 2.0})
    assert cfg.fiber.drying_law == "cdc" and cfg.fiber.cdc_exponent == 2.0
    assert cfg.parameters["mult_D"].value == LAWS["cdc"].parameters["mult_D"][0]
    assert cfg.parameters["mult_D"].low == 1e-4
    # the other sections and the input config are untouched
    assert cfg.tube == base.tube and base.fiber.drying_law == "double_sigmoid"


def test_ambient_loss_slope_key_is_the_ambient_extension_made_a_plant_constant(base):
    # the config's slope and the diagnosis's aux add up: either alone gives the same bits,
    # and it moves the outlets on a cold day (0.3/K at 265 K: the walls lose 6.4 x more)
    plain = DryerModel(base, threads=1)
    sloped = DryerModel(base.with_keys({"environment.ambient_loss_slope": 0.3}), threads=1)
    u = plain.nominal_inputs(T_amb=265.0)
    aux = np.array([0.3])
    _, y_aux = plain.steady_state(u, plain.theta0, aux)
    _, y_key = sloped.steady_state(u, plain.theta0)
    _, y_none = plain.steady_state(u, plain.theta0)
    assert np.array_equal(y_aux, y_key)
    assert y_none[1] - y_key[1] > 1.0  # K colder cyclone outlet


def test_commission_scales_the_rates_to_the_configured_outlet_and_keeps_the_library_true(base):
    paper = DryerModel(base, threads=1)
    target = paper.steady_state(paper.nominal_inputs(), paper.theta0)[1][2]
    for law in ("cdc", "rea"):
        alt = LAWS[law]
        cfg = commission(base, alt)
        # the library's stored commissioning is what commission finds (4 significant digits)
        for name, (value, _, _) in alt.parameters.items():
            assert cfg.parameters[name].value == pytest.approx(value, rel=1e-3), (law, name)
    # a free key that moves the rate's level: n = 2 needs 12 times the scale of n = 1
    cfg = commission(base, LAWS["cdc"], {"fiber.cdc_exponent": 2.0})
    m = DryerModel(cfg, threads=1)
    assert m.steady_state(m.nominal_inputs(), m.theta0)[1][2] == pytest.approx(target, abs=1e-6)
    assert cfg.parameters["mult_D"].value == pytest.approx(0.145, rel=0.01)
    assert cfg.parameters["mult_C"].value / cfg.parameters["mult_D"].value == pytest.approx(
        0.25, rel=1e-3)
    with pytest.raises(SolverError, match=r"no scale of mult_D and mult_C within their bounds"):
        commission(base, LAWS["cdc"], {"fiber.cdc_exponent": 5.0})
