"""Exception and warning classes of servotune.

Every error servotune raises on purpose derives from :class:`ServotuneError` and also from the
built-in exception it resembles, so callers may catch either.
"""

from __future__ import annotations

__all__ = [
    "AutotuneStopped",
    "CompileError",
    "ConfigError",
    "CounterFaultWarning",
    "DigestError",
    "ExportError",
    "FleetTableError",
    "HalError",
    "IdentificationError",
    "InfeasibleError",
    "LogFormatError",
    "RigError",
    "SchedulerError",
    "ServotuneError",
    "SimulationError",
    "SpecError",
    "TrustError",
    "TuningError",
]


class ServotuneError(Exception):
    """Base class of all servotune errors."""


class RigError(ServotuneError, ValueError):
    """A rig file or rig object is invalid (wrong field, value or unit)."""


class LogFormatError(ServotuneError, ValueError):
    """A log file does not follow the log format (docs/formats.md#log-file)."""


class IdentificationError(ServotuneError, ValueError):
    """The data do not allow the requested identification."""


class SpecError(ServotuneError, ValueError):
    """A specification or scenario request is invalid or impossible."""


class InfeasibleError(SpecError):
    """The spec is well-formed, but no tuning meets it (the CLI exits 1: the tuning failed its
    spec, as a failed verification does)."""


class CompileError(ServotuneError, RuntimeError):
    """A compiled kernel does not compile with the installed numba (the message has the cause).

    servotune has no slower fallback that would hide it: install the numba version range that
    ``pyproject.toml`` names.
    """


class SimulationError(ServotuneError, ValueError):
    """A simulation request is inconsistent (shapes, timebases, options)."""


class TuningError(ServotuneError, ValueError):
    """A tuning file is malformed or does not belong to the rig it is used with."""


class ExportError(ServotuneError, ValueError):
    """A table or runtime export cannot be produced."""


class FleetTableError(ServotuneError, ValueError):
    """A fleet table (``servotune fit LOGS --fleet FILE``) cannot be written or read back."""


class ConfigError(ServotuneError, ValueError):
    """An architecture configuration (``servotune sync`` / ``linkage``) is invalid."""


class HalError(ServotuneError, RuntimeError):
    """A running HAL session refused a command, or none runs (``servotune autotune``)."""


class AutotuneStopped(ServotuneError, RuntimeError):
    """A live autotune run stopped before it loaded verified gains (the wiring check, the
    safety envelope's trip, a failed verification or validation move, a signal); the axis
    is left with its previous parameters."""


class TrustError(ServotuneError):
    """What was verified and what is given differ: a tuning, rig or spec whose SHA-256 is not
    the one its verification record (or tuning) holds, a record or export that was edited, a
    record made by another tool version, or no passing verification at all. The CLI exits 1:
    the inputs are well-formed, but they are not the verified ones."""


class DigestError(ExportError, TrustError):
    """A well-formed tables export whose CRC or digest does not match its content: it was edited
    or damaged after export (the CLI exits 1, like any input that is not the verified one)."""


class SchedulerError(ServotuneError, ConnectionError):
    """A Dask scheduler does not answer (refused, unreachable, timed out), or the executor was
    asked for something it cannot be (:func:`servotune.executor.open_executor`). The CLI exits
    3, naming the address."""


class CounterFaultWarning(UserWarning):
    """A counter read violated the high-byte rule (a jump the unwrap cannot explain)."""
