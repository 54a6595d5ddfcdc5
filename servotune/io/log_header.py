"""The text, metadata lines and header row of a log-format CSV
(docs/formats.md#log-file).

A log is read as one UTF-8 text (NUL bytes refused, line ends normalised, the memory budget
checked), split into its ``# key: value`` metadata lines, its header row and the body; the
header's names are checked and, for a log, classified per axis; the settings the metadata may
carry (``counter_bits``, ``dac_bits``, ``dac_range_v``, ``period_s``, ``compute_s``) are parsed
here, from the metadata or from an option. The metadata keys a log may declare are
:data:`METADATA_KEYS` (another draws a :class:`LogMetadataWarning`), and :func:`read_metadata`
reads a log's metadata alone. The internals of :func:`servotune.logs.read_log` and
:func:`servotune.io.log_table.read_table`; every error is a one-line :class:`LogFormatError`.
"""

from __future__ import annotations

import contextlib
import difflib
import math
import os
import warnings
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

from servotune.budget import check_memory, format_bytes
from servotune.errors import LogFormatError
from servotune.io.files import MAX_NUMBER_CHARS
from servotune.io.log_rows import INT_RE, to_float

__all__ = [
    "MAX_METADATA_CHARS",
    "MAX_NAME_CHARS",
    "METADATA_KEYS",
    "PERIOD_RANGE_S",
    "TEXT_CHUNK_BYTES",
    "LogMetadataWarning",
    "file_size",
    "read_metadata",
    "read_text_chunks",
    "warn_unknown_metadata",
]

_AXIS_COLUMNS = ("dac_code", "cmd_v", "counter", "pos_counts", "ref_counts", "exc_code", "mode")
_TIME_COLUMNS = ("tick", "time_s")
PERIOD_RANGE_S = (1e-6, 60.0)
"""Sample periods a log may have [s] (1 µs … 1 min)."""

MAX_METADATA_CHARS = 1024
"""Longest metadata value (``# key: value``) accepted [characters]."""

MAX_NAME_CHARS = 64
"""Longest metadata key or header column name accepted [characters]."""

_DAC_RANGE_LIMIT_V = 1000.0  # |low|, |high| of a D/A range [V]

COLUMNS_HELP = (
    "expected tick and/or time_s, and per axis [axis.]dac_code or cmd_v, counter or pos_counts, "
    "optionally ref_counts, exc_code and mode"
)


def meta_pair(line: str) -> tuple[str, str] | None:
    """``(key, value)`` of a stripped ``# key: value`` line, None for any other comment."""
    if ":" not in line:
        return None
    key, value = (x.strip() for x in line[1:].split(":", 1))
    return key, value


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


def read_metadata(path: str | Path) -> dict[str, str]:
    """The ``# key: value`` lines at the head of a log, without reading the rest.

    Reading stops at the header row, or at a line too long to be metadata
    (:func:`servotune.logs.read_log` refuses such a file with the line named).

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


@contextlib.contextmanager
def read_errors(src: str, what: str = "log") -> Iterator[None]:
    """Turn the OS errors of opening a log into one-line LogFormatErrors."""
    try:
        yield
    except FileNotFoundError:
        noun = what if what.endswith("file") else f"{what} file"
        raise LogFormatError(f"{noun} {src!r} does not exist") from None
    except IsADirectoryError:
        raise LogFormatError(f"{what} {src!r} is a directory, not a file") from None
    except OSError as exc:
        raise LogFormatError(f"cannot read {what} {src!r}: {exc.strerror or exc}") from None


@contextlib.contextmanager
def naming(src: str, what: str = "log") -> Iterator[None]:
    """A :class:`LogFormatError` raised inside names the file: ``<what> '<src>': …`` (unless its
    message names ``src`` already)."""
    try:
        yield
    except LogFormatError as exc:
        if src in str(exc):
            raise
        raise LogFormatError(f"{what} {src!r}: {exc}") from None


_READ_BYTES_PER_BYTE = 4  # the bytes, the text, the row lines, the arrays: about 4x the file


def read_text(p: Path, src: str, what: str = "log") -> str:
    return decode_text(read_bytes(p, src, what), src, what)


def read_bytes(p: Path, src: str, what: str = "log") -> bytes:
    """The file's bytes (the memory budget checked first)."""
    with read_errors(src, what):
        with open(p, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            check_memory(
                _READ_BYTES_PER_BYTE * size,
                f"reading {what} {src!r}",
                f"{format_bytes(size)} × {_READ_BYTES_PER_BYTE}",
            )
            return fh.read()


def decode_text(data: bytes, src: str, what: str = "log", line0: int = 0) -> str:
    """The file's text: UTF-8 (a byte-order mark dropped), no NUL, line ends normalised.
    ``line0``: lines of the file before ``data`` (a chunk of it), for the line named."""
    try:
        text = data.decode("utf-8-sig" if line0 == 0 else "utf-8")
    except UnicodeDecodeError as exc:
        line = line0 + data.count(b"\n", 0, exc.start) + 1
        raise LogFormatError(
            f"{what} {src!r} is not UTF-8 text (byte 0x{data[exc.start]:02x} at line {line})"
        ) from None
    nul = text.find("\x00")
    if nul >= 0:
        line = line0 + text.count("\n", 0, nul) + 1
        raise LogFormatError(f"{what} {src!r} is not a text file (NUL byte at line {line})")
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text


def split_text(
    text: str, src: str, what: str = "log"
) -> tuple[dict[str, str], dict[str, int], int, str, str]:
    """Metadata, their line numbers, the header's line number and text, and the body text."""
    if not text or text.isspace():
        raise LogFormatError(f"{what} {src!r} is empty (no header row)")
    meta: dict[str, str] = {}
    meta_line: dict[str, int] = {}
    pos, line_no, end_of_text = 0, 0, len(text)
    while pos < end_of_text:
        nl = text.find("\n", pos)
        end = end_of_text if nl < 0 else nl
        line = text[pos:end].strip()
        line_no += 1
        if line and not line.startswith("#"):
            return meta, meta_line, line_no, text[pos:end], text[end + 1 :]
        kv = meta_pair(line)
        if kv is not None:
            key, value = kv
            if len(key) > MAX_NAME_CHARS or len(value) > MAX_METADATA_CHARS:
                item, n, most = (
                    ("key", len(key), MAX_NAME_CHARS)
                    if len(key) > MAX_NAME_CHARS
                    else (f"{key!r} value", len(value), MAX_METADATA_CHARS)
                )
                raise LogFormatError(
                    f"{what} {src!r}, line {line_no}: metadata {item} of {n} characters (at most "
                    f"{most} are accepted)"
                )
            if key in meta and meta[key] != value:
                raise LogFormatError(
                    f"line {line_no}: metadata {key!r} given twice with different values "
                    f"(first on line {meta_line[key]})"
                )
            meta[key] = value
            meta_line[key] = line_no
        pos = end + 1
    raise LogFormatError(f"{what} {src!r} has no header row, only metadata or comment lines")


_HEAD_BYTES = 1 << 16  # where the plain-ASCII shortcut looks for the header row


def split_ascii_head(
    data: bytes, src: str, what: str = "log"
) -> tuple[dict[str, str], dict[str, int], int, str, int] | None:
    """:func:`split_text` of a plain file from its head alone, the body as a byte offset.

    For a file of ASCII bytes without NUL or carriage return, decoding changes nothing, so the
    metadata and header lines found in the whole lines of the first :data:`_HEAD_BYTES` bytes
    are those of the whole text, and the body starts at the byte after the header's line end:
    the body need not be decoded or copied. None when that does not apply or the head does not
    settle it (no header row there, a problem in its lines): then :func:`decode_text` and
    :func:`split_text` of the whole file decide, with their messages.
    """
    if not data.isascii() or b"\0" in data or b"\r" in data:
        return None
    cut = len(data) if len(data) <= _HEAD_BYTES else data.rfind(b"\n", 0, _HEAD_BYTES) + 1
    head = data[:cut].decode("ascii")
    try:
        meta, meta_line, header_line, header_text, body = split_text(head, src, what)
    except LogFormatError:
        return None
    return meta, meta_line, header_line, header_text, cut - len(body)


def parse_header(header_text: str, line: int) -> list[str]:
    names = [h.strip().strip('"').strip() for h in header_text.split(",")]
    for sep, what in ((";", "semicolons"), ("\t", "tabs")):
        if len(names) == 1 and header_text.count(sep) >= 2:
            raise LogFormatError(
                f"line {line}: the header is separated by {what}, not commas: save the log as "
                f"comma-separated values (decimal point '.'), e.g. tick,time_s,master.dac_code,"
                f"master.counter"
            )
    for j, h in enumerate(names):
        if len(h) > MAX_NAME_CHARS:
            raise LogFormatError(
                f"line {line}: header column {j + 1} has a name of {len(h)} characters (at most "
                f"{MAX_NAME_CHARS} are accepted)"
            )
    if all(to_float(h) is not None for h in names):
        raise LogFormatError(
            f"line {line} looks like data, not a header; the first row after the metadata must "
            f"name the columns (e.g. tick,time_s,dac_code,counter)"
        )
    seen: dict[str, int] = {}
    for j, h in enumerate(names):
        if not h:
            hint = " (a trailing comma?)" if j == len(names) - 1 else ""
            raise LogFormatError(f"line {line}: header column {j + 1} has no name{hint}")
        if h in seen:
            raise LogFormatError(
                f"line {line}: duplicate column {h!r} (header columns {seen[h] + 1} and {j + 1})"
            )
        seen[h] = j
    return names


def classify_columns(header: list[str], line: int) -> dict[str, dict[str, str]]:
    """Per axis (header order), its column kinds mapped to header names; checks the set."""
    prefixes = [h.rpartition(".")[0] for h in header if h.rpartition(".")[0]]
    axes: dict[str, dict[str, str]] = {}
    for h in header:
        if h in _TIME_COLUMNS:
            continue
        ax, dot, col = h.rpartition(".")
        if (dot and not ax) or col not in _AXIS_COLUMNS:
            candidates = [*_TIME_COLUMNS, *_AXIS_COLUMNS]
            candidates += [f"{a}.{c}" for a in dict.fromkeys(prefixes) for c in _AXIS_COLUMNS]
            close = difflib.get_close_matches(h, candidates, n=1, cutoff=0.6)
            hint = f"; did you mean {close[0]!r}?" if close else f"; {COLUMNS_HELP}"
            if not close:  # a logger's own names, most likely
                hint += " (or keep your own names and map them: servotune fit --map)"
            raise LogFormatError(f"line {line}: unknown column {h!r}{hint}")
        axes.setdefault(ax, {})[col] = h
    if not any(h in _TIME_COLUMNS for h in header):
        raise LogFormatError(f"line {line}: no time column; expected 'time_s' and/or 'tick'")
    if not axes:
        raise LogFormatError(f"line {line}: no axis columns; {COLUMNS_HELP}")
    if "" in axes and len(axes) > 1:
        bare = ", ".join(repr(c) for c in axes[""])
        named = ", ".join(repr(a) for a in axes if a)
        raise LogFormatError(
            f"line {line}: column(s) {bare} have no axis prefix but the log has axes {named}; "
            f"prefix every axis column (e.g. '{next(a for a in axes if a)}.dac_code')"
        )
    for ax, cols in axes.items():
        label = f"{ax}." if ax else ""
        who = f"axis {ax!r}" if ax else "the (unprefixed) axis"
        others = [a for a in axes if a != ax]
        alike = difflib.get_close_matches(ax, others, n=1, cutoff=0.6) if ax else []
        hint = f" (axes {ax!r} and {alike[0]!r} look alike: a misspelt prefix?)" if alike else ""
        for kind, pair in (
            ("command", ("dac_code", "cmd_v")),
            ("position", ("counter", "pos_counts")),
        ):
            have = [c for c in pair if c in cols]
            if not have:
                raise LogFormatError(
                    f"line {line}: {who} has no {kind} column; expected '{label}{pair[0]}' or "
                    f"'{label}{pair[1]}'{hint}"
                )
            if len(have) == 2:
                raise LogFormatError(
                    f"line {line}: {who} has both '{label}{pair[0]}' and '{label}{pair[1]}'; "
                    f"keep one {kind} column"
                )
    return axes


def meta_setting(
    key: str, meta: Mapping[str, str], meta_line: Mapping[str, int], parse: Callable[[str], Any]
) -> Any:
    if key not in meta:
        return None
    if len(meta[key]) > MAX_NUMBER_CHARS:
        raise LogFormatError(
            f"line {meta_line[key]}: metadata {key!r} is {len(meta[key])} characters long; a "
            f"setting has at most {MAX_NUMBER_CHARS}"
        )
    try:
        return parse(meta[key])
    except ValueError as exc:
        raise LogFormatError(
            f"line {meta_line[key]}: metadata {key!r} must be {exc}, got {meta[key]!r}"
        ) from None


def option_value(key: str, value: Any, parse: Callable[[str], Any]) -> Any:
    text = ",".join(str(v) for v in value) if isinstance(value, tuple | list) else str(value)
    if isinstance(value, bool):
        text = "not a bool"
    if len(text) > MAX_NUMBER_CHARS:
        raise LogFormatError(
            f"option {key} is {len(text)} characters long; a setting has at most {MAX_NUMBER_CHARS}"
        )
    try:
        return parse(text)
    except ValueError as exc:
        raise LogFormatError(f"option {key} must be {exc}, got {value!r}") from None


def _parse_int(s: str) -> int:
    t = s.strip()
    if not INT_RE.fullmatch(t):
        raise ValueError
    return int(t)


def parse_counter_bits(s: str) -> int:
    try:
        v = _parse_int(s)
    except ValueError:
        v = None
    if v not in (16, 24, 32):
        raise ValueError("16, 24 or 32 (bits)")
    return v


def parse_dac_bits(s: str) -> int:
    try:
        v = _parse_int(s)
    except ValueError:
        v = 0
    if not 1 <= v <= 32:
        raise ValueError("an integer number of bits in 1…32")
    return v


def parse_range(s: str) -> tuple[float, float]:
    parts = [to_float(x) for x in s.strip().strip("[]()").split(",")]
    if len(parts) != 2 or None in parts:
        raise ValueError("'low,high' in volts (e.g. -10,10)")
    lo, hi = parts
    assert lo is not None and hi is not None
    lim = _DAC_RANGE_LIMIT_V
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi and -lim <= lo and hi <= lim):
        raise ValueError(f"'low,high' in volts with low < high, each within ±{lim:g} V")
    return (lo, hi)


def parse_period(s: str) -> float:
    v = to_float(s.strip())
    lo, hi = PERIOD_RANGE_S
    if v is None or not (math.isfinite(v) and lo <= v <= hi):
        raise ValueError(f"a number of seconds > 0, within {lo:g} … {hi:g}")
    return v


def parse_compute(s: str) -> float:
    v = to_float(s.strip())
    if v is None or not (math.isfinite(v) and v >= 0):
        raise ValueError("a finite number of seconds >= 0")
    return v


TEXT_CHUNK_BYTES = 8 * 1024**2
"""Bytes read at a time by :func:`read_text_chunks` (whole lines: a chunk ends at a newline)."""


def file_size(p: Path, src: str, what: str = "log") -> int:
    """The size of the file [bytes] (one line naming it when it cannot be read)."""
    with read_errors(src, what):
        with open(p, "rb") as fh:
            return os.fstat(fh.fileno()).st_size


def read_text_chunks(
    p: Path,
    src: str,
    what: str = "log",
    *,
    chunk_bytes: int | None = None,
    progress: Callable[[str], None] | None = None,
) -> Iterator[tuple[int, list[str]]]:
    """The file's lines, a chunk of about ``chunk_bytes`` at a time: ``(lines before the
    chunk, its lines)``, each chunk decoded and checked as the whole text would be (UTF-8, no
    NUL, line ends normalised; a problem named by its line in the file). Memory: a chunk, not
    the file. ``chunk_bytes`` None: :data:`TEXT_CHUNK_BYTES`. ``progress`` gets a line at each
    tenth of the file read, for files over ``4 * chunk_bytes``."""
    chunk_bytes = TEXT_CHUNK_BYTES if chunk_bytes is None else chunk_bytes
    with read_errors(src, what):
        fh = open(p, "rb")  # closed below, after the last chunk
    with fh:
        size = os.fstat(fh.fileno()).st_size
        line0, rest, done, told = 0, b"", 0, 0
        while True:
            with read_errors(src, what):
                block = fh.read(chunk_bytes)
            done += len(block)
            data = rest + block
            if block:
                cut = data.rfind(b"\n") + 1
                if cut == 0:  # no line end yet: read on
                    rest = data
                    continue
                data, rest = data[:cut], data[cut:]
            elif not data:
                return
            else:
                rest = b""
            lines = decode_text(data, src, what, line0).split("\n")
            if lines[-1] == "":
                lines.pop()  # the text after the chunk's last newline: the next chunk's
            yield line0, lines
            line0 += len(lines)
            tenth = 10 * done // max(size, 1)
            if progress is not None and size > 4 * chunk_bytes and tenth > told:
                told = tenth
                progress(f"reading {what} {src}: {format_bytes(done)} of {format_bytes(size)}")
            if not block:
                return
