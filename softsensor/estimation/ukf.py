"""The virtual sensor: an unscented Kalman filter that sees the unmeasured inlet moisture.

The paper's validation failed where the inlet fibre moisture moved: the outlet-temperature PID
moves ``T_air_in`` to hide the thermal signature, and the open-loop model, fed the nominal inlet
moisture, misses it. Here the filter carries ``moisture_in`` as a state and corrects it every
600 s tick with the two measured outlet temperatures (fed the *measured* ``T_air_in``, the model
needs the right inlet moisture to reproduce ``T_dryer_out``), and with the lab's outlet moisture
whenever a result arrives, tens of minutes after its sample time.

State choice (numbers for ``dryer1`` at its nominal point, ``DryerModel`` of 2026-11-21)
---------------------------------------------------------------------------------------
* Fibre and air profiles cross the tube in ~3 s and the cyclone in a few seconds: algebraic at
  a 600 s tick (the model already solves them as a steady profile, :mod:`softsensor.model`).
* The 50 tube-wall and 5 cyclone-shell temperatures are slow states that mostly settle within
  one tick: after a step of ``T_air_in`` 485 -> 500 K (inputs then constant) the first window
  ends 0.059 K (of 4.58 K) short of the new steady ``T_dryer_out`` and 0.12 K (of 4.49 K) short
  of ``T_cyclone_out``; the rest shrinks 2.3 to 2.8-fold per tick (time constants ~10-12 min).
  A step of ``moisture_in`` 1.0 -> 1.1 leaves 0.023 K and 0.050 K. They are driven by the
  measured inputs and by ``moisture_in``; their uncertainty is only the image of the inlet
  moisture's, a tick late and shrunk ~2.5-fold. So they are not filtered: every sigma point
  steps them from the shared mean (one batched ``DryerModel.simulate`` call, 7 members ~8 ms)
  and the posterior wall is the unscented conditional mean ``w = sum W_m w_i + P_wz S^-1 nu``
  (a "consider" state). Filtering them would take 2 x 58 + 1 = 117 sigma points (115 members
  cost 0.125 s a tick) for information the outlet temperatures already carry.
* ``moisture_in`` [kg/kg]: random walk, ``estimator.moisture_in_walk`` per sqrt(h); a step is
  taken at once by covariance matching (:meth:`UkfEstimator._match_covariance`).
* ``T_air_in_error`` [K]: white, redrawn each tick (``estimator.T_air_in_error_std``). With the
  true inlet moisture, the model fed window means misses the plant's window-mean outlet
  temperatures by 0.07 K (common to both channels, correlation 1.0) and its outlet moisture
  by 0.001 kg/kg, the two errors tied as a heat-input error ties them (regression -0.012
  kg/kg per K, correlation -0.95): the loop moves ``T_air_in`` within the window and the model
  is nonlinear. Treated as temperature noise instead, this error is all blamed on the inlet
  moisture and the outlet-moisture interval is too wide: on ``inlet_moisture`` days (seeds
  1-3) the 95 % interval held the truth at 99.7-100 % of ticks, with this state at 97-98 %.
* ``moisture_out_bias`` [kg/kg]: random walk added to the model's outlet moisture, last in the
  state. It earns its place when the calibrated model is off: the temperatures pin
  ``moisture_in`` through the energy balance, so without it the lab cannot correct a kinetic
  error. On ``inlet_moisture`` days whose plant has ``mult_D`` 15 % above the model's, it takes
  the outlet-moisture RMSE from 0.015-0.026 to 0.007-0.010 kg/kg (seeds 1-3). Its prior is
  tight (the calibrated model is trusted) and widened by covariance matching when a lab
  disagrees, so on a well-calibrated plant the reported uncertainty stays honest.

Measurements: ``T_dryer_out`` and ``T_cyclone_out`` window means every tick, variance
``sensor_std² / n_good + model_std²``; ``moisture_out`` (model + bias) for each lab result,
variance ``lab_std² + moisture_out_jitter_std²`` (a grab sample sees the outlet moisture's
jitter within the window, 0.004 kg/kg on the virtual plant). Measurement sizes vary, so
each filterpy ``update()`` gets its own ``hx`` and a full-size ``R`` (STACK.md). The model
outputs of all sigma points come from one batched model call before the update; ``hx`` only
looks them up.

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
the reason.

Each tick's body (``/softsensor/estimate``) holds the now-cast ``moisture_out`` (model + bias,
posterior mean at the window's end), ``moisture_in``, their standard deviations, the model
temperatures, the normalised innovation squared ``nis`` (``nu^T S^-1 nu``) with ``nis_dof``, and
``status``/``detail`` for the health topic: ``stale`` for a stale window (predict only),
``degraded`` when the innovations fail the chi-square test of :mod:`.consistency`.
``moisture_out_std`` is the uncertainty of the outlet moisture *at the tick*: the window
estimate's (``moisture_out_window_std``) plus the short-term jitter a window cannot follow
(``estimator.moisture_out_jitter_std``), so its 95 % interval is the one to hold a grab sample
or an instantaneous truth against. ``notes`` lists covariance-matching events (a step of the
inlet moisture, a lab that moved the bias).
"""

from __future__ import annotations

import logging
import math
from typing import Any, Protocol

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from softsensor.errors import ConfigError, EstimationError, SoftsensorError
from softsensor.estimation.base import LabResult, Window
from softsensor.estimation.consistency import Innovation, chi_square_test
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

#: Filter state layout.
STATE_NAMES: tuple[str, ...] = ("moisture_in", "T_air_in_error", "moisture_out_bias")
X_IN, X_TA, X_BIAS = 0, 1, 2
_T_AIR_IN = INPUT_NAMES.index("T_air_in")
_MO = OUTPUT_NAMES.index("moisture_out")
_CHECKPOINT_VERSION = 1


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


class _SigmaLookup:
    """``hx`` for filterpy: returns the precomputed measurement of each sigma point in turn.

    filterpy calls ``hx`` once per row of ``sigmas_f``, in order; the lookup checks that the
    point it is handed is the one it computed for, so a change in filterpy cannot silently
    pair the wrong outputs with a sigma point.
    """

    def __init__(self, sigmas: np.ndarray, h: np.ndarray) -> None:
        self.sigmas, self.h, self.i = sigmas, h, 0

    def __call__(self, s: np.ndarray) -> np.ndarray:
        if self.i >= len(self.sigmas) or not np.array_equal(s, self.sigmas[self.i]):
            raise EstimationError("filterpy handed hx a sigma point it was not computed for")
        self.i += 1
        return self.h[self.i - 1]


class UkfEstimator:
    """Unscented Kalman filter of the inlet moisture, an effective ``T_air_in`` error and the
    outlet-moisture bias (module docstring).

    Parameters
    ----------
    config : PlantConfig
        Plant configuration, with calibrated parameter values (``load_parameters``); its
        optional ``[estimator]`` table gives the :class:`EstimatorSettings`.
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
        n = len(STATE_NAMES)
        self._points = MerweScaledSigmaPoints(n, s.sigma_alpha, s.sigma_beta, s.sigma_kappa)
        self._ukf = UnscentedKalmanFilter(dim_x=n, dim_z=1, dt=self.window_s, hx=None,
                                          fx=_transition, points=self._points)
        self._ukf.Q = np.diag([s.walk_per_window(s.moisture_in_walk, self.window_s) ** 2,
                               s.T_air_in_error_std**2,
                               s.walk_per_window(s.moisture_out_bias_walk, self.window_s) ** 2])
        nominal = config.nominal
        self._x_in_nominal = float(nominal.moisture_in)
        self._hold = InputHold(config.nominal_inputs())
        self._state = FilterState(np.array([self._x_in_nominal, 0.0, 0.0]),
                                  np.diag([s.moisture_in_std0**2, s.T_air_in_error_std**2,
                                           s.moisture_out_bias_std0**2]),
                                  None)
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

    # ------------------------------------------------------------------ internals
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
        """Outlier test of ``lab`` against the estimate ``body`` of its tick.

        Returns the reason to refuse it (None when it passes) and the side it fell on (+1
        above, -1 below the estimate, 0 when it passes). A lone outlier is refused; a second
        one in a row on the same side is accepted by :meth:`add_lab`: two lab results agreeing
        against the estimate say the model is off, and refusing them would lock the filter out
        of the very information that corrects it.
        """
        mean, std = body.get("moisture_out"), body.get("moisture_out_std")
        if mean is None or std is None:
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

    def _run(self, rec: TickRecord) -> FilterState:
        """Filter one tick from ``rec.start``; fill ``rec.body``/``rec.innovation``; new state."""
        s = self.settings
        start = rec.start
        temps = temperatures(rec.window, s.temperature_sensor_std, s.temperature_model_std)
        wall = start.wall
        detail = ""
        if wall is None:
            u0 = rec.u.copy()
            u0[MOISTURE_IN] = np.clip(start.x[X_IN], s.moisture_in_min, s.moisture_in_max)
            try:
                wall = self.model.steady_state(u0, self.theta)[0]
            except (SoftsensorError, ValueError) as exc:  # predict only, retry next tick
                detail = f"model initialisation failed: {exc}"
        ukf = self._ukf
        ukf.x, ukf.P = start.x.copy(), start.P.copy()
        ukf.predict()
        x, P = ukf.x.copy(), _symmetric(ukf.P)
        raw = None
        if wall is not None:
            raw, detail = self._outputs(ukf.sigmas_f, rec.u, wall, detail)
        innovation = Innovation()
        notes: list[str] = []
        rows, z, R, names = self._measurements(temps, rec.labs)
        if raw is not None:
            for i in (X_IN, X_BIAS) if rows else ():
                if i == X_BIAS and not rec.labs:
                    continue
                note = self._match_covariance(i, raw, rows, z, R)
                if note and i == X_IN:
                    raw, detail = self._outputs(ukf.sigmas_f, rec.u, wall, detail)
                    if raw is None:
                        break
                if note:
                    notes.append(note)
        if raw is None:
            y_mean = y_var = np.full(3, np.nan)
            new_wall = wall
        else:
            sigmas = ukf.sigmas_f.copy()
            g = self._with_bias(raw, sigmas)
            wm, wc = self._points.Wm, self._points.Wc
            post = wm @ g
            dg = g - post
            y_mean = post[:3]
            y_var = (wc[:, None] * dg[:, :3] ** 2).sum(0)
            if rows:
                h = g[:, rows]
                dh = h - wm @ h
                ukf.update(z, R=R, hx=_SigmaLookup(sigmas, h))
                x, P = ukf.x.copy(), _symmetric(ukf.P)
                gain = ((wc[:, None] * dg).T @ dh) @ ukf.SI
                post = post + gain @ ukf.y
                y_mean = post[:3]
                y_var = y_var - np.einsum("ij,jk,ik->i", gain[:3], ukf.S, gain[:3])
                innovation = Innovation(float(ukf.y @ ukf.SI @ ukf.y), len(rows),
                                        _per_channel(names, ukf.y / np.sqrt(np.diag(ukf.S))))
            new_wall = post[3:]
        x[X_IN] = float(np.clip(x[X_IN], s.moisture_in_min, s.moisture_in_max))
        _check_covariance(P, rec.window.end_ns)
        rec.innovation = innovation
        rec.body = self._body(rec, x, P, y_mean, y_var, detail)
        rec.body["notes"] = notes
        return FilterState(x, P, None if new_wall is None else np.array(new_wall, float))

    @staticmethod
    def _with_bias(raw: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
        """Sigma-point outputs with the outlet-moisture bias added."""
        g = raw.copy()
        g[:, _MO] += sigmas[:, X_BIAS]
        return g

    def _match_covariance(self, i: int, raw: np.ndarray, rows: list[int], z: np.ndarray,
                          R: np.ndarray) -> str:
        """Widen the prior variance of state ``i`` when the innovation says it moved more than
        its random walk allows (covariance matching, Mehra 1972, "Approaches to adaptive
        filtering"); returns a note ('' when nothing changed).

        With ``h = Cov(z, x_i) / P_ii`` the sensitivity of the measurements to the state (from
        the prior sigma points), ``S`` the innovation covariance and ``nu`` the innovation,
        ``t = h^T S^-1 nu / sqrt(h^T S^-1 h)`` is the innovation's component along what a
        change of ``x_i`` would do, in standard deviations (for the bias and one lab result it
        is the lab innovation conditional on the tick's temperatures). When ``|t|`` exceeds the
        threshold (``estimator.moisture_in_adapt`` / ``moisture_out_bias_adapt``), ``P_ii``
        grows by ``(t² - 1) / (h^T S^-1 h)``, after which that component is one standard
        deviation. So a step of the inlet moisture is taken at once instead of over many ticks,
        and a lab that shows the model is off moves the bias at once, while the random walks
        stay small and the reported uncertainty honest on a quiet plant. A mismatch no change
        of the state can explain (one temperature channel off) is left to the chi-square test.

        Widening ``P_ii`` changes the sigma points: for the bias (last in the state, filterpy's
        upper Cholesky factor) only their bias coordinates, so ``raw`` stays valid; for the
        inlet moisture the caller evaluates the model again.
        """
        ukf, pts = self._ukf, self._points
        thr = self.settings.moisture_in_adapt if i == X_IN else \
            self.settings.moisture_out_bias_adapt
        h_sig = self._with_bias(raw, ukf.sigmas_f)[:, rows]
        dh = h_sig - pts.Wm @ h_sig
        S = (pts.Wc[:, None] * dh).T @ dh + R
        nu = z - pts.Wm @ h_sig
        dx = ukf.sigmas_f[:, i] - pts.Wm @ ukf.sigmas_f[:, i]
        h = (pts.Wc * dx) @ dh / ukf.P[i, i]
        w = np.linalg.solve(S, h)
        info = float(h @ w)
        if not info > 0:
            return ""
        t = float(w @ nu) / math.sqrt(info)
        if abs(t) <= thr:
            return ""
        P = ukf.P.copy()
        P[i, i] += (t * t - 1.0) / info
        sigmas = pts.sigma_points(ukf.x, P)
        if i == X_BIAS and not np.allclose(sigmas[:, :X_BIAS], ukf.sigmas_f[:, :X_BIAS],
                                           rtol=0, atol=1e-12):
            raise EstimationError("bias adaptation moved the model-input sigma points")
        ukf.P, ukf.sigmas_f = P, sigmas
        what = "inlet moisture" if i == X_IN else "outlet-moisture bias"
        msg = (f"measurements {abs(t):.1f} sigma from the model along the {what}: its prior "
               f"widened to {math.sqrt(P[i, i]):.4f} kg/kg")
        log.info(msg)
        return msg

    def _outputs(self, sigmas: np.ndarray, u: np.ndarray, wall: np.ndarray, detail: str
                 ) -> tuple[np.ndarray | None, str]:
        """Model outputs and end walls of every sigma point, ``(2n+1, 3 + n_state)``, without
        the bias (None and the reason when a solve failed)."""
        s = self.settings
        U = np.repeat(u[None, None, :], len(sigmas), axis=0)
        U[:, 0, MOISTURE_IN] = np.clip(sigmas[:, X_IN], s.moisture_in_min, s.moisture_in_max)
        U[:, 0, _T_AIR_IN] += sigmas[:, X_TA]
        Y, walls = self.model.simulate(U, self.theta, state0=wall, raise_on_failure=False)
        Y = Y[:, 0, :]
        if not np.all(np.isfinite(Y)):
            bad = int(np.flatnonzero(~np.isfinite(Y).all(1))[0])
            return None, (f"model solve failed at sigma point moisture_in="
                          f"{U[bad, 0, MOISTURE_IN]:.3f}: predict only")
        return np.hstack([Y, walls]), detail

    def _measurements(self, temps: TemperatureMeasurement, labs: list[LabResult]
                      ) -> tuple[list[int], np.ndarray, np.ndarray, list[str]]:
        """Rows of the model output used, measured values, full-size R, channel names."""
        rows = list(temps.channels)
        values = list(temps.values)
        var = list(temps.variances)
        names = [OUTPUT_NAMES[c] for c in temps.channels]
        for lab in labs:
            rows.append(_MO)
            values.append(lab.moisture_out)
            var.append(self.settings.lab_std**2 + self.settings.moisture_out_jitter_std**2)
            names.append("moisture_out (lab)")
        return rows, np.array(values, float), np.diag(var), names

    def _body(self, rec: TickRecord, x: np.ndarray, P: np.ndarray, y_mean: np.ndarray,
              y_var: np.ndarray, detail: str) -> dict[str, Any]:
        """The estimate body of one tick (``lab_updated`` is set by :meth:`tick`)."""
        window = rec.window
        jitter = self.settings.moisture_out_jitter_std
        recent = [r.innovation for r in self._history if r.window.end_ns < window.end_ns]
        recent = recent[max(0, len(recent) - (self.settings.consistency_ticks - 1)):]
        verdict = chi_square_test([*recent, rec.innovation], self.settings.consistency_alpha)
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
        inn = rec.innovation
        return {
            "moisture_out": _num(y_mean[_MO]),
            "moisture_out_std": _num(math.sqrt(max(y_var[_MO], 0.0) + jitter**2)),
            "moisture_out_window_std": _num(math.sqrt(max(y_var[_MO], 0.0))),
            "moisture_in": float(x[X_IN]),
            "moisture_in_std": float(math.sqrt(P[X_IN, X_IN])),
            "moisture_out_bias": float(x[X_BIAS]),
            "moisture_out_bias_std": float(math.sqrt(P[X_BIAS, X_BIAS])),
            "T_dryer_out_model": _num(y_mean[0]),
            "T_cyclone_out_model": _num(y_mean[1]),
            "nis": inn.nis if inn.dof else None,
            "nis_dof": inn.dof,
            "labs_applied": [r.sample_id for r in rec.labs],
            "lab_updated": bool(rec.labs),
            "status": status,
            "detail": detail,
            "window_start_ns": int(window.start_ns),
            "window_end_ns": int(window.end_ns),
            "estimator": self.kind,
        }


def _transition(x: np.ndarray, dt: float) -> np.ndarray:
    """State transition over one window: random walks keep their value, the white
    ``T_air_in`` error is redrawn (its process noise ``Q`` is its whole variance)."""
    out = x.copy()
    out[X_TA] = 0.0
    return out


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
