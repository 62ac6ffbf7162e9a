"""The pure physics core: humid air, wood, transfer coefficients, dryer tube and cyclone.

No I/O here. :class:`DryerModel` is the front door; :mod:`kernels` holds its compiled entry
points, which run the march down the tube and the wall step (:mod:`march`), each cell solved
(:mod:`cell_solver`) for its balances (:mod:`cell_physics`); :mod:`mol` is the full transient
method of lines used as a reference.
"""

from softsensor.jit_cache import configure as _configure_jit_cache

_configure_jit_cache()  # before the kernels are compiled or loaded from the cache

from softsensor.model.dryer import DryerModel, parameter_index  # noqa: E402

__all__ = ["DryerModel", "parameter_index"]
