"""Local identifiability of the seven multipliers (paper section 3.4).

Sensitivity trajectories (eq. 5)
    ``S_i(t) = theta_i * dy(t, theta)/d theta_i = dy/d ln(theta_i)``: the change of an output
    [K or kg/kg] per unit fractional change of a parameter, by central differences in
    ``ln(theta)`` through one batched model call of 15 members (nominal plus two per
    parameter), each from its own steady initial state.
Relative sensitivities
    ``J_relative = S_i / y_mean`` [-].
Weighted Fisher information (the form of the paper's Table 3)
    ``FIM = sum_m (1 / sigma^2) WF_m^2 J_m^T J_m`` with ``J_m`` the eq. 5 sensitivities of
    channel ``m`` at its samples (window means for the temperatures, lab sample times for
    ``moisture_out``: the information the data actually carry) and ``sigma = 1``. A common
    ``sigma`` scales the matrix only; its condition number, eigenvectors and correlations do
    not depend on it.
What the data can pin down
    The verdict needs the real noise of each channel, not the weights: the statistical FIM
    ``F = sum_m J_m^T J_m / s_m^2`` uses ``s_m``, the calibration's RMSE of channel ``m``
    (model error included), inflated by ``(1 + rho_m) / (1 - rho_m)`` for the lag-one
    autocorrelation ``rho_m`` of the window residuals (serially correlated residuals carry
    less information than independent ones). A weak Gaussian prior in ``ln(theta)`` whose
    +-2 sigma spans the Table 1 bounds regularises the exactly collinear directions
    (``mult_C`` and ``hm_cyc`` act only through their product). The posterior covariance
    ``C = (F + P0)^-1`` gives each parameter's relative standard error ``sqrt(C_ii)`` (in
    ``ln(theta)``, so 0.05 means about 5 %) and the correlation matrix.

The local FIM is not enough for the verdict. The model saturates (raising ``mult_h`` above
its value barely changes anything once air-to-fibre heat transfer stops limiting), so a
FIM standard error of a few percent can hide a ridge that runs tens of percent further; and
eq. 4 (a weighted sum of RMSEs) weights the temperature channels far less than their noise
would, so the estimator follows the 600 s temperature means much less than a likelihood
would. The verdict therefore tests the claim itself, non-linearly and with eq. 4:

*Displacement test* (points of the eq. 4 profile): each parameter is moved by
``x (1 +- WITHIN)`` (15 %); the other informed parameters start on the linearised eq. 4
valley (``delta_-i = -H_-i,-i^+ H_-i,i delta_i`` with the Gauss-Newton Hessian
``H = sum_m a_m J_m^T J_m`` of the re-weighted problem, ``a_m = WF_m / (N_m RMSE_m)``, see
:mod:`.refine`) and are re-fitted there by a few bounded Gauss-Newton steps, since the valley
is curved. The rise of eq. 4 is compared with its noise: a pure-noise change of the data moves
the difference of the two costs by ``sd = sqrt(sum_m s_m^2 |dJ/dy_m(moved) - dJ/dy_m(fit)|^2)``
with ``dJ/dy_m = WF_m r_m / (N_m RMSE_m)`` (``r_m`` the channel's residuals); for small
moves that is ``sqrt(sum_m a_m^2 s_m^2 |d_m|^2)``, ``d_m`` the change of channel ``m``'s
model outputs. ``z = (J_moved - J_fit) / sd``. For a quadratic
valley this is exactly ``z = delta / (2 s)``, with ``s`` the sandwich standard error
``sqrt([H^-1 G H^-1]_ii)`` of the eq. 4 estimator (``G = sum_m a_m^2 s_m^2 J_m^T J_m``), so
``s_eq4 = WITHIN / (2 z)`` is the eq. 4 estimator's standard error read off the non-linear
model.

Verdict per parameter: *not identifiable* when the data shrink its prior standard deviation
by less than half (statistical FIM above); *identifiable* when ``s_eq4 <= IDENTIFIABLE_SE``
on both sides (5 %: the 15 % recovery tolerance is three standard errors, even with the
other parameters compensating); *weakly identifiable* otherwise.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from softsensor.calibration.cost import Fit, ModelRun
from softsensor.calibration.dataset import Segment
from softsensor.errors import ConfigError, SolverError
from softsensor.model import DryerModel
from softsensor.plantconfig import PARAMETER_NAMES
from softsensor.signals import OUTPUT_NAMES

#: Central-difference step in ln(theta) (1 %; 0.1 % agrees to five digits).
SENSITIVITY_STEP = 1e-2
#: The displacement test's relative move (the recovery tolerance the verdict vouches for).
WITHIN = 0.15
#: Gauss-Newton evaluations re-fitting the other parameters at each displaced point.
PROFILE_NFEV = 4
#: eq. 4 standard error (from the displacement test) up to which a parameter is identifiable.
IDENTIFIABLE_SE = 0.05
#: Posterior / prior standard deviation above which a parameter counts as not identifiable.
NOT_IDENTIFIABLE_RATIO = 0.5
#: |correlation| above which two parameters are reported as confounded.
STRONG_CORRELATION = 0.9


@dataclass(frozen=True)
class Sensitivities:
    """Eq. 5 sensitivity trajectories on one segment.

    Attributes
    ----------
    theta : ndarray (7,)
    Y : ndarray (K, 3)
        Model outputs at ``theta`` (window ends).
    S : ndarray (K, 3, 7)
        ``dy_m / d ln(theta_i)`` at window ends [K or kg/kg per unit fractional change].
    S_lab : ndarray (L, 7)
        ``d moisture_out / d ln(theta_i)`` at the lab sample times [kg/kg].
    segment : Segment
    lab : ndarray (L,)
        Model ``moisture_out`` at the lab sample times at ``theta``.
    """

    theta: np.ndarray
    Y: np.ndarray
    S: np.ndarray
    S_lab: np.ndarray
    segment: Segment
    lab: np.ndarray | None = None

    @property
    def relative(self) -> np.ndarray:
        """``J_relative = S / y_mean`` (K, 3, 7) [-]."""
        return self.S / np.mean(self.Y, axis=0)[None, :, None]

    def channel_rows(self, c: int) -> np.ndarray:
        """Sensitivity rows of channel ``c`` at its measured samples: windows with a measured
        temperature (c = 0, 1) or lab samples (c = 2)."""
        if c == 2:
            return self.S_lab
        ok = np.isfinite(self.segment.Y[:, c])
        return self.S[ok, c, :]


def sensitivities(model: DryerModel, segment: Segment, theta: np.ndarray,
                  step: float = SENSITIVITY_STEP) -> Sensitivities:
    """Eq. 5 by central differences in ``ln(theta)``: one batched simulate of 15 members.

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
    from softsensor.calibration.chunked_run import simulate_segments

    run = simulate_segments(model, [segment], members)[0]
    Y, lab = run.Y, run.lab  # (2n+1, K, 3), (2n+1, L)
    ok = ~run.failed
    if not ok[0]:
        at = ", ".join(f"{k}={v:.4g}" for k, v in zip(PARAMETER_NAMES, theta, strict=True))
        raise SolverError(f"{segment.source}: the model fails at the parameters analysed "
                          f"({at})")
    S = np.empty(Y.shape[1:] + (n,))
    S_lab = np.empty((lab.shape[-1], n))
    for i in range(n):
        up, dn = 1 + 2 * i, 2 + 2 * i
        if ok[up] and ok[dn]:
            a, b, h = up, dn, 2 * step
        elif ok[up] or ok[dn]:
            a, b, h = (up, 0, step) if ok[up] else (0, dn, step)
        else:
            raise SolverError(f"{segment.source}: the model fails on both sides of "
                              f"{PARAMETER_NAMES[i]} = {theta[i]:.4g} (+-{step:g} in ln)")
        S[..., i] = (Y[a] - Y[b]) / h
        S_lab[:, i] = (lab[a] - lab[b]) / h
    return Sensitivities(theta=theta, Y=Y[0], S=S, S_lab=S_lab, segment=segment,
                         lab=lab[0])


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


def prior_sd(bounds: np.ndarray) -> np.ndarray:
    """Prior standard deviation of ln(theta): +-2 sd spans the Table 1 bounds."""
    return np.log(bounds[:, 1] / bounds[:, 0]) / 4.0


@dataclass(frozen=True)
class ParameterVerdict:
    name: str
    value: float
    relative_se: float
    prior_ratio: float
    partner: str | None
    correlation: float
    z: float
    eq4_se: float
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
    displacement: DisplacementTest | None = None

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


def noise_from_fit(fit: Fit, segments: Sequence[Segment], runs: Sequence[ModelRun]
                   ) -> np.ndarray:
    """Per-channel noise for the statistical FIM: the fit's RMSE, inflated for serially
    correlated window residuals by ``sqrt((1 + rho) / (1 - rho))`` (module docstring)."""
    noise = np.empty(3)
    for c, name in enumerate(OUTPUT_NAMES):
        s = float(fit.rmse[name]) if np.isfinite(fit.rmse[name]) else 0.0
        if c < 2:
            rho = np.mean([lag1_autocorrelation(seg.Y[:, c] - run.Y[0, :, c])
                           for seg, run in zip(segments, runs, strict=True)])
            rho = float(np.clip(rho, 0.0, 0.95))
            s *= np.sqrt((1 + rho) / (1 - rho))
        noise[c] = max(s, (0.01, 0.01, 1e-4)[c])  # floors: 0.01 K, 1e-4 kg/kg
    return noise


@dataclass(frozen=True)
class DisplacementTest:
    """Eq. 4 rise, in noise standard deviations, when a parameter moves by +-``within``
    with the others compensating (module docstring). NaN where not tested; ``inf`` where a
    bound blocks the move (the bound itself pins the parameter on that side)."""

    within: float
    z_up: np.ndarray
    z_down: np.ndarray
    dcost_up: np.ndarray
    dcost_down: np.ndarray

    def z(self, i: int) -> float:
        """The smaller rise of the two sides (NaN when untested)."""
        pair = [v for v in (self.z_up[i], self.z_down[i]) if not np.isnan(v)]
        return float(min(pair)) if pair else float("nan")


def eq4_standard_error(z: float, within: float = WITHIN) -> float:
    """Standard error of the eq. 4 estimator from a displacement-test rise ``z``:
    ``within / (2 z)`` (0 when a bound blocks the move, inf for no rise, NaN untested)."""
    if np.isnan(z):
        return float("nan")
    if z == np.inf:
        return 0.0
    return float(within / (2.0 * z)) if z > 0 else float("inf")


def eq4_weights(fit: Fit, weights: np.ndarray) -> np.ndarray:
    """``a_m = WF_m / (N_m RMSE_m)``: eq. 4 as re-weighted least squares at ``fit``."""
    a = np.zeros(3)
    for c, name in enumerate(OUTPUT_NAMES):
        r, n = fit.rmse[name], fit.n[name]
        if n and np.isfinite(r) and r > 0:
            a[c] = weights[c] / (n * r)
    return a


def displacement_test(model: DryerModel, segments: Sequence[Segment], theta: np.ndarray,
                      sens: Sequence[Sensitivities], fit: Fit, runs0: Sequence[ModelRun],
                      weights: np.ndarray, noise: np.ndarray, bounds: np.ndarray,
                      tested: np.ndarray, within: float = WITHIN,
                      profile_nfev: int = PROFILE_NFEV) -> DisplacementTest:
    """Move each ``tested`` parameter by ``x (1 +- within)``, re-fit the others and measure
    the rise of eq. 4 against its noise: points of the eq. 4 profile.

    The others start on the linearised eq. 4 valley and are then re-fitted by at most
    ``profile_nfev`` bounded Gauss-Newton steps (the re-weighted problem of :mod:`.refine`):
    the valley between ``mult_D`` and ``mult_h`` is curved (heat transfer saturates), and a
    straight line through it would overstate how well a parameter is pinned. Only the other
    ``tested`` parameters (those the data inform at all) are re-fitted: an uninformed one has
    a near-zero sensitivity column, and the valley would send it across decades.
    """
    from scipy.optimize import least_squares

    from softsensor.calibration.chunked_run import simulate_segments
    from softsensor.calibration.cost import evaluate_fit, residuals
    from softsensor.calibration.refine import WeightedResiduals, irls_scale

    n = len(PARAMETER_NAMES)
    a = eq4_weights(fit, weights)
    H = np.zeros((n, n))
    for s in sens:
        for c in range(3):
            J = s.channel_rows(c)
            H += a[c] * (J.T @ J)
    lo, hi = np.log(bounds[:, 0]), np.log(bounds[:, 1])
    z0 = np.log(theta)
    scale = irls_scale(fit, weights)
    members, where = [], []
    z_up, z_dn = np.full(n, np.nan), np.full(n, np.nan)
    for i in np.flatnonzero(tested):
        others = [j for j in np.flatnonzero(tested) if j != i]
        comp = (np.linalg.lstsq(H[np.ix_(others, others)], H[others, i], rcond=1e-10)[0]
                if others else np.zeros(0))
        for sign, step in ((1, np.log1p(within)), (-1, np.log1p(-within))):
            zi = z0[i] + step
            if zi > hi[i] + 1e-12 or zi < lo[i] - 1e-12:
                (z_up if sign > 0 else z_dn)[i] = np.inf
                continue
            z = z0.copy()
            z[i] = zi
            z[others] = np.clip(z0[others] - comp * step, lo[others], hi[others])
            if others and profile_nfev > 0:
                active = np.zeros(n, dtype=bool)
                active[others] = True
                prob = WeightedResiduals(model, segments, scale, z, active)
                sol = least_squares(prob.fun, z[active], jac=prob.jac,
                                    bounds=(lo[active], hi[active]), method="trf",
                                    max_nfev=profile_nfev, xtol=1e-4, ftol=1e-4)
                z = prob.full(np.clip(sol.x, lo[active], hi[active]))
            members.append(z)
            where.append((i, sign))
    d_up, d_dn = np.full(n, np.nan), np.full(n, np.nan)
    if members:
        runs = simulate_segments(model, segments, np.exp(np.array(members)))
        fits = evaluate_fit(runs, segments, weights)
        fit0 = evaluate_fit(runs0, segments, weights)[0]
        var = np.zeros(len(members))
        res0 = [residuals(r, seg) for r, seg in zip(runs0, segments, strict=True)]
        res1 = [residuals(r, seg) for r, seg in zip(runs, segments, strict=True)]
        for c, name in enumerate(OUTPUT_NAMES):
            n_c, R0 = fit0.n[name], fit0.rmse[name]
            if not n_c or not R0 > 0:
                continue
            R1 = np.array([f.rmse[name] for f in fits])[:, None]
            # d J / d data of both costs; their difference's variance under channel noise
            g0 = np.concatenate([r[c] for r in res0], axis=-1) / R0
            g1 = np.concatenate([r[c] for r in res1], axis=-1) / R1
            var += (weights[c] / n_c * noise[c]) ** 2 * np.sum((g1 - g0) ** 2, axis=-1)
        for b, (i, sign) in enumerate(where):
            dJ = fits[b].cost - fit0.cost
            sd = np.sqrt(var[b])
            zval = dJ / sd if sd > 0 and np.isfinite(dJ) else (np.inf if dJ > 0 else 0.0)
            (z_up if sign > 0 else z_dn)[i] = zval
            (d_up if sign > 0 else d_dn)[i] = dJ
    return DisplacementTest(within=within, z_up=z_up, z_down=z_dn, dcost_up=d_up,
                            dcost_down=d_dn)


def analyse(sens: Sequence[Sensitivities], weights: np.ndarray, noise: np.ndarray,
            bounds: np.ndarray, displacement: DisplacementTest | None = None
            ) -> Identifiability:
    """FIMs, condition number, eigenvectors, correlations and per-parameter verdicts.

    Without a ``displacement`` test no parameter is called identifiable (the local FIM
    alone cannot vouch for it); see the module docstring.
    """
    theta = sens[0].theta
    F = weighted_fim(sens, weights)
    lam, vec = np.linalg.eigh(F)
    lam_min = max(float(lam[0]), float(lam[-1]) * np.finfo(float).eps)
    cond = float(lam[-1] / lam_min) if lam[-1] > 0 else float("inf")
    Fs = statistical_fim(sens, noise)
    p_sd = prior_sd(bounds)
    C = np.linalg.inv(Fs + np.diag(1.0 / p_sd**2))
    C = 0.5 * (C + C.T)
    sd = np.sqrt(np.diag(C))
    R = C / np.outer(sd, sd)
    verdicts = []
    for i, name in enumerate(PARAMETER_NAMES):
        others = [j for j in range(len(PARAMETER_NAMES)) if j != i]
        j = others[int(np.argmax(np.abs(R[i, others])))]
        r = float(R[i, j])
        ratio = float(sd[i] / p_sd[i])
        z = np.nan if displacement is None else displacement.z(i)
        within = WITHIN if displacement is None else displacement.within
        pct = 100 * within
        se4 = eq4_standard_error(z, within)
        if ratio > NOT_IDENTIFIABLE_RATIO:
            verdict = "not identifiable"
            reason = (f"confounded with {PARAMETER_NAMES[j]} (correlation {r:+.2f})"
                      if abs(r) >= STRONG_CORRELATION
                      else "hardly any effect on the measured outputs")
        elif se4 <= IDENTIFIABLE_SE:
            verdict = "identifiable"
            reason = (f"eq. 4 s.e. {100 * se4:.1f} %: moving it {pct:.0f} % (others "
                      f"re-fitted) raises J by {min(z, 999):.1f} noise s.d.")
        else:
            verdict = "weakly identifiable"
            side = ""
            if displacement is not None:
                up, dn = displacement.z_up[i], displacement.z_down[i]
                side = "up" if (np.nan_to_num(up, nan=np.inf) <= np.nan_to_num(dn, nan=np.inf)) \
                    else "down"
            if np.isfinite(z) and z < 0:
                reason = (f"moving it {pct:.0f} % {side} with the others re-fitted lowers J "
                          f"({z:.1f} noise s.d.): a flat valley, the fit is one point of it")
            elif np.isfinite(z):
                reason = (f"eq. 4 s.e. {100 * se4:.0f} %: moving it {pct:.0f} % {side} (others "
                          f"re-fitted) raises J by only {z:.1f} noise s.d.")
            else:
                reason = f"local s.e. {100 * sd[i]:.0f} %, not tested non-linearly"
            if abs(r) >= STRONG_CORRELATION:
                reason += f"; confounded with {PARAMETER_NAMES[j]} ({r:+.2f})"
        verdicts.append(ParameterVerdict(
            name=name, value=float(theta[i]), relative_se=float(sd[i]), prior_ratio=ratio,
            partner=PARAMETER_NAMES[j], correlation=r, z=float(z), eq4_se=float(se4),
            verdict=verdict,
            reason=reason))
    return Identifiability(theta=theta, fim=F, condition_number=cond, eigenvalues=lam,
                           eigenvectors=vec, fim_statistical=Fs, covariance=C, correlation=R,
                           noise=np.asarray(noise, float), verdicts=verdicts,
                           displacement=displacement)


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
    "IMPORTANCE_METHODS",
    "WITHIN",
    "IDENTIFIABLE_SE",
    "eq4_standard_error",
    "DisplacementTest",
    "displacement_test",
    "eq4_weights",
    "Identifiability",
    "ParameterVerdict",
    "Sensitivities",
    "analyse",
    "lag1_autocorrelation",
    "noise_from_fit",
    "parameter_importance",
    "prior_sd",
    "sensitivities",
    "statistical_fim",
    "weighted_fim",
]
