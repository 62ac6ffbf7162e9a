"""Residual statistics (``softsensor/diagnosis/residuals.py``): Ljung-Box, change point and
cross-correlation on series with known structure, and the channel and lab statistics of a clean
virtual-plant day."""

from __future__ import annotations

import numpy as np
import pytest
from diagnosis_problem import make_problem

from softsensor.diagnosis.extensions import (
    LabTimeShift,
)
from softsensor.diagnosis.residuals import (
    LAB_SHIFTS_MIN,
    change_point,
    channel_stats,
    cross_correlation,
    lab_stats,
    ljung_box,
)


def test_ljung_box_tells_white_from_correlated():
    rng = np.random.default_rng(0)
    e = rng.standard_normal(300)
    ar = np.empty(300)
    ar[0] = e[0]
    for i in range(1, 300):
        ar[i] = 0.6 * ar[i - 1] + e[i]
    assert ljung_box(e)[1] > 0.01
    assert ljung_box(ar)[1] < 1e-10


def test_change_point_and_cross_correlation_find_what_was_put_in():
    rng = np.random.default_rng(1)
    hours = np.arange(1, 201) / 6.0
    r = 0.1 * rng.standard_normal(200)
    r[120:] += 1.0
    h, shift, t = change_point(r, hours)
    assert h == pytest.approx(hours[119]) and shift == pytest.approx(1.0, abs=0.05) and t > 20
    x = rng.standard_normal(200)
    y = np.concatenate([[0.0, 0.0], x[:-2]]) + 0.1 * rng.standard_normal(200)
    cc = cross_correlation(y, x)
    assert cc.lag == 2 and cc.corr > 0.95


def test_channel_and_lab_statistics_on_a_clean_day(cfg, model, day):
    p = make_problem(cfg, model, day)
    r = p.residuals(p.baseline)
    st = channel_stats("T_dryer_out", r.T[:, 0], p.windows, p.sigma[0])
    # a clean day with the plant's own parameters: residuals are the noise of a window mean
    # (0.5 K / sqrt(60) = 0.065 K) plus a little model discretisation
    assert st.rmse < 0.15 and abs(st.t_mean) < 4 and st.structure_ratio < 1.5
    _, shifted = LabTimeShift.lab_chi2(p, LAB_SHIFTS_MIN)
    lab = lab_stats(r.lab, p.windows, p.baseline.Y[:, 2], shifted)
    assert lab.rmse < 0.008
    # the lab RMSE at every shift of the sample times, recomputed here
    curve = np.sqrt(np.mean((p.windows.lab_value - shifted) ** 2, axis=1))
    # unshifted, the moved-sample model values are the baseline's own lab predictions (one
    # batched step against the baseline's run: round-off apart, measured 1.6e-12 relative)
    assert curve[LAB_SHIFTS_MIN == 0.0][0] == pytest.approx(lab.rmse, rel=1e-9)
    # the stamps of a clean day are right: the RMSE is least at no shift (one grid step, 2
    # min, either side it is a third higher or more: measured 0.0021 against 0.0028 and
    # 0.0037 kg/kg), and lab_stats reports that shift and that RMSE
    assert lab.best_shift_min == 0.0
    assert lab.rmse_at_best_shift == pytest.approx(curve.min(), rel=1e-12)
