"""Mutation check of the physics, the estimator and the tests mended in issue 23: does a wrong
sign, factor, digit or index fail a test?

Each mutation is ``(name, file, original snippet, mutated snippet, pytest selection)``. The
check copies the repository (without .git and the venv) to a temporary directory, replaces the
snippet there (never in the working tree), runs the selection under a timeout with a fresh
numba cache, and calls the mutation *killed* when the selection fails. Each selection is first
run on the unmutated copy: it must pass there, or a kill would mean nothing.

    python tests/support/mutation_check.py              # every mutation; exit 1 if one lives
    python tests/support/mutation_check.py --only NAME  # some of them

``tests/support/test_mutation_check.py`` (slow) runs it.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from paths import REPO

TIMEOUT_S = 900


@dataclass(frozen=True)
class Mutation:
    name: str
    file: str
    original: str
    mutated: str
    selection: tuple[str, ...]


HA, WOOD, TR = "softsensor/model/humid_air.py", "softsensor/model/wood.py", \
    "softsensor/model/transfer.py"
CELL, MARCH = "softsensor/model/cell_physics.py", "softsensor/model/march.py"
EST = "softsensor/estimation/"
T_HA, T_WOOD, T_TR = ("tests/model/test_humid_air.py",), ("tests/model/test_wood.py",), \
    ("tests/model/test_transfer.py",)
T_BAL = ("tests/model/test_balances.py",)
T_MOL = ("tests/model/test_mol.py", "-k", "agrees")
T_STATE = ("tests/estimation/test_state_space.py",)
T_CONSISTENCY = ("tests/estimation/test_consistency.py",)
T_LAB_ALIGN = ("tests/windows/test_lab_alignment.py",)
T_UKF = ("tests/estimation/test_ukf.py",)
# the tests issue 23 made able to fail, each run alone on the mutation of what it guards
DIAG, CAL = "softsensor/diagnosis/", "softsensor/calibration/"
WIN = "softsensor/windows/"
T_HA_REF = ("tests/model/test_humid_air.py", "-k", "psychrolib")
T_LAB_SHIFT = ("tests/diagnosis/test_residuals.py", "-k", "lab_statistics_on_a_clean_day")
T_REPORT = ("tests/system/test_plant_path.py", "-k", "calibrate_and_diagnose")
T_README = ("tests/service/test_offline_replay.py", "-k", "readme")
T_RECOVERY = ("tests/calibration/test_recovery.py", "-k", "recovery_24h")

MUTATIONS: tuple[Mutation, ...] = (
    Mutation("humidity ratio drops the partial pressure", HA,
             "return EPS * p_w / (P - p_w)", "return EPS * p_w / P", T_HA),
    Mutation("humid-air enthalpy: vapour term 10 % low", HA,
             "return dry_air_enthalpy(T) + Y * vapour_enthalpy(T)",
             "return dry_air_enthalpy(T) + 0.9 * Y * vapour_enthalpy(T)", T_HA),
    Mutation("humid-air viscosity: vapour's ignored", HA,
             "return _wilke_mix(Y, mu_a, mu_v, mu_a, mu_v)",
             "return _wilke_mix(Y, mu_a, mu_v, mu_a, mu_a)", T_HA),
    Mutation("sorption heat linear in the bound-water deficit", WOOD,
             "return 0.4 * h_fg0 * r * r", "return 0.4 * h_fg0 * r", T_WOOD),
    Mutation("wood enthalpy: sorption integral's sign", WOOD,
             "return dry + X * C_W * t + bond - _sorption_integral(X, X_fsp)",
             "return dry + X * C_W * t + bond + _sorption_integral(X, X_fsp)", T_WOOD),
    Mutation("equilibrium moisture in per cent", WOOD,
             "return M / 100.0", "return M / 10.0", T_WOOD),
    Mutation("Churchill-Bernstein coefficient", TR,
             "return 0.3 + 0.62 * np.sqrt(Re)", "return 0.3 + 0.66 * np.sqrt(Re)", T_TR),
    Mutation("Chilton-Colburn exponent", TR,
             "(Sc / Pr) ** (-2.0 / 3.0)", "(Sc / Pr) ** (-1.0 / 3.0)", T_TR),
    Mutation("radiation coefficient loses a factor", TR,
             "(T_w * T_w + T_amb * T_amb) * (T_w + T_amb)",
             "(T_w * T_w + T_amb * T_amb) * T_w", T_TR),
    Mutation("cell energy balance: latent heat's sign", CELL,
             "F2 = (Efp - m_f * hf) + Q - R * ha.vapour_enthalpy(Tfm)",
             "F2 = (Efp - m_f * hf) + Q + R * ha.vapour_enthalpy(Tfm)", T_BAL),
    Mutation("cell water balance: air takes 99 % of the water", CELL,
             "Y = Yp + m_f / m_a * (Xp - X)", "Y = Yp + 0.99 * m_f / m_a * (Xp - X)", T_BAL),
    Mutation("tube evaporation rate loses its driving force's sign", CELL,
             "R = theta[K_D] * alpha * K_c * rho * a_dx * drive  # eq. 2",
             "R = theta[K_D] * alpha * K_c * rho * a_dx * abs(drive)  # eq. 2", T_BAL),
    Mutation("wall step: Crank-Nicolson made explicit on the right", MARCH,
             "rhs[i] = C / dt * Tw[i] - 0.5 * KT + b", "rhs[i] = C / dt * Tw[i] - KT + b",
             T_MOL),
    Mutation("steady shell: outside conductance 10 % low", MARCH,
             "Tsh[j] = (UA * Ta + Uo * T_amb) / (UA + Uo)",
             "Tsh[j] = (UA * Ta + Uo * T_amb) / (UA + 0.9 * Uo)", T_BAL),
    Mutation("error states' noise: 1 - a for 1 - a^2", EST + "state_space.py",
             "priors.sigma**2 * (1.0 - a**2))",
             "priors.sigma**2 * (1.0 - a))", T_STATE),
    Mutation("random-walk error states: their walk per window, not per second",
             EST + "state_space.py", "priors.walk**2 * float(dt_s)", "priors.walk**2", T_STATE),
    Mutation("heat-input prior times the gain", EST + "state_space.py",
             "sigma[0] /= max(heat_gain, 1e-3)", "sigma[0] *= max(heat_gain, 1e-3)", T_STATE),
    Mutation("inlet transform's derivative twice as wide", EST + "state_space.py",
             "np.where(s > b, np.exp(-(np.maximum(s, b) - b) / m)",
             "np.where(s > b, np.exp(-(np.maximum(s, b) - b) / 2 / m)",
             T_STATE),
    Mutation("adaptive noise without the outlier clamp", EST + "state_space.py",
             "r = min(max(nu2_over_s, 0.0), 9.0)", "r = max(nu2_over_s, 0.0)", T_STATE),
    Mutation("lab window: boundary sample to the next window", WIN + "lab_alignment.py",
             "return (t - int(start_ns) - 1) // int(period_ns)",
             "return (t - int(start_ns)) // int(period_ns)", T_LAB_ALIGN),
    Mutation("lab inputs: span one bin short", WIN + "lab_alignment.py",
             "first = min(max((rel - int(span_ns)) // bin_ns, 0), last)",
             "first = min(max((rel - int(span_ns)) // bin_ns + 1, 0), last)", T_LAB_ALIGN),
    Mutation("consistency: the test's inequality turned", EST + "consistency.py",
             "if total <= limit:", "if total < 0.9 * limit:", T_CONSISTENCY),
    Mutation("consistency: one degree of freedom too many", EST + "consistency.py",
             "limit = float(chdtri(dof, alpha))", "limit = float(chdtri(dof + 1, alpha))",
             T_CONSISTENCY),
    Mutation("UKF: the joint covariance with the mean's weights", EST + "ukf_step.py",
             "mean, cov = unscented_transform(joint, pts.Wm, pts.Wc)",
             "mean, cov = unscented_transform(joint, pts.Wm, pts.Wm)", T_UKF),
    Mutation("UKF: a measurement row without its offset state", EST + "ukf_step.py",
             "out[:, m] = sig.y[:, r] + sigmas[:, ROW_OFFSET[r]]", "out[:, m] = sig.y[:, r]",
             T_UKF),
    Mutation("UKF: the update trusts the measurements ten times more", EST + "ukf_step.py",
             "mean, cov = kf_update(mean, cov, meas.z, meas.R, H)",
             "mean, cov = kf_update(mean, cov, meas.z, 0.1 * meas.R, H)", T_UKF),
    Mutation("UKF: the inlet gain left out of the outlet moisture", EST + "ukf_step.py",
             "return y_ref + gain_response(sigmas[:, X_GAIN]) * (y - y_ref) + sigmas[:, X_BIAS]",
             "return y + sigmas[:, X_BIAS]", T_UKF),
    Mutation("UKF: the learned discrepancy not taken off the measurements", EST + "ukf_step.py",
             "values = [v - g[c] for c, v in zip(temps.channels, temps.values, strict=True)]",
             "values = list(temps.values)",
             ("tests/estimation/test_ukf.py", "-k", "learned_discrepancy_is_taken_off")),
    # issue 23: each mended test against a one-line mutation its old form let through
    Mutation("saturation pressure: a coefficient's last digit dropped", HA,
             "C11, C12, C13 = 4.1764768e-5, -1.4452093e-8, 6.5459673",
             "C11, C12, C13 = 4.1764768e-5, -1.4452093e-8, 6.545967", T_HA_REF),
    Mutation("humidity ratio: ASHRAE 2009's M_w / M_da", HA,
             "EPS = 0.621945  # M_w / M_da", "EPS = 0.62198  # M_w / M_da", T_HA_REF),
    Mutation("lab statistics: the best shift one grid step off its RMSE", DIAG + "residuals.py",
             "float(LAB_SHIFTS_MIN[i]), float(rmse[i]))",
             "float(LAB_SHIFTS_MIN[i + 1]), float(rmse[i]))", T_LAB_SHIFT),
    Mutation("verdict: the ranking drops a cause", DIAG + "verdict.py",
             "ranking += [(s.cause, 0.0, s) for s in rest]",
             "ranking += [(s.cause, 0.0, s) for s in rest[1:]]", T_REPORT),
    Mutation("UKF: a lab result's variance ten times its noise", EST + "ukf_step.py",
             "lab_var = (s.lab_std**2 + s.moisture_out_jitter_std**2 if me is None",
             "lab_var = (10.0 * s.lab_std**2 + s.moisture_out_jitter_std**2 if me is None",
             T_README),
    Mutation("identifiability: the standard-error bar ten times stricter",
             CAL + "identifiability.py",
             "elif sd[i] <= IDENTIFIABLE_SE and np.isfinite(rise) and rise >= PROFILE_RISE:",
             "elif sd[i] <= 0.1 * IDENTIFIABLE_SE and np.isfinite(rise) and rise >= PROFILE_RISE:",
             T_RECOVERY),
)


def copy_repository(dest: Path) -> Path:
    ignore = shutil.ignore_patterns(".git", ".venv", "__pycache__", "*.egg-info", "build",
                                    "out", ".pytest_cache", ".ruff_cache")
    shutil.copytree(REPO, dest, ignore=ignore)
    return dest


def run_selection(tree: Path, selection: tuple[str, ...]) -> tuple[bool, float, str]:
    """``(passed, seconds, last line)`` of pytest on ``selection`` in ``tree``, with an empty
    numba cache (numba's cache does not see a change in a module the kernels inline)."""
    shutil.rmtree(tree / ".numba", ignore_errors=True)
    env = {**os.environ, "PYTHONPATH": str(tree), "NUMBA_CACHE_DIR": str(tree / ".numba")}
    t = time.perf_counter()
    try:
        r = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
                            "-m", "not slow", *selection], cwd=tree, env=env,
                           capture_output=True, text=True, timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return False, time.perf_counter() - t, f"timeout after {TIMEOUT_S} s"
    lines = r.stdout.strip().splitlines()
    return r.returncode == 0, time.perf_counter() - t, lines[-1] if lines else r.stderr[-200:]


def apply(tree: Path, m: Mutation) -> str:
    """Mutate ``m.file`` in ``tree``; returns the original text to restore."""
    path = tree / m.file
    text = path.read_text()
    if text.count(m.original) != 1:
        raise SystemExit(f"mutation {m.name!r}: {m.file} holds the snippet "
                         f"{text.count(m.original)} times, not once: {m.original!r}")
    path.write_text(text.replace(m.original, m.mutated))
    return text


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", nargs="+", default=None, metavar="NAME",
                   help="run the mutations whose name contains one of these")
    args = p.parse_args(argv)
    todo = [m for m in MUTATIONS
            if args.only is None or any(o in m.name for o in args.only)]
    if not todo:
        raise SystemExit(f"no mutation matches {args.only}")
    with tempfile.TemporaryDirectory(prefix="softsensor-mutants-") as tmp:
        tree = copy_repository(Path(tmp) / "repo")
        for sel in dict.fromkeys(m.selection for m in todo):
            ok, secs, last = run_selection(tree, sel)
            print(f"baseline {' '.join(sel)}: {'pass' if ok else 'FAIL'} ({secs:.0f} s) {last}",
                  flush=True)
            if not ok:
                raise SystemExit(f"the selection {' '.join(sel)} fails without a mutation")
        survivors = []
        print("| mutation | file | selection | result | s |\n|---|---|---|---|---|")
        for m in todo:
            original = apply(tree, m)
            try:
                passed, secs, last = run_selection(tree, m.selection)
            finally:
                (tree / m.file).write_text(original)
            verdict = "SURVIVED" if passed else "killed"
            if passed:
                survivors.append(m.name)
            print(f"| {m.name} | {m.file} | {' '.join(m.selection)} | {verdict} | {secs:.0f} |",
                  flush=True)
    print(f"{len(todo) - len(survivors)} of {len(todo)} killed"
          + (f"; survived: {survivors}" if survivors else ""))
    return 1 if survivors else 0


if __name__ == "__main__":
    sys.exit(main())
