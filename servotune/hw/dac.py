"""12-bit D/A converter (PCL728 style), offset-binary coding
(docs/runtime.md#da-quantisation).

LSB = span / 2**bits; the code for 0 V is ``zero_code`` (2048 for ±10 V, 12 bits); rails are
code 0 (−10 V) and code 4095 (+9.99512 V). Volts are coded by round-half-away-from-zero.
"""

from __future__ import annotations

import numpy as np

from servotune._numba_cache import jit
from servotune.fixed import round_half_away, shift_round
from servotune.validate import show_value

__all__ = ["code_from_uq", "code_from_volts", "lsb_v", "volts_from_code", "zero_code"]


def lsb_v(bits: int = 12, range_v: tuple[float, float] = (-10.0, 10.0)) -> float:
    """One D/A step [V].

    Examples
    --------
    >>> round(lsb_v() * 1e3, 5)
    4.88281
    """
    lo, hi = range_v
    return (hi - lo) / 2**bits


def zero_code(bits: int = 12, range_v: tuple[float, float] = (-10.0, 10.0)) -> int:
    """Code that outputs 0 V (mid-scale for a bipolar range).

    Raises
    ------
    ValueError
        If 0 V is not inside the range or not exactly on a code.
    """
    lo, _hi = range_v
    z = -lo / lsb_v(bits, range_v)
    if not (0 <= z < 2**bits) or z != np.floor(z):
        raise ValueError(
            f"range_v {show_value(range_v)} has no code for exactly 0 V with {bits} bits"
        )
    return int(z)


def code_from_volts(
    volts: np.ndarray | float, bits: int = 12, range_v: tuple[float, float] = (-10.0, 10.0)
) -> np.ndarray:
    """D/A codes for requested volts: ``clamp(round_half_away(u / LSB) + zero, 0, 2**bits - 1)``.

    Parameters
    ----------
    volts : float or ndarray
        Requested output [V].

    Returns
    -------
    ndarray of int64

    Examples
    --------
    >>> code_from_volts(np.array([-20.0, -10.0, 0.0, 10.0, 20.0])).tolist()
    [0, 0, 2048, 4095, 4095]
    """
    u = np.asarray(volts, dtype=float)
    if not np.all(np.isfinite(u)):
        raise ValueError("volts must be finite")
    c = round_half_away(u / lsb_v(bits, range_v)) + zero_code(bits, range_v)
    return np.clip(c, 0, 2**bits - 1).astype(np.int64)


def volts_from_code(
    code: np.ndarray | int, bits: int = 12, range_v: tuple[float, float] = (-10.0, 10.0)
) -> np.ndarray:
    """Output volts of D/A codes [V].

    Examples
    --------
    >>> volts_from_code(np.array([0, 2048, 4095])).round(5).tolist()
    [-10.0, 0.0, 9.99512]
    """
    c = np.asarray(code, dtype=np.int64)
    if np.any((c < 0) | (c > 2**bits - 1)):
        raise ValueError(f"D/A code out of range 0..{2**bits - 1}")
    return range_v[0] + c * lsb_v(bits, range_v)


@jit
def code_from_uq(u_q: int, f_u: int, zero: int, code_max: int) -> int:
    """Runtime coding: ``clamp(shift_round(u_q, f_u) + zero, 0, code_max)``, u_q in LSB."""
    c = shift_round(u_q, f_u) + zero
    if c < 0:
        return 0
    if c > code_max:
        return code_max
    return c
