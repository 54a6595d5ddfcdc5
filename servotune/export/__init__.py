"""Exports of a tuning (or a gantry tuning, or a linkage plan) to the runtime, one module per
export format, all of one shape: ``to_string(obj, **options)`` and ``to_file(obj, path,
**options)``, listed in :data:`~servotune.export.formats.FORMATS`, which
``export-table --format`` reads (:mod:`servotune.export.formats`):

- ``json``, :mod:`servotune.export.json`: the ``servotune.tables/4`` document of a rig's tuning
  (also ``load_tables``, which checks every CRC), the ``servotune.gantry-tables/2`` and
  ``servotune.linkage-export/1`` documents (:mod:`servotune.export.gantry`,
  :mod:`servotune.export.linkage`);
- ``c``, :mod:`servotune.export.c`: a directory of the generated header (``servotune_tables.h``
  and its gantry and linkage counterparts) and the reference runtime's sources;
- ``linuxcnc-hal``, :mod:`servotune.export.linuxcnc`: a HAL file of the stock ``pid``'s
  parameters (and the master's output filters as stock ``biquad`` instances);
- ``linuxcnc-comp``, :mod:`servotune.export.hal_component`: a realtime HAL component running
  the runtime.

Every export of a tuning renders the same constants exactly as the tuning file holds them,
never re-quantised (:func:`~servotune.export.json.tables_document`). This package imports only
the registry: a format's module is imported when it renders.
"""

from servotune.export.formats import DEFAULT_FORMAT, FORMATS, KINDS, ExportFormat, register

__all__ = ["DEFAULT_FORMAT", "FORMATS", "KINDS", "ExportFormat", "register"]
