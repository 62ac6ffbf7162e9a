"""One tick of the unscented Kalman filter, as a pure function: ``step(filter, state, tick)
-> (state, posterior)``.

:class:`FilterModel` holds what does not change from tick to tick (the model and its
parameters, the settings, the state layout's transition and process noise, the sigma points,
the learned model error); :class:`~softsensor.estimation.tick_history.FilterState` the filter's
state; :class:`TickData` what one tick brings (its window, the inputs after holding, the lab
results sampled in it). :func:`step` does the five steps of :mod:`softsensor.estimation.ukf`'s
docstring and returns the new state and a :class:`Posterior` (state, published outputs and
their variances, the model's own temperatures, walls, innovation). It reads no clock, writes
no log and keeps nothing: the estimator (:class:`~softsensor.estimation.ukf.UkfEstimator`)
keeps the history and publishes (:mod:`.publication`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from softsensor.errors import SoftsensorError
from softsensor.estimation.consistency import Innovation
from softsensor.estimation.interface import LabResult, Window, WindowModel
from softsensor.estimation.jump_matching import jumps, widen
from softsensor.estimation.model_error import ModelError
from softsensor.estimation.settings import EstimatorSettings
from softsensor.estimation.state_space import (
    ADAPT_CHANNELS,
    MODEL_STATES,
    STATE_NAMES,
    X_BIAS,
    X_GAIN,
    X_HEAT,
    X_IN,
    X_TCYC,
    X_TDRY,
    AdaptiveNoise,
    ErrorPriors,
    InletTransform,
    gain_response,
)
from softsensor.estimation.tick_history import FilterState
from softsensor.estimation.unscented import MerweScaledSigmaPoints, unscented_transform
from softsensor.estimation.unscented import predict as kf_predict
from softsensor.estimation.unscented import update as kf_update
from softsensor.signals import INPUT_NAMES, OUTPUT_NAMES
from softsensor.windows.inputs import MOISTURE_IN, temperatures
from softsensor.windows.lab_alignment import sample_inputs, sample_offset

_MO = OUTPUT_NAMES.index("moisture_out")
_T_AIR_IN = INPUT_NAMES.index("T_air_in")
#: The error state added to each kind of measurement row (0: T_dryer_out, 1: T_cyclone_out,
#: 2: a lab result's outlet moisture).
ROW_OFFSET = (X_TDRY, X_TCYC, X_BIAS)
#: Finite-difference steps of the model states for the partial derivatives: the inlet moisture
#: (in the filter's coordinate) [kg/kg] and the heat input [K].
_FD_STEP = {X_IN: 1e-3, X_HEAT: 0.5}


@dataclass(frozen=True)
class FilterModel:
    """What a tick needs besides the state (module docstring).

    ``F``, ``q``: transition and process-noise diagonal (:mod:`.state_space`); ``reference``:
    the state the inlet moisture reverts to (filter coordinate) and ``x_ref`` that inlet
    moisture [kg/kg], the point of the ``inlet_gain``'s response; ``thresholds``: the
    covariance-matching threshold of each state that may jump; ``heat_gain``: the model's gain
    from ``T_air_in`` to the outlet temperatures [K/K] that sized the heat input's prior.
    """

    model: WindowModel
    theta: np.ndarray
    settings: EstimatorSettings
    inlet: InletTransform
    priors: ErrorPriors
    points: MerweScaledSigmaPoints
    F: np.ndarray
    q: np.ndarray
    reference: np.ndarray
    x_ref: float
    lab_span: float
    thresholds: dict[int, float]
    heat_gain: float
    model_error: ModelError | None = None


@dataclass(frozen=True)
class TickData:
    """One tick's data: the window, its model inputs after holding (8,), and the lab results
    sampled in it."""

    window: Window
    u: np.ndarray
    labs: tuple[LabResult, ...] = ()


@dataclass
class Measurements:
    """One tick's measurement rows: their kind (0, 1: temperature channels; 2: a lab result,
    in the order of the tick's labs), measured values less the learned discrepancy, ``R``,
    channel names and the adaptive channel (:data:`~.state_space.ADAPT_CHANNELS`) of each
    row."""

    rows: list[int]
    z: np.ndarray
    R: np.ndarray
    names: list[str]
    channels: list[int]


@dataclass
class Posterior:
    """What a tick produced: state, published outputs (T_d, T_c, moisture_out with their
    error states and the learned discrepancy) and their variances, the model's own
    temperatures, the walls, the innovation, each row's normalised innovation with its
    adaptive channel, the covariance-matching notes and, when the model failed, why."""

    x: np.ndarray
    P: np.ndarray
    y_mean: np.ndarray
    y_var: np.ndarray
    model_T: np.ndarray
    wall: np.ndarray | None
    innovation: Innovation = field(default_factory=Innovation)
    normalised: np.ndarray = field(default_factory=lambda: np.zeros(0))
    channels: list[int] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    failure: str = ""

    @classmethod
    def predicted(cls, x: np.ndarray, P: np.ndarray, wall: np.ndarray | None,
                  failure: str = "", notes: list[str] | None = None) -> Posterior:
        """The prior alone (no model outputs): a tick that could not correct."""
        return cls(x, P, np.full(3, np.nan), np.full(3, np.nan), np.full(2, np.nan), wall,
                   notes=list(notes or []), failure=failure)


@dataclass
class _Sigma:
    """The model at a set of sigma points: window-end outputs (N, 3) at the point and at the
    reference inlet moisture with the point's heat input, walls per point, per lab the outlet
    moisture at its sample time (N, L) likewise, and the derivatives (3 + L) of the outputs
    with respect to each model state with the other held."""

    y: np.ndarray
    y_ref: np.ndarray
    wall: np.ndarray
    lab: np.ndarray
    lab_ref: np.ndarray
    d_in: np.ndarray
    d_heat: np.ndarray


@dataclass
class _LabSteps:
    """Per lab result, the model inputs just before its sample (L, 8) and the step from the
    window's start to its sample time (L,) [s] (:mod:`softsensor.windows.lab_alignment`)."""

    u: np.ndarray
    dt: np.ndarray


def step(filt: FilterModel, state: FilterState, tick: TickData) -> tuple[FilterState, Posterior]:
    """Filter one tick from ``state`` (module docstring); the new state and the posterior."""
    s = filt.settings
    adapt = AdaptiveNoise.from_json(state.adapt)
    Q = np.diag(filt.q * np.r_[1.0, adapt.inflation()])
    x, P = kf_predict(state.x, state.P, filt.F, Q, u=filt.reference,
                      B=np.eye(len(STATE_NAMES)) - filt.F)
    P = _symmetric(P)
    wall, failure = _start_wall(filt, state, tick)
    out = Posterior.predicted(x, P, wall, failure)
    if wall is not None:
        out = _correct(filt, x, P, tick, wall)
        for nu, channel in zip(out.normalised, out.channels, strict=True):
            adapt.update(channel, float(nu) ** 2, s.adapt_ticks, s.adapt_limit)
    new = FilterState(out.x, out.P, None if out.wall is None else np.array(out.wall, float),
                      adapt.to_json())
    return new, out


def _start_wall(filt: FilterModel, state: FilterState, tick: TickData
                ) -> tuple[np.ndarray | None, str]:
    """The wall temperatures at the start of the tick: the state's, or on the first tick
    (and after a failed start) the model's steady state; None and why when that fails
    (predict only, retried next tick)."""
    if state.wall is not None:
        return state.wall, ""
    u0 = tick.u.copy()
    u0[MOISTURE_IN] = float(filt.inlet.forward(state.x[X_IN]))
    try:
        return filt.model.steady_state(u0, filt.theta)[0], ""
    except (SoftsensorError, ValueError) as exc:
        return None, f"model initialisation failed: {exc}"


def learned_offsets(filt: FilterModel, window: Window) -> tuple[np.ndarray, np.ndarray]:
    """What the plant's history says the model misses on the three outputs at ``window``'s
    operating point, and its variance (:mod:`.model_error`, PARAMS.toml's ``[model_error]``;
    zeros without one)."""
    me = filt.model_error
    if me is None:
        return np.zeros(3), np.zeros(3)
    phi = me.phi(window.means)
    return (np.array([float(me.offset(c, phi)) for c in OUTPUT_NAMES]),
            np.array([float(me.offset_var(c, phi)) for c in OUTPUT_NAMES]))


def _correct(filt: FilterModel, x: np.ndarray, P: np.ndarray, tick: TickData,
             wall: np.ndarray) -> Posterior:
    """Steps 2 to 5 of :mod:`.ukf`'s docstring from the prior ``(x, P)``: the posterior, or
    when the model could not be solved the prior and why."""
    g, g_var = learned_offsets(filt, tick.window)
    meas = measurements(filt, tick, g, g_var)
    times = [r.sample_time_ns for r in tick.labs]
    steps = _LabSteps(sample_inputs(tick.window, tick.u, times, filt.lab_span),
                      sample_offset(tick.window.start_ns, np.array(times, np.int64)))
    sig, sigmas, failure = _sigma_outputs(filt, x, P, tick.u, wall, steps)
    notes = []
    if sig is not None and meas.rows:
        P_matched, note = _match_covariance(filt, x, P, sigmas, sig, meas)
        if note:
            notes.append(note)
            P = P_matched
            sig, sigmas, failure = _sigma_outputs(filt, x, P, tick.u, wall, steps)
    if sig is None:
        return Posterior.predicted(x, P, wall, failure, notes)
    post = _update(filt, sigmas, sig, meas)
    # the published outputs are the model's plus what the history says it misses here
    post.y_mean = post.y_mean + g
    post.y_var = post.y_var + g_var
    post.notes = notes
    return post


def measurements(filt: FilterModel, tick: TickData, g: np.ndarray, g_var: np.ndarray
                 ) -> Measurements:
    """The tick's measurement rows: the measured temperature channels, then each lab, less
    the learned discrepancy ``g`` at the window's operating point (its variance ``g_var``
    added). With a ``[model_error]`` a row's noise is at least the white residual the history
    left on that channel."""
    s = filt.settings
    me = filt.model_error
    temps = temperatures(tick.window, s.temperature_sensor_std, s.temperature_model_std)
    rows = list(temps.channels)
    values = [v - g[c] for c, v in zip(temps.channels, temps.values, strict=True)]
    moving = transient_variance(filt, tick.window)
    var = [(v if me is None else max(v, me.channel(OUTPUT_NAMES[c]).noise ** 2)) + g_var[c]
           + moving for c, v in zip(temps.channels, temps.variances, strict=True)]
    names = [OUTPUT_NAMES[c] for c in temps.channels]
    channels = list(temps.channels)
    lab_var = (s.lab_std**2 + s.moisture_out_jitter_std**2 if me is None
               else max(me.moisture_out.noise, s.lab_std) ** 2) + g_var[_MO]
    for lab in tick.labs:
        rows.append(2)
        values.append(lab.moisture_out - g[_MO])
        var.append(lab_var)
        names.append("moisture_out (lab)")
        channels.append(ADAPT_CHANNELS.index("moisture_out"))
    return Measurements(rows, np.array(values, float), np.diag(var), names, channels)


def transient_variance(filt: FilterModel, window: Window) -> float:
    """Variance [K^2] added to each outlet temperature of ``window`` while the inlet air
    temperature moves inside it: ``(f * heat_gain * range)^2``, with ``range`` the spread of
    ``T_air_in``'s sub-window bin means [K], ``heat_gain`` the model's outlet-temperature
    gain [K/K] and ``f`` ``estimator.transient_fraction``.

    The model steps the window at its mean inputs, and a thermometer that lags, a flow that
    surges or a production move put the plant's outlet temperatures off that mean response
    by a part of the move that no state of the filter stands for. Under the outlet loop every
    such move shows on ``T_air_in``. Without this term the filter reads each transient as an
    inlet-moisture jump and publishes a spike (0.02-0.05 kg/kg at every move on the
    independent plant's lag and production-move days)."""
    vals = [v for v in window.bins.get("T_air_in", ()) if v is not None and math.isfinite(v)]
    if len(vals) < 2:
        return 0.0
    f = filt.settings.transient_fraction
    return (f * filt.heat_gain * (max(vals) - min(vals))) ** 2


def _sigma_outputs(filt: FilterModel, x: np.ndarray, P: np.ndarray, u: np.ndarray,
                   wall: np.ndarray, steps: _LabSteps
                   ) -> tuple[_Sigma | None, np.ndarray, str]:
    """Sigma points of ``(x, P)`` and the model at them, at the reference inlet moisture with
    each point's heat input, and at four probes about the mean (one batched call per output
    time); None and the reason when a solve failed."""
    sigmas = filt.points.sigma_points(x, P)
    cols = list(MODEL_STATES)
    n = len(sigmas)
    mean = x[cols]
    probes = [mean + sign * _FD_STEP[i] * (np.arange(len(cols)) == j)
              for j, i in enumerate(MODEL_STATES) for sign in (1.0, -1.0)]
    refs = np.column_stack([np.full(n, float(filt.reference[X_IN])),
                            sigmas[:, X_HEAT]])
    unique, index = np.unique(np.vstack([sigmas[:, cols], probes, refs]), axis=0,
                              return_inverse=True)
    index = np.ravel(index)
    X = filt.inlet.forward(unique[:, 0])
    Y, walls = filt.model.simulate(_model_inputs(u, X, unique[:, 1]), filt.theta,
                                   state0=wall, raise_on_failure=False)
    Y = Y[:, 0, :]
    lab = np.empty((len(unique), len(steps.dt)))
    for j, (u_lab, dt) in enumerate(zip(steps.u, steps.dt, strict=True)):
        yl, _ = filt.model.simulate(_model_inputs(u_lab, X, unique[:, 1]), filt.theta,
                                    state0=wall, dt=float(dt), raise_on_failure=False)
        lab[:, j] = yl[:, 0, _MO]
    if not (np.all(np.isfinite(Y)) and np.all(np.isfinite(lab))):
        bad = int(np.flatnonzero(~(np.isfinite(Y).all(1) & np.isfinite(lab).all(1)))[0])
        return None, sigmas, (f"model solve failed at moisture_in={X[bad]:.3f} kg/kg, "
                              f"T_air_in offset {unique[bad, 1]:+.2f} K: predict only")
    out = np.hstack([Y, lab])
    probe, ref = index[n:n + 4], index[n + 4:]
    d = [(out[probe[2 * j]] - out[probe[2 * j + 1]]) / (2.0 * _FD_STEP[i])
         for j, i in enumerate(MODEL_STATES)]
    # the moisture rows respond to the inlet moisture through the inlet gain
    d[0] = d[0] * np.r_[1.0, 1.0, np.full(1 + len(steps.dt), gain_response(x[X_GAIN]))]
    return (_Sigma(Y[index[:n]], Y[ref], np.asarray(walls)[index[:n]], lab[index[:n]],
                   lab[ref], d[0], d[1]), sigmas, "")


def _model_inputs(u: np.ndarray, moisture_in: np.ndarray, heat: np.ndarray) -> np.ndarray:
    """Model inputs ``(K, 1, 8)``: ``u`` with each inlet moisture and ``T_air_in`` moved by
    each heat-input offset."""
    U = np.repeat(np.asarray(u, float)[None, None, :], len(moisture_in), axis=0)
    U[:, 0, MOISTURE_IN] = moisture_in
    U[:, 0, _T_AIR_IN] += heat
    return U


def _moisture(y: np.ndarray, y_ref: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    """Outlet moisture at the sigma points with the inlet gain and the bias (module
    docstring of :mod:`.state_space`)."""
    # the response 1 + g bounded below: a sigma point far out never inverts it
    return y_ref + gain_response(sigmas[:, X_GAIN]) * (y - y_ref) + sigmas[:, X_BIAS]


def _measurement_sigmas(sigmas: np.ndarray, sig: _Sigma, rows: list[int]) -> np.ndarray:
    """Predicted measurements (N, m) at the sigma points: the model plus the error states of
    each row."""
    out = np.empty((len(sigmas), len(rows)))
    j_lab = 0
    for m, r in enumerate(rows):
        if r < 2:
            out[:, m] = sig.y[:, r] + sigmas[:, ROW_OFFSET[r]]
        else:
            out[:, m] = _moisture(sig.lab[:, j_lab], sig.lab_ref[:, j_lab], sigmas)
            j_lab += 1
    return out


def _partial(i: int, sig: _Sigma, rows: list[int]) -> np.ndarray:
    """``dz / dx_i`` with the other states held: one on their rows for the error states
    added to the outputs, the model's central difference for the inlet moisture and the heat
    input (:func:`_sigma_outputs`)."""
    if i not in MODEL_STATES:
        return np.array([1.0 if ROW_OFFSET[r] == i else 0.0 for r in rows])
    d = sig.d_in if i == X_IN else sig.d_heat
    out, j_lab = [], 0
    for r in rows:
        if r < 2:
            out.append(d[r])
        else:
            out.append(d[3 + j_lab])
            j_lab += 1
    return np.array(out)


def _match_covariance(filt: FilterModel, x: np.ndarray, P: np.ndarray, sigmas: np.ndarray,
                      sig: _Sigma, meas: Measurements) -> tuple[np.ndarray, str]:
    """Widen the prior variance of the one state whose jump best explains the innovation,
    when the innovation says it moved more than its process noise allows
    (:mod:`.jump_matching`); returns the new ``P`` and a note ('' when nothing changed).

    The candidates are the inlet moisture, the heat input, each measured temperature
    channel's offset and, with a lab, the bias; among jumps the measurements cannot tell apart
    the inlet moisture's is taken.
    """
    pts = filt.points
    zp, S = unscented_transform(_measurement_sigmas(sigmas, sig, meas.rows), pts.Wm, pts.Wc,
                                meas.R)
    seen = set(meas.rows)
    candidates = [X_IN, X_HEAT] + [ROW_OFFSET[r] for r in range(3) if r in seen]
    found = jumps({i: _partial(i, sig, meas.rows) for i in candidates}, S, meas.z - zp)
    P, taken = widen(P, found, filt.thresholds, preferred=X_IN)
    if not taken:
        return P, ""
    parts = []
    for c in taken:
        what = {X_IN: "inlet moisture", X_BIAS: "outlet-moisture bias"}.get(
            c.state, STATE_NAMES[c.state].replace("_", " "))
        parts.append(f"{what} ({abs(c.t):.1f} sigma, prior widened to "
                     f"{math.sqrt(P[c.state, c.state]):.4g})")
    return P, "measurements far from the model along the " + ", ".join(parts)


@dataclass(frozen=True)
class JointLayout:
    """Where each block sits in the joint vector of the unscented update (:func:`_update`):
    the filter state, the published outputs with their error states (``T_dryer_out``,
    ``T_cyclone_out``, ``moisture_out``), the model's own outlet temperatures (without the
    offsets), the wall temperatures, and the predicted measurements."""

    state: slice
    published: slice
    model_T: slice
    wall: slice
    measured: slice

    @classmethod
    def of(cls, n_state: int, n_wall: int, n_measured: int) -> JointLayout:
        bounds = np.cumsum([0, n_state, 3, 2, n_wall, n_measured])
        return cls(*(slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:],
                                                             strict=True)))

    @property
    def size(self) -> int:
        return self.measured.stop


def _update(filt: FilterModel, sigmas: np.ndarray, sig: _Sigma, meas: Measurements
            ) -> Posterior:
    """The unscented update of the state, the outputs and the walls (:mod:`.ukf`, steps 3 and
    5): filterpy's unscented transform of the joint sigma points (:class:`JointLayout`), then
    its Kalman update of that Gaussian by the measured rows."""
    pts = filt.points
    at = JointLayout.of(sigmas.shape[1], sig.wall.shape[1], len(meas.rows))
    joint = np.empty((len(sigmas), at.size))
    joint[:, at.state] = sigmas
    joint[:, at.published] = np.column_stack([
        sig.y[:, 0] + sigmas[:, X_TDRY], sig.y[:, 1] + sigmas[:, X_TCYC],
        _moisture(sig.y[:, 2], sig.y_ref[:, 2], sigmas)])
    joint[:, at.model_T] = sig.y[:, :2]
    joint[:, at.wall] = sig.wall
    joint[:, at.measured] = _measurement_sigmas(sigmas, sig, meas.rows)
    mean, cov = unscented_transform(joint, pts.Wm, pts.Wc)
    innovation, norm = Innovation(), np.zeros(0)
    if meas.rows:
        m = at.measured
        nu = meas.z - mean[m]
        S = cov[m, m] + meas.R
        H = np.zeros((len(meas.rows), at.size))
        H[:, m] = np.eye(len(meas.rows))
        mean, cov = kf_update(mean, cov, meas.z, meas.R, H)
        norm = nu / np.sqrt(np.diag(S))
        innovation = Innovation(float(nu @ np.linalg.solve(S, nu)), len(meas.rows),
                                _per_channel(meas.names, norm))
    return Posterior(mean[at.state].copy(), _symmetric(cov[at.state, at.state]),
                     mean[at.published], np.diag(cov)[at.published].copy(), mean[at.model_T],
                     mean[at.wall], innovation, norm, list(meas.channels))


def _per_channel(names: list[str], norm: np.ndarray) -> dict[str, float]:
    """Normalised innovation per channel name (several lab results averaged)."""
    out: dict[str, list[float]] = {}
    for n, v in zip(names, norm, strict=True):
        out.setdefault(n, []).append(float(v))
    return {n: float(np.mean(v)) for n, v in out.items()}


def _symmetric(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)


def inlet_moments(filt: FilterModel, x: np.ndarray, P: np.ndarray) -> tuple[float, float]:
    """Mean and standard deviation of the inlet moisture (through the soft clip)."""
    pts = filt.points
    X = filt.inlet.forward(pts.sigma_points(x, P)[:, X_IN])
    mean, var = unscented_transform(X[:, None], pts.Wm, pts.Wc)
    return float(mean[0]), math.sqrt(max(float(var[0, 0]), 0.0))


__all__ = ["ROW_OFFSET", "FilterModel", "JointLayout", "Measurements", "Posterior", "TickData",
           "inlet_moments", "learned_offsets", "measurements", "step",
           "transient_variance"]
