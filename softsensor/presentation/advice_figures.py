"""The what-if's figure: the set point as run and advised, the outlet moisture as estimated
and as predicted with the advice, and the heat saved, hour by hour.

One PNG (matplotlib, Agg backend, no display needed). Refused hours are marked and keep
the set point as run.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from softsensor.advisor.advice import Advice, Situation  # noqa: E402
from softsensor.advisor.settings import AdvisorSettings  # noqa: E402


def what_if_figure(advices: Sequence[Advice], sits: Sequence[Situation],
                   cfg: AdvisorSettings, path: str | Path) -> Path:
    """Write the what-if figure to ``path`` (PNG) and return it."""
    t = [datetime.fromtimestamp(s.time_ns / 1e9, UTC) for s in sits]
    sp = [s.inputs.get("T_sp") for s in sits]
    adv = [a.T_sp_advised if a.advised else None for a in advices]
    fig, ax = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    ax[0].step(t, sp, where="post", color="0.4", label="T_sp as run")
    ax[0].plot([x for x, a in zip(t, adv, strict=True) if a is not None],
               [a for a in adv if a is not None], "o", color="C0", ms=4, label="advised")
    refused = [x for x, a in zip(t, advices, strict=True) if not a.advised]
    for x in refused:
        ax[0].axvline(x, color="C3", alpha=0.15, lw=3)
    ax[0].set_ylabel("T_sp [K]")
    ax[0].legend(loc="best", fontsize=8)
    ax[0].set_title(f"advice hour by hour ({len(refused)} of {len(advices)} refused: red bands)")
    m_est = [s.moisture_out for s in sits]
    ax[1].plot(t, m_est, color="0.4", label="estimate as run")
    pts = [(x, a) for x, a in zip(t, advices, strict=True) if a.advised]
    if pts:
        ax[1].errorbar([x for x, _ in pts], [a.moisture_out_advised for _, a in pts],
                       yerr=[a.moisture_out_advised_std for _, a in pts], fmt="o", ms=4,
                       color="C0", label="predicted with the advice (+-1 sd)")
    ax[1].axhline(cfg.moisture_target, color="C2", ls="--", label="target")
    ax[1].axhline(cfg.moisture_max, color="C3", ls="--", label="limit")
    ax[1].set_ylabel("moisture_out [kg/kg]")
    ax[1].legend(loc="best", fontsize=8)
    ax[2].bar([x for x, _ in pts], [a.saving_kwh_per_t for _, a in pts], width=0.03,
              color=["C2" if a.saving_kwh_per_t >= 0 else "C3" for _, a in pts])
    ax[2].axhline(0, color="0.3", lw=0.8)
    ax[2].set_ylabel("heat saved [kWh/t]")
    ax[2].set_xlabel("time (UTC)")
    fig.autofmt_xdate()
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


__all__ = ["what_if_figure"]
