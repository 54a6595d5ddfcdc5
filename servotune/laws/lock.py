"""Position-lock module (docs/systems.md#position-lock): zero-input proportional control against
analog drift.

While no task runs, the lock holds the axis at its target with ``u = Kp_lock · (target − y)``
[D/A LSB], ``Kp_lock`` in codes per count (0.4 on the example rig).
"""

from __future__ import annotations

import numpy as np

from servotune._numba_cache import jit
from servotune.fixed import F_U, Fixed, align, clamp_e, quantize, shift_round
from servotune.validate import show_value

__all__ = ["lock_holding_band", "lock_step"]


@jit(inline="always")
def lock_step(kl_q: int, kl_f: int, e: int) -> int:
    """Lock law output ``u_q`` [D/A LSB, F_U fraction bits] for error ``e`` [counts]."""
    return align(kl_q * clamp_e(e), F_U - kl_f)


def lock_holding_band(
    lock_gain: Fixed | float,
    offset_v: float,
    lsb_v: float,
    coulomb_v: float = 0.0,
    search_counts: int = 100_000,
) -> tuple[int, int]:
    """Error band [counts] in which the lock module holds an axis against a drift.

    The quantised fixed point of docs/runtime.md#position-lock-and-its-holding-band. The lock
    outputs code ``c(e) = round(Kp·e)`` (the integer law itself is evaluated); the motor sees
    ``c·LSB + offset_v`` and, being an integrator, settles only where that is within the Coulomb
    band. Where some codes hold (``|c·LSB + offset| <= coulomb``) the band is the errors that give
    one of those codes; where none does, the axis limit-cycles across the switch between the two
    codes that bracket ``-offset / LSB``, so the band is the two errors on either side of that
    switch.

    Parameters
    ----------
    lock_gain : Fixed or float
        Lock gain [codes/count] (a float is quantised as the runtime would).
    offset_v : float
        Analog zero drift [V].
    lsb_v : float
        D/A step [V].
    coulomb_v : float
        Coulomb friction as drive input [V].
    search_counts : int
        Errors searched, ±[counts].

    Returns
    -------
    (low, high) : tuple of int
        Band of ``e = target − y`` [counts].

    Examples
    --------
    The example rig's 5 mV drift, 0.4 codes/count, 4.88 mV LSB: held within 4 counts (±1 pulse).

    >>> lock_holding_band(0.4, 0.005, 20 / 4096)
    (-4, -3)
    """
    k = lock_gain if isinstance(lock_gain, Fixed) else quantize(lock_gain)
    e = np.arange(-search_counts, search_counts + 1, dtype=np.int64)
    codes = _lock_codes(k.q, k.f, e)
    net_v = codes * lsb_v + offset_v
    hold = np.abs(net_v) <= coulomb_v
    if np.any(hold):
        held = e[hold]
        # the block of holding errors nearest zero error
        i0 = int(np.argmin(np.abs(held)))
        lo = hi = i0
        while lo > 0 and held[lo - 1] == held[lo] - 1:
            lo -= 1
        while hi < held.size - 1 and held[hi + 1] == held[hi] + 1:
            hi += 1
        return int(held[lo]), int(held[hi])
    # no code holds: the switch where the net drive changes sign
    pos = net_v > 0
    if pos.all() or not pos.any():
        raise ValueError(
            f"the lock cannot cancel offset_v={show_value(offset_v)} V within ±{search_counts} "
            f"counts"
        )
    i = int(np.argmax(pos))  # first error whose code drives the motor positive
    return int(e[i - 1]), int(e[i])


@jit
def _lock_codes(kl_q: int, kl_f: int, e: np.ndarray) -> np.ndarray:
    out = np.empty(e.shape[0], dtype=np.int64)
    for i in range(e.shape[0]):
        out[i] = shift_round(lock_step(kl_q, kl_f, e[i]), F_U)
    return out
