"""The apps layer: the ``softsensor`` verbs and the files they read and write.

Everything that parses a command line or reads or writes a file on the user's behalf lives here
(the report pages and their figures are :mod:`softsensor.presentation`'s); the core
(:mod:`softsensor.model`, :mod:`softsensor.estimation`,
:mod:`softsensor.calibration`, :mod:`softsensor.diagnosis`) is handed data already read.
``lint-imports`` (contracts in ``pyproject.toml``) keeps it so.
"""
