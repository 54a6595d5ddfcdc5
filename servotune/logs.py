"""Log files (docs/formats.md#log-file): what ``servotune simulate`` writes and ``servotune fit``
reads.

A log is CSV: optional ``# key: value`` metadata lines, one header row, then one row per tick.
Time is ``time_s`` and/or ``tick``; per axis, columns prefixed ``<axis>.`` (a single-axis log may
leave the prefix out): the command (``dac_code`` or ``cmd_v``), the position (``counter`` raw
register or ``pos_counts`` unwrapped) and optionally ``ref_counts``, ``exc_code`` and ``mode``
(``lock`` / ``task`` / ``open``). Sampling is uniform. Writes are atomic (temp file, then rename).

``exc_code`` is the excitation the law adds to its output [D/A codes, signed, relative to the
zero code] (docs/decisions.md#5-excitation-is-logged): ``servotune simulate`` writes it,
``servotune fit`` builds its instruments from it (:mod:`servotune.identify.iv`); a log without
it still reads and fits. Log files carry no format version (they come from other tools too): the
column is an optional addition, so every older log reads as before, and a servotune that predates
it refuses a log that has it with one line naming the unknown column (exit 3) — never a silent
misread (docs/decisions.md#17-file-versions).

:func:`read_log` validates everything and names the first problem in one line, with its row
(the 1-based line number in the file) and column. The data rows are parsed in bulk: rows in
the plain form servotune writes straight from the bytes by one compiled pass, any others with
``numpy.loadtxt`` (one typed field per column, about 0.7 s per million rows); only when that
fails are the rows scanned one by one to find the first bad one. The format's parsing
lives in :mod:`servotune.io.log_header` (text, metadata, header) and
:mod:`servotune.io.log_rows` (data rows, time base); this module builds the :class:`Log`.
"""

from __future__ import annotations

import difflib
import io
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from servotune.budget import check_memory
from servotune.errors import LogFormatError
from servotune.hw import counter as hw_counter
from servotune.hw import dac as hw_dac
from servotune.io.files import atomic_write_text
from servotune.io.log_header import (
    COLUMNS_HELP,
    MAX_METADATA_CHARS,
    MAX_NAME_CHARS,
    PERIOD_RANGE_S,
    classify_columns,
    decode_text,
    meta_pair,
    meta_setting,
    naming,
    option_value,
    parse_compute,
    parse_counter_bits,
    parse_dac_bits,
    parse_header,
    parse_period,
    parse_range,
    read_bytes,
    read_errors,
    split_ascii_head,
    split_text,
)
from servotune.io.log_rows import (
    KIND,
    RowLines,
    base_name,
    check_range,
    column_kinds,
    data_rows,
    fast_columns,
    mode_codes,
    timebase,
    whole_counts,
)
from servotune.laws.axis import MODE_NAMES

__all__ = [
    "MAX_METADATA_CHARS",
    "MAX_NAME_CHARS",
    "METADATA_KEYS",
    "MIN_ROWS",
    "PERIOD_RANGE_S",
    "AxisLog",
    "Log",
    "LogMetadataWarning",
    "Table",
    "format_log",
    "read_log",
    "read_metadata",
    "read_table",
    "write_log",
]


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


# --- reading -------------------------------------------------------------------------------

MIN_ROWS = 3
"""Fewest data rows :func:`read_log` accepts (the identifier asks for more itself)."""

_DEFAULT_COUNTER_BITS = 24
_DEFAULT_DAC_BITS = 12
_DEFAULT_DAC_RANGE_V = (-10.0, 10.0)

METADATA_KEYS = frozenset(
    {
        # read (settings)
        "counter_bits", "dac_bits", "dac_range_v", "period_s", "compute_s",
        # written by servotune (simulate, excite) and declared provenance
        "rig", "scenario", "axis", "closed_loop", "seed", "servotune_version", "kind",
        "amplitude_codes", "limited_by", "predicted_max_speed_rpm", "predicted_travel_counts",
        "machine_id", "date", "description", "operator", "units",
    }
)  # fmt: skip
"""Metadata keys a log may declare; others draw a :class:`LogMetadataWarning` (not an error)."""


class LogMetadataWarning(UserWarning):
    """A log declares a metadata key servotune does not know (a typo, or someone's note)."""


def read_log(
    path: str | Path,
    *,
    counter_bits: int | None = None,
    dac_bits: int | None = None,
    dac_range_v: tuple[float, float] | None = None,
    period_s: float | None = None,
    compute_s: float | None = None,
    strict: bool = False,
) -> Log:
    """Read and validate a log file (docs/formats.md#log-file).

    Each setting comes from the keyword option if given (the command line, or the rig when one
    is known), else from the log's metadata (``# counter_bits: 24``, ``# dac_bits: 12``,
    ``# dac_range_v: -10,10``, ``# period_s: 0.004``), else from the defaults (24-bit counter,
    12-bit ±10 V D/A; the period from the ``time_s`` column). Malformed metadata is an error
    even when an option overrides it. An unknown metadata key (a typo such as
    ``# counter_bitz: 24``) is a :class:`LogMetadataWarning` naming the closest known key, or
    with ``strict`` an error.

    ``dac_code`` is converted to volts through the D/A model, ``counter`` is unwrapped with the
    runtime's high-byte rule relative to the first row; ``cmd_v`` and ``pos_counts`` are taken
    as they are. ``pos_counts`` and ``ref_counts`` may be written as numbers (``0.0``, as a
    logger that writes every column as a float does) when every value is within 1e-9 of an
    integer: they are read as those integers (:data:`servotune.io.log_rows.WHOLE_TOL`).

    Parameters
    ----------
    path : str or Path
        The CSV log.
    counter_bits : int, optional
        Counter register width (16, 24 or 32) to unwrap ``counter`` columns.
    dac_bits : int, optional
        D/A resolution to convert ``dac_code`` columns.
    dac_range_v : (float, float), optional
        D/A output range [V]: the low and high end of the span.
    period_s : float, optional
        Sample period [s]. Needed when the log has neither a ``time_s`` column nor ``period_s``
        metadata; when the log has ``time_s`` it must agree with its intervals within 0.1 %.
        Periods must lie in :data:`PERIOD_RANGE_S` (1 µs … 60 s), whatever their source.
    compute_s : float, optional
        Compute time [s] (tick start → D/A write), overriding metadata ``compute_s``; a finite
        number >= 0 and shorter than the period.

    Returns
    -------
    Log

    Raises
    ------
    LogFormatError
        One line naming the first problem and, for a data row, the row (its 1-based line
        number in the file) and the column: missing or unreadable file, not UTF-8 text, empty
        file, no header, header only, unknown (with the closest valid name), duplicate or
        missing columns, wrong number of fields, text in a number, NaN or inf, a non-integer or
        out-of-range ``dac_code`` or ``counter``, a ``pos_counts`` or ``ref_counts`` value that
        is not whole (the first one named, with its row), an unknown ``mode``, time not increasing,
        irregular sampling, ``tick`` and ``time_s`` disagreeing, malformed metadata, fewer than
        :data:`MIN_ROWS` rows; also invalid options. Bounds: a field of more than
        :data:`MAX_NUMBER_CHARS` characters, a metadata value of more than
        :data:`MAX_METADATA_CHARS`, a key or column name of more than :data:`MAX_NAME_CHARS`,
        a period outside :data:`PERIOD_RANGE_S`, a file whose reading would exceed the memory
        budget (:mod:`servotune.budget`).

    Warns
    -----
    LogMetadataWarning
        For metadata keys not in :data:`METADATA_KEYS` (they are kept in ``Log.metadata``).

    Examples
    --------
    >>> import os, tempfile
    >>> lines = ["# period_s: 0.001", "tick,dac_code,counter", "0,2048,16777215", "1,2458,0"]
    >>> lines.append("2,2458,3")
    >>> text = "\\n".join(lines) + "\\n"
    >>> with tempfile.TemporaryDirectory() as d:
    ...     f = os.path.join(d, "log.csv")
    ...     with open(f, "w") as fh:
    ...         _ = fh.write(text)
    ...     log = read_log(f)
    >>> log.period_s, log.axis().pos_counts.tolist(), log.axis().cmd_v.round(4).tolist()
    (0.001, [0, 1, 4], [0.0, 2.002, 2.002])
    """
    src = str(path)
    with naming(src):
        return _read_log(
            path,
            src,
            counter_bits,
            dac_bits,
            dac_range_v,
            period_s=period_s,
            compute_s=compute_s,
            strict=strict,
        )


def _read_log(
    path: str | Path,
    src: str,
    counter_bits: int | None,
    dac_bits: int | None,
    dac_range_v: tuple[float, float] | None,
    *,
    period_s: float | None,
    compute_s: float | None,
    strict: bool = False,
) -> Log:
    settings: dict[str, Any] = {}

    def prepare(
        meta: dict[str, str], meta_line: dict[str, int], header: list[str], header_line: int
    ) -> None:
        settings["axes"] = classify_columns(header, header_line)

        def setting(key: str, option: Any, parse: Callable[[str], Any], default: Any) -> Any:
            meta_value = meta_setting(key, meta, meta_line, parse)  # checked even if overridden
            if option is not None:
                return option_value(key, option, parse)
            return default if meta_value is None else meta_value

        settings["bits"] = setting(
            "counter_bits", counter_bits, parse_counter_bits, _DEFAULT_COUNTER_BITS
        )
        settings["d_bits"] = setting("dac_bits", dac_bits, parse_dac_bits, _DEFAULT_DAC_BITS)
        settings["d_range"] = setting("dac_range_v", dac_range_v, parse_range, _DEFAULT_DAC_RANGE_V)
        settings["period"] = meta_setting("period_s", meta, meta_line, parse_period)
        settings["compute"] = meta_setting("compute_s", meta, meta_line, parse_compute)
        if period_s is not None:
            settings["opt_period"] = option_value("period_s", period_s, parse_period)
        if compute_s is not None:
            settings["opt_compute"] = option_value("compute_s", compute_s, parse_compute)
        warn_unknown_metadata(meta, meta_line, src, strict)

    read = _read_columns(
        path,
        src,
        "log",
        prepare,
        lambda line: f"log {src!r} has a header (line {line}) but no data rows",
    )
    meta, meta_line, col, rows, n = (
        read.metadata,
        read.metadata_lines,
        read.columns,
        read.rows,
        read.n_rows,
    )
    axes_cols, bits, d_bits, d_range = (settings[k] for k in ("axes", "bits", "d_bits", "d_range"))
    meta_period, meta_compute = settings["period"], settings["compute"]
    period_s = settings.get("opt_period")
    compute_s = settings.get("opt_compute", meta_compute)
    if n < MIN_ROWS:
        raise LogFormatError(
            f"log {src!r} has {n} data row{'' if n == 1 else 's'}; at least {MIN_ROWS} are needed"
        )
    period = timebase(
        col.get("tick"),
        col.get("time_s"),
        rows,
        meta_period=meta_period,
        meta_source=f"metadata 'period_s' (line {meta_line.get('period_s')})",
        opt_period=period_s,
    )
    lo_p, hi_p = PERIOD_RANGE_S
    if not lo_p <= period <= hi_p:
        raise LogFormatError(
            f"log {src!r}: the sample period from the time_s column, {period:.6g} s, is outside "
            f"{lo_p:g} … {hi_p:g} s"
        )
    if compute_s is not None and compute_s >= period:
        where = (
            "option compute_s"
            if meta_compute is None or compute_s != meta_compute
            else (f"metadata 'compute_s' (line {meta_line['compute_s']})")
        )
        raise LogFormatError(
            f"{where} must be shorter than the sample period {period:.6g} s [s], got {compute_s!r}"
        )
    axes = {
        ax: _axis_log(ax, names, col, rows, counter_bits=bits, dac_bits=d_bits, dac_range_v=d_range)
        for ax, names in axes_cols.items()
    }
    return Log(
        period_s=period,
        axes=axes,
        metadata=meta,
        counter_bits=bits,
        dac_bits=d_bits,
        dac_range_v=d_range,
        compute_s=compute_s,
        path=src,
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class Table:
    """A log-format CSV file (docs/formats.md#log-file) parsed without the log's column-set rules.

    What :func:`read_table` returns, for files that share the log format but not its columns
    (the excitation files of :mod:`servotune.excite`).

    Attributes
    ----------
    path : str
    metadata : dict of str to str
        The ``# key: value`` lines.
    metadata_lines : dict of str to int
        The 1-based line of each metadata key.
    header : list of str
        Column names.
    header_line : int
        1-based line of the header.
    columns : dict of str to ndarray
        Per column: int64 (tick, dac_code, counter, pos_counts, ref_counts, exc_code), float64
        (time_s, cmd_v) or text (mode); as ``kinds`` says when it is given (its ``"skip"``
        columns left out).
    row_lines : ndarray of int64
        The 1-based file line of each data row.
    """

    path: str
    metadata: dict[str, str]
    metadata_lines: dict[str, int]
    header: list[str]
    header_line: int
    columns: dict[str, np.ndarray]
    row_lines: np.ndarray

    @property
    def n_rows(self) -> int:
        """Number of data rows."""
        return int(self.row_lines.shape[0])


def read_table(
    path: str | Path,
    *,
    what: str = "log",
    check_header: Callable[[list[str], int], None] | None = None,
    kinds: Callable[[list[str], int], Sequence[str]] | None = None,
) -> Table:
    """Read a log-format CSV file: metadata, header and typed columns, with the log's checks.

    The file checks of :func:`read_log` apply (readable UTF-8 text, no NUL, a byte-order mark
    ignored, the memory budget, metadata and field lengths), and every data row is parsed as
    :func:`read_log` parses it (integers in integer columns, finite numbers, the right number
    of fields); the first bad row is named with its line and column. Which columns a file may
    have is left to ``check_header``.

    Parameters
    ----------
    path : str or Path
    what : str
        What the file is, for the messages (``"excitation file"``).
    check_header : callable, optional
        Called with the header and its line before the rows are parsed; raises to refuse it.
        Columns must be log columns (``tick``, ``time_s``, ``[axis.]dac_code``, ...) in any
        case, unless ``kinds`` is given.
    kinds : callable, optional
        Called with the header and its line (after ``check_header``); returns each column's
        kind: ``"int"``, ``"counts"``, ``"float"``, ``"text"`` or ``"skip"`` (read as text
        and not kept: a column the caller does not use). Then any column names are accepted,
        and the caller's mapping (:func:`servotune.io.hal.read_mapped_csv`) gives them their
        meaning. Default: the log columns' kinds, by name.

    Returns
    -------
    Table

    Raises
    ------
    LogFormatError
        One line naming the file and the first problem.
    """
    src = str(path)
    kinds_used: list[str] = []
    try:

        def prepare(
            meta: dict[str, str], meta_line: dict[str, int], header: list[str], header_line: int
        ) -> list[str]:
            if kinds is None:
                for h in header:
                    if base_name(h) not in KIND:
                        raise LogFormatError(
                            f"line {header_line}: unknown column {h!r}; {COLUMNS_HELP}"
                        )
            if check_header is not None:
                check_header(header, header_line)
            kinds_used[:] = (
                column_kinds(header) if kinds is None else list(kinds(header, header_line))
            )
            return kinds_used

        read = _read_columns(
            path,
            src,
            what,
            prepare,
            lambda line: f"the header (line {line}) is followed by no data rows",
        )
        cols = read.columns
        for h, k in zip(read.header, kinds_used, strict=True):
            if k == "text" and cols[h].dtype.kind == "i":  # the fast pass's codes: their names
                cols[h] = np.asarray(MODE_NAMES)[cols[h]]
    except LogFormatError as exc:
        if src in str(exc):
            raise
        raise LogFormatError(f"{what} {src!r}: {exc}") from None
    return Table(
        path=src,
        metadata=read.metadata,
        metadata_lines=read.metadata_lines,
        header=read.header,
        header_line=read.header_line,
        columns=cols,
        row_lines=read.rows.array(read.n_rows),
    )


@dataclass(frozen=True, slots=True)
class _Columns:
    """What :func:`_read_columns` read: the file's head, its kept columns, where its rows are."""

    metadata: dict[str, str]
    metadata_lines: dict[str, int]
    header_line: int
    header: list[str]
    columns: dict[str, np.ndarray]
    rows: RowLines
    n_rows: int


def _read_columns(
    path: str | Path,
    src: str,
    what: str,
    prepare: Callable[[dict[str, str], dict[str, int], list[str], int], Sequence[str] | None],
    empty: Callable[[int], str],
) -> _Columns:
    """A log-format file's metadata, header line, header, typed columns and row lines.

    ``prepare(metadata, metadata_lines, header, header_line)`` checks the head before any data
    row is parsed and returns each column's kind (None: the log's, by name; ``"skip"`` columns
    are parsed and left out). A plain ASCII file's rows are parsed from its bytes by one
    compiled pass (:func:`~servotune.io.log_rows.fast_columns`), without decoding or copying
    the body; anything else by :func:`~servotune.io.log_rows.data_rows`, which names the first
    bad row. Numbers must be finite and counts whole, the first offender named.
    ``empty(header_line)``: the message for a header without rows.
    """
    data = read_bytes(Path(path), src, what)
    head = split_ascii_head(data, src, what)
    if head is None:
        text = decode_text(data, src, what)
        del data
        meta, meta_line, header_line, header_text, body = split_text(text, src, what)
        del text
    else:  # plain ASCII: the body stays bytes (data[body_start:]) unless the slow path needs it
        meta, meta_line, header_line, header_text, body_start = head
    header = parse_header(header_text, header_line)
    given = prepare(meta, meta_line, header, header_line)
    kind = column_kinds(header) if given is None else list(given)
    col = None
    if head is not None and any(k != "skip" for k in kind):
        col = fast_columns(data, body_start, header, kind)
        if col is None:
            body = data[body_start:].decode("ascii")
        del data
    if col is not None:
        rows = RowLines(None, header_line + 1)  # plain rows: one per line, no blank lines
        n = len(next(iter(col.values())))
    else:
        table, rows = data_rows(body, header_line, header, empty(header_line), kind)
        del body
        n = len(table)
        col = {
            h: np.ascontiguousarray(table[f"c{j}"])
            for j, (h, k) in enumerate(zip(header, kind, strict=True))
            if k != "skip"
        }
        del table
    for h, a in col.items():
        if a.dtype.kind == "f":
            bad = ~np.isfinite(a)
            if bad.any():
                k = int(np.argmax(bad))
                raise LogFormatError(f"row {rows(k)}, column {h!r}: {a[k]} is not finite")
    kept = [(h, k) for h, k in zip(header, kind, strict=True) if k != "skip"]
    whole_counts(col, [h for h, _ in kept], [k for _, k in kept], rows)  # counts written as 12.0
    return _Columns(meta, meta_line, header_line, header, col, rows, n)


# --- file, metadata and header ---------------------------------------------------------------


def read_metadata(path: str | Path) -> dict[str, str]:
    """The ``# key: value`` lines at the head of a log, without reading the rest.

    Reading stops at the header row, or at a line too long to be metadata (:func:`read_log`
    refuses such a file with the line named).

    Raises
    ------
    LogFormatError
        If the file cannot be read as text.
    """
    src = str(path)
    meta: dict[str, str] = {}
    with read_errors(src):
        try:
            with open(path, encoding="utf-8-sig", newline=None) as fh:
                limit = MAX_METADATA_CHARS + MAX_NAME_CHARS + 16
                while raw := fh.readline(limit):
                    if len(raw) >= limit and not raw.endswith("\n"):
                        break  # an overlong line: read_log names it
                    line = raw.strip()
                    if line and not line.startswith("#"):
                        break
                    kv = meta_pair(line)
                    if kv is not None:
                        meta.setdefault(*kv)
        except UnicodeDecodeError:
            raise LogFormatError(f"log {src!r} is not UTF-8 text") from None
    return meta


def warn_unknown_metadata(
    meta: Mapping[str, str], meta_line: Mapping[str, int], src: str, strict: bool = False
) -> None:
    """Warn (``strict``: refuse, :class:`LogFormatError`) naming each unknown metadata key
    with its line and the closest known key."""
    unknown = [k for k in meta if k not in METADATA_KEYS]
    if unknown:

        def near(k: str) -> str:
            close = difflib.get_close_matches(k, sorted(METADATA_KEYS), n=1)
            return f", did you mean {close[0]!r}?" if close else ""

        listed = ", ".join(f"{k!r} (line {meta_line[k]}{near(k)})" for k in unknown[:5])
        more = f" and {len(unknown) - 5} more" if len(unknown) > 5 else ""
        if strict:
            raise LogFormatError(f"log {src!r}: unknown metadata {listed}{more} (--strict)")
        warnings.warn(
            f"log {src!r}: unknown metadata {listed}{more}, kept but not used (a typo? see "
            f"servotune.logs.METADATA_KEYS)",
            LogMetadataWarning,
            stacklevel=3,
        )


def _axis_log(
    ax: str,
    names: Mapping[str, str],
    col: Mapping[str, np.ndarray],
    rows: RowLines,
    *,
    counter_bits: int,
    dac_bits: int,
    dac_range_v: tuple[float, float],
) -> AxisLog:
    dac_code = counter = ref = exc = mode = None
    faults = np.zeros(0, dtype=np.int64)
    if "dac_code" in names:
        name = names["dac_code"]
        dac_code = col[name]
        check_range(
            dac_code, dac_bits, rows, name, "code {v} is outside the {bits}-bit D/A range 0..{top}"
        )
        cmd_v = hw_dac.volts_from_code(dac_code, dac_bits, dac_range_v)
    else:
        cmd_v = col[names["cmd_v"]]
    if "counter" in names:
        name = names["counter"]
        counter = col[name]
        check_range(
            counter,
            counter_bits,
            rows,
            name,
            "{v} is outside the {bits}-bit counter "
            "register 0..{top} (set counter_bits if the register is wider)",
        )
        pos, fault = hw_counter.unwrap(counter, counter_bits)
        pos = pos - pos[0]
        faults = np.flatnonzero(fault).astype(np.int64)
    else:
        pos = col[names["pos_counts"]]
    if "ref_counts" in names:
        ref = col[names["ref_counts"]]
    if "exc_code" in names:
        name = names["exc_code"]
        exc = col[name]
        top = (1 << dac_bits) - 1
        bad = np.abs(exc) > top
        if bad.any():
            k = int(np.argmax(bad))
            raise LogFormatError(
                f"row {rows(k)}, column {name!r}: excitation {exc[k]} codes is beyond the "
                f"{dac_bits}-bit D/A span (at most ±{top})"
            )
    if "mode" in names:
        mode = mode_codes(col[names["mode"]], names["mode"], rows)
    return AxisLog(
        cmd_v=cmd_v,
        pos_counts=pos,
        dac_code=dac_code,
        counter=counter,
        ref_counts=ref,
        exc_code=exc,
        mode=mode,
        counter_faults=faults,
        name=ax,
    )
