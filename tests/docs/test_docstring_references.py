"""Every package-relative reference in a docstring (``:mod:`.verdict```,
``:func:`~.day_windows.delagged_air```) names something that exists.

The site's build fails on a ``softsensor.*`` reference to a name that is gone, but Sphinx
resolves a name that starts with a dot by a fuzzy search: ``:mod:`.export``` linked to
whatever ended in ``export`` after the module it meant was renamed. So these are checked here,
relative to the module that writes them and to its package, as Python resolves them.
"""

from __future__ import annotations

import importlib
import re

from paths import REPO

ROLE = re.compile(r":(?:mod|func|class|data|meth|attr|exc|obj):`~?\.([\w.]+)`")


def _exists(dotted: str) -> bool:
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        try:
            for name in parts[cut:]:
                obj = getattr(obj, name)
        except AttributeError:
            return False
        return True
    return False


def test_every_relative_reference_names_something_that_exists():
    missing = []
    for path in sorted((REPO / "softsensor").rglob("*.py")):
        module = ".".join(path.relative_to(REPO).with_suffix("").parts)
        package = module.removesuffix(".__init__") if path.name == "__init__.py" \
            else module.rpartition(".")[0]
        module = module.removesuffix(".__init__")
        text = path.read_text(encoding="utf-8")
        for m in ROLE.finditer(text):
            if not any(_exists(f"{base}.{m.group(1)}") for base in (module, package)):
                line = text.count("\n", 0, m.start()) + 1
                missing.append(f"{path.relative_to(REPO)}:{line}: {m.group(0)}")
    assert not missing, "references to names that do not exist:\n" + "\n".join(missing)
