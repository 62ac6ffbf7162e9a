"""Every test that needs outside machinery carries its marker, so CI's second pytest call runs it
by name and the default suite leaves it out (``.ci/run``; the markers are registered in
``pyproject.toml``). A test needs a tool when its body, or a helper of its module that it calls,
starts the tool (headless Chromium, ``mbpoll``, the libmodbus C server, PostgreSQL's server
binaries, ``docker``)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent

#: marker -> what in a function's source says it starts that tool
NEEDS = {
    "chromium": re.compile(r"\bchromium_dom\b|\b(chromium|browser)\("),
    "mbpoll": re.compile(r"[\"']mbpoll[\"']"),
    "libmodbus": re.compile(r"\bc_server_binary\b|-lmodbus"),
    "postgresql": re.compile(r"\b(initdb|pg_ctl)\b"),
    "docker": re.compile(r"\.docker\(|[\"']docker[\"'],"),
}


def _marks(decorators: list[ast.expr]) -> set[str]:
    """The names ``X`` of ``@pytest.mark.X`` (called or not) among ``decorators``."""
    out = set()
    for d in decorators:
        d = d.func if isinstance(d, ast.Call) else d
        if isinstance(d, ast.Attribute) and ast.unparse(d.value) == "pytest.mark":
            out.add(d.attr)
    return out


def _module_marks(tree: ast.Module) -> set[str]:
    """The marks of a module-level ``pytestmark``."""
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "pytestmark" for t in node.targets):
            values = node.value.elts if isinstance(node.value, ast.List | ast.Tuple) \
                else [node.value]
            return _marks(values)
    return set()


def unmarked(path: Path) -> list[str]:
    """``test (marker)`` for each test of ``path`` that needs a tool without its marker."""
    text = path.read_text(encoding="utf-8")
    tree = ast.parse(text)
    functions = {n.name: n for n in tree.body
                 if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)}
    body = {name: ast.get_source_segment(text, fn) or "" for name, fn in functions.items()}
    # what each function needs, through the module's own helpers it calls (to a fixed point)
    needs = {name: {m for m, rx in NEEDS.items() if rx.search(src)} for name, src in body.items()}
    changed = True
    while changed:
        changed = False
        for name, src in body.items():
            for helper, wanted in needs.items():
                if helper != name and re.search(rf"\b{helper}\b", src) \
                        and not wanted <= needs[name]:
                    needs[name] |= wanted
                    changed = True
    module = _module_marks(tree)
    return [f"{name} ({m})" for name, fn in functions.items() if name.startswith("test_")
            for m in sorted(needs[name] - module - _marks(fn.decorator_list))]


@pytest.mark.parametrize("path", sorted(p for p in TESTS.rglob("test_*.py")
                                         if p != Path(__file__).resolve()),
                         ids=lambda p: str(p.relative_to(TESTS)))
def test_tests_that_need_outside_machinery_are_marked(path):
    assert unmarked(path) == []


def test_the_check_sees_a_tool_behind_a_helper(tmp_path):
    """The check itself: a Chromium test reached through a helper is caught, the marked one
    and a test that only names the tool in a string it compares are not."""
    p = tmp_path / "test_x.py"
    p.write_text("import pytest\n\n\ndef _dom(url):\n    return chromium_dom(url)\n\n\n"
                 "def test_a():\n    assert _dom('u')\n\n\n@pytest.mark.chromium\n"
                 "def test_b():\n    assert _dom('u')\n\n\n"
                 "def test_c():\n    assert 'mbpoll -m tcp'.startswith('mbpoll ')\n")
    assert unmarked(p) == ["test_a (chromium)"]
