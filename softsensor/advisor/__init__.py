"""The set-point advisor: the outlet-temperature set point that holds the target outlet
moisture at the least heat, or one line saying why no advice is given.

No I/O here. :func:`~softsensor.advisor.advice.advise` is the front door (one tick's
:class:`~softsensor.advisor.advice.Situation` in, an :class:`~softsensor.advisor.advice.Advice`
out); :mod:`.search` holds the steady-state search over the set point through the model's
batched front door, the heat duty and the settling time; :mod:`.settings` the ``[advisor]``
table; :mod:`.replay` the hour-by-hour what-if over recorded estimates. Advisory only: nothing
is written to the PLC.
"""

from softsensor.advisor.settings import AdvisorSettings, advisor_settings

# light on purpose: the verbs' loader builds [advisor] without importing the model
__all__ = ["AdvisorSettings", "advisor_settings"]
