"""Reading a gantry config (:func:`load_gantry`). Gains the file leaves out stay unset: the
caller resolves them (:func:`servotune.arch.gantry.synthesis.resolve_gains`), a loader only
loads."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from servotune.arch.gantry.config import GantryConfig, gantry_from_dict
from servotune.errors import ConfigError
from servotune.io.files import parse_toml_as, read_bytes

__all__ = ["load_gantry"]


def load_gantry(path: str | Path, *, raw: bytes | None = None) -> GantryConfig:
    """Read a gantry config (TOML, e.g. ``plants/gantry.toml``).

    Parameters
    ----------
    path : str or Path
    raw : bytes, optional
        The file's bytes as the caller already read them (and hashed them): parsed instead of
        reading ``path`` again (which still names the file and anchors its rig path).

    Raises
    ------
    ConfigError
        If the file is missing, not TOML, or invalid (the message names the field).
    """
    p = Path(path)
    if raw is None:
        raw = read_bytes(p, ConfigError, "gantry config")
    cfg = parse_toml_as(
        raw, str(p), ConfigError, "gantry config", lambda d: gantry_from_dict(d, base_dir=p.parent)
    )
    cfg = replace(cfg, name=cfg.name if cfg.name != "gantry" else p.stem.removesuffix(".sync"))
    return cfg
