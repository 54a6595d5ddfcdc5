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
fails are the rows scanned one by one to find the first bad one.

This module reads a log file into a :class:`Log`, and is where the log's public names are
imported from. The rest lives in :mod:`servotune.io`, below every module that reads a log: the
model (:class:`Log`, :class:`AxisLog`) and its text (:func:`format_log`, :func:`write_log`) in
:mod:`servotune.io.log`; the pass over a log-format file (:func:`read_table`) in
:mod:`servotune.io.log_table`; the text, metadata (:func:`read_metadata`,
:data:`METADATA_KEYS`) and header in :mod:`servotune.io.log_header`; the data rows and the time
base in :mod:`servotune.io.log_rows`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from servotune.errors import LogFormatError
from servotune.hw import counter as hw_counter
from servotune.hw import dac as hw_dac
from servotune.io.log import AxisLog, Log, format_log, write_log
from servotune.io.log_header import (
    MAX_METADATA_CHARS,
    MAX_NAME_CHARS,
    METADATA_KEYS,
    PERIOD_RANGE_S,
    LogMetadataWarning,
    classify_columns,
    meta_setting,
    naming,
    option_value,
    parse_compute,
    parse_counter_bits,
    parse_dac_bits,
    parse_period,
    parse_range,
    read_metadata,
    warn_unknown_metadata,
)
from servotune.io.log_rows import RowLines, check_range, mode_codes, timebase
from servotune.io.log_table import MIN_ROWS, Table, read_columns, read_table

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

_DEFAULT_COUNTER_BITS = 24
_DEFAULT_DAC_BITS = 12
_DEFAULT_DAC_RANGE_V = (-10.0, 10.0)


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

    read = read_columns(
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
