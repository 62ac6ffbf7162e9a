"""The DryerModel front door: batch broadcasting, per-window parameters, continuation, errors."""

from __future__ import annotations

import numpy as np
import pytest
from paths import FIXTURES

from softsensor.errors import SolverError
from softsensor.model import parameter_index
from softsensor.signals import INPUT_NAMES

K = 5


@pytest.fixture(scope="module")
def U(model):
    """K windows with input changes (T_air_in ramp, production step)."""
    U = np.tile(model.nominal_inputs(), (K, 1))
    U[:, INPUT_NAMES.index("T_air_in")] = np.linspace(480.0, 500.0, K)
    U[3:, INPUT_NAMES.index("m_fiber")] = 6.5
    return U


def _theta(model, **scale):
    th = model.theta0.copy()
    for name, f in scale.items():
        th[parameter_index(name)] *= f
    return th


# ------------------------------------------------------------------ broadcasting
def test_steady_state_broadcasts_batch_axes(model):
    u = np.stack([model.nominal_inputs(T_air_in=t) for t in (470.0, 490.0)])[:, None, :]
    theta = np.stack([_theta(model, mult_D=f) for f in (0.5, 1.0, 2.0)])[None, :, :]
    state, y = model.steady_state(u, theta)  # (2, 1, 8) with (1, 3, 7)
    assert state.shape == (2, 3, model.n_state)
    assert y.shape == (2, 3, 3)
    for i in range(2):
        for j in range(3):
            s1, y1 = model.steady_state(u[i, 0], theta[0, j])
            np.testing.assert_array_equal(y[i, j], y1)
            np.testing.assert_array_equal(state[i, j], s1)
    # different members really differ
    assert np.ptp(y[..., 2]) > 0.01


def test_simulate_broadcasts_batch_axes(model, U):
    thetas = np.stack([_theta(model, mult_h=f) for f in (0.7, 1.0, 1.4)])  # (3, 7)
    Y, state = model.simulate(U, thetas)  # U (K, 8) with theta (3, 7)
    assert Y.shape == (3, K, 3)
    assert state.shape == (3, model.n_state)
    for b in range(3):
        Yb, sb = model.simulate(U, thetas[b])
        np.testing.assert_array_equal(Y[b], Yb)
        np.testing.assert_array_equal(state[b], sb)
    # two input sequences against one theta, nested batch axes (2, 1) x (3,) -> (2, 3)
    UU = np.stack([U, U + np.array([5.0, 0, 0, 0, 0, 0, 0, 0])])[:, None]
    Y2, _ = model.simulate(UU, thetas)
    assert Y2.shape == (2, 3, K, 3)
    np.testing.assert_array_equal(Y2[0], Y)
    assert np.all(Y2[1, :, :, 0] > Y2[0, :, :, 0])  # hotter inlet air, hotter outlet


def test_simulate_with_per_window_theta(model, U):
    const = model.theta0
    per_window = np.tile(const, (K, 1))
    Y_const, _ = model.simulate(U, const)
    Y_pw, _ = model.simulate(U, per_window)
    np.testing.assert_array_equal(Y_pw, Y_const)
    # fouling from window 2 on: earlier windows untouched, later ones wetter
    fouled = per_window.copy()
    fouled[2:, parameter_index("mult_D")] = 0.6
    Y_f, _ = model.simulate(U, fouled)
    np.testing.assert_array_equal(Y_f[:2], Y_const[:2])
    assert np.all(Y_f[2:, 2] > Y_const[2:, 2] + 0.01)
    # a batch of per-window thetas
    Y_b, _ = model.simulate(U, np.stack([per_window, fouled]))
    np.testing.assert_array_equal(Y_b[0], Y_const)
    np.testing.assert_array_equal(Y_b[1], Y_f)


def test_state0_continuation_equals_one_long_simulation(model, U):
    Y_all, s_all = model.simulate(U)
    Y_a, s_a = model.simulate(U[:2])
    Y_b, s_b = model.simulate(U[2:], state0=s_a)
    np.testing.assert_allclose(np.concatenate([Y_a, Y_b]), Y_all, rtol=1e-13, atol=0)
    np.testing.assert_allclose(s_b, s_all, rtol=1e-13, atol=0)
    # the state passed in is not modified
    keep = s_a.copy()
    model.simulate(U[2:], state0=s_a)
    np.testing.assert_array_equal(s_a, keep)


def test_default_start_is_the_steady_state_of_the_first_window(model, U):
    s0, _ = model.steady_state(U[0])
    Y_default, _ = model.simulate(U)
    Y_explicit, _ = model.simulate(U, state0=s0)
    np.testing.assert_array_equal(Y_default, Y_explicit)


def test_steady_state_is_a_fixed_point_of_simulate(model):
    u = model.nominal_inputs()
    s, y = model.steady_state(u)
    Y, s_end = model.simulate(np.tile(u, (3, 1)), state0=s)
    np.testing.assert_allclose(Y, np.broadcast_to(y, Y.shape), atol=1e-9)
    np.testing.assert_allclose(s_end, s, atol=1e-9)


def test_step_equals_one_window_of_simulate(model, U):
    s0, _ = model.steady_state(U[0])
    s1, y1 = model.step(s0, U[1])
    Y, s_end = model.simulate(U[1:2], state0=s0)
    np.testing.assert_array_equal(y1, Y[0])
    np.testing.assert_array_equal(s1, s_end)
    # the caller's state is not modified, and a broadcast (read-only) state steps each member
    s0_copy = s0.copy()
    s_b, y_b = model.step(np.broadcast_to(s0, (2, s0.size)), U[1])
    np.testing.assert_array_equal(s0, s0_copy)
    np.testing.assert_array_equal(s_b, np.stack([s1, s1]))
    np.testing.assert_array_equal(y_b, np.stack([y1, y1]))


# ------------------------------------------------------------------ parallel members
@pytest.fixture(scope="module")
def model2(config):
    """The reference plant with two threads per batch, whatever the cores of this machine."""
    from softsensor.model import DryerModel

    return DryerModel(config, threads=2)


def _varied_members(model, U, n=5):
    """``n`` members with different inputs and parameters: (n, K, 8) and (n, 7)."""
    UU = np.repeat(U[None], n, axis=0)
    UU[:, :, INPUT_NAMES.index("T_air_in")] += np.linspace(-15.0, 15.0, n)[:, None]
    UU[:, :, INPUT_NAMES.index("m_fiber")] *= np.linspace(0.9, 1.1, n)[::-1, None]
    thetas = np.stack([_theta(model, mult_D=f, mult_h=1.0 / f, hm_cyc=f * f)
                       for f in np.linspace(0.6, 1.6, n)])
    return UU, thetas


def test_parallel_batch_equals_members_alone(model2, U):
    # members run in threads: each must get exactly the numbers it gets alone
    UU, thetas = _varied_members(model2, U)
    Y, state = model2.simulate(UU, thetas)
    s0, y0 = model2.steady_state(UU[:, 0], thetas)
    s1, y1 = model2.step(s0, UU[:, 1], thetas)
    for b in range(len(UU)):
        Yb, sb = model2.simulate(UU[b], thetas[b])
        assert np.array_equal(Y[b], Yb) and np.array_equal(state[b], sb)
        s0b, y0b = model2.steady_state(UU[b, 0], thetas[b])
        assert np.array_equal(s0[b], s0b) and np.array_equal(y0[b], y0b)
        s1b, y1b = model2.step(s0b, UU[b, 1], thetas[b])
        assert np.array_equal(s1[b], s1b) and np.array_equal(y1[b], y1b)
    assert np.ptp(Y[:, -1, 2]) > 0.01  # the members really differ


def test_failing_member_does_not_disturb_the_others(model2, U):
    UU, thetas = _varied_members(model2, U)
    UU[2, 3, INPUT_NAMES.index("m_air")] = np.nan  # member 2 fails in window 3
    thetas[4, parameter_index("mult_h")] = -1.0  # member 4 from its steady state on
    Y, state = model2.simulate(UU, thetas, raise_on_failure=False)
    assert np.all(np.isnan(Y[2, 3:])) and np.all(np.isfinite(Y[2, :3]))
    assert np.all(np.isnan(Y[4]))
    for b in (0, 1, 3):
        Yb, sb = model2.simulate(UU[b], thetas[b])
        assert np.array_equal(Y[b], Yb) and np.array_equal(state[b], sb)
    good, _ = model2.simulate(UU[2, :3], thetas[2])
    assert np.array_equal(Y[2, :3], good)
    # each failure is reported for its own member, with its own cause
    with pytest.raises(SolverError, match="member 2: inputs or parameters are not physical"):
        model2.simulate(UU[:4], thetas[:4])
    s0, _ = model2.steady_state(UU[:4, 0], thetas[:4])
    bad = UU[:4, 1].copy()
    bad[3, INPUT_NAMES.index("T_air_in")] = np.inf
    with pytest.raises(SolverError, match="member 3: inputs or parameters are not physical"):
        model2.step(s0, bad, thetas[:4])


# ------------------------------------------------------------------ errors
@pytest.mark.parametrize("signal, value", [
    ("m_air", -82.0), ("m_fiber", -1.0), ("m_fiber", 0.0), ("T_air_in", np.nan),
    ("H_amb", np.inf), ("moisture_in", np.nan),
])
def test_bad_inputs_raise_solver_error(model, U, signal, value):
    bad = U.copy()
    bad[2, INPUT_NAMES.index(signal)] = value
    with pytest.raises(SolverError) as exc:
        model.simulate(bad)
    msg = str(exc.value)
    assert "\n" not in msg
    assert f"{signal}=" in msg and "not physical" in msg
    u = U[0].copy()
    u[INPUT_NAMES.index(signal)] = value
    with pytest.raises(SolverError):
        model.steady_state(u)


def test_bad_theta_raises_solver_error(model, U):
    with pytest.raises(SolverError):
        model.simulate(U, _theta(model, mult_D=-1.0))
    with pytest.raises(SolverError):
        model.simulate(U, _theta(model, hc_cyc=np.nan))


def test_failures_give_nan_rows_only_for_the_failing_member(model, U):
    bad = U.copy()
    bad[2, INPUT_NAMES.index("m_air")] = np.nan
    Y, _ = model.simulate(np.stack([U, bad]), raise_on_failure=False)
    assert np.all(np.isfinite(Y[0]))
    assert np.all(np.isfinite(Y[1, :2]))
    assert np.all(np.isnan(Y[1, 2:]))
    Y_good, _ = model.simulate(U)
    np.testing.assert_array_equal(Y[0], Y_good)
    np.testing.assert_array_equal(Y[1, :2], Y_good[:2])


def test_bad_shapes_are_value_errors(model, U):
    with pytest.raises(ValueError):
        model.simulate(U[:, :7])
    with pytest.raises(ValueError):
        model.simulate(U[0])
    with pytest.raises(ValueError):
        model.steady_state(U[0], model.theta0[:6])
    with pytest.raises(ValueError):
        model.nominal_inputs(T_air=400.0)


def test_fibre_heated_towards_boiling_still_solves(model):
    # regression: a calibration trial (strong air-to-fibre heat, slow drying) drove the fibre
    # towards boiling, where the window step once failed to converge (see the fixture)
    import json

    case = json.loads((FIXTURES / "newton_regression.json").read_text())
    state, y = model.step(np.array(case["state"]), np.array(case["u"]),
                          np.array(case["theta"]), dt=case["dt"])
    assert np.all(np.isfinite(state)) and np.all(np.isfinite(y))
    assert 0.0 < y[2] < 0.35 and 330.0 < y[0] < 370.0


def test_cell_on_the_boiling_kink_solves_by_bracketing(model):
    # regression: the virtual plant (advance_one, warm start) stopped when a cell's outlet
    # state sat where y_sat(T_f) climbs steeply below boiling and the cell Newton failed from
    # every start (fixture: shifted parameters, seed 31340); the nested bisection of
    # cell_solver.bisect_cell is the last resort that finds such a cell
    import json

    from softsensor.model import cell_physics, cell_solver, kernels
    from softsensor.model import humid_air as ha
    from softsensor.model import wood as wd
    from softsensor.model.geometry import X_FSP

    case = json.loads((FIXTURES
                       / "plant_boiling_regression.json").read_text())
    state = np.array(case["state"])
    wall = state.copy()  # advance_one steps the wall in place after solving the profile
    prof = np.array(case["prof"])
    work = np.empty(4 * state.size)
    y = np.empty(3)
    geo = model.geometry.packed
    u, theta = np.array(case["u"]), np.array(case["theta"])
    st = kernels.advance_one(state, u, theta, np.array(case["aux"]), geo, case["dt"], prof,
                             work, y)
    assert st == kernels.OK
    assert np.all(np.isfinite(y)) and 330.0 < y[0] < 370.0 and 0.0 < y[2] < 0.5
    n_d = int(geo[kernels.N_D])
    assert np.all(np.diff(prof[0][:n_d]) <= 1e-12)  # the fibre dries along the tube
    # the bisection alone, on the third tube cell with what enters it: both cell residuals
    # vanish at its answer (a bisection returning its bracket or the upstream state fails
    # here) and it is the root the solver's profile holds
    i = 2
    Xp, Tfp, Yp, Tap = prof[0][i - 1], prof[1][i - 1], prof[2][i - 1], prof[3][i - 1]
    m_a, m_f = u[cell_physics.U_MAIR], u[cell_physics.U_MFIB]
    Efp = m_f * wd.enthalpy(Xp, Tfp, geo[X_FSP])
    Etot = m_a * ha.enthalpy(Tap, Yp) + Efp
    v_s, UAw = cell_physics.inflow_coefficients(0, Tap, Yp, Xp, m_a, theta, geo)
    ctx = cell_physics.upstream_context(Xp, Tfp, Yp, Tap, Efp, Etot, wall[i], UAw, v_s, m_a, m_f)
    ok, X, Tf = cell_solver.bisect_cell(0, ctx, theta, geo)
    assert ok
    F1, F2, *_ = cell_physics.cell_residual(0, X, Tf, ctx, theta, geo)
    assert abs(F1) < 1e-9 * m_f and abs(F2) < 1e-6 * m_f * 2000.0
    assert X == pytest.approx(prof[0][i], abs=1e-7) and Tf == pytest.approx(prof[1][i], abs=1e-5)
    assert abs(X - Xp) > 0.01  # it moved off the state entering the cell
