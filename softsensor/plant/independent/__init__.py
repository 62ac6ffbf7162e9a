"""The independent plant: an MDF flash dryer simulated apart from :mod:`softsensor.model`.

Until this plant existed, every accuracy number of the project was measured on the matched
plant (:mod:`softsensor.plant.simulator`), which *is* the model with known parameters and so
proves only the algebra. This package is a second dryer, written without reading the
model's code or its equations and sharing none of them: its own gas and water properties,
sorption, kinetics, transfer correlations, numerics, walls, cyclone, instruments, control
and disturbances. Calibrating the model on one day of a plant seed and validating on another
day of the same plant seed measures how well the model predicts a dryer it is not.

Entry point::

    simulate_independent_day(config, hours, seed, effect=None, magnitude=None, *,
                             plant_seed=0, start_ns=DEFAULT_START_NS, schedule=None,
                             unmeasured_flow=None) -> SimulatedDay

``plant_seed`` draws the plant's *structure* from a family and commissions it
(:mod:`.family`, :mod:`.commissioning`); ``seed`` draws the *day* (disturbances, effect
timing, noise, failed reads, lab). The same pair gives a bit-identical day; day seeds of one
plant seed share the structure. The returned :class:`~softsensor.plant.day.SimulatedDay`
has the 11 contract scan signals (10 s scans), the lab results, and the truth (``moisture_in,
moisture_out, T_air_in, T_dryer_out, T_cyclone_out, m_fiber`` before sensor lag and noise,
plus ``moisture_tube_out, flap_position, m_air, T_amb``); its ``effect`` dict (written on
``/truth/effect``) says what was injected, ``plant: "independent"``, the ``plant_seed``, the
drawn ``structure`` (variant, constants, commissioning results) and the loop tuning. From
``config`` only the geometry (``tube``, ``cyclone``), the nominal point, the ambient pressure
and the ``[virtual_plant]`` settings are used, never ``fiber``, ``hot_gas`` or
``parameters``. A 48 h day takes about 10 s on one core once compiled (numba, cached; 8.5 to
11 s measured on the development machine).

What it models, the family of plants a seed draws from (every range), and what differs
from softsensor's model and why a real dryer may differ that way:
:doc:`/explanation/virtual-plants`.

Module map: :mod:`.properties` humid gas and water, :mod:`.fibre` sorption, enthalpy and
kinetics, :mod:`.transfer` correlations, :mod:`.layout` kernel arrays, :mod:`.flow` right-hand
side and Rosenbrock march, :mod:`.chain` tube-duct-cyclone at one instant, :mod:`.cyclone`,
:mod:`.wall`, :mod:`.process` the plant object, :mod:`.family` structure draw,
:mod:`.commissioning`, :mod:`.disturbances`, :mod:`.effects`, :mod:`.control`,
:mod:`.sensors`, :mod:`.simulator` the day loop, :mod:`.balances`.

Effects are injected in this plant's own terms (:mod:`.effects`), with the magnitudes of
:data:`softsensor.plant.effects.EFFECTS`.
"""

from softsensor.jit_cache import configure as _configure_jit_cache

_configure_jit_cache()  # before the plant's kernels are compiled or loaded from the cache

from softsensor.plant.independent.disturbances import UnmeasuredFlow  # noqa: E402
from softsensor.plant.independent.simulator import simulate_independent_day  # noqa: E402

__all__ = ["UnmeasuredFlow", "simulate_independent_day"]
