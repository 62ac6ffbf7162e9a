"""The calibration and identify report pages (:mod:`softsensor.presentation.calibration_report`).

The identify page drew Fig. 4 without the study's objective (its axis could name the wrong
one), headed it "Cost by trial" where the calibration page says "Objective by trial", and
turned kg/kg into % points at 0.1 kg/kg whatever the lab said; now it does as the calibration
page does: the objective minimised, the same heading, the segments' median lab result."""

from __future__ import annotations

import html
import re

import optuna
from synthetic_days import TRUTH

from softsensor.calibration.calibration_run import objective_spec
from softsensor.calibration.dataset import segment_from_day
from softsensor.calibration.identifiability import identify
from softsensor.calibration.settings import calibration_settings
from softsensor.plant.simulator import simulate_day
from softsensor.presentation import calibration_report
from softsensor.presentation.calibration_report import deployed_table, identify_page, noise_line
from softsensor.presentation.display import display_settings, lab_reference

optuna.logging.set_verbosity(optuna.logging.WARNING)


def test_the_identify_page_names_its_objective_and_the_labs_moisture(config, model, tmp_path,
                                                                     monkeypatch):
    day = simulate_day(config.with_parameters(TRUTH), 6.0, seed=5)
    seg = segment_from_day(day, config, source="day6")
    spec = objective_spec(model, [seg], config, calibration_settings(config))
    theta = config.parameter_vector()
    ident, sens = identify(model, [seg], theta, spec, config.bounds(), profile=False)
    drawn: list[str] = []
    monkeypatch.setattr(calibration_report.figures, "study_figure",
                        lambda study, importance, path, cost="likelihood": drawn.append(cost))
    page = identify_page(ident, sens[0], config, theta, tmp_path / "page", object(),
                         cost="eq4", segments=[seg]).read_text()
    assert drawn == ["eq4"]  # Fig. 4's axis names the objective the study minimised
    assert "Objective by trial and parameter importance (Fig. 4)" in page
    x_ref = lab_reference([seg])
    assert abs(x_ref - 0.1) > 1e-3  # (a day whose lab moisture tells the two apart)
    display = display_settings(config)
    assert html.escape(noise_line(ident.noise, display, x_ref)) in page
    assert html.escape(noise_line(ident.noise, display, 0.1)) not in page
    identify_page(ident, sens[0], config, theta, tmp_path / "default", object())
    assert drawn[1] == calibration_settings(config).cost  # without one: the config's


def test_the_deployed_table_lists_every_structure_key_at_any_depth(tmp_path):
    """``[structure]`` is applied as dotted keys at any depth (``dotted_keys``); the page
    flattened one level by hand, so a deeper table was shown as one cell of a dict."""
    params = tmp_path / "params.toml"
    params.write_text('[parameters.mult_D]\nvalue = 1.0\nlow = 0.5\nhigh = 2.0\n\n'
                      '[structure.model]\nn_cells = 20\n\n[structure.model.inlet]\nlag_s = 12.5\n\n'
                      '[structure.evidence]\ngain = 3.0\n')
    text = deployed_table(params)
    keys = re.findall(r"^\| (\S+) \| (\S+) \|$", text.split("`[structure]`")[1], re.M)
    assert keys[1:] == [("model.n_cells", "20"), ("model.inlet.lag_s", "12.5")], text
