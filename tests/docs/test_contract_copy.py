"""The site's contract page is the project's contract, verbatim.

``docs/reference/CONTRACT.md`` is a copy of ``shared/CONTRACT.md`` (the repository stands alone,
so the site carries it); the copy must not drift from the original wherever the original is
beside the repository (the project's checkout and CI lay ``shared/`` there).
"""

from __future__ import annotations

import pytest
from paths import REPO, SHARED

COPY = REPO / "docs" / "reference" / "CONTRACT.md"
ORIGINAL = SHARED / "CONTRACT.md"


def test_the_site_carries_the_contract_and_includes_it():
    assert COPY.is_file(), COPY
    page = (REPO / "docs" / "reference" / "contract.md").read_text(encoding="utf-8")
    assert "```{include} CONTRACT.md" in page, "reference/contract.md no longer includes the copy"


@pytest.mark.skipif(not ORIGINAL.is_file(),
                    reason=f"no {ORIGINAL} beside the repository to compare the copy with")
def test_the_copy_equals_the_shared_contract():
    assert COPY.read_bytes() == ORIGINAL.read_bytes(), (
        f"{COPY} differs from {ORIGINAL}: copy the contract again (cp {ORIGINAL} {COPY})")
