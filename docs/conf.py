"""Sphinx configuration of the softsensor documentation site.

Built by ``.ci/run`` (and ``tests/docs/test_site_builds.py``) with warnings as errors:

    .venv/bin/sphinx-build -W --keep-going -b html docs docs/_build/html

The reference is generated at build time from the package itself: the API pages from the
numpydoc docstrings (autosummary, recursive, one page per module under
``reference/generated/``, not committed), the command line from the parsers
(``_ext/cli_reference.py``) and the configuration tables from their dataclasses
(``_ext/config_reference.py``).
"""

from __future__ import annotations

import importlib
import sys
import types
from pathlib import Path

DOCS = Path(__file__).resolve().parent
REPO = DOCS.parent
# the package from this checkout, whatever is installed; and the site's own extensions
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(DOCS / "_ext"))

# The API pages are generated afresh every build: a page left from a module that was renamed
# would be built too (an orphan, and the module documented twice).
import shutil  # noqa: E402

from sphinx.util.nodes import make_refnode  # noqa: E402

import softsensor  # noqa: E402

shutil.rmtree(DOCS / "reference" / "generated", ignore_errors=True)

project = "softsensor"
author = "the softsensor authors"
copyright = "the softsensor authors, MIT licence"
release = version = softsensor.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_parser",
    "cli_reference",
    "config_reference",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
# reference/CONTRACT.md is the verbatim copy of shared/CONTRACT.md, included by
# reference/contract.md (which says what it is), not a page of its own
exclude_patterns = ["_build", "_templates", "grafana", "reference/CONTRACT.md"]
templates_path = ["_templates"]
# code blocks say their language; an indented block is plain text, never lexed as Python
highlight_language = "text"

# -- Markdown (myst-parser) ------------------------------------------------------------------
# dollarmath: the model page writes its equations as $...$ and $$...$$; colon_fence: notes
# and admonitions in Markdown; heading anchors so that a page can link to another's section
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# -- API reference (autosummary + autodoc + numpydoc) -----------------------------------------
autosummary_generate = True
autosummary_imported_members = False
# every public member defined in a module, whether or not the module's ``__all__`` names it
# (``__all__`` says what ``import *`` gives, not what a reader may look up)
autodoc_default_options = {"members": True, "undoc-members": True, "ignore-module-all": True,
                           "member-order": "bysource"}
# the types are in the numpydoc sections, with their units; signatures stay readable
autodoc_typehints = "none"
autodoc_member_order = "bysource"
# numpydoc's per-class member tables would need a stub page per method: the module page
# documents the methods already
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_attributes_as_param_list = True

# A reference to a softsensor object that does not exist (a module renamed, a function gone)
# is an error: nitpicky for the package's own names. Names outside the package (numpy, the
# standard library, zenoh, ...) are not resolvable offline (no intersphinx: CI has no
# network) and are not checked.
nitpicky = True
# reference/CONTRACT.md is a verbatim copy whose JSON example holds "..." (not valid JSON): a
# code block that cannot be highlighted is shown plain, not an error
suppress_warnings = ["misc.highlighting_failure"]
#: Packages and modules outside softsensor whose names the docstrings cite: not checked. Any
#: other name is (a bare ``LivePage.add_estimate`` is looked up in its module's context), so
#: a method or function renamed without its references fails the build.
OUTSIDE = ("numpy", "np", "scipy", "pandas", "pd", "numba", "zenoh", "optuna", "asyncua", "ua",
           "pymodbus", "mcap", "matplotlib", "pint", "filterpy", "prometheus_client", "psycopg",
           "sqlalchemy", "tomllib", "tomli_w", "typing", "collections", "pathlib", "os",
           "asyncio", "threading", "logging", "datetime", "dataclasses", "json", "socket",
           "enum", "re", "io", "math", "subprocess", "concurrent", "queue", "contextlib",
           "functools", "itertools", "types", "argparse", "signal", "time", "tempfile",
           "secrets", "zoneinfo", "statistics", "hashlib", "struct", "http", "urllib",
           "selectors", "sys", "platform", "shutil", "traceback", "inspect", "warnings",
           "int", "float", "str", "bool", "bytes", "dict", "list", "tuple", "set", "None",
           "object", "type", "callable", "Exception", "ValueError", "TypeError", "KeyError",
           "OSError", "RuntimeError", "ArithmeticError", "TimeoutError", "KeyboardInterrupt")
nitpick_ignore_regex = [
    (r"py:.*", rf"(?:{'|'.join(OUTSIDE)})(?:\..*)?"),
]

# -- HTML ------------------------------------------------------------------------------------
html_theme = "pydata_sphinx_theme"
html_title = f"softsensor {release}"
html_static_path = []
# the left bar shows the current section two levels deep, collapsed: rendering the whole
# toctree (160 module pages) into every page was most of the build's time
html_theme_options = {
    "navigation_depth": 2,
    "collapse_navigation": True,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": [],
}
html_sidebars = {"**": ["sidebar-nav-bs"]}
html_show_sourcelink = False


# A role whose dotted target the source wraps after a dot (``:class:`~softsensor.estimation.``
# at a line's end, ``model_error.ModelError``` on the next) reads as one name in the source;
# reST would see a space in it. Joined before the docstring is parsed.
from config_reference import WRAPPED_TARGET  # noqa: E402  (docs/_ext, on the path above)


def _join_wrapped_targets(app, what, name, obj, options, lines):
    text = "\n".join(lines)
    joined = WRAPPED_TARGET.sub(r"\1", text)
    if joined != text:
        lines[:] = joined.split("\n")


def _find(target: str):
    """The object a dotted ``target`` names, and the module that holds it, or None."""
    parts = target.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = module = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        try:
            for name in parts[cut:]:
                obj = getattr(obj, name)
        except AttributeError:
            return None
        return obj, module
    return None


def _resolve_existing(app, env, node, contnode):
    """A Python reference to a name that exists in the package but is documented elsewhere
    (a class re-exported by its package, ``softsensor.model.DryerModel``) or not at all (a
    module constant without a doc comment) links to where it is defined, or to its module's
    page. A name that does not exist (a module renamed, a function removed) is left missing,
    and the nitpicky build fails on it."""
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip("~.")
    context = node.get("py:module") or ""
    candidates = [target] if target.startswith("softsensor") else []
    while context and not target.startswith("softsensor"):
        candidates.append(f"{context}.{target}")
        context = context.rpartition(".")[0]
    py = env.get_domain("py")
    for name in candidates:
        found = _find(name)
        if found is None:
            continue
        obj, module = found
        canonical = (f"{obj.__module__}.{obj.__qualname__}"
                     if hasattr(obj, "__qualname__") and hasattr(obj, "__module__") else name)
        entry = py.objects.get(canonical)
        if entry is not None:
            return make_refnode(app.builder, node["refdoc"], entry.docname, entry.node_id,
                                contnode, canonical)
        mod = py.modules.get(module.__name__)
        if mod is not None:
            return make_refnode(app.builder, node["refdoc"], mod.docname, mod.node_id,
                                contnode, name)
    return None


def _skip_type_aliases(app, what, name, obj, skip, options):
    """A module-level type alias (``KnobSchedule = tuple[np.ndarray, ...]``) is not a class:
    autodoc would try to give it a class signature. It is read where it is used."""
    if isinstance(obj, types.GenericAlias):
        return True
    return None


def setup(app):
    app.connect("autodoc-process-docstring", _join_wrapped_targets)
    app.connect("autodoc-skip-member", _skip_type_aliases)
    app.connect("missing-reference", _resolve_existing)
