"""Runtime fixed-point arithmetic (docs/runtime.md#fixed-point-constants): the one quantiser and the
integer primitives.

Every design constant that reaches the runtime is turned into a pair ``(q, f)`` by
:func:`quantize`: ``q`` a signed integer, ``f`` its fraction bits, value ``q * 2**-f``.

The rule for choosing ``f`` (the only one in servotune):

    f is the largest integer in [0, f_max] such that round_half_away(x * 2**f) fits the signed
    integer type of ``bits`` bits, excluding its most negative value (|q| <= 2**(bits-1) - 1).
    For an array (a table) one ``f`` is shared by all entries.

Rounding is round half away from zero everywhere (here, in the laws and in the C runtime).
Gains use ``bits=32`` and ``f_max = F_U`` so that every product ``q * e`` aligns to the output's
fraction bits ``F_U`` by an exact multiplication by ``2**(F_U - f)``; tables use ``bits=16`` and
``f_max`` = the fraction bits of the gain they adjust.

The integer primitives below are compiled with numba (no fast-math) and mirrored line by line in
the C runtime. None of them right-shifts a negative value (implementation-defined in C99) or
left-shifts one (undefined in C99).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from servotune._numba_cache import jit
from servotune.validate import show_value

__all__ = [
    "E_MAX",
    "F_U",
    "INT64_MAX",
    "Fixed",
    "align",
    "clamp_e",
    "quantize",
    "quantize_table",
    "round_half_away",
    "sat_add",
    "shift_round",
]

F_U = 32
"""Fraction bits of the law output ``u_q`` [D/A LSB] and of the integrator."""

INT64_MAX = np.int64(2**63 - 1)
E_MAX = np.int64(2**31 - 1)
"""Errors, error changes and reference changes are clamped to ±E_MAX before any product."""


def round_half_away(x: np.ndarray | float) -> np.ndarray | float:
    """Round to the nearest integer, ties away from zero.

    Parameters
    ----------
    x : float or ndarray
        Values to round.

    Returns
    -------
    float or ndarray
        Rounded values (float dtype).

    Examples
    --------
    >>> round_half_away(np.array([-2.5, -0.5, 0.5, 1.5, 2.4]))
    array([-3., -1.,  1.,  2.,  2.])
    """
    return np.sign(x) * np.floor(np.abs(x) + 0.5)


@dataclass(frozen=True, slots=True, kw_only=True)
class Fixed:
    """A quantised constant, value ``q * 2**-f``.

    Parameters
    ----------
    q : int
        Signed integer mantissa.
    f : int
        Fraction bits (>= 0).
    bits : int
        Width of the integer type holding ``q`` (16 or 32).
    """

    q: int
    f: int
    bits: int = 32

    def __post_init__(self) -> None:
        if self.bits not in (16, 32):
            raise ValueError(f"bits must be 16 or 32, got {self.bits}")
        if not 0 <= self.f <= 62:
            raise ValueError(f"f must be in 0..62 fraction bits, got {show_value(self.f)}")
        lim = 2 ** (self.bits - 1) - 1
        if not -lim <= self.q <= lim:
            raise ValueError(f"q must fit int{self.bits} (|q| <= {lim}), got {show_value(self.q)}")

    @property
    def value(self) -> float:
        """The represented value ``q * 2**-f``."""
        return float(self.q) * 2.0 ** (-self.f)

    def to_dict(self) -> dict[str, int]:
        """Plain dict ``{"q": q, "f": f}`` for JSON."""
        return {"f": int(self.f), "q": int(self.q)}

    @classmethod
    def from_dict(cls, d: object, *, bits: int = 32, f_max: int = F_U) -> Fixed:
        """Inverse of :meth:`to_dict`: integers only, ``f <= f_max`` (no re-quantising).

        Raises
        ------
        ValueError
            If ``d`` is not ``{"q": int, "f": int}`` or a value is out of range.
        """
        if not isinstance(d, dict) or set(d) != {"q", "f"}:
            raise ValueError(
                f"a fixed-point constant must be {{'q': int, 'f': int}}, got {show_value(d)}"
            )
        q, f = d["q"], d["f"]
        if type(q) is not int or type(f) is not int:
            raise ValueError(f"q and f must be integers, got q={show_value(q)}, f={show_value(f)}")
        if f > f_max:
            raise ValueError(f"f must be <= {f_max} fraction bits, got {f}")
        return cls(q=q, f=f, bits=bits)


def _choose_f(xmax: float, bits: int, f_max: int) -> int:
    lim = 2 ** (bits - 1) - 1
    for f in range(f_max, -1, -1):
        if round_half_away(xmax * 2.0**f) <= lim:
            return f
    raise ValueError(
        f"value {show_value(xmax)} does not fit a {bits}-bit fixed-point number even with 0 "
        f"fraction bits"
    )


def quantize(x: float, *, bits: int = 32, f_max: int = F_U) -> Fixed:
    """Quantise one design constant to ``(q, f)`` by the rule in the module docstring.

    Parameters
    ----------
    x : float
        The constant (finite).
    bits : int
        Integer width of ``q`` (32 for gains, 16 for table entries).
    f_max : int
        Largest fraction bits allowed (default ``F_U`` so products align to the output exactly).

    Returns
    -------
    Fixed

    Raises
    ------
    ValueError
        If ``x`` is not finite or does not fit with ``f = 0``.

    Examples
    --------
    >>> k = quantize(0.4)
    >>> (k.q, k.f)
    (1717986918, 32)
    >>> quantize(3.0e6).f
    9
    """
    x = float(x)
    if not np.isfinite(x):
        raise ValueError(f"cannot quantise a non-finite value, got {show_value(x)}")
    f = _choose_f(abs(x), bits, f_max)
    return Fixed(q=int(round_half_away(x * 2.0**f)), f=f, bits=bits)


def quantize_table(x: np.ndarray, *, f_max: int, bits: int = 16) -> tuple[np.ndarray, int]:
    """Quantise a table of constants with one shared ``f`` (same rule as :func:`quantize`).

    Parameters
    ----------
    x : ndarray
        Finite table values.
    f_max : int
        Largest fraction bits allowed: the fraction bits of the base gain the table adjusts.
    bits : int
        Integer width of the entries (16 by default).

    Returns
    -------
    q : ndarray of int16 or int32
    f : int
    """
    x = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(x)):
        raise ValueError("cannot quantise a table with non-finite entries")
    f = _choose_f(float(np.max(np.abs(x))) if x.size else 0.0, bits, f_max)
    q = round_half_away(x * 2.0**f).astype(np.int16 if bits == 16 else np.int32)
    return q, f


# --- integer primitives (numba; mirrored in the C runtime) ----------------------------------


@jit
def shift_round(x: int, f: int) -> int:
    """``x * 2**-f`` rounded half away from zero, for f >= 1 and x > INT64_MIN.

    Never right-shifts a negative value: the magnitude is rounded and the sign restored.
    Written without a branch (``s`` is 0 or −1, ``(x ^ s) − s`` the magnitude): the sign of a
    filter's rounding remainder is as good as random, and a mispredicted branch cost more than
    the whole rounding (docs/runtime.md#rounding; the C runtime's st_shift_round gives the same
    integers).
    """
    s = -np.int64(x < 0)
    m = (x ^ s) - s
    return (((m >> f) + ((m >> (f - 1)) & 1)) ^ s) - s


@jit
def sat_add(a: int, b: int) -> int:
    """``a + b`` saturated to ±INT64_MAX (the most negative value is never produced)."""
    if b > 0 and a > INT64_MAX - b:
        return INT64_MAX
    if b < 0 and a < -INT64_MAX - b:
        return -INT64_MAX
    s = a + b
    if s < -INT64_MAX:
        return -INT64_MAX
    return s


@jit
def align(x: int, k: int) -> int:
    """``x * 2**k`` for k >= 0, saturated to ±INT64_MAX; exact when it fits (no shift of x)."""
    if k == 0:
        return x
    lim = INT64_MAX >> k
    if x > lim:
        return INT64_MAX
    if x < -lim:
        return -INT64_MAX
    return x * (np.int64(1) << k)


@jit
def clamp_e(x: int) -> int:
    """Clamp an error, error change or reference change to ±(2**31 - 1) before a product."""
    if x > E_MAX:
        return E_MAX
    if x < -E_MAX:
        return -E_MAX
    return x
