"""Tests for servotune.hw.timer: 8253 PIT divisor and achieved interrupt period."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from servotune.hw.timer import PC_PIT_CLOCK_HZ, achieved_period_s, divisor, period_error_ppm

# A clock that is a power of two makes every k / 2**20 period and the product period * clock
# exact in binary floating point, so a .5 tie really is a tie.
POW2_CLOCK_HZ = 2.0**20


def test_pc_clock_is_the_8253_input_clock():
    # docs/runtime.md#timer-and-achieved-period: 8253 PIT, input clock 1,193,180 Hz
    assert PC_PIT_CLOCK_HZ == 1_193_180.0


def test_4ms_divisor_achieved_period_and_error():
    # docs/runtime.md#timer-and-achieved-period: 4 ms → divisor 4773 → 4.000235 ms, +58.7 ppm
    # computed by hand: 0.004 · 1,193,180 = 4772.72 → 4773; 4773 / 1,193,180 = 4.0002347 ms
    div = divisor(0.004)
    assert div == 4773
    assert isinstance(div, int)
    assert_allclose(achieved_period_s(div), 0.004000235, rtol=0, atol=1e-9)
    assert_allclose(period_error_ppm(0.004), 58.7, rtol=0, atol=0.05)


def test_default_divisor_65536_is_18_2_hz():
    # the PC's default divisor 65536 = 18.2 Hz; computed by hand: 1,193,180 / 65,536 = 18.2065 Hz
    assert_allclose(1.0 / achieved_period_s(65536), 18.2065, rtol=0, atol=5e-5)
    # the longest period the PIT can make maps back to the largest divisor (programmed as 0)
    assert divisor(65536 / PC_PIT_CLOCK_HZ) == 65536


@pytest.mark.parametrize(
    ("exact_product", "expected"),
    [
        # computed by hand: divisor = floor(x + 0.5), so an exact .5 tie goes UP (to the larger
        # divisor, i.e. the longer period), never to even
        (1.5, 2),  # tie at the lower edge: 1.5 → 2 (in range)
        (2.5, 3),  # round-half-even would give 2
        (4773.5, 4774),
        (65535.5, 65536),  # tie at the upper edge: → 65536 (in range)
        # just off the tie: nearest
        (4773.5 - 2.0**-20, 4773),
        (4773.5 + 2.0**-20, 4774),
        (4773.49, 4773),
    ],
)
def test_round_to_nearest_ties_go_up(exact_product, expected):
    period = exact_product / POW2_CLOCK_HZ
    assert period * POW2_CLOCK_HZ == exact_product  # the tie is exact in binary
    assert divisor(period, POW2_CLOCK_HZ) == expected


def test_vectorised_over_periods():
    # computed by hand: p · 1,193,180 = 1193.18, 4772.72, 11931.8, 59659.0, 78.09...(1/15279.2 s)
    periods = np.array([0.001, 0.004, 0.010, 0.050])
    expected = np.array([1193, 4773, 11932, 59659])
    div = divisor(periods)
    assert isinstance(div, np.ndarray)
    assert div.dtype == np.int64
    assert_array_equal(div, expected)
    assert_array_equal(div, [divisor(float(p)) for p in periods])
    assert_allclose(achieved_period_s(div), expected / 1_193_180.0, rtol=1e-15, atol=0)
    # shape is kept for 2-D input
    assert_array_equal(divisor(periods.reshape(2, 2)), expected.reshape(2, 2))


def test_vectorised_range_edges():
    # divisor 2 and 65536 are the edges of the 8253 (16-bit down counter, 0 means 65536)
    periods = np.array([2.0, 65536.0]) / PC_PIT_CLOCK_HZ
    assert_array_equal(divisor(periods), [2, 65536])


@pytest.mark.parametrize(
    "period_s",
    [
        1.49 / POW2_CLOCK_HZ,  # → divisor 1 < 2
        65536.5 / POW2_CLOCK_HZ,  # tie rounds up to 65537 > 65536
        70000 / POW2_CLOCK_HZ,
        0.0,
        -0.004,
        math.nan,
        math.inf,
    ],
)
def test_out_of_range_period_raises_naming_it(period_s):
    with pytest.raises(ValueError, match="period_s") as info:
        divisor(period_s, POW2_CLOCK_HZ)
    assert repr(float(period_s)) in str(info.value)


def test_out_of_range_period_in_array_names_the_bad_one():
    # computed by hand: 0.1 s · 1,193,180 Hz = 119,318 > 65,536; 1 µs → 1.19 → divisor 1 < 2
    with pytest.raises(ValueError, match=r"0\.1\b"):
        divisor(np.array([0.004, 0.1, 0.004]))
    with pytest.raises(ValueError, match=r"1e-06"):
        divisor(np.array([0.004, 0.004, 1e-6]))


@pytest.mark.parametrize("clock_hz", [0.0, -1_193_180.0, math.nan, math.inf])
def test_bad_clock_raises(clock_hz):
    with pytest.raises(ValueError, match="clock_hz"):
        divisor(0.004, clock_hz)
