"""The fast model against the full transient method of lines (softsensor.model.mol).

Both use the same cell rates; the fast model holds fibre and air at their quasi-steady profile
and steps the wall by Crank-Nicolson, the method of lines integrates all five states of every
cell with BDF. Issue 2 asked for 0.1 K and 0.001 kg/kg; the model page
(``docs/explanation/model.md``) claims what they do after the input steps below, and this is the
test of that claim: 0.01 K at the dryer outlet, 0.02 K at the cyclone outlet and 1e-4 kg/kg
(measured 0.0088 K, 0.0184 K and 8.6e-5 kg/kg, all in the last window, where mult_p doubles in a
cold snap; the same at rtol 1e-8, so the difference is the fast model's: its wall substeps and its
outside coefficient evaluated at the start of each substep).
"""

from __future__ import annotations

import numpy as np
import pytest

from softsensor.errors import SolverError
from softsensor.model import DryerModel, mol
from softsensor.plantconfig import load_plant_config
from softsensor.signals import INPUT_NAMES

TOL = np.array([0.01, 0.02, 1e-4])  # K, K, kg/kg: the model page's claim


@pytest.fixture(scope="module")
def model():
    return DryerModel(load_plant_config())


def _stepped_inputs(model: DryerModel) -> np.ndarray:
    """Four windows: steady, a T_air_in step up, a production step, a cold snap."""
    u = model.nominal_inputs()
    U = np.tile(u, (4, 1))
    U[1:, INPUT_NAMES.index("T_air_in")] = 505.0
    U[2:, INPUT_NAMES.index("m_fiber")] = 6.8
    U[3, INPUT_NAMES.index("T_air_in")] = 470.0
    U[3, INPUT_NAMES.index("T_amb")] = 265.0
    return U


@pytest.mark.parametrize("overrides, theta_scale, aux", [
    ({}, None, None),
    ({"T_air_in": 530.0, "m_fiber": 5.0, "T_amb": 300.0},
     np.array([1.5, 2.0, 0.7, 3.0, 2.0, 3.0, 0.5]), np.array([0.02])),
])
def test_rhs_vanishes_at_the_fast_steady_state(model, overrides, theta_scale, aux):
    # the same algebraic equations at steady state: the quasi-steady profile on the fast
    # model's steady wall is an equilibrium of the full method of lines
    u = model.nominal_inputs(**overrides)
    theta = model.theta0 if theta_scale is None else model.theta0 * theta_scale
    y0 = mol.initial_vector(model, u, theta, aux)
    m = mol.MethodOfLines(model)
    d = m.rhs(0.0, y0, u, theta, np.zeros(1) if aux is None else aux)
    L = m.layout
    # a residence time of ~0.06 s per cell turns these into < 1e-9 kg/kg and < 1e-7 K
    assert np.abs(d[L.field("X")]).max() < 1e-8
    assert np.abs(d[L.field("Y")]).max() < 1e-8
    for f in ("T_f", "T_a", "T_w"):
        assert np.abs(d[L.field(f)]).max() < 1e-6, f
    # and away from it the right-hand side is not trivially zero
    y1 = y0.copy()
    y1[L.index("T_a", 10)] += 1.0
    assert abs(m.rhs(0.0, y1, u, theta, np.zeros(1))[L.index("T_a", 10)]) > 1.0


def test_sparsity_pattern_covers_the_dense_jacobian(model):
    m = mol.MethodOfLines(model)
    u = model.nominal_inputs()
    y0 = mol.initial_vector(model, u, model.theta0)
    f0 = m.rhs(0.0, y0, u, model.theta0, np.zeros(1))
    S = m.layout.sparsity().toarray().astype(bool)
    scale = np.where(np.arange(m.layout.size) < 3 * m.layout.n_cells, 1e-6, 1e-3)
    scale[m.layout.field("Y")] = 1e-6
    hits = 0
    for j in range(m.layout.size):
        y = y0.copy()
        y[j] += scale[j]
        col = m.rhs(0.0, y, u, model.theta0, np.zeros(1)) - f0
        assert np.all(col[~S[:, j]] == 0.0), j
        hits += np.count_nonzero(col)
    assert hits > 0.5 * S.sum()  # the pattern is not grossly larger than needed


@pytest.fixture(scope="module")
def stepped(model):
    U = _stepped_inputs(model)
    theta = np.tile(model.theta0, (4, 1))
    theta[3, 4] *= 2.0  # mult_p doubles in the last window
    Y_fast, _ = model.simulate(U, theta)
    ref = mol.simulate_mol(model, U, theta, jac="sparse", rtol=1e-6)
    return U, theta, Y_fast, ref


def test_fast_model_agrees_with_method_of_lines_after_input_steps(stepped):
    U, _, Y_fast, ref = stepped
    diff = np.abs(Y_fast - ref.Y)
    assert np.all(diff <= TOL), diff
    # the steps were real: the outputs moved by far more than the tolerance
    assert np.ptp(ref.Y[:, 0]) > 20 * TOL[0]
    assert np.ptp(ref.Y[:, 2]) > 20 * TOL[2]


def test_method_of_lines_uses_the_stiff_solver_efficiently(stepped):
    # BDF with a grouped sparse Jacobian: a few Jacobians per window; a non-stiff method or
    # a broken pattern would need orders of magnitude more evaluations
    *_, ref = stepped
    assert ref.njev <= 10 * 4
    assert ref.nfev < 1000 * 4


@pytest.mark.slow
def test_dense_and_sparse_jacobians_give_the_same_answer(model, stepped):
    U, theta, _, ref = stepped
    dense = mol.simulate_mol(model, U[:2], theta[:2], jac="dense", rtol=1e-6)
    np.testing.assert_allclose(dense.Y, ref.Y[:2], atol=2e-3, rtol=0)


def test_solver_failure_raises_solver_error_with_the_solvers_message(model, monkeypatch):
    good = mol.MethodOfLines.rhs

    def broken(self, t, y, *args):
        d = good(self, t, y, *args)
        return d if t < 1.0 else np.full_like(d, np.nan)

    monkeypatch.setattr(mol.MethodOfLines, "rhs", broken)
    with pytest.raises(SolverError, match=r"method of lines failed in window 0 .*: \S+"):
        mol.simulate_mol(model, model.nominal_inputs()[None], jac="sparse")


def test_non_finite_input_is_refused_naming_the_signal(model):
    U = np.tile(model.nominal_inputs(), (2, 1))
    U[1, INPUT_NAMES.index("m_air")] = np.nan
    with pytest.raises(SolverError, match="m_air"):
        mol.simulate_mol(model, U)


def test_layout_is_field_major_and_round_trips(model):
    L = mol.StateLayout(model.geometry.n_d, model.geometry.n_c)
    n = L.n_cells
    v = L.pack(*(np.full(n, k, float) for k in range(5)))
    for k, f in enumerate(("X", "T_f", "Y", "T_a", "T_w")):
        assert np.all(v[L.field(f)] == k)
        assert v[L.index(f, n - 1)] == k
    assert L.size == 5 * (model.geometry.n_d + model.geometry.n_c)


@pytest.mark.slow
@pytest.mark.parametrize("law", ["cdc", "rea"])
def test_fast_model_agrees_with_method_of_lines_with_each_drying_law(model, law):
    # the law is dispatched inside the shared cell rates, so the method of lines integrates
    # the same law; three windows of the steps above (a T_air_in step, then production and a
    # cold snap): measured 0.0017 K / 0.0040 K / 1.1e-5 kg/kg (cdc) and 0.0018 K / 0.0043 K /
    # 9.4e-6 kg/kg (rea), as close as the paper's law
    from softsensor.model.structure import alternative_config, structure_space

    alt = next(a for a in structure_space() if a.sets.get("fiber.drying_law") == law)
    m = DryerModel(alternative_config(model.config, alt))
    U = _stepped_inputs(m)[:3].copy()
    U[2, INPUT_NAMES.index("T_amb")] = 265.0
    theta = np.tile(m.theta0, (3, 1))
    Y_fast, _ = m.simulate(U, theta)
    ref = mol.simulate_mol(m, U, theta, jac="sparse", rtol=1e-6)
    diff = np.abs(Y_fast - ref.Y)
    assert np.all(diff <= TOL), diff
    assert np.ptp(ref.Y[:, 0]) > 20 * TOL[0]
    assert np.ptp(ref.Y[:, 2]) > 20 * TOL[2]
    # and the law is the one asked for: the paper's law on the same inputs and parameters
    # ends elsewhere
    Y_paper, _ = model.simulate(U, theta)
    assert np.abs(Y_paper[-1, 2] - ref.Y[-1, 2]) > 20 * TOL[2]
