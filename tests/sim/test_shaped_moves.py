"""Shaped moves in the engine on a resonant plant: the residual vibration the closed loop is
left with after a move, unshaped and shaped (servotune.analysis.shaping,
docs/runtime.md#input-shaping).

The axis: the belt-driven master of plants/belt-axis.toml (a 35 Hz mode, damping 0.04, gain
0.5) with a stiffer drive (τ = 4 ms instead of 25 ms) and the PI gains loop shaping gives it
(Kp ≈ 1 code/count). The example rig's own drive filters a move so much that its mode rings by
less than one count (under one count after a move like the one below), too little to measure a 5 %
residual against the counter's quantisation; here the unshaped move leaves 30–85 counts.
Offset, friction and encoder noise are off so that after the move the loop is linear.

The vibration is measured independently of the design code: after the reference has stopped,
the measured position (the engine's ``true_pos_counts``) is a sum of the closed loop's free
modes; a matrix-pencil fit (tests/sim/vibration.py: Hua and Sarkar's method, SVD of a
Hankel matrix, then the amplitudes by least squares) recovers them, and the one nearest the
mode is the vibration.
The move is a triangle of 10 ms acceleration and deceleration: its spectrum has no zero between
25 and 50 Hz (zeros at 100 Hz and its multiples), so the unshaped move excites the mode wherever
it lies within ±15 %.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from vibration import vibration_near

import servotune as st
from servotune.analysis.shaping import axis_shaper, closed_loop_modes
from servotune.laws.axis import MODE_TASK
from servotune.laws.shaping import shape_reference
from servotune.pipeline import default_pi_gains
from servotune.rig import EXAMPLES_DIR
from servotune.scenarios import Inputs, trapezoid_ref
from servotune.sim.engine import Loop, simulate
from servotune.tune.pi import pi_loop_shaping

N_TICKS = 600
START = 50
WINDOW = 200  # ticks after the move (0.8 s: the mode decays by e^-7)
ACCEL_S = 0.01


def _rig(tau_s: float, mode_scale: float = 1.0) -> st.Rig:
    rig = st.load_rig(EXAMPLES_DIR / "belt-axis.toml")
    m = rig.axis("master")
    plant = dataclasses.replace(
        m.plant,
        tau_s=tau_s,
        noise_counts=0.0,
        coulomb_v=0.0,
        offset_v=0.0,
        modes=tuple(
            dataclasses.replace(md, freq_hz=md.freq_hz * mode_scale) for md in m.plant.modes
        ),
    )
    return dataclasses.replace(rig, axes=(dataclasses.replace(m, plant=plant), rig.axis("slave")))


def _gains(rig: st.Rig) -> list:
    """Loop shaping's PI for the master's rigid plant, the default for the slave."""
    gains = default_pi_gains(rig)
    rigid = dataclasses.replace(rig.axis("master").plant, modes=())
    gains[0] = pi_loop_shaping(
        rigid, period_s=rig.period_s, lsb_v=rig.dac.lsb_v, compute_s=rig.timer.compute_s
    )
    return gains


def _move(rig: st.Rig) -> np.ndarray:
    v = 0.5 * rig.axis("master").speed_limit_rpm / 60.0 * rig.counts_per_rev
    return trapezoid_ref(N_TICKS, rig.period_s, v * ACCEL_S, v, v / ACCEL_S, start_tick=START)


def _vibration(rig: st.Rig, gains: list, ref: np.ndarray, near_hz: float) -> float:
    """Amplitude [counts] of the free oscillation nearest ``near_hz`` once the reference stops."""
    inp = Inputs.hold(N_TICKS, 2).replace_axis(0, ref_counts=ref, mode=np.full(N_TICKS, MODE_TASK))
    y = simulate(Loop.from_rig(rig, gains), inp, seed=0).true_pos_counts[:, 0]
    end = int(np.flatnonzero(np.diff(ref))[-1]) + 1
    return vibration_near(y[end : end + WINDOW] - ref[end], rig.period_s, near_hz)


@pytest.fixture(scope="module")
def design() -> tuple[st.Rig, list, dict]:
    rig = _rig(0.004)
    gains = _gains(rig)
    shapers = {k: axis_shaper(rig, "master", gains[0], k)[0] for k in ("zv", "zvd", "ei")}
    return rig, gains, shapers


@pytest.mark.parametrize("scale", [0.85, 1.0, 1.15])
def test_a_shaped_move_leaves_at_most_5_percent_of_the_vibration(design, scale: float) -> None:
    """Shapers designed for the nominal mode, the plant's mode at 85 %, 100 % and 115 % of it.
    Measured (2026-11-29): unshaped 83.9 / 51.6 / 33.3 counts; zv 17 % / 0.6 % / 18 %;
    zvd 0.8 % / 0.3 % / 3.5 %; ei 0.2 % / 0.7 % / 1.2 %. At the nominal mode every kind
    is ≤ 5 %; over ±15 % zvd and ei are, and zv is not (it is not meant to be)."""
    _, gains, shapers = design
    rig = _rig(0.004, scale)
    near = closed_loop_modes(
        rig.axis("master").plant,
        gains[0],
        period_s=rig.period_s,
        lag_s=rig.timer.compute_s + rig.axis("master").plant.delay_s,
        lsb_volts=rig.dac.lsb_v,
    )[0].freq_hz
    ref = _move(rig)
    unshaped = _vibration(rig, gains, ref, near)
    assert unshaped > 20.0  # the move does excite the mode
    ratios = {
        k: _vibration(rig, gains, shape_reference(ref, sh), near) / unshaped
        for k, sh in shapers.items()
    }
    robust = ("zvd", "ei") if scale != 1.0 else ("zv", "zvd", "ei")
    for k in robust:
        assert ratios[k] <= 0.05, (k, ratios)
    if scale != 1.0:
        assert ratios["zv"] > 0.10, ratios  # the measurement tells a robust shaper from zv


def test_the_shaper_is_designed_for_the_closed_loops_mode(design) -> None:
    """The stiff loop moves the 35 Hz mode up (to 37.3 Hz); a zv designed for the plant's own
    35 Hz leaves several times the vibration of one designed for the closed loop's pole
    (measured: 8.4 % against 0.6 %; zvd and ei are robust enough not to care). The
    closed loop's pole is checked against python-control's poles of a loop built here."""
    import control
    from scipy.signal import cont2discrete

    rig, gains, shapers = design
    m = rig.axis("master")
    p = m.plant
    cl = closed_loop_modes(
        p,
        gains[0],
        period_s=rig.period_s,
        lag_s=rig.timer.compute_s + p.delay_s,
        lsb_volts=rig.dac.lsb_v,
    )[0]
    assert cl.freq_hz > 36.0
    # an own loop: the plant K/(s(τs+1)) · (1 + g s²/(s² + 2ζωs + ω²)), ZOH at the tick with
    # the lag rounded to whole ticks (the pole moves by far less than the 1 Hz checked)
    md = p.modes[0]
    w = 2 * math.pi * md.freq_hz
    num = np.polymul(
        [p.gain_cps_per_v], np.polyadd([1, 2 * md.damping * w, w * w], [md.gain, 0, 0])
    )
    den = np.polymul([p.tau_s, 1, 0], [1, 2 * md.damping * w, w * w])
    b, a, _ = cont2discrete((num, den), rig.period_s, method="zoh")
    lag_ticks = round((rig.timer.compute_s + p.delay_s) / rig.period_s)
    plant_z = control.tf(np.ravel(b), np.polymul(a, [1] + [0] * lag_ticks), rig.period_s)
    pi = control.tf([gains[0].kp + gains[0].ki * rig.period_s, -gains[0].kp], [1, -1], rig.period_s)
    poles = np.log(control.feedback(pi * plant_z * rig.dac.lsb_v, 1).poles().astype(complex))
    f_own = poles.imag / (2 * math.pi * rig.period_s)
    assert np.min(np.abs(f_own - cl.freq_hz)) < 1.0
    ref = _move(rig)
    unshaped = _vibration(rig, gains, ref, cl.freq_hz)
    from servotune.laws.shaping import design_shaper

    at_plant = design_shaper("zv", md.freq_hz, md.damping, rig.period_s)
    left_plant = _vibration(rig, gains, shape_reference(ref, at_plant), cl.freq_hz) / unshaped
    left_loop = _vibration(rig, gains, shape_reference(ref, shapers["zv"]), cl.freq_hz) / unshaped
    assert left_loop * 3 < left_plant, (left_loop, left_plant)
