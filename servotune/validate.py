"""Field checks shared by the data objects' ``__post_init__`` (rig, architectures, logs).

Every message names the field, the rule, the unit and the value, e.g.
``"period_s must be a number > 0 [s], got -0.004"`` or
``"latency_cycles must be an integer in 1..1000 [cycles], got 1e9"``. Numbers must be ``int``
or ``float`` (a ``bool`` or a string is not a number), finite, and within the bounds; integers
must be exact ``int`` values (``24.0`` and ``"24"`` are not integers). Values too long to show
are shortened in the message (a 10**400 integer does not flood the terminal). Unknown keys are
refused with the allowed ones and the closest of them (``did you mean 'period_s'?``).

Why hand-written checks and not pydantic v2 or msgspec (a library was the first choice;
msgspec 0.22 was tried on the tuning format): both give exact types, enumerations, unknown-key
refusal and bounds, but their messages (``Expected `int`, got `float` - at `$.k.q` ``) carry
neither the unit nor the allowed range in our words nor a did-you-mean, so every field would
need a second, hand-written message anyway; the file kinds are already read into frozen
dataclasses (``Rig``, ``Plant``, ``Tuning``, ``Spec``, ``GantryConfig`` …) whose
``__post_init__`` is the one place their invariants live, and a library model beside each
would be a second home for the same schema; and it would add a compiled dependency for
checks that cost microseconds. The bounds on the bytes themselves (file size, nesting depth,
number and string length, NaN/Infinity, the BOM) live in :mod:`servotune.logs`
(``parse_json``, ``parse_toml``, ``read_bytes``), the one reader of each text format.
"""

from __future__ import annotations

import difflib
import math
import operator
from collections.abc import Mapping, Sequence
from typing import Any

__all__ = [
    "SEED_MAX",
    "check_integer",
    "check_keys",
    "check_number",
    "check_seed",
    "check_strings",
    "check_table",
    "is_finite",
    "is_number",
    "name_and_description",
    "show_number",
    "show_share",
    "show_value",
]

_SHOW_CHARS = 40

SEED_MAX = 2**64 - 1
"""Largest seed anywhere (a run's, a Monte Carlo's, the CLI's ``--seed``): every random
stream takes a seed of 64 bits."""


def is_number(v: object) -> bool:
    """True for an int or float that is not a bool."""
    return isinstance(v, int | float) and not isinstance(v, bool)


def show_value(v: object, limit: int = _SHOW_CHARS) -> str:
    """``repr(v)`` for a message, at most about ``limit`` characters.

    Huge integers are shown by their number of digits (their ``repr`` may even be refused by
    Python's integer-string limit); long strings and other values are cut with ``…``.

    Examples
    --------
    >>> show_value(10**400)
    'an integer of 401 digits'
    >>> show_value("x" * 100, limit=10)
    "'xxxxxxxx…"
    """
    if isinstance(v, int) and not isinstance(v, bool) and v.bit_length() > 128:
        return f"an integer of {len(str(abs(v))) if v.bit_length() < 14000 else 'over 4000'} digits"
    try:
        text = repr(v)
    except ValueError:  # e.g. the int-to-str digit limit
        return f"a {type(v).__name__}"
    return text if len(text) <= limit else text[: limit - 1] + "…"


def show_share(p: float) -> str:
    """A share in [0, 1] as a percentage (no unit) with one decimal, or as many more (up to six)
    as a share strictly between 0 and 1 needs not to print as ``0.0`` or ``100.0``: 99,996 of
    99,999 runs passing is not "100.0 %".

    Examples
    --------
    >>> show_share(63 / 64), show_share(1.0), show_share(99_996 / 99_999), show_share(2e-5)
    ('98.4', '100.0', '99.997', '0.002')
    """
    x = 100.0 * p
    d = 1
    while 0.0 < p < 1.0 and d < 7 and float(f"{x:.{d}f}") in (0.0, 100.0):
        d += 1
    return f"{x:.{d}f}"


def show_number(x: float | None, digits: int = 4) -> str:
    """A number for a table or a message: ``digits`` significant digits, exponent form when
    very large or small; ``n/a`` for None, ``never`` for +inf.

    Examples
    --------
    >>> show_number(0.0123456), show_number(123456.0), show_number(None), show_number(math.inf)
    ('0.01235', '1.235e+05', 'n/a', 'never')
    """
    if x is None:
        return "n/a"
    if math.isinf(x):
        return "never" if x > 0 else "-inf"
    if math.isnan(x):
        return "nan"
    if x == 0:
        return "0"
    if abs(x) >= 1e5 or abs(x) < 1e-3:
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits}g}"


def is_finite(v: object) -> bool:
    """``math.isfinite(v)``, False where it cannot say (an int beyond the float range)."""
    try:
        return math.isfinite(v)  # type: ignore[arg-type]
    except OverflowError:  # an int beyond the float range
        return False


def check_number(
    name: str,
    v: object,
    unit: str,
    *,
    strict: bool = False,
    lo: float = 0.0,
    hi: float | None = None,
    hi_strict: bool = False,
    error: type[Exception] = ValueError,
) -> None:
    """Raise ``error`` unless ``v`` is a finite number within the bounds.

    Parameters
    ----------
    name : str
        Field name for the message (e.g. ``"timer.period_s"``).
    v : object
        The value.
    unit : str
        Unit for the message (``"s"``, ``"V"``, ``"-"``).
    lo : float
        Lower bound; ``v >= lo`` (``v > lo`` if ``strict``). ``-math.inf`` for none.
    strict : bool
        Exclude ``lo``.
    hi : float, optional
        Upper bound; ``v <= hi`` (``v < hi`` if ``hi_strict``).
    hi_strict : bool
        Exclude ``hi``.
    error : type of Exception
        What to raise.

    Raises
    ------
    error
        ``"<name> must be a number > 0 [s], got -0.004"`` (with ``hi``:
        ``"<name> must be a number in (0, 1] [s], got 10"``).
    """
    ok = is_number(v) and is_finite(v)
    if ok:
        x = float(v)  # type: ignore[arg-type]
        ok = (x > lo if strict else x >= lo) and (hi is None or (x < hi if hi_strict else x <= hi))
    if not ok:
        if hi is None:
            rule = f"{'>' if strict else '>='} {lo:g}"
        elif lo == -math.inf:
            rule = f"{'<' if hi_strict else '<='} {hi:g}"
        else:
            rule = f"in {'(' if strict else '['}{lo:g}, {hi:g}{')' if hi_strict else ']'}"
        raise error(f"{name} must be a number {rule} [{unit}], got {show_value(v)}")


def check_integer(
    name: str,
    v: object,
    unit: str,
    *,
    lo: int = 0,
    hi: int | None = None,
    error: type[Exception] = ValueError,
) -> None:
    """Raise ``error`` unless ``v`` is an ``int`` (not a bool, not ``24.0``) in ``lo..hi``.

    Raises
    ------
    error
        ``"<name> must be an integer >= 1 [cycles], got 0"`` (with ``hi``:
        ``"<name> must be an integer in 1..1000 [cycles], got 1000000000.0"``).
    """
    if type(v) is not int or v < lo or (hi is not None and v > hi):
        rule = f">= {lo}" if hi is None else f"in {lo}..{hi}"
        raise error(f"{name} must be an integer {rule} [{unit}], got {show_value(v)}")


def check_seed(seed: object, name: str = "seed", *, error: type[Exception] = ValueError) -> int:
    """``seed`` as an ``int`` in ``0..SEED_MAX`` (an ``int`` or a numpy integer; not a bool,
    not ``1.5``), else ``error``: ``"seed must be an integer in 0..18446744073709551615 [-],
    got -1"`` (numpy's own refusals, ``expected non-negative integer`` or ``Python integer -1
    out of bounds for uint64``, named no seed; a float was silently truncated)."""
    try:
        value = None if isinstance(seed, bool) else operator.index(seed)  # type: ignore[arg-type]
    except TypeError:
        value = None
    if value is None or not 0 <= value <= SEED_MAX:
        raise error(f"{name} must be an integer in 0..{SEED_MAX} [-], got {show_value(seed)}")
    return value


def check_keys(
    d: object,
    path: str,
    required: Sequence[str],
    optional: Sequence[str] = (),
    *,
    error: type[Exception] = ValueError,
    noun: str = "key",
) -> dict[str, Any]:
    """Check that ``d`` is a table with every ``required`` key and no key outside
    ``required`` + ``optional``; return it as a dict.

    Parameters
    ----------
    d : object
        The parsed table (JSON object, TOML table).
    path : str
        Its dotted path for the messages (``"task.tables"``; ``""`` for the top level).
    required, optional : sequence of str
        Keys that must be there, and keys that may be.
    error : type of Exception
        What to raise.

    Raises
    ------
    error
        ``"task must be a table, got list"``, ``"missing key task.kp"`` or
        ``"unknown key task.kq (allowed: ki_t, kp)"``.
    """
    where = path or "the top level"
    if not isinstance(d, Mapping):
        raise error(f"{where} must be a table, got {type(d).__name__}")
    prefix = f"{path}." if path else ""
    allowed = set(required) | set(optional)
    unknown = sorted((k for k in d if k not in allowed), key=str)
    if unknown:  # before the missing ones: a misspelt required key is named as the typo
        k = unknown[0]
        name = k if isinstance(k, str) and len(k) <= _SHOW_CHARS else show_value(k)
        near = difflib.get_close_matches(str(k), sorted(allowed), n=1) if len(str(k)) < 64 else []
        hint = f"; did you mean {near[0]!r}?" if near else ""
        listed = ", ".join(sorted(allowed)) or "none"
        raise error(f"unknown {noun} {prefix}{name} (allowed: {listed}){hint}")
    missing = [k for k in required if k not in d]
    if missing:
        raise error(f"missing {noun} {prefix}{missing[0]}")
    return dict(d)


def check_strings(
    d: Mapping[str, Any], path: str, keys: Sequence[str], *, error: type[Exception] = ValueError
) -> None:
    """Raise ``error`` unless each of ``keys`` present in the table ``d`` is a string.

    Raises
    ------
    error
        ``"rig.name must be a string, got 3"`` (``path`` ``""``: ``"name must be ..."``).
    """
    prefix = f"{path}." if path else ""
    for k in keys:
        if k in d and not isinstance(d[k], str):
            raise error(f"{prefix}{k} must be a string, got {show_value(d[k])}")


def name_and_description(
    d: Mapping[str, Any], path: str, default_name: str, *, error: type[Exception] = ValueError
) -> dict[str, str]:
    """A file's ``name`` (default ``default_name``) and ``description`` (default ``""``), each
    checked to be a string (:func:`check_strings`): keywords for the dataclass it describes."""
    check_strings(d, path, ("name", "description"), error=error)
    return {"name": str(d.get("name", default_name)), "description": str(d.get("description", ""))}


def check_table(
    data: Mapping[str, Any],
    key: str,
    *,
    error: type[Exception] = ValueError,
    required: bool = True,
    path: str | None = None,
) -> Mapping[str, Any]:
    """The table ``data[key]`` of a parsed file (TOML); ``{}`` if it is absent and not
    ``required``. The messages name it ``[path]`` (default: ``[key]``).

    Raises
    ------
    error
        ``"missing table [bus]"`` or ``"[bus] must be a table, got list"``.
    """
    where = key if path is None else path
    if key not in data:
        if required:
            raise error(f"missing table [{where}]")
        return {}
    t = data[key]
    if not isinstance(t, Mapping):
        raise error(f"[{where}] must be a table, got {type(t).__name__}")
    return t
