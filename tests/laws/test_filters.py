"""The filter sections (docs/runtime.md#filters), each against an independent reference:

- the discrete design against ``scipy.signal.bilinear`` (with the pre-warping written as its
  ``fs``) and ``scipy.signal.iirnotch``;
- the realised response, measured with ``scipy.signal.freqz``, against the design values (the
  notch's centre and depth, the textbook second-order low-pass's −3 dB point and peak);
- the integer tick against a plain-Python big-integer re-implementation of its recurrence;
- limit cycles, overflow bounds and bumpless switching against runs of the integer tick itself.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from servotune.errors import SpecError
from servotune.laws.filters import (
    ACC_LIMIT,
    INPUT_BOUND_CODES,
    INPUT_BOUND_WIDE,
    N_FILTER_STATE,
    Section,
    SectionQ,
    biquad,
    biquad_step,
    bumpless_state,
    choose_frac_bits,
    discretize,
    filter_run,
    lowpass2,
    notch,
    quantize_section,
    state_bound,
)

PERIODS = (0.004, 0.001)
"""The tick periods of the grid [s]: the example rig's 4 ms and a 1 ms slave."""


def _sections() -> list[tuple[Section, float]]:
    """A spread of sections: narrow deep notches low and high, resonant and damped low-passes."""
    return [
        (notch(5.0, 1.0, -40.0), 0.001),
        (notch(5.0, 1.0, -40.0), 0.004),
        (notch(60.0, 12.0, -20.0), 0.004),
        (notch(200.0, 1.0, -40.0), 0.001),
        (notch(110.0, 1.0, -40.0), 0.004),
        (lowpass2(2.0, 0.05), 0.001),
        (lowpass2(5.0, 0.7), 0.001),
        (lowpass2(100.0, 0.1), 0.004),
        (biquad([1.0, 30.0, 4.0e4], [1.0, 200.0, 1.0e5]), 0.001),
    ]


def _quantized(section: Section, period_s: float, f: int | None = None) -> SectionQ:
    return quantize_section(section, period_s, f or choose_frac_bits(section, period_s))


def _run(q: SectionQ, xs: np.ndarray, st: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    st = np.zeros(N_FILTER_STATE, dtype=np.int64) if st is None else st
    ys = np.empty(xs.size, dtype=np.int64)
    acc_max = filter_run(*q.step_args(), st, np.asarray(xs, dtype=np.int64), ys)
    return ys, int(acc_max)


# --- the design against scipy ------------------------------------------------------------------


@pytest.mark.parametrize(
    "section",
    [
        notch(50.0, 10.0, -20.0),
        lowpass2(30.0, 0.4),
        biquad([2.0, 40.0, 9.0e4], [1.0, 150.0, 4.0e5]),
    ],
    ids=["notch", "lowpass2", "biquad"],
)
@pytest.mark.parametrize("period_s", PERIODS)
def test_design_is_scipy_bilinear_prewarped(section: Section, period_s: float) -> None:
    # scipy.signal.bilinear maps s = 2·fs·(z−1)/(z+1); pre-warping at ωw is fs = K/2
    ww = 2.0 * math.pi * section.warp_hz
    k = ww / math.tan(ww * period_s / 2.0)
    b, a = signal.bilinear(section.num_s, section.den_s, fs=k / 2.0)
    b0, b1, b2, a1, a2 = discretize(section, period_s)
    np.testing.assert_allclose([b0, b1, b2], b / a[0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose([1.0, a1, a2], a / a[0], rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize(("f0", "width"), [(5.0, 1.0), (50.0, 10.0), (110.0, 30.0)])
def test_deep_notch_is_scipy_iirnotch(f0: float, width: float) -> None:
    # scipy.signal.iirnotch sets the digital −3 dB bandwidth; the analog one maps to it by
    # tan(π·bw_d·T) = π·width·T·sin(ω0·T)/(ω0·T) (the pre-warped bilinear transform, worked out)
    period_s = 0.004
    w0t = 2.0 * math.pi * f0 * period_s
    bw_d = math.atan(math.pi * width * period_s * math.sin(w0t) / w0t) / (math.pi * period_s)
    b, a = signal.iirnotch(f0, f0 / bw_d, fs=1.0 / period_s)
    b0, b1, b2, a1, a2 = discretize(notch(f0, width, -300.0), period_s)
    np.testing.assert_allclose([b0, b1, b2, 1.0, a1, a2], [*b, *a], rtol=1e-9, atol=1e-12)


def _notch_measured(b: np.ndarray, a: np.ndarray, fs: float) -> tuple[float, float]:
    """Centre and depth of a notch from scipy.signal.freqz: a dense grid, refined twice."""
    f = np.geomspace(1.0, 0.49 * fs, 20_000)
    for _ in range(3):
        _, h = signal.freqz(b, a, worN=f, fs=fs)
        i = int(np.argmin(np.abs(h)))
        f = np.linspace(f[max(i - 1, 0)], f[min(i + 1, f.size - 1)], 1001)
    _, h = signal.freqz(b, a, worN=f, fs=fs)
    i = int(np.argmin(np.abs(h)))
    return float(f[i]), float(20.0 * np.log10(np.abs(h[i])))


def _lowpass_measured(b: np.ndarray, a: np.ndarray, fs: float) -> tuple[float, float]:
    """−3 dB point (interpolated on a dense grid) and peak [dB] from scipy.signal.freqz."""
    f = np.concatenate([[0.0], np.geomspace(0.01, 0.4999 * fs, 200_000)])
    _, h = signal.freqz(b, a, worN=f, fs=fs)
    g = 20.0 * np.log10(np.abs(h))
    j = int(np.nonzero(g <= -10.0 * math.log10(2.0))[0][0])
    t = (-10.0 * math.log10(2.0) - g[j - 1]) / (g[j] - g[j - 1])
    return float(f[j - 1] + t * (f[j] - f[j - 1])), float(np.max(g))


def test_design_notch_centre_and_depth_are_exact() -> None:
    # the pre-warping keeps the analog centre and depth exactly (freqz measures them)
    for period_s in PERIODS:
        for f0, width, depth in ((5.0, 1.0, -40.0), (80.0, 20.0, -12.0)):
            b0, b1, b2, a1, a2 = discretize(notch(f0, width, depth), period_s)
            fc, d = _notch_measured(np.array([b0, b1, b2]), np.array([1.0, a1, a2]), 1 / period_s)
            assert fc == pytest.approx(f0, rel=1e-5)
            assert d == pytest.approx(depth, abs=1e-4)


# --- the word-length rule over a grid ----------------------------------------------------------


def _notch_grid() -> list[tuple[float, float, float, float]]:
    grid = []
    for period_s in PERIODS:
        for f0 in (5.0, 10.0, 20.0, 40.0, 80.0, 110.0, 150.0, 200.0):
            if f0 < 0.45 / period_s:
                for width in (1.0, 0.2 * f0, f0):
                    grid.extend((period_s, f0, width, d) for d in (-6.0, -20.0, -40.0))
    return grid


def test_notch_grid_meets_tolerances() -> None:
    """Centres 5–200 Hz below 0.45·f_s at 4 ms and 1 ms, three widths, three depths: the chosen
    word length realises centre ±0.5 % and depth ±1 dB, measured with scipy.signal.freqz."""
    chosen = []
    for period_s, f0, width, depth in _notch_grid():
        section = notch(f0, width, depth)
        q = _quantized(section, period_s)
        fc, d = _notch_measured(*q.ba(), 1.0 / period_s)
        assert abs(fc - f0) <= 0.005 * f0, (period_s, f0, width, depth, q.frac_bits, fc)
        assert abs(d - depth) <= 1.0, (period_s, f0, width, depth, q.frac_bits, d)
        chosen.append(q.frac_bits)
    assert len(chosen) == 126
    assert 12 <= min(chosen) and max(chosen) <= 18  # measured: 12..17


def test_the_chosen_word_length_is_the_smallest() -> None:
    for section, period_s in _sections():
        f = choose_frac_bits(section, period_s)
        if f > 12:
            with pytest.raises(SpecError, match="no word length"):
                choose_frac_bits(section, period_s, f_max=f - 1)


@pytest.mark.parametrize("period_s", PERIODS)
@pytest.mark.parametrize("damping", [0.1, 0.3, 0.7, 2.0])
@pytest.mark.parametrize("corner", [5.0, 20.0, 100.0])
def test_lowpass_meets_tolerances(period_s: float, damping: float, corner: float) -> None:
    # textbook second-order low-pass: −3 dB at ω0·sqrt(1 − 2ζ² + sqrt((1 − 2ζ²)² + 1)), peak
    # 1/(2ζ·sqrt(1 − ζ²)) for ζ < 1/√2 (else 0 dB at DC); the bilinear map moves the frequency
    # by Ω = 2·atan(ω/K) and keeps the gain
    c = 1.0 - 2.0 * damping**2
    w3 = 2.0 * math.pi * corner * math.sqrt(c + math.sqrt(c * c + 1.0))
    ww = 2.0 * math.pi * corner
    k = ww / math.tan(ww * period_s / 2.0)
    f3_ref = math.atan(w3 / k) / (math.pi * period_s)
    peak_ref = -20.0 * math.log10(2 * damping * math.sqrt(1 - damping**2)) if c > 0 else 0.0
    q = _quantized(lowpass2(corner, damping), period_s)
    f3, peak = _lowpass_measured(*q.ba(), 1.0 / period_s)
    assert abs(f3 - f3_ref) <= 0.005 * f3_ref
    assert abs(peak - peak_ref) <= 1.0
    assert q.b0 + q.b1 + q.b2 == (1 << q.frac_bits) + q.a1 + q.a2  # unity DC gain, exactly


# --- the integer tick against big integers -----------------------------------------------------


def _rha_shift(x: int, f: int) -> int:
    """x · 2^−f rounded half away from zero (Python ints: exact)."""
    m = (abs(x) + (1 << (f - 1))) >> f
    return m if x >= 0 else -m


def _model(q: SectionQ, st: list[int], xs: list[int]) -> tuple[list[int], list[int]]:
    """The recurrence of docs/runtime.md#filters in Python integers; asserts int64 range."""
    b0, b1, b2, a1, a2, f = q.step_args()
    x1, x2, y1, y2, r1, r2 = st
    ys = []
    for x in xs:
        acc = b0 * x + b1 * x1 + b2 * x2 - a1 * y1 - a2 * y2 - _rha_shift(a1 * r1 + a2 * r2, f)
        assert abs(acc) < 2**63
        y = _rha_shift(acc, f)
        x1, x2, y1, y2, r1, r2 = x, x1, y, y1, acc - y * 2**f, r1
        ys.append(y)
    return ys, [x1, x2, y1, y2, r1, r2]


@pytest.mark.parametrize("case", range(9))
def test_tick_matches_big_integer_model(case: int) -> None:
    section, period_s = _sections()[case]
    rng = np.random.default_rng(case)
    f_chosen = choose_frac_bits(section, period_s)
    for f in sorted({f_chosen, 12, 30}):
        try:
            q = quantize_section(section, period_s, f)
        except SpecError:
            continue  # a coefficient does not fit int32 with 30 fraction bits
        x_max = min(INPUT_BOUND_WIDE, state_bound(q).y_max) // 4
        xs = rng.integers(-x_max, x_max + 1, 5000)
        xs[2000:2500] = rng.integers(-3, 4, 500)  # small signals: the rounding matters
        st0 = [int(v) for v in rng.integers(-1000, 1000, 4)] + [0, 0]
        want, st_want = _model(q, st0, [int(x) for x in xs])
        st = np.array(st0, dtype=np.int64)
        got, _ = _run(q, xs, st)
        assert got.tolist() == want
        assert st.tolist() == st_want


def test_tick_on_a_slice_of_a_state_array() -> None:
    q = _quantized(notch(60.0, 12.0, -20.0), 0.004)
    big = np.full((2, 3 * N_FILTER_STATE), 7, dtype=np.int64)
    big[1, 6:12] = 0
    ys = [biquad_step(*q.step_args(), big[1], 6, x) for x in (1000, -5, 300_000)]
    want, st = _model(q, [0] * 6, [1000, -5, 300_000])
    assert ys == want
    assert big[1, 6:12].tolist() == st
    assert (big[0] == 7).all() and (big[1, :6] == 7).all() and (big[1, 12:] == 7).all()


# --- limit cycles --------------------------------------------------------------------------------


@pytest.mark.parametrize("case", range(9))
def test_no_zero_input_limit_cycle(case: int) -> None:
    """An impulse, then a random full-scale burst, then 10^6 ticks of zero input: the output
    ends at 0 and nothing above 1 LSB persists over the last 10^5 ticks."""
    section, period_s = _sections()[case]
    rng = np.random.default_rng(100 + case)
    for f in (choose_frac_bits(section, period_s), 30):
        try:
            q = quantize_section(section, period_s, f)
        except SpecError:
            continue
        xs = np.zeros(1_000_000, dtype=np.int64)
        xs[0] = INPUT_BOUND_WIDE
        xs[10:2000] = rng.integers(-INPUT_BOUND_WIDE, INPUT_BOUND_WIDE + 1, 1990)
        ys, _ = _run(q, xs)
        assert state_bound(q).l1_inv <= 2 ** (f - 1)  # the rule that makes the decay to 0 sure
        assert np.max(np.abs(ys[:2000])) > 1000  # it was excited
        assert abs(int(ys[-1])) <= 1
        assert np.max(np.abs(ys[-100_000:])) <= 1
        assert np.max(np.abs(ys[-100_000:])) == 0  # measured: every case ends at exactly 0


def test_plain_rounding_has_a_dead_band_error_feedback_does_not() -> None:
    """The same recurrence without the remainders fed back holds a non-zero output forever
    (the dead band of a low-frequency section); with them it decays to 0."""
    q = _quantized(lowpass2(5.0, 0.7), 0.001)
    *_, a1, a2, f = q.step_args()
    y1 = y2 = 100
    for _ in range(20_000):
        y1, y2 = _rha_shift(-a1 * y1 - a2 * y2, f), y1
    assert y1 == 100  # stuck: A(1)·100 < 1/2 LSB
    ys, _ = _run(q, np.zeros(20_000, dtype=np.int64), bumpless_state(q, 0, 100))
    assert ys[-1] == 0


def test_the_limit_cycle_rule_binds_for_low_sections() -> None:
    # a 5 Hz notch at 1 ms meets its tolerances at 12 and 13 fraction bits, but ‖1/A_q‖₁ ≈ 6.5e3
    # exceeds 2^(f−1) there: the chosen word length is 14
    section = notch(5.0, 1.0, -6.0)
    with pytest.raises(SpecError, match="the limit-cycle rule"):
        choose_frac_bits(section, 0.001, f_max=13)
    assert choose_frac_bits(section, 0.001) == 14


# --- overflow ----------------------------------------------------------------------------------


@pytest.mark.parametrize("x_max", [INPUT_BOUND_CODES, INPUT_BOUND_WIDE], ids=["codes", "wide"])
@pytest.mark.parametrize("case", range(9))
def test_state_bound_holds_and_is_tight(case: int, x_max: int) -> None:
    section, period_s = _sections()[case]
    q = _quantized(section, period_s)
    sb = state_bound(q, x_max)
    b, a = q.ba()
    imp = np.zeros(200_000)
    imp[0] = 1.0
    h = signal.lfilter(b, a, imp)  # the quantised impulse response (scipy)
    n = int(np.nonzero(np.abs(h) > 1e-12 * np.max(np.abs(h)))[0][-1]) + 1
    # worst case: the sign pattern of the time-reversed impulse response drives |y| to ‖h‖₁·X
    worst = np.where(h[:n][::-1] >= 0, x_max, -x_max).astype(np.int64)
    rng = np.random.default_rng(case)
    rand = rng.integers(-x_max, x_max + 1, 50_000)
    y_obs, acc_obs = 0, 0
    for xs in (worst, -worst, rand, np.concatenate([worst, -worst])):
        ys, acc = _run(q, xs)
        y_obs, acc_obs = max(y_obs, int(np.max(np.abs(ys)))), max(acc_obs, acc)
    assert y_obs <= sb.y_max <= 4 * y_obs
    assert sb.y_max <= 1.01 * y_obs + 2  # measured: the worst case reaches the bound
    assert acc_obs <= sb.acc_max <= ACC_LIMIT
    assert sb.headroom_bits >= 11.0 if x_max == INPUT_BOUND_WIDE else sb.headroom_bits >= 27.0


def test_chosen_word_length_keeps_the_margin_for_wide_inputs() -> None:
    # at 30 fraction bits a resonant low-pass leaves under one bit of headroom: the 2^62 rule
    # makes choose_frac_bits refuse it, and its own choice keeps more than 11 bits
    section = lowpass2(2.0, 0.05)
    assert state_bound(quantize_section(section, 0.004, 30)).acc_max > ACC_LIMIT
    with pytest.raises(SpecError, match="accumulator bound"):
        choose_frac_bits(section, 0.004, f_min=30)
    assert state_bound(_quantized(section, 0.004)).headroom_bits > 11.0


# --- bumpless switching ------------------------------------------------------------------------


def _inputs(period_s: float) -> dict[str, np.ndarray]:
    t = np.arange(12_000) * period_s
    return {
        "steady": np.full(t.size, 123_456_789, dtype=np.int64),
        "sine": np.round(2.0**26 * np.sin(2.0 * np.pi * 0.5 * t)).astype(np.int64),
        "ramp": np.arange(t.size, dtype=np.int64) * 3000 - 9_000_000,
    }


def _pairs(period_s: float) -> list[tuple[Section, Section]]:
    nyq = 0.5 / period_s
    return [
        (notch(10.0, 2.0, -30.0), notch(8.0, 1.6, -25.0)),
        (notch(0.4 * nyq, 0.1 * nyq, -20.0), notch(0.3 * nyq, 0.05 * nyq, -40.0)),
        (lowpass2(30.0, 0.7), lowpass2(21.0, 0.5)),
        (lowpass2(0.4 * nyq, 0.3), notch(0.2 * nyq, 0.05 * nyq, -20.0)),
    ]


@pytest.mark.parametrize("period_s", PERIODS)
@pytest.mark.parametrize("kind", ["steady", "sine", "ramp"])
def test_bumpless_switch_in_and_retune(period_s: float, kind: str) -> None:
    """Switch a section in (from the bypass, output = input) at tick k, and re-tune a running
    section to another at tick k. Steady input: the output does not move at all (≤ 1 LSB is
    the rule). Slowly varying input: the step at the switch is no larger than the input's own
    step (measured: at most 1.085 times it), and the output joins the new section's (run from
    the start) within 1 LSB once the switch's transient has decayed (9 s later)."""
    xs = _inputs(period_s)[kind]
    k = 3000
    x_step = int(np.max(np.abs(np.diff(xs[k - 10 : k + 1]))))
    for old, new in _pairs(period_s):
        q_old, q_new = _quantized(old, period_s), _quantized(new, period_s)
        ref, _ = _run(q_new, xs, bumpless_state(q_new, int(xs[0]), int(xs[0])))
        before_ret, _ = _run(q_old, xs[:k], bumpless_state(q_old, int(xs[0]), int(xs[0])))
        for before in (xs[:k], before_ret):  # switch-in from the bypass; re-tune
            st = bumpless_state(q_new, int(xs[k - 1]), int(before[-1]))
            after, _ = _run(q_new, xs[k:], st)
            y = np.concatenate([before, after])
            jump = abs(int(y[k]) - int(y[k - 1]))
            if kind == "steady":
                assert np.all(y == xs[0]), (old, new)
                continue
            assert jump <= 1.1 * x_step + 1, (old, new, jump, x_step)
            assert np.max(np.abs(y[-500:] - ref[-500:])) <= 1, (old, new)


# --- bad inputs --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: notch(0.0, 1.0, -20.0), r"notch center_hz must be a number > 0 \[Hz\], got 0.0"),
        (lambda: notch(50.0, -1.0, -20.0), r"notch width_hz must be a number > 0 \[Hz\], got -1.0"),
        (lambda: notch(50.0, 5.0, 0.0), r"notch depth_db must be a number < 0 \[dB\], got 0.0"),
        (
            lambda: notch(50.0, 5.0, math.nan),
            r"notch depth_db must be a number < 0 \[dB\], got nan",
        ),
        (lambda: notch("50", 5.0, -3.0), r"notch center_hz must be a number > 0 \[Hz\], got '50'"),
        (lambda: lowpass2(20.0, 0.0), r"lowpass2 damping must be a number > 0 \[-\], got 0.0"),
        (lambda: lowpass2(-2.0, 0.7), r"lowpass2 corner_hz must be a number > 0 \[Hz\], got -2.0"),
        (
            lambda: discretize(notch(130.0, 5.0, -20.0), 0.004),
            r"notch center_hz must be a number in \(0, 125\) \[Hz\] \(below the Nyquist "
            r"frequency 0.5/period_s\), got 130.0",
        ),
        (
            lambda: discretize(lowpass2(20.0, 0.7), 0.0),
            r"period_s must be a number > 0 \[s\], got 0.0",
        ),
        (lambda: biquad([1.0], [1.0, -2.0, 5.0]), r"biquad den_s must be a stable second-order"),
        (lambda: biquad([1.0], [0.0, 2.0, 5.0]), r"biquad den_s must be a stable second-order"),
        (lambda: biquad([0.0, 0.0], [1.0, 2.0, 5.0]), r"biquad num_s must not be all zeros"),
        (lambda: biquad([1.0, 2.0, 3.0, 4.0], [1.0, 2.0, 5.0]), r"biquad num_s must be 1 to 3"),
        (
            lambda: biquad([1.0], [1.0, 2.0, 5.0], warp_hz=-1.0),
            r"biquad warp_hz must be a number > 0",
        ),
        (
            lambda: quantize_section(notch(50.0, 5.0, -20.0), 0.004, 31),
            r"frac_bits must be an integer in 1..30 \[bits\], got 31",
        ),
        (
            lambda: quantize_section(notch(2.0, 0.2, -20.0), 0.001, 3),
            r"not stable with 3 fraction bits",
        ),
        (
            lambda: choose_frac_bits(notch(5.0, 0.1, -60.0), 0.001, f_max=13),
            r"no word length of 12..13 fraction bits realises the notch at 5 Hz",
        ),
    ],
)
def test_bad_inputs_raise_spec_error(make, message: str) -> None:
    with pytest.raises(SpecError, match=message):
        make()


def test_the_sections_rounding_is_the_runtimes_within_the_accumulator_bound() -> None:
    """``round_acc`` (the section's shorter rounding) gives ``fixed.shift_round``'s integers
    for every |x| <= 2^62 tried, ties and the bound itself included, at every word length."""
    from servotune.fixed import shift_round
    from servotune.laws.filters import round_acc

    rng = np.random.default_rng(21)
    for f in range(1, 31):
        half = 1 << (f - 1)
        xs = [int(v) for v in rng.integers(-(2**62), 2**62, 400, endpoint=True)]
        xs += [0, 1, -1, half, -half, 3 * half, -3 * half, 2**62, -(2**62), half - 1, 1 - half]
        assert [round_acc(x, f) for x in xs] == [shift_round(x, f) for x in xs], f
