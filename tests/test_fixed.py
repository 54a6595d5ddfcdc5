"""Tests for servotune.fixed: the one quantiser and the integer primitives
(docs/runtime.md#fixed-point-constants)."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from servotune.fixed import (
    E_MAX,
    F_U,
    INT64_MAX,
    Fixed,
    align,
    clamp_e,
    quantize,
    quantize_table,
    round_half_away,
    sat_add,
    shift_round,
)

IMAX = 2**63 - 1  # INT64_MAX as a Python int
IMIN = -(2**63)  # INT64_MIN, never produced by the saturating primitives
# docs/runtime.md#fixed-point-constants: |q| <= 2**(bits−1) − 1, the most negative value excluded
LIM32 = 2**31 - 1
LIM16 = 2**15 - 1


def _rha(x: Fraction) -> int:
    """Exact round half away from zero of a rational (Python integers)."""
    m = math.floor(abs(x) + Fraction(1, 2))
    return m if x >= 0 else -m


def test_constants():
    # docs/runtime.md: f_u = 32 fraction bits; clamp to ±(2**31 − 1); saturation at ±INT64_MAX
    assert F_U == 32
    assert int(E_MAX) == 2**31 - 1
    assert int(INT64_MAX) == IMAX


@pytest.mark.parametrize(
    ("x", "expected"),
    [
        (-2.5, -3.0),
        (-1.5, -2.0),
        (-0.5, -1.0),
        (-0.49, 0.0),
        (0.0, 0.0),
        (0.49, 0.0),
        (0.5, 1.0),
        (1.5, 2.0),
        (2.5, 3.0),  # half-even would give 2
        (2.4, 2.0),
        (2.6, 3.0),
    ],
)
def test_round_half_away(x, expected):
    # docs/runtime.md#rounding: one rounding, half away from zero
    assert round_half_away(x) == expected
    assert_array_equal(round_half_away(np.array([x])), [expected])


# ---------------------------------------------------------------------------------------------
# the quantiser
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("x", "q", "f"),
    [
        # the lock's Kp = 0.4; fixed.py docstring: 0.4 → (1717986918, 32)
        # computed by hand: 0.4 · 2**32 = 1,717,986,918.4 → 1,717,986,918 <= 2**31 − 1
        (0.4, 1_717_986_918, 32),
        # computed by hand: 3e6 · 2**9 = 1.536e9 fits, 3e6 · 2**10 = 3.07e9 does not
        (3.0e6, 1_536_000_000, 9),
        # a power of two: 0.5 · 2**32 = 2**31 > 2**31 − 1 → f = 31, q = 2**30
        (0.5, 2**30, 31),
        # just below 0.5: (2**31 − 1) / 2**32 is the largest value with f = 32
        ((2**31 - 1) / 2**32, 2**31 - 1, 32),
        # (2**31 − 1.5) / 2**32 → rounds to 2**31 − 1: still f = 32
        ((2**31 - 1.5) / 2**32, 2**31 - 1, 32),
        # (2**31 − 0.5) / 2**32 → rounds (half away) to 2**31: too big → f = 31,
        # q = round(2**30 − 0.25) = 2**30
        ((2**31 - 0.5) / 2**32, 2**30, 31),
        # just above 0.5 → f = 31, q = round(2**30 + 2**-9) = 2**30
        (0.5 + 2.0**-40, 2**30, 31),
        # 1.0 = 2**0: f = 30, q = 2**30; just below: 1 − 2**-30 → 2**31 − 2 at f = 31
        (1.0, 2**30, 30),
        (1.0 - 2.0**-30, 2**31 - 2, 31),
        (1.0 + 2.0**-29, 2**30 + 2, 30),
        # 1024 = 2**10: f = 20, q = 2**30
        (1024.0, 2**30, 20),
        # a tie at f = 32: (2k + 1) / 2**33 rounds away to k + 1
        (5 / 2**33, 3, 32),
        # zero and tiny values get f_max
        (0.0, 0, 32),
        (1e-12, 0, 32),  # 1e-12 · 2**32 = 0.0043 → 0
        # the largest integer that fits with f = 0
        (float(2**31 - 1), 2**31 - 1, 0),
        (2.0**30, 2**30, 0),
    ],
)
def test_quantize_rule(x, q, f):
    k = quantize(x)
    assert isinstance(k, Fixed)
    assert (k.q, k.f, k.bits) == (q, f, 32)
    # negative values are symmetric
    kn = quantize(-x)
    assert (kn.q, kn.f) == (-q, f)
    # the rule itself: q fits, and one more fraction bit would not (unless f = f_max)
    assert abs(k.q) <= LIM32
    if f < F_U:
        assert abs(_rha(Fraction(x) * 2 ** (f + 1))) > LIM32
    assert k.q == _rha(Fraction(x) * 2**f)


def test_quantize_value_and_dict():
    k = quantize(0.4)
    # computed by hand: |q · 2**-32 − 0.4| <= 2**-33
    assert_allclose(k.value, 0.4, rtol=0, atol=2.0**-33)
    assert k.to_dict() == {"f": 32, "q": 1_717_986_918}


@pytest.mark.parametrize(
    ("x", "f_max", "q", "f"),
    [
        # computed by hand: 0.4 · 2**16 = 26,214.4 <= 32,767; 0.4 · 2**17 = 52,428.8 > 32,767
        (0.4, 32, 26_214, 16),
        (0.4, 10, 410, 10),  # f_max binds: 0.4 · 1024 = 409.6 → 410
        (0.5, 32, 2**14, 15),  # 0.5 · 2**16 = 32,768 > 32,767
        ((2**15 - 1) / 2**16, 32, 2**15 - 1, 16),
        (32_767.0, 32, 32_767, 0),
        (-32_767.0, 32, -32_767, 0),
        (0.0, 7, 0, 7),
    ],
)
def test_quantize_16_bit(x, f_max, q, f):
    k = quantize(x, bits=16, f_max=f_max)
    assert (k.q, k.f, k.bits) == (q, f, 16)


@pytest.mark.parametrize("f_max", [0, 1, 8, 20, 32])
def test_quantize_respects_f_max(f_max):
    # computed by hand: 1e-6 needs f >= 20 to be nonzero; it fits for every f <= 52
    k = quantize(1e-6, f_max=f_max)
    assert k.f == f_max
    assert k.q == _rha(Fraction(1e-6) * 2**f_max)


@pytest.mark.parametrize(
    ("x", "bits"),
    [
        # too large even with f = 0 (|q| <= 2**(bits−1) − 1)
        (2.0**31, 32),
        (-(2.0**31), 32),  # the most negative int32 is excluded
        (2**31 - 0.5, 32),  # rounds half away to 2**31
        (1e12, 32),
        (32_768.0, 16),
        (-32_768.0, 16),
        (32_767.5, 16),
    ],
)
def test_quantize_too_large_raises(x, bits):
    with pytest.raises(ValueError, match="does not fit"):
        quantize(x, bits=bits)


@pytest.mark.parametrize("x", [math.nan, math.inf, -math.inf])
def test_quantize_non_finite_raises(x):
    with pytest.raises(ValueError, match="non-finite"):
        quantize(x)
    with pytest.raises(ValueError, match="non-finite"):
        quantize_table(np.array([0.1, x]), f_max=12)


def test_quantize_table_shares_one_f():
    x = np.array([0.1, -0.4, 0.25, 0.0])
    # computed by hand: max |x| = 0.4 → 16-bit f = 16 (0.4 · 2**16 = 26,214.4);
    # 0.1 · 2**16 = 6553.6 → 6554; 0.25 · 2**16 = 16,384
    q, f = quantize_table(x, f_max=20)
    assert f == 16
    assert q.dtype == np.int16
    assert_array_equal(q, [6554, -26_214, 16_384, 0])
    # each entry alone would get more fraction bits: the table's f is the shared one
    assert quantize(0.1, bits=16, f_max=20).f == 18
    assert f == min(quantize(float(v), bits=16, f_max=20).f for v in x)


def test_quantize_table_respects_f_max():
    # computed by hand: f_max = 12 binds; 0.1 · 4096 = 409.6 → 410, 0.4 · 4096 = 1638.4 → 1638
    q, f = quantize_table(np.array([0.1, -0.4, 0.25]), f_max=12)
    assert f == 12
    assert_array_equal(q, [410, -1638, 1024])


def test_quantize_table_ties_and_2d():
    # computed by hand: ±1.5 and ±2.5 units of 2**-12 round half away to ±2 and ±3
    x = np.array([[1.5, -1.5], [2.5, -2.5]]) / 4096
    q, f = quantize_table(x, f_max=12)
    assert f == 12
    assert q.shape == (2, 2)
    assert_array_equal(q, [[2, -2], [3, -3]])


def test_quantize_table_32_bit_and_limits():
    q, f = quantize_table(np.array([0.4, -0.2]), f_max=32, bits=32)
    assert q.dtype == np.int32
    assert (f, int(q[0]), int(q[1])) == (32, 1_717_986_918, -858_993_459)
    # the largest int16 entry fits with f = 0; one more does not
    q, f = quantize_table(np.array([32_767.0, -32_767.0]), f_max=4)
    assert f == 0
    assert_array_equal(q, [32_767, -32_767])
    with pytest.raises(ValueError, match="does not fit"):
        quantize_table(np.array([1.0, -32_768.0]), f_max=4)


@pytest.mark.parametrize(
    "kwargs",
    [{"q": 0, "f": 0, "bits": 8}, {"q": 0, "f": -1}, {"q": 0, "f": 63}, {"q": 2**31, "f": 0}],
)
def test_fixed_validation(kwargs):
    with pytest.raises(ValueError):
        Fixed(**kwargs)


# ---------------------------------------------------------------------------------------------
# integer primitives (numba, mirrored in the C runtime)
# ---------------------------------------------------------------------------------------------


def _shift_round_cases() -> list[tuple[int, int]]:
    rng = np.random.default_rng(6)
    cases: list[tuple[int, int]] = []
    for f in range(1, 63):
        # edges: 0, ±1, ±INT64_MAX, ±(INT64_MAX − 1), ±2**62 and neighbours, ties around them
        for x in (0, 1, IMAX, IMAX - 1, 2**62, 2**62 - 1, 2**62 + 1, 2 ** (f - 1), 2**f - 1):
            cases += [(x, f), (-x, f)]
        # exact ties: (2k + 1) · 2**(f − 1), both signs, up to the int64 range
        kmax = (IMAX - 2 ** (f - 1)) // 2**f
        for k in rng.integers(0, kmax, 40, dtype=np.int64, endpoint=True):
            x = (2 * int(k) + 1) * 2 ** (f - 1)
            cases += [(x, f), (-x, f)]
        # one either side of a tie
        k = int(rng.integers(0, kmax, dtype=np.int64))
        tie = (2 * k + 1) * 2 ** (f - 1)
        cases += [(tie - 1, f), (tie + 1, f), (-tie + 1, f), (-tie - 1, f)]
        # random values over the whole range and small values
        for x in rng.integers(-IMAX, IMAX, 80, dtype=np.int64, endpoint=True):
            cases.append((int(x), f))
        for x in rng.integers(-(2**20), 2**20, 40, dtype=np.int64, endpoint=True):
            cases.append((int(x), f))
    return cases


def test_shift_round_is_exact_round_half_away():
    # docs/runtime.md#rounding: shift_round(x, f) = round half away from zero of x / 2**f, f >= 1, x
    # > INT64_MIN
    cases = _shift_round_cases()
    assert all(-IMAX <= x <= IMAX for x, _ in cases)
    got = [shift_round(x, f) for x, f in cases]
    expected = [_rha(Fraction(x, 2**f)) for x, f in cases]
    assert got == expected
    # also with numpy int64 arguments
    x, f = cases[-1]
    assert shift_round(np.int64(x), np.int64(f)) == expected[-1]


@pytest.mark.parametrize(
    ("x", "f", "expected"),
    [
        # computed by hand
        (3, 1, 2),  # 1.5 → 2
        (-3, 1, -2),  # −1.5 → −2 (away), not −1 (floor-based shifts give −1)
        (5, 1, 3),  # 2.5 → 3 (not half-even 2)
        (-5, 1, -3),
        (1, 1, 1),  # 0.5 → 1
        (-1, 1, -1),
        (6, 2, 2),  # 1.5 → 2
        (-6, 2, -2),
        (5, 2, 1),  # 1.25 → 1
        (-5, 2, -1),
        (IMAX, 1, 2**62),  # (2**63 − 1) / 2 = 2**62 − 0.5 → 2**62
        (-IMAX, 1, -(2**62)),
        (IMAX, 62, 2),  # 1.99999… → 2
        (-IMAX, 62, -2),
        (2**61, 62, 1),  # 0.5 → 1
        (-(2**61), 62, -1),
        (2**61 - 1, 62, 0),
    ],
)
def test_shift_round_by_hand(x, f, expected):
    assert shift_round(x, f) == expected


def _sat_expected(a: int, b: int) -> int:
    return max(-IMAX, min(IMAX, a + b))


@pytest.mark.parametrize(
    ("a", "b"),
    [
        (IMAX, 0),
        (IMAX, 1),
        (IMAX, IMAX),
        (IMAX - 1, 1),
        (IMAX - 1, 2),
        (-IMAX, 0),
        (-IMAX, -1),
        (-IMAX, -IMAX),
        (-IMAX + 1, -1),
        (-IMAX + 1, -2),
        (-(2**62), -(2**62)),  # exact sum is INT64_MIN: must give −INT64_MAX
        (-(2**62), -(2**62) + 1),  # exact sum −INT64_MAX
        (IMAX, -IMAX),
        (-IMAX, IMAX),
        (IMIN, 0),  # even an INT64_MIN input does not come out
        (0, IMIN),
        (IMIN, 1),
        (5, IMIN),
        (0, 0),
        (-3, 7),
    ],
)
def test_sat_add_edges(a, b):
    s = sat_add(a, b)
    assert s == _sat_expected(a, b)
    assert s != IMIN
    assert sat_add(b, a) == s


def test_sat_add_random():
    rng = np.random.default_rng(64)
    a = rng.integers(-IMAX, IMAX, 3000, dtype=np.int64, endpoint=True)
    b = rng.integers(-IMAX, IMAX, 3000, dtype=np.int64, endpoint=True)
    # half the pairs near the top/bottom so the sums overflow often
    small = rng.integers(-(2**40), 2**40, 3000, dtype=np.int64, endpoint=True)
    pairs = [(int(x), int(y)) for x, y in zip(a, b, strict=True)]
    pairs += [(IMAX - abs(int(s)), int(y)) for s, y in zip(small, small[::-1], strict=True)]
    pairs += [(-IMAX + abs(int(s)), int(y)) for s, y in zip(small, small[::-1], strict=True)]
    got = [sat_add(x, y) for x, y in pairs]
    assert got == [_sat_expected(x, y) for x, y in pairs]
    assert IMIN not in got
    assert any(g == IMAX for g in got)
    assert any(g == -IMAX for g in got)


def _align_expected(x: int, k: int) -> int:
    return max(-IMAX, min(IMAX, x * 2**k))


def test_align_edges_every_k():
    for k in range(0, 63):
        lim = IMAX // 2**k  # largest x with x · 2**k <= INT64_MAX
        for x in (0, 1, -1, lim, -lim, lim + 1, -lim - 1, lim - 1, -lim + 1, IMAX, -IMAX):
            if k == 0 and abs(x) > IMAX:
                continue
            got = align(x, k)
            assert got == _align_expected(x, k), (x, k)
            assert got != IMIN
        if k >= 1:
            # exactly at the limit: exact; one past: saturated (both signs)
            assert align(lim, k) == lim * 2**k
            assert align(-lim, k) == -lim * 2**k
            assert align(lim + 1, k) == IMAX
            assert align(-lim - 1, k) == -IMAX


def test_align_random():
    rng = np.random.default_rng(32)
    cases = []
    for k in range(0, 63):
        # up to twice the exact limit IMAX >> k, so about half the cases saturate
        bound = min(2 * (IMAX >> k) + 1, IMAX)
        for x in rng.integers(-bound, bound, 30, dtype=np.int64, endpoint=True):
            cases.append((int(x), k))
    got = [align(x, k) for x, k in cases]
    assert got == [_align_expected(x, k) for x, k in cases]
    # both outcomes occur, for negative x too
    assert any(g == -IMAX for g in got)
    assert any(g == IMAX for g in got)
    assert any(x < 0 and -IMAX < g < 0 for (x, _), g in zip(cases, got, strict=True))


@pytest.mark.parametrize(
    ("x", "expected"),
    [
        # docs/runtime.md#saturation-and-clamps: e, ec and Δr clamped to ±(2**31 − 1) before any
        # product
        (0, 0),
        (2**31 - 1, 2**31 - 1),
        (2**31, 2**31 - 1),
        (-(2**31) + 1, -(2**31) + 1),
        (-(2**31), -(2**31) + 1),
        (IMAX, 2**31 - 1),
        (-IMAX, -(2**31) + 1),
        (12_345, 12_345),
        (-12_345, -12_345),
    ],
)
def test_clamp_e(x, expected):
    assert clamp_e(x) == expected
    assert clamp_e(np.int64(x)) == expected


def test_products_after_clamp_cannot_overflow():
    # docs/runtime.md#saturation-and-clamps: int32 q × clamped int32 e fits int64: (2**31 − 1)**2 <
    # INT64_MAX
    e = clamp_e(IMAX)
    assert LIM32 * e <= IMAX
    assert (-LIM32) * clamp_e(-IMAX) <= IMAX
