"""The runtime's per-axis tick: counter read and unwrap, modes, faults, and the task law.

Positions are int64 counts relative to each axis's first read (its power-up home).
A controller tick (engine, C runtime) first calls :func:`axis_read` for every axis (so a slave
can use its master's position read in the same tick), then :func:`axis_control` for every axis.
State and constants are small int64 arrays whose layouts (the ``S_*`` and ``C_*`` indices) are
shared with the C runtime's structs.

Modes (``MODE_*``): *lock* (the position-lock module holds the lock target), *task* (the task
law follows the reference), *open* (the output is the additive command alone, for open-loop
experiments). Switches are bumpless (SPEC §6): entering a task sets ``I := u_last − Kp·e`` and
``e_prev := e``, ``r_prev := r``; leaving it latches the lock target at the current position.
Faults (counter fault, following-error trip) latch: the code goes to 0 V until a reset.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from servotune.fixed import F_U, Fixed, align, quantize, sat_add, shift_round
from servotune.hw.counter import unwrap_step
from servotune.laws.lock import lock_step
from servotune.laws.pi import PIConstants, pi_enter, pi_step

__all__ = [
    "FLAG_COUNTER_FAULT",
    "FLAG_FOLLOWING_ERROR",
    "FLAG_SATURATED",
    "LAW_NONE",
    "LAW_PI",
    "MODE_LOCK",
    "MODE_OPEN",
    "MODE_TASK",
    "AxisController",
    "axis_control",
    "axis_read",
]

# modes
MODE_LOCK = 0
MODE_TASK = 1
MODE_OPEN = 2
MODE_NAMES = ("lock", "task", "open")

# task laws
LAW_NONE = 0
LAW_PI = 1

# flags (faults latch; SATURATED is per tick)
FLAG_COUNTER_FAULT = 1
FLAG_FOLLOWING_ERROR = 2
FLAG_SATURATED = 4
FAULT_MASK = FLAG_COUNTER_FAULT | FLAG_FOLLOWING_ERROR

# state layout (int64)
S_INIT = 0
S_HI_PREV = 1
S_WRAPS = 2
S_Y = 3
S_MODE = 4
S_FAULT = 5
S_LOCK_TARGET = 6
S_INTEG = 7
S_U_LAST = 8
S_E_PREV = 9
S_R_PREV = 10
S_ORIGIN = 11
N_STATE = 12

# constants layout (int64)
C_LAW = 0
C_LOCK_Q = 1
C_LOCK_F = 2
C_KP_Q = 3
C_KP_F = 4
C_KIT_Q = 5
C_KIT_F = 6
C_FE_LIMIT = 7
C_COUNTER_BITS = 8
C_DAC_ZERO = 9
C_DAC_MAX = 10
N_CONST = 16


@dataclass(frozen=True, slots=True, kw_only=True)
class AxisController:
    """What the runtime holds for one axis, every constant quantised.

    Parameters
    ----------
    lock_gain : Fixed
        Position-lock gain [D/A LSB per count].
    pi : PIConstants or None
        Task law (PI); None for an axis that only locks or runs open loop.
    following_error_limit_counts : int
        Trip threshold on |e| [counts]; 0 disables it.
    """

    lock_gain: Fixed
    pi: PIConstants | None = None
    following_error_limit_counts: int = 0

    def __post_init__(self) -> None:
        if self.following_error_limit_counts < 0:
            raise ValueError(
                "following_error_limit_counts must be >= 0 [counts], "
                f"got {self.following_error_limit_counts}"
            )

    @classmethod
    def from_gains(
        cls,
        *,
        lock_gain_codes_per_count: float,
        pi_gains: object | None = None,
        period_s: float,
        following_error_limit_counts: int = 0,
    ) -> AxisController:
        """Quantise design gains (``pi_gains`` a :class:`~servotune.laws.pi.PIGains`)."""
        return cls(
            lock_gain=quantize(lock_gain_codes_per_count),
            pi=None if pi_gains is None else pi_gains.quantize(period_s),  # type: ignore[attr-defined]
            following_error_limit_counts=int(following_error_limit_counts),
        )

    def consts(self, *, counter_bits: int, dac_bits: int, dac_zero: int) -> np.ndarray:
        """The constants vector (``C_*`` layout) the tick functions read."""
        c = np.zeros(N_CONST, dtype=np.int64)
        c[C_LAW] = LAW_NONE if self.pi is None else LAW_PI
        c[C_LOCK_Q], c[C_LOCK_F] = self.lock_gain.q, self.lock_gain.f
        if self.pi is not None:
            c[C_KP_Q], c[C_KP_F] = self.pi.kp.q, self.pi.kp.f
            c[C_KIT_Q], c[C_KIT_F] = self.pi.ki_t.q, self.pi.ki_t.f
        c[C_FE_LIMIT] = self.following_error_limit_counts
        c[C_COUNTER_BITS] = counter_bits
        c[C_DAC_ZERO] = dac_zero
        c[C_DAC_MAX] = 2**dac_bits - 1
        return c


@nb.njit(cache=True, inline="always")
def axis_read(st: np.ndarray, c: np.ndarray, a: int, raw: int, reset: bool) -> int:
    """Read one axis's counter: unwrap with the high-byte rule, flag a counter fault.

    Parameters
    ----------
    st : ndarray of int64, shape (axes, N_STATE)
        Axis states (``S_*`` layout), row ``a`` updated in place.
    c : ndarray of int64, shape (axes, N_CONST)
        Axis constants (``C_*`` layout).
    a : int
        The axis (row).
    raw : int
        Register value assembled from the byte reads.
    reset : bool
        Re-initialise the unwrap from this read (after a fault reset).

    Returns
    -------
    int
        Extended position [counts], relative to the first read (the power-up home), so every
        axis's positions and references share one frame.
    """
    bits = c[a, C_COUNTER_BITS]
    if st[a, S_INIT] == 0:
        st[a, S_ORIGIN] = raw
        st[a, S_WRAPS] = 0
        st[a, S_LOCK_TARGET] = 0
        st[a, S_R_PREV] = 0
        st[a, S_INIT] = 1
        reset = True
    if reset:
        st[a, S_HI_PREV] = (raw >> (bits - 8)) & 0xFF
        y = st[a, S_WRAPS] * (np.int64(1) << bits) + raw - st[a, S_ORIGIN]
        st[a, S_Y] = y
        return y
    ext, hi, wraps, fault = unwrap_step(raw, st[a, S_HI_PREV], st[a, S_WRAPS], bits)
    st[a, S_HI_PREV] = hi
    st[a, S_WRAPS] = wraps
    if fault:
        st[a, S_FAULT] |= FLAG_COUNTER_FAULT
    y = ext - st[a, S_ORIGIN]
    st[a, S_Y] = y
    return y


@nb.njit(cache=True, inline="always")
def axis_control(
    st: np.ndarray, c: np.ndarray, a: int, ref: int, mode_cmd: int, reset: bool, u_add: int
) -> tuple[int, int, int]:
    """One axis's control step after :func:`axis_read`.

    Parameters
    ----------
    st, c : ndarray of int64
        Axis states (row ``a`` updated in place) and constants, as in :func:`axis_read`.
    a : int
        The axis (row).
    ref : int
        Task reference this tick [counts, extended].
    mode_cmd : int
        Requested mode (``MODE_LOCK``, ``MODE_TASK``, ``MODE_OPEN``).
    reset : bool
        Clear latched faults; the axis returns to lock at its current position.
    u_add : int
        Command added to the output [D/A codes] (excitation; the whole output in open mode).

    Returns
    -------
    code : int
        D/A code to write.
    flags : int
        ``FLAG_*`` bits: latched faults, and ``FLAG_SATURATED`` if the output hit a rail.
    e : int
        The law's error this tick [counts] (0 in open mode or under a fault).
    """
    zero = c[a, C_DAC_ZERO]
    cmax = c[a, C_DAC_MAX]
    y = st[a, S_Y]
    if reset:
        st[a, S_FAULT] = 0
        st[a, S_MODE] = MODE_LOCK
        st[a, S_LOCK_TARGET] = y
        st[a, S_INTEG] = 0
        st[a, S_U_LAST] = 0
        st[a, S_E_PREV] = 0
        st[a, S_R_PREV] = ref
    if st[a, S_FAULT] != 0:
        st[a, S_U_LAST] = 0
        return zero, st[a, S_FAULT], 0
    if mode_cmd == MODE_TASK and c[a, C_LAW] == LAW_NONE:
        mode_cmd = MODE_LOCK  # no task law: the lock keeps the axis
    entering = mode_cmd == MODE_TASK and st[a, S_MODE] != MODE_TASK
    if mode_cmd == MODE_LOCK and st[a, S_MODE] != MODE_LOCK:
        st[a, S_LOCK_TARGET] = y
    st[a, S_MODE] = mode_cmd
    u_add_q = align(u_add, F_U)
    e = 0
    if mode_cmd == MODE_LOCK:
        e = st[a, S_LOCK_TARGET] - y
        u = sat_add(lock_step(c[a, C_LOCK_Q], c[a, C_LOCK_F], e), u_add_q)
    elif mode_cmd == MODE_TASK:
        e = ref - y
        if entering:
            u, st[a, S_INTEG] = pi_enter(
                c[a, C_KP_Q], c[a, C_KP_F], st[a, S_U_LAST], e, u_add_q, zero, cmax
            )
        else:
            u, st[a, S_INTEG] = pi_step(
                c[a, C_KP_Q],
                c[a, C_KP_F],
                c[a, C_KIT_Q],
                c[a, C_KIT_F],
                st[a, S_INTEG],
                e,
                u_add_q,
                zero,
                cmax,
            )
    else:
        u = u_add_q
    fe = c[a, C_FE_LIMIT]
    if fe > 0 and (e > fe or e < -fe):
        st[a, S_FAULT] |= FLAG_FOLLOWING_ERROR
        st[a, S_U_LAST] = 0
        return zero, st[a, S_FAULT], e
    st[a, S_U_LAST] = u
    st[a, S_E_PREV] = e
    st[a, S_R_PREV] = ref
    code = shift_round(u, F_U) + zero  # code_from_uq, with the rail flag on the way
    flags = st[a, S_FAULT]
    if code > cmax:
        code = cmax
        flags |= FLAG_SATURATED
    elif code < 0:
        code = 0
        flags |= FLAG_SATURATED
    return code, flags, e
