"""The ``[diagnosis]`` table: how the diagnosis turns evidence into probabilities.

Example ``config/dryer1.toml`` fragment::

    [diagnosis]
    healthy_base_rate = 0.9      # prior share of days with nothing wrong
    min_history_days = 7         # history days needed to know this plant's normal verdicts
    cap_without_history = 0.5    # no cause above this probability with fewer of them

The probabilities are judged against the plant's own healthy history (:mod:`.plant_normal`):
what every candidate's evidence reaches on history days, each diagnosed against a normal
that did not see it. ``healthy_base_rate`` is the prior that a day has nothing wrong; the
rest is shared evenly by the causes and ``unexplained``. With fewer than
``min_history_days`` history days judged that way, the verdict says so first and no cause is
given more than ``cap_without_history``.
"""

from __future__ import annotations

from dataclasses import dataclass

from softsensor.configfile import num
from softsensor.plantconfig import PlantConfig, section_of


@dataclass(frozen=True)
class DiagnosisSettings:
    """The ``[diagnosis]`` table (module docstring).

    Attributes
    ----------
    healthy_base_rate : float
        Prior probability that a day has nothing wrong (``none``) [-]. Most days of a
        running dryer are healthy; 0.9 says one day in ten has something to find.
    min_history_days : int
        History days (recorded periods) judged against a normal that did not see them
        (:func:`~.plant_normal.learn_plant_normal`) below which the verdict says there is too
        little history to know this plant's normal [-]. Seven: with ``n`` healthy days a new
        healthy day lies beyond all of them with probability ``1 / (n + 1)``, one in eight
        at seven, and the spread of each candidate's evidence is estimated from ``n - 1``
        degrees of freedom.
    cap_without_history : float
        Highest probability given to any cause (``none`` excepted) with fewer history days
        than ``min_history_days`` [-]: the evidence then leans, it does not decide.
    """

    healthy_base_rate: float = num(0.9, gt=0, lt=1)
    min_history_days: int = num(7, ge=2)
    cap_without_history: float = num(0.5, gt=0, le=1)


def diagnosis_settings(cfg: PlantConfig) -> DiagnosisSettings:
    """The validated ``[diagnosis]`` table of ``cfg`` (built once; the defaults when absent)."""
    return section_of(cfg, "diagnosis", DiagnosisSettings)


__all__ = ["DiagnosisSettings", "diagnosis_settings"]
