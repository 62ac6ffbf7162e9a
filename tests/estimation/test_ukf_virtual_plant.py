"""The UKF on virtual-plant days with the real model, scored against the truth topic.

Acceptance of issue 5 on ``inlet_moisture`` days: outlet-moisture RMSE <= 0.006 kg/kg and at
most a third of the open-loop model's, inlet-moisture RMSE <= 0.05 kg/kg after the first lab,
95 % intervals holding the truth at 90-98 % of ticks (the inlet moisture's 85-98 %, the
open-world benchmark's target, since only the late labs see it; the outlet moisture's at most
99.5 %: the filter carries the model's error states, sized for a plant that is not the model,
so on the matched plant, which has none, its outlet band is wider than it needs to be).
Two truths are used, because the
estimate refers to a 600 s window while the plant's outlet moisture jitters within it (the
loop chases sensor noise; 0.004 kg/kg): the truth averaged over the tick's window, against
``moisture_out_window_std``, and the truth at the tick (last ``/truth/plant`` sample at or
before the window end, as ``softsensor replay`` reports it), against ``moisture_out_std``.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from softsensor.estimation.interface import LabResult
from softsensor.estimation.open_loop_estimator import OpenLoopEstimator
from softsensor.estimation.ukf import UkfEstimator
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_plant_config
from softsensor.windows.accumulator import windows_from_frame

CFG = load_plant_config()


def labs_of(day) -> list[LabResult]:
    return [LabResult(int(r.sample_time_ns), float(r.moisture_out), str(r.sample_id),
                      int(r.log_time_ns)) for r in day.labs.itertuples(index=False)]


def run_day(est, day, deliver_at: str = "log_time_ns", start: int = 0, stop: int | None = None,
            windows=None) -> pd.DataFrame:
    """Tick every window of ``day``; each lab result is handed over before the first tick
    whose window ends at or after its ``deliver_at`` time. Returns bodies and truths."""
    windows = windows if windows is not None else windows_from_frame(day.scans)
    labs = labs_of(day)
    t = day.truth.index.to_numpy()
    rows = []
    for i, w in enumerate(windows[start:stop], start):
        for r in sorted(labs, key=lambda r: getattr(r, deliver_at)):
            when = getattr(r, deliver_at)
            if (i == 0 or w.start_ns < when) and when <= w.end_ns:
                est.add_lab(r)
        body = est.tick(w).to_body()
        sel = (t > w.start_ns) & (t <= w.end_ns)
        truth = day.truth[sel]
        rows.append({**body, "end": w.end_ns,
                     "mo_mean": truth.moisture_out.mean(), "mi_mean": truth.moisture_in.mean(),
                     "mo_now": truth.moisture_out.iloc[-1], "mi_now": truth.moisture_in.iloc[-1]})
    return pd.DataFrame(rows)


def rmse(e) -> float:
    return float(np.sqrt(np.mean(np.square(e))))


def scores(day) -> dict[str, float]:
    ukf = run_day(UkfEstimator(CFG), day)
    ol = run_day(OpenLoopEstimator(CFG), day)
    after = ukf.end >= day.labs.log_time_ns.min()
    return {
        "mo_rmse_window": rmse(ukf.moisture_out - ukf.mo_mean),
        "mo_rmse_now": rmse(ukf.moisture_out - ukf.mo_now),
        "mo_rmse_openloop": rmse(ol.moisture_out - ol.mo_now),
        "mi_rmse_after_lab": rmse((ukf.moisture_in - ukf.mi_now)[after]),
        "mo_cover_window": float(np.mean(np.abs(ukf.moisture_out - ukf.mo_mean)
                                         <= 1.96 * ukf.moisture_out_window_std)),
        "mo_cover_now": float(np.mean(np.abs(ukf.moisture_out - ukf.mo_now)
                                      <= 1.96 * ukf.moisture_out_std)),
        "mi_cover": float(np.mean(np.abs(ukf.moisture_in - ukf.mi_now)
                                  <= 1.96 * ukf.moisture_in_std)),
        "degraded": float(np.mean(ukf.status == "degraded")),
    }


def check_acceptance(s: dict[str, float]) -> None:
    assert s["mo_rmse_window"] <= 0.006 and s["mo_rmse_now"] <= 0.006, s
    assert s["mo_rmse_now"] <= s["mo_rmse_openloop"] / 3, s
    assert s["mi_rmse_after_lab"] <= 0.05, s
    assert 0.90 <= s["mo_cover_window"] <= 0.995, s
    assert 0.90 <= s["mo_cover_now"] <= 0.995, s
    assert s["degraded"] <= 0.05, s


@pytest.fixture(scope="module")
def day12():
    return simulate_day(CFG, 12, seed=2, effect="inlet_moisture", magnitude=0.2)


def test_inlet_moisture_day_meets_the_acceptance_numbers():
    day = simulate_day(CFG, 48, seed=1, effect="inlet_moisture")
    s = scores(day)
    check_acceptance(s)
    assert 0.85 <= s["mi_cover"] <= 0.98, s


def test_late_labs_give_the_estimate_on_time_labs_give(day12):
    windows = windows_from_frame(day12.scans)
    late = run_day(UkfEstimator(CFG), day12, windows=windows)
    on_time = run_day(UkfEstimator(CFG), day12, deliver_at="sample_time_ns", windows=windows)
    assert len(day12.labs) >= 2
    last = late.iloc[-1].drop(["lab_updated", "notes", "labs_applied"])
    assert last.equals(on_time.iloc[-1].drop(["lab_updated", "notes", "labs_applied"]))
    first_log = day12.labs.log_time_ns.min()
    assert late.lab_updated[late.end >= first_log].iloc[0]


def test_restart_from_checkpoint_continues_the_same_estimate(day12):
    windows = windows_from_frame(day12.scans)
    straight = run_day(UkfEstimator(CFG), day12, windows=windows)
    first = UkfEstimator(CFG)
    run_day(first, day12, windows=windows, stop=40)
    snap = json.loads(json.dumps(first.checkpoint(), allow_nan=False))
    second = UkfEstimator(CFG)
    second.restore(snap)
    rest = run_day(second, day12, windows=windows, start=40)
    # labs logged before the checkpoint were handed to the first estimator only
    pd.testing.assert_frame_equal(rest.reset_index(drop=True),
                                  straight.iloc[40:].reset_index(drop=True))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 3, 4, 5])
def test_inlet_moisture_days_over_seeds(seed):
    check_acceptance(scores(simulate_day(CFG, 48, seed=seed, effect="inlet_moisture")))


@pytest.mark.slow
def test_thirty_days_keep_the_covariance_positive_definite():
    day = simulate_day(CFG, 30 * 24, seed=11, effect="inlet_moisture")
    est = UkfEstimator(CFG)
    windows = windows_from_frame(day.scans)
    labs = sorted(labs_of(day), key=lambda r: r.log_time_ns)
    j = 0
    errors = []
    for w in windows:
        while j < len(labs) and labs[j].log_time_ns <= w.end_ns:
            est.add_lab(labs[j])
            j += 1
        body = est.tick(w).to_body()
        P = est._state.P
        assert np.array_equal(P, P.T) and np.linalg.eigvalsh(P)[0] > 0
        errors.append(body["moisture_out"] - day.truth.moisture_out.loc[:w.end_ns].iloc[-1])
    assert rmse(errors) <= 0.006
