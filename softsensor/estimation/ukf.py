"""The virtual sensor: an unscented Kalman filter of the inlet moisture and the model's error.

The outlet-temperature loop moves ``T_air_in`` to hide the thermal signature of the inlet
moisture, so an open-loop model fed the nominal inlet moisture misses it. Here the filter
carries ``moisture_in`` as a state and corrects it every 600 s tick with the two measured
outlet temperatures (the model, fed the *measured* ``T_air_in``, needs the right inlet
moisture to reproduce them), and with the lab's outlet moisture whenever a result arrives,
tens of minutes after its sample time. Because a real dryer is never the model, the state also
carries the model's own slowly varying error (:mod:`.state_space`): an offset of the heat
input it sees, two per-channel temperature offsets, an outlet-moisture bias and the error of
its outlet-moisture response to the inlet moisture; and the measurement model adds what the
plant's history says the model misses at the window's operating point (:mod:`.model_error`,
PARAMS.toml's ``[model_error]``), so that the error states track only what is left.

One tick (:func:`~.ukf_step.step`, pure)
----------------------------------------
1. *Predict* (linear, exact): the inlet moisture a mean-reverting walk, the error states
   first-order processes or random walks: ``x = F x + (I - F) x_ref``, ``P = F P F' + Q``
   (``filterpy.kalman.predict``), ``Q``'s diagonal inflated per channel by the
   innovation-based adaptation (:class:`~.state_space.AdaptiveNoise`).
2. *Sigma points* of the prior (filterpy's ``MerweScaledSigmaPoints``). Only the inlet moisture
   and the heat input's offset enter the model (:data:`~.state_space.MODEL_STATES`), so the
   sigma points hold five distinct pairs of them; the model is stepped over the window for
   those, for each point's heat input at the reference inlet moisture (the inlet gain's
   response), and for four probes about the mean (partial derivatives for step 4): one batched
   call from the current wall temperatures. A lab result sampled in the window adds one
   batched short step to its sample time (:mod:`softsensor.windows.lab_alignment`, the
   calibration's alignment).
3. *Measurements*: ``T_dryer_out = y_d(X_in, T_air_in + offset) + g_d + T_dryer_out_offset``,
   the same for ``T_cyclone_out``, and per lab result ``y(X_ref) + (1 + inlet_gain) (y(X_in) -
   y(X_ref)) + g_m + moisture_out_bias`` (``g``: the learned discrepancy, its variance added
   to the row's), variances from the history's white residuals (without one: ``sensor_std^2 /
   n_good + model_std^2`` and ``lab_std^2 + jitter^2``); a missing temperature or a tick
   without lab drops its row, so the size varies tick to tick.
4. *Covariance matching* before the update (Mehra 1972, :mod:`.jump_matching`): when the
   innovation along what a change of the inlet moisture (of one channel's offset; of the bias,
   with a lab) would do is more than ``moisture_in_adapt`` (``offset_adapt``;
   ``moisture_out_bias_adapt``) standard deviations, that state's prior variance grows until
   it is one: a step of the inlet moisture or of one thermometer is taken at once. The model
   is then run at the new sigma points.
5. *Update*: filterpy's ``unscented_transform`` of the joint sigma points (state, published
   outputs, the model's own temperatures, walls, predicted measurements) gives their mean and
   joint covariance; ``filterpy.kalman.update``, with a measurement matrix that selects the
   predicted measurements, conditions that Gaussian on the measured values: the unscented
   update written as the linear Kalman update of the joint Gaussian, which also conditions the
   published outputs and the walls (a "consider" state that mostly settles within a tick).

Why filterpy's functions and not its ``UnscentedKalmanFilter``: the class calls ``hx`` once
per sigma point, where the model here runs once, batched over the distinct model inputs;
covariance matching changes ``P`` between the model run and the update; and the measurement
vector changes size. ``tests/estimation/test_ukf.py`` checks a tick against the class with the
model in ``hx``.

Published (:mod:`.publication`): the now-cast ``moisture_out`` with ``moisture_out_std`` (its
uncertainty plus the short-term jitter a 600 s window cannot follow, so its 95 % band is the
one to hold a grab sample against), ``moisture_in`` and its standard deviation, the error
states, the model temperatures, ``nis``, and ``status``/``detail``; a lab-anchored fallback
when the model has lost the plant.

Why this design, and what else was tried on the independent plant: the documentation's
explanation of the estimator (``docs/explanation/estimator.md``).

Late lab results
----------------
The estimator keeps a history of ticks (``estimator.history_hours``): window, inputs, the
filter state at the start of the tick and the lab results applied there. A result whose sample
time lies in a past window is attached to that tick, and the next :meth:`UkfEstimator.tick`
re-filters from it to now, so the current estimate is exactly what it would have been had the
lab been on time; results arriving out of order give the same estimate as in order. A result
sampled after the last tick is applied at the coming one (results wait for their window in
the service's queue, not here). Older than the history: logged and skipped. Duplicate
``sample_id``: ignored. A value further than ``estimator.lab_gate`` standard deviations from
the estimate at its sample time: refused with the reason (a second one in a row on the same
side is taken: the model is off, not the lab). Its values need no other check: a
:class:`~softsensor.messages.LabResult` holds the lab-result contract.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import Any

import numpy as np

from softsensor.errors import ConfigError, EstimationError, SoftsensorError
from softsensor.estimate import Estimate
from softsensor.estimation import peer_blend
from softsensor.estimation.interface import LabResult, ModelEstimator, Window, WindowModel
from softsensor.estimation.lab_regression import regression_of
from softsensor.estimation.model_error import model_error_of
from softsensor.estimation.publication import TickContext, at_tick, blended, physics
from softsensor.estimation.settings import EstimatorSettings
from softsensor.estimation.state_space import (
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
from softsensor.estimation.tick_history import FilterState, LabBook, TickRecord
from softsensor.estimation.ukf_step import FilterModel, TickData, step
from softsensor.estimation.unscented import MerweScaledSigmaPoints
from softsensor.plantconfig import PlantConfig, made_with
from softsensor.signals import INPUT_NAMES
from softsensor.windows.inputs import InputHold

log = logging.getLogger(__name__)

_T_AIR_IN = INPUT_NAMES.index("T_air_in")
_CHECKPOINT_VERSION = 3


class UkfEstimator(ModelEstimator):
    """Unscented Kalman filter of the inlet moisture and the model's error (module docstring).

    Parameters
    ----------
    config : PlantConfig
        Plant configuration with calibrated parameter values (``load_parameters``, which also
        carries the calibration's ``[discrepancy]`` and ``[model_error]``); its optional
        ``[estimator]`` table gives the :class:`EstimatorSettings`.
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
        self.max_history = s.history_ticks(self.window_s)
        if s.consistency_ticks > self.max_history:
            raise ConfigError(f"{config.source}: estimator.consistency_ticks must be <= the "
                              f"history ({self.max_history} ticks), got {s.consistency_ticks}")
        self.filter = _filter_model(config, s, self.model, self.theta, self.window_s)
        #: the history's lab regression, run beside the physics (:mod:`.peer_blend`)
        self.regression = regression_of(config)
        self._hold = InputHold(config.nominal_inputs())
        self._state = self._initial_state()
        self._history: list[TickRecord] = []
        self._dirty: int | None = None
        #: what the state is made with, written into every checkpoint (hashes of the
        #: calibration: fixed for the estimator's life, so computed once, not at every tick)
        self._made_with = made_with(self.config)
        #: refused outliers in a row, signed by their side (+ above the estimate, - below)
        self._gate_streak = 0
        #: the gate's prior until a lab is taken: the spread the calibration gives the
        #: model's outlet moisture against the labs, the history's held-out error or the bias
        #: state's prior, whichever is wider; a fresh filter's wider spread does not let any
        #: first lab through (issue 49: 0.02 kg/kg against 0.11 taken, refused at 17.8 sigma
        #: once the filter had settled)
        me = model_error_of(config)
        self._gate_sd = max(self.priors.sd("moisture_out_bias"),
                            0.0 if me is None else me.moisture_out.rmse_held_out)
        #: the last outlier taken as the second of a streak, until a result confirms or
        #: contradicts it: sample_id, side, and the estimate (mean, sd) it was judged against
        self._taken: dict[str, Any] | None = None

    @property
    def inlet(self) -> InletTransform:
        return self.filter.inlet

    @property
    def priors(self) -> ErrorPriors:
        return self.filter.priors

    @property
    def heat_gain(self) -> float:
        return self.filter.heat_gain

    # ------------------------------------------------------------------ Estimator protocol
    def tick(self, window: Window) -> Estimate:
        """Advance to ``window.end_ns``: apply late labs, predict, correct; the estimate."""
        if self._history and window.end_ns <= self._history[-1].window.end_ns:
            raise EstimationError(f"window ending at {window.end_ns} ns is not after the last "
                                  f"tick ({self._history[-1].window.end_ns} ns)")
        late = self._dirty is not None
        notes = self._apply_late_labs()
        labs = []
        last = self._history[-1].estimate if self._history else None
        for lab in self._labs.take_due(window.end_ns):
            if lab.sample_time_ns <= window.start_ns - self.window_s * 1e9:
                log.warning("lab %r: sample time %d ns falls in a gap before window %d..%d ns; "
                            "skipped", lab.sample_id, lab.sample_time_ns, window.start_ns,
                            window.end_ns)
            elif not self._screen(lab, last):
                labs.append(lab)
        if self._dirty is not None:  # a result here withdrew a taken outlier: at once
            late = True
            notes += self._apply_late_labs()
        u, held = self._hold.inputs(window)
        rec = TickRecord(window, u, tuple(held), self._state, tuple(labs))
        self._state, rec = self._run(rec, len(self._history))
        self._history.append(rec)
        if len(self._history) > self.max_history:
            del self._history[: len(self._history) - self.max_history]
        self._labs.prune(self._history[0].window.start_ns)
        assert rec.estimate is not None
        return at_tick(rec.estimate, lab_updated=late, notes=tuple(notes),
                       refused_streak=self._gate_streak)

    def _apply_late_labs(self) -> list[str]:
        """Re-filter from the earliest tick a late (or withdrawn) lab changed; its notes."""
        if self._dirty is None:
            return []
        self._refilter(self._dirty)
        notes = [n for r in self._history[self._dirty:] for n in r.estimate.notes]
        self._dirty = None
        return notes

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
        refused = self._screen(lab, rec.estimate)
        if refused:
            return refused
        self._history[j] = rec.with_labs((*rec.labs, lab))
        self._dirty = j if self._dirty is None else min(self._dirty, j)
        return None

    def checkpoint(self) -> dict[str, Any]:
        """JSON-able snapshot: filter state, history, labs, held inputs, and what the state
        was made with (:func:`~softsensor.plantconfig.made_with`)."""
        return {"kind": self.kind, "version": _CHECKPOINT_VERSION,
                "made_with": self._made_with,
                "state": self._state.to_json(), "hold": self._hold.last.tolist(),
                "labs": self._labs.to_json(), "dirty": self._dirty,
                "gate_streak": self._gate_streak, "taken_outlier": self._taken,
                "history": [r.to_json() for r in self._history]}

    def restore(self, snapshot: dict[str, Any]) -> None:
        """Continue from :meth:`checkpoint` output; EstimationError if it does not fit.

        A checkpoint made with another calibration (parameters, structure, model error,
        discrepancy or regression: :func:`~softsensor.plantconfig.made_with`) keeps what the
        plant is doing, the inlet moisture and its variance, and starts the rest afresh from
        this calibration's priors: the model's error states, the walls, the noise
        adaptation and the peers' weights belong to the old model and would pass its errors
        off as the new one's. The kept hours are filtered again with the
        new model at the next tick, so late lab results still find their ticks.
        """
        self._check_snapshot(snapshot, _CHECKPOINT_VERSION)
        try:
            state = FilterState.from_json(snapshot["state"])
            history = [TickRecord.from_json(r) for r in snapshot["history"]]
            labs = LabBook.from_json(snapshot["labs"])
            hold = np.array(snapshot["hold"], float)
            dirty = snapshot["dirty"]
            streak = int(snapshot["gate_streak"])
            taken = snapshot.get("taken_outlier")  # absent in checkpoints before issue 31
            if taken is not None:
                taken = {"sample_id": str(taken["sample_id"]), "side": int(taken["side"]),
                         "value": float(taken["value"]), "mean": float(taken["mean"])}
            AdaptiveNoise.from_json(state.adapt)
            for rec in [*history, None]:
                peer_blend.check_state((rec.start if rec else state).peers)
        except (KeyError, TypeError, ValueError) as exc:
            raise EstimationError(f"checkpoint is malformed: {exc!r}") from exc
        n = len(STATE_NAMES)
        m = len(INPUT_NAMES)
        if state.x.shape != (n,) or state.P.shape != (n, n) or hold.shape != (m,):
            raise EstimationError(f"checkpoint state has shapes x{state.x.shape} "
                                  f"P{state.P.shape} hold{hold.shape}, expected ({n},), "
                                  f"({n}, {n}) and ({m},)")
        _check_state(state.x, state.P, hold)
        old = snapshot.get("made_with")  # absent from checkpoints before issue 38
        # a part the checkpoint's writer did not fingerprint yet (PARAMS.toml's [sensor],
        # issue 47) is not a change
        changed = [] if old is None else [k for k, v in self._made_with.items()
                                          if k in old and old[k] != v]
        if changed:
            fresh = self._initial_state()
            state = self._reseeded(fresh, state)
            if history:
                history[0] = replace(history[0], start=self._reseeded(fresh, history[0].start))
                dirty = 0
            log.warning("checkpoint made under another calibration (changed: %s): the inlet "
                        "moisture carried (%.3f kg/kg), the model's error states started "
                        "afresh from this calibration's priors%s", ", ".join(changed),
                        float(self.inlet.forward(state.x[X_IN])),
                        f", the kept {len(history)} ticks filtered again" if history else "")
        self._state, self._history, self._labs = state, history, labs
        self._hold = InputHold(hold)
        self._dirty = None if dirty is None else int(dirty)
        self._gate_streak, self._taken = streak, taken

    def _initial_state(self) -> FilterState:
        """The state before the first tick: this calibration's priors, the inlet moisture at
        the latest history day's level (the dryer's current state) when there is one."""
        f = self.filter
        P0 = np.zeros((len(STATE_NAMES), len(STATE_NAMES)))
        P0[X_IN, X_IN] = _inlet_sd0(self.config, self.settings) ** 2
        P0[1:, 1:] = f.priors.covariance()
        x0 = f.reference.copy()
        me = model_error_of(self.config)
        if me is not None:
            x0[X_IN] = float(f.inlet.inverse(me.start_moisture_in))
        return FilterState(x0, P0, None, AdaptiveNoise.fresh().to_json())

    @staticmethod
    def _reseeded(fresh: FilterState, old: FilterState) -> FilterState:
        """``fresh`` (this calibration's start) with ``old``'s inlet moisture and variance."""
        x, P = fresh.x.copy(), fresh.P.copy()
        x[X_IN] = old.x[X_IN]
        P[X_IN, :] = P[:, X_IN] = 0.0
        P[X_IN, X_IN] = old.P[X_IN, X_IN]
        return FilterState(x, P, None, dict(fresh.adapt))

    # ------------------------------------------------------------------ lab screening
    def _screen(self, lab: LabResult, estimate: Estimate | None) -> str | None:
        """Outlier screen of ``lab`` against the ``estimate`` at its sample time (None: no
        tick yet): the reason to refuse it, or None (then the caller attaches it).

        A lone outlier is refused. The second in a row on the same side is taken only when
        it agrees with what the temperatures say: the temperatures fix the inlet moisture and
        with it the model's outlet moisture, from which the plant may differ by the model's
        outlet-moisture error, whose spread the bias state's prior holds (the history's, or
        ``moisture_out_bias_std``); a result within ``lab_gate`` of that widened band is
        possible, one beyond it (a copied typo) is refused however often it comes, unless the
        temperatures contradict the model themselves (the estimate at its tick is
        ``degraded``: inconsistent innovations, a lost model, a suspect sensor), when the
        labs lead as before. A later
        result that contradicts a taken outlier (on the other side of the estimate now, and
        nearer the estimate the taken one was judged against than to it) withdraws it: the
        history is filtered again without it at the next tick, and this result is taken.
        """
        gate, side, z_wide = self._gate(lab, estimate)
        taken = self._taken
        mean = None if estimate is None else estimate.moisture_out
        if (taken is not None and mean is not None
                and (lab.moisture_out - mean) * taken["side"] < 0
                and abs(lab.moisture_out - taken["mean"]) < abs(lab.moisture_out
                                                                 - taken["value"])
                and self._withdraw(taken["sample_id"])):
            log.warning("lab %r contradicts the outlier %r taken before (it sides with the "
                        "estimate that one was judged against): that one is withdrawn and "
                        "this result taken", lab.sample_id, taken["sample_id"])
            self._gate_streak, self._taken = 0, None
            return None
        if gate is None:
            self._gate_streak = 0
            if mean is not None:
                self._taken = None  # a result in line with the estimate: nothing to undo
            return None
        head = gate.split("; rejected")[0]
        # a model the temperatures themselves contradict (degraded: inconsistent
        # innovations, lost, a suspect sensor) vouches for no estimate: the labs lead
        status = None if estimate is None else estimate.status
        allowed = z_wide <= self.settings.lab_gate or status == "degraded"
        if side * self._gate_streak > 0 and allowed:
            log.warning("%s, but so was the previous result, on the same side, and the "
                        "temperatures allow it (%.1f sigma with the model's bias spread, "
                        "estimate %s): accepted (the model is off, not the lab)", head, z_wide,
                        status)
            self._gate_streak = 0
            self._taken = {"sample_id": lab.sample_id, "side": side,
                           "value": float(lab.moisture_out), "mean": float(mean)}
            return None
        if side * self._gate_streak > 0:
            gate = (f"{head}, the previous result too, but the temperatures do not allow it "
                    f"({z_wide:.1f} sigma with the model's bias spread); rejected as an "
                    f"outlier")
        self._gate_streak = side * (abs(self._gate_streak) + 1) if \
            side * self._gate_streak > 0 else side
        log.warning(gate)
        return gate

    def _withdraw(self, sample_id: str) -> bool:
        """Take the lab ``sample_id`` out of the history (re-filtered from its tick at the
        next tick); False when it has left the history."""
        for j, rec in enumerate(self._history):
            kept = tuple(lab for lab in rec.labs if lab.sample_id != sample_id)
            if len(kept) < len(rec.labs):
                self._history[j] = rec.with_labs(kept)
                self._dirty = j if self._dirty is None else min(self._dirty, j)
                return True
        return False

    def _gate(self, lab: LabResult, estimate: Estimate | None
              ) -> tuple[str | None, int, float]:
        """Outlier test of ``lab`` against the ``estimate`` of its tick: the reason to refuse
        it (None when it passes), the side it fell on (+1 above, -1 below, 0), and its
        distance in standard deviations once the model's bias spread is added (what the
        temperatures allow, :meth:`_screen`)."""
        if estimate is None:
            return None, 0, 0.0
        mean, std = estimate.moisture_out, estimate.moisture_out_std
        if mean is None or std is None or (estimate.filter is not None
                                           and estimate.filter.fallback):
            return None, 0, 0.0
        s = self.settings
        d = lab.moisture_out - mean
        first = not any(r.labs for r in self._history)  # no lab taken yet: the prior's
        z = d / math.sqrt((min(std, self._gate_sd) if first else std)**2 + s.lab_std**2)
        z_wide = abs(d) / math.sqrt(std**2 + s.lab_std**2
                                    + self.priors.sd("moisture_out_bias") ** 2)
        if abs(z) > s.lab_gate:
            return (f"lab {lab.sample_id!r}: moisture_out {lab.moisture_out:g} kg/kg is "
                    f"{abs(z):.1f} sigma from the estimate {mean:.4f} at its sample time "
                    f"(estimator.lab_gate = {s.lab_gate:g}); rejected as an outlier"), \
                (1 if z > 0 else -1), z_wide
        return None, 0, z_wide

    # ------------------------------------------------------------------ the history
    def _refilter(self, j: int) -> None:
        """Run the history again from tick ``j`` (a late lab was attached there) to now."""
        state = self._history[j].start
        for k in range(j, len(self._history)):
            state, self._history[k] = self._run(replace(self._history[k], start=state), k)
        self._state = state

    def _run(self, rec: TickRecord, k: int) -> tuple[FilterState, TickRecord]:
        """Filter one tick from ``rec.start`` (tick ``k`` of the history, appended after the
        last when new): the new state and the record with what it produced."""
        state, post = step(self.filter, rec.start, TickData(rec.window, rec.u, rec.labs))
        _check_covariance(post.P, rec.window.end_ns)
        for note in post.notes:
            log.info(note)
        s = self.settings
        recent = tuple(r.innovation for r in
                       self._history[max(0, k - (s.consistency_ticks - 1)):k])
        estimate = physics(self.filter, TickContext(rec.window, rec.held, rec.labs, recent,
                                                    self._latest_lab(rec, k)), post, self.kind)
        if s.peer_blend or s.band_conformal:
            peers, blend, mixture = peer_blend.advance(
                s, self.regression, rec.start.peers or peer_blend.fresh(s, self.regression),
                rec.window, rec.labs, (estimate.moisture_out, estimate.moisture_out_std))
            estimate = blended(estimate, blend, mixture, s)
            state = replace(state, peers=peers)
        return state, rec.ran(estimate, post.innovation)

    def _latest_lab(self, rec: TickRecord, k: int) -> LabResult | None:
        """The latest lab result applied at tick ``k`` (``rec``) or before. A tick's results
        are sampled in its window and after the previous tick's, so the latest is in the
        nearest tick that has any."""
        for r in [rec, *(self._history[i] for i in range(k - 1, -1, -1))]:
            if r.labs:
                return max(r.labs, key=lambda lab: lab.sample_time_ns)
        return None


def _filter_model(config: PlantConfig, s: EstimatorSettings, model: WindowModel,
                  theta: np.ndarray, window_s: float) -> FilterModel:
    """The tick-invariant part of the filter (:class:`~.ukf_step.FilterModel`)."""
    me = model_error_of(config)
    inlet = InletTransform(s.moisture_in_min, s.moisture_in_max, s.inlet_margin)
    heat_gain = _heat_gain(model, config.nominal_inputs(), theta)
    priors = ErrorPriors.from_config(config, s, heat_gain)
    inlet_tau = s.moisture_in_tau_h * 3600.0
    F = transition(window_s, priors, inlet_tau)
    q = process_noise(window_s, priors, s.walk_per_window(s.moisture_in_walk, window_s),
                      inlet_tau)
    x_ref = float(config.nominal.moisture_in) if me is None else me.moisture_in
    reference = np.zeros(len(STATE_NAMES))
    reference[X_IN] = float(inlet.inverse(x_ref))
    thresholds = {X_IN: s.moisture_in_adapt, X_HEAT: s.offset_adapt, X_TDRY: s.offset_adapt,
                  X_TCYC: s.offset_adapt, X_BIAS: s.moisture_out_bias_adapt}
    points = MerweScaledSigmaPoints(len(STATE_NAMES), s.sigma_alpha, s.sigma_beta,
                                    s.sigma_kappa)
    return FilterModel(model, np.asarray(theta, float), s, inlet, priors, points, F, q,
                       reference, x_ref, config.solver.lab_span, thresholds, heat_gain, me)


def _inlet_sd0(config: PlantConfig, s: EstimatorSettings) -> float:
    """Prior standard deviation of the inlet moisture at start-up: the settings', or with a
    history the spread of its days' levels (floored) [kg/kg]."""
    me = model_error_of(config)
    if me is None:
        return s.moisture_in_std0
    return max(me.moisture_in_day_sd, s.moisture_in_std_floor)


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
    if not np.allclose(P, P.T, rtol=1e-9, atol=1e-12):
        raise EstimationError("checkpoint covariance is not symmetric positive definite")
    # the filter's own test (a held state's variance of 1e-18 is positive definite to a
    # Cholesky factorisation but reads as a rounding-error negative eigenvalue)
    try:
        np.linalg.cholesky(P)
    except np.linalg.LinAlgError as exc:
        raise EstimationError("checkpoint covariance is not symmetric positive definite") from exc
