"""What validation leaves on held-out data: PARAMS.toml's ``[discrepancy]``, one dataclass from
the calibration's numbers to the estimator's prior (issue 37: two dataclasses, one written and
one read, held the same table)."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from softsensor.calibration.params_file import params_document, write_params
from softsensor.calibration.validation import discrepancy_prior
from softsensor.plantconfig import (
    PARAMETER_NAMES,
    DiscrepancyPrior,
    discrepancy_of,
    load_parameters,
    load_plant_config,
)


def _held_out(rd: list[float], rc: list[float], labs: list[float], inlet: list[float] = (),
              knots: list[float] = ()) -> tuple[SimpleNamespace, list[SimpleNamespace]]:
    """A validation evaluation of one held-out segment whose windows all have both outlet
    temperatures, with these residuals, lab residuals and inlet knots [h]."""
    n = len(rd)
    seg = SimpleNamespace(Y=np.column_stack([np.zeros(n), np.zeros(n), np.full(n, np.nan)]),
                          n_windows=n, window=600.0)
    ev = SimpleNamespace(res=[[np.asarray(rd, float), np.asarray(rc, float),
                               np.asarray(labs, float)]],
                         inlet=[np.asarray(inlet, float)], knots=[np.asarray(knots, float)])
    return ev, [seg]


def _through_params_toml(prior: DiscrepancyPrior, tmp_path: Path) -> DiscrepancyPrior | None:
    """``prior`` written into a PARAMS.toml as ``calibrate`` writes it and read back."""
    cfg = load_plant_config()
    values = dict(zip(PARAMETER_NAMES, cfg.parameter_vector(), strict=True))
    path = write_params(tmp_path / "params.toml",
                        params_document(cfg, values, {}, discrepancy=prior.as_table()))
    return discrepancy_of(load_parameters(path, cfg))


def test_the_held_out_numbers_are_the_table_the_estimator_reads(tmp_path: Path) -> None:
    rd, rc = [1.0, 2.0, 1.5, 0.5], [1.0, 1.0, 2.0, 0.0]
    ev, segs = _held_out(rd, rc, [0.01, -0.02], inlet=[1.0, 1.1, 1.05], knots=[0.0, 1.0, 4.0])
    prior = discrepancy_prior(ev, segs)
    assert type(prior) is DiscrepancyPrior
    # moments about zero: mean(rd rc) = 1.5, mean(rd^2) = 1.875, mean(rc^2) = 1.5
    assert prior.common_std == pytest.approx(math.sqrt(1.5))
    assert prior.dryer_std == pytest.approx(math.sqrt(0.375))
    assert prior.cyclone_std == pytest.approx(0.0)
    assert prior.moisture_std == pytest.approx(math.sqrt((0.01**2 + 0.02**2) / 2))
    steps = np.array([0.1, -0.05]) / np.sqrt([1.0, 3.0])
    assert prior.inlet_walk == pytest.approx(math.sqrt(np.mean(steps**2)))
    # the mean residual (1, 1.5, 1.75, 0.25) has a lag-one autocorrelation of -0.274, floored
    # at 0.001: tau = 600 s / ln(1000)
    assert prior.tau_s == pytest.approx(600.0 / math.log(1000.0))
    assert (prior.n_windows, prior.n_labs) == (4, 2)
    assert _through_params_toml(prior, tmp_path) == prior


def test_numbers_the_data_cannot_give_are_not_known(tmp_path: Path) -> None:
    """One window, no lab result, no inlet knot: those numbers are None (not NaN) in memory
    and absent from PARAMS.toml, and read back as the same object."""
    ev, segs = _held_out([1.0], [2.0], [])
    prior = discrepancy_prior(ev, segs)
    assert prior.common_std is prior.dryer_std is prior.cyclone_std is None
    assert prior.moisture_std is None and prior.inlet_walk is None
    assert prior.as_table() == {"tau_s": prior.tau_s, "n_windows": 1.0, "n_labs": 0.0}
    assert _through_params_toml(prior, tmp_path) == prior
