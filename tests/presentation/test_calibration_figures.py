"""The calibration and validation figures draw the model their tables score (issue 24,
item 8): the calibration figure's model line sat about 1 °C and 1 % point off the data while
its table said 0.33 K and 0.0038 kg/kg. The table was right: it scores the model with the
inlet moisture fitted (the calibration's nuisance trajectory, :mod:`softsensor.calibration.
objective`), while the figure drew the model at the nominal inlet moisture (open loop). The
figure now draws the scored model solid and the open loop dashed beside it; here the RMSE of
each drawn line against the drawn measurements is the table's number (to rounding: the same
arrays, in °C instead of K and in % dry basis instead of kg/kg). The report page they go into
is one file, its figures inside and its text escaped."""

from __future__ import annotations

import base64

import matplotlib.pyplot as plt
import numpy as np
import optuna
import pytest
from synthetic_days import TRUTH

from softsensor.calibration.calibration_run import calibrate, objective_spec
from softsensor.calibration.dataset import segment_from_day
from softsensor.calibration.optimize import StudySettings
from softsensor.calibration.settings import calibration_settings
from softsensor.calibration.validation import validate
from softsensor.plant.simulator import simulate_day
from softsensor.presentation.calibration_figures import markdown_table, trajectory_plot, write_page
from softsensor.presentation.display import DisplaySettings

optuna.logging.set_verbosity(optuna.logging.WARNING)
#: The moisture drawn in % of the dry mass: 100 X, so the drawn lab errors are 100 x kg/kg.
DRY = DisplaySettings(moisture_basis="dry")


@pytest.fixture(scope="module")
def result(config):
    """A short calibration (the config's [calibration]: inlet moisture estimated) of a day
    whose inlet moisture is not the nominal, so that open loop and fitted differ."""
    day = simulate_day(config.with_parameters(TRUTH), 8.0, seed=3)
    seg = segment_from_day(day, config, source="day8")
    return calibrate([seg], config, StudySettings(n_trials=4, progress=False),
                     calibration_settings(config), polish=False, identify_result=False)


def _drawn(fig, axis: int, gid: str) -> np.ndarray:
    return np.concatenate([ln.get_ydata() for ln in fig.axes[axis].get_lines()
                           if ln.get_gid() == gid]).astype(float)


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    d = a - b
    return float(np.sqrt(np.mean(d[np.isfinite(d)] ** 2)))


def _check_lines(segments, runs, fit, open_fit):
    fig = trajectory_plot(segments, runs, "test", DRY)
    try:
        for c, name in enumerate(("T_dryer_out", "T_cyclone_out")):
            measured = _drawn(fig, c, "measured")
            assert _rmse(measured, _drawn(fig, c, "model")) == pytest.approx(fit.rmse[name],
                                                                            rel=1e-9)
            assert _rmse(measured, _drawn(fig, c, "open_loop")) == pytest.approx(
                open_fit.rmse[name], rel=1e-9)
        labs = _drawn(fig, 2, "lab")
        assert _rmse(labs, _drawn(fig, 2, "model_at_lab")) / 100 == pytest.approx(
            fit.rmse["moisture_out"], rel=1e-9)
    finally:
        plt.close(fig)


def test_the_calibration_figure_draws_the_model_its_table_scores(result):
    # the day's inlet moisture is off the nominal: the open loop misses by more
    assert result.evaluation.open_fit.rmse["T_dryer_out"] > 1.5 * result.fit.rmse["T_dryer_out"]
    _check_lines(result.segments, result.runs, result.fit, result.evaluation.open_fit)


def test_the_validation_figure_draws_the_model_its_table_scores(result, config, model):
    day = simulate_day(config.with_parameters(TRUTH), 6.0, seed=4)
    seg = segment_from_day(day, config, source="day6")
    spec = objective_spec(model, [seg], config, calibration_settings(config))
    val = validate([seg], config, spec, result.theta, model=model)
    _check_lines(val.segments, val.runs, val.fit, val.evaluation.open_fit)


def test_page_is_one_file_with_figures_inside_and_text_escaped(tmp_path):
    png = base64.b64decode("iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNk"
                           "YPhfDwAChwGA60e6kgAAAABJRU5ErkJggg==")
    (tmp_path / "fig.png").write_bytes(png)
    page = write_page(tmp_path, "Day <script>x</script>", [
        ("Table", markdown_table(["a", "b"], [[1, "<b>2</b>"]])),
        ("Figure", "![](fig.png)")], verdict="Check the <thermometer> & wiring")
    html = page.read_text()
    assert page.name == "index.html"
    assert "<script>" not in html and "&lt;script&gt;" in html
    assert "&lt;thermometer&gt; &amp; wiring" in html and "<b>2</b>" not in html
    assert html.index('class="verdict"') < html.index("<h2>")
    assert "<table>" in html and "<td>1</td>" in html
    assert 'src="data:image/png;base64,' + base64.b64encode(png).decode() + '"' in html


def test_the_study_figure_draws_every_trial_of_what_the_study_minimised():
    """Issue 40: Fig. 4 plotted eq. 4 on a log axis while the study minimised the likelihood
    (negative): about 15 of 200 trials were drawn and the legend's "best so far" had no line.
    Now every complete trial's objective is drawn, the best so far is a line, and the axis
    says what was minimised."""
    from optuna.distributions import FloatDistribution
    from optuna.trial import create_trial

    from softsensor.presentation.calibration_figures import OBJECTIVE_LABELS, study_plot

    study = optuna.create_study()
    values = [-140.0 - 10 * np.sin(k) - 0.05 * k for k in range(60)]
    for v in values:
        study.add_trial(create_trial(params={"x": 1.0}, value=v,
                                     distributions={"x": FloatDistribution(0.0, 2.0)}))
    fig = study_plot(study, {"mult_D": 0.7, "mult_C": 0.3}, "likelihood")
    try:
        ax = fig.axes[0]
        drawn = {ln.get_gid(): ln.get_ydata() for ln in ax.get_lines()}
        assert list(drawn["complete"]) == values  # every one, negative as they are
        assert drawn["best"][-1] == min(values) and list(drawn["best"]) == list(
            np.minimum.accumulate(values))
        low, _high = ax.get_ylim()
        assert low < min(values)  # the best trial is inside the axis
        assert ax.get_ylabel() == OBJECTIVE_LABELS["likelihood"]
    finally:
        plt.close(fig)


def test_the_noise_line_says_errors_as_the_tables_do():
    """Issue 40: the page's tables said °C and % points (wet basis) while the identifiability
    note said K and kg/kg; one way now."""
    from softsensor.presentation.calibration_report import noise_line

    line = noise_line(np.array([0.5, 0.8, 0.004]), DisplaySettings(moisture_basis="wet"), 0.1)
    assert line == ("T_dryer_out 0.5 °C, T_cyclone_out 0.8 °C, moisture_out 0.329 % points "
                    "(wet basis)")
    assert " K" not in line and "kg/kg" not in line


def test_the_front_is_drawn_with_the_deployed_and_current_points_and_the_targets():
    """Issue 40: the temperature-moisture front was a table only; drawn now, worse outlet
    temperature against lab RMSE (held out, °C and % points), deployed and current marked,
    the targets as lines."""
    from softsensor.calibration.trade_off import FrontPoint, TradeOff
    from softsensor.presentation.calibration_figures import front_plot

    def point(label, t, m):
        rmse = {"T_dryer_out": t, "T_cyclone_out": t / 2, "moisture_out": m}
        return FrontPoint(label, np.ones(7), rmse, rmse, rmse)

    trade = TradeOff([point("trial 3", 0.4, 0.012), point("deployed", 0.7, 0.005),
                      point("current", 1.9, 0.004)], temperature_target=1.0,
                     moisture_target=0.006)
    fig = front_plot(trade, DRY, 0.1)
    try:
        ax = fig.axes[0]
        drawn = {ln.get_gid(): (ln.get_xdata(), ln.get_ydata()) for ln in ax.get_lines()}
        assert [float(x) for x in drawn["deployed"][0]] == [0.7]
        assert float(drawn["deployed"][1][0]) == pytest.approx(0.5)  # % dry basis points
        assert [float(x) for x in drawn["current"][0]] == [1.9]
        assert list(drawn["target_T"][0]) == [1.0, 1.0]
        assert float(drawn["target_moisture"][1][0]) == pytest.approx(0.6)
        assert "°C" in ax.get_xlabel() and "% points" in ax.get_ylabel()
    finally:
        plt.close(fig)
