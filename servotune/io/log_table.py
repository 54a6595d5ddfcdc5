"""A log-format CSV file's columns (docs/formats.md#log-file): the file read as a log is, typed
column by column, without the log's rules on which columns it has.

:func:`read_table` is what reads the files that share the log format but not its columns (the
excitation files, :mod:`servotune.excitation_file`; the CSV logs with their own column names,
:func:`servotune.io.hal.read_mapped_csv`); :func:`read_columns` is its pass over the file, which
:func:`servotune.logs.read_log` makes too. The text, metadata and header are parsed by
:mod:`servotune.io.log_header`, the data rows by :mod:`servotune.io.log_rows`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from servotune.errors import LogFormatError
from servotune.io.log_header import (
    COLUMNS_HELP,
    decode_text,
    parse_header,
    read_bytes,
    split_ascii_head,
    split_text,
)
from servotune.io.log_rows import (
    KIND,
    MODE_NAMES,
    RowLines,
    base_name,
    column_kinds,
    data_rows,
    fast_columns,
    whole_counts,
)

__all__ = ["MIN_ROWS", "Columns", "Table", "read_columns", "read_table"]

MIN_ROWS = 3
"""Fewest data rows a log may have (:func:`servotune.logs.read_log`; the HAL captures too); the
identifier asks for more itself."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Table:
    """A log-format CSV file (docs/formats.md#log-file) parsed without the log's column-set rules.

    What :func:`read_table` returns, for files that share the log format but not its columns
    (the excitation files of :mod:`servotune.excitation_file`).

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

    The file checks of :func:`~servotune.logs.read_log` apply (readable UTF-8 text, no NUL, a
    byte-order mark ignored, the memory budget, metadata and field lengths), and every data row
    is parsed as :func:`~servotune.logs.read_log` parses it (integers in integer columns, finite
    numbers, the right number of fields); the first bad row is named with its line and column.
    Which columns a file may have is left to ``check_header``.

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

        read = read_columns(
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
class Columns:
    """What :func:`read_columns` read: the file's head, its kept columns, where its rows are."""

    metadata: dict[str, str]
    metadata_lines: dict[str, int]
    header_line: int
    header: list[str]
    columns: dict[str, np.ndarray]
    rows: RowLines
    n_rows: int


def read_columns(
    path: str | Path,
    src: str,
    what: str,
    prepare: Callable[[dict[str, str], dict[str, int], list[str], int], Sequence[str] | None],
    empty: Callable[[int], str],
) -> Columns:
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
    return Columns(meta, meta_line, header_line, header, col, rows, n)
