"""Input shapers on the tick grid (servotune.laws.shaping, docs/runtime.md#input-shaping).

The oracles are independent of the design code: the residual vibration is measured on the step
response of the continuous second-order mode computed by ``scipy.signal.step`` and superposed
at the impulse times; the integer step is compared with a plain-Python convolution in exact
integers and the half-away-from-zero rounding written out here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from servotune.errors import SpecError
from servotune.laws.shaping import (
    EI_TOLERANCE,
    KINDS,
    MAX_REFERENCE,
    SHAPER_FRAC_BITS,
    design_shaper,
    shape_reference,
    shaper_for_modes,
    shaper_state,
    shaper_step,
)

GRID = [
    (period_s, freq_hz, damping)
    for period_s in (0.004, 0.001)
    for freq_hz in (2.0, 10.0, 35.0, 60.0, 100.0, 400.0)
    for damping in (0.0, 0.04, 0.1)
    if freq_hz < 0.45 / period_s
]
"""4 ms and 1 ms ticks (the example rig's loop and the gantry's bus loop), modes from 2 Hz to
0.45 of the sampling rate, undamped to 10 % damped."""


def _measured_residual(
    amplitudes_q: tuple[int, ...], period_s: float, freq_hz: float, damping: float
) -> float:
    """The shaped step's vibration at its end (the last impulse) over the unshaped step's at its
    end (t = 0), ``y`` the response of
    ω² / (s² + 2ζωs + ω²) simulated by ``scipy.signal.lsim`` (input held between samples: the
    shaped step is a staircase on the tick grid; at least 400 samples per period of the mode)."""
    w = 2 * math.pi * freq_hz
    sys = signal.lti([w * w], [1.0, 2 * damping * w, w * w])
    a = np.asarray(amplitudes_q, dtype=float) / (1 << SHAPER_FRAC_BITS)
    sub = max(1, math.ceil(400 * freq_hz * period_s))  # at least 400 samples per period
    t_last = (a.size - 1) * period_s
    t_end = t_last + 2 * 2 * math.pi / (w * math.sqrt(1 - damping**2))
    n = math.ceil(t_end / period_s) * sub + 1
    t = np.arange(n) * (period_s / sub)
    tick = np.minimum(np.arange(n) // sub, a.size - 1)
    shaped_u = np.cumsum(a)[tick]
    after = t >= t_last - 1e-12
    _, shaped, _ = signal.lsim(sys, shaped_u, t, interp=False)
    _, unshaped, _ = signal.lsim(sys, np.ones(n), t, interp=False)
    # after the last impulse y − 1 is a free damped oscillation: its amplitude at t_last by a
    # least-squares fit of e^{−σ(t − t_last)} (a cos ω_d t + b sin ω_d t), phase-independent
    ta = t[after]
    env = np.exp(-damping * w * (ta - t_last))
    wd = w * math.sqrt(1 - damping**2)
    basis = np.stack([env * np.cos(wd * ta), env * np.sin(wd * ta)], axis=1)

    def amplitude(y: np.ndarray) -> float:
        return float(np.hypot(*np.linalg.lstsq(basis, y[after] - 1, rcond=None)[0]))

    # each move's vibration at its own end (Singer and Seering's convention): the unshaped
    # step's amplitude at t = 0 is its fitted one at t_last grown back by e^{σ t_last}
    return amplitude(shaped) / (amplitude(unshaped) * math.exp(damping * w * t_last))


@pytest.mark.parametrize(("period_s", "freq_hz", "damping"), GRID)
@pytest.mark.parametrize("kind", KINDS)
def test_the_shapers_cancel_the_mode_on_the_tick_grid(
    kind: str, period_s: float, freq_hz: float, damping: float
) -> None:
    """Every impulse on a whole tick, amplitudes non-negative, in Q15 summing to exactly 2^15;
    the residual vibration measured on scipy's step response: zv and zvd ≤ 1 % at the mode
    (the Q15 rounding leaves a little), ei at most its tolerance; over ±15 % of the mode the
    robust ones stay ≤ 5.5 % (zvd: the textbook undamped zvd reaches 5.4 % at ±15 %) and
    ei ≤ its tolerance plus 0.5 %; zv alone is not robust (more than 10 % at ±15 %)."""
    sh = design_shaper(kind, freq_hz, damping, period_s)
    assert sum(sh.amplitudes_q) == 1 << SHAPER_FRAC_BITS
    assert min(sh.amplitudes_q) >= 0 and sh.amplitudes_q[-1] > 0
    assert sh.added_time_s == pytest.approx((sh.n_taps - 1) * period_s)
    at_mode = _measured_residual(sh.amplitudes_q, period_s, freq_hz, damping)
    assert at_mode == pytest.approx(sh.residual(freq_hz, damping), abs=0.01)
    if kind == "ei":
        assert at_mode <= EI_TOLERANCE + 0.005
    else:
        assert at_mode <= 0.01
    band = [
        _measured_residual(sh.amplitudes_q, period_s, freq_hz * r, damping)
        for r in (0.85, 0.9, 0.95, 1.05, 1.1, 1.15)
        if freq_hz * r < 0.5 / period_s
    ]
    if kind == "zv":
        assert max(band) > 0.10
    elif kind == "zvd":
        assert max(band) <= 0.055
    else:
        assert max(band) <= EI_TOLERANCE + 0.005


def test_the_shapers_length_is_what_the_mode_asks() -> None:
    """The textbook lengths at a 35 Hz mode, 4 ms tick: zv half a damped period (14.3 ms), zvd
    and ei one period (28.6 ms), rounded up to whole ticks."""
    half = 0.5 / 35.0
    for kind, want in (("zv", half), ("zvd", 2 * half), ("ei", 2 * half)):
        sh = design_shaper(kind, 35.0, 0.0, 0.004)
        assert want <= sh.added_time_s < want + 0.004 + 1e-12, (kind, sh.added_time_s)


def test_two_modes_take_the_product() -> None:
    """One shaper per mode, convolved: each mode cancelled, the lengths add."""
    modes = [(35.0, 0.04), (80.0, 0.05)]
    sh = shaper_for_modes(["zvd", "zv"], modes, 0.004)
    one = design_shaper("zvd", 35.0, 0.04, 0.004)
    two = design_shaper("zv", 80.0, 0.05, 0.004)
    assert sh.n_taps == one.n_taps + two.n_taps - 1
    for f, z in modes:
        assert _measured_residual(sh.amplitudes_q, 0.004, f, z) <= 0.01


def _reference_shape(ref: np.ndarray, a_q: tuple[int, ...]) -> list[int]:
    """The integer step written out: exact Python integers, history primed with the first
    reference, half away from zero."""
    out = []
    n = len(a_q)
    hist = [int(ref[0])] * n
    for r in ref:
        hist = [int(r), *hist[:-1]]
        acc = sum(a * h for a, h in zip(a_q, hist, strict=True))
        q, rem = divmod(abs(acc), 1 << SHAPER_FRAC_BITS)
        q += 1 if 2 * rem >= 1 << SHAPER_FRAC_BITS else 0
        out.append(q if acc >= 0 else -q)
    return out


def test_the_integer_step_is_the_exact_convolution_rounded() -> None:
    rng = np.random.default_rng(5)
    sh = shaper_for_modes(["ei", "zv"], [(35.0, 0.04), (80.0, 0.02)], 0.004)
    ref = np.concatenate(
        [
            np.cumsum(rng.integers(-300, 301, 3000)),
            rng.integers(-(1 << 46), 1 << 46, 500),
            np.full(100, -(MAX_REFERENCE - 1)),
        ]
    )
    got = shape_reference(ref, sh)
    assert got.tolist() == _reference_shape(ref, sh.amplitudes_q)
    st = shaper_state(sh.n_taps)
    taps = np.asarray(sh.amplitudes_q, dtype=np.int64)
    one_by_one = [shaper_step(taps, st, int(r)) for r in ref[:200]]
    assert one_by_one == got[:200].tolist()


def test_a_constant_reference_passes_to_the_count_and_a_move_stays_monotone() -> None:
    sh = design_shaper("zvd", 35.0, 0.04, 0.004)
    assert shape_reference(np.full(50, 1234567), sh).tolist() == [1234567] * 50
    ramp = np.concatenate([np.zeros(10), np.arange(0, 5000, 37), np.full(30, 4995)])
    shaped = shape_reference(ramp.astype(np.int64), sh)
    assert np.all(np.diff(shaped) >= 0)
    assert shaped[-1] == 4995 and shaped[0] == 0


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"kind": "zvdd"}, "kind must be one of"),
        ({"freq_hz": 125.0}, "freq_hz must be in (0, 125) Hz"),
        ({"freq_hz": -1.0}, "freq_hz"),
        ({"damping": 1.0}, "damping must be in [0, 1)"),
        ({"freq_hz": 0.1}, "more than 1024"),
    ],
)
def test_a_bad_shaper_is_one_clear_error(kwargs: dict, words: str) -> None:
    args = {"kind": "zvd", "freq_hz": 35.0, "damping": 0.04, "period_s": 0.004} | kwargs
    with pytest.raises(SpecError, match=None) as e:
        design_shaper(**args)
    assert words in str(e.value)


def test_a_reference_beyond_the_sum_is_refused() -> None:
    sh = design_shaper("zv", 35.0, 0.04, 0.004)
    with pytest.raises(SpecError, match="2\\^47"):
        shape_reference(np.array([MAX_REFERENCE]), sh)
