"""What every export document shares: its JSON text (:func:`document_text`), its atomic write
(:func:`write_export`) and the verification record's digest of one of its files
(:func:`recorded_sha`). The tables (:mod:`servotune.export.json`), gantry
(:mod:`servotune.export.gantry`) and linkage (:mod:`servotune.export.linkage`) documents are
written with them, so every JSON export has the same layout.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from servotune.errors import ExportError
from servotune.io.files import atomic_write_text

__all__ = ["document_text", "recorded_sha", "write_export"]

# rows of numbers on one line: a JSON list of numbers only (no string can hold a newline)
_NUM = r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?"
_NUM_LIST = re.compile(r"\[\n\s*(" + _NUM + r"(?:,\n\s*" + _NUM + r")*)\n\s*\]")


def document_text(doc: Mapping[str, Any]) -> str:
    """An export document as JSON text: sorted keys, indented, lists of numbers on one line,
    a final newline (deterministic bytes)."""
    text = json.dumps(doc, sort_keys=True, indent=2, allow_nan=False, ensure_ascii=False)
    text = _NUM_LIST.sub(lambda m: "[" + re.sub(r",\n\s*", ", ", m.group(1)) + "]", text)
    return text + "\n"


def write_export(path: str | Path, text: str) -> None:
    """Write one export file atomically; failing, an :class:`ExportError` naming the file."""
    try:
        atomic_write_text(path, text)
    except OSError as exc:
        raise ExportError(f"{path}: cannot write: {exc}") from None


def recorded_sha(record: Mapping[str, Any], kind: str) -> str | None:
    """A verification record's SHA-256 of one of its files (``files.<kind>.sha256``), or None."""
    entry = record.get("files", {}).get(kind) if isinstance(record.get("files"), dict) else None
    return entry.get("sha256") if isinstance(entry, dict) else None
