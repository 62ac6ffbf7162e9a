"""The virtual sensor: an unscented Kalman filter of the inlet moisture and the model's error.

The outlet-temperature loop moves ``T_air_in`` to hide the thermal signature of the inlet
moisture, so an open-loop model fed the nominal inlet moisture misses it. Here the filter
carries ``moisture_in`` as a state and corrects it every 600 s tick with the two measured
outlet temperatures (the model, fed the *measured* ``T_air_in``, needs the right inlet
moisture to reproduce them), and with the lab's outlet moisture whenever a result arrives,
tens of minutes after its sample time. Because a real dryer is never the model, the state also
carries the model's own slowly varying error: an offset of the heat input it sees (common to
both temperatures), two per-channel temperature offsets and an outlet-moisture bias
(:mod:`.discrepancy`, priors from the calibration's residuals on data it was not fitted on).

One tick
--------
1. *Predict* (linear, exact): the inlet moisture a mean-reverting walk, the error states
   first-order processes: ``x = F x + (I - F) x_nominal``, ``P = F P F' + Q``
   (``filterpy.kalman.predict`` with the nominal state as its control input), ``Q``'s constant
   diagonal (:func:`~.discrepancy.process_noise`, computed once) inflated per channel by the
   innovation-based adaptation (:class:`~.discrepancy.AdaptiveNoise`).
2. *Sigma points* of the prior (filterpy's ``MerweScaledSigmaPoints``). Only the inlet moisture
   and the heat input's offset enter the model (:data:`~.discrepancy.MODEL_STATES`, the first
   two states; the others add to its outputs), so the sigma points hold five distinct pairs of
   them (the mean and two along each of the first two columns of the Cholesky factor). The
   model is stepped over the window for those five only, plus four points about the mean, each
   model state moved alone, for the partial derivatives of step 4: one batched call, from the
   current wall temperatures, with ``moisture_in`` and ``T_air_in`` plus the heat offset as its
   inputs. A lab result sampled in the window adds one batched short step to its sample time,
   with the inputs just before the sample (:mod:`.lab_alignment`, the calibration's alignment).
3. *Measurements*: ``T_dryer_out = y_d(X_in, T_air_in + T_air_in_offset) +
   T_dryer_out_offset``, ``T_cyclone_out = y_c(...) + T_cyclone_out_offset`` (window means,
   variance ``sensor_std^2 / n_good + model_std^2``), and per lab result ``y_lab(...) +
   moisture_out_bias`` (variance ``lab_std^2 + moisture_out_jitter_std^2``); a missing
   temperature or a tick without lab drops its row, so the size varies tick to tick.
4. *Covariance matching* before the update (Mehra 1972, :mod:`.jump_matching`): when the
   innovation along what a change of the inlet moisture (of one channel's offset; of the bias,
   with a lab) would do is more than ``moisture_in_adapt`` (``offset_adapt``;
   ``moisture_out_bias_adapt``) standard deviations, that state's prior variance grows until
   it is one: a step of the inlet moisture or of one thermometer is taken at once. The model
   is then run at the new sigma points.
5. *Update*: filterpy's ``unscented_transform`` of the joint sigma points (state, published
   outputs, the model's own temperatures, walls, predicted measurements) gives their mean and
   joint covariance, whose off-diagonal blocks are the cross-covariances with the
   measurements; ``filterpy.kalman.update``, with a measurement matrix that selects the
   predicted measurements, conditions that Gaussian on the measured values. This is the
   unscented update written as the linear Kalman update of the joint Gaussian, and it
   conditions the published outputs and the wall temperatures (not filtered: a "consider"
   state that mostly settles within a tick) on the innovation with the state.

Why filterpy's functions and not its ``UnscentedKalmanFilter``: the class calls ``hx`` once
per sigma point (eleven model calls a tick), where the model here runs once, batched over the
five distinct model inputs of the sigma points and the four derivative probes; covariance
matching changes ``P`` after the model has been run at the sigma points and before the update;
and the measurement vector changes size. With the class each of these means writing its ``P``
and ``sigmas_f`` between ``predict`` and ``update``, or a cached ``hx`` that ignores its
argument. Its building blocks (``predict``, ``MerweScaledSigmaPoints``, ``unscented_transform``,
``update``) are called here with their documented arguments; ``tests/test_ukf.py`` checks a
tick against the class with the model in ``hx``.

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

import itertools
import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, unscented_transform
from filterpy.kalman import predict as kf_predict
from filterpy.kalman import update as kf_update

from softsensor.errors import ConfigError, EstimationError, SoftsensorError
from softsensor.estimation.base import LabResult, ModelEstimator, Window, WindowModel
from softsensor.estimation.consistency import Innovation, chi_square_test
from softsensor.estimation.discrepancy import (
    ADAPT_CHANNELS,
    MODEL_STATES,
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
from softsensor.estimation.jump_matching import jumps, widen
from softsensor.estimation.lab_alignment import sample_inputs, sample_offset
from softsensor.estimation.lab_history import FilterState, LabBook, TickRecord
from softsensor.estimation.settings import EstimatorSettings
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
#: The error state added to each kind of measurement row (0: T_dryer_out, 1: T_cyclone_out,
#: 2: a lab result's outlet moisture).
_ROW_OFFSET = (X_TDRY, X_TCYC, X_BIAS)
#: Finite-difference steps of the model states for the partial derivatives: the inlet moisture
#: (in the filter's coordinate) [kg/kg] and the heat input [K].
_FD_STEP = {X_IN: 1e-3, X_HEAT: 0.5}


@dataclass
class _Measurements:
    """One tick's measurement rows: their kind (0, 1: temperature channels; 2: a lab result,
    in the order of the tick's labs), measured values, ``R``, channel names and the adaptive
    channel (:data:`~.discrepancy.ADAPT_CHANNELS`) of each row."""

    rows: list[int]
    z: np.ndarray
    R: np.ndarray
    names: list[str]
    channels: list[int]


@dataclass
class _Posterior:
    """What a tick produced: state, published outputs (T_d, T_c, moisture_out with their
    error states) and their variances, the model's own temperatures, the walls, the innovation
    and each measurement row's normalised innovation with its adaptive channel."""

    x: np.ndarray
    P: np.ndarray
    y_mean: np.ndarray
    y_var: np.ndarray
    model_T: np.ndarray
    wall: np.ndarray | None
    innovation: Innovation = field(default_factory=Innovation)
    normalised: np.ndarray = field(default_factory=lambda: np.zeros(0))
    channels: list[int] = field(default_factory=list)

    @classmethod
    def predicted(cls, x: np.ndarray, P: np.ndarray, wall: np.ndarray | None) -> _Posterior:
        """The prior alone (no model outputs): a tick that could not correct."""
        return cls(x, P, np.full(3, np.nan), np.full(3, np.nan), np.full(2, np.nan), wall)


@dataclass
class _Sigma:
    """The model at a set of sigma points: window-end outputs (3) and walls per point, per
    lab the outlet moisture at its sample time, and the outputs' derivatives (3 + L) with
    respect to each model state with the other held (:data:`~.discrepancy.MODEL_STATES`)."""

    y: np.ndarray        # (N, 3)
    wall: np.ndarray     # (N, n_state)
    lab: np.ndarray      # (N, L)
    d_in: np.ndarray     # (3 + L,)
    d_heat: np.ndarray   # (3 + L,)


@dataclass
class _LabSteps:
    """Per lab result of a tick, the model inputs just before its sample (L, 8) and the step
    from the window's start to its sample time (L,) [s] (:mod:`.lab_alignment`)."""

    u: np.ndarray
    dt: np.ndarray


class UkfEstimator(ModelEstimator):
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
        super().__init__(config, settings, model)
        s = self.settings
        model = self.model
        self.max_history = s.history_ticks(self.window_s)
        if s.consistency_ticks > self.max_history:
            raise ConfigError(f"{config.source}: estimator.consistency_ticks must be <= the "
                              f"history ({self.max_history} ticks), got {s.consistency_ticks}")
        self.inlet = InletTransform(s.moisture_in_min, s.moisture_in_max, s.inlet_margin)
        self.heat_gain = _heat_gain(model, config.nominal_inputs(), self.theta)
        self.priors = ErrorPriors.from_config(config, s, self.heat_gain)
        n = len(STATE_NAMES)
        self._points = MerweScaledSigmaPoints(n, s.sigma_alpha, s.sigma_beta, s.sigma_kappa)
        inlet_tau = s.moisture_in_tau_h * 3600.0
        self._F = transition(self.window_s, self.priors, inlet_tau)
        # the process noise's diagonal is fixed by the settings; only its inflation changes
        self._q = process_noise(self.window_s, self.priors,
                                s.walk_per_window(s.moisture_in_walk, self.window_s), inlet_tau)
        x0 = np.zeros(n)
        x0[X_IN] = float(self.inlet.inverse(float(config.nominal.moisture_in)))
        # the inlet moisture's deviation from the nominal decays (mean reversion): the nominal
        # state is the prediction's control input, ``(I - F)`` its control matrix
        self._nominal = x0
        self._reversion = np.eye(n) - self._F
        P0 = np.diag(np.r_[s.moisture_in_std0**2, self.priors.sigma**2])
        # how many standard deviations of innovation along a state's jump widen its variance
        self._jump_threshold = {X_IN: s.moisture_in_adapt, X_HEAT: s.offset_adapt,
                                X_TDRY: s.offset_adapt, X_TCYC: s.offset_adapt,
                                X_BIAS: s.moisture_out_bias_adapt}
        self._hold = InputHold(config.nominal_inputs())
        self._state = FilterState(x0, P0, None, AdaptiveNoise.fresh().to_json())
        self._history: list[TickRecord] = []
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
        self._state = self._run(rec, len(self._history))
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
        problem = self._screen_lab(lab)
        if problem:
            return problem
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
        self._check_snapshot(snapshot, _CHECKPOINT_VERSION)
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
        _check_state(state.x, state.P, hold)
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
        for k in range(j, len(self._history)):
            rec = self._history[k]
            rec.start = state
            state = self._run(rec, k)
        self._state = state

    # ------------------------------------------------------------------ one tick
    def _run(self, rec: TickRecord, k: int) -> FilterState:
        """Filter one tick from ``rec.start`` (tick ``k`` of the history, appended after the
        last when new); fill ``rec.body``/``rec.innovation``; return the new state."""
        s = self.settings
        adapt = AdaptiveNoise.from_json(rec.start.adapt)
        Q = np.diag(self._q * np.r_[1.0, adapt.inflation()])
        x, P = kf_predict(rec.start.x, rec.start.P, self._F, Q, u=self._nominal,
                          B=self._reversion)
        P = _symmetric(P)
        wall, detail = self._start_wall(rec)
        out, notes = _Posterior.predicted(x, P, wall), []
        if wall is not None:
            out, detail, notes = self._correct(x, P, rec, wall)
            for nu, channel in zip(out.normalised, out.channels, strict=True):
                adapt.update(channel, float(nu) ** 2, s.adapt_ticks, s.adapt_limit)
        _check_covariance(out.P, rec.window.end_ns)
        rec.innovation = out.innovation
        rec.body = self._body(rec, k, out, detail)
        rec.body["notes"] = notes
        return FilterState(out.x, out.P, None if out.wall is None else np.array(out.wall, float),
                           adapt.to_json())

    def _start_wall(self, rec: TickRecord) -> tuple[np.ndarray | None, str]:
        """The wall temperatures at the start of the tick: the state's, or on the first tick
        (and after a failed start) the model's steady state; None and why when that fails
        (predict only, retried next tick)."""
        if rec.start.wall is not None:
            return rec.start.wall, ""
        u0 = rec.u.copy()
        u0[MOISTURE_IN] = float(self.inlet.forward(rec.start.x[X_IN]))
        try:
            return self.model.steady_state(u0, self.theta)[0], ""
        except (SoftsensorError, ValueError) as exc:
            return None, f"model initialisation failed: {exc}"

    def _correct(self, x: np.ndarray, P: np.ndarray, rec: TickRecord, wall: np.ndarray
                 ) -> tuple[_Posterior, str, list[str]]:
        """Steps 2 to 5 of the module docstring from the prior ``(x, P)``: the posterior, or
        when the model could not be solved the prior and why; and the covariance-matching
        note, if any."""
        s = self.settings
        meas = self._measurements(temperatures(rec.window, s.temperature_sensor_std,
                                               s.temperature_model_std), rec.labs)
        steps = _LabSteps(
            sample_inputs(rec.window, rec.u, [r.sample_time_ns for r in rec.labs],
                          self.config.solver.lab_span),
            sample_offset(rec.window.start_ns,
                          np.array([r.sample_time_ns for r in rec.labs], np.int64)))
        sig, sigmas, failure = self._sigma_outputs(x, P, rec.u, wall, steps)
        notes = []
        if sig is not None and meas.rows:
            P_matched, note = self._match_covariance(P, sigmas, sig, meas)
            if note:
                notes.append(note)
                P = P_matched
                sig, sigmas, failure = self._sigma_outputs(x, P, rec.u, wall, steps)
        if sig is None:
            return _Posterior.predicted(x, P, wall), failure, notes
        return self._update(sigmas, sig, meas), "", notes

    def _sigma_outputs(self, x: np.ndarray, P: np.ndarray, u: np.ndarray, wall: np.ndarray,
                       steps: _LabSteps) -> tuple[_Sigma | None, np.ndarray, str]:
        """Sigma points of ``(x, P)`` and the model at them (module docstring, step 2); None
        and the reason when a solve failed."""
        sigmas = self._points.sigma_points(x, P)
        model = list(MODEL_STATES)
        mean = x[model]
        probes = [mean + sign * _FD_STEP[i] * (np.arange(len(model)) == j)
                  for j, i in enumerate(MODEL_STATES) for sign in (1.0, -1.0)]
        unique, index = np.unique(np.vstack([sigmas[:, model], probes]), axis=0,
                                  return_inverse=True)
        index = np.ravel(index)
        X = self.inlet.forward(unique[:, 0])
        Y, walls = self.model.simulate(self._model_inputs(u, X, unique[:, 1]), self.theta,
                                       state0=wall, raise_on_failure=False)
        Y = Y[:, 0, :]
        lab = np.empty((len(unique), len(steps.dt)))
        for j, (u_lab, dt) in enumerate(zip(steps.u, steps.dt, strict=True)):
            yl, _ = self.model.simulate(self._model_inputs(u_lab, X, unique[:, 1]), self.theta,
                                        state0=wall, dt=float(dt), raise_on_failure=False)
            lab[:, j] = yl[:, 0, _MO]
        if not (np.all(np.isfinite(Y)) and np.all(np.isfinite(lab))):
            bad = int(np.flatnonzero(~(np.isfinite(Y).all(1) & np.isfinite(lab).all(1)))[0])
            return None, sigmas, (f"model solve failed at moisture_in={X[bad]:.3f} kg/kg, "
                                  f"T_air_in offset {unique[bad, 1]:+.2f} K: predict only")
        out = np.hstack([Y, lab])
        n = len(sigmas)
        probe = index[n:]
        d = [(out[probe[2 * j]] - out[probe[2 * j + 1]]) / (2.0 * _FD_STEP[i])
             for j, i in enumerate(MODEL_STATES)]
        return (_Sigma(Y[index[:n]], np.asarray(walls)[index[:n]], lab[index[:n]], d[0], d[1]),
                sigmas, "")

    @staticmethod
    def _model_inputs(u: np.ndarray, moisture_in: np.ndarray, heat: np.ndarray
                      ) -> np.ndarray:
        """Model inputs ``(K, 1, 8)``: ``u`` with each inlet moisture and ``T_air_in`` moved
        by each heat-input offset."""
        U = np.repeat(np.asarray(u, float)[None, None, :], len(moisture_in), axis=0)
        U[:, 0, MOISTURE_IN] = moisture_in
        U[:, 0, _T_AIR_IN] += heat
        return U

    @staticmethod
    def _measurement_sigmas(sigmas: np.ndarray, sig: _Sigma, rows: list[int]) -> np.ndarray:
        """Predicted measurements (N, m) at the sigma points: the model plus the error state
        of each row (module docstring, step 3)."""
        out = np.empty((len(sigmas), len(rows)))
        j_lab = 0
        for m, r in enumerate(rows):
            if r < 2:
                model = sig.y[:, r]
            else:
                model = sig.lab[:, j_lab]
                j_lab += 1
            out[:, m] = model + sigmas[:, _ROW_OFFSET[r]]
        return out

    def _match_covariance(self, P: np.ndarray, sigmas: np.ndarray, sig: _Sigma,
                          meas: _Measurements) -> tuple[np.ndarray, str]:
        """Widen the prior variance of the one state whose jump best explains the innovation,
        when the innovation says it moved more than its process noise allows
        (:mod:`.jump_matching`); returns the new ``P`` and a note ('' when nothing changed).

        The candidates are the inlet moisture, the heat input, each measured temperature
        channel's offset and, with a lab, the bias; their thresholds
        ``estimator.moisture_in_adapt``, ``offset_adapt`` and ``moisture_out_bias_adapt``;
        among jumps the measurements cannot tell apart the inlet moisture's is taken.
        """
        pts = self._points
        zp, S = unscented_transform(self._measurement_sigmas(sigmas, sig, meas.rows),
                                    pts.Wm, pts.Wc, meas.R)
        seen = set(meas.rows)
        candidates = [X_IN, X_HEAT] + [_ROW_OFFSET[r] for r in range(3) if r in seen]
        found = jumps({i: self._partial(i, sig, meas.rows) for i in candidates}, S,
                      meas.z - zp)
        P, taken = widen(P, found, self._jump_threshold, preferred=X_IN)
        if not taken:
            return P, ""
        parts = []
        for c in taken:
            what = {X_IN: "inlet moisture", X_BIAS: "outlet-moisture bias"}.get(
                c.state, STATE_NAMES[c.state].replace("_", " "))
            parts.append(f"{what} ({abs(c.t):.1f} sigma, prior widened to "
                         f"{math.sqrt(P[c.state, c.state]):.4g})")
        msg = "measurements far from the model along the " + ", ".join(parts)
        log.info(msg)
        return P, msg

    @staticmethod
    def _partial(i: int, sig: _Sigma, rows: list[int]) -> np.ndarray:
        """``dz / dx_i`` with the other states held: one on their rows for the error states
        added to the outputs, the model's central difference for the inlet moisture and the
        heat input (:meth:`_sigma_outputs`)."""
        if i not in MODEL_STATES:
            return np.array([1.0 if _ROW_OFFSET[r] == i else 0.0 for r in rows])
        d = sig.d_in if i == X_IN else sig.d_heat
        out, j_lab = [], 0
        for r in rows:
            if r < 2:
                out.append(d[r])
            else:
                out.append(d[3 + j_lab])
                j_lab += 1
        return np.array(out)

    def _update(self, sigmas: np.ndarray, sig: _Sigma, meas: _Measurements) -> _Posterior:
        """The unscented update of the state, the outputs and the walls (module docstring,
        steps 3 and 5): filterpy's unscented transform of the joint sigma points, then its
        Kalman update of that Gaussian by the measured rows."""
        pts = self._points
        n, m = sigmas.shape[1], len(meas.rows)
        # published outputs with their error states (T_d, T_c, moisture_out), the model's own
        # temperatures (without offsets), the walls, the predicted measurements
        published = sig.y + sigmas[:, list(_ROW_OFFSET)]
        joint = np.hstack([sigmas, published, sig.y[:, :2], sig.wall,
                           self._measurement_sigmas(sigmas, sig, meas.rows)])
        mean, cov = unscented_transform(joint, pts.Wm, pts.Wc)
        innovation, norm = Innovation(), np.zeros(0)
        if m:
            nu = meas.z - mean[-m:]
            S = cov[-m:, -m:] + meas.R
            H = np.zeros((m, joint.shape[1]))
            H[:, -m:] = np.eye(m)
            mean, cov = kf_update(mean, cov, meas.z, meas.R, H)
            norm = nu / np.sqrt(np.diag(S))
            innovation = Innovation(float(nu @ np.linalg.solve(S, nu)), m,
                                    _per_channel(meas.names, norm))
        out = slice(n, n + 3)
        return _Posterior(mean[:n].copy(), _symmetric(cov[:n, :n]), mean[out],
                          np.diag(cov)[out].copy(), mean[n + 3:n + 5],
                          mean[n + 5:n + 5 + sig.wall.shape[1]], innovation, norm,
                          list(meas.channels))

    def _measurements(self, temps: TemperatureMeasurement, labs: list[LabResult]
                      ) -> _Measurements:
        """The tick's measurement rows: the measured temperature channels, then each lab."""
        s = self.settings
        rows = list(temps.channels)
        values = list(temps.values)
        var = list(temps.variances)
        names = [OUTPUT_NAMES[c] for c in temps.channels]
        channels = list(temps.channels)
        for lab in labs:
            rows.append(2)
            values.append(lab.moisture_out)
            var.append(s.lab_std**2 + s.moisture_out_jitter_std**2)
            names.append("moisture_out (lab)")
            channels.append(ADAPT_CHANNELS.index("moisture_out"))
        return _Measurements(rows, np.array(values, float), np.diag(var), names, channels)

    # ------------------------------------------------------------------ the body
    def _inlet_moments(self, x: np.ndarray, P: np.ndarray) -> tuple[float, float]:
        """Mean and standard deviation of the inlet moisture (through the soft clip)."""
        pts = self._points
        X = self.inlet.forward(pts.sigma_points(x, P)[:, X_IN])
        mean, var = unscented_transform(X[:, None], pts.Wm, pts.Wc)
        return float(mean[0]), math.sqrt(max(float(var[0, 0]), 0.0))

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

    def _fallback(self, rec: TickRecord, k: int) -> tuple[float, float, str] | None:
        """The lab-anchored estimate at tick ``k`` (``rec``): the latest lab result applied
        there or before, its band widened with the time since (None without one). A tick's
        results are sampled in its window and after the previous tick's, so the latest is in
        the nearest tick that has any."""
        earlier = (self._history[i] for i in range(k - 1, -1, -1))
        labs = next((r.labs for r in itertools.chain([rec], earlier) if r.labs), None)
        if labs is None:
            return None
        latest = max(labs, key=lambda lab: lab.sample_time_ns)
        s = self.settings
        hours = max(rec.window.end_ns - latest.sample_time_ns, 0) / 3.6e12
        std = math.sqrt(s.lab_std**2 + s.moisture_out_jitter_std**2
                        + s.fallback_drift**2 * hours)
        return float(latest.moisture_out), std, latest.sample_id

    def _health(self, rec: TickRecord, k: int, detail: str) -> tuple[str, str]:
        """Status and detail of tick ``k`` (``rec``) before the guard: stale, degraded by
        ``detail`` (a failed model), or the chi-square test of the last
        ``consistency_ticks`` innovations."""
        s = self.settings
        if rec.window.stale:
            reasons = "; ".join(f"{key}: {v}" for key, v in rec.window.reasons.items())
            return "stale", "stale window, predicting without correction" + (
                f": {reasons}" if reasons else "")
        if detail:
            return "degraded", detail
        recent = [r.innovation for r in self._history[max(0, k - (s.consistency_ticks - 1)):k]]
        verdict = chi_square_test([*recent, rec.innovation], s.consistency_alpha)
        detail = verdict.detail
        if rec.held:
            detail += f"; holding last value of {', '.join(rec.held)}"
        return verdict.status, detail

    def _guard(self, rec: TickRecord, k: int, out: _Posterior, failed: bool, status: str,
               detail: str) -> tuple[float, float, bool, str, str]:
        """The published ``moisture_out``, its standard deviation, whether it is the
        lab-anchored fallback, and status and detail after the guard (module docstring)."""
        mo = float(out.y_mean[_MO]) if math.isfinite(out.y_mean[_MO]) else math.nan
        mo_std = (math.sqrt(max(out.y_var[_MO], 0.0) + self.settings.moisture_out_jitter_std**2)
                  if math.isfinite(mo) else math.nan)
        fallback = False
        lost = "" if rec.window.stale else self._lost(out.x, failed)
        if lost or not math.isfinite(mo):
            anchor = self._fallback(rec, k)
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
        suspect = "" if rec.window.stale else self._suspect(out.x)
        if suspect:
            status = "degraded"
            detail = f"{suspect}; {detail}"
        return mo, mo_std, fallback, status, detail

    def _body(self, rec: TickRecord, k: int, out: _Posterior, detail: str) -> dict[str, Any]:
        """The estimate body of tick ``k`` (``rec``); ``detail`` says why the model failed
        ('' when it did not). ``lab_updated`` is set by :meth:`tick`."""
        s = self.settings
        status, health = self._health(rec, k, detail)
        mo, mo_std, fallback, status, health = self._guard(rec, k, out, bool(detail), status,
                                                           health)
        clipped = math.isfinite(mo) and not s.lab_min <= mo <= s.lab_max
        if clipped:
            mo = min(max(mo, s.lab_min), s.lab_max)
        x, P = out.x, out.P
        x_in, x_in_std = self._inlet_moments(x, P)
        inn = rec.innovation
        return {
            "moisture_out": _num(mo),
            "moisture_out_std": _num(mo_std),
            "moisture_out_window_std": _num(math.sqrt(max(out.y_var[_MO], 0.0))),
            "moisture_in": x_in,
            "moisture_in_std": x_in_std,
            "moisture_out_bias": float(x[X_BIAS]),
            "moisture_out_bias_std": float(math.sqrt(P[X_BIAS, X_BIAS])),
            "T_air_in_offset": float(x[X_HEAT]),
            "T_offset": float(self.heat_gain * x[X_HEAT]),
            "T_dryer_out_offset": float(x[X_TDRY]),
            "T_cyclone_out_offset": float(x[X_TCYC]),
            "T_dryer_out_model": _num(out.y_mean[0]),
            "T_cyclone_out_model": _num(out.y_mean[1]),
            "T_dryer_out_model_raw": _num(float(out.model_T[0])),
            "T_cyclone_out_model_raw": _num(float(out.model_T[1])),
            "fallback": fallback,
            "clipped": clipped,
            "nis": inn.nis if inn.dof else None,
            "nis_dof": inn.dof,
            "labs_applied": [r.sample_id for r in rec.labs],
            "lab_updated": bool(rec.labs),
            "status": status,
            "detail": health,
            "discrepancy_priors": self.priors.source,
            "window_start_ns": int(rec.window.start_ns),
            "window_end_ns": int(rec.window.end_ns),
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


#: Largest magnitude of a filter state or covariance entry a checkpoint may hold (the states
#: are kg/kg and K, in transformed units of order 1 to 100).
_STATE_LIMIT = 1e3
_COVARIANCE_LIMIT = 1e6


def _check_state(x: np.ndarray, P: np.ndarray, hold: np.ndarray) -> None:
    """:class:`EstimationError` for a restored state no filter could have reached: non-finite,
    huge, or a covariance that is not symmetric positive definite (a NaN state used to be
    accepted and no estimate was ever published again; ``x = 1e308`` was published)."""
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P)) and np.all(np.isfinite(hold))):
        raise EstimationError("checkpoint state holds non-finite values")
    if np.max(np.abs(x)) > _STATE_LIMIT or np.max(np.abs(P)) > _COVARIANCE_LIMIT:
        raise EstimationError("checkpoint state is out of range")
    if not np.allclose(P, P.T, rtol=1e-9, atol=1e-12) or np.linalg.eigvalsh(P)[0] <= 0:
        raise EstimationError("checkpoint covariance is not symmetric positive definite")
