"""The model's outputs on fixed inputs, bit for bit (``tests/support/model_digest.py``).

A refactoring of the compiled model must not move one bit of what it returns; a change that
does fails here. When the physics or the solver changes on purpose, regenerate the stored
digest with ``.venv/bin/python tests/support/model_digest.py --write`` and say in the commit why the
numbers moved.
"""

from __future__ import annotations

import json

import model_digest as md
import numpy as np


def test_model_outputs_are_bit_identical_to_the_stored_digest():
    stored = json.loads(md.STORED.read_text())
    outputs = md.model_outputs()
    now = md.samples(outputs)
    # how far the samples moved: round-off (another CPU or libm) or a real change
    moved = {k: float(np.max(np.abs(np.subtract(now[k], v)) / np.maximum(np.abs(v), 1e-300)))
             for k, v in stored["samples"].items()}
    assert md.digest(outputs) == stored["sha256"], (
        f"the model's outputs changed (largest relative change of the stored samples: {moved});"
        " if on purpose, run `python tests/support/model_digest.py --write`")
