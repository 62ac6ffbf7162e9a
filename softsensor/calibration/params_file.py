"""``PARAMS.toml``: a calibrated parameter set with its bounds and how well it fits.

Layout (loadable by :func:`softsensor.plantconfig.load_parameters`, which reads the
``[parameters.<name>]`` tables)::

    [parameters.mult_D]        one table per Table 1 parameter
    value = 0.7012
    low = 0.01                 the bounds searched
    high = 5.0
    log = true
    verdict = "identifiable"   when an identifiability analysis ran (of the model deployed)
    at_bound = true            when the value ended within the bound margin (flagged)

    [fit]                      the study's (paper's form): objective, cost kind, trials, seed,
                               data, chosen window(s) and why, its parameters at a bound,
                               validation against the current ones
    [fit.deployed_model]       the model this file deploys (structure, which parameters, its
                               held-out RMSE, open loop and the current ones' on the same
                               data, its bound flags and identifiability), which the report
                               page reads (:mod:`softsensor.presentation.deployed_model`)
    [fit.rmse]                 per channel: T_dryer_out [K], T_cyclone_out [K],
                               moisture_out [kg/kg]
    [fit.weighted_rmse]        WF_m * RMSE_m, the numbers the paper quotes
    [fit.weights]              the eq. 4 weights used
    [fit.samples]              samples per channel
    [structure]                a structural alternative adopted from history (plant-section
    [structure.fiber]          keys such as fiber.bound_fraction, applied on load) and
    [structure.evidence]       the held-out evidence for it (:mod:`.structure_search`)
    [discrepancy]              what the model leaves on held-out data (the estimator's prior
                               on its own error, :class:`~softsensor.plantconfig.DiscrepancyPrior`)
    [model_error]              what the history says the model misses, channel by channel
                               (:class:`~softsensor.estimation.model_error.ModelError`): the
                               features and their scales, the days and the typical inlet
    [model_error.T_dryer_out]  moisture; per channel the discrepancy's slopes and their
    ...                        covariance, the day offsets' mean and spread, the within-day
                               walk and noise, and the held-out RMSE with and without it

Python's standard library reads TOML but does not write it; :func:`dumps` writes it with
``tomli-w``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import tomli_w

from softsensor.configfile import read_toml
from softsensor.errors import ConfigError
from softsensor.files import replace_file
from softsensor.plantconfig import PARAMETER_NAMES, PlantConfig


def _drop_none(d: Mapping[str, Any]) -> dict[str, Any]:
    """``d`` without its ``None`` leaves (TOML has no null: an absent key means "not known")."""
    return {k: _drop_none(v) if isinstance(v, Mapping) else v
            for k, v in d.items() if v is not None}


def dumps(doc: Mapping[str, Any], comment: str | None = None) -> str:
    """TOML text of nested dicts (tables); ``None`` leaves are left out, ``comment`` lines
    head the file. Non-finite floats are written as TOML's ``nan``/``inf``."""
    head = "".join(f"# {c}\n" if c else "#\n" for c in (comment or "").splitlines())
    try:
        return head + tomli_w.dumps(_drop_none(doc))
    except TypeError as exc:
        raise TypeError(f"cannot write to TOML: {exc}") from exc


def params_document(config: PlantConfig, values: Mapping[str, float],
                    fit: Mapping[str, Any], verdicts: Mapping[str, str] | None = None,
                    at_bounds: Sequence[str] = (),
                    discrepancy: Mapping[str, float] | None = None,
                    model_error: Mapping[str, Any] | None = None,
                    structure: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The PARAMS.toml document for parameter ``values``, the ``[fit]`` section, the flags
    of parameters at a bound, the ``[discrepancy]`` section, the history's
    ``[model_error]`` (:meth:`~softsensor.estimation.model_error.ModelError.to_table`) and
    an adopted ``[structure]`` (:meth:`~.structure_search.StructureSearch.params_table`)."""
    params: dict[str, Any] = {}
    for name in PARAMETER_NAMES:
        spec = config.parameters[name]
        entry: dict[str, Any] = {"value": float(values[name]), "low": float(spec.low),
                                 "high": float(spec.high), "log": bool(spec.log)}
        if verdicts and name in verdicts:
            entry["verdict"] = verdicts[name]
        if name in at_bounds:
            entry["at_bound"] = True
        params[name] = entry
    doc: dict[str, Any] = {"parameters": params, "fit": dict(fit)}
    if discrepancy:
        doc["discrepancy"] = dict(discrepancy)
    if model_error:
        doc["model_error"] = dict(model_error)
    if structure:
        doc["structure"] = dict(structure)
    return doc


def write_params(path: str | Path, document: Mapping[str, Any], comment: str | None = None
                 ) -> Path:
    """Write ``document`` as TOML (atomically: a temporary file renamed into place)."""
    return replace_file(path, dumps(document, comment).encode("utf-8"), "--out")


def _section(path: str | Path, name: str) -> dict[str, Any]:
    """The ``[name]`` table of a PARAMS.toml ({} when absent)."""
    table = read_toml(path).get(name, {})
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: [{name}] must be a table")
    return table


def read_fit(path: str | Path) -> dict[str, Any]:
    """The ``[fit]`` section of a PARAMS.toml ({} when absent)."""
    return _section(path, "fit")


__all__ = ["dumps", "params_document", "read_fit", "write_params"]
