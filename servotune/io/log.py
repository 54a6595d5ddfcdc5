"""The log model (docs/formats.md#log-file): a :class:`Log` of uniformly sampled axes, each an
:class:`AxisLog` in physical units, and its text (:func:`format_log`, :func:`write_log`).

Every reader of a log builds one: :func:`servotune.logs.read_log` from a log file,
:meth:`servotune.io.hal.HalCapture.to_log` from a LinuxCNC capture or a CSV log with its own
column names, :meth:`servotune.identify.emps.EmpsLog.to_log` from the EMPS benchmark's files.
The names are public as :mod:`servotune.logs`'s.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from servotune.budget import check_memory
from servotune.errors import LogFormatError
from servotune.hw import dac as hw_dac
from servotune.io.files import atomic_write_text
from servotune.io.log_rows import MODE_NAMES

__all__ = ["AxisLog", "Log", "format_log", "write_log"]


@dataclass(frozen=True, slots=True, kw_only=True)
class AxisLog:
    """One axis's columns, converted to physical units.

    Attributes
    ----------
    cmd_v : ndarray of float
        D/A output [V] (from ``dac_code`` through the D/A, or ``cmd_v`` as it is).
    pos_counts : ndarray of int64
        Position [counts]: ``counter`` unwrapped with the runtime's high-byte rule relative to
        the first row (so it starts at 0), or ``pos_counts`` as it is.
    dac_code : ndarray of int64 or None
        Raw D/A codes when the log has them.
    counter : ndarray of int64 or None
        Raw counter register values when the log has them.
    ref_counts : ndarray of int64 or None
        Closed-loop reference [counts] when the log has it.
    exc_code : ndarray of int64 or None
        Excitation the law added to its output [D/A codes, relative to the zero code] when the
        log has it (signal independent of the loop's disturbances: the identifier's
        instruments).
    mode : ndarray of int8 or None
        ``MODE_*`` values (index into ``MODE_NAMES``: lock, task, open) when the log has them.
    counter_faults : ndarray of int64
        Rows (0-based sample indices) where the unwrap flagged a counter fault (empty if none).
    name : str
        Axis name (``""`` for an unprefixed single-axis log).
    """

    cmd_v: np.ndarray
    pos_counts: np.ndarray
    dac_code: np.ndarray | None = None
    counter: np.ndarray | None = None
    ref_counts: np.ndarray | None = None
    exc_code: np.ndarray | None = None
    mode: np.ndarray | None = None
    counter_faults: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    name: str = ""

    def __post_init__(self) -> None:
        n = np.shape(self.cmd_v)
        if len(n) != 1:
            raise LogFormatError(f"AxisLog.cmd_v must be 1-D, got shape {n}")
        for f in ("pos_counts", "dac_code", "counter", "ref_counts", "exc_code", "mode"):
            a = getattr(self, f)
            if a is not None and np.shape(a) != n:
                raise LogFormatError(
                    f"AxisLog.{f} has shape {np.shape(a)}, cmd_v has {n} (one value per row)"
                )

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.cmd_v.shape[0])

    def in_mode(self, mode: str) -> np.ndarray:
        """Boolean mask of the rows logged in ``mode`` (``"lock"``, ``"task"`` or ``"open"``).

        Raises
        ------
        LogFormatError
            If the log has no mode column for this axis, or ``mode`` is not a mode name.
        """
        if mode not in MODE_NAMES:
            raise LogFormatError(f"mode must be one of {', '.join(MODE_NAMES)}, got {mode!r}")
        if self.mode is None:
            who = f"axis {self.name!r}" if self.name else "the axis"
            raise LogFormatError(f"{who} has no mode column in the log")
        return self.mode == MODE_NAMES.index(mode)


@dataclass(frozen=True, slots=True, kw_only=True)
class Log:
    """A parsed log: uniformly sampled axes and the settings used to convert them.

    Attributes
    ----------
    period_s : float
        Sample period [s] (option, else metadata ``period_s``, else the ``time_s`` column).
    axes : dict of str to AxisLog
        Per axis, in header order (``""`` for an unprefixed single-axis log).
    metadata : dict of str to str
        The ``# key: value`` lines, as written.
    counter_bits : int
        Register width used to unwrap ``counter`` columns.
    dac_bits : int
        D/A resolution used to convert ``dac_code`` columns.
    dac_range_v : (float, float)
        D/A range [V] used to convert ``dac_code`` columns.
    compute_s : float or None
        Metadata ``compute_s`` [s] (code written at t_k + compute_s,
        docs/runtime.md#one-tick), if present.
    path : str
        Where the log was read from (``""`` if built in memory).
    """

    period_s: float
    axes: dict[str, AxisLog]
    metadata: dict[str, str]
    counter_bits: int = 24
    dac_bits: int = 12
    dac_range_v: tuple[float, float] = (-10.0, 10.0)
    compute_s: float | None = None
    path: str = ""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.period_s) and self.period_s > 0):
            raise LogFormatError(f"period_s must be > 0, got {self.period_s!r}")
        if not self.axes:
            raise LogFormatError("a log needs at least one axis")
        ns = {name: ax.n for name, ax in self.axes.items()}
        if len(set(ns.values())) != 1:
            raise LogFormatError(f"all axes need the same number of samples, got {ns}")

    @property
    def n_samples(self) -> int:
        """Number of rows."""
        return next(iter(self.axes.values())).n

    @property
    def axis_names(self) -> tuple[str, ...]:
        """Axis names in header order (``("",)`` for an unprefixed single-axis log)."""
        return tuple(self.axes)

    @property
    def time_s(self) -> np.ndarray:
        """Time of each row since the first [s]: the integer sample index times ``period_s``."""
        return np.arange(self.n_samples, dtype=np.int64) * self.period_s

    @property
    def duration_s(self) -> float:
        """Time from the first to the last row [s]."""
        return (self.n_samples - 1) * self.period_s

    @property
    def dac_lsb_v(self) -> float:
        """One D/A step [V] for the log's D/A settings."""
        return hw_dac.lsb_v(self.dac_bits, self.dac_range_v)

    def axis(self, name: str | None = None) -> AxisLog:
        """One axis; ``name`` may be omitted when the log has one axis.

        Raises
        ------
        LogFormatError
            If the axis is not in the log or the choice is ambiguous.
        """
        if name is None:
            if len(self.axes) != 1:
                raise LogFormatError(
                    f"the log has axes {sorted(self.axes)}; choose one (--axis NAME)"
                )
            return next(iter(self.axes.values()))
        if name not in self.axes:
            raise LogFormatError(f"no axis {name!r} in the log; axes: {sorted(self.axes)}")
        return self.axes[name]


_FORMAT_BYTES_PER_VALUE = 80


def format_log(
    *,
    period_s: float,
    columns: Mapping[str, np.ndarray],
    metadata: Mapping[str, str | float | int],
) -> str:
    """Render a log as text (deterministic: fixed float formats, metadata in given order).

    Parameters
    ----------
    period_s : float
        Sample period [s]; the ``tick`` and ``time_s`` columns are written from it.
    columns : mapping of str to ndarray
        Column name → values, in output order. Integer arrays are written as integers; float
        arrays with 9 significant decimals; ``*.mode`` arrays as mode names.
    metadata : mapping
        ``# key: value`` lines.
    """
    n = len(next(iter(columns.values())))
    width = len(columns) + 2
    check_memory(  # every value is a Python string while the text is built
        n * width * _FORMAT_BYTES_PER_VALUE,
        f"formatting a log of {n:,} rows",
        f"{n:,} rows × {width} columns × {_FORMAT_BYTES_PER_VALUE} bytes",
    )
    out = io.StringIO()
    for k, v in metadata.items():
        out.write(f"# {k}: {v}\n")
    names = ["tick", "time_s", *columns]
    out.write(",".join(names) + "\n")
    ticks = np.arange(n, dtype=np.int64)
    cols: list[list[str]] = [[str(t) for t in ticks.tolist()]]
    cols.append([f"{t:.9f}" for t in (ticks * period_s).tolist()])
    for name, arr in columns.items():
        a = np.asarray(arr)
        if name.endswith("mode"):
            cols.append([MODE_NAMES[int(m)] for m in a.tolist()])
        elif np.issubdtype(a.dtype, np.integer):
            cols.append([str(x) for x in a.tolist()])
        else:
            cols.append([f"{x:.9g}" for x in a.tolist()])
    for row in zip(*cols, strict=True):
        out.write(",".join(row) + "\n")
    return out.getvalue()


def write_log(path: str | Path, **kwargs: object) -> None:
    """Format (:func:`format_log`) and write a log atomically."""
    atomic_write_text(path, format_log(**kwargs))  # type: ignore[arg-type]
