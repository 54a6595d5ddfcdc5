"""The composite law (fuzzy-PID + feedforward differential) in the runtime arithmetic."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from servotune.laws.axis import (
    FLAG_SATURATED,
    LAW_FUZZY_PID,
    MODE_LOCK,
    MODE_TASK,
    N_STATE,
    AxisController,
    axis_control,
    axis_read,
)
from servotune.laws.fuzzy_pid import TABLE_NAMES, FuzzyPIDConstants, FuzzyPIDGains
from servotune.laws.pi import PIGains

# the example rig's achieved 8253 period (docs/runtime.md#timer-and-achieved-period)
PERIOD_S = 0.004000235


def _controller(task: object) -> AxisController:
    return AxisController.from_gains(
        lock_gain_codes_per_count=0.4, task_gains=task, period_s=PERIOD_S
    )


def _state(ctl: AxisController) -> tuple[np.ndarray, np.ndarray]:
    c = ctl.consts(counter_bits=24, dac_bits=12, dac_zero=2048)[None, :].copy()
    return np.zeros((1, N_STATE), dtype=np.int64), c


def _run(ctl: AxisController, raws, refs, modes) -> tuple[list[int], list[int]]:
    st, c = _state(ctl)
    codes, flags = [], []
    for raw, ref, mode in zip(raws, refs, modes, strict=True):
        axis_read(st, c, 0, int(raw), False)
        code, fl, _ = axis_control(st, c, 0, int(ref), int(mode), False, 0)
        codes.append(code)
        flags.append(fl)
    return codes, flags


def _random_tables(rng: np.random.Generator, n: int, scale: dict[str, float]) -> dict:
    size = 2 * n + 1
    return {"d" + t: rng.uniform(-1.0, 1.0, (size, size)) * scale[t] for t in TABLE_NAMES}


# --- an independent reference: Python integers, the runtime's formulas written out -----------


def _rha_shift(x: int, f: int) -> int:
    """x · 2^−f rounded half away from zero (Python ints: exact)."""
    if f == 0:
        return x
    m = abs(x)
    r = (m + (1 << (f - 1))) >> f
    return r if x >= 0 else -r


def _clamp(x: int, lo: int, hi: int) -> int:
    return max(lo, min(hi, x))


def _reference_law(k: FuzzyPIDConstants, errors, refs, f_u: int = 32) -> list[int]:
    """Codes of the composite law for an error/reference sequence (task mode from tick 0).

    Tick 0 enters the task from lock with u_last = 0 (bumpless: I = −Kp·e, no derivative or
    feedforward); later ticks follow docs/runtime.md. No term here comes near saturation.
    """
    n = k.n
    em = 2**31 - 1
    integ = 0
    codes = []
    e_prev, r_prev = 0, 0
    for i, (e, r) in enumerate(zip(errors, refs, strict=True)):
        ec = 0 if i == 0 else e - e_prev
        dr = 0 if i == 0 else r - r_prev
        e_c, ec_c, dr_c = (_clamp(v, -em, em) for v in (e, ec, dr))
        lv_e = _clamp(_rha_shift(e_c * k.ke.q, k.ke.f), -n, n)
        lv_ec = _clamp(_rha_shift(ec_c * k.kec.q, k.kec.f), -n, n)
        g = {}
        for name, base, (q, f_t) in zip(TABLE_NAMES, k.bases, k.tables, strict=True):
            # row = E level, column = EC level (unequal Ke, Kec catch a transposed lookup)
            g[name] = (base.q + int(q[lv_e + n, lv_ec + n]) * 2 ** (base.f - f_t), base.f)
        p = g["kp"][0] * e_c * 2 ** (f_u - g["kp"][1])
        d = g["kd"][0] * ec_c * 2 ** (f_u - g["kd"][1])
        ff = g["k1"][0] * dr_c * 2 ** (f_u - g["k1"][1])
        if i == 0:
            integ = -p  # u_last = 0
        else:
            d_i = g["ki"][0] * e_c * 2 ** (f_u - g["ki"][1])
            raw = _rha_shift(p + integ + d_i + d + ff, f_u) + 2048
            if not ((raw > 4095 and d_i > 0) or (raw < 0 and d_i < 0)):
                integ = _clamp(integ + d_i, -2048 * 2**f_u, 2047 * 2**f_u)
        u = p + integ + d + ff
        codes.append(_clamp(_rha_shift(u, f_u) + 2048, 0, 4095))
        e_prev, r_prev = e, r
    return codes


def _gains(rng: np.random.Generator, n: int = 6, **kw) -> FuzzyPIDGains:
    base = dict(kp0=0.6, ki0=2.0, kd0=0.004, k10=0.0167, ke=0.03, kec=0.5, n=n)
    base.update(kw)
    tabs = _random_tables(rng, n, {"kp": 0.3, "ki": 1.5, "kd": 0.003, "k1": 0.004})
    return FuzzyPIDGains(**base, **tabs)


@pytest.mark.parametrize("n", [3, 6])
def test_integer_law_equals_independent_reference(n: int) -> None:
    rng = np.random.default_rng(7)
    gains = _gains(rng, n=n)
    ctl = _controller(gains)
    assert ctl.law == LAW_FUZZY_PID
    k = ctl.task
    # positions: the slave wanders around a moving reference; errors cover every level of E and EC
    t = np.arange(3000)
    refs = (20.0 * t + 400.0 * np.sin(t / 37.0)).astype(np.int64)
    ys = refs - rng.integers(-300, 300, t.size)
    ys[0] = 0  # first read is home: extended position 0
    refs[0] = ys[0] + 25
    raws = (ys + 5000) & 0xFFFFFF
    codes, _ = _run(ctl, [raws[0], *raws], [0, *refs], [MODE_LOCK] + [MODE_TASK] * t.size)
    expected = _reference_law(k, (refs - ys).tolist(), refs.tolist())
    # the first task tick follows a lock tick at code 2048 (u_last = 0)
    assert codes[0] == 2048
    assert codes[1:] == expected


def test_reference_law_catches_a_transposed_table() -> None:
    # guard on the reference itself: with Ke != Kec, reading the tables transposed changes codes
    rng = np.random.default_rng(3)
    gains = _gains(rng)
    k = _controller(gains).task
    flipped = dataclasses.replace(k, tables=tuple((q.T.copy(), f) for q, f in k.tables))
    errs = rng.integers(-300, 300, 400).tolist()
    refs = np.cumsum(rng.integers(0, 40, 400)).tolist()
    assert _reference_law(k, errs, refs) != _reference_law(flipped, errs, refs)


def test_zero_tables_no_derivative_no_feedforward_is_the_pi_law() -> None:
    # conventional PI is the composite law with zero tables, Kd = 0 and K1 = 0
    pi = PIGains(kp=0.8, ki=3.0)
    fz = FuzzyPIDGains(kp0=0.8, ki0=3.0, ke=0.02, kec=0.3)
    rng = np.random.default_rng(1)
    ys = np.cumsum(rng.integers(-40, 60, 2000))
    ys[0] = 0
    refs = np.cumsum(np.full(2000, 12))
    raws = ys & 0xFFFFFF
    modes = [MODE_LOCK] * 50 + [MODE_TASK] * 1900 + [MODE_LOCK] * 50
    a = _run(_controller(pi), raws, refs, modes)
    b = _run(_controller(fz), raws, refs, modes)
    assert a == b
    assert any(f & FLAG_SATURATED for f in a[1])  # the rails were exercised too


def test_entry_is_bumpless_and_feedforward_acts_from_the_next_tick() -> None:
    rng = np.random.default_rng(5)
    gains = _gains(rng)
    ctl = _controller(gains)
    st, c = _state(ctl)
    # lock holds against a 30-count disturbance, then the task starts with a moving reference
    for raw in (1000, 1030, 1030):
        axis_read(st, c, 0, raw, False)
        code_lock, _, _ = axis_control(st, c, 0, 0, MODE_LOCK, False, 0)
    axis_read(st, c, 0, 1030, False)
    code_in, _, _ = axis_control(st, c, 0, 500, MODE_TASK, False, 0)
    assert code_in == code_lock  # no kick from Kp·e, derivative or feedforward
    axis_read(st, c, 0, 1030, False)
    code_next, _, _ = axis_control(st, c, 0, 540, MODE_TASK, False, 0)
    # the reference moved 40 counts: the feedforward (K1/T ≈ 4.2 codes per count/tick) acts
    assert code_next - code_in > 100


def test_design_terms_within_quantisation() -> None:
    # the integer law against the design formula in floats, one task tick after entry
    rng = np.random.default_rng(11)
    gains = _gains(rng)
    k = _controller(gains).task
    e0, e1, r0, r1 = 40, 55, 1000, 1030
    codes = _reference_law(k, [e0, e1], [r0, r1])
    n = gains.n
    lv_e = int(np.clip(np.round(e1 * gains.ke), -n, n))
    lv_ec = int(np.clip(np.round((e1 - e0) * gains.kec), -n, n))
    g = {
        t: getattr(gains, t + "0") + getattr(gains, "d" + t)[lv_e + n, lv_ec + n]
        for t in TABLE_NAMES
    }
    kp_e0 = (gains.kp0 + gains.dkp[n + round(e0 * gains.ke), n]) * e0
    integ = -kp_e0 + g["ki"] * PERIOD_S * e1
    u = g["kp"] * e1 + integ + g["kd"] * (e1 - e0) / PERIOD_S + g["k1"] * (r1 - r0) / PERIOD_S
    assert abs(codes[1] - (round(u) + 2048)) <= 1


def test_negative_scheduled_gain_is_refused() -> None:
    with pytest.raises(ValueError, match="kp0 \\+ min Δkp must be >= 0"):
        FuzzyPIDGains(kp0=0.1, ki0=1.0, ke=0.1, kec=0.1, n=1, dkp=np.full((3, 3), -0.2))
    with pytest.raises(ValueError, match="ke must be > 0"):
        FuzzyPIDGains(kp0=0.1, ki0=1.0, ke=0.0, kec=0.1)
    with pytest.raises(ValueError, match="shape \\(13, 13\\)"):
        FuzzyPIDGains(kp0=0.1, ki0=1.0, ke=0.1, kec=0.1, dkd=np.zeros((13, 12)))


def test_constants_round_trip_and_compare_by_value() -> None:
    rng = np.random.default_rng(2)
    k = _controller(_gains(rng)).task
    back = FuzzyPIDConstants.from_dict(k.to_dict())
    assert back == k and hash(back) == hash(k)
    for (q1, f1), (q2, f2) in zip(k.tables, back.tables, strict=True):
        assert f1 == f2 and np.array_equal(q1, q2) and q2.dtype == np.int16
    other = _controller(_gains(np.random.default_rng(99))).task
    assert other != k  # tables differ: not equal even though every scalar field matches
    for name, base, (_, f_t) in zip(TABLE_NAMES, k.bases, k.tables, strict=True):
        # docs/runtime.md#fuzzy-levels-and-scheduled-gains: table fraction bits never exceed the
        # base's
        assert f_t <= base.f, name
