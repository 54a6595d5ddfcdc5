"""Data rows of a log-format CSV (docs/formats.md#log-file): parsed in bulk, the first bad one
explained.

A log whose rows are all in the plain form servotune writes (ASCII, no blank lines, no spaces,
integers, decimal numbers, mode names) is parsed straight from the file's bytes by one compiled
pass (:func:`fast_columns`, about 0.05 s per million rows); any other body, and every body
of :func:`servotune.io.log_table.read_table`, is parsed with ``numpy.loadtxt`` (one typed field per
column, about 0.7 s per million rows), and only when that fails are the rows scanned to find the
first bad row, which is then explained field by field with its 1-based file line and column.
Both give the same values (integers exact, numbers correctly rounded). The counts columns
(``pos_counts``, ``ref_counts``) may also be written as numbers (``0.0``) if every value is
whole within :data:`WHOLE_TOL` (:func:`whole_counts`). Also here: the time base (``tick`` and
``time_s`` checked, the period chosen), counter and D/A range checks and the ``mode`` column.
The internals of :func:`servotune.logs.read_log` and :func:`servotune.io.log_table.read_table`;
every error is a one-line :class:`LogFormatError`.
"""

from __future__ import annotations

import functools
import io
import math
import re
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from servotune.errors import LogFormatError
from servotune.io.files import MAX_NUMBER_CHARS

MODE_NAMES = ("lock", "task", "open")
"""The ``mode`` column's values, indexed by the runtime's mode codes (``MODE_LOCK`` 0,
``MODE_TASK`` 1, ``MODE_OPEN`` 2 of :mod:`servotune.laws.axis`)."""

# docs/formats.md#sampling: intervals within 0.1 % of the median; tick·period ≈ time_s
REL_TOL = 1e-3
KIND = {
    "tick": "int",
    "time_s": "float",
    "dac_code": "int",
    "cmd_v": "float",
    "counter": "int",
    "pos_counts": "counts",
    "ref_counts": "counts",
    "exc_code": "int",
    "mode": "text",
}
_MODE_WIDTH = 16  # mode fields are read as U16; a value that fills it may be truncated: invalid
_DTYPES: dict[str, Any] = {
    "int": np.int64,
    "counts": np.int64,  # integers; numbers too when every one is whole (:func:`whole_counts`)
    "float": np.float64,
    "text": f"U{_MODE_WIDTH}",
    "skip": "U1",  # a column read but not used (a mapped CSV's unmapped columns): any text
}
WHOLE_TOL = 1e-9
"""How far from an integer a number in a counts column may be (``12.0000000001`` is 12)."""
MAX_WHOLE = 2.0**53
"""Beyond this a number no longer holds every whole count exactly."""
INT_RE = re.compile(r"[+-]?[0-9]+")
_LONG_FIELD_RE = re.compile(rf"[^,\n]{{{MAX_NUMBER_CHARS + 1}}}")


def to_float(s: str) -> float | None:
    """``float(s)``, or None if ``s`` is not a number (digit separators are not numbers)."""
    if "_" in s or len(s) > MAX_NUMBER_CHARS:
        return None
    try:
        return float(s)
    except ValueError:
        return None


# --- data rows ---------------------------------------------------------------------------------


class RowLines:
    """The 1-based file line of each data row, worked out only when an error names one.

    With neither ``body`` nor ``lines``, the rows are consecutive lines from ``first`` on (a
    body without blank lines).
    """

    __slots__ = ("_body", "_first", "_lines")

    def __init__(self, body: str | None, first: int, lines: np.ndarray | None = None) -> None:
        self._body, self._first, self._lines = body, first, lines

    def __call__(self, i: int) -> int:
        if self._lines is None and self._body is None:
            return self._first + int(i)
        if self._lines is None:
            assert self._body is not None
            lines = self._body.split("\n")
            self._lines = np.asarray([k for k, s in enumerate(lines) if s.strip()]) + self._first
            self._body = None
        return int(self._lines[i])

    def array(self, n: int) -> np.ndarray:
        """The lines of the first ``n`` rows, as int64."""
        if n == 0:
            return np.zeros(0, dtype=np.int64)
        self(0)  # works the line numbers out once
        if self._lines is None:
            return np.arange(self._first, self._first + n, dtype=np.int64)
        return np.asarray(self._lines, dtype=np.int64)[:n]


def _check_field_lengths(body: str, header_line: int, header: list[str]) -> None:
    """Refuse a data field longer than :data:`MAX_NUMBER_CHARS` before parsing.

    One vectorised pass over the bytes: the gaps between consecutive separators (comma or
    newline) are the field lengths; only when one is too long is the row located and named.
    """
    data = np.frombuffer(body.encode("utf-8"), dtype=np.uint8)
    is_sep = (data == 0x2C) | (data == 0x0A)
    # A run of 2b - 1 bytes without a separator holds an aligned block of b such bytes, so if
    # every aligned block of b = (MAX + 2) // 2 bytes has a separator, no field is too long.
    b = (MAX_NUMBER_CHARS + 2) // 2
    pad = np.ones(-data.size % b, dtype=bool)
    if np.concatenate((is_sep, pad)).reshape(-1, b).any(axis=1).all():
        return
    seps = np.flatnonzero(is_sep)
    bounds = np.concatenate(([-1], seps, [data.size]))
    long = np.flatnonzero(np.diff(bounds) - 1 > MAX_NUMBER_CHARS)
    if long.size == 0:
        return
    byte_start = int(bounds[long[0]]) + 1  # the long field's first byte
    # a field of multi-byte characters may be long in bytes only: the first field long in
    # characters is at or after this one
    m = _LONG_FIELD_RE.search(body, len(data[:byte_start].tobytes().decode("utf-8")))
    if m is None:
        return
    start = body.rfind("\n", 0, m.start()) + 1  # the row's first character
    field_start = body.rfind(",", start, m.start()) + 1 or start
    j = body.count(",", start, m.start())
    stop = len(body)
    for sep in (",", "\n"):
        k = body.find(sep, m.end())
        if k >= 0:
            stop = min(stop, k)
    row = header_line + 1 + body.count("\n", 0, start)
    name = f", column {header[j]!r}" if j < len(header) else ""
    raise LogFormatError(
        f"row {row}{name}: a field of {stop - field_start} characters (a field has at most "
        f"{MAX_NUMBER_CHARS})"
    )


# --- the plain form, parsed from the bytes ------------------------------------------------------

_FAST_KIND = {"int": 0, "counts": 0, "float": 1, "text": 2, "skip": 1}
_FAST_DIGITS = 18  # most digits of a number the fast pass reads (no int64 overflow)
_POW10 = np.array([float(10**k) for k in range(23)])  # 1e0 … 1e22, each exact in a double
_MODE_BYTES = np.array([list(m.encode("ascii")) for m in MODE_NAMES], dtype=np.uint8)


def _scan_plain(
    buf: np.ndarray,
    kinds: np.ndarray,
    slots: np.ndarray,
    names: np.ndarray,
    max_chars: int,
    pow10: np.ndarray,
    ints: np.ndarray,
    floats: np.ndarray,
    modes: np.ndarray,
) -> int:
    """Parse plain rows from bytes: the number of rows, or -1 at anything not plain.

    Plain: every row has one field per column, separated by ``,`` and ended by ``\\n`` (the
    last one may end the file instead); an integer field is ``-?[0-9]{1,18}``; a number field
    ``-?[0-9]{1,18}(.[0-9]*)?([eE][+-]?[0-9]{1,4})?`` (18 digits in all) whose digits, as an
    integer, are at most 2**53 and whose decimal exponent is within ±22, so that one
    multiplication or division by an exact power of ten gives the correctly rounded double, as
    ``float()`` does (Clinger's fast path); a text field is a mode name; no field is longer
    than ``max_chars``. Column ``j`` of kind ``kinds[j]`` (0 int, 1 number, 2 mode) goes to row
    ``slots[j]`` of ``ints``, ``floats`` or ``modes``.
    """
    n = buf.shape[0]
    ncol = kinds.shape[0]
    cap = ints.shape[1]
    pos = 0
    row = 0
    while pos < n:
        if row >= cap:
            return -1
        for j in range(ncol):
            start = pos
            kind = kinds[j]
            if kind == 2:
                code = -1
                for m in range(names.shape[0]):
                    w = names.shape[1]
                    if pos + w <= n:
                        same = True
                        for i in range(w):
                            if buf[pos + i] != names[m, i]:
                                same = False
                                break
                        if same:
                            code = m
                            break
                if code < 0:
                    return -1
                pos += names.shape[1]
                modes[slots[j], row] = code
            else:
                neg = False
                if pos < n and buf[pos] == 45:  # -
                    neg = True
                    pos += 1
                mant = 0
                digits = 0
                point = -1  # the digits before the decimal point, once a number field has one
                while pos < n:
                    c = buf[pos]
                    if c >= 48 and c <= 57:
                        if digits == _FAST_DIGITS:
                            return -1
                        mant = mant * 10 + (np.int64(c) - 48)
                        digits += 1
                    elif c == 46 and kind == 1 and point < 0 and digits > 0:  # .
                        point = digits
                    else:
                        break
                    pos += 1
                if digits == 0:
                    return -1
                if kind == 0:
                    ints[slots[j], row] = -mant if neg else mant
                else:
                    frac = digits - point if point >= 0 else 0
                    exp = 0
                    if pos < n and (buf[pos] == 101 or buf[pos] == 69):  # e E
                        pos += 1
                        exp_neg = False
                        if pos < n and (buf[pos] == 43 or buf[pos] == 45):  # + -
                            exp_neg = buf[pos] == 45
                            pos += 1
                        exp_digits = 0
                        while pos < n and buf[pos] >= 48 and buf[pos] <= 57:
                            if exp_digits == 4:
                                return -1
                            exp = exp * 10 + (np.int64(buf[pos]) - 48)
                            exp_digits += 1
                            pos += 1
                        if exp_digits == 0:
                            return -1
                        if exp_neg:
                            exp = -exp
                    if mant > 9007199254740992:  # 2**53
                        return -1
                    e10 = exp - frac
                    if mant == 0:
                        val = 0.0
                    elif e10 >= 0 and e10 <= 22:
                        val = float(mant) * pow10[e10]
                    elif e10 < 0 and e10 >= -22:
                        val = float(mant) / pow10[-e10]
                    else:
                        return -1
                    floats[slots[j], row] = -val if neg else val
            if pos - start > max_chars:
                return -1
            if j + 1 < ncol:
                if pos >= n or buf[pos] != 44:  # ,
                    return -1
                pos += 1
            elif pos < n:
                if buf[pos] != 10:  # newline
                    return -1
                pos += 1
        row += 1
    return row


@functools.cache
def _plain_kernel() -> Any:
    # compiled on first use: the modules that import this one stay free of numba
    from servotune._numba_cache import jit

    return jit(_scan_plain)


def fast_columns(
    data: bytes, start: int, header: list[str], kinds: Sequence[str] | None = None
) -> dict[str, np.ndarray] | None:
    """The columns of a plain body (``data[start:]``, :func:`_scan_plain`), or None.

    Integer columns are int64, number columns float64, and a ``mode`` column comes as its
    ``MODE_*`` codes (int8), as :func:`mode_codes` makes them. ``kinds``: each column's kind
    (default the log's, by name); a ``"skip"`` column must be plain numbers too and is left
    out. None when the body is not all plain rows (or has none): :func:`data_rows` then
    parses and judges it.
    """
    if start >= len(data):
        return None
    from servotune._numba_cache import call_compiled

    named = column_kinds(header) if kinds is None else list(kinds)
    kinds = np.array([_FAST_KIND[k] for k in named], dtype=np.int64)
    slots = np.zeros(kinds.size, dtype=np.int64)
    counts = [0, 0, 0]
    for j, k in enumerate(kinds.tolist()):
        slots[j] = counts[k]
        counts[k] += 1
    cap = data.count(b"\n", start) + 1
    ints = np.empty((counts[0], cap), dtype=np.int64)
    floats = np.empty((counts[1], cap), dtype=np.float64)
    modes = np.empty((counts[2], cap), dtype=np.int8)
    buf = np.frombuffer(data, dtype=np.uint8, offset=start)
    n = call_compiled(
        _plain_kernel(),
        buf,
        kinds,
        slots,
        _MODE_BYTES,
        MAX_NUMBER_CHARS,
        _POW10,
        ints,
        floats,
        modes,
    )
    if n < 1:
        return None
    out = (ints, floats, modes)
    return {
        h: out[k][s, :n]
        for h, k, s, kind in zip(header, kinds.tolist(), slots.tolist(), named, strict=True)
        if kind != "skip"
    }


def data_rows(
    body: str,
    header_line: int,
    header: list[str],
    empty: str,
    kinds: Sequence[str] | None = None,
) -> tuple[np.ndarray, RowLines]:
    """The data rows under the header, parsed (``empty``: the message when there are none).

    ``kinds``: each column's kind (a key of :data:`_DTYPES`); default the log's, by name."""
    if not body or body.isspace():
        raise LogFormatError(empty)
    _check_field_lengths(body, header_line, header)
    return _parse_body(body, header_line, header, kinds)


def column_kinds(header: list[str]) -> list[str]:
    """Each log column's kind (:data:`KIND`), by its name."""
    return [KIND[base_name(h)] for h in header]


def _parse_body(
    body: str, header_line: int, header: list[str], kinds: Sequence[str] | None = None
) -> tuple[np.ndarray, RowLines]:
    """All data rows as a structured array (field ``c<j>`` per column) and their line numbers.

    The fast path parses the whole body with ``numpy.loadtxt`` (one typed field per column),
    which skips empty lines. If that fails, whitespace-only lines are dropped and, if the rest
    still fails, the first bad row is found by bisection (``loadtxt`` judges rows one by one,
    so a block fails exactly when it holds a bad row) and then explained field by field.

    A ``counts`` column is read as integers; if any of its fields is written as a number
    (``0.0``) the body is read again with those columns as numbers, which
    :func:`whole_counts` then turns into integers if every value is whole.
    """
    kinds = column_kinds(header) if kinds is None else list(kinds)
    dtype = np.dtype([(f"c{j}", _DTYPES[k]) for j, k in enumerate(kinds)])
    loose = dtype
    if "counts" in kinds:
        loose = np.dtype(
            [(f"c{j}", np.float64 if k == "counts" else _DTYPES[k]) for j, k in enumerate(kinds)]
        )
    first = header_line + 1

    def load_as(lines: str | list[str], dt: np.dtype) -> np.ndarray:
        src = io.StringIO(lines) if isinstance(lines, str) else lines
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "input contained no data"
            # numpy < 2 parses "12.5" in an integer column as 12 with a DeprecationWarning
            warnings.simplefilter("error", DeprecationWarning)
            return np.loadtxt(src, delimiter=",", dtype=dt, comments=None, ndmin=1)

    def load(lines: str | list[str]) -> np.ndarray:
        if loose is dtype:
            return load_as(lines, dtype)
        try:
            return load_as(lines, dtype)
        except (ValueError, OverflowError, DeprecationWarning):
            return load_as(lines, loose)  # a counts column written as numbers?

    def reason(exc: Exception) -> str:
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        return re.sub(r" at row \d+.*$", "", text)  # loadtxt's row counts from 0 and blocks

    try:
        return load(body), RowLines(body, first)
    except (ValueError, OverflowError, DeprecationWarning):
        pass
    lines = body.split("\n")
    keep = [k for k, s in enumerate(lines) if s.strip()]
    kept = [lines[k] for k in keep]
    del lines
    rows = RowLines(None, first, np.asarray(keep, dtype=np.int64) + first)
    try:
        return load(kept), rows
    except (ValueError, OverflowError, DeprecationWarning) as exc:
        why = reason(exc)
    lo, hi = 0, len(kept)  # the first bad row is in [lo, hi); all rows before lo are good
    while hi - lo > 1:
        mid = (lo + hi) // 2
        try:
            load_as(kept[lo:mid], loose)
            lo = mid
        except (ValueError, OverflowError, DeprecationWarning) as exc:
            why = reason(exc)
            hi = mid
    raise LogFormatError(
        _row_problem(kept[lo], rows(lo), header, header_line, kinds) or f"row {rows(lo)}: {why}"
    )


def not_whole(a: np.ndarray) -> np.ndarray:
    """Where the numbers ``a`` are not whole counts: more than :data:`WHOLE_TOL` from an
    integer, not finite, or beyond :data:`MAX_WHOLE`."""
    with np.errstate(invalid="ignore"):
        return ~(np.abs(a - np.rint(a)) <= WHOLE_TOL) | ~(np.abs(a) < MAX_WHOLE)


def whole_problem(x: float) -> str:
    """Why the number ``x`` (:func:`not_whole`) is not a whole count."""
    if not math.isfinite(x):
        return f"{x!r} is not finite"
    if abs(x) >= MAX_WHOLE:
        return f"{x!r} is beyond the counts a number holds exactly (below 2**53)"
    return f"{x!r} is not an integer (a count written as a number must be whole, within 1e-9)"


def whole_counts(
    col: dict[str, np.ndarray], header: list[str], kinds: Sequence[str], rows: RowLines
) -> None:
    """Turn each ``counts`` column read as numbers (``0.0``) into int64 in place, refusing the
    first value that is not whole (within :data:`WHOLE_TOL`) with its row and column."""
    for h, kind in zip(header, kinds, strict=True):
        a = col[h]
        if kind != "counts" or a.dtype.kind != "f":
            continue
        bad = not_whole(a)
        if bad.any():
            k = int(np.argmax(bad))
            raise LogFormatError(f"row {rows(k)}, column {h!r}: {whole_problem(float(a[k]))}")
        col[h] = np.rint(a).astype(np.int64)


def check_range(
    values: np.ndarray, bits: int, rows: Callable[[int], int], name: str, what: str
) -> None:
    """Raise naming the first row whose value is outside 0 .. 2**bits − 1."""
    top = (1 << bits) - 1
    bad = (values < 0) | (values > top)
    if bad.any():
        k = int(np.argmax(bad))
        msg = what.format(v=values[k], bits=bits, top=top)
        raise LogFormatError(f"row {rows(k)}, column {name!r}: {msg}")


def base_name(h: str) -> str:
    return h.rpartition(".")[2]


def _row_problem(
    line: str, row: int, header: list[str], header_line: int, kinds: Sequence[str]
) -> str | None:
    """What is wrong with one data row (wrong number of fields, a bad field), or None."""
    fields = line.split(",")
    if len(fields) != len(header):
        return (
            f"row {row} has {len(fields)} field{'' if len(fields) == 1 else 's'}; the header "
            f"(line {header_line}) has {len(header)}"
        )
    for s, name, kind in zip(fields, header, kinds, strict=True):
        problem = _field_problem(s, kind)
        if problem:
            return f"row {row}, column {name!r}: {problem}"
    return None


def _field_problem(s: str, kind: str) -> str | None:
    """What is wrong with one field of a column of ``kind`` (int, counts, float, text, skip), or
    None. A ``counts`` field may be any number here (:func:`whole_counts` judges it)."""
    if kind in ("text", "skip"):
        return None
    t = s.strip()
    if not t:
        return "empty value" + (" (an integer is expected)" if kind in ("int", "counts") else "")
    if len(t) > MAX_NUMBER_CHARS:
        return f"a field of {len(t)} characters (a number has at most {MAX_NUMBER_CHARS})"
    if kind == "int":
        if INT_RE.fullmatch(t):
            return None if -(2**63) <= int(t) < 2**63 else f"{t!r} is too large for int64"
        x = to_float(t)
        if x is None:
            return f"{t!r} is not a number (an integer is expected)"
        if not math.isfinite(x):
            return f"{t!r} is not finite (an integer is expected)"
        return f"{t!r} is not an integer"
    x = to_float(t)
    if x is None:
        return f"{t!r} is not a number"
    if not math.isfinite(x):
        return f"{t!r} is not finite"
    return None


def timebase(
    tick: np.ndarray | None,
    time_s: np.ndarray | None,
    rows: RowLines,
    *,
    meta_period: float | None,
    meta_source: str,
    opt_period: float | None,
    names: tuple[str, str] = ("tick", "time_s"),
) -> float:
    """Check the time columns and choose the period [s]: option, metadata, else ``time_s``.

    ``names``: the tick and time columns' names in the file, for the messages."""
    tick_name, time_name = names
    if tick is not None:
        step = np.diff(tick)
        bad = step != 1
        if bad.any():
            k = int(np.argmax(bad)) + 1
            what = "does not increase" if step[k - 1] <= 0 else "skips"
            raise LogFormatError(
                f"row {rows(k)}, column {tick_name!r}: {tick[k]} after {tick[k - 1]}: the tick "
                f"{what} (it must step by 1; a dropped sample is not interpolated)"
            )
    estimate = None
    if time_s is not None:
        dt = np.diff(time_s)
        back = dt <= 0
        if back.any():
            k = int(np.argmax(back)) + 1
            what = "repeats" if dt[k - 1] == 0 else "goes back"
            raise LogFormatError(
                f"row {rows(k)}, column {time_name!r}: {float(time_s[k])!r} after "
                f"{float(time_s[k - 1])!r}: time "
                f"{what} (it must increase)"
            )
        med = float(np.median(dt))
        off = np.abs(dt - med) > REL_TOL * med
        if off.any():
            k = int(np.argmax(off)) + 1
            raise LogFormatError(
                f"row {rows(k)}, column {time_name!r}: irregular sampling: interval "
                f"{dt[k - 1]:.9g} s vs the median {med:.9g} s (more than 0.1 % apart; a dropped "
                f"sample is not interpolated)"
            )
        for value, source in ((meta_period, meta_source), (opt_period, "option period_s")):
            if value is not None and abs(value - med) > REL_TOL * med:
                raise LogFormatError(
                    f"{source} = {value!r} s disagrees with the {time_name} column (median "
                    f"interval {med:.9g} s) by more than 0.1 %"
                )
        # end to end: unlike the median, not limited by the resolution time_s is written with
        estimate = float(time_s[-1] - time_s[0]) / (time_s.shape[0] - 1)
        if tick is not None:
            p = estimate if meta_period is None else meta_period
            bad = np.abs(tick * p - time_s) > REL_TOL * p
            if bad.any():
                k = int(np.argmax(bad))
                src = f"from {time_name}" if meta_period is None else meta_source
                raise LogFormatError(
                    f"row {rows(k)}: tick {tick[k]} × period {p:.9g} s ({src}) = "
                    f"{tick[k] * p:.9g} s but {time_name} = {time_s[k]!r} s; {tick_name} and "
                    f"{time_name} must agree within 0.1 % of a period"
                )
    for p in (opt_period, meta_period, estimate):
        if p is not None:
            return p
    raise LogFormatError(
        "the log has no time_s column and no period: add a '# period_s: <seconds>' metadata "
        "line or give the period (option period_s)"
    )


def mode_codes(text: np.ndarray, name: str, rows: RowLines) -> np.ndarray:
    """The ``MODE_*`` code (int8) of each row's mode name; codes already (int8) pass."""
    if text.dtype == np.int8:  # :func:`fast_columns` read the names as codes
        return text
    codes = np.full(text.shape, -1, dtype=np.int8)
    for m, mode_name in enumerate(MODE_NAMES):
        codes[text == mode_name] = m
    if np.any(codes < 0):
        stripped = np.char.strip(text)
        for m, mode_name in enumerate(MODE_NAMES):
            codes[stripped == mode_name] = m
        codes[np.char.str_len(text) >= _MODE_WIDTH] = -1  # possibly truncated on reading
    bad = codes < 0
    if bad.any():
        k = int(np.argmax(bad))
        raise LogFormatError(
            f"row {rows(k)}, column {name!r}: mode {str(text[k]).strip()!r} is not one of "
            f"{', '.join(MODE_NAMES)}"
        )
    return codes
