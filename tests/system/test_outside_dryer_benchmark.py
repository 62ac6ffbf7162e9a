"""The sister dryer's benchmark (``benchmarks/outside_dryer.py``): every lab scored against
what each method had published before the result arrived.

On a hand-made stream whose answers are known: the sensor's estimate is the one for the
window holding the sample time, published before the arrival; the hold is the latest result
arrived by then (by sample time); the regression adds the mean residual of the last three
arrived results; a result arriving before its window's estimate falls back to the latest
estimate published before it.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from paths import REPO
from script_modules import load_script

bench = load_script(REPO / "benchmarks" / "outside_dryer.py")
W = 600 * 10**9


def _estimates(n: int) -> pd.DataFrame:
    k = np.arange(n)
    return pd.DataFrame({"log_time_ns": (k + 1) * W, "start": k * W, "end": (k + 1) * W,
                         "moisture_out": 0.10 + 0.001 * k, "moisture_out_std": 0.005,
                         "moisture_in": 1.0, "moisture_in_std": 0.05,
                         "physics": 0.20 + 0.001 * k})


def test_each_method_knows_only_what_had_arrived():
    est = _estimates(20)
    # (sample, arrival, lab, regression at the sample without its bias)
    labs = pd.DataFrame({"period": 0,
                         "sample_ns": [W // 2, 3 * W + W // 2, 5 * W + W // 2, 9 * W + 1,
                                       12 * W + 5],
                         "arrival_ns": [4 * W, 7 * W, 9 * W, 13 * W, 12 * W + 9],
                         "lab": [0.11, 0.12, 0.13, 0.14, 0.15],
                         "reg_raw": [0.10, 0.10, 0.10, 0.10, 0.10]})
    s = bench.score_labs(labs, est, est)
    assert np.allclose(s["sensor"][:4], [0.100, 0.103, 0.105, 0.109], rtol=0, atol=1e-12)
    assert math.isnan(s["hold"][0]) and s["hold"][1] == 0.11
    # at the third sample's estimate (published at 6 W) only the first had arrived
    assert s["hold"][2] == 0.11
    # the fourth: published 10 W, the first three arrived; bias = mean(0.01, 0.02, 0.03)
    assert s["hold"][3] == 0.13 and math.isclose(s["regression"][3], 0.12, abs_tol=1e-12)
    # the fifth arrived (12 W + 9) before its window's estimate (13 W): the latest before it
    assert math.isclose(s["sensor"][4], 0.10 + 0.001 * 11, abs_tol=1e-12)
    pooled = bench.summarise(s[np.isfinite(s["hold"])])
    assert pooled["n_labs"] == 4 and 0 <= pooled["band_coverage"] <= 1
    assert pooled["better_peer"] in ("hold", "regression")
