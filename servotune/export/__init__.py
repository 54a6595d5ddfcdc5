"""Exports of a tuning to the runtime: the tables as JSON, and C (tables header + runtime).

- :mod:`servotune.export.json`: ``servotune.tables/2`` documents (``to_string``, ``to_file``,
  ``load_tables`` which checks every CRC);
- :mod:`servotune.export.c`: ``servotune_tables.h`` and the reference runtime
  ``servotune_rt.c/.h`` (``write_c``).

Both render the same document (:func:`~servotune.export.json.tables_document`): the constants
exactly as the tuning file holds them, never re-quantised.
"""

from servotune.export.c import RUNTIME_FILES, runtime_source, write_c
from servotune.export.c import to_string as c_header_to_string
from servotune.export.json import (
    SCHEMA,
    constants_crc32,
    controllers_from_tables,
    load_tables,
    table_crc32,
    tables_document,
)
from servotune.export.json import to_file as write_tables
from servotune.export.json import to_string as tables_to_string

__all__ = [
    "RUNTIME_FILES",
    "SCHEMA",
    "c_header_to_string",
    "constants_crc32",
    "controllers_from_tables",
    "load_tables",
    "runtime_source",
    "table_crc32",
    "tables_document",
    "tables_to_string",
    "write_c",
    "write_tables",
]
