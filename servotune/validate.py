"""Field checks shared by the data objects' ``__post_init__`` (rig, architectures).

Every message names the field, the rule, the unit and the value, e.g.
``"period_s must be a number > 0 [s], got -0.004"``.
"""

from __future__ import annotations

import math

__all__ = ["check_integer", "check_number", "is_number"]


def is_number(v: object) -> bool:
    """True for an int or float that is not a bool."""
    return isinstance(v, int | float) and not isinstance(v, bool)


def check_number(
    name: str,
    v: object,
    unit: str,
    *,
    lo: float = 0.0,
    strict: bool = False,
    error: type[Exception] = ValueError,
) -> None:
    """Raise ``error`` unless ``v`` is a finite number ``>= lo`` (``> lo`` if ``strict``)."""
    ok = is_number(v) and math.isfinite(v) and (v > lo if strict else v >= lo)  # type: ignore[arg-type,operator]
    if not ok:
        rel = ">" if strict else ">="
        raise error(f"{name} must be a number {rel} {lo:g} [{unit}], got {v!r}")


def check_integer(
    name: str, v: object, unit: str, *, lo: int = 0, error: type[Exception] = ValueError
) -> None:
    """Raise ``error`` unless ``v`` is an int (not a bool) ``>= lo``."""
    if type(v) is not int or v < lo:
        raise error(f"{name} must be an integer >= {lo} [{unit}], got {v!r}")
