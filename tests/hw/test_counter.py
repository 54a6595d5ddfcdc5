"""Tests for servotune.hw.counter: PCL833 register, byte reads and the high-byte unwrap."""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from servotune.hw.counter import (
    MULTIPLIERS,
    assemble,
    counts_from_pulses,
    high_byte,
    input_speed_limit_rpm,
    max_counts_per_tick,
    read_bytes,
    register,
    torn_read,
    unwrap,
    unwrap_speed_limit_rpm,
    unwrap_step,
)

# docs/runtime.md#counter-overflow-high-byte-rule: PCL833, 24-bit up/down counters, absolute cyclic
# counting (wraps modulo 2**24)
TOP24 = 2**24 - 1
# counter.py docstring / docs/runtime.md#counter-overflow-high-byte-rule: the high-byte rule holds
# for motions up to 2**(24-8) counts
LIMIT24 = 65_536
PHASES = 2**16  # phases of the low 16 bits relative to a high-byte boundary (24-bit register)

# ---------------------------------------------------------------------------------------------
# register and unwrap at the wrap edges
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("bits", [16, 24, 32])
def test_register_wraps_at_its_edges(bits):
    top = 2**bits - 1
    # computed by hand: the register is counts + init modulo 2**bits
    assert_array_equal(register(np.array([-1, 0, 1]), bits, init=0), [top, 0, 1])
    assert_array_equal(register(np.array([-1, 0, 1, 2]), bits, init=top), [top - 1, top, 0, 1])
    # one full turn of the register returns to the same value
    assert_array_equal(register(np.array([2**bits, -(2**bits)]), bits, init=5), [5, 5])


def test_register_forward_then_reverse_step_over_the_wrap():
    # 2**24 − 1 → 0 (forward step), then 0 → 2**24 − 1 (reverse step)
    counts = np.array([0, 1, 0, 1, 2, 1, 0, -1])
    reg = register(counts, 24, init=TOP24)
    assert_array_equal(reg, [TOP24, 0, TOP24, 0, 1, 0, TOP24, TOP24 - 1])
    pos, fault = unwrap(reg)
    assert_array_equal(pos - pos[0], counts)
    assert not fault.any()


@pytest.mark.parametrize("bits", [16, 24, 32])
@pytest.mark.parametrize("direction", [1, -1])
def test_unwrap_continuous_across_the_wrap(bits, direction):
    # ±1000 counts around the wrap in steps of 37 counts (< max_counts_per_tick for all widths)
    counts = direction * np.arange(-1000, 1001, 37)
    reg = register(counts, bits, init=0)
    assert reg.min() >= 0
    assert reg.max() <= 2**bits - 1
    assert (np.diff(reg) * direction < 0).any()  # the sequence really crosses the wrap
    pos, fault = unwrap(reg, bits)
    assert pos.dtype == np.int64
    assert pos[0] == reg[0]  # documented: the first position equals raw[0]
    assert_array_equal(pos - pos[0], counts - counts[0])
    assert not fault.any()


def test_unwrap_many_turns_both_ways():
    # 5 register turns up then back down, 40,000 counts per tick (< 65,536)
    up = np.arange(0, 5 * 2**24, 40_000)
    counts = np.concatenate([up, up[::-1]])
    pos, fault = unwrap(register(counts, 24, init=123))
    assert_array_equal(pos - pos[0], counts)
    assert not fault.any()


def test_unwrap_empty():
    pos, fault = unwrap(np.array([], dtype=np.int64))
    assert pos.shape == (0,)
    assert fault.shape == (0,)


# ---------------------------------------------------------------------------------------------
# x1 / x2 / x4 quadrature multiplication
# ---------------------------------------------------------------------------------------------

PULSES = np.array([-1.0, -0.75, -0.5, -0.25, -0.1, 0.0, 0.1, 0.25, 0.5, 0.75, 1.0, 2.6])


@pytest.mark.parametrize(
    ("multiplier", "expected"),
    [
        # computed by hand: floor(pulses · multiplier), floor also for negative pulses
        (1, [-1, -1, -1, -1, -1, 0, 0, 0, 0, 0, 1, 2]),
        (2, [-2, -2, -1, -1, -1, 0, 0, 0, 1, 1, 2, 5]),
        (4, [-4, -3, -2, -1, -1, 0, 0, 1, 2, 3, 4, 10]),
    ],
)
def test_counts_from_pulses_floor(multiplier, expected):
    counts = counts_from_pulses(PULSES, multiplier)
    assert counts.dtype == np.int64
    assert_array_equal(counts, expected)


def test_counts_from_pulses_default_is_x4():
    assert MULTIPLIERS == (1, 2, 4)
    assert_array_equal(counts_from_pulses(PULSES), counts_from_pulses(PULSES, 4))


@pytest.mark.parametrize("multiplier", [0, 3, 8, -4])
def test_counts_from_pulses_bad_multiplier(multiplier):
    with pytest.raises(ValueError, match="multiplier"):
        counts_from_pulses(PULSES, multiplier)


# ---------------------------------------------------------------------------------------------
# byte reads
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("bits", "value", "low_first"),
    [
        # computed by hand: bytes of the value, low byte first
        (16, 0, [0x00, 0x00]),
        (16, 0xFF, [0xFF, 0x00]),
        (16, 0x100, [0x00, 0x01]),
        (16, 0xFFFF, [0xFF, 0xFF]),
        (24, 0, [0x00, 0x00, 0x00]),
        (24, 0xFF, [0xFF, 0x00, 0x00]),
        (24, 0xFFFF, [0xFF, 0xFF, 0x00]),
        (24, 0x10000, [0x00, 0x00, 0x01]),
        (24, 0xFFFFFF, [0xFF, 0xFF, 0xFF]),
        (32, 0, [0x00, 0x00, 0x00, 0x00]),
        (32, 0xFF, [0xFF, 0x00, 0x00, 0x00]),
        (32, 0xFFFF, [0xFF, 0xFF, 0x00, 0x00]),
        (32, 0xFFFFFF, [0xFF, 0xFF, 0xFF, 0x00]),
        (32, 0x1000000, [0x00, 0x00, 0x00, 0x01]),
        (32, 0xFFFFFFFF, [0xFF, 0xFF, 0xFF, 0xFF]),
    ],
)
def test_read_bytes_assemble_round_trip(bits, value, low_first):
    b = read_bytes(value, bits)
    assert b.dtype == np.uint8
    assert_array_equal(b, low_first)
    assert int(assemble(b)) == value


@pytest.mark.parametrize("bits", [16, 24, 32])
def test_read_bytes_assemble_round_trip_vectorised(bits):
    rng = np.random.default_rng(833)
    top = 2**bits - 1
    values = np.concatenate([[0, 1, 0xFF, 0x100, top - 1, top], rng.integers(0, top + 1, 1000)])
    b = read_bytes(values, bits)
    assert b.shape == (values.size, bits // 8)
    assert_array_equal(assemble(b), values)


@pytest.mark.parametrize(
    ("bits", "value", "expected"),
    [
        # computed by hand: value >> (bits − 8)
        (16, 0x00FF, 0x00),
        (16, 0x0100, 0x01),
        (16, 0xFFFF, 0xFF),
        (24, 0x00FFFF, 0x00),
        (24, 0x010000, 0x01),
        (24, 0xFEFFFF, 0xFE),
        (24, 0xFF0000, 0xFF),
        (24, 0xFFFFFF, 0xFF),
        (32, 0x00FFFFFF, 0x00),
        (32, 0x01000000, 0x01),
        (32, 0xFFFFFFFF, 0xFF),
    ],
)
def test_high_byte(bits, value, expected):
    assert int(high_byte(value, bits)) == expected
    assert int(high_byte(value, bits)) == int(read_bytes(value, bits)[-1])


@pytest.mark.parametrize("bits", [0, 8, 12, 20, 64])
def test_bad_bits_raise(bits):
    with pytest.raises(ValueError, match="bits"):
        register(np.array([0]), bits)
    with pytest.raises(ValueError, match="bits"):
        read_bytes(0, bits)
    with pytest.raises(ValueError, match="bits"):
        high_byte(0, bits)
    with pytest.raises(ValueError, match="bits"):
        unwrap(np.array([0, 1]), bits)
    with pytest.raises(ValueError, match="bits"):
        max_counts_per_tick(bits)


# ---------------------------------------------------------------------------------------------
# non-latched (torn) reads
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("at_reads", "torn"),
    [
        # computed by hand: byte j of the value at read j (low, mid, high)
        # 0x00FFFF → 0x010000 between low and mid read: low FF, mid 00, high 01
        ([0x00FFFF, 0x010000, 0x010000], 0x0100FF),
        # 0x00FFFF → 0x010000 between mid and high read: low FF, mid FF, high 01
        ([0x00FFFF, 0x00FFFF, 0x010000], 0x01FFFF),
        # downward 0x010000 → 0x00FFFF between low and mid read: low 00, mid FF, high 00
        ([0x010000, 0x00FFFF, 0x00FFFF], 0x00FF00),
        # at the wrap, 0xFFFFFF → 0x000000 between low and mid read: low FF, mid 00, high 00
        ([0xFFFFFF, 0x000000, 0x000000], 0x0000FF),
        # at the wrap, between mid and high read: low FF, mid FF, high 00
        ([0xFFFFFF, 0xFFFFFF, 0x000000], 0x00FFFF),
    ],
)
def test_torn_read_crossing_a_byte_boundary(at_reads, torn):
    assert int(torn_read(np.array(at_reads))) == torn


def test_torn_read_error_sizes():
    # computed by hand: one count of motion (0x00FFFF → 0x010000) torn between the low and mid
    # read gives 0x0100FF, 255 counts past the new value; torn between mid and high read gives
    # 0x01FFFF, 65,535 counts past it: far more than the one count the register moved
    new = 0x010000
    assert int(torn_read(np.array([0x00FFFF, new, new]))) - new == 255
    assert int(torn_read(np.array([0x00FFFF, 0x00FFFF, new]))) - new == 65_535


@pytest.mark.parametrize("bits", [16, 24, 32])
def test_torn_read_exact_when_register_does_not_move(bits):
    top = 2**bits - 1
    values = np.array([0, 0xFF, 0x100, 0xFFFF, top // 2, top - 1, top]) & top
    at_reads = np.repeat(values[:, None], bits // 8, axis=1)
    assert_array_equal(torn_read(at_reads, bits), values)


def test_torn_read_needs_one_value_per_byte():
    with pytest.raises(ValueError, match="3"):
        torn_read(np.array([0x00FFFF, 0x010000]), 24)


# ---------------------------------------------------------------------------------------------
# unwrap input validation and faults
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("raw", "index"),
    [
        ([0, 1, -1, 2], 2),
        ([0, 2**24, 1], 1),
        ([TOP24 + 1], 0),
        ([5, 6, 7, -(2**40)], 3),
    ],
)
def test_unwrap_rejects_values_outside_the_register(raw, index):
    with pytest.raises(ValueError, match=rf"index {index}\b"):
        unwrap(np.array(raw))


def test_unwrap_accepts_the_register_edges():
    pos, fault = unwrap(np.array([0, TOP24, 0]))
    assert_array_equal(pos - pos[0], [0, -1, 0])
    assert not fault.any()


def test_unwrap_rejects_2d():
    with pytest.raises(ValueError, match="1-D"):
        unwrap(np.zeros((2, 2), dtype=np.int64))


@pytest.mark.parametrize(
    "raw",
    [
        # computed by hand: high byte steps of +2, −2, −254 (0xFF → 0x01), +254 (0x01 → 0xFF)
        [0x000000, 0x000000, 0x020000, 0x020000],
        [0x020000, 0x020000, 0x000000, 0x000000],
        [0xFF0000, 0xFF0000, 0x010000, 0x010000],
        [0x01FFFF, 0x01FFFF, 0xFF0000, 0xFF0000],
        # a genuine high-byte jump of 2 from the very top of a byte: 0x00FFFF → 0x020000
        [0x00FFFF, 0x00FFFF, 0x020000, 0x020000],
    ],
)
def test_unwrap_flags_a_high_byte_jump_of_2_at_that_index(raw):
    _pos, fault = unwrap(np.array(raw))
    assert_array_equal(fault, [False, False, True, False])


def test_unwrap_high_byte_change_of_one_is_not_a_fault():
    # computed by hand: 0x000000 → 0x01FFFF is 131,071 counts but the high byte moves by 1 only,
    # so the rule accepts it and the motion is still exact (true motion < 2 · 2**16)
    pos, fault = unwrap(np.array([0x000000, 0x01FFFF]))
    assert pos[1] - pos[0] == 0x01FFFF
    assert not fault.any()


# ---------------------------------------------------------------------------------------------
# Acceptance: the unwrap limit sweep (motion per tick past max_counts_per_tick, every phase)
# ---------------------------------------------------------------------------------------------


@nb.njit(cache=False)
def _runtime_motion(start, end, bits):
    """Motion from ``start`` to ``end`` as the runtime's ``unwrap_step`` sees it, per pair.

    Initialised like the runtime: the high byte of the first read, zero wraps.
    """
    n = start.shape[0]
    motion = np.empty(n, dtype=np.int64)
    fault = np.empty(n, dtype=np.bool_)
    for i in range(n):
        hi0 = (start[i] >> (bits - 8)) & 0xFF
        p0, hi, w, _f0 = unwrap_step(start[i], hi0, 0, bits)
        p1, _hi, _w, f1 = unwrap_step(end[i], hi, w, bits)
        motion[i] = p1 - p0
        fault[i] = f1
    return motion, fault


def _sweep(start_ext: np.ndarray, d: int, direction: int):
    """Run one tick of true motion ``direction * d`` from each extended start position."""
    true = direction * d
    start = register(start_ext, 24)
    end = register(start_ext + true, 24)
    motion, fault = _runtime_motion(start, end, 24)
    # the public unwrap on interleaved pairs goes through the same unwrap_step: the step at
    # every odd index depends only on that pair (its previous high byte is the pair's start)
    pos, fault_u = unwrap(np.stack([start, end], axis=1).reshape(-1))
    assert_array_equal(pos[1::2] - pos[0::2], motion)
    assert_array_equal(fault_u[1::2], fault)
    # the true number of high-byte boundaries crossed (extended arithmetic, by hand)
    crossings = np.abs((start_ext + true) // PHASES - start_ext // PHASES)
    return motion, fault, true, crossings


def _crossing_starts(d: int, direction: int) -> np.ndarray:
    """Every extended start from which a tick of ``d`` counts crosses the 2**24 wrap."""
    j = np.arange(1, d + 1, dtype=np.int64)
    # up: start 2**24 − j reaches 2**24 − j + d >= 2**24; down: start j − 1 reaches j − 1 − d < 0
    return 2**24 - j if direction > 0 else j - 1


def test_max_counts_per_tick():
    # counter.py docstring: the rule is right up to 2**(bits − 8) counts per tick
    assert max_counts_per_tick(16) == 256
    assert max_counts_per_tick(24) == LIMIT24
    assert max_counts_per_tick() == LIMIT24
    assert max_counts_per_tick(32) == 2**24


@pytest.mark.parametrize("direction", [1, -1], ids=["overflow", "underflow"])
@pytest.mark.parametrize("d", [1, 255, 256, 4096, 65_535, 65_536])
def test_unwrap_limit_sweep_exact_up_to_the_limit(d, direction):
    # Ticks that cross the wrap: every start 2**24 − j (up) or j − 1 (down), j = 1 … d.
    starts = _crossing_starts(d, direction)
    motion, fault, true, _ = _sweep(starts, d, direction)
    assert not fault.any()
    assert_array_equal(motion, np.full(d, true))

    # Every one of the 65,536 phases of the low 16 bits, from a start whose high byte is 0xFF
    # (ticks from here cross the wrap upward when phase + d >= 2**16) and 0x00 (they cross it
    # downward when phase < d), and from the middle of the register (no wrap at all).
    phase = np.arange(PHASES, dtype=np.int64)
    for base in (0xFF0000, 0x000000, 0x7F0000):
        starts = base + phase
        motion, fault, true, _ = _sweep(starts, d, direction)
        assert not fault.any()
        assert_array_equal(motion, np.full(PHASES, true))


@pytest.mark.parametrize("direction", [1, -1], ids=["overflow", "underflow"])
@pytest.mark.parametrize("d", [65_537, 70_000, 100_000, 131_071, 131_072])
def test_unwrap_limit_sweep_faults_just_above_the_limit(d, direction):
    # Above 2**16 counts per tick the high byte can move by 2: the rule must flag it (from the
    # phases where it does) and must still be exact from the others; never silently wrong here.
    for starts in (
        _crossing_starts(d, direction),
        0xFF0000 + np.arange(PHASES, dtype=np.int64),
        0x7F0000 + np.arange(PHASES, dtype=np.int64),
    ):
        motion, fault, true, crossings = _sweep(starts, d, direction)
        # computed by hand: a fault exactly where the tick crosses two high-byte boundaries
        assert_array_equal(fault, crossings >= 2)
        assert_array_equal(motion[~fault], true)
    # from the crossing window (all 65,536 phases covered since d > 2**16) at least one fault
    _motion, fault, _true, _ = _sweep(_crossing_starts(d, direction), d, direction)
    assert fault.any()
    # computed by hand: 2**16 < d < 2**17 faults from 2**16·(d/2**16 − 1) = d − 2**16 phases of
    # every 2**16; d = 2**17 always moves the high byte by exactly 2 → always a fault
    phase_faults = _sweep(0x7F0000 + np.arange(PHASES), d, direction)[1].sum()
    assert phase_faults == min(d - PHASES, PHASES)


def test_unwrap_limit_at_65537_faults_from_exactly_one_phase():
    # computed by hand: 65,537 counts up cross two boundaries only from phase 0xFFFF
    starts = 0xFF0000 + np.arange(PHASES, dtype=np.int64)
    motion, fault, true, _ = _sweep(starts, 65_537, 1)
    assert_array_equal(np.flatnonzero(fault), [0xFFFF])
    assert_array_equal(motion[:-1], true)


# ---------------------------------------------------------------------------------------------
# speed limits
# ---------------------------------------------------------------------------------------------


def test_unwrap_speed_limit_example_rig():
    # computed by hand: 65,536 counts/tick / 12,288 counts/rev = 16/3 rev per tick;
    # 16/3 / 0.004000235 s · 60 = 79,995.30 r/min (the example rig: 3072 pulses/rev, x4, 4.000235
    # ms)
    assert_allclose(unwrap_speed_limit_rpm(24, 12288, 0.004000235), 79_995.30, rtol=0, atol=0.01)


def test_input_speed_limit_example_rig():
    # the PCL833's max 2.4 MHz input; computed by hand: 2.4e6 / 3072 · 60 = 46,875 r/min
    assert_allclose(input_speed_limit_rpm(2.4e6, 3072), 46_875.0, rtol=0, atol=1e-9)


def test_input_limit_binds_first_on_the_example_rig():
    # the example rig: 3072 pulses/rev at x4 → 12,288 counts/rev; 4773 / 1,193,180 s per tick
    period_s = 4773 / 1_193_180
    v_in = input_speed_limit_rpm(2.4e6, 3072)
    v_unwrap = unwrap_speed_limit_rpm(24, 3072 * 4, period_s)
    assert v_in < v_unwrap
    # computed by hand: at 46,875 r/min the motion is 781.25 · 12,288 · 0.0040002347
    # = 38,402 counts per tick, well inside the 65,536 the unwrap rule allows
    counts_per_tick = v_in / 60.0 * 3072 * 4 * period_s
    assert_allclose(counts_per_tick, 38_402.25, rtol=0, atol=0.01)
    assert counts_per_tick < max_counts_per_tick(24)
