"""8253/8254 programmable interval timer: divisor and achieved interrupt period.

The PIT counts down from a 16-bit divisor at ``clock_hz`` (1,193,180 Hz on the PC); a divisor
of 65536 is programmed as 0. The requested period is realised by the nearest divisor, so the
engine always runs at the *achieved* period.
"""

from __future__ import annotations

import numpy as np

from servotune.validate import show_value

__all__ = ["PC_PIT_CLOCK_HZ", "achieved_period_s", "divisor", "period_error_ppm"]

PC_PIT_CLOCK_HZ = 1_193_180.0
"""Input clock of the PC's 8253 [Hz]."""

DIVISOR_MIN = 2
DIVISOR_MAX = 65536


def divisor(period_s: float | np.ndarray, clock_hz: float = PC_PIT_CLOCK_HZ) -> np.ndarray | int:
    """Timer divisor for a requested period: round to nearest of ``clock_hz * period_s``.

    Parameters
    ----------
    period_s : float or ndarray
        Requested interrupt period [s].
    clock_hz : float
        Timer input clock [Hz].

    Returns
    -------
    int or ndarray of int64
        Divisor in 2 … 65536.

    Raises
    ------
    ValueError
        If a divisor falls outside 2 … 65536 (period too short or too long for the clock).

    Examples
    --------
    >>> divisor(0.004)
    4773
    """
    if clock_hz <= 0 or not np.isfinite(clock_hz):
        raise ValueError(f"clock_hz must be > 0 [Hz], got {show_value(clock_hz)}")
    p = np.asarray(period_s, dtype=float)
    with np.errstate(over="ignore"):  # a huge period overflows to inf, refused just below
        d = np.floor(p * clock_hz + 0.5)
    bad = ~np.isfinite(d) | (d < DIVISOR_MIN) | (d > DIVISOR_MAX)
    if np.any(bad):
        first = float(p.reshape(-1)[np.argmax(bad.reshape(-1))])
        lo, hi = DIVISOR_MIN / clock_hz, DIVISOR_MAX / clock_hz
        raise ValueError(
            f"period_s {show_value(first)} needs a timer divisor outside "
            f"{DIVISOR_MIN}..{DIVISOR_MAX}; "
            f"with clock_hz {clock_hz:g} the period must be within {lo:.3g}..{hi:.6g} s"
        )
    out = d.astype(np.int64)
    return int(out) if out.ndim == 0 else out


def achieved_period_s(
    div: int | np.ndarray, clock_hz: float = PC_PIT_CLOCK_HZ
) -> float | np.ndarray:
    """Period the timer actually produces for a divisor [s].

    Examples
    --------
    >>> round(achieved_period_s(4773) * 1e3, 6)
    4.000235
    """
    out = np.asarray(div, dtype=float) / float(clock_hz)
    return float(out) if out.ndim == 0 else out


def period_error_ppm(period_s: float, clock_hz: float = PC_PIT_CLOCK_HZ) -> float:
    """Relative error of the achieved period against the requested one [ppm].

    Examples
    --------
    >>> round(period_error_ppm(0.004), 1)
    58.7
    """
    achieved = achieved_period_s(divisor(period_s, clock_hz), clock_hz)
    return (achieved - period_s) / period_s * 1e6
