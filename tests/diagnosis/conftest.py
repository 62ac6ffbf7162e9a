"""Fixtures of the diagnosis tests: the clean 14 h virtual-plant day of the reference plant
(``clean_14h_day`` of ``tests/conftest.py``) that the tests of the windows, the problem, the
residual statistics, the extensions and the verdict read as ``day``."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def day(clean_14h_day):
    return clean_14h_day
