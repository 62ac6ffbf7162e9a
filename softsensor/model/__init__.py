"""The pure physics core: humid air, wood, transfer coefficients, dryer tube and cyclone.

No I/O here. :class:`DryerModel` is the front door; :mod:`kernels` holds the compiled cell
balances, :mod:`mol` the full transient method of lines used as a reference.
"""

from softsensor.jit_cache import configure as _configure_jit_cache

_configure_jit_cache()  # before the kernels are compiled or loaded from the cache

from softsensor.model.dryer import DryerModel, parameter_index  # noqa: E402

__all__ = ["DryerModel", "parameter_index"]
