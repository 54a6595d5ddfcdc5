"""The export formats: one registry, one shape (``servotune export-table --format NAME``).

An export format is one module with two functions:

- ``to_string(obj, **options) -> str``: the export's text, deterministic bytes. A format of
  several files gives the one file generated for ``obj`` (the C format: the header; the
  runtime's sources it is copied with are package data);
- ``to_file(obj, path, **options)``: write that export to ``path`` atomically (rendered in
  memory first: :func:`servotune.export.document.write_export`), nothing written on an error.
  A format whose export is several files (:attr:`ExportFormat.directory`) writes them into
  the directory ``path`` as a whole (:func:`servotune.io.files.write_files`: all or none) and
  returns the paths written, the generated file first.

``obj`` is what is exported, one of the document kinds of :data:`KINDS`: a rig's tuning
(:class:`servotune.tuning.Tuning`), a gantry tuning
(:class:`servotune.arch.gantry.tuning.GantryTuning`) or a linkage plan
(:class:`servotune.arch.linkage.plan.LinkagePlan`). Every format takes the keywords
``verification`` (the checked verification record) and ``unverified`` (export without one,
marked so), a rig's and a gantry's export also ``rig``
(:class:`servotune.export.json.TablesOptions`); its own keywords are listed in
:attr:`ExportFormat.options`.

:data:`FORMATS` holds the formats by name, in the order ``--format`` lists them;
:func:`register` adds one (docs/contributing.md#adding-an-export-format). A format's module is
imported only when it renders (:meth:`ExportFormat.load`): this module imports no other
module of servotune but :mod:`servotune.errors`, so that ``servotune --help`` stays light.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType, ModuleType
from typing import Any

from servotune.errors import ExportError

__all__ = ["DEFAULT_FORMAT", "FORMATS", "KINDS", "ExportFormat", "formats_for", "register"]

KINDS: Mapping[str, str] = MappingProxyType(
    {
        "rig": "a rig's tuning (one runtime, its master and slave axes)",
        "gantry": "a gantry tuning",
        "linkage": "a linkage plan",
    }
)
"""The document kinds an export renders (:func:`servotune.arch.kind.document_kind`), each with
its description in the CLI's messages."""


@dataclass(frozen=True)
class ExportFormat:
    """One export format: its name, its help, its module and what it exports.

    Attributes
    ----------
    name : str
        The ``--format`` choice (no space).
    help : str
        Its words in ``export-table --format``'s help.
    module : str
        The dotted name of the module defining ``to_string`` and ``to_file`` (module
        docstring), imported on first use.
    kinds : mapping
        The document kinds it exports (keys of :data:`KINDS`), each with the words naming what
        it writes in the CLI's ``wrote … to PATH`` line (``"the tables"``).
    directory : bool
        ``to_file`` writes a directory of several files (``-o DIR`` is then needed; nothing
        goes to stdout) and returns the paths written; else it writes one file, and without
        ``-o`` the CLI writes ``to_string`` to stdout.
    options : tuple of str
        The keywords of its own that ``to_string`` and ``to_file`` take; the CLI passes each
        from the ``export-table`` option of the same ``dest`` (servotune/cli/parser.py).
    """

    name: str
    help: str
    module: str
    kinds: Mapping[str, str]
    directory: bool = False
    options: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        if not self.name or any(c.isspace() for c in self.name):
            raise ExportError(f"an export format's name is one word, not {self.name!r}")
        unknown = sorted(set(self.kinds) - set(KINDS))
        if not self.kinds or unknown:
            raise ExportError(
                f"export format {self.name!r}: kinds {unknown or '(none)'}; "
                f"the kinds are {', '.join(KINDS)}"
            )
        object.__setattr__(self, "kinds", MappingProxyType(dict(self.kinds)))
        object.__setattr__(self, "options", tuple(self.options))

    def load(self) -> ModuleType:
        """The format's module (imported on first use).

        Raises
        ------
        ExportError
            The module lacks ``to_string`` or ``to_file``.
        """
        module = importlib.import_module(self.module)
        missing = [f for f in ("to_string", "to_file") if not callable(getattr(module, f, None))]
        if missing:
            raise ExportError(
                f"export format {self.name!r}: {self.module} has no {' and no '.join(missing)}"
            )
        return module

    def to_string(self, obj: Any, **options: Any) -> str:
        """The export of ``obj`` as text: the module's ``to_string``."""
        return self.load().to_string(obj, **options)

    def to_file(self, obj: Any, path: str | Path, **options: Any) -> Any:
        """Write the export of ``obj`` to ``path``: the module's ``to_file`` (for a
        :attr:`directory` format, the paths written)."""
        return self.load().to_file(obj, path, **options)


FORMATS: dict[str, ExportFormat] = {}
"""The export formats by name, in the order ``export-table --format`` lists them."""

DEFAULT_FORMAT = "json"
"""The format ``export-table`` writes without ``--format``."""


def register(fmt: ExportFormat) -> ExportFormat:
    """Add ``fmt`` to :data:`FORMATS` (``export-table --format`` offers it from then on); returns
    it.

    Raises
    ------
    ExportError
        A format of that name is registered already.
    """
    if fmt.name in FORMATS:
        raise ExportError(f"an export format {fmt.name!r} is registered already")
    FORMATS[fmt.name] = fmt
    return fmt


def formats_for(kind: str) -> tuple[str, ...]:
    """The names of the formats that export the document kind ``kind``."""
    return tuple(name for name, fmt in FORMATS.items() if kind in fmt.kinds)


register(
    ExportFormat(
        name="json",
        help="the tables, gantry tables or linkage export as JSON",
        module="servotune.export.json",
        kinds={"rig": "the tables", "gantry": "the gantry tables", "linkage": "the linkage export"},
    )
)
register(
    ExportFormat(
        name="c",
        help="header + runtime sources",
        module="servotune.export.c",
        kinds=dict.fromkeys(KINDS, "the C files"),
        directory=True,
    )
)
register(
    ExportFormat(
        name="linuxcnc-hal",
        help="a HAL file setting the stock pid component's parameters for the master axis",
        module="servotune.export.linuxcnc",
        kinds={"rig": "the HAL file"},
        options=("position_scale", "output_scale", "pid_name", "velocity_feedforward"),
    )
)
register(
    ExportFormat(
        name="linuxcnc-comp",
        help="a realtime HAL component (build it with halcompile) running the verified runtime "
        "and its tables",
        module="servotune.export.hal_component",
        kinds={"rig": "the HAL component"},
        options=("name", "position_scale"),
    )
)
