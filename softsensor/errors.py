"""The project's error hierarchy.

Every error raised on purpose derives from :class:`SoftsensorError`; its message is one line
that names what is wrong (the file, the dotted config key, the signal). The command line turns
any ``SoftsensorError`` into ``softsensor: <message>`` on stderr and a non-zero exit status::

    SoftsensorError
    +-- ConfigError      a config or parameter file is missing, malformed or out of range
    +-- IngestError      a recorded day, a Modbus read or a lab result cannot be used
    +-- SolverError      the model could not be solved (the solver's message is kept)
    +-- EstimationError  the estimator cannot continue (e.g. covariance lost definiteness)
    +-- MissingPackageError  a package of an extra is not installed (exit status 1, like a
                             broken install, not 2: the input is fine)
"""


class SoftsensorError(Exception):
    """Base class of all errors the project raises on purpose."""


class ConfigError(SoftsensorError):
    """A configuration value is missing, of the wrong type or out of range."""


class IngestError(SoftsensorError):
    """Input data (MCAP day, Modbus registers, lab result) cannot be used."""


class SolverError(SoftsensorError):
    """The model could not be solved for the given inputs and parameters."""


class EstimationError(SoftsensorError):
    """The estimator cannot continue."""


class MissingPackageError(SoftsensorError):
    """A package this use needs is not installed (the ``offline`` extra)."""


#: The extra of pyproject.toml that holds what only the offline studies use: Optuna
#: (calibration), Matplotlib (report figures), PyArrow (Parquet tables), filterpy (the
#: diagnosis's Kalman steps), about 250 MB that the daemon's install and container image
#: leave out.
OFFLINE_EXTRA = "offline"


def require_packages(purpose: str, *modules: str) -> None:
    """Raise :class:`MissingPackageError` naming the first of ``modules`` that is not
    installed and the command that installs it (``purpose`` says what needs it: a verb, a
    file format)."""
    import importlib.util  # here, so that importing the error classes stays free

    for module in modules:
        if importlib.util.find_spec(module) is None:
            raise MissingPackageError(f"{purpose} needs the package {module}, which this "
                                      f"install leaves out: pip install "
                                      f"'softsensor[{OFFLINE_EXTRA}]'")


def one_line(message: str, max_chars: int | None = None) -> str:
    """``message`` as one printable line: a line break or other control character in it (a
    user's typo, a hostile file's value) is shown escaped; cut to ``max_chars`` if given."""
    line = "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(message))
    if max_chars is not None and len(line) > max_chars:
        line = line[:max_chars - 3] + "..."
    return line
