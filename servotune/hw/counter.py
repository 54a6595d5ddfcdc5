"""Up/down quadrature counter (PCL833 style): register, byte reads and the high-byte unwrap.

The card counts quadrature edges (x1, x2 or x4 per encoder pulse) into a ``bits``-wide register
that wraps modulo ``2**bits`` (absolute cyclic counting). The runtime reads it as bytes, low
first, and decides overflow from the **high byte only**
(docs/runtime.md#counter-overflow-high-byte-rule):

- high byte change 0 or ±1: no wrap;
- change −255 (0xFF → 0x00): the register wrapped upward (overflow), add ``2**bits``;
- change +255 (0x00 → 0xFF): it wrapped downward (underflow), subtract ``2**bits``;
- any other change: the motion was too large for the rule: a **counter fault**.

The rule is right for any motion of at most ``2**(bits - 8)`` counts per tick (65,536 for 24
bits) from every start phase, and fails from some phase above it.
"""

from __future__ import annotations

import numpy as np

from servotune._numba_cache import jit

__all__ = [
    "MULTIPLIERS",
    "assemble",
    "counts_from_pulses",
    "high_byte",
    "input_speed_limit_rpm",
    "max_counts_per_tick",
    "read_bytes",
    "register",
    "torn_read",
    "unwrap",
    "unwrap_speed_limit_rpm",
    "unwrap_step",
]

MULTIPLIERS = (1, 2, 4)


def _check_bits(bits: int) -> None:
    if bits not in (16, 24, 32):
        raise ValueError(f"counter bits must be 16, 24 or 32, got {bits}")


def counts_from_pulses(pulses: np.ndarray | float, multiplier: int = 4) -> np.ndarray:
    """Counts the card accumulates for an encoder position given in pulses (quadrature cycles).

    x1 counts one edge per cycle, x2 two, x4 all four; the count is ``floor(pulses * multiplier)``.

    Examples
    --------
    >>> counts_from_pulses(np.array([0.0, 0.3, 1.0, -0.1]), 4).tolist()
    [0, 1, 4, -1]
    """
    if multiplier not in MULTIPLIERS:
        raise ValueError(f"multiplier must be 1, 2 or 4, got {multiplier}")
    return np.floor(np.asarray(pulses, dtype=float) * multiplier).astype(np.int64)


def register(counts: np.ndarray | int, bits: int = 24, init: int = 0) -> np.ndarray:
    """Register value for a count (relative to power-up) with initial register ``init``.

    Examples
    --------
    >>> register(np.array([-1, 0, 1]), 24, init=0).tolist()
    [16777215, 0, 1]
    """
    _check_bits(bits)
    mask = (1 << bits) - 1
    return (np.asarray(counts, dtype=np.int64) + np.int64(init)) & np.int64(mask)


def read_bytes(reg: np.ndarray | int, bits: int = 24) -> np.ndarray:
    """Split register values into bytes, low first: shape ``(..., bits // 8)`` of uint8."""
    _check_bits(bits)
    r = np.asarray(reg, dtype=np.int64)
    shifts = np.arange(bits // 8, dtype=np.int64) * 8
    return ((r[..., None] >> shifts) & 0xFF).astype(np.uint8)


def assemble(byte_values: np.ndarray) -> np.ndarray:
    """Assemble bytes (low first, last axis) into register values (int64)."""
    b = np.asarray(byte_values, dtype=np.int64)
    shifts = np.arange(b.shape[-1], dtype=np.int64) * 8
    return np.sum(b << shifts, axis=-1)


def high_byte(reg: np.ndarray | int, bits: int = 24) -> np.ndarray:
    """The top byte of register values."""
    _check_bits(bits)
    return (np.asarray(reg, dtype=np.int64) >> (bits - 8)) & 0xFF


def torn_read(reg_at_reads: np.ndarray, bits: int = 24) -> np.ndarray:
    """Value a non-latched read returns when the register moves between byte reads.

    Parameters
    ----------
    reg_at_reads : ndarray, shape (..., bits // 8)
        Register value at the instant each byte is read, low byte first.

    Returns
    -------
    ndarray of int64
        The assembled value: byte j taken from ``reg_at_reads[..., j]``.

    Examples
    --------
    A register moving 0x00FFFF → 0x010000 between the low and the mid read:

    >>> hex(int(torn_read(np.array([0x00FFFF, 0x010000, 0x010000]))))
    '0x100ff'
    """
    r = np.asarray(reg_at_reads, dtype=np.int64)
    n = bits // 8
    if r.shape[-1] != n:
        raise ValueError(f"need {n} register values (one per byte read), got {r.shape[-1]}")
    shifts = np.arange(n, dtype=np.int64) * 8
    return np.sum(((r >> shifts) & 0xFF) << shifts, axis=-1)


@jit
def unwrap_step(raw: int, hi_prev: int, wraps: int, bits: int) -> tuple[int, int, int, bool]:
    """One runtime unwrap step (the high-byte rule); mirrored in the C runtime.

    Parameters
    ----------
    raw : int
        Register value read this tick (0 … 2**bits − 1).
    hi_prev : int
        High byte of the previous read.
    wraps : int
        Number of wraps so far (signed).
    bits : int
        Register width.

    Returns
    -------
    position : int
        Extended position ``wraps * 2**bits + raw`` [counts] (int64).
    hi : int
        High byte of this read.
    wraps : int
        Updated wrap count.
    fault : bool
        True if the high byte moved by anything other than 0, ±1 or ±255.
    """
    hi = (raw >> (bits - 8)) & 0xFF
    dh = hi - hi_prev
    fault = False
    if dh == -255:
        wraps += 1
    elif dh == 255:
        wraps -= 1
    elif dh > 1 or dh < -1:
        fault = True
    return wraps * (np.int64(1) << bits) + raw, hi, wraps, fault


@jit
def _unwrap_kernel(raw: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray]:
    n = raw.shape[0]
    pos = np.empty(n, dtype=np.int64)
    fault = np.zeros(n, dtype=np.bool_)
    if n == 0:
        return pos, fault
    hi_prev = (raw[0] >> (bits - 8)) & 0xFF
    wraps = 0
    for k in range(n):
        pos[k], hi_prev, wraps, fault[k] = unwrap_step(raw[k], hi_prev, wraps, bits)
    return pos, fault


def unwrap(raw: np.ndarray, bits: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """Unwrap a sequence of register reads with the runtime's high-byte rule.

    Parameters
    ----------
    raw : ndarray of int
        Register values, one per tick, in 0 … 2**bits − 1.
    bits : int
        Register width.

    Returns
    -------
    position : ndarray of int64
        Extended positions [counts]; the first equals ``raw[0]``.
    fault : ndarray of bool
        Ticks where the rule flagged a counter fault.

    Raises
    ------
    ValueError
        If a value is outside the register range.

    Examples
    --------
    >>> p, f = unwrap(np.array([2**24 - 2, 2**24 - 1, 0, 1]))
    >>> (p - p[0]).tolist(), f.any()
    ([0, 1, 2, 3], np.False_)
    """
    _check_bits(bits)
    r = np.asarray(raw, dtype=np.int64)
    if r.ndim != 1:
        raise ValueError(f"raw must be 1-D, got shape {r.shape}")
    if r.size and (r.min() < 0 or r.max() > (1 << bits) - 1):
        bad = int(np.argmax((r < 0) | (r > (1 << bits) - 1)))
        raise ValueError(
            f"counter value {int(r[bad])} at index {bad} is outside 0..{(1 << bits) - 1}"
        )
    return _unwrap_kernel(r, bits)


def max_counts_per_tick(bits: int = 24) -> int:
    """Largest motion per tick [counts] for which the high-byte rule is right from every phase."""
    _check_bits(bits)
    return 1 << (bits - 8)


def unwrap_speed_limit_rpm(bits: int, counts_per_rev: float, period_s: float) -> float:
    """Speed at which the motion per tick reaches :func:`max_counts_per_tick` [r/min].

    Examples
    --------
    >>> round(unwrap_speed_limit_rpm(24, 12288, 0.004000235))
    79995
    """
    return max_counts_per_tick(bits) / counts_per_rev / period_s * 60.0


def input_speed_limit_rpm(max_input_hz: float, pulses_per_rev: float) -> float:
    """Speed at which encoder pulses per channel reach the card's input-frequency limit [r/min].

    Examples
    --------
    >>> input_speed_limit_rpm(2.4e6, 3072)
    46875.0
    """
    return max_input_hz / pulses_per_rev * 60.0
