"""One JSON converter for bus bodies, MCAP messages and reports: strict JSON out of numpy."""

from __future__ import annotations

import json
import math

import numpy as np

from softsensor.jsonable import dumps, jsonable
from softsensor.messages import encode_body


def test_numpy_and_non_finite_values_become_plain_json():
    body = {"a": np.float32(1.5), "b": np.array([1.0, np.nan, np.inf]), "c": np.int64(7),
            "d": (np.bool_(True), -math.inf), 3: {"e": np.array([[1, 2], [3, 4]])}}
    want = {"a": 1.5, "b": [1.0, None, None], "c": 7, "d": [True, None],
            "3": {"e": [[1, 2], [3, 4]]}}
    assert jsonable(body) == want
    assert json.loads(dumps(body)) == want
    assert json.loads(encode_body(body)) == want
    assert type(jsonable(np.int64(7))) is int and type(jsonable(np.bool_(False))) is bool


def test_compact_on_the_wire_indented_for_people():
    assert encode_body({"x": 1, "y": [1, 2]}) == b'{"x":1,"y":[1,2]}'
    assert dumps({"x": 1}, indent=2) == '{\n  "x": 1\n}'


def test_times_read_as_utc_seconds():
    from softsensor.messages import iso_utc

    assert iso_utc(1_767_571_200_999_999_999) == "2026-01-05T00:00:00Z"  # truncated, not rounded
    assert iso_utc(-1) == "1969-12-31T23:59:59Z"
