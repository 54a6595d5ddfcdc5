"""Provenance: an input file as read once, and a file a record binds by its SHA-256 alone.

The trust chain (docs/decisions.md#3-digests) binds every product to its inputs by their SHA-256: a
:class:`SourceFile` is read once, so the bytes used are the bytes digested; a
:class:`FileDigest` names a file whose bytes were read elsewhere. Both give the record's entry
for the file (its name and SHA-256). This module sits below everything that writes a record
(the verification, the linkage plan, the autotune record) and imports only the digests and the
file reader.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

from servotune.digest import bytes_sha256
from servotune.io.files import read_bytes

__all__ = ["FileDigest", "SourceFile"]


@dataclass(frozen=True, slots=True)
class SourceFile:
    """One input file as read once: its path as given, its SHA-256 and its bytes.

    ``instead_of``: set when the file was found elsewhere than where its owner recorded it
    (:func:`matching_file`): the recorded path, gone (``""``: none was recorded); None for the
    recorded file itself or a file the user gave.
    """

    path: str
    sha256: str
    raw: bytes = field(repr=False, compare=False)
    instead_of: str | None = field(default=None, compare=False)

    @classmethod
    def read(cls, path: str | Path, error: type[Exception], what: str) -> SourceFile:
        """Read ``path``'s bytes once (a failure is one line of ``error`` naming ``what``)."""
        raw = read_bytes(path, error, what)
        return cls(path=str(path), sha256=bytes_sha256(raw), raw=raw)

    def entry(self) -> dict[str, str]:
        """The record's entry for this file: its name and SHA-256."""
        return FileDigest(self.path, self.sha256).entry()


class FileDigest(NamedTuple):
    """A file a record binds by its path and SHA-256 alone, its bytes read elsewhere (the fleet
    table a plant distribution was drawn from)."""

    path: str
    sha256: str

    def entry(self) -> dict[str, str]:
        """The record's entry for this file: its name and SHA-256."""
        return {"name": Path(self.path).name, "sha256": self.sha256}
