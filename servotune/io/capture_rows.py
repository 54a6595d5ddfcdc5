"""The rows of HAL captures (halsampler, halscope): whitespace- or ';'-separated numbers read a
chunk of lines at a time, each problem named by its line in the file (the readers that use them:
:mod:`servotune.io.hal`)."""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from servotune.budget import check_memory, format_bytes, format_count
from servotune.errors import LogFormatError
from servotune.io.log_header import TEXT_CHUNK_BYTES, file_size, read_text_chunks
from servotune.validate import show_value

__all__ = ["NUMBER_RE", "check_capture_memory", "check_rows", "numbers", "stream_rows"]


def stream_rows(
    path: Path,
    src: str,
    delimiter: str | None,
    what: str,
    label: Callable[[int], str],
    each: Callable[[int, list[str]], int],
    progress: Callable[[str], None] | None,
    *,
    empty: str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """A capture's rows as an (n, m) float array and their 1-based lines, read a chunk of lines
    at a time (:func:`~servotune.io.log_header.read_text_chunks`) after the arrays' estimate is
    checked against the memory budget (:func:`check_capture_memory`). ``each(lines before the
    chunk, its lines)`` checks a chunk and returns how many of its first lines are not rows (a
    header). Every chunk must have as many fields per row as the first. ``empty``: the message
    for a file without a line (default: the capture is empty)."""
    check_capture_memory(path, src, delimiter)
    parts: list[np.ndarray] = []
    row_parts: list[np.ndarray] = []
    seen = False
    for line0, lines in read_text_chunks(path, src, "HAL capture", progress=progress):
        seen = True
        start = each(line0, lines)
        if not any(ln.strip() for ln in lines[start:]):
            continue
        values, rows = numbers(lines, start, delimiter, what, label, line0=line0)
        if parts and values.shape[1] != parts[0].shape[1]:
            raise LogFormatError(
                f"line {rows[0]} has {values.shape[1]} fields, the rows before it "
                f"{parts[0].shape[1]} (line {row_parts[0][0]})"
            )
        parts.append(values)
        row_parts.append(rows)
    if not parts:
        if not seen and empty is not None:
            raise LogFormatError(f"{empty} (no samples)")
        raise LogFormatError(f"the {what} capture is empty (no samples)")
    values = parts[0] if len(parts) == 1 else np.concatenate(parts)
    rows = row_parts[0] if len(row_parts) == 1 else np.concatenate(row_parts)
    return values, rows


_SAMPLE_BYTES = 64 * 1024  # the head of a capture its rows are estimated from


def check_capture_memory(path: Path, src: str, delimiter: str | None = None) -> None:
    """Refuse, before reading, a capture whose arrays would not fit in the memory budget:
    rows estimated from the file's size and the bytes per row of its first 64 KiB; per row,
    its fields as float64 and its line number, three times (the chunks, the whole array, the
    sample-number checks and the pins' contiguous copy), and the chunk being parsed (its
    text, lines and numbers: about 8 times its bytes)."""
    size = file_size(path, src, "HAL capture")
    with open(path, "rb") as fh:
        head = fh.read(_SAMPLE_BYTES)
    end = head.rfind(b"\n") + 1
    sample = head[:end] if end else head
    first = next((ln for ln in sample.split(b"\n") if ln.strip()), b"")
    fields = max(1, len(first.split(None if delimiter is None else delimiter.encode())))
    rows = size * max(1, sample.count(b"\n")) / max(1, len(sample))
    per_row = 3 * (8 * fields + 8)
    check_memory(
        rows * per_row + 8 * TEXT_CHUNK_BYTES,
        f"reading HAL capture {src!r}",
        f"{format_bytes(size)}: about {format_count(rows)} rows × {fields} fields × "
        f"{per_row // 3} bytes, three times",
    )


NUMBER_RE = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


def numbers(
    lines: list[str],
    start: int,
    delimiter: str | None,
    what: str,
    label: Callable[[int], str],
    *,
    line0: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """The non-blank lines from ``start`` as an (n, m) float array, and their 1-based line
    numbers (``line0``: lines of the file before ``lines``, a chunk of it). Bulk-parsed by
    ``numpy.loadtxt``; on failure the lines are scanned one by one to name the first bad one
    (``label(j)`` names field ``j``)."""
    idx = [i for i in range(start, len(lines)) if lines[i].strip()]
    if not idx:
        raise LogFormatError(f"the {what} capture is empty (no samples)")
    rows = np.asarray(idx, dtype=np.int64) + (1 + line0)
    body = [lines[i] for i in idx]
    try:
        values = np.loadtxt(body, dtype=float, delimiter=delimiter, comments=None, ndmin=2)
    except ValueError:
        first_bad(body, rows, delimiter, label)
        raise  # pragma: no cover  (first_bad raises: loadtxt refused something it finds)
    return values, rows


def split_fields(line: str, delimiter: str | None) -> list[str]:
    return line.split() if delimiter is None else [t.strip() for t in line.split(delimiter)]


def first_bad(
    body: list[str], rows: np.ndarray, delimiter: str | None, label: Callable[[int], str]
) -> None:
    width = len(split_fields(body[0], delimiter))
    for k, line in enumerate(body):
        fields = split_fields(line, delimiter)
        if len(fields) != width:
            raise LogFormatError(
                f"line {rows[k]} has {len(fields)} field{'s' if len(fields) != 1 else ''}, "
                f"the rows before it {width} (line {rows[0]})"
            )
        for j, tok in enumerate(fields):
            if not NUMBER_RE.fullmatch(tok) and tok.lower().lstrip("+-") not in ("nan", "inf"):
                raise LogFormatError(
                    f"line {rows[k]}, {label(j)}: {show_value(tok)} is not a number"
                )
    raise LogFormatError(f"line {rows[0]}: the rows are not numbers numpy can read")


def check_rows(values: np.ndarray, rows: np.ndarray, names: Sequence[str] | None) -> None:
    bad = ~np.isfinite(values)
    if bad.any():
        k, j = (int(x) for x in np.argwhere(bad)[0])
        label = f"column {j}" if names is None else f"column {j} ({names[j]})"
        raise LogFormatError(f"line {rows[k]}, {label}: {values[k, j]} is not finite")
