"""Parameter recovery on virtual-plant days made with known, non-default parameters, through
the command line: calibrate on one day, validate on another (different seed), identify.

The matched plant (the model itself) with known parameters, calibrated with the likelihood
cost and no prior (the cost that weighs each channel by its noise; eq. 4 is dominated by the
lab channel, whose noise the inlet trajectory fitted to the labs absorbs, and leaves the
temperatures free). What must hold: the data term of the calibration's cost at its result
is at most 1.25 times the same term at the true values, scored by the same function on the
same windows (the held-out tail cut off, the inlet trajectory fitted to the labs); the
analysis calls mult_D identifiable (measured on the 24 h day: mult_D alone, 1.4 % from the
truth; the others weakly or not identifiable), and every parameter it calls identifiable is
within 15 % of the truth (the designed-experiments results' "identifiable to 15 %",
docs/results/design.md); the cyclone pair (mult_C, hm_cyc, which act only through their product)
and mult_k are reported as poorly identifiable; on the other day, with the inlet moisture fitted to
the temperatures only, the eq. 4 cost is at most 3 times (24 h, 40 trials: the poorly identified
cyclone pair may sit at a bound) or 1.5 times (48 h, 200 trials) the true parameters' cost there;
PARAMS.toml loads into the plant config. The fast test uses a 24 h day and 40 trials; the slow one
the paper's setting, a 48 h day and 200 trials.
"""

from __future__ import annotations

import dataclasses
import html
import json

import numpy as np
import pytest
from synthetic_days import TRUTH

from softsensor.apps.calibrate import load_segment, load_segments
from softsensor.calibration.calibration_run import objective_spec
from softsensor.calibration.chunked_run import evaluate_parameters
from softsensor.calibration.params_file import read_fit
from softsensor.calibration.selection import DataSelection
from softsensor.calibration.settings import calibration_settings
from softsensor.calibration.validation import split_holdout, validate
from softsensor.cli import main as cli_main
from softsensor.configfile import read_toml
from softsensor.model import DryerModel
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import PARAMETER_NAMES, load_parameters, load_plant_config

#: What the analysis must call at least weakly identifiable, and recover within 15 %, on these
#: days (module docstring): the tube's evaporation multiplier, which every channel sees. With
#: the polish of 2 passes of 6 it stopped at a likelihood of -89.08 and was "identifiable"
#: (profile rise 2.05); with 4 of 15 it reaches -90.64, where the profile along it is flatter
#: (rise 0.24, "weakly identifiable") though the value is 0.688 against the truth's 0.7.
MUST_IDENTIFY = ("mult_D",)


def _check_identifiability(params, config, fit: dict):
    """The parameters the data pin down are called identifiable, what is called identifiable
    is within 15 % (the claim), the rest is said so; returns the verdicts and the calibrated
    config."""
    calibrated = load_parameters(params, config)
    doc = read_toml(params)["parameters"]
    verdicts = {n: doc[n]["verdict"] for n in PARAMETER_NAMES}
    identifiable = [n for n in PARAMETER_NAMES if verdicts[n] == "identifiable"]
    for name in MUST_IDENTIFY:
        assert verdicts[name] in ("identifiable", "weakly identifiable"), verdicts
        assert calibrated.parameters[name].value == pytest.approx(TRUTH[name], rel=0.15)
    assert sorted(fit["identifiability"]["identifiable"]) == sorted(identifiable)
    for name in PARAMETER_NAMES:
        spec = calibrated.parameters[name]
        assert config.parameters[name].low <= spec.value <= config.parameters[name].high
    for name in identifiable:
        spec = calibrated.parameters[name]
        assert spec.value == pytest.approx(TRUTH[name], rel=0.15), (name, spec.value)
    for name in ("mult_C", "hm_cyc", "mult_k"):
        assert verdicts[name] != "identifiable"
        assert name in fit["identifiability"]["poorly_identifiable"]
    assert sorted(fit["identifiability"]["identifiable"]
                  + fit["identifiability"]["poorly_identifiable"]) == sorted(PARAMETER_NAMES)
    return verdicts, calibrated


def _recover(tmp_path, capsys, hours: float, trials: int, seed: int, report: bool,
             val_factor: float, cost_factor: float):
    config = load_plant_config()
    truth_cfg = config.with_parameters(TRUTH)
    cal = simulate_day(truth_cfg, hours, seed=seed).write(tmp_path / "cal.mcap")
    val = simulate_day(truth_cfg, hours, seed=seed + 100).write(tmp_path / "val.mcap")
    params = tmp_path / "PARAMS.toml"
    argv = ["calibrate", str(cal), "--trials", str(trials), "--out", str(params), "--quiet",
            "--seed", "2", "--window-hours", str(hours), "--no-prior", "--cost", "likelihood",
            "--json", "-"]
    if report:
        argv += ["--report", str(tmp_path / "report")]
    assert cli_main(argv) == 0
    summary = json.loads(capsys.readouterr().out)

    # the truth scored exactly as the calibration scored its result: the same window
    # selection, the same held-out tail cut off, the same objective (likelihood, no prior,
    # the inlet trajectory fitted to the labs), the same data term
    model = DryerModel(config)
    calibration = dataclasses.replace(calibration_settings(config), cost="likelihood",
                                      prior=False)
    segments, _ = load_segments([cal], config, DataSelection(window_hours=hours))
    fit_segs, _ = split_holdout(segments, calibration.holdout_fraction)
    spec = objective_spec(model, fit_segs, config, calibration)
    truth_ev = evaluate_parameters(model, fit_segs, truth_cfg.parameter_vector(), spec)[0]
    fit = read_fit(params)
    assert fit["windows"] == [seg.source for seg in fit_segs]
    assert fit["cost"] == pytest.approx(summary["cost"])
    # the data term the fit leaves is the truth's within cost_factor (24 h, 40 trials, seed
    # 21: 0.0219 against the truth's 0.0184, 1.19x)
    assert fit["cost"] <= cost_factor * truth_ev.fit.cost, (fit["cost"], truth_ev.fit.cost)
    assert fit["cost"] < 0.6 * fit["cost_at_current"]  # the defaults are far off

    verdicts, calibrated = _check_identifiability(params, config, fit)

    # validation on an independent day
    assert cli_main(["validate", str(val), "--params", str(params), "--json", "-"]) == 0
    v = json.loads(capsys.readouterr().out)["inlet_read"]
    # the validation fits the inlet moisture to the temperatures only (no labs), so its cost
    # is compared with the true parameters' cost on the same day, scored the same way
    vseg = load_segment(val, config)
    spec = objective_spec(model, [vseg], config, calibration_settings(config))
    truth_val = validate([vseg], config, spec, truth_cfg.parameter_vector(), model=model)
    truth_v = truth_val.evaluation.fit.cost
    assert v["cost"] <= val_factor * truth_v, (v["cost"], truth_v, v["rmse"])
    assert v["cost_ratio"] == pytest.approx(v["cost"] / fit["cost"])
    assert set(v["rmse"]) == {"T_dryer_out", "T_cyclone_out", "moisture_out"}
    return summary, verdicts, calibrated


def test_recovery_24h(tmp_path, capsys):
    summary, verdicts, calibrated = _recover(tmp_path, capsys, 24.0, 40, seed=21, report=True,
                                             val_factor=3.0, cost_factor=1.25)
    page = (tmp_path / "report" / "index.html").read_text()
    for fig in ("fig2_sensitivity.png", "fig3_profile_steps.png", "fig4_study.png",
                "fig5_calibration.png"):
        assert (tmp_path / "report" / fig).stat().st_size > 10_000
    # the figures are inside the page (one file to mail), none left as a link
    assert page.count('src="data:image/png;base64,') == 4 and ".png\"" not in page
    assert "What the data can and cannot pin down" in page and "Table 3" in page
    # the plain-language verdict comes first, in plant units: the terminal's last line,
    # which file to deploy and what it holds
    first = page.index('<p class="verdict">')
    verdict = html.unescape(page[first + len('<p class="verdict">'):page.index("</p>", first)])
    assert first < page.index("<h2>") and verdict == summary["outcome"]
    assert verdict.startswith(f"Deploy {summary['out']}: it holds the calibrated parameters")
    assert "°C" in verdict
    assert summary["windows"][0]["reason"].startswith("whole record")
    assert 0 < summary["pruned_share"] < 1


@pytest.mark.slow
def test_recovery_48h_200_trials(tmp_path, capsys):
    summary, verdicts, calibrated = _recover(tmp_path, capsys, 48.0, 200, seed=5,
                                             report=False, val_factor=1.5, cost_factor=1.25)
    assert summary["trials"] >= 200
    assert summary["tpe_best"]["trial"] <= 200 and summary["refined"]
    assert np.isfinite(summary["cost"])
