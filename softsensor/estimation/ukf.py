"""The virtual sensor: an unscented Kalman filter of the inlet moisture and the model's error.

The outlet-temperature loop moves ``T_air_in`` to hide the thermal signature of the inlet
moisture, so an open-loop model fed the nominal inlet moisture misses it. Here the filter
carries ``moisture_in`` as a state and corrects it every 600 s tick with the two measured
outlet temperatures (the model, fed the *measured* ``T_air_in``, needs the right inlet
moisture to reproduce them), and with the lab's outlet moisture whenever a result arrives,
tens of minutes after its sample time. Because a real dryer is never the model, the state also
carries the model's own slowly varying error, a common and two per-channel temperature offsets
and an outlet-moisture bias (:mod:`.discrepancy`, priors from the calibration's residuals on
data it was not fitted on).

One tick
--------
1. *Predict* (linear, exact): the inlet moisture a mean-reverting walk, the error states
   first-order processes: ``x = F x + (I - F) x_nominal``, ``P = F P F' + Q``
   (``filterpy.kalman.predict``), ``Q`` inflated per channel by the innovation-based
   adaptation (:class:`~.discrepancy.AdaptiveNoise`).
2. *Sigma points* of the prior (filterpy's ``MerweScaledSigmaPoints``). Only the inlet moisture
   moves the model, and it is the first state, so the sigma points hold three distinct inlet
   moistures (the mean and the two along the first column of the Cholesky factor): the model is
   stepped over the window for those three only, in one batched call, from the current wall
   temperatures; a lab result sampled in the window adds one short step per inlet moisture to
   its sample time (:mod:`.lab_alignment`, the calibration's alignment).
3. *Measurements*: ``T_dryer_out = y_d(X_in) + T_offset + T_dryer_out_offset``,
   ``T_cyclone_out = y_c(X_in) + T_offset + T_cyclone_out_offset`` (window means, variance
   ``sensor_std^2 / n_good + model_std^2``), and per lab result ``y_lab(X_in) +
   moisture_out_bias`` (variance ``lab_std^2 + moisture_out_jitter_std^2``). Measurement sizes
   vary; the update uses filterpy's ``unscented_transform`` for the predicted measurement and
   its covariance and the sigma points' deviations for the cross-covariance.
4. *Covariance matching* before the update (Mehra 1972): when the innovation along what a
   change of the inlet moisture (of one channel's offset; of the bias, with a lab) would do is
   more than ``moisture_in_adapt`` (``offset_adapt``; ``moisture_out_bias_adapt``) standard
   deviations, that state's prior variance grows until it is one: a step of the inlet moisture
   or of one thermometer is taken at once.
5. *Update*, and the wall temperatures (not filtered; a "consider" state that mostly settles
   within a tick) conditioned on the innovation like the outputs.

Published (``/softsensor/estimate``): the now-cast ``moisture_out`` (model + bias, posterior mean
at the window's end) with ``moisture_out_std`` (its uncertainty plus the short-term jitter a
600 s window cannot follow, so its 95 % band is the one to hold a grab sample against),
``moisture_in`` and its standard deviation, the error states, the model temperatures, the
normalised innovation squared ``nis`` and ``status``/``detail`` for health: ``stale`` for a
stale window (predict only), ``degraded`` when the innovations fail the chi-square test of
:mod:`.consistency` or the model failed.

The guard
---------
When the model has lost the plant, its outlet moisture is nonsense however the filter bends.
The tick then publishes a *lab-anchored* ``moisture_out``: the latest lab result, with a band
``sqrt(lab_std^2 + fallback_drift^2 * hours since it was sampled)``, ``fallback`` true, health
``degraded`` and the reason. The model has lost the plant when a model solve fails, when the
inlet moisture sits at a bound of its range, or when an
error state is further than ``guard_sigma`` of its prior standard deviations from zero (the
model misses the plant by far more than the calibration found it does).

Late lab results
----------------
The filter keeps a history of ticks (``estimator.history_hours``): window, inputs, the filter
state at the start of the tick and the lab results applied there. A result whose sample time
lies in a past window is attached to that tick, and the next :meth:`UkfEstimator.tick`
re-filters from it to now, so the current estimate is exactly what it would have been had the
lab been on time; results arriving out of order give the same estimate as in order. A result
sampled after the last tick waits for its window. Older than the history: logged and skipped.
Duplicate ``sample_id``: ignored. Out-of-range value or a value further than
``estimator.lab_gate`` standard deviations from the estimate at its sample time: refused with
the reason (a second one in a row on the same side is taken: the model is off, not the lab).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, unscented_transform
from filterpy.kalman import predict as kf_predict

from softsensor.errors import ConfigError, EstimationError, SoftsensorError
from softsensor.estimation.base import LabResult, Window
from softsensor.estimation.consistency import Innovation, chi_square_test
from softsensor.estimation.discrepancy import (
    ADAPT_CHANNELS,
    STATE_NAMES,
    X_BIAS,
    X_HEAT,
    X_IN,
    X_TCYC,
    X_TDRY,
    AdaptiveNoise,
    ErrorPriors,
    InletTransform,
    process_noise,
    transition,
)
from softsensor.estimation.lab_alignment import sample_inputs, sample_offset
from softsensor.estimation.lab_history import FilterState, LabBook, TickRecord, lab_problem
from softsensor.estimation.settings import EstimatorSettings, estimator_settings
from softsensor.estimation.window_inputs import (
    MOISTURE_IN,
    InputHold,
    TemperatureMeasurement,
    temperatures,
)
from softsensor.plantconfig import PlantConfig
from softsensor.signals import INPUT_NAMES, OUTPUT_NAMES

log = logging.getLogger(__name__)

_MO = OUTPUT_NAMES.index("moisture_out")
_T_AIR_IN = INPUT_NAMES.index("T_air_in")
_CHECKPOINT_VERSION = 2
#: The error state added to each measured channel (T_dryer_out, T_cyclone_out, a lab result).
_OFFSETS = ((X_TDRY,), (X_TCYC,), (X_BIAS,))
#: Finite-difference steps of the model states for the partial derivatives: the inlet moisture
#: (in the filter's coordinate) [kg/kg] and the heat input [K].
_FD_STEP = {X_IN: 1e-3, X_HEAT: 0.5}
#: Two jumps whose effects on the measurements have a cosine above this (``S^-1`` metric)
#: cannot be told apart by them.
SAME_JUMP = 0.95


class WindowModel(Protocol):
    """What the filter needs from a model (:class:`softsensor.model.DryerModel` has it)."""

    theta0: np.ndarray
    window: float

    def steady_state(self, u: np.ndarray, theta: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray]: ...

    def simulate(self, U: np.ndarray, theta: np.ndarray | None = None,
                 aux: np.ndarray | None = None, state0: np.ndarray | None = None,
                 dt: float | None = None, raise_on_failure: bool = True
                 ) -> tuple[np.ndarray, np.ndarray]: ...


@dataclass
class _Posterior:
    """What an update produced: state, published outputs (T_d, T_c, moisture_out with their
    error states) and their variances, the model's own temperatures, the walls, the innovation
    and each measurement row's normalised innovation."""

    x: np.ndarray
    P: np.ndarray
    y_mean: np.ndarray
    y_var: np.ndarray
    model_T: np.ndarray
    wall: np.ndarray
    innovation: Innovation
    normalised: np.ndarray


@dataclass
class _Sigma:
    """The model at a set of sigma points: window-end outputs (3) and walls per point, per
    lab the outlet moisture at its sample time, and the outputs' derivatives (3 + L) with
    respect to each model state with the other held (:data:`MODEL_STATES` order)."""

    y: np.ndarray        # (N, 3)
    wall: np.ndarray     # (N, n_state)
    lab: np.ndarray      # (N, L)
    d_in: np.ndarray     # (3 + L,)
    d_heat: np.ndarray   # (3 + L,)


class UkfEstimator:
    """Unscented Kalman filter of the inlet moisture and the model's error (module docstring).

    Parameters
    ----------
    config : PlantConfig
        Plant configuration with calibrated parameter values (``load_parameters``, which also
        carries the calibration's ``[discrepancy]``); its optional ``[estimator]`` table gives
        the :class:`EstimatorSettings`.
    settings : EstimatorSettings, optional
        Overrides the config's table.
    model : WindowModel, optional
        The model (default ``DryerModel(config)``); tests pass others.
    """

    kind = "ukf"

    def __init__(self, config: PlantConfig, settings: EstimatorSettings | None = None,
                 model: WindowModel | None = None) -> None:
        if model is None:
            from softsensor.model import DryerModel
            model = DryerModel(config)
        self.config = config
        self.settings = s = settings if settings is not None else estimator_settings(config)
        self.model = model
        self.theta = np.asarray(model.theta0, float)
        self.window_s = float(model.window)
        self.max_history = s.history_ticks(self.window_s)
        if s.consistency_ticks > self.max_history:
            raise ConfigError(f"{config.source}: estimator.consistency_ticks must be <= the "
                              f"history ({self.max_history} ticks), got {s.consistency_ticks}")
        self.inlet = InletTransform(s.moisture_in_min, s.moisture_in_max, s.inlet_margin)
        self.heat_gain = _heat_gain(model, config.nominal_inputs(), self.theta)
        self.priors = ErrorPriors.from_config(config, s, self.heat_gain)
        n = len(STATE_NAMES)
        self._points = MerweScaledSigmaPoints(n, s.sigma_alpha, s.sigma_beta, s.sigma_kappa)
        self._inlet_tau = s.moisture_in_tau_h * 3600.0
        self._F = transition(self.window_s, self.priors, self._inlet_tau)
        self._walk = s.walk_per_window(s.moisture_in_walk, self.window_s)
        x_nom = float(config.nominal.moisture_in)
        x0 = np.zeros(n)
        x0[X_IN] = float(self.inlet.inverse(x_nom))
        # the inlet moisture's deviation from the nominal decays (mean reversion)
        self._drift = (np.eye(n) - self._F) @ x0
        P0 = np.diag(np.r_[s.moisture_in_std0**2, self.priors.sigma**2])
        self._hold = InputHold(config.nominal_inputs())
        self._state = FilterState(x0, P0, None, AdaptiveNoise.fresh().to_json())
        self._history: list[TickRecord] = []
        self._labs = LabBook()
        self._dirty: int | None = None
        self._gate_streak = 0

    # ------------------------------------------------------------------ Estimator protocol
    def tick(self, window: Window) -> dict[str, Any]:
        """Advance to ``window.end_ns``: apply late labs, predict, correct; return the body."""
        if self._history and window.end_ns <= self._history[-1].window.end_ns:
            raise EstimationError(f"window ending at {window.end_ns} ns is not after the last "
                                  f"tick ({self._history[-1].window.end_ns} ns)")
        lab_updated = self._dirty is not None
        notes: list[str] = []
        if self._dirty is not None:
            self._refilter(self._dirty)
            notes = [n for r in self._history[self._dirty:] for n in r.body["notes"]]
            self._dirty = None
        labs = []
        last_body = self._history[-1].body if self._history else {}
        for lab in self._labs.take_due(window.end_ns):
            if lab.sample_time_ns <= window.start_ns - self.window_s * 1e9:
                log.warning("lab %r: sample time %d ns falls in a gap before window %d..%d ns; "
                            "skipped", lab.sample_id, lab.sample_time_ns, window.start_ns,
                            window.end_ns)
            elif not self._screen(lab, last_body):
                labs.append(lab)
        u, held = self._hold.inputs(window)
        rec = TickRecord(window, u, held, self._state, labs)
        self._state = self._run(rec)
        self._history.append(rec)
        if len(self._history) > self.max_history:
            del self._history[: len(self._history) - self.max_history]
        self._labs.prune(self._history[0].window.start_ns)
        body = dict(rec.body)
        body["lab_updated"] = bool(lab_updated or labs)
        body["notes"] = notes + rec.body["notes"]
        return body

    def add_lab(self, lab: LabResult) -> str | None:
        """Validate ``lab`` and attach it to the tick of its sample time (module docstring).

        Returns ``None`` when accepted (applied at the next tick), else the reason.
        """
        problem = lab_problem(lab, self.settings)
        if problem:
            log.warning("%s; rejected", problem)
            return problem
        if self._labs.is_duplicate(lab):
            return f"lab {lab.sample_id!r}: duplicate sample_id, ignored"
        self._labs.remember(lab)
        if not self._history or lab.sample_time_ns > self._history[-1].window.end_ns:
            self._labs.add_pending(lab)
            return None
        first = self._history[0].window
        if lab.sample_time_ns <= first.start_ns:
            reason = (f"lab {lab.sample_id!r}: sample time is older than the kept history "
                      f"({self.settings.history_hours:g} h, estimator.history_hours); skipped")
            log.warning(reason)
            return reason
        j = next(i for i, r in enumerate(self._history)
                 if r.window.end_ns >= lab.sample_time_ns)
        rec = self._history[j]
        if lab.sample_time_ns <= rec.window.start_ns - self.window_s * 1e9:
            reason = f"lab {lab.sample_id!r}: no estimator window covers its sample time"
            log.warning(reason)
            return reason
        refused = self._screen(lab, rec.body)
        if refused:
            return refused
        rec.labs.append(lab)
        self._dirty = j if self._dirty is None else min(self._dirty, j)
        return None

    def checkpoint(self) -> dict[str, Any]:
        """JSON-able snapshot: filter state, history, labs, held inputs."""
        return {"kind": self.kind, "version": _CHECKPOINT_VERSION,
                "state": self._state.to_json(), "hold": self._hold.last.tolist(),
                "labs": self._labs.to_json(), "dirty": self._dirty,
                "gate_streak": self._gate_streak,
                "history": [r.to_json() for r in self._history]}

    def restore(self, snapshot: dict[str, Any]) -> None:
        """Continue from :meth:`checkpoint` output; EstimationError if it does not fit."""
        if snapshot.get("kind") != self.kind or snapshot.get("version") != _CHECKPOINT_VERSION:
            raise EstimationError(f"checkpoint is of kind {snapshot.get('kind')!r} version "
                                  f"{snapshot.get('version')!r}, expected {self.kind!r} "
                                  f"version {_CHECKPOINT_VERSION}")
        try:
            state = FilterState.from_json(snapshot["state"])
            history = [TickRecord.from_json(r) for r in snapshot["history"]]
            labs = LabBook.from_json(snapshot["labs"])
            hold = np.array(snapshot["hold"], float)
            dirty = snapshot["dirty"]
            streak = int(snapshot["gate_streak"])
            AdaptiveNoise.from_json(state.adapt)
        except (KeyError, TypeError, ValueError) as exc:
            raise EstimationError(f"checkpoint is malformed: {exc!r}") from exc
        n = len(STATE_NAMES)
        m = len(INPUT_NAMES)
        if state.x.shape != (n,) or state.P.shape != (n, n) or hold.shape != (m,):
            raise EstimationError(f"checkpoint state has shapes x{state.x.shape} "
                                  f"P{state.P.shape} hold{hold.shape}, expected ({n},), "
                                  f"({n}, {n}) and ({m},)")
        self._state, self._history, self._labs = state, history, labs
        self._hold = InputHold(hold)
        self._dirty = None if dirty is None else int(dirty)
        self._gate_streak = streak

    # ------------------------------------------------------------------ lab screening
    def _screen(self, lab: LabResult, body: dict[str, Any]) -> str | None:
        """Outlier screen of ``lab`` against the estimate ``body``: the reason to refuse it,
        or None. A lone outlier is refused; the second in a row on the same side is taken."""
        gate, side = self._gate(lab, body)
        if gate and side != self._gate_streak:
            self._gate_streak = side
            log.warning(gate)
            return gate
        if gate:
            log.warning("%s, but so was the previous result, on the same side: accepted (the "
                        "model is off, not the lab)", gate.split("; rejected")[0])
        self._gate_streak = 0
        return None

    def _gate(self, lab: LabResult, body: dict[str, Any]) -> tuple[str | None, int]:
        """Outlier test of ``lab`` against the estimate ``body`` of its tick: the reason to
        refuse it (None when it passes) and the side it fell on (+1 above, -1 below, 0)."""
        mean, std = body.get("moisture_out"), body.get("moisture_out_std")
        if mean is None or std is None or body.get("fallback"):
            return None, 0
        s = self.settings
        z = (lab.moisture_out - mean) / math.sqrt(std**2 + s.lab_std**2)
        if abs(z) > s.lab_gate:
            return (f"lab {lab.sample_id!r}: moisture_out {lab.moisture_out:g} kg/kg is "
                    f"{abs(z):.1f} sigma from the estimate {mean:.4f} at its sample time "
                    f"(estimator.lab_gate = {s.lab_gate:g}); rejected as an outlier"), \
                (1 if z > 0 else -1)
        return None, 0

    def _refilter(self, j: int) -> None:
        """Re-run the history from tick ``j`` (a late lab was attached there) to now."""
        state = self._history[j].start
        for rec in self._history[j:]:
            rec.start = state
            state = self._run(rec)
        self._state = state

    # ------------------------------------------------------------------ one tick
    def _run(self, rec: TickRecord) -> FilterState:
        """Filter one tick from ``rec.start``; fill ``rec.body``/``rec.innovation``; new state."""
        s = self.settings
        start = rec.start
        adapt = AdaptiveNoise.from_json(start.adapt)
        temps = temperatures(rec.window, s.temperature_sensor_std, s.temperature_model_std)
        wall, detail = start.wall, ""
        if wall is None:
            u0 = rec.u.copy()
            u0[MOISTURE_IN] = float(self.inlet.forward(start.x[X_IN]))
            try:
                wall = self.model.steady_state(u0, self.theta)[0]
            except (SoftsensorError, ValueError) as exc:  # predict only, retry next tick
                detail = f"model initialisation failed: {exc}"
        Q = process_noise(self.window_s, self.priors, self._walk, self._inlet_tau,
                          adapt.inflation())
        x, P = kf_predict(start.x, start.P, self._F, Q)
        x = x + self._drift
        P = _symmetric(P)
        innovation, notes = Innovation(), []
        y_mean = y_var = np.full(3, np.nan)
        model_T = np.full(2, np.nan)
        new_wall = wall
        failed = bool(detail)
        if wall is not None:
            rows, z, R, names, kinds = self._measurements(temps, rec.labs)
            sig, sigmas, detail = self._sigma_outputs(x, P, rec, wall, detail)
            if sig is not None:
                if rows:
                    candidates = [i for i in (X_IN, X_HEAT, X_TDRY, X_TCYC, X_BIAS)
                                  if not ((i == X_BIAS and not rec.labs)
                                          or (i == X_TDRY and 0 not in rows)
                                          or (i == X_TCYC and 1 not in rows))]
                    P_new, note = self._match_covariance(candidates, P, sigmas, sig, rows, z, R)
                    if note:
                        notes.append(note)
                        P = P_new
                        sig, sigmas, detail = self._sigma_outputs(x, P, rec, wall, detail)
            if sig is None:
                failed = True
            else:
                post = self._update(x, P, sigmas, sig, rows, z, R, names)
                x, P, y_mean, y_var = post.x, post.P, post.y_mean, post.y_var
                model_T, new_wall, innovation = post.model_T, post.wall, post.innovation
                for nu, kind in zip(post.normalised, kinds, strict=True):
                    adapt.update(kind, float(nu) ** 2, s.adapt_ticks, s.adapt_limit)
        _check_covariance(P, rec.window.end_ns)
        rec.innovation = innovation
        rec.body = self._body(rec, x, P, y_mean, y_var, model_T, detail, failed)
        rec.body["notes"] = notes
        return FilterState(x, P, None if new_wall is None else np.array(new_wall, float),
                           adapt.to_json())

    def _sigma_outputs(self, x: np.ndarray, P: np.ndarray, rec: TickRecord, wall: np.ndarray,
                       detail: str) -> tuple[_Sigma | None, np.ndarray, str]:
        """Sigma points of ``(x, P)`` and the model at them (module docstring, step 2); None
        and the reason when a solve failed.

        The model runs once per distinct pair (inlet moisture, heat input) among the sigma
        points (five: the mean and two along each of the first two Cholesky columns), plus
        four points about the mean, each model state moved alone, for the partial derivatives
        covariance matching needs.
        """
        sigmas = self._points.sigma_points(x, P)
        mean = x[[X_IN, X_HEAT]]
        probes = [mean + sign * _FD_STEP[i] * (np.arange(2) == j)
                  for j, i in enumerate((X_IN, X_HEAT)) for sign in (1.0, -1.0)]
        pairs = np.vstack([sigmas[:, [X_IN, X_HEAT]], probes])
        unique, index = np.unique(pairs, axis=0, return_inverse=True)
        index = np.ravel(index)
        X = self.inlet.forward(unique[:, 0])
        U = np.repeat(rec.u[None, None, :], len(unique), axis=0)
        U[:, 0, MOISTURE_IN] = X
        U[:, 0, _T_AIR_IN] += unique[:, 1]
        Y, walls = self.model.simulate(U, self.theta, state0=wall, raise_on_failure=False)
        Y = Y[:, 0, :]
        lab = np.empty((len(unique), len(rec.labs)))
        for j, r in enumerate(rec.labs):
            u_lab = sample_inputs(rec.window, rec.u, r.sample_time_ns,
                                  self.config.solver.lab_span)
            Ul = np.repeat(u_lab[None, None, :], len(unique), axis=0)
            Ul[:, 0, MOISTURE_IN] = X
            Ul[:, 0, _T_AIR_IN] += unique[:, 1]
            dt = float(sample_offset(rec.window.start_ns, r.sample_time_ns))
            yl, _ = self.model.simulate(Ul, self.theta, state0=wall, dt=dt,
                                        raise_on_failure=False)
            lab[:, j] = yl[:, 0, _MO]
        if not (np.all(np.isfinite(Y)) and np.all(np.isfinite(lab))):
            bad = int(np.flatnonzero(~(np.isfinite(Y).all(1) & np.isfinite(lab).all(1)))[0])
            return None, sigmas, (f"model solve failed at moisture_in={X[bad]:.3f} kg/kg, "
                                  f"T_air_in offset {unique[bad, 1]:+.2f} K: predict only")
        out = np.hstack([Y, lab])
        n = len(sigmas)
        probe = index[n:]
        d = [(out[probe[2 * j]] - out[probe[2 * j + 1]]) / (2.0 * _FD_STEP[i])
             for j, i in enumerate((X_IN, X_HEAT))]
        return (_Sigma(Y[index[:n]], np.asarray(walls)[index[:n]], lab[index[:n]], d[0], d[1]),
                sigmas, detail)

    def _measurement_sigmas(self, sigmas: np.ndarray, sig: _Sigma, rows: list[int]
                            ) -> np.ndarray:
        """Predicted measurements (N, m) at the sigma points: the model plus the error
        states (rows < 2: temperature channels; rows >= 2: lab results in order)."""
        out = np.empty((len(sigmas), len(rows)))
        j_lab = 0
        for m, r in enumerate(rows):
            if r < 2:
                out[:, m] = sig.y[:, r] + sigmas[:, list(_OFFSETS[r])].sum(axis=1)
            else:
                out[:, m] = sig.lab[:, j_lab] + sigmas[:, X_BIAS]
                j_lab += 1
        return out

    def _match_covariance(self, candidates: list[int], P: np.ndarray, sigmas: np.ndarray,
                          sig: _Sigma, rows: list[int], z: np.ndarray, R: np.ndarray
                          ) -> tuple[np.ndarray, str]:
        """Widen the prior variance of the one state whose jump best explains the innovation,
        when the innovation says it moved more than its process noise allows (covariance
        matching, Mehra 1972); returns the new ``P`` and a note ('' when nothing changed).

        For each candidate state ``i``, with ``h = dz / dx_i`` the sensitivity of the
        measurements to that state alone (the others held: :meth:`_partial`), ``S`` the
        innovation covariance and ``nu`` the innovation, ``t_i = h' S^-1 nu / sqrt(h' S^-1 h)``
        is the innovation's component along what a jump of ``x_i`` would do, in standard
        deviations, and ``t_i^2`` the drop of the normalised innovation squared that such a jump
        buys (a generalised likelihood ratio). The candidate with the largest ``|t_i|`` is the
        best single explanation: a step of the inlet moisture moves both temperatures (and the
        lab) as the model says, a thermometer that steps moves one channel. When its ``|t|``
        exceeds its threshold (``estimator.moisture_in_adapt``, ``offset_adapt``,
        ``moisture_out_bias_adapt``), ``P_ii`` grows by ``(t^2 - 1) / (h' S^-1 h)``, after
        which that component is one standard deviation. Taking one jump, the best, keeps a
        single thermometer's step from being read as an inlet-moisture step plus the other
        thermometer's opposite offset; among jumps these measurements cannot tell apart
        (cosine above :data:`SAME_JUMP` in the ``S^-1`` metric) the inlet moisture's is taken.
        """
        pts = self._points
        h_sig = self._measurement_sigmas(sigmas, sig, rows)
        zp, S = unscented_transform(h_sig, pts.Wm, pts.Wc, R)
        nu = z - zp
        found = []
        for i in candidates:
            h = self._partial(i, sig, rows)
            w = np.linalg.solve(S, h)
            info = float(h @ w)
            if info > 0:
                found.append((i, float(w @ nu) / math.sqrt(info), info, h, w))
        if not found:
            return P, ""
        best = max(found, key=lambda c: abs(c[1]))
        thr = {X_IN: self.settings.moisture_in_adapt,
               X_BIAS: self.settings.moisture_out_bias_adapt}
        if abs(best[1]) <= thr.get(best[0], self.settings.offset_adapt):
            return P, ""
        # the states whose jump looks the same to these measurements (an inlet-moisture step
        # and a heat-input step both move the two temperatures together) cannot be told
        # apart by them; the inlet moisture is the one that steps (a new pile of chips), the
        # heat input's error drifts with the conditions, so the inlet moisture takes the jump
        # and later lab results, which see it through the outlet moisture, confirm or undo it
        same = [c for c in found
                if abs(c[3] @ best[4]) / math.sqrt(c[2] * best[2]) > SAME_JUMP
                and abs(c[1]) > thr.get(c[0], self.settings.offset_adapt)]
        inlet = [c for c in same if c[0] == X_IN]
        chosen = inlet if inlet else [best]
        P = P.copy()
        parts = []
        for i, t, info, _h, _w in chosen:
            P[i, i] += (t * t - 1.0) / info
            what = {X_IN: "inlet moisture", X_BIAS: "outlet-moisture bias"}.get(
                i, STATE_NAMES[i].replace("_", " "))
            parts.append(f"{what} ({abs(t):.1f} sigma, prior widened to "
                         f"{math.sqrt(P[i, i]):.4g})")
        msg = "measurements far from the model along the " + ", ".join(parts)
        log.info(msg)
        return P, msg

    @staticmethod
    def _partial(i: int, sig: _Sigma, rows: list[int]) -> np.ndarray:
        """``dz / dx_i`` with the other states held: one on their rows for the error states
        added to the outputs, the model's central difference for the inlet moisture and the
        heat input (:meth:`_sigma_outputs`)."""
        if i not in (X_IN, X_HEAT):
            return np.array([1.0 if i in _OFFSETS[r] else 0.0 for r in rows])
        d = sig.d_in if i == X_IN else sig.d_heat
        out, j_lab = [], 0
        for r in rows:
            if r < 2:
                out.append(d[r])
            else:
                out.append(d[3 + j_lab])
                j_lab += 1
        return np.array(out)

    def _update(self, x: np.ndarray, P: np.ndarray, sigmas: np.ndarray, sig: _Sigma,
                rows: list[int], z: np.ndarray, R: np.ndarray, names: list[str]
                ) -> _Posterior:
        """The unscented update of the state, the outputs and the walls (module docstring,
        steps 3 and 5)."""
        pts = self._points
        wm, wc = pts.Wm, pts.Wc
        # outputs the body publishes, with their error states: T_d, T_c, moisture_out
        g = np.column_stack([sig.y[:, 0] + sigmas[:, X_TDRY],
                             sig.y[:, 1] + sigmas[:, X_TCYC],
                             sig.y[:, _MO] + sigmas[:, X_BIAS], sig.wall])
        # the model's own temperatures (without offsets) for the body
        g_model = sig.y[:, :2]
        post = wm @ g
        dg = g - post
        y_var = (wc[:, None] * dg[:, :3] ** 2).sum(0)
        model_T = wm @ g_model
        innovation = Innovation()
        norm = np.zeros(0)
        if rows:
            h_sig = self._measurement_sigmas(sigmas, sig, rows)
            zp, S = unscented_transform(h_sig, wm, wc, R)
            dh = h_sig - zp
            Pxz = ((wc[:, None] * (sigmas - x)).T @ dh)
            SI = np.linalg.inv(S)
            K = Pxz @ SI
            nu = z - zp
            x = x + K @ nu
            P = _symmetric(P - K @ S @ K.T)
            gain = ((wc[:, None] * dg).T @ dh) @ SI
            post = post + gain @ nu
            y_var = y_var - np.einsum("ij,jk,ik->i", gain[:3], S, gain[:3])
            gain_m = ((wc[:, None] * (g_model - model_T)).T @ dh) @ SI
            model_T = model_T + gain_m @ nu
            norm = nu / np.sqrt(np.diag(S))
            innovation = Innovation(float(nu @ SI @ nu), len(rows), _per_channel(names, norm))
        return _Posterior(x, P, post[:3].copy(), y_var, model_T, post[3:], innovation, norm)

    def _measurements(self, temps: TemperatureMeasurement, labs: list[LabResult]
                      ) -> tuple[list[int], np.ndarray, np.ndarray, list[str], list[int]]:
        """Rows (0, 1: temperature channels; 2: a lab result), measured values, full-size
        ``R``, channel names and the adaptive channel of each row."""
        rows = list(temps.channels)
        values = list(temps.values)
        var = list(temps.variances)
        names = [OUTPUT_NAMES[c] for c in temps.channels]
        kinds = list(temps.channels)
        for lab in labs:
            rows.append(2)
            values.append(lab.moisture_out)
            var.append(self.settings.lab_std**2 + self.settings.moisture_out_jitter_std**2)
            names.append("moisture_out (lab)")
            kinds.append(ADAPT_CHANNELS.index("moisture_out"))
        return rows, np.array(values, float), np.diag(var), names, kinds

    # ------------------------------------------------------------------ the body
    def _inlet_moments(self, x: np.ndarray, P: np.ndarray) -> tuple[float, float]:
        """Mean and standard deviation of the inlet moisture (through the soft clip)."""
        sig = self._points.sigma_points(x, P)[:, X_IN]
        X = self.inlet.forward(sig)
        mean = float(self._points.Wm @ X)
        var = float(self._points.Wc @ (X - mean) ** 2)
        return mean, math.sqrt(max(var, 0.0))

    def _lost(self, x: np.ndarray, failed: bool) -> str:
        """Why the model has lost the plant ('' when it has not): the guard's rules. Only the
        errors that move the outlet moisture count: the heat input's offset (the energy
        balance) and the outlet-moisture bias; one channel's own offset is a suspect sensor
        (:meth:`_suspect`)."""
        if failed:
            return "the model could not be solved"
        if self.inlet.near_bound(float(x[X_IN])):
            X = float(self.inlet.forward(x[X_IN]))
            return (f"the inlet moisture sits at the bound of its range ({X:.2f} kg/kg in "
                    f"[{self.inlet.lo:g}, {self.inlet.hi:g}])")
        for i in (X_HEAT, X_BIAS):
            z = x[i] / self.priors.sigma[i - 1]
            if abs(z) > self.settings.guard_sigma:
                unit = "kg/kg" if i == X_BIAS else "K"
                return (f"{STATE_NAMES[i]} {x[i]:+.3g} {unit} is {abs(z):.1f} times the "
                        f"model error the calibration expects "
                        f"({self.priors.sigma[i - 1]:.3g} {unit}, {self.priors.source})")
        return ""

    def _suspect(self, x: np.ndarray) -> str:
        """A temperature channel whose own offset is beyond ``guard_sigma`` of its prior: its
        sensor (or that part of the model) is off ('' when none is)."""
        out = []
        for i, name in ((X_TDRY, "T_dryer_out"), (X_TCYC, "T_cyclone_out")):
            z = x[i] / self.priors.sigma[i - 1]
            if abs(z) > self.settings.guard_sigma:
                out.append(f"{name} reads {x[i]:+.2f} K from the model ({abs(z):.1f} times "
                           f"the error expected): check its sensor")
        return "; ".join(out)

    def _fallback(self, end_ns: int) -> tuple[float, float, str] | None:
        """The lab-anchored estimate: the latest accepted lab result sampled by ``end_ns``,
        its band widened with the time since (None without a lab in the history)."""
        latest = None
        for r in self._history:
            for lab in r.labs:
                if lab.sample_time_ns <= end_ns and (latest is None or lab.sample_time_ns
                                                     > latest.sample_time_ns):
                    latest = lab
        if latest is None:
            return None
        s = self.settings
        hours = max(end_ns - latest.sample_time_ns, 0) / 3.6e12
        std = math.sqrt(s.lab_std**2 + s.moisture_out_jitter_std**2
                        + s.fallback_drift**2 * hours)
        return float(latest.moisture_out), std, latest.sample_id

    def _body(self, rec: TickRecord, x: np.ndarray, P: np.ndarray, y_mean: np.ndarray,
              y_var: np.ndarray, model_T: np.ndarray, detail: str, failed: bool
              ) -> dict[str, Any]:
        """The estimate body of one tick (``lab_updated`` is set by :meth:`tick`)."""
        s = self.settings
        window = rec.window
        jitter = s.moisture_out_jitter_std
        recent = [r.innovation for r in self._history if r.window.end_ns < window.end_ns]
        recent = recent[max(0, len(recent) - (s.consistency_ticks - 1)):]
        verdict = chi_square_test([*recent, rec.innovation], s.consistency_alpha)
        if window.stale:
            status = "stale"
            reasons = "; ".join(f"{k}: {v}" for k, v in window.reasons.items())
            detail = "stale window, predicting without correction" + (
                f": {reasons}" if reasons else "")
        elif detail:
            status = "degraded"
        else:
            status, detail = verdict.status, verdict.detail
            if rec.held:
                detail += f"; holding last value of {', '.join(rec.held)}"
        mo = float(y_mean[_MO]) if math.isfinite(y_mean[_MO]) else math.nan
        mo_std = math.sqrt(max(y_var[_MO], 0.0) + jitter**2) if math.isfinite(mo) else math.nan
        fallback = False
        lost = "" if window.stale else self._lost(x, failed)
        if lost or not math.isfinite(mo):
            anchor = self._fallback(window.end_ns)
            if anchor is not None:
                mo, mo_std, sid = anchor
                fallback = True
                status = "degraded"
                detail = (f"model lost the plant ({lost or 'no model estimate'}): moisture_out "
                          f"is the last lab result {sid} {mo:.4f} +- {mo_std:.4f} kg/kg; "
                          + detail)
            elif lost:
                status = "degraded"
                detail = f"model lost the plant ({lost}); no lab result yet; " + detail
        suspect = "" if window.stale else self._suspect(x)
        if suspect:
            status = "degraded"
            detail = f"{suspect}; {detail}"
        clipped = math.isfinite(mo) and not s.lab_min <= mo <= s.lab_max
        if clipped:
            mo = min(max(mo, s.lab_min), s.lab_max)
        x_in, x_in_std = self._inlet_moments(x, P)
        inn = rec.innovation
        return {
            "moisture_out": _num(mo),
            "moisture_out_std": _num(mo_std),
            "moisture_out_window_std": _num(math.sqrt(max(y_var[_MO], 0.0))),
            "moisture_in": x_in,
            "moisture_in_std": x_in_std,
            "moisture_out_bias": float(x[X_BIAS]),
            "moisture_out_bias_std": float(math.sqrt(P[X_BIAS, X_BIAS])),
            "T_air_in_offset": float(x[X_HEAT]),
            "T_offset": float(self.heat_gain * x[X_HEAT]),
            "T_dryer_out_offset": float(x[X_TDRY]),
            "T_cyclone_out_offset": float(x[X_TCYC]),
            "T_dryer_out_model": _num(y_mean[0]),
            "T_cyclone_out_model": _num(y_mean[1]),
            "T_dryer_out_model_raw": _num(float(model_T[0])),
            "T_cyclone_out_model_raw": _num(float(model_T[1])),
            "fallback": fallback,
            "clipped": clipped,
            "nis": inn.nis if inn.dof else None,
            "nis_dof": inn.dof,
            "labs_applied": [r.sample_id for r in rec.labs],
            "lab_updated": bool(rec.labs),
            "status": status,
            "detail": detail,
            "discrepancy_priors": self.priors.source,
            "window_start_ns": int(window.start_ns),
            "window_end_ns": int(window.end_ns),
            "estimator": self.kind,
        }


def _heat_gain(model: WindowModel, u: np.ndarray, theta: np.ndarray) -> float:
    """Mean gain from ``T_air_in`` to the two outlet temperatures at ``u`` [K/K] (steady
    state, central difference of 2 K); 0.3 when the model cannot be solved there."""
    U = np.tile(np.asarray(u, float), (2, 1))
    U[0, _T_AIR_IN] += 1.0
    U[1, _T_AIR_IN] -= 1.0
    try:
        _, y = model.steady_state(U, theta)
    except (SoftsensorError, ValueError):
        return 0.3
    g = float(np.mean((y[0, :2] - y[1, :2]) / 2.0))
    return g if math.isfinite(g) and g > 0 else 0.3


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def _per_channel(names: list[str], norm: np.ndarray) -> dict[str, float]:
    """Normalised innovation per channel name (several lab results averaged)."""
    out: dict[str, list[float]] = {}
    for n, v in zip(names, norm, strict=True):
        out.setdefault(n, []).append(float(v))
    return {n: float(np.mean(v)) for n, v in out.items()}


def _symmetric(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)


def _check_covariance(P: np.ndarray, end_ns: int) -> None:
    """Raise EstimationError unless ``P`` is finite, symmetric and positive definite."""
    if not np.all(np.isfinite(P)):
        raise EstimationError(f"filter covariance became non-finite at tick ending {end_ns} ns")
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError as exc:
        raise EstimationError(f"filter covariance lost positive definiteness at tick ending "
                              f"{end_ns} ns") from exc
