"""The runtime's per-axis tick functions (servotune.laws.axis), driven tick by tick."""

from __future__ import annotations

import dataclasses

import numpy as np

from servotune.fixed import F_U, quantize, shift_round
from servotune.laws.axis import (
    FLAG_COUNTER_FAULT,
    FLAG_FOLLOWING_ERROR,
    FLAG_SATURATED,
    MODE_LOCK,
    MODE_OPEN,
    MODE_TASK,
    N_STATE,
    S_INTEG,
    AxisController,
    axis_control,
    axis_read,
)
from servotune.laws.pi import PIGains, pi_step


def _axis(pi: PIGains | None = None, fe: int = 0) -> tuple[np.ndarray, np.ndarray]:
    ctl = AxisController.from_gains(
        lock_gain_codes_per_count=0.4,
        task_gains=pi,
        period_s=0.004,
        following_error_limit_counts=fe,
    )
    c = ctl.consts(counter_bits=24, dac_bits=12, dac_zero=2048)[None, :].copy()
    return np.zeros((1, N_STATE), dtype=np.int64), c


def _tick(st, c, raw, ref=0, mode=MODE_LOCK, reset=False, u_add=0):
    y = axis_read(st, c, 0, raw, reset)
    code, flags, e = axis_control(st, c, 0, ref, mode, reset, u_add)
    return y, code, flags, e


def test_first_read_is_home_and_lock_pulls_back() -> None:
    st, c = _axis()
    y, code, flags, e = _tick(st, c, 0xFFFFF0)
    assert (y, code, flags, e) == (0, 2048, 0, 0)
    # 16 counts upward through the wrap: high byte 0xFF → 0x00 is an overflow, not a fault
    y, code, flags, e = _tick(st, c, 0x000000)
    assert y == 16 and flags == 0
    assert code == 2048 + round(0.4 * -16)  # lock: u = 0.4 codes/count · (0 − 16) = −6.4 → −6


def test_counter_fault_latches_mid_scale_until_reset() -> None:
    st, c = _axis()
    _tick(st, c, 0x100000)
    # the high byte jumps by 2 (0x10 → 0x12): more motion than the rule can explain
    y, code, flags, _ = _tick(st, c, 0x120000)
    assert flags & FLAG_COUNTER_FAULT and code == 2048
    for raw in (0x120001, 0x120002, 0x11FFFF):
        _, code, flags, _ = _tick(st, c, raw)
        assert flags & FLAG_COUNTER_FAULT and code == 2048  # latched: 0 V, flag kept
    y, code, flags, e = _tick(st, c, 0x11FFFF, reset=True)
    assert flags == 0 and code == 2048 and e == 0  # lock at the current position
    y2, code, flags, e = _tick(st, c, 0x120009)
    assert flags == 0 and y2 - y == 10 and e == -10


def test_following_error_trip_in_lock_too() -> None:
    st, c = _axis(fe=20)
    _tick(st, c, 1000)
    _, code, flags, _ = _tick(st, c, 1020)
    assert flags == 0 and code == 2048 - 8
    _, code, flags, e = _tick(st, c, 1021)
    assert flags & FLAG_FOLLOWING_ERROR and code == 2048 and e == -21


def test_open_mode_outputs_the_added_command_and_clamps() -> None:
    st, c = _axis()
    _tick(st, c, 0)
    _, code, flags, e = _tick(st, c, 5, mode=MODE_OPEN, u_add=300)
    assert (code, flags, e) == (2348, 0, 0)
    _, code, flags, _ = _tick(st, c, 9, mode=MODE_OPEN, u_add=-5000)
    assert code == 0 and flags & FLAG_SATURATED
    # back to lock: the target latches at the switch position
    _, code, flags, e = _tick(st, c, 12, mode=MODE_LOCK)
    assert (code, e) == (2048, 0)


def test_entering_task_is_bumpless_and_integrator_is_stored_as_output() -> None:
    st, c = _axis(PIGains(kp=1.3, ki=25.0))
    _tick(st, c, 0)
    _, lock_code, _, _ = _tick(st, c, 7)  # lock output −2.8 → −3 codes
    _, code, _, e = _tick(st, c, 7, ref=100, mode=MODE_TASK)
    assert e == 93 and code == lock_code  # first task output = lock's last
    # the stored integrator is that output minus the P term: I = u_lock − Kp·e
    kp = quantize(1.3)
    u_lock = shift_round(st[0, S_INTEG], F_U) + round(kp.value * 93)
    assert abs(u_lock - (lock_code - 2048)) <= 1


def test_conditional_integration_at_the_rails() -> None:
    g = PIGains(kp=2.0, ki=50.0).quantize(0.004)
    kp, kit = g.kp, g.ki_t
    integ0 = 1000 * 2**F_U  # the integrator already holds 1000 codes
    integ = integ0
    # a large error drives the output past the upper rail: no integration while it pushes on
    for _ in range(50):
        u, new = pi_step(kp.q, kp.f, kit.q, kit.f, integ, 5000, 0, 2048, 4095)
        assert shift_round(u, F_U) + 2048 > 4095
        assert new == integ
        integ = new
    assert integ == integ0
    # an error back toward the span integrates again at once
    u, new = pi_step(kp.q, kp.f, kit.q, kit.f, integ, -10, 0, 2048, 4095)
    assert new == integ0 + kit.q * -10 * 2 ** (F_U - kit.f)
    # below the rail the integrator accumulates Ki·T·e exactly (in F_U fraction bits)
    u, new = pi_step(kp.q, kp.f, kit.q, kit.f, 0, 100, 0, 2048, 4095)
    assert new == kit.q * 100 * 2 ** (F_U - kit.f)


# --- output filters (docs/runtime.md#filters-in-the-law) ------------------------------------


def _filtered_axis(*designs) -> tuple[np.ndarray, np.ndarray, tuple]:
    from servotune.laws.filters import realize

    secs = tuple(realize(d, 0.004) for d in designs)
    ctl = dataclasses.replace(
        AxisController.from_gains(lock_gain_codes_per_count=0.4, period_s=0.004), filters=secs
    )
    c = ctl.consts(counter_bits=24, dac_bits=12, dac_zero=2048)[None, :].copy()
    return np.zeros((1, N_STATE), dtype=np.int64), c, secs


def _float_chain(secs, x: np.ndarray) -> np.ndarray:
    """The sections' realised coefficients as floats, by scipy (an independent filter)."""
    from scipy.signal import lfilter

    y = x.astype(float)
    for s in secs:
        b, a = s.ba()
        y = lfilter(b, a, y)
    return y


def test_filters_shape_the_output_as_scipy_does() -> None:
    """Open mode, a chirp within ±1500 codes through a notch and a low-pass: the code equals
    scipy's float filter of the same quantised coefficients to the one final rounding."""
    from servotune.laws.filters import lowpass2, notch

    st, c, secs = _filtered_axis(notch(35.0, 10.0, -30.0), lowpass2(80.0, 0.5))
    k = np.arange(6000)
    x = np.round(1500 * np.sin(2 * np.pi * (2 + 100 * k / k.size) * k * 0.004)).astype(int)
    codes = np.array([_tick(st, c, 0, mode=MODE_OPEN, u_add=int(u))[1] for u in x])
    want = _float_chain(secs, x)
    assert np.max(np.abs(codes - 2048 - want)) <= 0.5 + 1e-6
    assert np.max(np.abs(want)) < 2000  # no rail touched: the comparison is linear


def test_filters_clamp_each_section_input_to_the_dac_range_and_flag_the_rail() -> None:
    """A low-pass with a resonant peak driven at a rail: the section's input is held to the
    D/A's range (−2048 … 2047 codes), its output rings above it and the code is clipped."""
    from servotune.laws.filters import lowpass2

    st, c, _ = _filtered_axis(lowpass2(20.0, 0.15))
    out = [_tick(st, c, 0, mode=MODE_OPEN, u_add=5000) for _ in range(200)]
    codes = [o[1] for o in out]
    assert max(codes) == 4095 and any(o[2] & FLAG_SATURATED for o in out)
    assert codes[-1] == 4095  # settles at the clamped input (+2047), rounded up to the rail


def test_a_reset_clears_the_filter_state() -> None:
    from servotune.laws.filters import notch

    st, c, _ = _filtered_axis(notch(35.0, 10.0, -30.0))
    for _ in range(50):
        _tick(st, c, 0, mode=MODE_OPEN, u_add=300)
    _tick(st, c, 0, reset=True)
    fresh_st, fresh_c, _ = _filtered_axis(notch(35.0, 10.0, -30.0))
    _tick(fresh_st, fresh_c, 0)
    a = [_tick(st, c, 0, mode=MODE_OPEN, u_add=-200)[1] for _ in range(20)]
    b = [_tick(fresh_st, fresh_c, 0, mode=MODE_OPEN, u_add=-200)[1] for _ in range(20)]
    assert a == b


def test_without_filters_the_output_is_the_plain_rounding() -> None:
    """No section: ``code = round(u · 2^-F_U) + zero`` exactly as before filters existed."""
    st, c = _axis()
    for u in (-7, 0, 3, 1999, -2048):
        _, code, _, _ = _tick(st, c, 0, mode=MODE_OPEN, u_add=u)
        assert code == min(max(u + 2048, 0), 4095)


# --- switching filters while running (docs/runtime.md#switching-filters-while-running) --------


def _chains():
    """Chains of sections realised at 4 ms for the 12-bit D/A: none, one notch, a re-tuned
    notch with a low-pass, four sections."""
    from servotune.laws.filters import lowpass2, notch, realize

    def q(*designs):
        return tuple(realize(d, 0.004) for d in designs)

    return (
        (),
        q(notch(15.0, 4.0, -25.0)),
        q(notch(13.5, 6.0, -20.0), lowpass2(60.0, 0.6)),
        q(
            notch(9.0, 3.0, -30.0),
            notch(22.0, 5.0, -15.0),
            lowpass2(45.0, 0.3),
            lowpass2(90.0, 0.7),
        ),
    )


def test_switching_filters_at_a_steady_output_moves_the_code_by_at_most_one_lsb() -> None:
    """Lock held off its target (a steady, fractional law output), every chain switched to every
    other, at 40 output levels across the D/A range: the code after each switch stays within
    1 LSB of the code before, for 300 ticks. Writing the constants without the bumpless state
    (the sections' state zeroed) moves it by hundreds of codes: the test can fail."""
    from servotune.laws.axis import filter_block, switch_filters

    chains = _chains()
    rng = np.random.default_rng(5)
    worst, worst_naive = 0, 0
    for level in rng.uniform(-2040.0, 2040.0, 40):
        raw = round(-level / 0.4) & 0xFFFFFF  # lock gain 0.4 codes/count: u = −0.4·y
        i, j = rng.choice(len(chains), 2, replace=False)
        for naive in (False, True):
            st, c = _axis()
            _tick(st, c, 0)  # home
            switch_filters(st, c, 0, filter_block(chains[i]))
            codes = [_tick(st, c, raw)[1] for _ in range(400)]  # settled on chain i
            if naive:
                c[0, 24:49] = filter_block(chains[j])  # C_NF … C_TAB, state left as it is
                st[0, 12:36] = 0
            else:
                switch_filters(st, c, 0, filter_block(chains[j]))
            after = [_tick(st, c, raw)[1] for _ in range(300)]
            bump = max(abs(a - codes[-1]) for a in after)
            if naive:
                worst_naive = max(worst_naive, bump if chains[j] else 0)
            else:
                worst = max(worst, bump)
            assert codes[-1] == codes[-2]  # steady before the switch
    assert worst <= 1
    assert worst_naive > 100


def test_switching_a_filter_in_during_a_move_follows_the_new_chain() -> None:
    """After a switch the law runs the new chain: from the switch on, the codes equal an axis
    that had the new chain all along once both have settled on the same steady input, and the
    switched-out chain's constants are gone (its slots are zero)."""
    from servotune.laws.axis import C_FILT, C_NF, N_CONST, filter_block, switch_filters

    chains = _chains()
    st, c = _axis()
    _tick(st, c, 0)
    switch_filters(st, c, 0, filter_block(chains[3]))
    for k in range(200):
        _tick(st, c, 0, mode=MODE_OPEN, u_add=int(800 * np.sin(k / 9.0)))
    switch_filters(st, c, 0, filter_block(chains[1]))
    assert c[0, C_NF] == 1 and not np.any(c[0, C_FILT + 6 : N_CONST])
    ref_st, ref_c = _axis()
    _tick(ref_st, ref_c, 0)
    switch_filters(ref_st, ref_c, 0, filter_block(chains[1]))
    a = [_tick(st, c, 0, mode=MODE_OPEN, u_add=-700)[1] for _ in range(600)]
    b = [_tick(ref_st, ref_c, 0, mode=MODE_OPEN, u_add=-700)[1] for _ in range(600)]
    assert a[-100:] == b[-100:] == [2048 - 700] * 100
    assert a[:50] != b[:50]  # the switched axis started from its own past


def test_filter_block_refuses_more_than_four_sections() -> None:
    import pytest

    from servotune.laws.axis import filter_block

    secs = _chains()[3]
    with pytest.raises(ValueError, match="at most 4"):
        filter_block(secs + secs[:1])
    with pytest.raises(ValueError, match="SectionQ"):
        filter_block(("notch",))
