"""Every configuration table and key, rendered from the frozen dataclasses that read them.

Each TOML table of softsensor's files is one frozen dataclass built by
:func:`softsensor.configfile.build_section` (unknown keys refused, bounds and choices from the
fields' metadata). ``.. softsensor-config::`` renders, per file and table of :data:`FILES`,
every key with its type, its default (or "required"), its bounds (``num(gt=..., le=...)``),
its choices (``choice(...)``), its unit and what it means. The unit and the meaning come from
the class's numpydoc ``Attributes`` section (the unit in brackets at the end of a key's
description, ``[kg/kg]``), else from the comment on the field's line or above it (``# m``,
``# s, PID and plant step``). A field typed as another dataclass is a sub-table, rendered
under its dotted name. ``tests/docs/test_config_reference.py`` fails when a table the program
builds is missing here.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import io
import math
import re
import textwrap
import tokenize
import types
import typing
from dataclasses import dataclass

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles

from softsensor.ingest.units import registry


@dataclass(frozen=True)
class Table:
    """One TOML table: its dotted name in its file and the dataclass that reads it."""

    name: str
    cls: str
    note: str = ""
    #: Render fields typed as dataclasses as sub-tables (off where one generic table, such as
    #: ``[plausibility.<signal>]``, stands for them all).
    subtables: bool = True
    #: The keys are signals of CONTRACT section 1 (the nominal operating point): a key
    #: without a unit of its own has its signal's SI unit.
    signal_units: bool = False


@dataclass(frozen=True)
class ConfigFile:
    """One kind of file and its tables, in the order a reader meets them."""

    title: str
    example: str
    intro: str
    tables: tuple[Table, ...]


PC = "softsensor.plantconfig"
FILES: tuple[ConfigFile, ...] = (
    ConfigFile(
        "The plant config", "config/dryer1.toml",
        "The plant (CONTRACT section 6), its Table 1 parameters and the settings of every part "
        "of the program. Loaded by every verb (``--config``; default the packaged "
        "``dryer1.toml``) and checked whole before anything starts "
        "(:func:`softsensor.plantconfig.load_plant_config`).",
        (Table("unit", f"{PC}.Unit"),
         Table("tube", f"{PC}.Tube"),
         Table("cyclone", f"{PC}.Cyclone"),
         Table("fiber", f"{PC}.Fiber"),
         Table("hot_gas", f"{PC}.HotGas"),
         Table("environment", f"{PC}.Environment"),
         Table("nominal", f"{PC}.Nominal",
               "The nominal operating point, one key per model input of CONTRACT section 1, "
               "in its SI unit (:doc:`/nomenclature`).", signal_units=True),
         Table("solver", f"{PC}.Solver"),
         Table("cost", f"{PC}.Cost",
               "The weights of the paper's eq. 4, per channel [1/K for the temperatures, "
               "kg/kg⁻¹ for the moisture]."),
         Table("parameters.<name>", f"{PC}.ParameterSpec",
               "One table per parameter of the paper's Table 1 (``mult_D``, ``mult_C``, "
               "``mult_h``, ``mult_k``, ``mult_p``, ``hm_cyc`` [kg/(m2 s)], ``hc_cyc`` "
               "[W/(m2 K)]; the multipliers are dimensionless)."),
         Table("service", "softsensor.service.settings.ServiceSettings"),
         Table("estimator", "softsensor.estimation.settings.EstimatorSettings"),
         Table("calibration", "softsensor.calibration.settings.CalibrationSettings"),
         Table("display", "softsensor.presentation.display.DisplaySettings"),
         Table("outputs", "softsensor.outputs.settings.OutputSettings",
               "Each operator output is a sub-table; all are off by default."),
         Table("plausibility", "softsensor.windows.plausibility.PlausibilityTable",
               "``hold_s`` and one sub-table per scan signal, whose keys replace that "
               "signal's default limits (the table below).", subtables=False),
         Table("plausibility.<signal>", "softsensor.windows.plausibility.SignalLimits",
               "Every key is optional here: each one given replaces that signal's default "
               "(the defaults table below), and the result is checked as one table."),
         Table("lab", "softsensor.ingest.historian_map.LabMap",
               "The LIMS file's layout for the daemon's lab folder: the same table as a "
               "historian map's ``[lab]``."),
         Table("virtual_plant", "softsensor.plant.settings.VirtualPlantSettings"),
         Table("diagnosis", "softsensor.diagnosis.settings.DiagnosisSettings"),
         Table("advisor", "softsensor.advisor.settings.AdvisorSettings"))),
    ConfigFile(
        "The tag map", "config/tagmap_dryer1.toml",
        "Where each signal lives in the PLC (read by ``run`` and ``plant-server``; "
        ":mod:`softsensor.ingest.tagmap`).",
        (Table("modbus", "softsensor.ingest.tagmap.ModbusSettings"),
         Table("tags.<signal>", "softsensor.ingest.tagmap.TagSpec"),
         Table("clock", "softsensor.ingest.tagmap.ClockSpec"))),
    ConfigFile(
        "The historian map", "replay/historian-map.toml",
        "How ``softsensor import`` reads a historian export and a LIMS file "
        "(:doc:`/historian-map` explains each key with examples).",
        (Table("source", "softsensor.ingest.historian_map.SourceMap"),
         Table("signals.<name>", "softsensor.ingest.historian_map.SignalMap"),
         Table("lab", "softsensor.ingest.historian_map.LabMap"))),
    ConfigFile(
        "PARAMS.toml", "written by softsensor calibrate",
        "A calibrated parameter set and what the calibration learned, written by "
        "``calibrate`` and read by every verb's ``--params`` "
        "(:mod:`softsensor.calibration.params_file` describes the whole layout, including "
        "the ``[fit]`` and ``[structure]`` tables the program writes for people and for "
        "itself). ``[parameters.<name>]`` is the plant config's table above.",
        (Table("discrepancy", f"{PC}.DiscrepancyPrior"),
         Table("model_error", "softsensor.estimation.model_error.ModelError"),
         Table("regression", "softsensor.estimation.lab_regression.LabRegression",
               "The lab-regression peer's coefficients and its history's spreads "
               "(:func:`softsensor.estimation.lab_regression.fit_lab_regression`)."))),
)

#: A role whose dotted target the source wraps after a dot (``:class:`~softsensor.estimation.``
#: at a line's end, the rest on the next): one name to a reader, a space to reST (conf.py joins
#: them in every docstring before it is parsed).
WRAPPED_TARGET = re.compile(r"(:[a-z]+:`[~.]?[\w.]*\.)\n\s*(?=\w)")
_BOUND_SIGNS = {"gt": ">", "ge": "≥", "lt": "<", "le": "≤"}
_PLAIN_UNITS = {"s", "K", "m", "kg", "Pa", "W", "J", "%", "h", "min", "ns", "bytes"}
#: The unit column of a key that is no quantity (a name, a switch, a table, a list of names).
NO_UNIT = "—"
#: Key types that are no quantity: their unit is :data:`NO_UNIT` unless the source says one.
NOT_QUANTITIES = {"string", "boolean", "table", "array of string", "list", "Any"}
#: What each signal of CONTRACT section 1 is (the nominal operating point's keys).
SIGNAL_MEANINGS = {
    "T_air_in": "hot air temperature entering the dryer tube (after the mixing flaps)",
    "m_air": "dry-air mass flow through the tube",
    "m_fiber": "dry fibre mass flow (production rate)",
    "T_fiber_in": "fibre temperature at the injection point",
    "m_steam": "steam injected with the fibre",
    "T_amb": "ambient air temperature",
    "H_amb": "ambient specific humidity",
    "flap_cmd": "PID output to the mixing-air flaps",
    "T_sp": "set point of the outlet-temperature loop",
    "T_dryer_out": "air temperature at the dryer tube outlet",
    "T_cyclone_out": "air temperature at the cyclone outlet",
    "moisture_in": "fibre moisture at the dryer inlet, dry basis",
    "moisture_out": "fibre moisture at the cyclone outlet, dry basis",
}


#: What the source leaves unsaid of a key, by ``Class.field``: ``(unit, meaning)``, either
#: empty where the source says it. The source (the class's ``Attributes`` section or the
#: comment on the field) comes first; this table holds what it lacks in modules where a
#: docstring would push the module past the house's 600 lines (``plantconfig.py``) or into
#: another change's lines, and ``tests/docs/test_config_reference.py`` refuses an entry the
#: source has made redundant, so that the two cannot disagree. Units: SI symbols; ``1`` a
#: ratio, fraction or multiplier; ``count`` a number of things; ``—`` no quantity (a name, a
#: switch, an address).
SUPPLEMENT: dict[str, tuple[str, str]] = {
    # the plant config: softsensor/plantconfig.py (issue 49: 93 keys had no meaning)
    "Unit.name": ("", "the unit's name: the ``<unit>`` of the Zenoh keys and the label of "
                      "every output"),
    "Tube.n_cells": ("count", "finite volumes the tube is divided into along its length"),
    "Tube.wall_heat_capacity": ("", "specific heat capacity of the wall's steel"),
    "Tube.wall_conductivity": ("", "thermal conductivity of the wall's steel"),
    "Tube.wall_emissivity": ("1", "emissivity of the wall's outer surface (radiation to the "
                                  "surroundings)"),
    "Tube.deposit_conductivity": ("W/(m K)", ""),
    "Cyclone.count": ("count", "cyclones in parallel"),
    "Cyclone.height": ("", "height of one cyclone"),
    "Cyclone.n_cells": ("count", "well-mixed cells of the lumped cyclone model"),
    "Cyclone.shell_density": ("", "density of the shell's steel"),
    "Cyclone.shell_heat_capacity": ("", "specific heat capacity of the shell's steel"),
    "Fiber.diameter": ("", "diameter of a fibre (a cylinder)"),
    "Fiber.length": ("", "length of a fibre"),
    "Fiber.saturation_point": ("", "fibre saturation point: the moisture below which water is "
                                   "bound in the cell wall, dry basis"),
    "Fiber.critical_moisture": ("", "critical moisture of the drying-rate law: the falling "
                                    "rate begins below it, dry basis"),
    "Fiber.bound_fraction": ("1", "the drying rate's bound-water plateau, as a fraction of the "
                                  "free-water rate (paper's eq. 2)"),
    "Fiber.equilibrium_width": ("", "width of the double sigmoid's step at the equilibrium "
                                    "moisture (paper's eq. 2)"),
    "Fiber.cdc_exponent": ("1", ""),
    "Fiber.rea_c": ("1", ""),
    "HotGas.fraction_min": ("1", "hot-gas share of the mixed air with the flaps at 0 %"),
    "HotGas.fraction_max": ("1", "hot-gas share of the mixed air with the flaps at 100 %"),
    "Environment.wind_speed": ("", "wind speed outside (convective heat loss)"),
    "Solver.wall_substeps": ("count", "Crank-Nicolson substeps of the wall temperature per "
                                      "window"),
    "Solver.min_good_fraction": ("1", ""),
    "Cost.T_dryer_out": ("1/K", "weight WF of the dryer outlet temperature's RMSE in the "
                                "paper's eq. 4"),
    "Cost.T_cyclone_out": ("1/K", "weight WF of the cyclone outlet temperature's RMSE in the "
                                  "paper's eq. 4"),
    "Cost.moisture_out": ("1/(kg/kg)", "weight WF of the outlet moisture's RMSE in the paper's "
                                       "eq. 4"),
    "ParameterSpec.value": ("Table 1's (1 for the multipliers)",
                            "the parameter's value (one of the paper's Table 1)"),
    "ParameterSpec.low": ("the parameter's", "lower bound of the calibration's search"),
    "ParameterSpec.high": ("the parameter's", "upper bound of the calibration's search"),
    "ParameterSpec.log": ("", "search and prior on the logarithm of the parameter"),
    "ModbusOutputSettings.max_requests_per_s": ("1/s", ""),
    # the daemon and the estimator
    "ServiceSettings.checkpoint_every": ("count", ""),
    "ServiceSettings.max_message_bytes": ("bytes", ""),
    "ServiceSettings.max_queue": ("count", ""),
    "ServiceSettings.max_queue_bytes": ("bytes", ""),
    "EstimatorSettings.sigma_alpha": ("1", ""),
    "EstimatorSettings.sigma_beta": ("1", ""),
    "EstimatorSettings.sigma_kappa": ("1", ""),
    "CalibrationSettings.holdout_fraction": ("1", ""),
    "CalibrationSettings.bound_margin": ("1", ""),
    "CalibrationSettings.search_wall_substeps": ("count", ""),
    "CalibrationSettings.polish_passes": ("count", ""),
    "CalibrationSettings.polish_evaluations": ("count", ""),
    # the operator outputs
    **{f"{cls}.{key}": value for cls in ("ModbusOutputSettings", "MetricsSettings",
                                         "WebSettings", "OpcUaSettings")
       for key, value in (("enabled", ("", "serve this output")),
                          ("host", ("", "address to listen on (127.0.0.1: this machine "
                                        "only; 0.0.0.0: every interface)")),
                          ("port", ("—", "TCP port to listen on")))},
    "ModbusOutputSettings.unit_id": ("—", "Modbus unit id the server answers as"),
    "ModbusOutputSettings.max_connections": ("count", ""),
    "MetricsSettings.backlog": ("count", "connections beyond the workers that may wait"),
    "MetricsSettings.timeout_s": ("s", "deadline for a request's whole header, and for the "
                                       "client to take the answer"),
    "WebSettings.history_h": ("h", ""),
    "WebSettings.workers": ("count", ""),
    "WebSettings.backlog": ("count", ""),
    "OpcUaSettings.history_h": ("h", ""),
    "OpcUaSettings.idle_timeout_s": ("s", "a session idle this long is closed"),
    # the plausibility screen
    "PlausibilityTable.hold_s": ("s", "how long a suspect signal's new level must hold steady "
                                      "before it is believed"),
    **{f"PlausibilityTable.{name}": ("", f"limits of {name}, replacing the defaults' keys "
                                         f"given (``[plausibility.<signal>]``)")
       for name in ("T_air_in", "m_air", "m_fiber", "T_fiber_in", "m_steam", "T_amb", "H_amb",
                    "flap_cmd", "T_sp", "T_dryer_out", "T_cyclone_out")},
    # the virtual plant
    "VirtualPlantSettings.ti": ("", "integral time of the outlet-temperature PI loop"),
    "VirtualPlantSettings.noise_lab": ("", "standard deviation of a lab result's error"),
    "VirtualPlantSettings.lab_interval_max": ("", "longest time between two lab samples"),
    "VirtualPlantSettings.lab_delay_min": ("", "shortest delay of a lab result after its "
                                               "sample"),
    "VirtualPlantSettings.lab_delay_max": ("", "longest delay of a lab result after its "
                                               "sample"),
    "VirtualPlantSettings.m_fiber_max": ("kg/s", "highest production rate drawn"),
    "VirtualPlantSettings.production_hold_max": ("s", "longest time between production "
                                                      "changes"),
    "VirtualPlantSettings.setpoint_change_probability": ("1", ""),
    "VirtualPlantSettings.ambient_amplitude_max": ("K", "largest daily swing of the ambient "
                                                        "temperature drawn"),
    "VirtualPlantSettings.ambient_mean_min": ("", "lowest mean ambient temperature drawn"),
    "VirtualPlantSettings.ambient_mean_max": ("K", "highest mean ambient temperature drawn"),
    # the tag map and the historian map
    "ModbusSettings.port": ("—", ""),
    "ModbusSettings.retries": ("count", ""),
    "ModbusSettings.max_gap_registers": ("count", ""),
    "ModbusSettings.max_registers_per_read": ("count", ""),
    "TagSpec.unit_id": ("—", ""),
    "TagSpec.address": ("—", ""),
    "TagSpec.scale": ("engineering unit per count", ""),
    "TagSpec.offset": ("", "added after the scale: eng = raw * scale + offset"),
    "ClockSpec.unit_id": ("—", ""),
    "ClockSpec.address": ("—", ""),
    "SourceMap.good_quality": ("", "quality codes whose rows are taken (the rest dropped)"),
    "SourceMap.skip_rows": ("count", ""),
    "SourceMap.max_rows": ("count", ""),
    "LabMap.skip_rows": ("count", ""),
    "SignalMap.constant": ("the signal's, as the column's unit", ""),
    # PARAMS.toml
    "DiscrepancyPrior.n_windows": ("count", ""),
    "DiscrepancyPrior.n_labs": ("count", ""),
    "ModelError.mean": ("each feature's SI unit", ""),
    "ModelError.scale": ("each feature's SI unit", ""),
    "ModelError.days": ("count", ""),
    "ModelError.hours": ("h", ""),
    "ChannelError.samples": ("count", ""),
    "LabRegression.signals": ("", "the scan signals the regression reads, in order"),
    "LabRegression.mean": ("each signal's SI unit", "each signal's mean over the history's "
                                                    "lab windows"),
    "LabRegression.scale": ("each signal's SI unit", "each signal's standard deviation over "
                                                     "them (the standardisation)"),
    "LabRegression.coef": ("kg/kg", "intercept, then one slope per standardised signal"),
    "LabRegression.step_sd": ("kg/kg", "standard deviation of the bias-updated regression's "
                                       "error from one lab result to the next"),
    "LabRegression.hold_sd": ("kg/kg", "standard deviation of holding the last lab result "
                                       "until the next"),
    "LabRegression.n_labs": ("count", "lab results the regression was fitted on"),
}


def resolve(path: str) -> type:
    """The class at dotted ``path``."""
    module, _, name = path.rpartition(".")
    return getattr(importlib.import_module(module), name)


def looks_like_unit(text: str) -> bool:
    """Whether ``text`` reads as a unit (pint parses it, ``m2`` as ``m**2``)."""
    text = text.strip()
    if not text or len(text) > 24 or text[0].isdigit() and text != "1" and "/" not in text:
        return False
    spelled = re.sub(r"([a-zA-Z])(\d)", r"\1**\2", text.replace("%", "percent"))
    try:
        registry().parse_units(spelled)
    except Exception:
        return False
    return True


def _attribute_docs(cls: type) -> dict[str, str]:
    """Field name -> description from the numpydoc ``Attributes`` section."""
    from numpydoc.docscrape import NumpyDocString

    doc = inspect.getdoc(cls) or ""
    if "Attributes\n" not in doc:
        return {}
    out: dict[str, str] = {}
    for param in NumpyDocString(doc)["Attributes"]:
        # a role whose dotted target the source wraps after a dot is one name (conf.py)
        text = " ".join(WRAPPED_TARGET.sub(r"\1", "\n".join(param.desc)).split())
        names = [n.strip() for n in param.name.split(",")]
        units = re.findall(r"\[([^\[\]]+)\]", text)
        for i, name in enumerate(names):
            # names described together with one unit each, in order ("Standard deviation
            # [unit] and correlation time [h]"): each its own
            own = f" [{units[i]}]" if len(names) > 1 and len(units) == len(names) else ""
            out[name] = text + own
    return out


def _comment_docs(cls: type) -> dict[str, tuple[str, str]]:
    """Field name -> (the comment lines above it, the comment on its line)."""
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    names = {f.name for f in dataclasses.fields(cls)}
    above_of: dict[str, str] = {}
    trailing: dict[str, str] = {}
    above: list[str] = []
    line_field: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.NAME and tok.start[1] == 4 and tok.string in names:
            line_field.setdefault(tok.start[0], tok.string)
            if above:
                above_of[tok.string] = " ".join(above)
                above = []
        elif tok.type == tokenize.COMMENT:
            text = tok.string.lstrip("#:").strip()
            field = line_field.get(tok.start[0])
            if field is not None:
                trailing[field] = text
            elif tok.start[1] == 4:
                above.append(text)
        elif tok.type == tokenize.NL and tok.start[1] == 0 and not tok.line.strip():
            above = []
    return {n: (above_of.get(n, ""), trailing.get(n, "")) for n in names}


def split_unit(text: str, from_comment: bool) -> tuple[str, str]:
    """(unit, description) of a key's text: a trailing ``[unit]``, else the first bracketed
    one (``Their correlation times [h]. ...``); in a comment also a leading unit (``m,
    inner``; ``s between production changes``; ``kg/m3 (steel 7850)``)."""
    text = text.strip()
    bracket = re.search(r"\s*\[([^\[\]]+)\]\.?$", text)
    if bracket:
        return bracket.group(1), text[:bracket.start()].rstrip(" .,;:")
    if not from_comment:
        inner = re.search(r"\[([^\[\]]+)\]", text)
        if inner:
            return inner.group(1), text
    if from_comment and text:
        first = re.split(r"[\s(]", text, maxsplit=1)[0].rstrip(",;")
        if (first in _PLAIN_UNITS or "/" in first or re.fullmatch(r"[a-zA-Z]+\d", first)) \
                and looks_like_unit(first):
            return first, text[len(first):].strip(" ,;")
        head, _, rest = text.partition(",")
        if looks_like_unit(head):
            return head.strip(), rest.strip()
        inner = re.search(r"\[([^\[\]]+)\]", text)
        if inner:
            return inner.group(1), (text[:inner.start()] + text[inner.end():]).strip()
        first, _, rest = text.partition(" ")
        if first in _PLAIN_UNITS:
            return first, rest.strip()
    return "", text


def _type_name(typ: typing.Any) -> str:
    origin = typing.get_origin(typ)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(typ) if a is not type(None)]
        return " or ".join(_type_name(a) for a in args) + " (optional)"
    if origin is tuple:
        args = typing.get_args(typ)
        return f"array of {_type_name(args[0]) if args else 'values'}"
    if origin in (dict, typing.Mapping) or typ is dict:
        return "table"
    names = {float: "number", int: "integer", bool: "boolean", str: "string"}
    return names.get(typ, getattr(typ, "__name__", str(typ)))


def _default(f: dataclasses.Field) -> str:
    if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
        return "required"
    value = f.default if f.default is not dataclasses.MISSING else f.default_factory()
    if value is None:
        return "none"
    if dataclasses.is_dataclass(value):
        return "(table)"
    if isinstance(value, bool):
        return "``true``" if value else "``false``"
    if isinstance(value, float):
        return f"``{value:g}``" if math.isfinite(value) else f"``{value}``"
    if isinstance(value, str):
        return f'``"{value}"``'
    if isinstance(value, list | tuple):
        return "``[" + ", ".join(repr(v) for v in value) + "]``" if value else "``[]``"
    return f"``{value!r}``"


def _rules(f: dataclasses.Field) -> str:
    meta = f.metadata
    if "one_of" in meta:
        return "one of " + ", ".join(f'``"{o}"``' for o in meta["one_of"])
    return ", ".join(f"{_BOUND_SIGNS[k]} {meta[k]:g}" for k in _BOUND_SIGNS if k in meta)


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", r"\|")


@dataclass(frozen=True)
class Key:
    """One row of a table's reference."""

    key: str
    type: str
    default: str
    rules: str
    unit: str
    description: str


def table_keys(cls: type, signal_units: bool = False
               ) -> tuple[list[Key], list[tuple[str, type]]]:
    """The keys of ``cls`` and its sub-tables (``(field name, dataclass)``); with
    ``signal_units`` a key named after a signal without a unit of its own has the signal's."""
    from softsensor.configfile import TOML_KEY
    from softsensor.signals import SCAN_SIGNALS

    units = {**SCAN_SIGNALS, "moisture_in": "kg/kg", "moisture_out": "kg/kg"}

    attrs, comments = _attribute_docs(cls), _comment_docs(cls)
    hints = typing.get_type_hints(cls)
    keys: list[Key] = []
    subs: list[tuple[str, type]] = []
    for f in dataclasses.fields(cls):
        if not f.init or f.metadata.get("raw"):
            continue
        typ = hints[f.name]
        bare = [a for a in typing.get_args(typ) if a is not type(None)] or [typ]
        if dataclasses.is_dataclass(bare[0]) and isinstance(bare[0], type):
            subs.append((f.name, bare[0]))
            continue
        if f.name in attrs:
            unit, text = split_unit(attrs[f.name], from_comment=False)
        else:
            above, line = comments.get(f.name, ("", ""))
            unit, text = split_unit(line, from_comment=True)
            if not unit:
                unit, above = split_unit(above, from_comment=True)
            text = "; ".join(t for t in (above, text) if t)
        if signal_units and not unit:
            unit = units.get(f.name, "")
        if signal_units and not text and f.name in SIGNAL_MEANINGS:
            text = SIGNAL_MEANINGS[f.name]
        more_unit, more_text = SUPPLEMENT.get(f"{cls.__qualname__}.{f.name}", ("", ""))
        unit, text = unit or more_unit, text or more_text
        if not unit and _type_name(typ).split(" (")[0] in NOT_QUANTITIES:
            unit = NO_UNIT
        keys.append(Key(f.metadata.get(TOML_KEY, f.name), _type_name(typ), _default(f),
                        _rules(f), unit, text))
    return keys, subs


def _summary(cls: type) -> str:
    """The first paragraph of the class's own docstring (a dataclass without one has its
    signature as ``__doc__``: nothing to say)."""
    doc = cls.__dict__.get("__doc__") or ""
    if doc.startswith(f"{cls.__name__}("):
        return ""
    return " ".join(inspect.cleandoc(doc).split("\n\n")[0].split())


def table_rst(name: str, cls: type, note: str = "", path: str = "", file: str = "",
              subtables: bool = True, signal_units: bool = False) -> list[str]:
    """reST of table ``[name]`` read by ``cls`` (at dotted ``path``: a class made by
    ``dataclasses.make_dataclass`` does not know its module), then its sub-tables."""
    keys, subs = table_keys(cls, signal_units)
    label = re.sub(r"[^a-z0-9]+", "-", f"{file} {name}".lower()).strip("-")
    lines = [f".. _config-{label}:", "",
             f"``[{name}]``", "^" * (len(name) + 6), ""]
    summary = _summary(cls)
    if summary:
        lines += [summary, ""]
    if note:
        lines += [note, ""]
    path = path or f"{cls.__module__}.{cls.__qualname__}"
    lines += [f"Read by :class:`{path}`.", ""]
    if keys:
        lines += [".. list-table::", "   :header-rows: 1", "   :widths: 18 12 12 14 12 32", "",
                  "   * - key", "     - type", "     - default", "     - allowed",
                  "     - unit", "     - meaning"]
        for k in keys:
            lines += [f"   * - ``{k.key}``", f"     - {_cell(k.type)}", f"     - {k.default}",
                      f"     - {_cell(k.rules)}", f"     - {_cell(k.unit)}",
                      f"     - {_cell(k.description)}"]
        lines.append("")
    for sub_name, sub_cls in subs if subtables else ():
        lines += table_rst(f"{name}.{sub_name}", sub_cls, file=file)
    return lines


def plausibility_defaults_rst() -> list[str]:
    """The default limits of every scan signal (``[plausibility.<signal>]``)."""
    from softsensor.signals import SCAN_SIGNALS
    from softsensor.windows.plausibility import DEFAULT_LIMITS, HOLD_S

    lines = [f"Default limits of the reference plant (``hold_s`` {HOLD_S:g} s; "
             ":data:`softsensor.windows.plausibility.DEFAULT_LIMITS`); a rate of 0 is no "
             "rate check:", "",
             ".. list-table::", "   :header-rows: 1", "",
             "   * - signal", "     - low", "     - high", "     - max_rate [unit/s]",
             "     - max_step", "     - unit"]
    for name in SCAN_SIGNALS:
        lim = DEFAULT_LIMITS.get(name)
        if lim is None:
            continue
        lines += [f"   * - ``{name}``", f"     - {lim.low:g}", f"     - {lim.high:g}",
                  f"     - {lim.max_rate:g}", f"     - {lim.max_step:g}",
                  f"     - {SCAN_SIGNALS[name]}"]
    return lines + [""]


def config_rst() -> list[str]:
    lines: list[str] = []
    for cf in FILES:
        lines += [cf.title, "-" * len(cf.title), "", cf.intro, "",
                  f"Example: ``{cf.example}``.", ""]
        for table in cf.tables:
            lines += table_rst(table.name, resolve(table.cls), table.note, table.cls,
                               cf.title, table.subtables, table.signal_units)
            if table.name == "plausibility.<signal>":
                lines += plausibility_defaults_rst()
    return lines


class ConfigReference(SphinxDirective):
    """``.. softsensor-config::``: every table and key of :data:`FILES`."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        for cf in FILES:
            for table in cf.tables:
                module = importlib.import_module(table.cls.rpartition(".")[0])
                if getattr(module, "__file__", None):
                    self.env.note_dependency(module.__file__)
        node = nodes.section()
        node.document = self.state.document
        nested_parse_with_titles(self.state, StringList(config_rst(), source="config"), node)
        return node.children


def setup(app):
    app.add_directive("softsensor-config", ConfigReference)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
