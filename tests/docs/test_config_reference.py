"""The configuration reference (``docs/_ext/config_reference.py``) lists every table the
program reads, and every key of each with its default, bounds, choices and unit.

The tables are found in the package itself, not from a list kept by hand: every dataclass that
:func:`softsensor.configfile.build_section` or :func:`softsensor.plantconfig.section_of` builds
anywhere in ``softsensor/``, every table name :func:`softsensor.plantconfig.built_table`
caches, and every section of a plant config file. A table added to the program and left out
of the reference fails here.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import re
import typing

import pytest
from paths import REPO

from softsensor.plantconfig import EXTRA_SECTIONS, PlantFile

PACKAGE = REPO / "softsensor"


def _module_name(path) -> str:
    return ".".join(path.relative_to(REPO).with_suffix("").parts).removesuffix(".__init__")


def _calls(name: str):
    """(module, call node) of every call of ``name`` in the package's sources."""
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                f = node.func
                called = f.id if isinstance(f, ast.Name) else getattr(f, "attr", None)
                if called == name:
                    yield _module_name(path), node


def built_classes() -> dict[str, type]:
    """Every dataclass a config table is built into, by qualified name."""
    found: dict[str, type] = {}
    for fn, position in (("build_section", 0), ("section_of", 2)):
        for module, call in _calls(fn):
            if len(call.args) <= position or not isinstance(call.args[position], ast.Name):
                continue  # a class chosen at run time (``type(current)``)
            cls = getattr(importlib.import_module(module), call.args[position].id, None)
            if not isinstance(cls, type):
                continue  # a variable holding a class given at run time (``cls``, ``typ``)
            found[f"{cls.__module__}.{cls.__qualname__}"] = cls
    return found


def cached_tables() -> set[str]:
    """Every table name given to ``built_table`` or ``section_of`` as a string literal."""
    names = set()
    for fn in ("built_table", "section_of"):
        for _module, call in _calls(fn):
            if len(call.args) > 1 and isinstance(call.args[1], ast.Constant):
                names.add(call.args[1].value)
    return names


def documented(config_reference) -> tuple[dict[str, type], set[str]]:
    """The classes the reference renders (sub-tables included) and its table names."""
    classes: dict[str, type] = {}
    names: set[str] = set()

    def walk(name: str, cls: type) -> None:
        classes[f"{cls.__module__}.{cls.__qualname__}"] = cls
        names.add(name)
        _keys, subs = config_reference.table_keys(cls)
        for sub_name, sub_cls in subs:
            walk(f"{name}.{sub_name}", sub_cls)

    for cf in config_reference.FILES:
        for table in cf.tables:
            walk(table.name, config_reference.resolve(table.cls))
    return classes, names


def test_every_table_the_program_builds_is_in_the_reference(config_reference):
    classes, _names = documented(config_reference)
    built = built_classes()
    assert len(built) >= 15, sorted(built)  # the scan itself works
    # the top level of a plant config file is the file, not a table: its sections are
    # checked one by one below
    missing = sorted(set(built) - set(classes) - {f"{PlantFile.__module__}.PlantFile"})
    assert not missing, f"config tables missing from docs/_ext/config_reference.py: {missing}"


def test_every_cached_table_name_is_in_the_reference(config_reference):
    _classes, names = documented(config_reference)
    tops = {n.split(".")[0] for n in names}
    missing = sorted(cached_tables() - tops)
    assert not missing, f"tables missing from docs/_ext/config_reference.py: {missing}"


def test_every_section_of_a_plant_config_file_is_in_the_reference(config_reference):
    plant = config_reference.FILES[0]
    tops = {t.name.split(".")[0] for t in plant.tables}
    sections = {f.name for f in dataclasses.fields(PlantFile)}
    assert set(EXTRA_SECTIONS) <= sections
    assert sections - tops == set(), sorted(sections - tops)


def test_every_key_is_rendered_with_its_default_and_rules(config_reference):
    """Each documented table's rows are its fields: the TOML key, "required" exactly for a
    field without a default, the bounds of ``num(...)`` and the choices of ``choice(...)``."""
    from softsensor.configfile import TOML_KEY

    for cf in config_reference.FILES:
        for table in cf.tables:
            cls = config_reference.resolve(table.cls)
            keys, subs = config_reference.table_keys(cls)
            rows = {k.key: k for k in keys}
            hints = typing.get_type_hints(cls)
            for f in dataclasses.fields(cls):
                if f.metadata.get("raw") or f.name in dict(subs):
                    continue
                row = rows[f.metadata.get(TOML_KEY, f.name)]
                required = (f.default is dataclasses.MISSING
                            and f.default_factory is dataclasses.MISSING)
                assert (row.default == "required") == required, (table.name, f.name, row)
                for bound in ("gt", "ge", "lt", "le"):
                    if bound in f.metadata:
                        assert f"{f.metadata[bound]:g}" in row.rules, (table.name, f.name, row)
                for option in f.metadata.get("one_of", ()):
                    assert f'"{option}"' in row.rules, (table.name, f.name, row)
                assert row.type, (table.name, f.name, hints[f.name])
            rst = "\n".join(config_reference.table_rst(table.name, cls, table.note))
            assert f"``[{table.name}]``" in rst


def _all_keys(config_reference) -> list[tuple[str, type, object]]:
    """``(dotted table, class, Key)`` of every key the reference renders, sub-tables too."""
    out = []

    def walk(name: str, cls: type, signal_units: bool) -> None:
        keys, subs = config_reference.table_keys(cls, signal_units)
        out.extend((name, cls, k) for k in keys)
        for sub_name, sub_cls in subs:
            walk(f"{name}.{sub_name}", sub_cls, False)

    for cf in config_reference.FILES:
        for table in cf.tables:
            walk(table.name, config_reference.resolve(table.cls), table.signal_units)
    return out


def test_every_key_has_a_meaning_and_a_unit(config_reference):
    """Issue 49: the reference had 385 keys, 93 without a meaning and 228 without a unit. Every
    key now says what it is and in what unit (``1`` a ratio, ``count`` a number of things,
    ``—`` no quantity), from its source or :data:`SUPPLEMENT`."""
    rows = _all_keys(config_reference)
    assert len(rows) > 300
    bare = [f"{name}.{k.key}: {'no meaning' if not k.description.strip() else ''} "
            f"{'no unit' if not k.unit.strip() else ''}"
            for name, _cls, k in rows if not (k.description.strip() and k.unit.strip())]
    assert not bare, ("keys without a meaning or a unit (say it in the class's Attributes "
                      f"section or the field's comment): {bare}")


def test_the_supplement_says_only_what_the_source_does_not(config_reference, monkeypatch):
    """:data:`SUPPLEMENT` fills what a key's source leaves unsaid; an entry for a key that is
    gone, or that repeats a unit or a meaning the source now gives, is refused (the two would
    drift apart)."""
    supplement = dict(config_reference.SUPPLEMENT)
    monkeypatch.setattr(config_reference, "SUPPLEMENT", {})
    own = {f"{cls.__qualname__}.{k.key}": k for _name, cls, k in _all_keys(config_reference)}
    gone = sorted(set(supplement) - set(own))
    assert not gone, f"SUPPLEMENT entries for keys that are not rendered: {gone}"
    redundant = []
    for key, (unit, meaning) in supplement.items():
        src = own[key]
        if unit and src.unit.strip() and src.unit != config_reference.NO_UNIT:
            redundant.append(f"{key}: unit {unit!r}, the source says {src.unit!r}")
        if meaning and src.description.strip():
            redundant.append(f"{key}: its meaning, the source says {src.description[:40]!r}")
    assert not redundant, redundant


@pytest.mark.parametrize(("text", "comment", "unit", "rest"), [
    ("Uncompressed MCAP chunk size of the recorder [bytes]", False, "bytes",
     "Uncompressed MCAP chunk size of the recorder"),
    ("m, inner", True, "m", "inner"),
    ("W/(m K)", True, "W/(m K)", ""),
    ("kg/m3", True, "kg/m3", ""),
    ("s between production changes", True, "s", "between production changes"),
    ("Chen's b [(kg/kg)^-c]", True, "(kg/kg)^-c", "Chen's b"),
    ("relative", True, "", "relative"),
    ("kg/m3 (steel 7850)", True, "kg/m3", "(steel 7850)"),
    ("Their default correlation times [h]. The calibration sets them", False, "h",
     "Their default correlation times [h]. The calibration sets them"),
    ("a table another part of the program builds", True, "", "a table another part of the "
     "program builds"),
])
def test_units_are_read_from_brackets_and_leading_unit_comments(config_reference, text,
                                                                   comment, unit, rest):
    assert config_reference.split_unit(text, from_comment=comment) == (unit, rest)


def test_the_config_page_renders_the_reference():
    page = (REPO / "docs" / "reference" / "config.rst").read_text(encoding="utf-8")
    assert re.search(r"^\.\. softsensor-config::$", page, re.M), page
