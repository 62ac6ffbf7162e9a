"""The plant configuration (``config/dryer1.toml``): geometry, fibre, operation, parameters.

One frozen dataclass per TOML section (see :mod:`softsensor.configfile` for the rules). The
seven calibration parameters of the paper's Table 1 live in ``[parameters.<name>]`` tables with
their value, bounds and whether the search is log-scaled; a calibrated ``PARAMS.toml`` has the
same ``[parameters]`` layout and overrides the values (see :func:`load_parameters`).

The other tables of a plant config (:data:`EXTRA_SECTIONS`: ``[service]``, ``[estimator]``,
``[outputs]``, ...) and PARAMS.toml's ``[discrepancy]`` and ``[model_error]`` belong to higher
layers, whose dataclasses this module cannot import. :class:`PlantConfig` keeps them as read
(``extra``) and each owner's access function (``estimator_settings(cfg)``,
``service_settings(cfg)``, ...) builds its frozen dataclass through :func:`built_table`: once
per config, the same object after. The verbs' load point (:mod:`softsensor.apps.loading`)
builds every one of them before anything starts, so a misspelt key anywhere stops the start
with one line naming the file and the dotted key.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from softsensor.configfile import build_section, choice, num, read_toml
from softsensor.errors import ConfigError

#: The paper's Table 1, in this order everywhere (arrays of parameters use it).
PARAMETER_NAMES: tuple[str, ...] = (
    "mult_D", "mult_C", "mult_h", "mult_k", "mult_p", "hm_cyc", "hc_cyc",
)


@dataclass(frozen=True)
class Unit:
    name: str = "dryer1"


# Physical ranges of a dryer, not of a number (issue 49: 29 of 100 extreme values a PARAMS.toml
# or config may hold published ``ok`` estimates far off; ``tube.length = 1e-9`` crashed the
# model and ``solver.scan_period = 1e-9`` hung it). Each range holds the published envelope of
# MDF flash dryers with a margin of about a factor of three: tube 30 to 60 m, air 15 to 25 m/s,
# residence about 5 s, outlet air 66 to 88 degC, fibre out 8 to 12 % (../shared/STACK.md,
# after Fritzell et al. 2009 and the paper's dryer); the other limits are cited where set.


@dataclass(frozen=True)
class Tube:
    length: float = num(ge=5, le=200)         # m (MDF tubes 30 to 60 m)
    diameter: float = num(ge=0.2, le=6)       # m, inner (2 to 3 m at 15 to 25 m/s air)
    wall_thickness: float = num(ge=1e-3, le=0.05)  # m (sheet steel, 3 to 10 mm)
    n_cells: int = num(ge=2, le=2000)
    # a metal wall: aluminium 2700 kg/m3, 900 J/(kg K), 200 W/(m K); stainless steel 8000,
    # 500, 15; carbon steel 7850, 490, 45 (engineering handbooks)
    wall_density: float = num(ge=1000, le=10_000)        # kg/m3
    wall_heat_capacity: float = num(ge=200, le=2000)     # J/(kg K)
    wall_conductivity: float = num(ge=1, le=450)         # W/(m K)
    wall_emissivity: float = num(ge=0, le=1)
    # fibre and resin deposit on the inside of the tube wall (cleaned at shutdowns)
    deposit_thickness: float = num(0.0015, ge=0, lt=0.05)  # m
    # W/(m K): wood and resin 0.1 to 0.4, a porous fibre cake down to about 0.05
    deposit_conductivity: float = num(0.12, ge=0.02, le=10)


@dataclass(frozen=True)
class Cyclone:
    count: int = num(ge=1, le=20)
    diameter: float = num(ge=0.3, le=15)      # m (the reference plant's 5 m)
    height: float = num(ge=1, le=60)          # m
    volume: float = num(ge=1, le=10_000)      # m3, all cyclones together
    n_cells: int = num(ge=1, le=100)
    shell_thickness: float = num(ge=1e-3, le=0.05)    # m, as the tube's wall
    shell_density: float = num(ge=1000, le=10_000)    # kg/m3
    shell_heat_capacity: float = num(ge=200, le=2000)  # J/(kg K)
    # gas to shell: forced convection of swirling gas, 5 to 100 W/(m2 K) (the plant's 15)
    inner_heat_transfer: float = num(ge=1, le=500)    # W/(m2 K)
    # s, fibre residence in the cyclones: the reference plant's (config/dryer1.toml), the
    # paper's form of the structural library (softsensor.model.structure), which searches
    # 1 to 30 s
    hold_up_time: float = num(4.0, ge=0.5, le=120)


#: The drying-rate laws the model compiles (``fiber.drying_law``; the model's law index is the
#: position here): the paper's double sigmoid (the default), Keey's characteristic drying
#: curve, Chen's reaction engineering approach (:mod:`softsensor.model.wood`).
DRYING_LAWS: tuple[str, ...] = ("double_sigmoid", "cdc", "rea")


@dataclass(frozen=True)
class Fiber:
    # physical ranges (issues 40 and 49: a PARAMS.toml [structure] fiber.critical_moisture =
    # 1e6, then 3.0, was taken, and estimates went out ok far off): wood's cell wall is about
    # 1500 kg/m3 and wood 300 to 900 kg/m3; a wood fibre is 15 to 50 um across and 1 to 5 mm
    # long, MDF fibre bundles to about 0.3 mm across (Kollmann & Cote, Principles of Wood
    # Science); the fibre saturation point is 0.25 to 0.35 kg/kg, lower when hot (Siau, Wood:
    # Influence of Moisture); the largest water a fibre holds is 1/rho - 1/1500 m3/kg, 2.2
    # kg/kg at 350 kg/m3, and spruce MDF fibre dries at a constant rate down to about 1.25
    # kg/kg (Fritzell et al. 2009), which the structure search varies from 0.8 to 2.0
    dry_density: float = num(ge=150, le=1500)          # kg/m3
    diameter: float = num(ge=5e-6, le=3e-4)            # m
    length: float = num(ge=1e-4, le=1e-2)              # m
    # 4 / (dry_density diameter) over those ranges: 9 to 5300
    specific_surface: float = num(ge=5, le=6000)       # m2/kg dry fibre
    saturation_point: float = num(ge=0.15, le=0.45)    # kg/kg
    critical_moisture: float = num(ge=0.4, le=2.5)     # kg/kg
    # the sigmoids' widths and the bound-water fraction: the structure search's ranges
    # (softsensor.model.structure: 0.03-0.5, 0.02-0.3, 1e-4-2e-2) with a margin
    critical_width: float = num(ge=0.005, le=1.0)      # kg/kg
    bound_fraction: float = num(ge=1e-6, le=0.2)
    equilibrium_width: float = num(ge=0.005, le=1.0)   # kg/kg
    # the drying-rate law (a structural choice, softsensor.model.structure) and the shape
    # parameters of the alternatives; each law reads only its own
    drying_law: str = choice(DRYING_LAWS, "double_sigmoid")
    # (bounds: an exponent below 1 gives the rate an infinite slope at X_eq, where the cell
    # Newton fails; measured on the nominal point and three corners of the operating range)
    cdc_exponent: float = num(1.0, ge=1.0, le=5.0)   # Keey's n, falling-rate exponent
    rea_b: float = num(5.0, ge=0.5, le=100.0)        # Chen's b [(kg/kg)^-c]
    rea_c: float = num(1.0, ge=1.0, le=3.0)          # Chen's c


@dataclass(frozen=True)
class HotGas:
    # burner gas before the mixing flaps: 600 to 1200 degC (the plant's 900 K); adiabatic
    # flame temperatures stay below about 2200 K and no burner of a dryer runs near them
    temperature: float = num(ge=400, le=1700)  # K
    # water of combustion: natural gas at stoichiometry gives about 0.12 kg per kg dry gas,
    # wet wood fuel about 0.2; with excess air less (the plant's 0.06)
    humidity: float = num(ge=0, le=0.3)        # kg/kg
    fraction_min: float = num(ge=0, le=1)
    fraction_max: float = num(gt=0, le=1)

    def check(self) -> str | None:
        if self.fraction_max <= self.fraction_min:
            return (f"fraction_max must be > fraction_min ({self.fraction_min:g}), "
                    f"got {self.fraction_max:g}")
        return None


@dataclass(frozen=True)
class Environment:
    # the atmosphere from sea level (101.3 kPa) to 4000 m (61.6 kPa, ISO 2533), a fan's few
    # kPa below or above it
    pressure: float = num(ge=6e4, le=1.1e5)    # Pa
    wind_speed: float = num(ge=0, lt=50)       # m/s
    # outside heat loss grows by this per K of ambient below 283.15 K (a structural choice of
    # the heat-loss law, softsensor.model.structure; the diagnosis's ambient_heat_loss
    # extension adds its own on top, model aux BETA_AMB)
    ambient_loss_slope: float = num(0.0, ge=-0.1, le=0.6)  # 1/K


@dataclass(frozen=True)
class Nominal:
    # MDF lines dry 2 to 15 kg/s of fibre at inlet moistures of 0.8 to 1.5 kg/kg with air
    # at 150 to 250 degC (some to 350), 8 to 15 kg of air per kg of fibre; outdoor air from
    # -50 to +60 degC, saturated at 40 degC holds 0.049 kg/kg; outlet set points 66 to 88 degC
    # (the reference plant: 6 kg/s, 1.0 kg/kg, 82 kg/s, 210 degC)
    m_fiber: float = num(ge=0.1, le=50)       # kg/s
    moisture_in: float = num(ge=0.3, le=3)    # kg/kg
    m_air: float = num(ge=1, le=500)          # kg/s
    T_air_in: float = num(ge=323.15, le=723.15)  # K
    T_fiber_in: float = num(gt=273.15, lt=450)   # K
    m_steam: float = num(ge=0, le=20)         # kg/s
    T_amb: float = num(ge=223.15, le=333.15)  # K
    H_amb: float = num(ge=0, le=0.05)         # kg/kg
    T_sp: float = num(ge=303.15, le=423.15)   # K


@dataclass(frozen=True)
class Solver:
    """How data become model windows and how the model steps through them."""

    # s, model window (estimator tick): a minute (the fibre's residence is seconds, the
    # wall's response minutes) to an hour (the labs come every one to four hours)
    window: float = num(600.0, ge=60, le=3600)
    wall_substeps: int = num(4, ge=1, le=1000)
    # s, period of the plant's scans; None (the key absent): measured from each recorded day
    # (the median spacing of its scans), the Modbus poll period live; a PLC or historian
    # scans every 0.1 s at the fastest (issue 49: 1e-9 s hung the windowing)
    scan_period: float | None = num(None, ge=0.1, le=600)
    min_good_fraction: float = num(0.5, ge=0, le=1)  # of a window's expected scans to use it
    lab_span: float = num(120.0, ge=1, le=3600)  # s of scans before a lab sample: its inputs

    def check(self) -> str | None:
        if self.scan_period is not None and self.scan_period > self.window:
            return f"scan_period must be <= window ({self.window:g} s), got {self.scan_period:g}"
        return None


@dataclass(frozen=True)
class ParameterSpec:
    value: float = num()
    low: float = num(gt=0)
    high: float = num(gt=0)
    log: bool = True

    def check(self) -> str | None:
        if self.high <= self.low:
            return f"high must be > low ({self.low:g}), got {self.high:g}"
        if not self.low <= self.value <= self.high:
            return f"value must lie within [{self.low:g}, {self.high:g}], got {self.value:g}"
        return None


@dataclass(frozen=True)
class Cost:
    T_dryer_out: float = num(0.003, ge=0)
    T_cyclone_out: float = num(0.003, ge=0)
    moisture_out: float = num(5.0, ge=0)

    def weights(self) -> np.ndarray:
        """Weights of the paper's eq. 4 in ``OUTPUT_NAMES`` order."""
        return np.array([self.T_dryer_out, self.T_cyclone_out, self.moisture_out])


@dataclass(frozen=True, kw_only=True)
class PlantSections:
    """The plant's own sections of a plant config file, one dataclass each (all but
    ``[parameters]``)."""

    unit: Unit = Unit()
    tube: Tube
    cyclone: Cyclone
    fiber: Fiber
    hot_gas: HotGas
    environment: Environment
    nominal: Nominal
    solver: Solver = Solver()
    cost: Cost = Cost()


@dataclass(frozen=True, kw_only=True)
class PlantConfig(PlantSections):
    """The whole plant configuration; ``source`` is the file it came from."""

    parameters: dict[str, ParameterSpec]
    extra: dict[str, Any] = dataclasses.field(default_factory=dict)
    source: str = "<built-in>"
    #: The typed objects built from ``extra`` (:func:`built_table`); a copy made with
    #: ``dataclasses.replace`` starts empty, so it never serves a table it no longer holds.
    _tables: dict[str, Any] = dataclasses.field(default_factory=dict, init=False, repr=False,
                                                compare=False)

    def nominal_inputs(self) -> np.ndarray:
        """Model inputs at the nominal operating point, in ``signals.INPUT_NAMES`` order."""
        from softsensor.signals import INPUT_NAMES

        return np.array([getattr(self.nominal, n) for n in INPUT_NAMES], dtype=float)

    def parameter_vector(self) -> np.ndarray:
        """Parameter values as an array in :data:`PARAMETER_NAMES` order."""
        return np.array([self.parameters[n].value for n in PARAMETER_NAMES])

    def bounds(self) -> np.ndarray:
        """(7, 2) array of [low, high] per parameter."""
        return np.array([[self.parameters[n].low, self.parameters[n].high]
                         for n in PARAMETER_NAMES])

    def with_parameters(self, values: dict[str, float] | np.ndarray,
                        source: str | None = None) -> PlantConfig:
        """A copy with new parameter values (bounds kept); values outside bounds are refused,
        naming ``source`` (the file that set them; default the config's own)."""
        where = source or self.source
        if not isinstance(values, dict):
            values = dict(zip(PARAMETER_NAMES, np.asarray(values, float), strict=True))
        params = dict(self.parameters)
        for name, v in values.items():
            if name not in params:
                raise ConfigError(f"{where}: parameters.{name} is not a parameter")
            spec = dataclasses.replace(params[name], value=float(v))
            problem = spec.check()
            if problem:
                raise ConfigError(f"{where}: parameters.{name}.{problem}")
            params[name] = spec
        return _keeping_tables(self, dataclasses.replace(self, parameters=params))

    def with_keys(self, values: Mapping[str, Any], source: str | None = None) -> PlantConfig:
        """A copy with plant keys changed, named as in the TOML file: ``"fiber.drying_law"``,
        ``"cyclone.hold_up_time"``, ``"parameters.mult_D.low"``.

        Each changed section is rebuilt and checked as on load (bounds, choices, cross-field
        rules), so a bad value is one :class:`ConfigError` line naming the dotted key; this is
        how a structural alternative (:func:`softsensor.model.structure.structure_space`)
        becomes a config. Errors name ``source`` (the file that set the values; default the
        config's own). The tables already built stay built.
        """
        where = source or self.source
        sections: dict[str, dict[str, Any]] = {}
        specs: dict[str, dict[str, Any]] = {}
        names = {f.name for f in dataclasses.fields(PlantSections)}
        for key, value in values.items():
            parts = key.split(".")
            if len(parts) == 2 and parts[0] in names:
                sections.setdefault(parts[0], {})[parts[1]] = value
            elif len(parts) == 3 and parts[0] == "parameters":
                if parts[1] not in PARAMETER_NAMES:
                    raise ConfigError(f"{where}: {key}: {parts[1]} is not one of the "
                                      f"paper's Table 1 parameters")
                specs.setdefault(parts[1], {})[parts[2]] = value
            else:
                raise ConfigError(f"{where}: {key} is not a plant key (section.key of "
                                  f"{', '.join(sorted(names))}, or parameters.<name>.<field>)")
        changes: dict[str, Any] = {}
        for name, table in sections.items():
            current = getattr(self, name)
            old = {f.name: getattr(current, f.name) for f in dataclasses.fields(current)
                   if getattr(current, f.name) is not None}
            changes[name] = build_section(type(current), {**old, **table}, name, where)
        if specs:
            params = dict(self.parameters)
            for name, table in specs.items():
                old = dataclasses.asdict(params[name])
                params[name] = build_section(ParameterSpec, {**old, **table},
                                             f"parameters.{name}", where)
            changes["parameters"] = params
        return _keeping_tables(self, dataclasses.replace(self, **changes))


T = TypeVar("T")


def built_table(cfg: PlantConfig, name: str, build: Callable[[PlantConfig], T]) -> T:
    """The typed object of ``cfg``'s table ``name`` (a section of :data:`EXTRA_SECTIONS`, or
    PARAMS.toml's ``discrepancy`` or ``model_error``): ``build(cfg)``, which reads
    ``cfg.extra[name]``, the first time it is asked for; the same object after (module
    docstring). ``build`` raises :class:`ConfigError` naming the file and the dotted key."""
    tables = cfg._tables
    if name not in tables:
        tables[name] = build(cfg)
    return tables[name]


def section_of(cfg: PlantConfig, name: str, cls: type[T]) -> T:
    """:func:`built_table` of a table that is one frozen dataclass ``cls`` whose fields all
    have defaults (the defaults when the table is absent)."""
    return built_table(cfg, name, lambda c: build_section(cls, c.extra.get(name, {}), name,
                                                          c.source))


#: The sections that make the model (its geometry, fibre, gas and numerics, with what a
#: PARAMS.toml ``[structure]`` changed in them), for :func:`made_with`.
MODEL_SECTIONS: tuple[str, ...] = ("tube", "cyclone", "fiber", "hot_gas", "environment",
                                   "solver")


def made_with(cfg: PlantConfig) -> dict[str, str]:
    """Short digests of what an estimator's state is made with: the parameter values, the
    model's structure (:data:`MODEL_SECTIONS`) and PARAMS.toml's ``[discrepancy]``,
    ``[model_error]`` and ``[regression]``. A checkpoint carries them, so that a state made
    with one calibration is never continued under another as if nothing had changed."""

    def digest(x: Any) -> str:
        text = json.dumps(x, sort_keys=True, default=repr)
        return hashlib.sha256(text.encode()).hexdigest()[:12]

    return {"parameters": digest(cfg.parameter_vector().tolist()),
            "structure": digest({k: repr(getattr(cfg, k)) for k in MODEL_SECTIONS}),
            **{k: digest(cfg.extra.get(k)) for k in ("discrepancy", "model_error",
                                                      "regression", "sensor")}}


def with_table(cfg: PlantConfig, name: str, table: dict[str, Any]) -> PlantConfig:
    """``cfg`` with PARAMS.toml's table ``name`` (e.g. ``regression``) set to ``table``, as
    :func:`load_parameters` would carry it; the other built tables kept."""
    out = _keeping_tables(cfg, dataclasses.replace(cfg, extra={**cfg.extra, name: table}))
    out._tables.pop(name, None)
    return out


def _keeping_tables(old: PlantConfig, new: PlantConfig) -> PlantConfig:
    """``new`` with the tables ``old`` built from the very tables ``new`` still holds (or
    from their absence, which it shares)."""
    new._tables.update({k: v for k, v in old._tables.items()
                        if new.extra.get(k) is old.extra.get(k)})
    return new


@dataclass(frozen=True)
class Parameters:
    """``[parameters]``: one ``[parameters.<name>]`` table per parameter of the paper's
    Table 1 (:data:`PARAMETER_NAMES`)."""

    mult_D: ParameterSpec
    mult_C: ParameterSpec
    mult_h: ParameterSpec
    mult_k: ParameterSpec
    mult_p: ParameterSpec
    hm_cyc: ParameterSpec
    hc_cyc: ParameterSpec


assert tuple(f.name for f in dataclasses.fields(Parameters)) == PARAMETER_NAMES


def _raw() -> Any:
    """A section another part of the program builds (:func:`built_table`): a table, kept as
    read."""
    return dataclasses.field(default=None, metadata={"raw": True})


@dataclass(frozen=True, kw_only=True)
class PlantFile(PlantSections):
    """The top level of a plant config file: the plant's sections, its parameters and the
    tables of :data:`EXTRA_SECTIONS` as read."""

    parameters: Parameters
    virtual_plant: dict[str, Any] | None = _raw()
    estimator: dict[str, Any] | None = _raw()
    service: dict[str, Any] | None = _raw()
    calibration: dict[str, Any] | None = _raw()
    display: dict[str, Any] | None = _raw()
    outputs: dict[str, Any] | None = _raw()
    plausibility: dict[str, Any] | None = _raw()
    lab: dict[str, Any] | None = _raw()
    advisor: dict[str, Any] | None = _raw()
    diagnosis: dict[str, Any] | None = _raw()


#: Sections built by other parts of the program (:func:`built_table`), kept as read.
EXTRA_SECTIONS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(PlantFile)
                                        if f.metadata.get("raw"))


def plant_config_from_dict(data: dict[str, Any], source: str = "<dict>") -> PlantConfig:
    """Validate a parsed TOML document into a :class:`PlantConfig`."""
    doc = build_section(PlantFile, data, "", source)
    kwargs = {f.name: getattr(doc, f.name) for f in dataclasses.fields(PlantSections)}
    parameters = {n: getattr(doc.parameters, n) for n in PARAMETER_NAMES}
    extra = {k: getattr(doc, k) for k in EXTRA_SECTIONS if getattr(doc, k) is not None}
    return PlantConfig(**kwargs, parameters=parameters, extra=extra, source=source)


def default_config_path() -> Path:
    """The reference plant's config shipped with the package (the repository's
    config/dryer1.toml links to it)."""
    return Path(str(resources.files("softsensor").joinpath("data/dryer1.toml")))


def load_plant_config(path: str | Path | None = None) -> PlantConfig:
    """Load and validate a plant config; ``None`` loads the built-in reference plant."""
    p = Path(path) if path is not None else default_config_path()
    return plant_config_from_dict(read_toml(p), str(p))


@dataclass(frozen=True)
class DiscrepancyPrior:
    """PARAMS.toml's ``[discrepancy]``: what the calibrated model leaves on data it was not
    fitted on (after the inlet trajectory fitted to the temperatures), the estimator's prior on
    its own error. The calibration builds it
    (:func:`softsensor.calibration.validation.discrepancy_prior`) and writes it; it is read back
    here (:func:`~softsensor.plantconfig.load_parameters`) for
    :meth:`softsensor.estimation.state_space.ErrorPriors.from_config` and the diagnosis. Every
    key may be absent: not known (TOML has no null; a NaN in memory counts as absent too).

    Attributes
    ----------
    common_std : float
        Root mean square of the part of the two outlet temperatures' residuals they share
        (``sqrt(max(mean(r_d r_c), 0))``, moments about zero: the mean offset counts) [K].
    dryer_std, cyclone_std : float
        Root mean square of each outlet temperature's own part [K].
    tau_s : float
        Correlation time of the temperature residuals, from their lag-one autocorrelation [s].
    moisture_std : float
        Root mean square of the lab residuals (out of sample) [kg/kg].
    inlet_walk : float
        Random-walk intensity of the fitted inlet trajectory [kg/kg / sqrt(h)].
    n_windows, n_labs : float
        Samples behind these numbers (numbers, not integers, as PARAMS.toml files have
        always been read).
    """

    common_std: float | None = num(None, ge=0)
    dryer_std: float | None = num(None, ge=0)
    cyclone_std: float | None = num(None, ge=0)
    tau_s: float | None = num(None, gt=0)
    moisture_std: float | None = num(None, ge=0)
    inlet_walk: float | None = num(None, ge=0)
    n_windows: float | None = num(None, ge=0)
    n_labs: float | None = num(None, ge=0)

    def as_dict(self) -> dict[str, float | None]:
        """Every key, None where not known (the JSON summaries; :meth:`as_table` for TOML)."""
        return dataclasses.asdict(self)

    def as_table(self) -> dict[str, float]:
        """The ``[discrepancy]`` table as PARAMS.toml holds it: the known keys only."""
        return {k: v for k, v in self.as_dict().items() if v is not None}


def _discrepancy(table: Any, source: str) -> DiscrepancyPrior | None:
    """The ``[discrepancy]`` table built and checked (None when absent)."""
    if table is None:
        return None
    if isinstance(table, dict):
        table = {k: v for k, v in table.items() if not (isinstance(v, float) and math.isnan(v))}
    return build_section(DiscrepancyPrior, table, "discrepancy", source)


def discrepancy_of(cfg: PlantConfig) -> DiscrepancyPrior | None:
    """The ``[discrepancy]`` a PARAMS.toml (or a calibration in memory) gave ``cfg``, built
    once (:func:`built_table`); None without one."""
    return built_table(cfg, "discrepancy",
                       lambda c: _discrepancy(c.extra.get("discrepancy"), c.source))


def dotted_keys(table: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """A nested TOML table as ``{"section.key": value}``; the ``evidence`` sub-table, which
    records why a structure was adopted, is not a key."""
    out: dict[str, Any] = {}
    for k, v in table.items():
        if not prefix and k == "evidence":
            continue
        if isinstance(v, dict):
            out.update(dotted_keys(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _learned_values(sensor: Any, path: str) -> dict[str, float]:
    """PARAMS.toml's ``[sensor].values``: the ``[estimator]`` keys the calibration learned
    from the history (:mod:`softsensor.calibration.sensor_tuning`). They take the place of
    the shipped defaults; a key the plant config's own ``[estimator]`` sets wins (the
    engineer's word). Their ranges are checked where ``[estimator]`` is built, naming
    ``estimator.<key>``."""
    if not isinstance(sensor, dict):
        raise ConfigError(f"{path}: [sensor] must be a table")
    values = sensor.get("values", {})
    if not isinstance(values, dict):
        raise ConfigError(f"{path}: sensor.values must be a table")
    for k, v in values.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(f"{path}: sensor.values.{k} must be a finite number, got {v!r}")
    return dict(values)


def load_parameters(path: str | Path, config: PlantConfig) -> PlantConfig:
    """Apply a ``PARAMS.toml`` (written by ``softsensor calibrate``) to ``config``.

    ``[parameters.<name>]`` tables give the values (each within its bounds); the calibration's
    ``[discrepancy]`` table (what the model left on held-out data, checked here:
    :class:`DiscrepancyPrior`) and ``[model_error]`` (what the history says it misses, built by
    :func:`softsensor.estimation.model_error.model_error_of`), when present, are carried in
    ``extra`` for the estimator and the diagnosis, as is ``[regression]`` (the lab regression
    fitted on the same history, :mod:`softsensor.estimation.lab_regression`); ``[structure]``
    (a structural alternative adopted from history: plant-section keys such as
    ``fiber.critical_moisture``) replaces
    those keys of the plant sections (:meth:`PlantConfig.with_keys`). The tables
    ``config`` built already stay built.
    """
    data = read_toml(path)
    table = data.get("parameters")
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: section [parameters] is missing")
    values = {}
    for name, spec in table.items():
        if name not in PARAMETER_NAMES:
            raise ConfigError(f"{path}: parameters.{name} is not one of the paper's Table 1 "
                              f"parameters")
        if not isinstance(spec, dict) or "value" not in spec:
            raise ConfigError(f"{path}: parameters.{name}.value is missing")
        v = spec["value"]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(f"{path}: parameters.{name}.value must be a number, got {v!r}")
        values[name] = float(v)
    cfg = config
    structure = data.get("structure")
    if structure is not None:  # first: it may widen the bounds the values must keep within
        if not isinstance(structure, dict):
            raise ConfigError(f"{path}: [structure] must be a table")
        cfg = cfg.with_keys(dotted_keys(structure), source=str(path))
    cfg = cfg.with_parameters(values, source=str(path)) if values else cfg
    extra = dict(cfg.extra)
    built: dict[str, Any] = {}
    disc = data.get("discrepancy")
    if disc is not None:
        prior = built["discrepancy"] = _discrepancy(disc, str(path))
        extra["discrepancy"] = prior.as_table()
    error = data.get("model_error")
    if error is not None:
        if not isinstance(error, dict):
            raise ConfigError(f"{path}: [model_error] must be a table")
        extra["model_error"] = error  # built and checked by estimation.model_error_of
    regression = data.get("regression")
    if regression is not None:  # built and checked by estimation.lab_regression
        extra["regression"] = regression
    sensor = data.get("sensor")
    if sensor is not None:
        extra["sensor"] = sensor
        extra["estimator"] = {**_learned_values(sensor, str(path)),
                              **config.extra.get("estimator", {})}
    out = _keeping_tables(cfg, dataclasses.replace(cfg, extra=extra,
                                                   source=f"{config.source} + {path}"))
    out._tables.update(built)
    return out
