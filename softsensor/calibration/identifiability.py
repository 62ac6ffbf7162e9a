"""Local identifiability of the seven parameters (paper section 3.4).

Sensitivity trajectories (eq. 5)
    ``S_i(t) = theta_i * dy(t, theta)/d theta_i = dy/d ln(theta_i)``: the change of an output
    [K or kg/kg] per unit fractional change of a parameter, by central differences in
    ``ln(theta)`` through one batched model call (nominal plus two members per parameter, each
    from its own steady initial state), with the nominal inlet moisture (Fig. 2).
What the cost sees
    When the calibration estimates the inlet moisture (:mod:`.disturbance`), a parameter's
    effect that a slow inlet-moisture trajectory can imitate is not information about the
    parameter. So the rows ``J_m`` of the Fisher information are the sensitivities of the
    outputs *after* the trajectory is re-fitted (central differences of the residuals the
    objective sees, :mod:`.objective`): the nuisance is profiled out.
Weighted Fisher information (the form of the paper's Table 3)
    ``FIM = sum_m (1 / sigma^2) WF_m^2 J_m^T J_m`` with ``sigma = 1`` and ``J_m`` channel ``m``'s
    rows at its samples (window means for the temperatures, lab sample times for
    ``moisture_out``). A common ``sigma`` scales the matrix only; its condition number,
    eigenvectors and correlations do not depend on it. Each Table 1 parameter has an effect of
    its own in the model (:mod:`softsensor.model.kernels`), so the condition number is finite;
    the paper's is 584.
What the data can pin down
    The statistical FIM ``F = sum_m J_m^T J_m / s_m^2`` uses each channel's noise ``s_m``: the
    RMSE the fit leaves (model error included), inflated by ``sqrt((1 + rho_m) / (1 - rho_m))``
    for the lag-one autocorrelation ``rho_m`` of the window residuals (serially correlated
    residuals carry less information than independent ones). With the calibration's prior
    precision (or, without a prior, a weak one whose +-2 sd spans the Table 1 bounds) the
    posterior covariance ``C = (F + P0)^-1`` gives each parameter's relative standard error
    ``sqrt(C_ii)`` (in ``ln(theta)``: 0.05 is about 5 %) and the correlations.

The local FIM can overstate what is pinned down: the model saturates (raising ``mult_h``
barely changes anything once air-to-fibre heat transfer stops limiting), and a standard error of
a few percent can hide a curved valley that runs tens of percent further. So a parameter the
FIM calls pinned is tested on the objective itself (:func:`profile_test`): moved by
``+-WITHIN`` (15 %) with the other parameters re-fitted by a few Gauss-Newton steps, the
objective must rise, on both sides, by at least ``PROFILE_RISE`` (2) in units of the prior's
scale ``lambda`` (:mod:`.objective`: for the likelihood a log-likelihood unit, for eq. 4 the
change one noise-sized sample makes). A rise of 2 is a likelihood ratio of e^2: the 15 % move
lies two standard errors out.

Verdict per parameter: *not identifiable* when the data shrink its prior standard deviation
by less than half; *identifiable* when the FIM standard error is at most ``IDENTIFIABLE_SE``
(7.5 %: 15 % is two standard errors) and the profile test confirms it on both sides;
*weakly identifiable* otherwise.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from softsensor.calibration.chunked_run import ChunkedRun
from softsensor.calibration.dataset import Segment
from softsensor.calibration.objective import Evaluation, ObjectiveSpec
from softsensor.errors import ConfigError, SolverError
from softsensor.model import DryerModel
from softsensor.plantconfig import PARAMETER_NAMES
from softsensor.signals import OUTPUT_NAMES

#: Central-difference step in ln(theta) (1 %; 0.1 % agrees to five digits).
SENSITIVITY_STEP = 1e-2
#: The profile test's relative move (the recovery tolerance the verdict vouches for).
WITHIN = 0.15
#: Objective rise, in units of the prior's scale, that pins a parameter at +-WITHIN.
PROFILE_RISE = 2.0
#: Gauss-Newton evaluations re-fitting the other parameters at each displaced point.
PROFILE_NFEV = 3
#: FIM standard error in ln(theta) up to which a parameter may be identifiable.
IDENTIFIABLE_SE = 0.075
#: Posterior / prior standard deviation above which a parameter counts as not identifiable.
NOT_IDENTIFIABLE_RATIO = 0.5
#: Absolute correlation above which two parameters are reported as confounded.
STRONG_CORRELATION = 0.9
#: Noise floors of the statistical FIM [K, K, kg/kg].
NOISE_FLOOR = np.array([0.01, 0.01, 1e-4])

#: Condition number of the weighted FIM in the paper's Table 3, printed beside ours.
PAPER_CONDITION_NUMBER = 584.2


@dataclass(frozen=True)
class Sensitivities:
    """Sensitivities on one segment.

    Attributes
    ----------
    theta : ndarray (7,)
    Y : ndarray (K, 3)
        Model outputs at ``theta`` (window ends), nominal inlet moisture.
    S : ndarray (K, 3, 7)
        Eq. 5: ``dy_m / d ln(theta_i)`` at window ends [K or kg/kg per unit fractional change].
    S_lab : ndarray (L, 7)
        ``d moisture_out / d ln(theta_i)`` at the lab sample times [kg/kg].
    rows : list of ndarray
        Per channel, ``(n_m, 7)``: the sensitivities of the outputs the cost compares, after
        the inlet trajectory is re-fitted (module docstring), at the channel's samples.
    segment : Segment
    """

    theta: np.ndarray
    Y: np.ndarray
    S: np.ndarray
    S_lab: np.ndarray
    rows: list[np.ndarray]
    segment: Segment

    @property
    def relative(self) -> np.ndarray:
        """``J_relative = S / y_mean`` (K, 3, 7) [-]."""
        return self.S / np.mean(self.Y, axis=0)[None, :, None]

    def channel_rows(self, c: int) -> np.ndarray:
        """Rows of channel ``c`` the information is counted on (``rows[c]``)."""
        return self.rows[c]


def sensitivities(model: DryerModel, segments: Sequence[Segment], theta: np.ndarray,
                  spec: ObjectiveSpec, step: float = SENSITIVITY_STEP
                  ) -> tuple[list[Sensitivities], Evaluation]:
    """Eq. 5 and the profiled rows on every segment, by central differences in
    ``ln(theta)``: one batched run of 15 parameter sets. Returns them and the evaluation at
    ``theta``.

    Where one perturbed member's solve fails, that parameter falls back to the one-sided
    difference of the other; both failing, or the nominal member failing, is a
    :class:`~softsensor.errors.SolverError`.
    """
    theta = np.asarray(theta, float)
    n = theta.size
    members = np.tile(theta, (2 * n + 1, 1))
    for i in range(n):
        members[1 + 2 * i, i] *= np.exp(step)
        members[2 + 2 * i, i] *= np.exp(-step)
    run = ChunkedRun(model, segments, members, spec, n_chunks=1)
    evs = run.run()
    ok = np.array([not e.failed for e in evs])
    if not ok[0]:
        at = ", ".join(f"{k}={v:.4g}" for k, v in zip(PARAMETER_NAMES, theta, strict=True))
        raise SolverError(f"the model fails at the parameters analysed ({at})")
    pairs = []
    for i in range(n):
        up, dn = 1 + 2 * i, 2 + 2 * i
        if ok[up] and ok[dn]:
            pairs.append((up, dn, 2 * step))
        elif ok[up] or ok[dn]:
            pairs.append((up, 0, step) if ok[up] else (0, dn, step))
        else:
            raise SolverError(f"the model fails on both sides of {PARAMETER_NAMES[i]} = "
                              f"{theta[i]:.4g} (+-{step:g} in ln)")
    out = []
    for s, seg in enumerate(segments):
        Y, lab = run.runs[s].Y, run.runs[s].lab
        S = np.empty(Y.shape[1:] + (n,))
        S_lab = np.empty((lab.shape[-1], n))
        rows = [np.empty((evs[0].res[s][c].size, n)) for c in range(3)]
        for i, (a, b, h) in enumerate(pairs):
            S[..., i] = (Y[a] - Y[b]) / h
            S_lab[:, i] = (lab[a] - lab[b]) / h
            for c in range(3):  # residual = measured - model: the model moves the other way
                rows[c][:, i] = -(evs[a].res[s][c] - evs[b].res[s][c]) / h
        out.append(Sensitivities(theta=theta, Y=Y[0], S=S, S_lab=S_lab, rows=rows,
                                 segment=seg))
    return out, evs[0]


def weighted_fim(sens: Sequence[Sensitivities], weights: np.ndarray, sigma: float = 1.0
                 ) -> np.ndarray:
    """The paper's Table 3 form: ``sum_m (1/sigma^2) WF_m^2 J_m^T J_m`` (7, 7), in ln(theta)."""
    F = np.zeros((len(PARAMETER_NAMES),) * 2)
    for s in sens:
        for c in range(len(OUTPUT_NAMES)):
            J = s.channel_rows(c)
            F += (weights[c] ** 2 / sigma**2) * (J.T @ J)
    return 0.5 * (F + F.T)


def lag1_autocorrelation(r: np.ndarray) -> float:
    """Lag-one autocorrelation of a residual series (0 for fewer than 3 samples)."""
    r = np.asarray(r, float)
    r = r[np.isfinite(r)]
    if r.size < 3:
        return 0.0
    d = r - r.mean()
    den = float(d @ d)
    return float(d[1:] @ d[:-1] / den) if den > 0 else 0.0


def statistical_fim(sens: Sequence[Sensitivities], noise: np.ndarray) -> np.ndarray:
    """``sum_m J_m^T J_m / noise_m^2`` (7, 7) with per-channel noise [K, K, kg/kg]."""
    F = np.zeros((len(PARAMETER_NAMES),) * 2)
    for s in sens:
        for c in range(len(OUTPUT_NAMES)):
            J = s.channel_rows(c)
            F += (J.T @ J) / noise[c] ** 2
    return 0.5 * (F + F.T)


def noise_from_evaluation(ev: Evaluation) -> np.ndarray:
    """Per-channel noise for the statistical FIM: the RMSE the fit leaves, inflated for
    serially correlated window residuals by ``sqrt((1 + rho) / (1 - rho))``."""
    noise = np.empty(3)
    for c, name in enumerate(OUTPUT_NAMES):
        s = float(ev.fit.rmse[name]) if np.isfinite(ev.fit.rmse[name]) else 0.0
        if c < 2:
            rho = float(np.clip(np.mean([lag1_autocorrelation(r[c]) for r in ev.res]),
                                0.0, 0.95))
            s *= np.sqrt((1 + rho) / (1 - rho))
        noise[c] = max(s, NOISE_FLOOR[c])
    return noise


def bounds_prior_sd(bounds: np.ndarray) -> np.ndarray:
    """A weak prior standard deviation of ln(theta): +-2 sd spans the Table 1 bounds."""
    return np.log(bounds[:, 1] / bounds[:, 0]) / 4.0


@dataclass(frozen=True)
class ProfileTest:
    """Objective rise, in units of the prior scale, when a parameter moves by +-``within``
    with the others re-fitted (module docstring). NaN where not tested; ``inf`` where a bound
    blocks the move (the bound pins the parameter on that side)."""

    within: float
    rise_up: np.ndarray
    rise_down: np.ndarray

    def rise(self, i: int) -> float:
        """The smaller rise of the two sides (NaN when untested)."""
        pair = [v for v in (self.rise_up[i], self.rise_down[i]) if not np.isnan(v)]
        return float(min(pair)) if pair else float("nan")


def profile_test(model: DryerModel, segments: Sequence[Segment], theta: np.ndarray,
                 ev: Evaluation, spec: ObjectiveSpec, bounds: np.ndarray, tested: np.ndarray,
                 informed: np.ndarray, within: float = WITHIN,
                 profile_nfev: int = PROFILE_NFEV,
                 jac_model: DryerModel | None = None) -> ProfileTest:
    """Move each ``tested`` parameter by ``x (1 +- within)``, re-fit the other ``informed``
    ones by at most ``profile_nfev`` bounded Gauss-Newton steps and measure the objective's
    rise in units of ``spec.prior_scale``: points of the profile of the objective.
    ``jac_model``: a cheaper model for the steps' Jacobians (:class:`~.refine.
    WeightedResiduals`); every objective compared is ``model``'s."""
    from scipy.optimize import least_squares

    from softsensor.calibration.chunked_run import evaluate_parameters
    from softsensor.calibration.objective import irls_scale
    from softsensor.calibration.refine import WeightedResiduals

    n = len(PARAMETER_NAMES)
    lo, hi = np.log(bounds[:, 0]), np.log(bounds[:, 1])
    z0 = np.log(np.asarray(theta, float))
    scale = irls_scale(ev, spec)
    up, dn = np.full(n, np.nan), np.full(n, np.nan)
    unit = spec.prior_scale if spec.prior_scale > 0 else 1.0

    def refit(z: np.ndarray, others: np.ndarray, at: Evaluation | None = None) -> float:
        """The objective with ``others`` re-fitted from ``z`` (a few Gauss-Newton steps);
        ``at``: the evaluation at ``z`` when known."""
        if not (others.size and profile_nfev > 0):
            return (at or evaluate_parameters(model, segments, np.exp(z), spec)[0]).objective
        active = np.zeros(n, dtype=bool)
        active[others] = True
        prob = WeightedResiduals(model, segments, spec, scale, z, active, jac_model)
        if at is not None:
            prob.seed(z[active], at)
        sol = least_squares(prob.fun, z[active], jac=prob.jac,
                            bounds=(lo[active], hi[active]), method="trf",
                            max_nfev=profile_nfev, xtol=1e-4, ftol=1e-4)
        x = np.clip(sol.x, lo[active], hi[active])
        end = prob.evaluation(x)  # least_squares ends on a point it evaluated
        if end is None:
            end = evaluate_parameters(model, segments, np.exp(prob.full(x)), spec)[0]
        return end.objective

    for i in np.flatnonzero(tested):
        others = np.array([j for j in np.flatnonzero(informed) if j != i], dtype=int)
        # the reference is the calibrated point re-fitted the same way, so that an optimum
        # the polish left a little short of does not pass for a rise
        ref = min(ev.objective, refit(z0.copy(), others, ev))
        for sign, step in ((1, np.log1p(within)), (-1, np.log1p(-within))):
            zi = z0[i] + step
            if zi > hi[i] + 1e-12 or zi < lo[i] - 1e-12:
                (up if sign > 0 else dn)[i] = np.inf
                continue
            z = z0.copy()
            z[i] = zi
            (up if sign > 0 else dn)[i] = (refit(z, others) - ref) / unit
    return ProfileTest(within=within, rise_up=up, rise_down=dn)


@dataclass(frozen=True)
class ParameterVerdict:
    name: str
    value: float
    relative_se: float
    prior_ratio: float
    partner: str | None
    correlation: float
    rise: float
    verdict: str
    reason: str


@dataclass(frozen=True)
class Identifiability:
    """Everything section 3.4 reports, for one calibrated parameter set."""

    theta: np.ndarray
    fim: np.ndarray                 # Table 3 form (weighted), ln(theta)
    condition_number: float
    eigenvalues: np.ndarray         # of ``fim``, ascending
    eigenvectors: np.ndarray        # columns, ascending eigenvalue
    fim_statistical: np.ndarray
    covariance: np.ndarray          # posterior, ln(theta)
    correlation: np.ndarray
    noise: np.ndarray               # per channel, as used in ``fim_statistical``
    verdicts: list[ParameterVerdict]
    profile: ProfileTest | None = None

    def verdict(self, name: str) -> ParameterVerdict:
        return self.verdicts[PARAMETER_NAMES.index(name)]

    @property
    def identifiable(self) -> list[str]:
        return [v.name for v in self.verdicts if v.verdict == "identifiable"]

    @property
    def poorly_identifiable(self) -> list[str]:
        return [v.name for v in self.verdicts if v.verdict != "identifiable"]

    def weakest_directions(self, count: int = 2) -> list[str]:
        """The least informed eigenvectors of the weighted FIM, as readable combinations."""
        out = []
        top = max(float(self.eigenvalues[-1]), 1e-300)
        for j in range(min(count, len(self.eigenvalues))):
            v = self.eigenvectors[:, j]
            v = v * np.sign(v[np.argmax(np.abs(v))])
            terms = [f"{v[i]:+.2f} ln {PARAMETER_NAMES[i]}" for i in np.argsort(-np.abs(v))
                     if abs(v[i]) >= 0.1]
            out.append(f"{' '.join(terms)} (eigenvalue {max(self.eigenvalues[j], 0.0) / top:.1e}"
                       f" of the largest)")
        return out


def prior_sd(spec: ObjectiveSpec, bounds: np.ndarray) -> np.ndarray:
    """The prior sd (7,) of ln theta: the calibration's own prior when it has one, else the
    one the Table 1 bounds imply (:func:`bounds_prior_sd`)."""
    if spec.prior_center is not None:
        return np.full(len(PARAMETER_NAMES), spec.prior_sigma)
    return bounds_prior_sd(bounds)


def condition_number(F: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Condition number, eigenvalues (ascending) and eigenvectors of a symmetric matrix."""
    lam, vec = np.linalg.eigh(F)
    cond = float(lam[-1] / lam[0]) if lam[0] > 0 else float("inf")
    return cond, lam, vec


def analyse(sens: Sequence[Sensitivities], weights: np.ndarray, noise: np.ndarray,
            prior_sd: np.ndarray, profile: ProfileTest | None = None) -> Identifiability:
    """FIMs, condition number, eigenvectors, correlations and per-parameter verdicts.

    ``prior_sd`` (7,) is the prior standard deviation of ``ln(theta)`` the verdict measures
    the data against. Without a ``profile`` test no parameter is called identifiable (the
    local FIM alone cannot vouch for it); see the module docstring.
    """
    theta = sens[0].theta
    F = weighted_fim(sens, weights)
    cond, lam, vec = condition_number(F)
    Fs = statistical_fim(sens, noise)
    p_sd = np.asarray(prior_sd, float)
    C = np.linalg.inv(Fs + np.diag(1.0 / p_sd**2))
    C = 0.5 * (C + C.T)
    sd = np.sqrt(np.diag(C))
    R = C / np.outer(sd, sd)
    pct = 100 * (WITHIN if profile is None else profile.within)
    verdicts = []
    for i, name in enumerate(PARAMETER_NAMES):
        others = [j for j in range(len(PARAMETER_NAMES)) if j != i]
        j = others[int(np.argmax(np.abs(R[i, others])))]
        r = float(R[i, j])
        ratio = float(sd[i] / p_sd[i])
        rise = np.nan if profile is None else profile.rise(i)
        confounded = (f"; confounded with {PARAMETER_NAMES[j]} ({r:+.2f})"
                      if abs(r) >= STRONG_CORRELATION else "")
        if ratio > NOT_IDENTIFIABLE_RATIO:
            verdict = "not identifiable"
            reason = (f"confounded with {PARAMETER_NAMES[j]} (correlation {r:+.2f})"
                      if abs(r) >= STRONG_CORRELATION
                      else "hardly any effect on the outputs the cost compares")
        elif sd[i] <= IDENTIFIABLE_SE and np.isfinite(rise) and rise >= PROFILE_RISE:
            verdict = "identifiable"
            reason = (f"s.e. {100 * sd[i]:.1f} %; moved {pct:.0f} % with the others "
                      f"re-fitted, the objective rises by {min(rise, 999):.1f}")
        else:
            verdict = "weakly identifiable"
            if sd[i] > IDENTIFIABLE_SE:
                reason = f"s.e. {100 * sd[i]:.0f} %" + confounded
            elif np.isfinite(rise):
                reason = (f"s.e. {100 * sd[i]:.1f} %, but moved {pct:.0f} % with the others "
                          f"re-fitted the objective rises by only {rise:.2f}: a curved "
                          f"valley" + confounded)
            else:
                reason = f"s.e. {100 * sd[i]:.1f} %, not tested on the objective" + confounded
        verdicts.append(ParameterVerdict(
            name=name, value=float(theta[i]), relative_se=float(sd[i]), prior_ratio=ratio,
            partner=PARAMETER_NAMES[j], correlation=r, rise=float(rise), verdict=verdict,
            reason=reason))
    return Identifiability(theta=theta, fim=F, condition_number=cond, eigenvalues=lam,
                           eigenvectors=vec, fim_statistical=Fs, covariance=C, correlation=R,
                           noise=np.asarray(noise, float), verdicts=verdicts, profile=profile)


def identify(model: DryerModel, segments: Sequence[Segment], theta: np.ndarray,
             spec: ObjectiveSpec, bounds: np.ndarray, *, profile: bool = True,
             jac_model: DryerModel | None = None
             ) -> tuple[Identifiability, list[Sensitivities]]:
    """The whole analysis at ``theta``: sensitivities, FIMs, and the profile test of the
    parameters the FIM calls pinned (its steps' Jacobians from ``jac_model`` when given,
    :func:`profile_test`)."""
    sens, ev = sensitivities(model, segments, theta, spec)
    noise = noise_from_evaluation(ev)
    p_sd = prior_sd(spec, bounds)
    local = analyse(sens, spec.weights, noise, p_sd)
    if not profile:
        return local, sens
    tested = np.array([v.relative_se <= IDENTIFIABLE_SE for v in local.verdicts])
    informed = np.array([v.verdict != "not identifiable" for v in local.verdicts])
    if not tested.any():
        return local, sens
    prof = profile_test(model, segments, theta, ev, spec, bounds, tested, informed,
                        jac_model=jac_model)
    return analyse(sens, spec.weights, noise, p_sd, prof), sens


#: Importance evaluators ``parameter_importance`` offers.
IMPORTANCE_METHODS: tuple[str, ...] = ("ped-anova", "fanova")


def parameter_importance(study, method: str = "ped-anova") -> dict[str, float]:
    """Importance of each parameter for reaching low costs in the study (paper's Fig. 4).

    ``"ped-anova"`` (default, no extra dependency, deterministic): how differently the best
    10 % of the trials are distributed from all trials, per parameter, normalised to 1.
    ``"fanova"``: the paper's fANOVA (Optuna's ``FanovaImportanceEvaluator``, seeded), which
    needs scikit-learn (``pip install softsensor[fanova]``). PED-ANOVA is the default because
    on a test cost that depends on ``mult_D`` and ``mult_h`` only, fANOVA over a TPE study gave
    41 to 63 % of the importance to ``hm_cyc`` (TPE samples the parameters jointly, so its
    forest confounds them), while PED-ANOVA ranked ``mult_D`` and ``mult_h`` first.
    """
    import optuna

    if method == "ped-anova":
        from optuna.importance import PedAnovaImportanceEvaluator

        evaluator = PedAnovaImportanceEvaluator()
    elif method == "fanova":
        try:
            import sklearn  # noqa: F401
        except ModuleNotFoundError as exc:
            raise ConfigError("fANOVA importance needs scikit-learn: pip install "
                              "'softsensor[fanova]'") from exc
        from optuna.importance import FanovaImportanceEvaluator

        evaluator = FanovaImportanceEvaluator(seed=0)
    else:
        raise ConfigError(f"unknown importance method {method!r} "
                          f"(known: {', '.join(IMPORTANCE_METHODS)})")
    return dict(optuna.importance.get_param_importances(
        study, evaluator=evaluator, params=list(PARAMETER_NAMES)))


__all__ = [
    "IDENTIFIABLE_SE",
    "IMPORTANCE_METHODS",
    "WITHIN",
    "Identifiability",
    "ParameterVerdict",
    "ProfileTest",
    "Sensitivities",
    "analyse",
    "bounds_prior_sd",
    "prior_sd",
    "condition_number",
    "identify",
    "lag1_autocorrelation",
    "noise_from_evaluation",
    "parameter_importance",
    "profile_test",
    "sensitivities",
    "statistical_fim",
    "weighted_fim",
]
