"""PI position control (the master axis of the PC dual-servo rig,
docs/systems.md#pc-dual-servo-synchronisation), integer and ideal.

Design terms: ``u = Kp·e + I``, ``I(k) = I(k−1) + Ki·T·e(k)`` (backward Euler, so the discrete
controller is ``Kp + Ki·T·z/(z−1)``), ``u`` in D/A LSB, ``e = r − y`` in counts.
At run time the period is folded into ``Ki·T``, so there is no division
(docs/runtime.md#the-period-folded-into-the-gains).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from servotune._numba_cache import jit
from servotune.fixed import F_U, Fixed, align, clamp_e, quantize, sat_add, shift_round
from servotune.validate import check_keys, show_value

__all__ = ["PIConstants", "PIGains", "pi_enter", "pi_ideal_step", "pi_step"]


@dataclass(frozen=True, slots=True, kw_only=True)
class PIGains:
    """PI gains in design units.

    Parameters
    ----------
    kp : float
        Proportional gain [codes/count].
    ki : float
        Integral gain [codes/(count·s)].
    """

    kp: float
    ki: float

    def __post_init__(self) -> None:
        for name in ("kp", "ki"):
            v = getattr(self, name)
            if not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
                unit = "codes/count" if name == "kp" else "codes/(count·s)"
                raise ValueError(
                    f"{name} must be a finite number >= 0 [{unit}], got {show_value(v)}"
                )

    def quantize(self, period_s: float) -> PIConstants:
        """Fold the period in and quantise: ``Kp`` and ``Ki·T`` as (q, f) pairs."""
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0 [s], got {show_value(period_s)}")
        return PIConstants(kp=quantize(self.kp), ki_t=quantize(self.ki * period_s))

    def to_dict(self) -> dict[str, float]:
        """Plain dict."""
        return {"ki": self.ki, "kp": self.kp}


@dataclass(frozen=True, slots=True, kw_only=True)
class PIConstants:
    """PI constants as the runtime holds them.

    Parameters
    ----------
    kp : Fixed
        Proportional gain [D/A LSB per count].
    ki_t : Fixed
        Integral gain times the period [D/A LSB per count per tick].
    """

    kp: Fixed
    ki_t: Fixed

    def to_dict(self) -> dict[str, dict[str, int]]:
        """Plain dict of (q, f) pairs."""
        return {"ki_t": self.ki_t.to_dict(), "kp": self.kp.to_dict()}

    @classmethod
    def from_dict(cls, d: dict[str, dict[str, int]]) -> PIConstants:
        """Inverse of :meth:`to_dict` (no re-quantising; exactly the keys ``kp``, ``ki_t``).

        Raises
        ------
        ValueError
            A missing or unknown key, or a malformed constant (the message names it).
        """
        d = check_keys(d, "task", ("ki_t", "kp"))
        return cls(kp=Fixed.from_dict(d["kp"]), ki_t=Fixed.from_dict(d["ki_t"]))


@jit(inline="always")
def pi_step(
    kp_q: int,
    kp_f: int,
    kit_q: int,
    kit_f: int,
    integ: int,
    e: int,
    u_add: int,
    zero: int,
    code_max: int,
) -> tuple[int, int]:
    """One PI tick in the runtime arithmetic.

    Parameters
    ----------
    kp_q, kp_f, kit_q, kit_f : int
        ``Kp`` and ``Ki·T`` as (q, f).
    integ : int
        Integrator ``I(k−1)`` [D/A LSB, F_U fraction bits].
    e : int
        Error ``r − y`` [counts] (int64; clamped here).
    u_add : int
        Term added to the output before the D/A [D/A LSB, F_U fraction bits] (excitation).
    zero, code_max : int
        D/A code of 0 V and largest code (the rails).

    Returns
    -------
    u_q : int
        Output [D/A LSB, F_U fraction bits], before the D/A.
    integ : int
        ``I(k)``: not integrated on a tick where the unclamped output is past a rail and the
        increment pushes further past it (conditional integration); clamped to the D/A span.

    Notes
    -----
    The sums saturate (docs/runtime.md#saturation-and-clamps). When ``Kp·e``, ``Ki·T·e``, ``I`` and
    ``u_add`` are all below 2**60 in magnitude, which is every tick of an ordinary loop, no sum can
    reach 2**62, so they are done as plain adds (the C runtime saturates every one; the integers are
    the same). The saturating checks cost about a fifth of a batched one-axis run.
    """
    ec = clamp_e(e)
    p_term = align(kp_q * ec, F_U - kp_f)
    d_i = align(kit_q * ec, F_U - kit_f)
    if _below_2_60(p_term) and _below_2_60(d_i) and _below_2_60(integ) and _below_2_60(u_add):
        # plain adds, the same integers (Notes; tests/laws/test_pi.py checks both paths)
        return _pi_core(_add, p_term, d_i, integ, u_add, zero, code_max)
    return _pi_core(sat_add, p_term, d_i, integ, u_add, zero, code_max)


_TWO_60 = 1 << 60


@jit(inline="always")
def _below_2_60(x: int) -> bool:
    return -_TWO_60 < x < _TWO_60


@jit(inline="always")
def _add(a: int, b: int) -> int:
    return a + b


@jit(inline="always")
def _clamp_to_span(integ: int, zero: int, code_max: int) -> int:
    """The integrator clamped to the D/A span: ``[−zero, code_max − zero]`` [LSB, F_U bits]."""
    i_max = (code_max - zero) * (1 << F_U)
    i_min = -zero * (1 << F_U)
    if integ > i_max:
        return i_max
    if integ < i_min:
        return i_min
    return integ


@jit(inline="always")
def _pi_core(
    add: Callable[[int, int], int],
    p_term: int,
    d_i: int,
    integ: int,
    u_add: int,
    zero: int,
    code_max: int,
) -> tuple[int, int]:
    """The PI tick after the products, its sums done by ``add`` (sat_add, or _add when safe).

    I is bounded by its rails (the D/A span, 2**11 * 2**32 = 2**43; for the sync law
    ±limit·2**32 < 2**63), p_term and d_i are saturated, so only the adds can overflow, and
    with ``sat_add`` they saturate.
    """
    u_pre = add(add(add(p_term, integ), d_i), u_add)
    raw = shift_round(u_pre, F_U) + zero
    if not ((raw > code_max and d_i > 0) or (raw < 0 and d_i < 0)):
        integ = _clamp_to_span(add(integ, d_i), zero, code_max)
    return add(add(p_term, integ), u_add), integ


@jit(inline="always")
def pi_enter(
    kp_q: int, kp_f: int, u_last: int, e: int, u_add: int, zero: int, code_max: int
) -> tuple[int, int]:
    """Bumpless entry into PI: ``I := (u_last − u_add) − Kp·e``, clamped to the D/A span.

    Returns ``(u_q, I)``; unless the clamp binds, ``u_q = Kp·e + I + u_add = u_last``: the first
    task output equals the previous law's last output. No integration on the entry tick.
    """
    p_term = align(kp_q * clamp_e(e), F_U - kp_f)
    integ = _clamp_to_span(sat_add(sat_add(u_last, -u_add), -p_term), zero, code_max)
    return sat_add(sat_add(p_term, integ), u_add), integ


@jit
def pi_ideal_step(kp: float, ki_t: float, integ: float, e: float) -> tuple[float, float]:
    """Ideal floating-point PI (design and comparison only): ``u = Kp·e + I(k)`` [D/A LSB]."""
    integ = integ + ki_t * e
    return kp * e + integ, integ
