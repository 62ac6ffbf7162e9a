"""One estimate body as the estimator publishes it, and its window end, for the tests of the
operator outputs (Modbus registers, Prometheus metrics)."""

from __future__ import annotations

from softsensor.estimate import Estimate

#: Degraded, a lab result just applied; the outlet in kg/kg dry basis.
BODY = {"moisture_out": 0.1034, "moisture_out_std": 0.0042, "moisture_in": 1.0312,
        "moisture_in_std": 0.021, "status": "degraded", "lab_updated": True}
#: The estimate's window end.
T_NS = 1_767_607_800 * 10**9  # 2026-01-05T10:10:00Z
#: The same as the estimator hands it to the outputs.
ESTIMATE = Estimate.from_body({**BODY, "window_end_ns": T_NS})


__all__ = ["BODY", "ESTIMATE", "T_NS"]
