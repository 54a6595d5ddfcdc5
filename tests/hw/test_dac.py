"""Tests for servotune.hw.dac: PCL728 12-bit D/A, bipolar ±10 V, offset-binary coding."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from servotune.hw.dac import code_from_uq, code_from_volts, lsb_v, volts_from_code, zero_code

# PCL728: 12-bit, ±10 V: LSB = 20/4096 V = 4.8828125 mV (exact in binary: 5 · 2**-10)
LSB = 20.0 / 4096.0
# docs/runtime.md#da-quantisation: u_q has f_u = 32 fraction bits; code = clamp(shift_round(u_q, 32)
# + 2048, 0, 4095)
F_U = 32
ALL_CODES = np.arange(4096)


def _uq_from_volts(volts: float) -> int:
    """u_q = round_half_away(volts / LSB · 2**32), exactly, with Python integers.

    computed by hand: 1 / LSB · 2**32 = 4096 / 20 · 2**32 = 2**42 / 5
    """
    num, den = Fraction(volts).as_integer_ratio()
    n, dd = abs(num) * 2**42, den * 5
    q = (2 * n + dd) // (2 * dd)  # floor(n / dd + 1/2): half away from zero on the magnitude
    return q if num >= 0 else -q


def test_lsb():
    # PCL728: 12-bit, ±10 V: LSB = 20/4096 V
    assert lsb_v() == 20.0 / 4096.0
    assert lsb_v(12, (-10.0, 10.0)) == 0.0048828125
    # computed by hand: 16 bits over ±10 V → 20 / 65536 V; 12 bits over 0..10 V → 10 / 4096 V
    assert lsb_v(16, (-10.0, 10.0)) == 20.0 / 65536.0
    assert lsb_v(12, (0.0, 10.0)) == 10.0 / 4096.0


@pytest.mark.parametrize(
    ("volts", "code"),
    [
        # docs/runtime.md#da-quantisation: rails −10 V (code 0) and +9.99512 V (code 4095)
        (-10.0, 0),
        (-10.0 + LSB, 1),
        (9.99512, 4095),
        (10.0 - LSB, 4095),  # 9.9951171875 V exactly
        (10.0 - 2 * LSB, 4094),
        # beyond the rails: clamp
        (-10.1, 0),
        (-10.0 - 0.5 * LSB, 0),  # rounds to −2049 + 2048 = −1 → clamp 0
        (-20.0, 0),
        (10.0, 4095),  # 2048 + 2048 = 4096 → clamp 4095
        (10.0 - 0.5 * LSB, 4095),  # tie 2047.5 → 2048 → 4096 → clamp 4095
        (20.0, 4095),
        (1e300, 4095),
        (-1e300, 0),
        # around 0 V: mid-scale and ±1 LSB
        (0.0, 2048),
        (-0.0, 2048),
        (LSB, 2049),
        (-LSB, 2047),
    ],
)
def test_code_from_volts_rails_and_zero(volts, code):
    out = code_from_volts(volts)
    assert out.dtype == np.int64
    assert int(out) == code


@pytest.mark.parametrize(
    ("lsbs", "code"),
    [
        # docs/runtime.md#da-quantisation: round_half_away(u / LSB) + 2048 — ties go away from zero
        (0.5, 2049),
        (-0.5, 2047),
        (1.5, 2050),
        (-1.5, 2046),
        (2.5, 2051),  # half-even would give 2050
        (-2.5, 2045),
        (2047.5, 4095),  # tie → 2048 → 4096 → clamp
        (-2047.5, 0),  # tie → −2048 → 0 (the bottom rail, no clamp needed)
        (-2048.5, 0),  # tie → −2049 → clamp
    ],
)
def test_code_from_volts_ties_round_half_away(lsbs, code):
    volts = lsbs * LSB  # exact in binary: multiples of 2**-11 V
    assert volts / LSB == lsbs
    assert int(code_from_volts(volts)) == code


def test_code_from_volts_just_off_a_tie_rounds_to_nearest():
    half = 0.5 * LSB
    below, above = np.nextafter(half, 0.0), np.nextafter(half, 1.0)
    # computed by hand: just below +0.5 LSB → 0 → 2048; just above → 1 → 2049 (and mirrored)
    assert_array_equal(code_from_volts(np.array([below, above])), [2048, 2049])
    assert_array_equal(code_from_volts(np.array([-below, -above])), [2048, 2047])


def test_code_from_volts_rejects_non_finite():
    with pytest.raises(ValueError, match="finite"):
        code_from_volts(np.array([0.0, np.nan]))
    with pytest.raises(ValueError, match="finite"):
        code_from_volts(np.inf)


def test_volts_from_code_exact_on_all_codes():
    # PCL728 offset binary: volts = −10 + code · 20/4096, exactly (multiples of 2**-10 V < 16 V)
    v = volts_from_code(ALL_CODES)
    exact = [Fraction(-10) + Fraction(20 * int(c), 4096) for c in ALL_CODES]
    assert [Fraction(float(x)) for x in v] == exact
    assert v[0] == -10.0
    assert v[2048] == 0.0
    assert v[4095] == 9.9951171875  # the +9.99512 V rail
    # code_from_volts is the inverse on every code
    assert_array_equal(code_from_volts(v), ALL_CODES)


@pytest.mark.parametrize("code", [-1, 4096, 10_000])
def test_volts_from_code_out_of_range_raises(code):
    with pytest.raises(ValueError, match=r"0\.\.4095"):
        volts_from_code(code)
    with pytest.raises(ValueError, match=r"0\.\.4095"):
        volts_from_code(np.array([0, 2048, code]))


def _volt_sweep() -> np.ndarray:
    rng = np.random.default_rng(728)
    return np.concatenate(
        [
            # every exact tie and every code centre from beyond −rail to beyond +rail
            np.arange(-2 * 2100, 2 * 2100 + 1) * (0.5 * LSB),
            # eighths of an LSB (exact in binary) over ±40 LSB around 0 V and near both rails
            np.arange(-320, 321) * (LSB / 8),
            -10.0 + np.arange(-80, 81) * (LSB / 8),
            10.0 + np.arange(-80, 81) * (LSB / 8),
            # a dense uniform grid and random volts, past both rails
            np.linspace(-10.5, 10.5, 20_001),
            rng.uniform(-10.5, 10.5, 5_000),
            rng.uniform(-3 * LSB, 3 * LSB, 2_000),
        ]
    )


def test_code_from_uq_agrees_with_code_from_volts():
    # docs/runtime.md#da-quantisation: code = clamp(shift_round(u_q, f_u) + 2048, 0, 4095) equals
    # clamp(round_half_away(u_volts / LSB) + 2048, 0, 4095) in volts
    volts = _volt_sweep()
    expected = code_from_volts(volts)
    got = np.array([code_from_uq(_uq_from_volts(float(v)), F_U, 2048, 4095) for v in volts])
    assert_array_equal(got, expected)
    # the sweep really reaches both rails and crosses ties
    assert expected.min() == 0
    assert expected.max() == 4095


@pytest.mark.parametrize(
    ("u_q", "code"),
    [
        # computed by hand: shift_round(u_q, 32) + 2048, clamped to 0..4095
        (0, 2048),
        (2**31, 2049),  # +0.5 LSB tie → away
        (-(2**31), 2047),
        (2**31 - 1, 2048),
        (-(2**31) + 1, 2048),
        (2047 * 2**32, 4095),
        (2047 * 2**32 + 2**31 - 1, 4095),
        (2047 * 2**32 + 2**31, 4095),  # 2048 + 2048 = 4096 → clamp
        (-2048 * 2**32, 0),
        (-2048 * 2**32 - 2**31, 0),  # −2049 + 2048 = −1 → clamp
        (-2047 * 2**32 - 2**31 + 1, 1),
        (2**62, 4095),
        (-(2**62), 0),
        (2**63 - 1, 4095),  # INT64_MAX
        (-(2**63) + 1, 0),  # −INT64_MAX
    ],
)
def test_code_from_uq_edges_and_rails(u_q, code):
    assert code_from_uq(u_q, F_U, 2048, 4095) == code
    assert code_from_uq(np.int64(u_q), np.int64(F_U), 2048, 4095) == code


def test_zero_code():
    # PCL728 ±10 V, 12 bits: mid-scale 2048 (docs/runtime.md#da-quantisation)
    assert zero_code() == 2048
    assert zero_code(12, (-10.0, 10.0)) == 2048
    # computed by hand: −lo / LSB
    assert zero_code(16, (-10.0, 10.0)) == 32768
    assert zero_code(12, (-5.0, 5.0)) == 2048
    assert zero_code(12, (0.0, 10.0)) == 0  # unipolar: 0 V is code 0
    assert zero_code(12, (-7.5, 12.5)) == 1536  # 7.5 / (20/4096) = 1536


@pytest.mark.parametrize(
    "range_v",
    [
        (-3.0, 10.0),  # computed by hand: 3 / (13/4096) = 945.23…, not a code
        (-10.0, 0.0),  # 0 V would be code 4096, one past the top
        (1.0, 10.0),  # 0 V below the range
        (-10.0, -1.0),  # 0 V above the range
    ],
)
def test_zero_code_raises_without_an_exact_zero(range_v):
    with pytest.raises(ValueError, match="0 V"):
        zero_code(12, range_v)
    with pytest.raises(ValueError, match="0 V"):
        code_from_volts(0.0, 12, range_v)


def test_other_widths_and_ranges():
    # computed by hand: 16 bits ±10 V → mid 32768, rails 0 and 65535
    assert_array_equal(code_from_volts(np.array([-10.0, 0.0, 10.0]), 16), [0, 32768, 65535])
    # 12 bits 0..10 V: LSB 10/4096; 5 V → 2048
    assert_array_equal(
        code_from_volts(np.array([-1.0, 5.0, 10.0]), 12, (0.0, 10.0)), [0, 2048, 4095]
    )
    assert_array_equal(volts_from_code(np.array([0, 65535]), 16), [-10.0, 10.0 - 20.0 / 65536])
