"""Digests: SHA-256 over files' bytes and over JSON documents' canonical form.

A JSON document's digest (the tables export, the verification record) is the SHA-256 of its
**canonical JSON**: the document without its own digest field, serialised with sorted keys,
no insignificant whitespace (``","`` and ``":"`` separators), non-ASCII characters as UTF-8
(not ``\\u`` escapes), no NaN or infinity, encoded as UTF-8. Floats are written as Python's
shortest round-trip ``repr``, so a document read back and serialised again gives the same bytes.

A text export (the LinuxCNC HAL file, the HAL component) carries its digest on one comment
line, ``<comment> sha256 of this file without this line: <hex>``: the SHA-256 of the file's
UTF-8 bytes with that line taken out (:func:`with_digest_line`, :func:`text_digest_problem`).

Threat model: accidental edits, stale files and mix-ups of rigs and tunings, not an attacker
holding the tool (there are no keys).
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Mapping
from typing import Any

__all__ = [
    "DIGEST_FIELD",
    "bytes_sha256",
    "canonical_json",
    "document_sha256",
    "text_digest_problem",
    "with_digest_line",
]

DIGEST_FIELD = "sha256"
"""The top-level field of a document that holds its own digest."""


def bytes_sha256(raw: bytes) -> str:
    """SHA-256 of bytes, lower-case hex."""
    return hashlib.sha256(raw).hexdigest()


def canonical_json(doc: Mapping[str, Any], *, omit: str = DIGEST_FIELD) -> bytes:
    """The canonical JSON bytes of ``doc`` without its top-level field ``omit``.

    Raises
    ------
    ValueError
        If the document holds NaN or infinity (JSON cannot).
    """
    body = {k: v for k, v in doc.items() if k != omit}
    text = json.dumps(
        body, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False
    )
    return text.encode("utf-8")


def document_sha256(doc: Mapping[str, Any], *, omit: str = DIGEST_FIELD) -> str:
    """SHA-256 (hex) of :func:`canonical_json` of ``doc``."""
    return bytes_sha256(canonical_json(doc, omit=omit))


_TEXT_DIGEST = " sha256 of this file without this line: "


def with_digest_line(text: str, comment: str, *, line: int = 1) -> str:
    """``text`` with its digest line inserted as line ``line`` (0-based): ``<comment> sha256 of
    this file without this line: <hex>``, the SHA-256 of ``text``'s UTF-8 bytes."""
    lines = text.splitlines(keepends=True)
    digest = bytes_sha256(text.encode("utf-8"))
    lines.insert(line, f"{comment}{_TEXT_DIGEST}{digest}\n")
    return "".join(lines)


def text_digest_problem(text: str, comment: str) -> str | None:
    """What is wrong with a text export's digest line (:func:`with_digest_line`), or ``None``
    when it matches the rest of the file."""
    pattern = re.compile(rf"^{re.escape(comment)}{_TEXT_DIGEST}([0-9a-f]{{64}})\n", re.MULTILINE)
    found = list(pattern.finditer(text))
    if len(found) != 1:
        return f"{len(found)} digest lines ('{comment}{_TEXT_DIGEST.rstrip()} …'), expected one"
    m = found[0]
    rest = text[: m.start()] + text[m.end() :]
    if bytes_sha256(rest.encode("utf-8")) != m.group(1):
        return "the file's sha256 does not match its content: it was edited after export"
    return None
