"""The one JSON converter: numpy values and NaN/inf become what ``allow_nan=False`` accepts."""

import json
import math

import numpy as np

from softsensor.jsonable import jsonable
from softsensor.recording.mcap_day import encode_body


def test_numpy_and_non_finite_values_become_plain_json():
    doc = {1: np.float32(np.inf), "a": np.array([[1.5, np.nan], [np.float64(2), -np.inf]]),
           "t": (np.int16(4), np.bool_(False), math.nan), "s": "x", "n": None,
           "f": np.float64(0.25)}
    out = jsonable(doc)
    assert out == {"1": None, "a": [[1.5, None], [2.0, None]], "t": [4, False, None],
                   "s": "x", "n": None, "f": 0.25}
    assert type(out["t"][0]) is int and type(out["t"][1]) is bool and type(out["f"]) is float
    json.dumps(out, allow_nan=False)


def test_recorder_encodes_through_the_same_converter():
    body = {"x": np.array([1.0, np.nan]), "y": np.float32(np.nan), "k": np.int64(7)}
    assert json.loads(encode_body(body)) == jsonable(body) == {"x": [1.0, None], "y": None,
                                                              "k": 7}
