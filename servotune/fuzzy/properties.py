"""Properties of query and rule tables: direction independence, monotonicity in ``|E|``.

The checks are exact comparisons, so they apply alike to float query tables, to scaled and
quantised int16 tables and to rule tables of set names.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike

from servotune.errors import SpecError
from servotune.fuzzy.inference import QueryTables
from servotune.fuzzy.rules import INDEX, SETS, RuleBase
from servotune.laws.fuzzy_pid import TABLE_NAMES

__all__ = [
    "check_default_properties",
    "direction_independent",
    "nondecreasing_in_abs_e",
    "nonincreasing_in_abs_e",
]


def _square_odd(table: ArrayLike, name: str = "table") -> np.ndarray:
    a = np.asarray(table)
    if a.dtype.kind in "UO":  # a rule table: set names → −3…3
        try:
            a = np.vectorize(lambda c: INDEX[c] - 3, otypes=[np.int64])(a)
        except KeyError as exc:
            raise SpecError(f"{name} holds a name not in {' '.join(SETS)}: {exc}") from exc
    if a.ndim != 2 or a.shape[0] != a.shape[1] or a.shape[0] % 2 == 0:
        raise SpecError(f"{name} must be a square table with an odd side, got shape {a.shape}")
    return a


def direction_independent(table: ArrayLike) -> bool:
    """True if ``table[−E, −EC] == table[E, EC]`` exactly, i.e. the table equals its 180° rotation.

    Parameters
    ----------
    table : array_like, shape (m, m), m odd
        A query table (float or integer, e.g. quantised int16) or a rule table of set names.

    Returns
    -------
    bool
    """
    a = _square_odd(table)
    return bool(np.array_equal(a, a[::-1, ::-1]))


def _centre_halves(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = a.shape[0] // 2
    col = a[:, c]
    return col[c:], col[c::-1]  # EC = 0 column from E = 0 outwards, positive and negative side


def _monotone_in_abs_e(table: ArrayLike, step_ok: np.ufunc) -> bool:
    """True if ``step_ok(next, previous)`` holds down the ``EC = 0`` column, outwards in |E|."""
    halves = _centre_halves(_square_odd(table))
    return all(bool(np.all(step_ok(h[1:], h[:-1]))) for h in halves)


def nondecreasing_in_abs_e(table: ArrayLike) -> bool:
    """True if the ``EC = 0`` column does not decrease as ``|E|`` grows (on both sides).

    Parameters
    ----------
    table : array_like, shape (m, m), m odd
        A query table (float or integer) or a rule table of set names.

    Returns
    -------
    bool
    """
    return _monotone_in_abs_e(table, np.greater_equal)


def nonincreasing_in_abs_e(table: ArrayLike) -> bool:
    """True if the ``EC = 0`` column does not increase as ``|E|`` grows (on both sides).

    The mirror of :func:`nondecreasing_in_abs_e` (the check ΔKi must pass), for the same
    ``table``: a query table (float or integer) or a rule table of set names, square with an odd
    side.
    """
    return _monotone_in_abs_e(table, np.less_equal)


def check_default_properties(tables: QueryTables | RuleBase | Mapping[str, ArrayLike]) -> list[str]:
    """The properties :data:`DEFAULT_RULES` promises that ``tables`` violate.

    Every table direction-independent; ΔKp not decreasing and ΔKi not increasing with ``|E|`` at
    ``EC = 0``; ΔK1 constant. All checks are exact comparisons, so they apply to float tables,
    to scaled and quantised int16 tables and to rule tables alike.

    Parameters
    ----------
    tables : QueryTables, RuleBase or mapping
        Something with the four tables ``kp``, ``ki``, ``kd``, ``k1`` (keys or attributes).

    Returns
    -------
    list of str
        One line per violated property; empty if all hold.
    """
    if isinstance(tables, QueryTables | RuleBase):
        get = {t: getattr(tables, t) for t in TABLE_NAMES}
    elif isinstance(tables, Mapping):
        missing = [t for t in TABLE_NAMES if t not in tables]
        if missing:
            raise SpecError(f"tables must hold {', '.join(TABLE_NAMES)}; missing {missing}")
        get = {t: tables[t] for t in TABLE_NAMES}
    else:
        raise SpecError(f"tables must be QueryTables, RuleBase or a mapping, got {tables!r}")
    bad = [
        f"{t} is not direction-independent"
        for t in TABLE_NAMES
        if not direction_independent(get[t])
    ]
    if not nondecreasing_in_abs_e(get["kp"]):
        bad.append("kp decreases with |E| at EC = 0")
    if not nonincreasing_in_abs_e(get["ki"]):
        bad.append("ki increases with |E| at EC = 0")
    k1 = _square_odd(get["k1"], "k1")
    if not np.all(k1 == k1.flat[0]):
        bad.append("k1 is not constant")
    return bad
