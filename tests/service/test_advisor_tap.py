"""The set-point advisor in the daemon (softsensor.service.advisor_tap): scans in, the advice
out on the bus and on the real operator outputs (Prometheus' exposition, the web page and its
JSON), a refusal when the health is not ok."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from softsensor.advisor.advice import Envelope
from softsensor.advisor.settings import AdvisorSettings
from softsensor.errors import ConfigError
from softsensor.estimate import Estimate, Health, Reason
from softsensor.estimation.model_error import model_error_of
from softsensor.model import DryerModel
from softsensor.outputs.metrics import DaemonMetrics
from softsensor.outputs.settings import MetricsSettings, WebSettings
from softsensor.outputs.web import LivePage
from softsensor.plantconfig import (
    PARAMETER_NAMES,
    load_parameters,
    load_plant_config,
    with_table,
)
from softsensor.presentation.display import DisplaySettings
from softsensor.service.advisor_tap import AdvisorTap, advisor_tap, covariance_from_identify
from softsensor.signals import INPUT_NAMES, SCAN_SIGNALS

PARAMS = Path(__file__).resolve().parents[1] / "fixtures" / "independent_plant_params.toml"
T0 = 1_699_999_200 * 10**9
W = 600 * 10**9


@pytest.fixture(scope="module")
def config():
    return load_parameters(str(PARAMS), load_plant_config())


def _model(config) -> DryerModel:
    return DryerModel(config, n_d=10, threads=1)  # a coarse tube: fast


def _feed(tap: AdvisorTap, config) -> Estimate:
    """An hour and a window of steady scans at the history's mean point, and the estimate of
    the last window (the model's own moisture, so the plant sits where the model says)."""
    me = model_error_of(config)
    point = dict(zip(me.features, me.mean, strict=True))
    model = tap.model
    u = np.array([point.get(n, 1.0) for n in INPUT_NAMES])
    _, y = model.steady_state(u)
    body = dict.fromkeys(SCAN_SIGNALS, 50.0)
    body.update({n: point[n] for n in INPUT_NAMES[:-1]})
    body.update(T_dryer_out=float(y[0]), T_sp=float(y[0]), T_cyclone_out=float(y[1]))
    for t in range(T0, T0 + 7 * W, 10 * 10**9):
        tap.on_scan(t, body)
    end = T0 + 7 * W
    return Estimate(end - W, end, "ukf", float(y[2]), 0.005, 1.0, 0.01, float(y[0]),
                    float(y[1]))


def _tap(config, **kw) -> AdvisorTap:
    s = AdvisorSettings(**kw)
    return AdvisorTap(config, s, np.diag(np.full(7, 0.05**2)),
                      Envelope.of(model_error_of(config), s.envelope_sd), _model(config))


def test_the_advice_goes_out_on_the_bus_and_to_prometheus_and_the_web_page(config):
    tap = _tap(config, moisture_target=0.09)
    est = _feed(tap, config)
    metrics = DaemonMetrics(MetricsSettings(enabled=True, port=0))
    page = LivePage(WebSettings(enabled=True, port=0), DisplaySettings())
    sent = []
    tap.after(est, None, lambda kind, body, t: sent.append((kind, body, t)), [metrics, page])
    assert [k for k, _, _ in sent] == ["advice"] and sent[0][2] == est.time_ns
    body = sent[0][1]
    assert body["advised"], body["reason"]
    assert body["moisture_out_advised"] == pytest.approx(0.09, abs=2e-3)
    json.dumps(body)  # a JSON body, no NaN
    text = metrics.answer("/metrics").text.decode()
    assert 'softsensor_advice_given{' in text and "} 1.0" in text.split(
        "softsensor_advice_given{")[1].splitlines()[0]
    adv_c = body["T_sp_advised"] - 273.15
    assert f'which="advised"}} {adv_c:.4f}'[:-2] in text
    assert "Set-point advice (advisory only)" in page.page()
    assert json.loads(page.latest_json())["advice"]["T_sp_advised"] == body["T_sp_advised"]


def test_a_degraded_health_in_force_refuses_the_advice(config):
    tap = _tap(config)
    est = _feed(tap, config)
    ok = Reason("ok", "")
    health = Health(est.time_ns, "dryer1", "ukf", ok, ok,
                    Reason("degraded", "2 lab results refused"))
    sent = []
    tap.after(est, health, lambda kind, body, t: sent.append(body), [])
    assert not sent[0]["advised"]
    assert sent[0]["reason"] == "health is degraded: 2 lab results refused"


def test_covariance_file_and_a_tap_without_its_tables(tmp_path, config):
    doc = {"verdicts": {n: {"relative_se": 0.1 * (i + 1)} for i, n in
                        enumerate(PARAMETER_NAMES)},
           "correlation": np.eye(7).tolist()}
    f = tmp_path / "ident.json"
    f.write_text(json.dumps(doc))
    cov = covariance_from_identify(f)
    assert np.allclose(np.sqrt(np.diag(cov)), 0.1 * np.arange(1, 8))
    with pytest.raises(ConfigError, match="no such file"):
        covariance_from_identify(tmp_path / "none.json")
    assert advisor_tap(config) is None  # not enabled by default
    table = {"enabled": True, "identify": str(f)}
    assert isinstance(advisor_tap(with_table(config, "advisor", table)), AdvisorTap)
    bare = with_table(load_plant_config(), "advisor", table)
    with pytest.raises(ConfigError, match="model_error"):
        advisor_tap(bare)
