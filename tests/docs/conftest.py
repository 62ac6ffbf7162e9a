"""The documentation site's own extensions (``docs/_ext``), importable by the tests."""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType

import pytest
from paths import REPO

EXT = REPO / "docs" / "_ext"


def load_extension(name: str) -> ModuleType:
    """``docs/_ext/<name>.py`` as a module (it is not part of the package)."""
    pytest.importorskip("sphinx", reason="the docs extra is not installed "
                        "(pip install -e '.[docs]')")
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, EXT / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def config_reference() -> ModuleType:
    return load_extension("config_reference")


@pytest.fixture(scope="module")
def cli_reference() -> ModuleType:
    return load_extension("cli_reference")
