"""The apps layer: the ``softsensor`` verbs, the files they write and their figures.

Everything that parses a command line, reads or writes a file on the user's behalf, or draws
a figure lives here; the core (:mod:`softsensor.model`, :mod:`softsensor.estimation`,
:mod:`softsensor.calibration`, :mod:`softsensor.diagnosis`) is handed data already read.
``lint-imports`` (contracts in ``pyproject.toml``) keeps it so.
"""
