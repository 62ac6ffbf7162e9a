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
                             plant_seed=0, start_ns=DEFAULT_START_NS) -> SimulatedDay

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

What it models
--------------
Burner gas (drawn temperature, humidity and CO2 share, wandering with burner load and fuel
moisture) is mixed with ambient air at the flaps (nonlinear characteristic) and reaches the
tube after a dead time. Fibre enters with steam at the bottom of a 55 m x 2.6 m tube (a 30 m
riser, then horizontal), is carried by the gas as flocs with a drag-law slip, heats and dries
by one of three kinetics laws, continues through a duct into two cyclones where it is held
for seconds at the wall and keeps drying, while false air leaks in at the fibre discharge and
the gas loses heat through the shells. The flow is solved quasi-steady every 10 s plant step
(gas transit about 3 s, fibre about 3 s plus hold-up) by a stiff-aware march
(:mod:`.flow`, :mod:`.chain`); walls and shells carry the dynamics (:mod:`.wall`); each output
reaches its sensor after its transit time, each thermocouple lags (:mod:`.sensors`); a PI on
the filtered measured outlet temperature moves the flaps (:mod:`.control`). Water and energy
close to rounding along the march; at steady state :func:`.balances.steady_balances` lists
every stream and closes to about 1e-10.

Module map: :mod:`.properties` humid gas and water, :mod:`.fibre` sorption, enthalpy and
kinetics, :mod:`.transfer` correlations, :mod:`.layout` kernel arrays, :mod:`.flow` right-hand
side and Rosenbrock march, :mod:`.chain` tube-duct-cyclone at one instant, :mod:`.cyclone`,
:mod:`.wall`, :mod:`.process` the plant object, :mod:`.family` structure draw,
:mod:`.commissioning`, :mod:`.disturbances`, :mod:`.effects`, :mod:`.control`,
:mod:`.sensors`, :mod:`.simulator` the day loop, :mod:`.balances`.

The family (uniform draws per plant seed)
-----------------------------------------
=============================== ===========================================================
drying kinetics (one of three)  REA (Chen): ``b`` 5..12, ``c`` 0.8..1.3; characteristic drying
                                curve (Keey): ``X_cr`` 1.1..1.4 kg/kg, ``n`` 1.0..2.5; two
                                resistances: ``E_a`` 15..40 kJ/mol, ``beta`` 2.5..6
kinetic multiplier ``kappa``    set at commissioning so that the nominal outlet moisture is
                                the member's target, drawn 0.085..0.12 kg/kg
GAB sorption                    ``Xm0`` 0.055..0.065 kg/kg, ``C0`` 6..10, ``K0`` 0.77..0.80,
                                ``lam`` 0.0015..0.0025 1/K, ``E_C`` 700..1300 K, ``E_K``
                                150..350 K
heat of sorption                ``q0`` 0.9..1.2 MJ/kg, ``Xq`` 0.06..0.09 kg/kg
fibre                           diameter 30..50 um, density 400..600 kg/m3 (geometric surface
                                133..333 m2/kg), dry heat capacity x 0.95..1.08
flocs                           open share of the surface 0.06..0.2, diameter 1..4 mm, dry
                                density 30..100 kg/m3, sphericity 0.3..0.7, injection
                                velocity 3..8 m/s
burner gas and flaps            temperature 850..1000 K, humidity 0.05..0.12 kg/kg, CO2 share
                                of its dry gas 0.08..0.16; hot-gas share shut 0.02..0.06,
                                open 0.5..0.65, characteristic exponent +-0.3..1.5; dead time
                                to the tube 5..30 s
tube and duct walls             deposit 0.5..3 mm (up to 60 % thicker at the inlet),
                                conductivity 0.08..0.15 W/(m K); inner-h enhancement by the
                                fibre load 1.0..1.4; emissivity 0.6..0.9; wind exposure
                                0.5..1.0; duct 5..15 m
cyclone                         fibre hold-up 3..20 s; false air 0..3 % of the gas; strand
                                surface 0.5..3 % of the tube's; strand relative velocity
                                0.2..0.5 of the inlet velocity; gas-shell h 15..45 W/(m2 K);
                                outer-vortex share of the shell 0.6..0.8
thermocouple lags               10..90 s each: T_air_in, T_dryer_out, T_cyclone_out,
                                T_fiber_in, T_amb
site and feed                   median wind 1.5..5 m/s; inlet moisture day-to-day sd
                                0.005..0.015 kg/kg (day mean clipped to 0.9..1.1), within-day
                                wander sd 0.001..0.004 kg/kg with correlation time 3..6 h
=============================== ===========================================================

A member must commission into a plausible
dryer (nominal ``T_air_in`` 450..550 K, flaps 10..90 %, wet fibre below boiling), else the
next draw of the same plant seed is used; the accepted attempt is in the structure.

What differs from softsensor's model, and why a real dryer may differ that way
-----------------------------------------------------------------------------
The model is known here only from CONTRACT.md and the project brief: a quasi-steady 1-D
finite-volume tube with a double-sigmoid drying-rate reduction, Chilton-Colburn transfer
coefficients, a lumped stirred cyclone, constant fibre properties, and no sensor lags, no
leaks and no transport delays.

* **Drying kinetics.** Here the rate follows one of three published laws with re-adsorption
  below equilibrium, an explicit GAB isotherm, a moisture-dependent heat of sorption and
  high-flux (Stefan) mass transfer, never a double sigmoid. Real fibre dries by mechanisms
  (free water in lumens, bound water in cell walls, resin and chip species) that no single
  curve shape is known to capture; which law fits a given furnish is an open question, so
  the family spans three.
* **Transfer.** Fibre-gas coefficients from Ranz-Marshall on the fibre diameter with the
  floc's slip from the Haider-Levenspiel drag of a non-spherical floc, and an open-surface
  share for flocculation; gas-to-wall by Gnielinski with entry enhancement and a solids
  factor; outside by Zukauskas cross-flow, Churchill-Chu natural convection and radiation to
  the sky. In a real tube the fibre travels as flocs whose size and openness are unknown and
  vary; the gas-side coefficient grows at the entry and with the solids load; wind and clear
  skies cool a bare tube more than a still, cloudy day.
* **Numerics.** An adaptive L-stable Rosenbrock march along the flow instead of finite
  volumes: a different discretisation error, so that calibration cannot fit the model's own
  grid artefacts.
* **Cyclone.** Fibre held 3 to 20 s as a wall strand that keeps drying in plug flow beside
  the outer-vortex gas, false air at the discharge cooling the inner vortex, two shell
  nodes; not a stirred tank. Real cyclones under suction do leak at the rotary valve, and
  the strand's contact with the gas is neither perfect mixing nor zero.
* **Walls.** A deposit layer with its own resistance and heat capacity on the steel, in 22
  tube and 2 duct segments, thicker at the wet inlet. Real tubes foul with fibre and resin;
  the deposit insulates and adds thermal mass.
* **Fibre properties.** Heat capacity rising with temperature (Wood Handbook) and with
  moisture, sorption enthalpy, a floc density rising with the water it carries.
* **Hot gas.** Combustion gas with CO2 (higher heat capacity) and a humidity that wanders
  with the fuel's moisture and a temperature that wanders with burner load, none of them
  measured; the flap characteristic is nonlinear and reaches the tube after a dead time.
* **Instruments.** Thermocouples lag 10 to 90 s (sheath, well, deposit), the PLC filters the
  controlled temperature, an odd read fails; the model assumes instantaneous sensors.
* **Transport delays.** Hot gas reaches the tube 5 to 30 s after the flaps move; outlet
  readings lag the inlet by the gas transit; the outlet moisture lags by the fibre transit
  plus the hold-up. A real plant has all of them.
* **Feed.** The inlet moisture is never exactly nominal: it sits at a day level and wanders
  within the day, as chips, refiner and blow-line steam vary. On a clean day it moves little
  (an inlet moisture that drifts or steps is a cause of its own, CONTRACT section 5's
  ``inlet_moisture``, injected at 0.08 to 0.25 kg/kg): the outlet moisture follows the inlet
  moisture at about half of it while the outlet temperatures barely show it (-25 K per kg/kg
  at the nominal point), so a wander of 0.01 kg/kg already moves the outlet moisture by more
  than a lab result's noise.

Effects are injected in this plant's own terms (:mod:`.effects`), with the magnitudes of
:data:`softsensor.plant.effects.EFFECTS`.
"""

from softsensor.jit_cache import configure as _configure_jit_cache

_configure_jit_cache()  # before the plant's kernels are compiled or loaded from the cache

from softsensor.plant.independent.simulator import simulate_independent_day  # noqa: E402

__all__ = ["simulate_independent_day"]
