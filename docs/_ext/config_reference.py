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
         Table("diagnosis", "softsensor.diagnosis.settings.DiagnosisSettings"))),
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
        for name in param.name.split(","):
            out[name.strip()] = text
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
    """(unit, description) of a key's text: a trailing ``[unit]``; in a comment also a
    leading unit (``m, inner``; ``s between production changes``)."""
    text = text.strip()
    bracket = re.search(r"\s*\[([^\[\]]+)\]\.?$", text)
    if bracket:
        return bracket.group(1), text[:bracket.start()].rstrip(" .,;:")
    if from_comment and text:
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
