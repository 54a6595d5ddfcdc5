"""Experiment design (servotune.excite): excitations within the D/A, speed and travel limits.

Every designed excitation is played on the virtual rig (the engine, with friction, drift and
encoder noise) and checked there, not only against the design's own prediction.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import servotune as st
from servotune.errors import LogFormatError, SpecError
from servotune.excite import (
    KINDS,
    Excitation,
    design_excitation,
    excitation_inputs,
    multisine_bins,
    multisine_codes,
    read_excitation,
    write_excitation,
)
from servotune.laws.axis import MODE_LOCK, MODE_OPEN
from servotune.rig import Dac

# plants/pc-dual-servo.toml: 600 r/min × 3072 pulses/rev × 4 (x4) / 60 = 122,880 counts/s
SPEED_LIMIT_CPS = 122_880.0
# 10 s at the achieved period 4.000235 ms (divisor 4773, docs/runtime.md#timer-and-achieved-period)
# rounds to 2500 ticks
N_10S = 2500


def _with_master(rig: st.Rig, **changes: object) -> st.Rig:
    master = dataclasses.replace(rig.axis("master"), **changes)
    return dataclasses.replace(rig, axes=(master, rig.axis("slave")))


def _tight(rig: st.Rig) -> st.Rig:
    return _with_master(rig, travel_counts=(-2000, 2000))


def _rotary(rig: st.Rig) -> st.Rig:
    return _with_master(rig, travel_counts=None)


VARIANTS = {"example": lambda r: r, "tight": _tight, "rotary": _rotary}


def _play(rig: st.Rig, ex: Excitation, closed_loop: bool = False) -> st.Trace:
    inputs = excitation_inputs(rig, ex.axis, ex.absolute_codes, closed_loop=closed_loop)
    return st.simulate(st.Loop.from_rig(rig), inputs, seed=0)


# --- the designed excitations, played on the virtual rig -----------------------------------


@pytest.mark.parametrize("variant", sorted(VARIANTS))
@pytest.mark.parametrize("kind", KINDS)
def test_excitation_plays_within_dac_speed_and_travel(rig: st.Rig, kind: str, variant: str) -> None:
    r = VARIANTS[variant](rig)
    ex = design_excitation(r, "master", kind, 10.0, seed=0)
    assert ex.n_ticks == N_10S
    codes = ex.absolute_codes
    assert codes.dtype == np.int64
    assert codes.min() >= 0 and codes.max() <= 4095  # 12-bit D/A (PCL728)

    tr = _play(r, ex)
    i = tr.axis("master")
    speed, pos = tr.speed_cps[:, i], tr.pos_counts[:, i]
    # the hard limits hold on the simulated rig; the design kept 10 % free
    assert np.max(np.abs(speed)) <= SPEED_LIMIT_CPS
    assert ex.predicted_max_speed_rpm <= 0.9 * 600.0 * (1 + 1e-12)
    travel = r.axis("master").travel_counts
    if travel is not None:
        assert travel[0] <= pos.min() and pos.max() <= travel[1]
        lo, hi = ex.predicted_travel_counts
        assert 0.9 * travel[0] - 1e-9 <= lo and hi <= 0.9 * travel[1] + 1e-9
    # the prediction (nominal plant, no friction) matches the rig: friction (2 mV) and noise
    # (0.3 counts) only; the predicted travel adds the coast-down after the last tick
    pred_cps = ex.predicted_max_speed_rpm / 60.0 * 12288.0
    np.testing.assert_allclose(np.max(np.abs(speed)), pred_cps, rtol=0.02)
    lo, hi = ex.predicted_travel_counts
    slack = 0.01 * max(abs(lo), abs(hi)) + 5.0
    assert lo - slack <= pos.min() and pos.max() <= hi + slack
    assert np.ptp(pos) >= 0.9 * (hi - lo)
    # direction reversals: the speed swings both ways, many times
    assert speed.max() > 0.5 * pred_cps and speed.min() < -0.5 * pred_cps
    big = speed[np.abs(speed) > 0.25 * pred_cps]
    assert np.count_nonzero(np.diff(np.sign(big))) >= 4
    # the other axis stays in lock: within ±1 pulse (±4 counts at x4,
    # docs/runtime.md#position-lock-and-its-holding-band)
    assert np.ptp(tr.pos_counts[:, tr.axis("slave")]) <= 8


def test_step_amplitude_set_by_the_speed_limit(rig: st.Rig) -> None:
    # steady speed of a level (docs/formats.md#axis-model): K (A·LSB + offset_v) <= 0.9 · limit, so
    # A = floor((0.9 · 122880 / 12288 − 0.005) / (20 / 4096)) = floor(1842.18) = 1842
    ex = design_excitation(rig, "master", "steps", 10.0)
    assert ex.amplitude_codes == 1842
    assert ex.limited_by == "speed"
    # 12288 counts/s/V over 12288 counts/rev: 60 r/min per volt; a 0.25 s level is 10 tau, so
    # the speed settles within 1.5 · 2 · exp(−10) ≈ 1.4e-4 of that (the step from −A/2 to +A)
    np.testing.assert_allclose(
        ex.predicted_max_speed_rpm, (1842 * 20 / 4096 + 0.005) * 60.0, rtol=2e-4
    )


@pytest.mark.parametrize("kind", KINDS)
def test_tight_travel_gives_a_smaller_valid_excitation(rig: st.Rig, kind: str) -> None:
    wide = design_excitation(rig, "master", kind, 10.0)
    tight = design_excitation(_tight(rig), "master", kind, 10.0)
    assert tight.limited_by == "travel"
    assert 1 <= tight.amplitude_codes < wide.amplitude_codes / 5
    lo, hi = tight.predicted_travel_counts
    assert -1800.0 - 1e-9 <= lo and hi <= 1800.0 + 1e-9
    # travel is the binding limit: the design uses most of the 90 %
    assert max(-lo, hi) >= 0.9 * 1800.0


def test_rotary_axis_is_not_travel_limited(rig: st.Rig) -> None:
    for kind in KINDS:
        ex = design_excitation(_rotary(rig), "master", kind, 60.0)
        assert ex.limited_by in ("speed", "dac")


def test_requested_amplitude_is_kept_when_it_fits(rig: st.Rig) -> None:
    ex = design_excitation(rig, "slave", "prbs", 5.0, amplitude_codes=200)
    assert ex.amplitude_codes == 200 and ex.limited_by == "requested"
    assert set(np.unique(ex.codes).tolist()) == {-200, 200}
    big = design_excitation(rig, "slave", "prbs", 5.0, amplitude_codes=100_000)
    assert big.amplitude_codes <= 2047 and big.limited_by in ("dac", "speed")


def test_closed_loop_play_keeps_the_axis_nearer_home(rig: st.Rig) -> None:
    ex = design_excitation(_tight(rig), "master", "prbs", 10.0)
    i = rig.axis_names.index("master")
    open_tr, closed_tr = _play(rig, ex), _play(rig, ex, closed_loop=True)
    assert np.ptp(closed_tr.pos_counts[:, i]) < np.ptp(open_tr.pos_counts[:, i])
    # open loop writes exactly the designed codes (D/A as written, docs/runtime.md#da-quantisation)
    np.testing.assert_array_equal(open_tr.code[:, i], ex.absolute_codes)


# --- signals -------------------------------------------------------------------------------


def test_multisine_lines_log_grid_flat_and_zero_mean(rig: st.Rig) -> None:
    period = rig.period_s
    bins = multisine_bins(N_10S, period)
    f = bins / (N_10S * period)
    # ~0.2 Hz to 0.4 · Nyquist (0.4 · 125 Hz = 50 Hz), ~10 lines per decade
    np.testing.assert_allclose(f[0], 0.2, rtol=1e-3)
    assert f[-1] <= 0.4 * 0.5 / period + 1e-9 and f[-1] > 0.35 * 0.5 / period
    assert 20 <= bins.size <= 30
    c = multisine_codes(N_10S, period, 1000)
    assert np.max(np.abs(c)) == 1000
    spec = np.abs(np.fft.rfft(c.astype(float)))
    # energy only on the designed lines (rounding to codes leaves < 1 % elsewhere)
    assert set(np.flatnonzero(spec > 0.05 * spec.max()).tolist()) == set(bins.tolist())
    np.testing.assert_allclose(spec[bins], spec[bins].mean(), rtol=0.01)  # equal amplitudes
    assert abs(c.mean()) < 0.01  # no DC: whole periods in the record


def test_prbs_is_the_scenario_sequence_held_a_time_constant(rig: st.Rig) -> None:
    ex = design_excitation(_rotary(rig), "master", "prbs", 10.0, amplitude_codes=100)
    # hold = round(tau_s / period_s) = round(0.025 / 0.004000235) = 6 ticks
    changes = np.flatnonzero(np.diff(ex.codes)) + 1
    runs = np.diff(changes)
    assert np.all(runs % 6 == 0)
    assert runs.min() == 6


def test_short_request_is_still_valid(rig: st.Rig) -> None:
    # 10 ticks is the shortest excitation
    for kind in KINDS:
        ex = design_excitation(rig, "master", kind, 10 * rig.period_s)
        assert ex.n_ticks == 10
        assert ex.codes.max() > 0 > ex.codes.min()


# --- determinism and files -----------------------------------------------------------------


@pytest.mark.parametrize("kind", KINDS)
def test_same_seed_same_bytes(tmp_path: Path, rig: st.Rig, kind: str) -> None:
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    write_excitation(a, design_excitation(rig, "master", kind, 3.0, seed=7), rig)
    write_excitation(b, design_excitation(rig, "master", kind, 3.0, seed=7), rig)
    assert a.read_bytes() == b.read_bytes()


def test_prbs_seed_changes_the_sequence(rig: st.Rig) -> None:
    a = design_excitation(rig, "master", "prbs", 10.0, seed=0, amplitude_codes=50)
    b = design_excitation(rig, "master", "prbs", 10.0, seed=1, amplitude_codes=50)
    assert not np.array_equal(a.codes, b.codes)


def test_write_read_round_trip(tmp_path: Path, rig: st.Rig) -> None:
    ex = design_excitation(rig, "slave", "multisine", 3.0)
    path = tmp_path / "excitation.csv"
    write_excitation(path, ex, rig)
    text = path.read_text(encoding="utf-8")
    lines = text.splitlines()
    assert lines[0] == "# rig: pc-dual-servo"
    assert "# period_s: 0.0040002346670242545" in lines  # repr of the achieved period
    assert "# axis: slave" in lines and "# kind: multisine" in lines
    assert "# dac_bits: 12" in lines and "# dac_range_v: -10,10" in lines
    assert "tick,time_s,slave.dac_code" in lines
    axis, codes = read_excitation(path, rig)
    assert axis == "slave"
    np.testing.assert_array_equal(codes, ex.absolute_codes)
    # the codes read back play the same inputs
    inp = excitation_inputs(rig, axis, codes)
    np.testing.assert_array_equal(inp.dac_add_codes[:, rig.axis_names.index("slave")], ex.codes)


def test_excitation_inputs_open_and_closed(rig: st.Rig) -> None:
    codes = np.array([2048, 2100, 1990, 0, 4095, 2048, 2048, 2050, 2040, 2048], dtype=np.int64)
    m, s = rig.axis_names.index("master"), rig.axis_names.index("slave")
    for closed, mode in ((False, MODE_OPEN), (True, MODE_LOCK)):
        inp = excitation_inputs(rig, "slave", codes, closed_loop=closed)
        assert inp.n_ticks == 10 and inp.n_axes == 2
        np.testing.assert_array_equal(inp.dac_add_codes[:, s], codes - 2048)
        assert np.all(inp.mode[:, s] == mode)
        assert np.all(inp.mode[:, m] == MODE_LOCK) and np.all(inp.dac_add_codes[:, m] == 0)
    with pytest.raises(SpecError, match="D/A range"):
        excitation_inputs(rig, "slave", codes + 1)
    with pytest.raises(SpecError, match="integer"):
        excitation_inputs(rig, "slave", codes.astype(float))
    with pytest.raises(st.RigError, match="no axis"):
        excitation_inputs(rig, "spindle", codes)


# --- reading: every error names its problem ------------------------------------------------


def _good(tmp_path: Path, rig: st.Rig) -> str:
    path = tmp_path / "good.csv"
    write_excitation(path, design_excitation(rig, "master", "steps", 0.1), rig)
    return path.read_text(encoding="utf-8")


def _edit_rows(text: str, fn) -> str:
    out = []
    for ln in text.splitlines():
        out.append(ln if ln.startswith("#") else fn(ln))
    return "\n".join(out) + "\n"


def _set_row(text: str, row: int, value: str) -> str:
    lines = text.splitlines()
    first = next(i for i, ln in enumerate(lines) if ln.startswith("tick,"))
    cells = lines[first + 1 + row].split(",")
    cells[-1] = value
    lines[first + 1 + row] = ",".join(cells)
    return "\n".join(lines) + "\n"


READ_ERRORS = {
    "no_dac_code_column": (
        lambda t: _edit_rows(t, lambda ln: ln.rsplit(",", 1)[0]),
        "no <axis>.dac_code column",
    ),
    "extra_column": (
        lambda t: _edit_rows(t, lambda ln: ln + (",master.counter" if ln[0] == "t" else ",0")),
        "unexpected column 'master.counter'",
    ),
    "two_axes": (
        lambda t: _edit_rows(t, lambda ln: ln + (",slave.dac_code" if ln[0] == "t" else ",2048")),
        "more than one dac_code column",
    ),
    "unknown_axis": (
        lambda t: t.replace("master.dac_code", "spindle.dac_code").replace(
            "# axis: master", "# axis: spindle"
        ),
        "no axis 'spindle'",
    ),
    "axis_disagrees_with_metadata": (
        lambda t: t.replace("# axis: master", "# axis: slave"),
        "metadata axis 'slave' disagrees",
    ),
    "code_above_range": (lambda t: _set_row(t, 3, "4096"), "code 4096 outside the D/A range"),
    "code_below_range": (lambda t: _set_row(t, 3, "-1"), "code -1 outside the D/A range"),
    "fractional_code": (lambda t: _set_row(t, 4, "2048.5"), "'2048.5' is not an integer"),
    "text_code": (
        lambda t: _set_row(t, 4, "abc"),
        "'abc' is not a number (an integer is expected)",
    ),
    "missing_field": (
        lambda t: _set_row(t, 2, "2048,7"),
        "row 16 has 4 fields; the header (line 13) has 3",
    ),
    "metadata_period_mismatch": (
        lambda t: t.replace("# period_s: 0.0040002346670242545", "# period_s: 0.005"),
        "metadata period 0.005 s differs",
    ),
    "time_column_period_mismatch": (
        lambda t: _edit_rows(
            t,
            lambda ln: (
                ln
                if ln[0] == "t"
                else ",".join((ln.split(",")[0], f"{int(ln.split(',')[0]) * 0.00401:.9f}", "2048"))
            ),
        ).replace("# period_s: 0.0040002346670242545\n", ""),
        "time_s period 0.00401",
    ),
    "irregular_time": (
        lambda t: t.replace("\n5,0.020001173,", "\n5,0.020501173,"),
        "irregular or non-increasing time",
    ),
    "tick_jump": (lambda t: t.replace("\n5,0.020001173,", "\n6,0.020001173,"), "step by 1"),
    "dac_bits_mismatch": (
        lambda t: t.replace("# dac_bits: 12", "# dac_bits: 16"),
        "dac_bits 16 disagrees",
    ),
    "too_few_rows": (lambda t: "\n".join(t.splitlines()[:20]) + "\n", "need at least 10"),
    "empty": (lambda t: "", "no header row"),
    "superscript_digit": (lambda t: _set_row(t, 4, "2²"), "'2²' is not a number"),
    "double_sign": (lambda t: _set_row(t, 4, "+-5"), "'+-5' is not a number"),
    "huge_code": (lambda t: _set_row(t, 4, "9" * 400), "a field of 400 characters"),
    "bom_ok_but_nan_time": (
        lambda t: "\ufeff" + t.replace("\n5,0.020001173,", "\n5,nan,"),
        "row 19, column 'time_s': nan is not finite",
    ),
}


@pytest.mark.parametrize("case", sorted(READ_ERRORS))
def test_read_errors_name_the_problem(tmp_path: Path, rig: st.Rig, case: str) -> None:
    edit, message = READ_ERRORS[case]
    good = _good(tmp_path, rig)
    bad = edit(good)
    assert bad != good
    path = tmp_path / f"{case}.csv"
    path.write_text(bad, encoding="utf-8")
    with pytest.raises(LogFormatError, match=_escape(message)):
        read_excitation(path, rig)


def _escape(message: str) -> str:
    import re

    return re.escape(message)


def test_read_missing_file(tmp_path: Path, rig: st.Rig) -> None:
    with pytest.raises(LogFormatError, match="does not exist"):
        read_excitation(tmp_path / "nope.csv", rig)


def test_read_accepts_tick_only_with_period_metadata(tmp_path: Path, rig: st.Rig) -> None:
    good = _good(tmp_path, rig)
    tick_only = _edit_rows(good, lambda ln: ",".join(ln.split(",")[::2]))
    path = tmp_path / "ticks.csv"
    path.write_text(tick_only, encoding="utf-8")
    axis, codes = read_excitation(path, rig)
    assert axis == "master" and codes.size == 25  # 0.1 s / 4.000235 ms
    no_period = tick_only.replace("# period_s: 0.0040002346670242545\n", "")
    path.write_text(no_period, encoding="utf-8")
    with pytest.raises(LogFormatError, match="period cannot be checked"):
        read_excitation(path, rig)


def test_write_refuses_a_foreign_rig(tmp_path: Path, rig: st.Rig) -> None:
    ex = design_excitation(rig, "master", "steps", 1.0)
    slow = dataclasses.replace(rig, timer=dataclasses.replace(rig.timer, period_s=0.008))
    with pytest.raises(SpecError, match="differs from rig"):
        write_excitation(tmp_path / "x.csv", ex, slow)


# --- impossible requests -------------------------------------------------------------------


def test_impossible_requests_raise_spec_error(rig: st.Rig) -> None:
    with pytest.raises(SpecError, match="only 7 ticks"):
        design_excitation(rig, "master", "prbs", 0.03)
    with pytest.raises(SpecError, match="unknown excitation kind 'chirp'"):
        design_excitation(rig, "master", "chirp", 10.0)
    with pytest.raises(SpecError, match="seconds must be > 0"):
        design_excitation(rig, "master", "prbs", float("nan"))
    with pytest.raises(SpecError, match="amplitude_codes must be an integer >= 1"):
        design_excitation(rig, "master", "prbs", 10.0, amplitude_codes=0)
    with pytest.raises(SpecError, match="seed must be an integer >= 0"):
        design_excitation(rig, "master", "prbs", 10.0, seed=-1)


def test_travel_too_short_for_one_code(rig: st.Rig) -> None:
    # no drift, ±5 counts: one code (4.88 mV · 12288 = 60 counts/s) for one 0.25 s step level
    # already moves the axis ~7 counts, beyond 90 % of 5
    master = rig.axis("master")
    r = _with_master(
        rig, travel_counts=(-5, 5), plant=dataclasses.replace(master.plant, offset_v=0.0)
    )
    for kind in KINDS:
        with pytest.raises(SpecError, match="even 1 D/A code"):
            design_excitation(r, "master", kind, 10.0)


def test_drift_alone_leaves_the_travel(rig: st.Rig) -> None:
    # 5 mV drift · 12288 counts/s/V ≈ 61 counts/s: about 610 counts in 10 s, beyond 0.9 · 500
    with pytest.raises(SpecError, match="drift"):
        design_excitation(_with_master(rig, travel_counts=(-500, 500)), "master", "prbs", 10.0)


def test_amplitude_too_small_to_reverse_against_drift(rig: st.Rig) -> None:
    # 1 code = 4.88 mV does not beat the 5 mV drift plus 2 mV friction in the negative direction
    with pytest.raises(SpecError, match="cannot reverse"):
        design_excitation(rig, "master", "steps", 10.0, amplitude_codes=1)


def test_unipolar_dac_cannot_excite(rig: st.Rig) -> None:
    r = dataclasses.replace(rig, dac=Dac(bits=12, range_v=(0.0, 10.0)))
    with pytest.raises(SpecError, match="both polarities"):
        design_excitation(r, "master", "prbs", 10.0)


def test_excitation_object_is_validated(rig: st.Rig) -> None:
    ex = design_excitation(rig, "master", "steps", 1.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        ex.kind = "prbs"  # type: ignore[misc]
    assert not ex.codes.flags.writeable
    assert list(ex.to_columns()) == ["master.dac_code"]
    with pytest.raises(SpecError, match="at least 10 ticks"):
        dataclasses.replace(ex, codes=ex.codes[:5], amplitude_codes=int(abs(ex.codes[:5]).max()))
    with pytest.raises(SpecError, match="amplitude_codes must equal"):
        dataclasses.replace(ex, amplitude_codes=ex.amplitude_codes + 1)
