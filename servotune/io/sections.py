"""A configuration file's TOML tables built into validated dataclasses: the rig file's
(docs/formats.md#rig-file) and the architecture configurations'.

:func:`build_section` builds one validated dataclass from one TOML table (the rig's sections,
and the architecture configurations' of ``servotune.arch.gantry`` and
``servotune.arch.linkage``), errors naming ``path.field``. :func:`servotune.rig.file.load_rig`
checks the result against the model of :mod:`servotune.rig.model`; a rig file's plant table is
rewritten by :mod:`servotune.rig.edit`; the bytes and the TOML themselves are read and written
through :mod:`servotune.io.files`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import MISSING, fields
from typing import Any

from servotune.errors import RigError
from servotune.validate import check_keys, show_value

__all__ = ["build_section"]


def build_section(
    cls: type, table: Mapping[str, Any], path: str, error: type[Exception] = RigError, **fixed: Any
) -> Any:
    """Build the dataclass ``cls`` from one TOML table, errors naming ``path.field``.

    Unknown keys are refused (the message lists the allowed ones); lists become tuples;
    the dataclass's own validation message is prefixed with ``path``. Used for the rig file and
    for the architecture configurations (``servotune.arch.gantry``, ``servotune.arch.linkage``).
    """
    try:
        return _build(cls, table, path, **fixed)
    except RigError as exc:
        if error is RigError:
            raise
        raise error(str(exc)) from None


def _build(cls: type, table: Mapping[str, Any], path: str, **fixed: Any) -> Any:
    allowed = [f.name for f in fields(cls) if f.init and f.name not in fixed]
    required = [
        f.name
        for f in fields(cls)
        if f.name in allowed and f.default is MISSING and f.default_factory is MISSING
    ]
    kwargs = check_keys(table, path, required, allowed, error=RigError)
    for k, v in kwargs.items():
        for x in v if isinstance(v, list) else (v,):
            if type(x) is int and not -(2**63) <= x < 2**63:  # no field takes such a number
                raise RigError(
                    f"{path}.{k} must be a number within ±2**63 (int64), got {show_value(x)}"
                )
        if isinstance(v, list):
            kwargs[k] = tuple(v)
    try:
        return cls(**kwargs, **fixed)
    except RigError:
        raise
    except TypeError as exc:
        raise RigError(f"[{path}]: {exc}") from None
    except ValueError as exc:
        raise RigError(f"{path}.{exc}") from None
