"""LinuxCNC HAL captures (``halsampler`` output, halscope's saved data) and CSV logs with
their own column names, read into a log through a mapping.

LinuxCNC users log a servo loop in one of two ways, and servotune reads both (one reader per
format, :func:`read_halsampler` and :func:`read_halscope`, each into a :class:`HalCapture`):

``halsampler`` (the realtime ``sampler`` component and the ``halsampler`` user program)
    One line per sample, the values separated by single spaces, a trailing space, no header.
    Float pins print with ``%f`` (6 decimals), s32/u32 pins as integers, bits as 0/1. With
    ``halsampler -t`` the first field is the sample number (0, 1, 2, …). The columns are the
    sampler's ``cfg`` order (``sampler.0.pin.0``, ``.pin.1``, …): the file does not name them,
    nor does it carry the sample period.
halscope "save data" (``write_log_file`` in LinuxCNC's ``scope_files.c``)
    Line 1 ``# Sampling period is <ns> ns``; line 2 the channels' names (pins, signals or
    parameters) separated by ``;``; then the comment lines ``# Position: …`` and
    ``# Scale: …`` (the display settings); then one line per sample, the values printed with
    ``%.14f`` (bits and integers too) and separated by ``;``.

Lost samples
------------
A sample lost between the realtime ``sampler`` and ``halsampler`` (the FIFO full) would be a
silent jump in time, so every witness of one is refused, naming the first: a gap in the ``-t``
sample numbers, the line ``overrun`` that ``halsampler`` prints at a gap, and a change in the
sampler's own ``sampler.N.overruns`` pin recorded as a column (mapping key ``overruns``). On
LinuxCNC 2.9 only the last one sees a loss: its sampler drops the record of a full FIFO
without advancing the stream's sample number, so the ``-t`` numbers stay consecutive and no
``overrun`` line is printed (checked with halsampler 2.9 and a FIFO left to fill:
``tests/io/test_hal_logs.py``). Record ``sampler.0.overruns`` (an ``s`` pin in ``cfg``) to
be sure.

A :class:`HalSettings` (:mod:`servotune.io.hal_map`, re-exported here) says which column is
what (the mapping: servotune's ``cmd`` or ``code``, ``pos`` or ``counts``, optionally ``ref``,
``exc`` and ``overruns``, each a pin name or a 0-based column number) and gives LinuxCNC's
scales; :meth:`HalCapture.to_log` converts the mapped columns to servotune's units and builds
the :class:`servotune.logs.Log` that :func:`servotune.fit` takes, as
:meth:`servotune.identify.emps.EmpsLog.to_log` does for the EMPS files. :func:`read_hal_log` does
both steps; :func:`hal_settings` (also :mod:`servotune.io.hal_map`'s) builds the settings from
``servotune fit``'s options.


The conversion, mapping key by mapping key (LinuxCNC's terms and units → servotune's), is
tabled in :mod:`servotune.io.hal_capture`, where :class:`HalCapture` and its
:meth:`~HalCapture.to_log` live.

CSV logs with their own column names
------------------------------------
A machine's own logger writes CSV with its own column names (``t,drive_volts,encoder,…``).
The same mapping reads it (:func:`read_mapped_csv`): each key names a column of the header
(or its 0-based number), the keys and their units are those of that table, with two
differences and two additions. Without ``position_scale``, ``pos`` and ``ref`` are in counts
(with it, in machine units as there); counts (``pos``, ``counts``, ``ref``, and ``code``,
``overruns``) may be written as numbers (``0.0``) but must be whole within 1e-9, as the log
reader's ``pos_counts`` and ``ref_counts``. A position in counts is taken as it is: unwrapped (a raw
counter register that wraps is a log's ``counter`` column, read without ``--map``). ``time``
maps the time column [s] and ``tick`` the sample number; columns named ``time_s`` or ``tick``
are the time base without being mapped; the other columns the mapping does not name are
ignored. The rest is the log format's: ``# key: value`` metadata (``period_s``, ``dac_bits``,
``dac_range_v``, ``compute_s``, kept as the log's metadata), the period from the option, else
``# period_s:``, else the time column, all checked as a log's.

Which reader a file needs is read from its content (:func:`capture_format`): halscope's
first line, halsampler's rows of numbers, or a CSV's header naming its columns.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypedDict, Unpack

import numpy as np

from servotune.errors import LogFormatError
from servotune.io.capture_rows import NUMBER_RE, check_rows, stream_rows
from servotune.io.hal_capture import (
    CMD_LOG_DAC_BITS,
    CMD_LOG_DAC_RANGE_V,
    MORE_DEPTH,
    SHOW_NAMES,
    HalCapture,
    HalPrecisionWarning,
    find_column,
)
from servotune.io.hal_map import (
    HAL_FORMATS,
    MAP_KEYS,
    HalSettings,
    hal_settings,
    parse_hal_map,
    read_hal_map,
)
from servotune.io.log import Log
from servotune.io.log_header import (
    PERIOD_RANGE_S,
    meta_setting,
    naming,
    option_value,
    parse_compute,
    parse_counter_bits,
    parse_dac_bits,
    parse_period,
    parse_range,
    warn_unknown_metadata,
)
from servotune.io.log_rows import RowLines, timebase
from servotune.io.log_table import MIN_ROWS, read_table
from servotune.validate import show_value

__all__ = [
    "CMD_LOG_DAC_BITS",
    "CMD_LOG_DAC_RANGE_V",
    "HAL_FORMATS",
    "MAP_KEYS",
    "HalCapture",
    "HalLogOptions",
    "HalPrecisionWarning",
    "HalSettings",
    "capture_format",
    "hal_settings",
    "parse_hal_map",
    "read_hal_capture",
    "read_hal_log",
    "read_hal_map",
    "read_halsampler",
    "read_halscope",
    "read_mapped_csv",
]

HALSCOPE_PERIOD_LINE = "# Sampling period is"
"""How halscope's saved data begin (what the format detection looks for)."""

_HALSCOPE_PERIOD_RE = re.compile(r"# Sampling period is (-?\d+) ns\s*")
_DETECT_BYTES = 1 << 16  # how much of a file capture_format looks at


# --- reading the files -----------------------------------------------------------------------


def read_halsampler(
    path: str | Path,
    *,
    columns: Sequence[str] | None = None,
    sample_number: bool = False,
    progress: Callable[[str], None] | None = None,
) -> HalCapture:
    """Read ``halsampler`` output (module docstring), a chunk of lines at a time: memory is
    the capture's array and a chunk, not the text (the estimate is checked against the memory
    budget before reading: :func:`~servotune.io.capture_rows.check_capture_memory`).

    Parameters
    ----------
    path : str or Path
        The file (halsampler's stdout, redirected).
    columns : sequence of str, optional
        The sampler's pin names in its ``cfg`` order; the rows must have that many values.
    sample_number : bool
        The file was written with ``halsampler -t``: the first field is the sample number
        (not a column); the numbers must run on by one.
    progress : callable, optional
        Gets a line at each tenth of a large file read.

    Returns
    -------
    HalCapture
        ``period_s`` None (halsampler does not record it).

    Raises
    ------
    LogFormatError
        One line naming the file and the line: unreadable, not text, empty, a row with another
        number of fields than the first (or than ``columns`` names), a field that is not a
        number, a value that is not finite, a sample number that is not a whole number, a gap
        in the sample numbers or halsampler's ``overrun`` line (lost samples: the first one
        named), fewer than :data:`~servotune.logs.MIN_ROWS` samples.
    BudgetError
        The capture's arrays would not fit in the memory budget (nothing read).
    """
    src = str(path)
    with naming(src, "HAL capture"):
        names = None if columns is None else tuple(columns)
        lead = 1 if sample_number else 0

        def label(j: int) -> str:
            if j < lead:
                return "field 1 (the sample number)"
            c = j - lead
            known = names is not None and c < len(names)
            return f"column {c} ({names[c]})" if known else f"column {c}"  # type: ignore[index]

        def each(line0: int, lines: list[str]) -> int:
            if line0 == 0:
                _no_comment(lines, line0)
            if any(ln.strip() == "overrun" for ln in lines):  # halsampler's mark of a gap
                k = next(i for i, ln in enumerate(lines) if ln.strip() == "overrun")
                raise LogFormatError(
                    f"lost samples: line {line0 + k + 1} is halsampler's 'overrun' mark (the "
                    f"sampler's FIFO was full; {MORE_DEPTH})"
                )
            return 0

        values, rows = stream_rows(Path(path), src, None, "halsampler", label, each, progress)
        if values.shape[0] < MIN_ROWS:
            n = values.shape[0]
            raise LogFormatError(
                f"{n} sample{'s' if n != 1 else ''}; at least {MIN_ROWS} are needed"
            )
        width = values.shape[1]
        expect = None if names is None else len(names) + lead
        if expect is not None and width != expect:
            hint = ""
            if not sample_number and width == len(names) + 1:  # type: ignore[arg-type]
                hint = " (written with halsampler -t? give --sample-number)"
            elif sample_number and width == len(names):  # type: ignore[arg-type]
                hint = " (not written with -t? drop --sample-number)"
            raise LogFormatError(
                f"line {rows[0]} has {width} fields; the {len(names)} columns named "  # type: ignore[arg-type]
                f"({', '.join(names[:SHOW_NAMES])}){' and the sample number' if lead else ''} "  # type: ignore[index]
                f"need {expect}{hint}"
            )
        if width <= lead:
            raise LogFormatError(f"line {rows[0]} has only the sample number: no pin values")
        numbers = None
        if sample_number:
            numbers = _sample_numbers(values[:, 0], rows)
            values = values[:, 1:]
        check_rows(values, rows, names)
        return HalCapture(
            format="halsampler",
            values=np.ascontiguousarray(values),
            names=names,
            lines=rows,
            sample_numbers=numbers,
            path=src,
        )


def _halscope_head(lines: list[str]) -> tuple[float, tuple[str, ...], int]:
    """The sampling period [s], the channels' names and the index of the first data line, from
    the first lines of a halscope file."""
    if not any(ln.strip() for ln in lines):
        raise LogFormatError("the file is empty (no samples)")
    head = _HALSCOPE_PERIOD_RE.fullmatch(lines[0])
    if head is None:
        raise LogFormatError(
            f"line 1 is {show_value(lines[0])}, not halscope's '{HALSCOPE_PERIOD_LINE} N ns'"
        )
    ns = int(head.group(1))
    period_s = ns / 1e9
    lo, hi = PERIOD_RANGE_S
    if not lo <= period_s <= hi:
        raise LogFormatError(f"line 1: the sampling period {ns} ns is outside {lo:g} … {hi:g} s")
    if len(lines) < 2 or not lines[1].strip():
        raise LogFormatError("line 2 should name the channels (pins separated by ';')")
    if lines[1].lstrip().startswith("#"):
        raise LogFormatError(
            f"line 2 is a comment, not the channels' names: {show_value(lines[1])}"
        )
    names = tuple(n.strip() for n in lines[1].split(";"))
    if any(not n or len(n.split()) != 1 for n in names):
        raise LogFormatError(
            f"line 2: channel names separated by ';' must be non-empty pin names, got "
            f"{show_value(lines[1], 80)}"
        )
    start = 2
    while start < len(lines) and lines[start].lstrip().startswith("#"):
        start += 1  # '# Position: …', '# Scale: …' (display settings)
    return period_s, names, start


def _no_comment(lines: list[str], line0: int) -> None:
    """halsampler writes only numbers: a first non-blank line that is a comment is refused
    (halscope's saved data, which starts with one, named as such)."""
    first = next((i for i, ln in enumerate(lines) if ln.strip()), None)
    if first is not None and lines[first].lstrip().startswith("#"):
        hint = (
            " (halscope's saved data: --hal-format halscope)"
            if lines[first].startswith(HALSCOPE_PERIOD_LINE)
            else ""
        )
        raise LogFormatError(
            f"line {line0 + first + 1} is a comment; halsampler writes only numbers{hint}"
        )


def read_halscope(path: str | Path, *, progress: Callable[[str], None] | None = None) -> HalCapture:
    """Read halscope's saved data (module docstring; LinuxCNC ``scope_files.c``), a chunk of
    lines at a time as :func:`read_halsampler` reads (``progress`` likewise).

    Returns
    -------
    HalCapture
        ``names`` from line 2, ``period_s`` from line 1.

    Raises
    ------
    LogFormatError
        One line naming the file and the line: unreadable, not text, empty, line 1 not
        ``# Sampling period is N ns`` with N > 0, no channel names (or an empty one), a row
        with another number of fields than there are channels, a field that is not a number,
        a value that is not finite, fewer than :data:`~servotune.logs.MIN_ROWS` samples.
    """
    src = str(path)
    with naming(src, "HAL capture"):
        head: dict[str, Any] = {}

        def each(line0: int, lines: list[str]) -> int:
            if line0 == 0:
                head["period_s"], head["names"], start = _halscope_head(lines)
                return start
            return 0

        def label(j: int) -> str:
            names = head["names"]
            return f"column {j} ({names[j]})" if j < len(names) else f"field {j + 1}"

        values, rows = stream_rows(
            Path(path), src, ";", "halscope", label, each, progress, empty="the file is empty"
        )
        names, period_s = head["names"], head["period_s"]
        if values.shape[0] < MIN_ROWS:
            n = values.shape[0]
            raise LogFormatError(
                f"{n} sample{'s' if n != 1 else ''}; at least {MIN_ROWS} are needed"
            )
        if values.shape[1] != len(names):
            raise LogFormatError(
                f"line {rows[0]} has {values.shape[1]} fields; line 2 names {len(names)} "
                f"channels ({', '.join(names[:SHOW_NAMES])})"
            )
        check_rows(values, rows, names)
        return HalCapture(
            format="halscope", values=values, names=names, lines=rows, period_s=period_s, path=src
        )


def read_mapped_csv(
    path: str | Path,
    mapping: Mapping[str, str | int],
    *,
    period_s: float | None = None,
    strict: bool = False,
) -> HalCapture:
    """Read a CSV log whose header names its columns in its own words, for ``mapping``.

    The file is read by the log reader (:func:`servotune.logs.read_table`: metadata lines,
    header, rows, every check and message of a log) with the mapped columns as numbers (a
    mapped ``tick`` as whole numbers) and the others read but not kept: a column the mapping
    does not name may hold anything. The time base is checked as a log's
    (:func:`servotune.io.log_rows.timebase`): the column mapped as ``time`` [s] (else one
    named ``time_s``) and the one mapped as ``tick`` (else one named ``tick``); the period is
    ``period_s`` if given (checked against the time column within 0.1 %), else the
    ``# period_s:`` line, else the time column's. The ``# dac_bits:``, ``# dac_range_v:`` and
    ``# compute_s:`` lines are kept as :attr:`HalCapture.log_settings`, the metadata as
    :attr:`HalCapture.metadata`. :meth:`HalCapture.to_log` then converts the mapped columns
    as a HAL capture's (module docstring), except that without a ``position_scale`` ``pos``
    and ``ref`` are in counts.

    Parameters
    ----------
    path : str or Path
    mapping : mapping of str to str or int
        :data:`MAP_KEYS` → a column name of the header, or a 0-based column number.
    period_s : float, optional
        Sample period [s].
    strict : bool
        An unknown metadata key is an error (else a
        :class:`~servotune.logs.LogMetadataWarning`).

    Returns
    -------
    HalCapture
        ``format`` ``"csv"``, ``names`` the header, ``period_s`` the period.

    Raises
    ------
    LogFormatError
        One line naming the file: anything the log reader refuses, a mapped column that is not
        in the header (the header's columns listed, the closest named), a time column that
        does not increase regularly, no time column and no period, a period outside
        :data:`~servotune.logs.PERIOD_RANGE_S`.
    """
    src = str(path)
    times: dict[str, int] = {}  # "time", "tick" → the column

    def kinds(header: list[str], line: int) -> list[str]:
        names = tuple(header)
        found = {
            key: find_column(names, len(names), target, key, "csv", line)
            for key, target in mapping.items()
        }
        out = ["skip"] * len(header)
        for key, j in found.items():
            out[j] = "counts" if key == "tick" else "float"
        for key, name in (("time", "time_s"), ("tick", "tick")):
            if key in found:
                times[key] = found[key]
            elif name in header and out[header.index(name)] == "skip":
                times[key] = header.index(name)
                out[times[key]] = "counts" if key == "tick" else "float"
        return out

    table = read_table(path, what="log", kinds=kinds)
    with naming(src):
        header, cols = table.header, table.columns
        rows = RowLines(None, table.header_line + 1, table.row_lines)
        meta, meta_line = table.metadata, table.metadata_lines
        if table.n_rows < MIN_ROWS:
            raise LogFormatError(
                f"{table.n_rows} data row{'' if table.n_rows == 1 else 's'}; at least "
                f"{MIN_ROWS} are needed"
            )
        settings: dict[str, Any] = {}
        parsers = {
            "counter_bits": parse_counter_bits,
            "dac_bits": parse_dac_bits,
            "dac_range_v": parse_range,
            "compute_s": parse_compute,
        }
        for key, parse in parsers.items():
            value = meta_setting(key, meta, meta_line, parse)  # checked even if not used
            if value is not None and key != "counter_bits":
                settings[key] = value
        meta_period = meta_setting("period_s", meta, meta_line, parse_period)
        if period_s is not None:
            period_s = option_value("period_s", period_s, parse_period)
        warn_unknown_metadata(meta, meta_line, src, strict)
        tick = cols[header[times["tick"]]] if "tick" in times else None
        time_s = cols[header[times["time"]]] if "time" in times else None
        if tick is None and time_s is None and period_s is None and meta_period is None:
            raise LogFormatError(
                "no time column and no period: map the time column (time=COLUMN, in seconds, "
                "or tick=COLUMN), add a '# period_s: <seconds>' line or give --period-s"
            )
        period = timebase(
            tick,
            time_s,
            rows,
            meta_period=meta_period,
            meta_source=f"metadata 'period_s' (line {meta_line.get('period_s')})",
            opt_period=period_s,
            names=(header[times.get("tick", 0)], header[times.get("time", 0)]),
        )
        lo, hi = PERIOD_RANGE_S
        if not lo <= period <= hi:
            raise LogFormatError(
                f"the sample period from the time column, {period:.6g} s, is outside "
                f"{lo:g} … {hi:g} s (is the time column in seconds?)"
            )
        values = np.full((table.n_rows, len(header)), np.nan)
        for j, h in enumerate(header):
            if h in cols:
                values[:, j] = cols[h]
    return HalCapture(
        format="csv",
        values=values,
        names=tuple(header),
        lines=table.row_lines,
        period_s=float(period),
        path=src,
        metadata=dict(meta),
        log_settings=settings,
    )


def capture_format(path: str | Path) -> str:
    """What a file mapped with ``--map`` is, from its content: ``"halscope"`` (it begins with
    ``# Sampling period is``), ``"csv"`` (its first line that is not blank is a ``#`` line,
    as a CSV log's metadata, or holds a comma, or is not all numbers: a header naming the
    columns) or ``"halsampler"`` (numbers separated by spaces; also an unreadable or empty
    file, whose reader then names the problem)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(_DETECT_BYTES)
    except OSError:
        return "halsampler"
    text = head.decode("utf-8", errors="replace").lstrip("\ufeff")
    if text.startswith(HALSCOPE_PERIOD_LINE):
        return "halscope"
    for line in text.splitlines():
        line = line.strip()
        if not line:
            continue
        if line.startswith("#") or "," in line:
            return "csv"
        if line == "overrun":  # halsampler's mark of lost samples: its reader names it
            return "halsampler"
        numbers = all(
            NUMBER_RE.fullmatch(t) or t.lower().lstrip("+-") in ("nan", "inf") for t in line.split()
        )
        return "halsampler" if numbers else "csv"
    return "halsampler"


def read_hal_capture(
    path: str | Path,
    *,
    format: str | None = None,
    columns: Sequence[str] | None = None,
    sample_number: bool = False,
    mapping: Mapping[str, str | int] | None = None,
    period_s: float | None = None,
    strict: bool = False,
    progress: Callable[[str], None] | None = None,
) -> HalCapture:
    """Read a HAL capture in either format, or a CSV log with its own column names; ``format``
    None detects which from the content (:func:`capture_format`).

    ``mapping``, ``period_s`` and ``strict`` are for a CSV (:func:`read_mapped_csv`): the
    mapping says which columns to read, the period (if given) is checked against its time
    column, ``strict`` refuses unknown metadata keys. ``progress``: lines while a large
    halsampler or halscope capture is read (:func:`read_halsampler`)."""
    if format is None:
        format = capture_format(path)
    if format == "csv":
        if columns is not None or sample_number:
            what = "columns (--hal-columns)" if columns is not None else "--sample-number"
            raise LogFormatError(
                f"log {str(path)!r} is a CSV log whose header names its columns: {what} is for "
                "halsampler captures"
            )
        if mapping is None:
            raise LogFormatError(
                f"log {str(path)!r} is a CSV log: give the mapping of its columns (--map)"
            )
        return read_mapped_csv(path, mapping, period_s=period_s, strict=strict)
    if format == "halscope":
        if columns is not None or sample_number:
            what = "columns (--hal-columns)" if columns is not None else "--sample-number"
            raise LogFormatError(
                f"HAL capture {str(path)!r} is halscope's saved data, which names its channels "
                f"(line 2) and has no sample numbers: {what} is for halsampler captures"
            )
        return read_halscope(path, progress=progress)
    if format != "halsampler":
        raise LogFormatError(f"format must be one of {', '.join(HAL_FORMATS)}, got {format!r}")
    return read_halsampler(path, columns=columns, sample_number=sample_number, progress=progress)


class HalLogOptions(TypedDict, total=False):
    """The keywords of :meth:`HalCapture.to_log`, which :func:`read_hal_log` passes on:
    ``period_s``, ``dac_bits``, ``dac_range_v`` and ``compute_s``."""

    period_s: float | None
    dac_bits: int | None
    dac_range_v: tuple[float, float] | None
    compute_s: float | None


def read_hal_log(
    path: str | Path,
    settings: HalSettings,
    *,
    strict: bool = False,
    progress: Callable[[str], None] | None = None,
    **options: Unpack[HalLogOptions],
) -> Log:
    """Read a HAL capture or a CSV log with its own column names (:func:`read_hal_capture`)
    and convert it (:meth:`HalCapture.to_log`, whose keywords it takes): what
    ``servotune fit FILE --map …`` reads. ``strict``: a CSV's unknown metadata key is an
    error, not a :class:`~servotune.logs.LogMetadataWarning`. ``progress``: lines while a
    large capture is read.

    Examples
    --------
    >>> import os, tempfile
    >>> rows = "".join(f"{k} {0.5 * (k % 2):f} {k * 0.001:f} \\n" for k in range(4))
    >>> with tempfile.TemporaryDirectory() as d:
    ...     f = os.path.join(d, "capture.txt")
    ...     with open(f, "w") as fh:
    ...         _ = fh.write(rows)
    ...     s = HalSettings(mapping={"cmd": "pid.0.output", "pos": "encoder.0.position"},
    ...                     columns=("pid.0.output", "encoder.0.position"), sample_number=True,
    ...                     period_s=0.001, position_scale=2000.0, output_scale=0.5)
    ...     log = read_hal_log(f, s)
    >>> log.axis().cmd_v.tolist(), log.axis().pos_counts.tolist(), log.period_s
    ([0.0, 1.0, 0.0, 1.0], [0, 2, 4, 6], 0.001)
    """
    period = options.get("period_s")
    cap = read_hal_capture(
        path,
        format=settings.format,
        columns=settings.columns,
        sample_number=settings.sample_number,
        mapping=settings.mapping,
        period_s=settings.period_s if period is None else period,
        strict=strict,
        progress=progress,
    )
    return cap.to_log(settings, **options)


# --- parsing helpers -------------------------------------------------------------------------


def _sample_numbers(tags: np.ndarray, rows: np.ndarray) -> np.ndarray:
    bad = ~np.isfinite(tags) | (tags != np.rint(tags)) | (tags < 0)
    if bad.any():
        k = int(np.argmax(bad))
        raise LogFormatError(
            f"line {rows[k]}: the sample number (field 1, halsampler -t) must be a whole "
            f"number >= 0, got {float(tags[k])!r}"
        )
    s = tags.astype(np.int64)
    step = np.diff(s)
    gap = np.flatnonzero(step != 1)
    if gap.size:
        k = int(gap[0])
        if step[k] > 1:
            lost = int(step[k] - 1)
            raise LogFormatError(
                f"lost samples: the sample number jumps from {s[k]} (line {rows[k]}) to "
                f"{s[k + 1]} (line {rows[k + 1]}), {lost} sample{'s' if lost != 1 else ''} "
                f"missing (a sampler FIFO overrun; {MORE_DEPTH})"
            )
        raise LogFormatError(
            f"the sample number goes from {s[k]} (line {rows[k]}) to {s[k + 1]} "
            f"(line {rows[k + 1]}): not one capture in order"
        )
    return s
