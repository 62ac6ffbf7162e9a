"""Chi-square consistency of the filter's innovations: is the model still right?

For a consistent Kalman filter the normalised innovation squared of tick ``k``,
``NIS_k = nu_k^T S_k^-1 nu_k`` (``nu`` the innovation, ``S`` its predicted covariance), is
chi-square distributed with ``m_k`` degrees of freedom (the measurement size), and the NIS of
different ticks are independent. Over a window of ticks, ``sum NIS_k`` is then chi-square with
``sum m_k`` degrees of freedom (Bar-Shalom, Li and Kirubarajan 2001, "Estimation with
Applications to Tracking and Navigation", section 5.4.2). Health turns ``degraded`` when that
sum exceeds the upper ``1 - alpha`` quantile: the innovations are larger than the filter
believes, i.e. the model, its parameters or a sensor is off. The detail gives each channel's
mean normalised innovation (measurement minus model, in standard deviations), largest first,
e.g. "T_dryer_out -4.4, T_cyclone_out +4.3": one outlet temperature sensor off by a constant
shows as the two channels pulling apart (the inlet moisture moves the model to split the
difference, so which of the two is off needs the lab or a diagnosis).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtri  # = scipy.stats.chi2.isf, without scipy.stats's 45 MB


@dataclass(frozen=True)
class Innovation:
    """Innovation statistics of one tick.

    Attributes
    ----------
    nis : float
        Normalised innovation squared of all measurements used in the tick. [-]
    dof : int
        Number of measurements (0 when the tick had no update).
    normalised : dict[str, float]
        Per channel, innovation divided by its predicted standard deviation. [-]
    """

    nis: float = 0.0
    dof: int = 0
    normalised: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class Verdict:
    """Outcome of the consistency test: ``status`` is ``ok`` or ``degraded``."""

    status: str
    detail: str
    nis_sum: float
    dof: int
    limit: float


def chi_square_test(window: Sequence[Innovation], alpha: float) -> Verdict:
    """Test the innovations of a window of ticks for consistency.

    Parameters
    ----------
    window : sequence of Innovation
        The last ticks (any number; ticks without update count zero degrees of freedom).
    alpha : float
        False-alarm probability of the test. [-]
    """
    dof = int(sum(i.dof for i in window))
    if dof == 0:
        return Verdict("ok", "no measurements in the consistency window", 0.0, 0, float("inf"))
    total = float(sum(i.nis for i in window))
    limit = float(chdtri(dof, alpha))
    if total <= limit:
        return Verdict("ok", f"innovations consistent (NIS {total:.1f} <= {limit:.1f} over "
                             f"{len(window)} ticks, {dof} dof)", total, dof, limit)
    channels: dict[str, list[float]] = {}
    for i in window:
        for name, v in i.normalised.items():
            channels.setdefault(name, []).append(v)
    means = sorted(((n, float(np.mean(v))) for n, v in channels.items()),
                   key=lambda t: -abs(t[1]))
    per_channel = ", ".join(f"{n} {m:+.1f}" for n, m in means)
    return Verdict("degraded",
                   f"innovations inconsistent: NIS {total:.1f} > {limit:.1f} over "
                   f"{len(window)} ticks ({dof} dof, chi-square alpha {alpha:g}); mean "
                   f"measurement - model in sigma: {per_channel}", total, dof, limit)
