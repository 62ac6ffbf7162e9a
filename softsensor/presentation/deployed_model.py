"""What a calibration from history deploys, described as itself (issue 49).

``calibrate`` fits the paper's form in its study, then may keep the current parameters (they
predict the held-out hours better) or adopt a structural alternative
(:mod:`softsensor.calibration.structure_search`) with its own parameters. PARAMS.toml, the
verb's last line and the ``--report`` page must then describe the model deployed, not the
study's fit: its held-out errors beside the current parameters', its parameters at a search
bound, its identifiability, its trajectories. :func:`deployed_model` gathers these;
:meth:`DeployedModel.fit_table` is PARAMS.toml's ``[fit.deployed]``, which the page's
headline, front marker and error table read back from the file.

For the study's own parameters in the paper's form (the usual case) everything is the
study's result, computed once. For the current parameters kept, or an alternative adopted,
the model deployed is run once more on the fit windows (the figures) and, unless
``--no-identify``, analysed once more (:func:`~softsensor.calibration.identifiability.
identify` at its own structure and parameters: the identifiability of the study's form says
nothing of another drying law's parameters).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from softsensor.calibration.calibration_run import at_bounds, search_model
from softsensor.calibration.chunked_run import ChunkedRun
from softsensor.calibration.identifiability import Identifiability, identify
from softsensor.calibration.settings import CalibrationSettings
from softsensor.model import DryerModel
from softsensor.plantconfig import PlantConfig
from softsensor.signals import OUTPUT_NAMES

#: ``[fit.deployed] structure`` when the paper's form is deployed.
PAPER_FORM = "paper's form"


@dataclass
class DeployedModel:
    """The model PARAMS.toml deploys (module docstring).

    ``config``: the plant config with the deployed structure's keys; ``theta``: its
    parameters; ``structure``: the adopted alternative's name or :data:`PAPER_FORM`;
    ``parameters``: ``"calibrated"`` or ``"current"`` (kept); ``where``: the data its errors
    are on (``"held-out data"``, or ``"calibration data"`` when nothing was held out);
    ``rmse`` and ``open_loop_rmse``: its errors there (the inlet read from the
    temperatures, and open loop) [K, kg/kg]; ``current_rmse``: the current parameters' on the
    same data; ``identifiability``, ``sensitivities`` and ``runs``: its own analysis and
    model lines on the fit windows (None when not computed).
    """

    config: PlantConfig
    theta: np.ndarray
    structure: str
    parameters: str
    where: str
    rmse: dict[str, float] | None
    open_loop_rmse: dict[str, float] | None
    current_rmse: dict[str, float] | None
    at_bounds: list[str]
    identifiability: Identifiability | None
    sensitivities: list[Any] | None
    runs: list[Any] | None

    @property
    def verdicts(self) -> dict[str, str] | None:
        """Each parameter's identifiability verdict (None when not analysed)."""
        if self.identifiability is None:
            return None
        return {v.name: v.verdict for v in self.identifiability.verdicts}

    def fit_table(self) -> dict[str, Any]:
        """PARAMS.toml's ``[fit.deployed]``: what the page's headline and front read."""
        out: dict[str, Any] = {"structure": self.structure, "parameters": self.parameters,
                               "where": self.where, "at_bounds": list(self.at_bounds)}
        for key in ("rmse", "open_loop_rmse", "current_rmse"):
            value = getattr(self, key)
            if value is not None:
                out[key] = {n: float(value[n]) for n in OUTPUT_NAMES}
        if self.identifiability is not None:
            out["identifiable"] = self.identifiability.identifiable
            out["poorly_identifiable"] = self.identifiability.poorly_identifiable
        return out


def _rmse(fit: Any) -> dict[str, float]:
    return {n: float(fit.rmse[n]) for n in OUTPUT_NAMES}


def deployed_model(hist: Any, base: PlantConfig, calibration: CalibrationSettings,
                   identify_result: bool = True) -> DeployedModel:
    """The model a :class:`~softsensor.calibration.history_calibration.HistoryResult`
    deploys (module docstring); ``base``: the plant config the study ran on."""
    result = hist.calibration
    adopted = None if hist.structure is None else hist.structure.adopted
    config = base if adopted is None else base.with_keys(adopted.keys)
    theta = np.asarray(hist.theta, float)
    val, cur_val = result.validation, result.current_validation
    where = "held-out data" if val is not None and cur_val is not None else "calibration data"
    current = (_rmse(cur_val.fit) if where == "held-out data" else
               None if result.current_evaluation is None else _rmse(result.current_evaluation.fit))
    flags = at_bounds(theta, config.bounds(), calibration.bound_margin)
    if adopted is None and not hist.kept_current:  # the study's own parameters and form
        held = where == "held-out data"
        rmse = _rmse(val.fit) if held else _rmse(result.fit)
        open_loop = _rmse((val.evaluation if held else result.evaluation).open_fit)
        return DeployedModel(config, theta, PAPER_FORM, "calibrated", where, rmse, open_loop,
                             current, flags, result.identifiability, result.sensitivities,
                             result.runs)
    if adopted is not None:
        rmse, open_loop = dict(adopted.held_out) or None, dict(adopted.open_loop) or None
    else:  # the current parameters, kept
        rmse = current
        open_loop = (_rmse(cur_val.evaluation.open_fit) if where == "held-out data" else
                     None if result.current_evaluation is None
                     else _rmse(result.current_evaluation.open_fit))
    model = DryerModel(config)
    run = ChunkedRun(model, result.segments, theta[None], result.spec, n_chunks=1)
    runs = run.model_lines(0, run.run()[0])
    ident = sens = None
    if identify_result:
        ident, sens = identify(model, result.segments, theta, result.spec, config.bounds(),
                               jac_model=search_model(model, calibration))
    return DeployedModel(config, theta, PAPER_FORM if adopted is None
                         else adopted.candidate.name,
                         "current" if hist.kept_current else "calibrated", where, rmse,
                         open_loop, current, flags, ident, sens, runs)


__all__ = ["PAPER_FORM", "DeployedModel", "deployed_model"]
