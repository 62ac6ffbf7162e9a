"""Each cause's shape on the open-loop residuals, with its marginal evidence against the normal.

The extensions of :mod:`.extensions` change the model and are scored held out; where the
model's form of a cause is not the plant's (the outside loss of a real dryer does not grow
linearly with cold on warm hours, a fouled plant's transfer does not fall as the model's
multipliers do), their fit fails and the day lands on ``unexplained`` or ``none``. Here every
cause is instead the *shape* it leaves on the baseline's residuals (measured minus the model
with the history's normal, :class:`~.problem.Problem`), a small linear model in its size:

================== ==========================================================================
cause              shape (unit size; alternatives marginalised over)
================== ==========================================================================
ambient_heat_loss  a regressor ``(T_COLD - T_amb)^+ / 10 K`` on each outlet temperature, one
                   coefficient per channel [K per 10 K of cold], both negative (the outside
                   loss grows per 10 K of ambient below ``T_COLD`` and leaves the outlets
                   colder; zero on warm hours: a day that is never cold cannot show it)
lab_delay          the lab residual of moved sample times: ``y(t + delta) - y(t)`` of the
                   baseline's outlet moisture at each stamped time ``t``, for ``delta`` on a
                   grid (a shift shows only while the moisture moves); no free size
fouling_drift      a ramp from the day's start to its end, times the fibre load over its
                   mean (the same loss of transfer moves the outputs in proportion to what
                   is dried), along the model's steady response to a lost transfer on both
                   temperatures and the labs; one size, the loss by the day's end, a loss
                   only (fouling never gains transfer; on every clean tuning and fresh day
                   the ramp fitted a gain)
sensor_bias        a step from an onset on the grid to the day's end on one thermometer alone
                   (the offset does not scale with load), one coefficient; the channel and the
                   onset are alternatives, each only where the raw residuals allow an offset
                   on that channel from that onset (:mod:`.instrument`: not both
                   thermometers off together, not the other one off more)
================== ==========================================================================

The whitening through the normal (:class:`~.calibration_error.CalibrationErrorModel`) is
linear, so a shape ``G x`` leaves whitened residuals ``v - W x`` (``v`` the baseline's,
``W`` the whitened shape), and with a Gaussian prior ``x ~ N(0, diag(s^2))`` of the cause's
plant size (:attr:`Shape.prior_sd`, cut to :attr:`Shape.signs` where the physics fixes the
sign) the evidence against the normal alone is exact (:func:`linear_evidence`):

    ``log B = b' (A + S^-1)^-1 b / 2 - log det(I + A S) / 2``,  ``A = W'W``, ``b = W'v``

the second term the Occam factor (what a size the prior spreads over costs). Alternatives
(onsets, channels, shifts) are a uniform discrete prior: ``log B`` is the log of the mean of
their Bayes factors. The candidate's log-evidence in the posterior (:mod:`.posterior`) is
``log B - SHAPE_CHARGE`` less what the residuals still hold after the best alternative is
removed (its structure margin, :func:`~.verdict.margins`): a shape that leaves the residuals
structured explains part of something else (a chip batch), not the day.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import multivariate_normal, norm

from softsensor.diagnosis.extensions import TransferDrift
from softsensor.diagnosis.instrument import offset_contradiction
from softsensor.diagnosis.problem import Problem, Residuals
from softsensor.diagnosis.verdict import margins
from softsensor.signals import INPUT_NAMES, KELVIN_CHANNELS

_T_AMB = INPUT_NAMES.index("T_amb")
_M_FIBER = INPUT_NAMES.index("m_fiber")

#: Below this ambient temperature the outside loss of the ambient cause grows. [K]
T_COLD = 283.15
#: Onsets of the step and ramp shapes, as shares of the day.
ONSETS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)
#: Lab time shifts of the lab-delay shape: a 5 min grid without the unshifted labs (a shift
#: of 0 is the normal the shape is weighed against), not the residual statistics' 2 min grid
#: :data:`~.residuals.LAB_SHIFTS_MIN`. [min]
SHAPE_LAB_SHIFTS_MIN = tuple(float(m) for m in np.arange(-90.0, 90.0 + 1e-9, 5.0) if m != 0.0)


@dataclass(frozen=True)
class Alternative:
    """One member of a shape's family: its unit regressors and what names it.

    ``T`` (p, K, 2) [K per unit] and ``lab`` (p, L) [kg/kg per unit] are the residual change
    per unit of each of the ``p`` sizes; ``fixed`` True when the shape has no free size (the
    regressor is the cause at its full size: ``p = 1``, size one)."""

    params: dict[str, float]
    channel: str | None
    T: np.ndarray
    lab: np.ndarray
    fixed: bool = False


@dataclass(frozen=True)
class ShapeFit:
    """A shape's evidence on one day (module docstring).

    Attributes
    ----------
    cause : str
    channel : str or None
        The thermometer of a ``sensor_bias`` shape.
    log_bayes : float
        ``log B`` against the normal alone, marginalised over the alternatives. [nats]
    structure_left : float
        The structure margin of the residuals after the best alternative's posterior mean
        is removed (:func:`~.verdict.margins`, the largest over the channels). [nats]
    params : dict[str, float]
        The best alternative's parameters and posterior mean sizes.
    description : str
    """

    cause: str
    channel: str | None
    log_bayes: float
    structure_left: float
    params: dict[str, float]
    description: str

    def to_json(self) -> dict[str, Any]:
        """The fit as JSON (non-finite numbers as null: a shape the day cannot show)."""
        return {"cause": self.cause, "channel": self.channel,
                "log_bayes": _rounded(self.log_bayes, 3),
                "structure_left": _rounded(self.structure_left, 3),
                "params": {k: _rounded(v, 6) for k, v in self.params.items()},
                "description": self.description}

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> ShapeFit:
        """The fit :meth:`to_json` wrote (a null log Bayes factor: the shape not
        applicable, ``-inf``; a null structure left: ``+inf``)."""
        lb, left = doc.get("log_bayes"), doc.get("structure_left")
        return cls(str(doc["cause"]), doc.get("channel"),
                   -math.inf if lb is None else float(lb),
                   math.inf if left is None else float(left),
                   {k: float(v) for k, v in (doc.get("params") or {}).items()
                    if v is not None}, str(doc.get("description", "")))


def _rounded(x: float, digits: int) -> float | None:
    return round(float(x), digits) if math.isfinite(x) else None


def whitened_shape(problem: Problem, T: np.ndarray, lab: np.ndarray,
                   base: Residuals | None = None) -> np.ndarray:
    """A residual change ``T`` (K, 2), ``lab`` (L,) whitened as the baseline's residuals are
    over the whole day (:meth:`Problem.whitened <.problem.Problem.whitened>`, ``"all"``), with
    the baseline's missing samples left out, as one vector in the same order. ``base``: the
    baseline's residuals, when the caller has them (a fit whitens dozens of alternatives).

    The whitening is linear and keeps exactly the samples it is given, so an all-zero block
    (the temperatures of a lab shift, the labs of a thermometer step) whitens to zeros
    without running its filter."""
    base = problem.residuals(problem.baseline) if base is None else base
    okT, okl = np.isfinite(base.T), np.isfinite(base.lab)
    ce = problem.calibration_error
    if np.any(T[okT]):
        wT = ce.whiten_temperatures(np.where(okT, T, np.nan))
        blocks = [wT[:, 0][okT[:, 0]], wT[:, 1][okT[:, 1]]]
    else:
        blocks = [np.zeros(int(okT[:, 0].sum())), np.zeros(int(okT[:, 1].sum()))]
    if np.any(lab[okl]):
        t_s = (problem.windows.lab_time_ns - problem.windows.start_ns) / 1e9
        blocks.append(ce.whiten_labs(np.where(okl, lab, np.nan), t_s)[okl])
    else:
        blocks.append(np.zeros(int(okl.sum())))
    return np.concatenate(blocks)


def linear_evidence(v: np.ndarray, W: np.ndarray, prior_sd: np.ndarray,
                    signs: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """``(log B, posterior mean)`` of ``v = W x + e``, ``e`` white, ``x ~ N(0, diag(sd^2))``
    against ``x = 0`` (module docstring); ``W`` (n, p).

    ``signs`` (p,) of +1, -1 or 0 restricts each size to that sign (0: either): the prior
    is then the Gaussian cut to that orthant, and the Bayes factor is the unrestricted one
    times the posterior's probability of the orthant over the prior's (``2^-m`` for ``m``
    restricted sizes). The mean returned is the unrestricted posterior's."""
    A = W.T @ W
    b = W.T @ v
    S = np.diag(np.asarray(prior_sd, float) ** 2)
    M = A + np.linalg.inv(S)
    mean = np.linalg.solve(M, b)
    _, logdet = np.linalg.slogdet(np.eye(len(b)) + A @ S)
    log_b = float(0.5 * b @ mean - 0.5 * logdet)
    sg = np.zeros(len(b)) if signs is None else np.asarray(signs, float)
    cut = sg != 0
    if cut.any():
        cov = np.linalg.inv(M)[np.ix_(cut, cut)]
        # P(s_i x_i > 0 for every restricted i) = P(z < s m) for z ~ N(0, D cov D)
        D = np.diag(sg[cut])
        upper = sg[cut] * mean[cut]
        if cut.sum() == 1:
            log_p = float(norm.logcdf(upper[0] / math.sqrt(cov[0, 0])))
        else:
            p = float(multivariate_normal(np.zeros(cut.sum()), D @ cov @ D).cdf(upper))
            log_p = math.log(max(p, 1e-300))
        log_b += log_p + cut.sum() * math.log(2.0)
    return log_b, mean


def _split(problem: Problem, w: np.ndarray) -> list[np.ndarray]:
    """A whole-day whitened vector back into its channels (the baseline's sample counts)."""
    counts = [p.size for p in problem.whitened(problem.baseline, "all")]
    return np.split(w, np.cumsum(counts)[:-1])


class Shape(ABC):
    """One cause's shape: a family of alternatives, each linear in its sizes."""

    cause: str
    #: Prior standard deviation of each size (the virtual plant's default size of the
    #: cause's effect on the residuals).
    prior_sd: tuple[float, ...]
    #: What each size is called in :attr:`ShapeFit.params` (the names the report's verdict
    #: sentences read, :mod:`softsensor.presentation.verdicts`).
    size_names: tuple[str, ...]
    #: The sign each size can take (+1, -1; 0: either), where the cause's physics fixes it.
    signs: tuple[int, ...] = ()

    @abstractmethod
    def alternatives(self, problem: Problem) -> Iterator[Alternative]:
        """Every member of the family on ``problem``'s day."""

    @abstractmethod
    def describe(self, alt: Alternative, size: np.ndarray) -> str:
        """The best alternative ``alt`` at its posterior mean ``size``, in words."""

    def fit(self, problem: Problem) -> ShapeFit:
        """The shape's evidence on ``problem``'s day, marginalised over its alternatives."""
        v = np.concatenate(problem.whitened(problem.baseline, "all"))
        residuals = problem.residuals(problem.baseline)
        logs, best = [], None
        for alt in self.alternatives(problem):
            W = np.stack([whitened_shape(problem, alt.T[j], alt.lab[j], residuals)
                          for j in range(alt.T.shape[0])], axis=1)
            if alt.fixed:
                w = W[:, 0]
                lb, size = float(v @ w - 0.5 * w @ w), np.ones(1)
            else:
                lb, size = linear_evidence(v, W, np.array(self.prior_sd),
                                           np.array(self.signs))
            logs.append(lb)
            if best is None or lb > best[0]:
                best = (lb, alt, size, W)
        if best is None:
            return ShapeFit(self.cause, None, -math.inf, math.inf, {}, "not applicable")
        log_b = float(np.logaddexp.reduce(logs) - math.log(len(logs)))
        _, alt, size, W = best
        left = v - W @ size
        m = margins(_split(problem, left))
        params = dict(alt.params)
        if not alt.fixed:
            params.update({n: float(x) for n, x in zip(self.size_names, size, strict=True)})
        return ShapeFit(self.cause, alt.channel, log_b,
                        max((x for x, _, _ in m.values()), default=-math.inf), params,
                        self.describe(alt, size))


class AmbientShape(Shape):
    """``ambient_heat_loss``: each outlet temperature moves by ``a_c (T_COLD - T_amb)^+ / 10 K``
    (module docstring); both coefficients free, the labs untouched."""

    cause = "ambient_heat_loss"
    prior_sd = (3.0, 3.0)
    size_names = ("dT_dryer_out_per_10K", "dT_cyclone_out_per_10K")
    #: More outside loss leaves both outlets colder than the model says.
    signs = (-1, -1)

    def alternatives(self, problem: Problem) -> Iterator[Alternative]:
        U = problem.windows.U
        cold = np.maximum(T_COLD - U[:, _T_AMB], 0.0) / 10.0
        if not np.any(cold > 0):
            return
        L = problem.windows.lab_value.size
        T = np.zeros((2, cold.size, 2))
        T[0, :, 0] = cold
        T[1, :, 1] = cold
        yield Alternative({}, None, T, np.zeros((2, L)))

    def describe(self, alt: Alternative, size: np.ndarray) -> str:
        return (f"the outlet temperatures move by {size[0]:+.2f} K and {size[1]:+.2f} K per "
                f"10 K of ambient below {T_COLD:g} K")


class LabDelayShape(Shape):
    """``lab_delay``: the lab results were sampled ``delta`` away from their stamped times."""

    cause = "lab_delay"
    prior_sd = ()
    size_names = ()

    def alternatives(self, problem: Problem) -> Iterator[Alternative]:
        w = problem.windows
        if w.lab_value.size == 0:
            return
        K = w.n_windows
        at = problem.baseline.lab
        for m in SHAPE_LAB_SHIFTS_MIN:
            moved = problem.baseline_labs(problem.lab_points(m * 60e9))
            # the residual of a sample taken at t + delta against the model at t
            g = moved - at
            if not np.all(np.isfinite(g)):
                continue
            yield Alternative({"shift_min": m}, None, np.zeros((1, K, 2)), g[None], fixed=True)

    def describe(self, alt: Alternative, size: np.ndarray) -> str:
        m = alt.params["shift_min"]
        return (f"lab samples taken {abs(m):.0f} min {'later' if m > 0 else 'earlier'} than "
                f"stamped")


class FoulingShape(Shape):
    """``fouling_drift``: the transfer falls on a ramp from the day's start to its end, and
    the outputs move by the model's steady response to that loss (:meth:`TransferDrift.response
    <.extensions.TransferDrift.response>`) scaled by the fibre load over its mean; one size,
    the loss by the day's end.

    The ramp starts at the day's start only: fouling builds over days, and with the onsets
    of the step shape as alternatives late ramps fitted the normal's own wander on clean
    days (tuning plant 12, seed 300: 14.6 nats)."""

    cause = "fouling_drift"
    prior_sd = (0.3,)
    size_names = ("loss_by_end",)
    #: Fouling loses transfer; it never gains it.
    signs = (1,)

    def alternatives(self, problem: Problem) -> Iterator[Alternative]:
        w = problem.windows
        S = TransferDrift().response(problem)
        load = w.U[:, _M_FIBER] / float(np.mean(w.U[:, _M_FIBER]))
        lab_k = np.clip(w.lab_window, 0, w.n_windows - 1)
        t_lab = w.lab_hours / float(w.hours[-1])
        ramp = np.clip(w.day_fraction, 0.0, None) * load
        ramp_lab = np.clip(t_lab, 0.0, None) * load[lab_k]
        yield Alternative({}, None, (ramp[:, None] * S[:2])[None], (ramp_lab * S[2])[None])

    def describe(self, alt: Alternative, size: np.ndarray) -> str:
        return (f"tube transfer lost {size[0]:.0%} by the day's end on a ramp from the day's "
                f"start, its effect scaled by the fibre load")


class OffsetShape(Shape):
    """``sensor_bias``: a step on one thermometer from an onset on, not scaled by load."""

    cause = "sensor_bias"
    prior_sd = (3.0,)
    size_names = ("offset_K",)
    signs = (0,)

    def alternatives(self, problem: Problem) -> Iterator[Alternative]:
        w = problem.windows
        K, L = w.n_windows, w.lab_value.size
        t = w.day_fraction
        for c, name in enumerate(KELVIN_CHANNELS):
            for on in ONSETS:
                # both thermometers off together, or the other one off more: not an offset
                # on this one (:mod:`.instrument`)
                if offset_contradiction(problem, name, on * float(w.hours[-1])) is not None:
                    continue
                T = np.zeros((1, K, 2))
                T[0, :, c] = (t >= on).astype(float)
                yield Alternative({"onset_h": on * float(w.hours[-1])}, name, T,
                                  np.zeros((1, L)))

    def describe(self, alt: Alternative, size: np.ndarray) -> str:
        return (f"{alt.channel} reads {size[0]:+.2f} K off from {alt.params['onset_h']:.1f} h "
                f"on")


#: One shape per cause whose model extension fails where the model's form is not the plant's.
SHAPES: tuple[Shape, ...] = (AmbientShape(), LabDelayShape(), FoulingShape(), OffsetShape())

__all__ = ["SHAPES", "Alternative", "Shape", "ShapeFit", "linear_evidence",
           "whitened_shape"]
