"""Exception and warning classes of servotune.

Every error servotune raises on purpose derives from :class:`ServotuneError` and also from the
built-in exception it resembles, so callers may catch either.
"""

from __future__ import annotations

__all__ = [
    "CounterFaultWarning",
    "ExportError",
    "IdentificationError",
    "LogFormatError",
    "RigError",
    "ServotuneError",
    "SimulationError",
    "SpecError",
    "TuningError",
]


class ServotuneError(Exception):
    """Base class of all servotune errors."""


class RigError(ServotuneError, ValueError):
    """A rig file or rig object is invalid (wrong field, value or unit)."""


class LogFormatError(ServotuneError, ValueError):
    """A log file does not follow the log format (SPEC §5)."""


class IdentificationError(ServotuneError, ValueError):
    """The data do not allow the requested identification."""


class SpecError(ServotuneError, ValueError):
    """A specification or scenario request is invalid or impossible."""


class SimulationError(ServotuneError, ValueError):
    """A simulation request is inconsistent (shapes, timebases, options)."""


class TuningError(ServotuneError, ValueError):
    """A tuning file is malformed or does not belong to the rig it is used with."""


class ExportError(ServotuneError, ValueError):
    """A table or runtime export cannot be produced."""


class ConfigError(ServotuneError, ValueError):
    """An architecture configuration (``servotune sync`` / ``linkage``) is invalid."""


class CounterFaultWarning(UserWarning):
    """A counter read violated the high-byte rule (a jump the unwrap cannot explain)."""
