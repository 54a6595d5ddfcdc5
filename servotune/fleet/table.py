"""The fleet table (``servotune fit LOGS --fleet out.parquet|out.csv``): its columns, and its
two file forms, Apache Parquet (via ``pyarrow``) and CSV (the standard library's ``csv``).

One record per log and axis, as :class:`servotune.fleet.FleetRow` builds it: a mapping of
every column of :data:`COLUMNS` to a value of the column's type (``str``, ``float``, ``int``,
``bool``) or None. Both forms hold the same table: a record written to either and read back is
equal to the one written (floats round-trip exactly: CSV writes their shortest ``repr``), and
the same records give the same bytes (no time stamps; the CSV's lines are ``\\n``-terminated).

- **Parquet**: one row group, the column types of :data:`COLUMNS` (``string``, ``double``,
  ``int64``, ``bool``; None is a null), the schema and the servotune version in the file's
  key-value metadata (``servotune.schema``, ``servotune.version``).
- **CSV**: ``# schema: servotune.fleet/1`` and ``# servotune_version: …`` lines, then a header
  row with the column names in :data:`COLUMNS` order, then one line per record. An empty cell
  is None for a number or a flag and ``""`` for text; flags are ``true``/``false``.

The version line is provenance: a reader checks the schema only (docs/decisions.md#17-file-versions:
a table of another schema is refused with one line, never misread).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from servotune._version import __version__
from servotune.errors import FleetTableError
from servotune.identify.model import ALL_PARAMS
from servotune.io.files import atomic_write_bytes, read_bytes

__all__ = [
    "COLUMNS",
    "FLEET_SCHEMA",
    "FORMATS",
    "fleet_table_bytes",
    "parse_fleet_table",
    "read_fleet_records",
    "table_format",
    "write_fleet_records",
]

FLEET_SCHEMA = "servotune.fleet/1"
"""Schema of the fleet table (the columns of :data:`COLUMNS`)."""

FORMATS = {".parquet": "parquet", ".csv": "csv"}
"""File suffix → table form."""

_TEXT, _FLOAT, _INT, _BOOL = "string", "double", "int64", "bool"


def _param_columns() -> list[tuple[str, str]]:
    out = []
    for p in ALL_PARAMS:
        out += [(p, _FLOAT), (f"{p}_lo", _FLOAT), (f"{p}_hi", _FLOAT)]
    return out


COLUMNS: tuple[tuple[str, str], ...] = (
    ("machine_id", _TEXT),
    ("date", _TEXT),
    ("file", _TEXT),
    ("axis", _TEXT),
    ("sha256", _TEXT),
    ("status", _TEXT),
    ("error", _TEXT),
    ("method", _TEXT),
    ("structure", _TEXT),
    ("friction", _TEXT),
    ("adequate", _BOOL),
    ("failed_tests", _TEXT),
    ("velocity_fit_pct", _FLOAT),
    ("velocity_fit_cv_pct", _FLOAT),
    ("position_fit_pct", _FLOAT),
    ("position_fit_cv_pct", _FLOAT),
    *_param_columns(),
    ("n_samples", _INT),
    ("period_s", _FLOAT),
    ("outliers", _TEXT),
    ("drift", _TEXT),
    ("warnings", _TEXT),
)
"""Column names and types, in table order. Per parameter of
:data:`servotune.identify.model.ALL_PARAMS`: its value and the bounds of its 95 % interval
(``<p>_lo``, ``<p>_hi``), units in the names."""

_NAMES = tuple(n for n, _ in COLUMNS)
_TYPES = dict(COLUMNS)


def table_format(path: str | Path) -> str:
    """``"parquet"`` or ``"csv"`` from the file's suffix.

    Raises
    ------
    FleetTableError
        For another suffix.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise FleetTableError(
            f"fleet table {str(path)!r}: name it .parquet or .csv (the suffix chooses the form)"
        )
    return FORMATS[suffix]


def _check_record(rec: Mapping[str, Any], i: int) -> None:
    missing = [n for n in _NAMES if n not in rec]
    extra = [n for n in rec if n not in _TYPES]
    if missing or extra:
        raise FleetTableError(
            f"fleet record {i}: missing columns {missing}, unknown columns {extra}"
        )


def fleet_table_bytes(records: Sequence[Mapping[str, Any]], fmt: str) -> bytes:
    """The table of ``records`` (in the order given) as the bytes of a ``fmt`` file
    (``"parquet"`` or ``"csv"``); the same records give the same bytes."""
    for i, rec in enumerate(records):
        _check_record(rec, i)
    if fmt == "csv":
        return _csv_bytes(records)
    if fmt == "parquet":
        return _parquet_bytes(records)
    raise FleetTableError(f"fleet table form must be 'parquet' or 'csv', got {fmt!r}")


def write_fleet_records(records: Sequence[Mapping[str, Any]], path: str | Path) -> None:
    """Write the table atomically (temporary file, then rename), in the form its suffix names."""
    atomic_write_bytes(path, fleet_table_bytes(records, table_format(path)))


def read_fleet_records(path: str | Path) -> list[dict[str, Any]]:
    """Read a fleet table (either form, by its suffix) back into records.

    Raises
    ------
    FleetTableError
        If the file cannot be read, is not a fleet table, has another schema, or a cell is
        not of its column's type.
    """
    fmt = table_format(path)
    raw = read_bytes(path, FleetTableError, "fleet table")
    return parse_fleet_table(raw, fmt, str(path))


def parse_fleet_table(raw: bytes, fmt: str, src: str = "<bytes>") -> list[dict[str, Any]]:
    """Records of a fleet table's bytes (:func:`read_fleet_records` without the file)."""
    if fmt == "csv":
        return _parse_csv(raw, src)
    if fmt == "parquet":
        return _parse_parquet(raw, src)
    raise FleetTableError(f"fleet table form must be 'parquet' or 'csv', got {fmt!r}")


# --- CSV -------------------------------------------------------------------------------------


def _csv_cell(value: Any, kind: str) -> str:
    if value is None:
        return ""
    if kind == _BOOL:
        return "true" if value else "false"
    if kind == _FLOAT:
        x = float(value)
        return repr(x) if math.isfinite(x) else ""
    if kind == _INT:
        return str(int(value))
    return str(value)


def _csv_bytes(records: Sequence[Mapping[str, Any]]) -> bytes:
    buf = io.StringIO()
    buf.write(f"# schema: {FLEET_SCHEMA}\n# servotune_version: {__version__}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(_NAMES)
    for rec in records:
        w.writerow([_csv_cell(rec[n], k) for n, k in COLUMNS])
    return buf.getvalue().encode("utf-8")


def _parse_cell(text: str, kind: str, where: str) -> Any:
    if kind == _TEXT:
        return text
    if text == "":
        return None
    try:
        if kind == _FLOAT:
            return float(text)
        if kind == _INT:
            return int(text)
    except ValueError:
        raise FleetTableError(f"{where}: {text!r} is not a number") from None
    if text not in ("true", "false"):
        raise FleetTableError(f"{where}: {text!r} is not true or false")
    return text == "true"


def _parse_csv(raw: bytes, src: str) -> list[dict[str, Any]]:
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise FleetTableError(f"fleet table {src!r} is not UTF-8 text") from None
    lines = text.splitlines()
    meta: dict[str, str] = {}
    start = 0
    while start < len(lines) and lines[start].startswith("#"):
        key, _, value = lines[start][1:].partition(":")
        meta[key.strip()] = value.strip()
        start += 1
    _check_schema(meta.get("schema"), src)
    rows = list(csv.reader(lines[start:]))
    if not rows or tuple(rows[0]) != _NAMES:
        got = rows[0] if rows else []
        raise FleetTableError(
            f"fleet table {src!r}: the header row is not {FLEET_SCHEMA}'s columns (missing "
            f"{[n for n in _NAMES if n not in got]}, unknown {[n for n in got if n not in _TYPES]})"
        )
    out = []
    for i, row in enumerate(rows[1:], start=start + 2):
        if len(row) != len(_NAMES):
            raise FleetTableError(
                f"fleet table {src!r} line {i}: {len(row)} cells, {len(_NAMES)} columns"
            )
        out.append(
            {
                n: _parse_cell(c, _TYPES[n], f"fleet table {src!r} line {i} column {n}")
                for n, c in zip(_NAMES, row, strict=True)
            }
        )
    return out


def _check_schema(schema: str | None, src: str) -> None:
    if schema is None:
        raise FleetTableError(
            f"{src!r} is not a servotune fleet table (no schema; write one with "
            "`servotune fit LOGS --fleet FILE`)"
        )
    if schema != FLEET_SCHEMA:
        raise FleetTableError(
            f"fleet table {src!r} has schema {schema!r}; this servotune reads {FLEET_SCHEMA} "
            "(re-run `servotune fit LOGS --fleet FILE`)"
        )


# --- Parquet ---------------------------------------------------------------------------------


def _arrow_schema() -> Any:
    import pyarrow as pa

    kinds = {_TEXT: pa.string(), _FLOAT: pa.float64(), _INT: pa.int64(), _BOOL: pa.bool_()}
    return pa.schema(
        [pa.field(n, kinds[k]) for n, k in COLUMNS],
        metadata={"servotune.schema": FLEET_SCHEMA, "servotune.version": __version__},
    )


def _arrow_value(value: Any, kind: str) -> Any:
    if value is None:
        return None
    if kind == _FLOAT:
        x = float(value)
        return x if math.isfinite(x) else None
    return value


def _parquet_bytes(records: Sequence[Mapping[str, Any]]) -> bytes:
    import pyarrow as pa
    import pyarrow.parquet as pq

    schema = _arrow_schema()
    cols = {n: [_arrow_value(r[n], k) for r in records] for n, k in COLUMNS}
    table = pa.Table.from_pydict(cols, schema=schema)
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, row_group_size=max(1, len(records)))
    return sink.getvalue().to_pybytes()


def _parse_parquet(raw: bytes, src: str) -> list[dict[str, Any]]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(pa.BufferReader(raw))
    except (pa.ArrowException, OSError, ValueError) as exc:
        why = " ".join(str(exc).split())
        raise FleetTableError(f"fleet table {src!r} is not a Parquet file ({why})") from None
    meta = {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items()}
    _check_schema(meta.get("servotune.schema"), src)
    if tuple(table.column_names) != _NAMES:
        got = table.column_names
        raise FleetTableError(
            f"fleet table {src!r}: its columns are not {FLEET_SCHEMA}'s (missing "
            f"{[n for n in _NAMES if n not in got]}, unknown {[n for n in got if n not in _TYPES]})"
        )
    expected = _arrow_schema()
    for f in expected:
        if not table.schema.field(f.name).type.equals(f.type):
            raise FleetTableError(
                f"fleet table {src!r}: column {f.name} is {table.schema.field(f.name).type}, "
                f"expected {f.type}"
            )
    out = table.to_pylist()
    for rec in out:
        for n, k in COLUMNS:
            if k == _TEXT and rec[n] is None:
                rec[n] = ""
    return out
