"""Digests: SHA-256 over files' bytes and over JSON documents' canonical form.

A JSON document's digest (the tables export, the verification record) is the SHA-256 of its
**canonical JSON**: the document without its own digest field, serialised with sorted keys,
no insignificant whitespace (``","`` and ``":"`` separators), non-ASCII characters as UTF-8
(not ``\\u`` escapes), no NaN or infinity, encoded as UTF-8. Floats are written as Python's
shortest round-trip ``repr``, so a document read back and serialised again gives the same bytes.

Threat model: accidental edits, stale files and mix-ups of rigs and tunings, not an attacker
holding the tool (there are no keys).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

__all__ = ["DIGEST_FIELD", "bytes_sha256", "canonical_json", "document_sha256"]

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
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False,
                      allow_nan=False)  # fmt: skip
    return text.encode("utf-8")


def document_sha256(doc: Mapping[str, Any], *, omit: str = DIGEST_FIELD) -> str:
    """SHA-256 (hex) of :func:`canonical_json` of ``doc``."""
    return bytes_sha256(canonical_json(doc, omit=omit))
