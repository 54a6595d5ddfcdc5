"""Which architecture a config file or a JSON document (tuning, plan, export) belongs to, read
from its content (the CLI's verbs take any of them and hand each to its architecture).

A file that cannot be read or parsed is reported as the single rig's (``"rig"``), whose reader
then names the problem.
"""

from __future__ import annotations

from pathlib import Path

from servotune.errors import ServotuneError
from servotune.io.files import parse_json, parse_toml, read_bytes

__all__ = ["config_kind", "document_kind"]


def _toml(path: str | Path) -> dict:
    try:
        return parse_toml(read_bytes(path, ServotuneError, "file"), str(path), ServotuneError)
    except (OSError, ServotuneError):
        return {}


def config_kind(path: str | Path) -> str:
    """``"gantry"`` (a ``[gantry]`` table), ``"linkage"`` (``[[cpu]]`` tables) or ``"rig"``."""
    data = _toml(path)
    if isinstance(data.get("gantry"), dict):
        return "gantry"
    if isinstance(data.get("cpu"), list):
        return "linkage"
    return "rig"


def document_kind(path: str | Path) -> str:
    """The architecture of a JSON document (a tuning, a plan or an export) by its schema:
    ``"gantry"`` (``servotune.gantry-…``), ``"linkage"`` (``servotune.linkage-…``), else
    ``"rig"``."""
    try:
        doc = parse_json(
            read_bytes(path, ServotuneError, "file").decode("utf-8"), str(path), ServotuneError
        )
    except (OSError, ValueError, ServotuneError):
        return "rig"
    schema = doc.get("schema") if isinstance(doc, dict) else None
    if not isinstance(schema, str):
        return "rig"
    for kind in ("gantry", "linkage"):
        if schema.startswith(f"servotune.{kind}-"):
            return kind
    return "rig"
