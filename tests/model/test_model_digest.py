"""The model's outputs on fixed inputs against stored numbers (``tests/support/model_digest.py``).

A refactoring of the compiled model must not move what it returns; a change that does fails
here. The reference is compared within 1e-9 relative (``tests/support/stored_numbers.py``):
another machine's compiled code differs in the last bits, the physics does not. When the
physics or the solver changes on purpose, regenerate the stored numbers with
``.venv/bin/python tests/support/model_digest.py --write`` and say in the commit why the
numbers moved.
"""

from __future__ import annotations

import json

import model_digest as md
from stored_numbers import differences


def test_model_outputs_match_the_stored_numbers():
    stored = json.loads(md.STORED.read_text())
    moved = differences(md.numbers(md.model_outputs()), stored["numbers"])
    assert not moved, ("the model's outputs changed: " + "; ".join(moved)
                       + "; if on purpose, run `python tests/support/model_digest.py --write`")
