"""A SHA-256 of the dryer model's outputs on fixed inputs: a refactoring must leave it as is.

The compiled model (:mod:`softsensor.model`) is refactored for readability now and then (the
kernels split into modules, arguments packed); such a change must not move a single bit of
its outputs. :func:`digest` runs every path of :class:`~softsensor.model.DryerModel` on fixed
inputs and hashes the raw bytes of every array it returns:

* the 48 h closed-loop input sequence of ``benchmarks/model.py`` (seed 0; building it runs 288
  one-window ``simulate`` calls in a PI loop, so the inputs themselves hash model outputs),
  then ``simulate`` over all of it;
* ``simulate`` of four parameter sets at once (a batch, in parallel threads), with the
  ambient heat-loss extension (``aux``) on, and with a drifting parameter (``theta`` per
  window);
* ``steady_state`` of a batch of inputs and parameters; ``step`` with a ``dt`` per member;
* the lab short step: ``simulate`` from a wall state with ``dt`` a fraction of the window,
  as the filter's and the calibration's lab samples run it;
* ``profiles``; the virtual plant's ``control_stepper`` over 90 control steps of 20 s;
* a coarse grid (``n_d = 25``, one wall substep), and the two regression cases of
  ``tests/fixtures`` (a window near boiling; a cell the nested bisection solves).

``tests/fixtures/model_digest.json`` holds the digest and every number it hashes (6,614, to
12 digits). ``tests/model/test_model_digest.py`` compares the numbers at the tolerance of
:mod:`stored_numbers` (1e-9 relative): the digest is of one build (numba compiles for the
host CPU and the system's ``libm``, so another machine may differ in the last bits), the
numbers are what the physics computes. When the physics or the solver changes *on purpose*
(the outputs are meant to move), regenerate the file and commit it with the change, saying
why the numbers moved::

    .venv/bin/python tests/support/model_digest.py --write

``python tests/support/model_digest.py`` prints the digest, whether it matches the stored one
bit for bit, and whether the numbers match within the tolerance.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np
from paths import FIXTURES, REPO
from script_modules import load_script
from stored_numbers import RTOL, differences, stored

STORED = FIXTURES / "model_digest.json"


def _closed_loop_inputs(model, hours: float) -> np.ndarray:
    """``benchmarks/model.py``'s input sequence (loaded from the file: benchmarks is not a
    package)."""
    bench = load_script(REPO / "benchmarks" / "model.py")
    return bench.closed_loop_inputs(model, hours, seed=0)


def _fixture(name: str) -> dict:
    return json.loads((FIXTURES / f"{name}.json")
                      .read_text())


def _parameter_sets(model) -> np.ndarray:
    """Four parameter sets (4, 7) inside Table 1's bounds: nominal, and three spread out."""
    lo, hi = model.config.bounds().T
    rng = np.random.default_rng(23)
    spread = lo * (hi / lo) ** rng.uniform(0.2, 0.8, size=(3, lo.size))  # log-uniform inside
    return np.vstack([model.theta0, spread])


def model_outputs() -> dict[str, np.ndarray]:
    """Every array the cases above return, by name (in a fixed order)."""
    from softsensor.model import DryerModel
    from softsensor.plantconfig import load_plant_config

    config = load_plant_config()
    model = DryerModel(config)
    out: dict[str, np.ndarray] = {}
    U = _closed_loop_inputs(model, 48.0)
    out["bench_U"] = U
    out["bench_Y"], out["bench_state"] = model.simulate(U)

    thetas = _parameter_sets(model)
    U12 = U[:72]
    out["batch_Y"], out["batch_state"] = model.simulate(U12[None], thetas)
    aux = np.array([[0.0], [0.01], [0.02], [-0.005]])
    out["aux_Y"], _ = model.simulate(U12[None, :24], thetas, aux=aux)
    drift = np.repeat(model.theta0[None], 24, axis=0)
    drift[:, 2] *= np.linspace(1.0, 0.7, 24)  # mult_h decays over the day (fouling)
    out["drift_Y"], _ = model.simulate(U12[:24], drift)

    u_batch = U[::48][:4]
    out["steady_state"], out["steady_y"] = model.steady_state(u_batch, thetas)
    out["step_state"], out["step_y"] = model.step(out["steady_state"], u_batch, thetas,
                                                  dt=np.array([600.0, 137.0, 45.0, 1200.0]))
    wall = out["batch_state"]
    for dt in (37.0, 311.0):
        out[f"lab_Y_{dt:g}"], out[f"lab_state_{dt:g}"] = model.simulate(
            U[72:73][None].repeat(4, axis=0), thetas, state0=wall, dt=dt,
            raise_on_failure=False)
    prof = model.profiles(out["bench_state"], U[-1])
    out.update({f"profile_{k}": v for k, v in prof.items()})

    stepper = model.control_stepper(20.0)
    state = out["steady_state"][0].copy()
    plant = []
    for k in range(90):
        u = U[k // 30].copy()
        plant.append(stepper.advance(state, u, model.theta0, np.zeros(1)))
    out["plant_Y"], out["plant_state"] = np.array(plant), state

    coarse = DryerModel(config, n_d=25, wall_substeps=1)
    out["coarse_Y"], out["coarse_state"] = coarse.simulate(U[:36])

    case = _fixture("newton_regression")
    out["newton_state"], out["newton_y"] = model.step(
        np.array(case["state"]), np.array(case["u"]), np.array(case["theta"]), dt=case["dt"])
    case = _fixture("plant_boiling_regression")
    stepper = model.control_stepper(case["dt"])
    stepper._prof[:] = np.array(case["prof"])  # the warm start the failing step had
    state = np.array(case["state"])
    out["boiling_y"] = stepper.advance(state, np.array(case["u"]), np.array(case["theta"]),
                                       np.array(case["aux"]))
    out["boiling_state"] = state
    return out


def digest(outputs: dict[str, np.ndarray]) -> str:
    """SHA-256 over each array's name, shape, dtype and raw bytes (C order)."""
    h = hashlib.sha256()
    for name, a in outputs.items():
        a = np.ascontiguousarray(a)
        h.update(f"{name}:{a.shape}:{a.dtype.str}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def numbers(outputs: dict[str, np.ndarray]) -> dict[str, list[float]]:
    """Every output's numbers, flattened (C order), by name: what the reference stores."""
    return {name: np.ascontiguousarray(a).ravel().tolist() for name, a in outputs.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--write", action="store_true",
                   help=f"store the digest in {STORED.relative_to(REPO)} (physics changed on "
                        "purpose)")
    args = p.parse_args(argv)
    outputs = model_outputs()
    return store_or_compare(digest(outputs), numbers(outputs), STORED, args.write)


def store_or_compare(d: str, numbers_: dict[str, list], stored_path: Path, write: bool) -> int:
    """Print digest ``d``; store it with ``numbers_`` (``{field: values}``, floats to
    :data:`stored_numbers.DIGITS` digits) in ``stored_path`` when ``write``, else compare
    with the stored ones: exit status 1 when a number differs beyond the tolerance of
    :mod:`stored_numbers` (a digest of other bits alone is round-off of another build).
    Shared with ``tests/support/estimate_digest.py``."""
    print(d)
    if write:
        doc = {"sha256": d, "rtol": RTOL,
               "numbers": {k: [stored(v) for v in vs] for k, vs in numbers_.items()}}
        stored_path.write_text(json.dumps(doc, separators=(",", ":")).replace('],"', '],\n"')
                               + "\n")
        print(f"written to {stored_path}")
        return 0
    doc = json.loads(stored_path.read_text())
    print("matches the stored digest bit for bit" if d == doc["sha256"] else
          f"differs from the stored digest {doc['sha256']} (another build, or a change)")
    moved = differences(numbers_, doc["numbers"])
    print("\n".join(moved) if moved else f"every number within {RTOL:g} relative of the stored")
    return 1 if moved else 0


if __name__ == "__main__":
    sys.exit(main())
