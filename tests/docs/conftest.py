"""The documentation site's own extensions (``docs/_ext``), importable by the tests."""

from __future__ import annotations

from types import ModuleType

import pytest
from paths import REPO
from script_modules import load_script

EXT = REPO / "docs" / "_ext"


def load_extension(name: str) -> ModuleType:
    """``docs/_ext/<name>.py`` as a module (it is not part of the package)."""
    pytest.importorskip("sphinx", reason="the docs extra is not installed "
                        "(pip install -e '.[docs]')")
    return load_script(EXT / f"{name}.py")


@pytest.fixture(scope="module")
def config_reference() -> ModuleType:
    return load_extension("config_reference")


@pytest.fixture(scope="module")
def cli_reference() -> ModuleType:
    return load_extension("cli_reference")
