"""The chi-square test of the filter's innovations (``softsensor/estimation/consistency.py``) at
its limit, against the closed form for two degrees of freedom and scipy's quantile
(``tests/support/mutation_check.py`` turns its inequality and its degrees of freedom)."""

from __future__ import annotations

import math

import pytest
from scipy.stats import chi2

from softsensor.estimation.consistency import Innovation, chi_square_test


def test_chi_square_test_at_its_limit():
    alpha = 0.01
    limit = -2.0 * math.log(alpha)  # chi-square with two degrees of freedom, closed form
    ticks = [Innovation(nis=0.5 * limit - 1e-9, dof=1, normalised={"T_dryer_out": 1.0}),
             Innovation(nis=0.5 * limit, dof=1, normalised={"T_dryer_out": 3.0}),
             Innovation()]  # a tick without update adds nothing
    ok = chi_square_test(ticks, alpha)
    assert ok.status == "ok" and ok.dof == 2 and ok.limit == pytest.approx(limit)
    bad = chi_square_test([*ticks[:1], Innovation(nis=0.5 * limit + 1e-6, dof=1,
                                                  normalised={"T_dryer_out": 3.0})], alpha)
    assert bad.status == "degraded" and "T_dryer_out +2.0" in bad.detail
    assert chi_square_test([Innovation()], alpha).status == "ok"
    assert chi_square_test([Innovation(nis=30.0, dof=10)], alpha).limit == pytest.approx(
        chi2.isf(alpha, 10))
