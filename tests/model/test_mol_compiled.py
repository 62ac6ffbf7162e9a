"""The method of lines' compiled right-hand side against the same source interpreted.

``benchmarks/model.py`` times the method of lines with a compiled right-hand side as the fair
peer of the fast model; that is only a fair peer if the compiled derivatives are the Python
ones. Both run :func:`softsensor.model.mol.derivatives` (numba, and its ``py_func``), on
states away from equilibrium, in tube and cyclone cells, with parameters and the model
extension changed.
"""

from __future__ import annotations

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

from softsensor.model import DryerModel, mol
from softsensor.plantconfig import load_plant_config


@pytest.fixture(scope="module")
def model():
    return DryerModel(load_plant_config())


def _states(model: DryerModel, rng: np.random.Generator) -> list[tuple[np.ndarray, ...]]:
    """(y, u, theta, aux): the consistent start, then perturbed states, inputs and parameters."""
    u = model.nominal_inputs()
    y0 = mol.initial_vector(model, u, model.theta0)
    L = mol.StateLayout(model.geometry.n_d, model.geometry.n_c)
    cases = [(y0, u, model.theta0, np.zeros(1))]
    for _ in range(3):
        y = y0.copy()
        y[L.field("X")] *= rng.uniform(0.9, 1.1, L.n_cells)
        y[L.field("Y")] *= rng.uniform(0.9, 1.1, L.n_cells)
        for f in ("T_f", "T_a", "T_w"):
            y[L.field(f)] += rng.uniform(-5.0, 5.0, L.n_cells)
        theta = model.theta0 * np.exp(rng.uniform(-0.7, 0.7, 7))
        cases.append((y, model.nominal_inputs(T_air_in=505.0, m_fiber=6.5, T_amb=270.0),
                      theta, np.array([0.02])))
    return cases


def test_compiled_derivatives_equal_the_interpreted_ones(model):
    assert isinstance(mol.derivatives, CPUDispatcher)  # really numba-compiled
    compiled = mol.MethodOfLines(model)
    interpreted = mol.MethodOfLines(model, compiled=False)
    for k, (y, u, theta, aux) in enumerate(_states(model, np.random.default_rng(3))):
        d_c = compiled.rhs(0.0, y, u, theta, aux)
        d_p = interpreted.rhs(0.0, y, u, theta, aux)
        assert np.all(np.isfinite(d_c))
        # the same operations in the same order; libm's exp/log may differ in the last bit
        np.testing.assert_allclose(d_c, d_p, rtol=1e-11, atol=1e-12)
        if k > 0:  # away from equilibrium: not trivially zero in any field
            assert np.all(np.abs(d_c).reshape(5, -1).max(axis=1) > 1e-6)
    assert compiled.nfev == interpreted.nfev == 4
    assert mol.derivatives.signatures  # the compiled path ran


def test_simulate_mol_gives_the_same_outputs_compiled_or_interpreted(model):
    U = np.tile(model.nominal_inputs(), (1, 1))
    U[0, 0] = 505.0  # a T_air_in step: the window is a transient
    fast = mol.simulate_mol(model, U, jac="sparse", rtol=1e-6)
    slow = mol.simulate_mol(model, U, jac="sparse", rtol=1e-6, compiled=False)
    assert fast.nfev == slow.nfev  # the same BDF path
    np.testing.assert_allclose(fast.Y, slow.Y, rtol=1e-9)


def test_aux_of_the_wrong_length_is_refused(model):
    # the compiled right-hand side does not check bounds: simulate_mol does
    with pytest.raises(ValueError, match=r"aux must have shape \(1,\)"):
        mol.simulate_mol(model, model.nominal_inputs()[None], aux=np.zeros(3))
