"""Resource bounds checked before allocating: the memory budget.

A request such as ``servotune simulate --seconds 1e12`` would need terabytes of trace arrays;
instead of a ``MemoryError`` (or the machine swapping), every run path estimates what it is
about to allocate and calls :func:`check_memory` first, which refuses it in one line:

    simulate 1e+12 s needs about 160 TiB (250,000,000,000,000 ticks × 2 axes × 76 bytes);
    over the memory budget of 2 GiB (--max-memory)

The budget is 2 GiB unless the environment variable ``SERVOTUNE_MAX_MEMORY`` sets it (bytes,
or with a ``K``/``M``/``G``/``T`` suffix, powers of 1024: ``512M``, ``8G``) or
:func:`set_memory_budget` does (the command line's ``--max-memory``).
"""

from __future__ import annotations

import math
import os
import re

from servotune.errors import SimulationError

__all__ = [
    "DEFAULT_MEMORY_BUDGET",
    "ENV_VAR",
    "BudgetError",
    "check_memory",
    "format_bytes",
    "format_count",
    "memory_budget",
    "parse_bytes",
    "set_memory_budget",
]

DEFAULT_MEMORY_BUDGET = 2 * 1024**3
"""Default memory budget [bytes]: 2 GiB."""

ENV_VAR = "SERVOTUNE_MAX_MEMORY"
"""Environment variable read for the budget when :func:`set_memory_budget` was not called."""

_SUFFIX = {"": 1, "K": 1024, "M": 1024**2, "G": 1024**3, "T": 1024**4}
_SIZE_RE = re.compile(r"\s*([0-9]+(?:\.[0-9]*)?)\s*([KMGT]?)(?:i?B)?\s*", re.IGNORECASE)
_MAX_BUDGET = 1024**6  # 1 EiB: anything above is a typo

_budget: int | None = None


class BudgetError(SimulationError):
    """A request would allocate more memory than the budget allows (nothing was allocated)."""


def parse_bytes(text: str, what: str = ENV_VAR) -> int:
    """Bytes from ``"2147483648"``, ``"512M"``, ``"8G"``, ``"1.5G"`` (K/M/G/T = 1024^1..4).

    Raises
    ------
    BudgetError
        If ``text`` is not such a size, or is 0.
    """
    m = _SIZE_RE.fullmatch(str(text)[:64])
    if m is None:
        raise BudgetError(
            f"{what} must be a number of bytes with an optional K, M, G or T suffix (e.g. 512M, "
            f"8G), got {str(text)[:40]!r}"
        )
    value = float(m.group(1)) * _SUFFIX[m.group(2).upper()]
    if not (math.isfinite(value) and 1 <= value <= _MAX_BUDGET):
        raise BudgetError(f"{what} must be within 1 byte .. 1 EiB, got {str(text)[:40]!r}")
    return int(value)


def set_memory_budget(nbytes: int | str | None) -> None:
    """Set the memory budget [bytes] (``None``: back to the environment / default).

    ``nbytes`` may be a string with a suffix as :func:`parse_bytes` reads it.

    Raises
    ------
    BudgetError
        If it is not a positive size.
    """
    global _budget
    if nbytes is None:
        _budget = None
        return
    if isinstance(nbytes, str):
        _budget = parse_bytes(nbytes, "--max-memory")
        return
    if isinstance(nbytes, bool) or not isinstance(nbytes, int) or not 1 <= nbytes <= _MAX_BUDGET:
        raise BudgetError(
            f"the memory budget must be an integer in 1..2**60 [bytes], got {nbytes!r}"
        )
    _budget = int(nbytes)


def memory_budget() -> int:
    """The memory budget [bytes]: :func:`set_memory_budget`, else ``$SERVOTUNE_MAX_MEMORY``,
    else :data:`DEFAULT_MEMORY_BUDGET` (2 GiB).

    Raises
    ------
    BudgetError
        If the environment variable is set but malformed.
    """
    if _budget is not None:
        return _budget
    env = os.environ.get(ENV_VAR, "").strip()
    return parse_bytes(env, ENV_VAR) if env else DEFAULT_MEMORY_BUDGET


def format_bytes(n: float) -> str:
    """Human-readable size with binary units: ``2 GiB``, ``160 TiB``, ``512 bytes``.

    Examples
    --------
    >>> format_bytes(2 * 1024**3), format_bytes(1536), format_bytes(10)
    ('2 GiB', '1.5 KiB', '10 bytes')
    """
    if n < 1024:
        return f"{n:.0f} bytes"
    for unit in ("KiB", "MiB", "GiB", "TiB", "PiB", "EiB"):
        n /= 1024.0
        if n < 1024 or unit == "EiB":
            break
    return f"{n:.3g} {unit}"


def format_count(x: float) -> str:
    """A count for a message: ``250,000,000`` (thousands separated), or ``2.5e+302`` beyond
    10**15.

    Examples
    --------
    >>> format_count(2.5e8), format_count(2.5e302)
    ('250,000,000', '2.5e+302')
    """
    return f"{x:,.0f}" if x < 1e15 else f"{x:.3g}"


def check_memory(estimate_bytes: float, what: str, detail: str = "") -> None:
    """Refuse a request whose estimated allocation exceeds the memory budget.

    Call it before allocating, with what the arrays will take.

    Parameters
    ----------
    estimate_bytes : int or float
        Estimated allocation [bytes] (a float is fine for astronomically large requests).
    what : str
        The request, for the message, e.g. ``"simulate 1e+12 s"``.
    detail : str
        How the estimate is made, e.g. ``"250,000,000,000,000 ticks × 2 axes × 76 bytes"``.

    Raises
    ------
    BudgetError
        ``"<what> needs about 160 TiB; over the memory budget of 2 GiB (--max-memory)"``.

    Examples
    --------
    >>> check_memory(1000, "a small run")
    """
    budget = memory_budget()
    est = float(estimate_bytes)
    if not (math.isfinite(est) and est <= budget):
        size = f"about {format_bytes(est)}" if math.isfinite(est) else "unbounded memory"
        how = f" ({detail})" if detail else ""
        raise BudgetError(
            f"{what} needs {size}{how}; over the memory budget of "
            f"{format_bytes(budget)} (--max-memory or ${ENV_VAR})"
        )
