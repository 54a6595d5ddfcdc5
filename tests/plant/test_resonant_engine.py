"""The engine runs a resonant plant (docs/frf.md): checked against independent simulations of the
same modal model — scipy's exact zero-order-hold discretisation (``scipy.signal.cont2discrete``)
for the linear plant, and scipy's ``solve_ivp`` with direction events for one with Coulomb
friction — never against servotune's own plant step."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.signal import cont2discrete

from servotune.errors import SpecError
from servotune.laws.axis import MODE_LOCK
from servotune.modal import discretize, modal_state_space
from servotune.plant import Plant, lag_split
from servotune.resonance import MAX_MODES, Mode
from servotune.rig import load_rig
from servotune.scenarios import Inputs
from servotune.sim.engine import Loop, prepare_batch, run_batch, simulate

RIG = load_rig("plants/pc-dual-servo.toml")
# a belt-driven master: a 35 Hz mode, load-to-motor inertia 0.5 (docs/frf.md's two-mass
# model), and a second, lighter one at 80 Hz with the anti-resonance below
MODES = (Mode(freq_hz=35.0, damping=0.03, gain=0.5), Mode(freq_hz=80.0, damping=0.05, gain=-0.3))


def _inputs(n: int, seed: int, codes: int = 300) -> Inputs:
    """Both axes holding position (the lock module) while random D/A codes are added."""
    rng = np.random.default_rng(seed)
    add = np.zeros((n, 2), dtype=np.int64)
    add[:, 0] = rng.integers(-codes, codes + 1, n)
    return Inputs(
        ref_counts=np.zeros((n, 2), dtype=np.int64),
        mode=np.full((n, 2), MODE_LOCK, dtype=np.int8),
        reset=np.zeros((n, 2), dtype=np.int8),
        dac_add_codes=add,
        load_v=np.zeros((n, 2)),
    )


def _scipy_positions(plant: Plant, volts: np.ndarray) -> np.ndarray:
    """The measured position at each tick start, from the volts written each tick, by
    ``cont2discrete`` of the two pieces of a tick (before and after the lag's fraction)."""
    a, b, c = modal_state_space(plant.gain_cps_per_v, plant.tau_s, plant.modes)
    period = RIG.period_s
    m, lam = lag_split(RIG.timer.compute_s + plant.delay_s, period)
    pieces = []
    for h in (lam, period - lam):
        ad, bd, *_ = cont2discrete((a, b[:, None], c[None, :], np.zeros((1, 1))), h, "zoh")
        pieces.append((ad, bd[:, 0]))
    x = np.zeros(a.shape[0])
    y = np.empty(volts.size)
    for k in range(volts.size):
        y[k] = c @ x
        u_old = volts[k - m - 1] if k >= m + 1 else 0.0
        u_new = volts[k - m] if k >= m else 0.0
        x = pieces[0][0] @ x + pieces[0][1] * u_old
        x = pieces[1][0] @ x + pieces[1][1] * u_new
    return y


def test_the_engine_moves_a_linear_resonant_plant_as_scipy_does_over_100k_ticks() -> None:
    master = Plant(gain_cps_per_v=12288.0, tau_s=0.025, delay_s=0.0013, modes=MODES)
    tr = simulate(Loop.from_rig(RIG), _inputs(100_000, 1), plants=(master, RIG.axes[1].plant))
    ref = _scipy_positions(master, tr.volts[:, 0])
    got = tr.true_pos_counts[:, 0]
    scale = np.abs(ref).max()
    assert scale > 100.0  # the axis moved
    assert np.abs(got - ref).max() <= 1e-9 * scale
    # the mode is in it: the rigid plant given the same volts is off by more than a count
    rigid = _scipy_positions(
        Plant(gain_cps_per_v=12288.0, tau_s=0.025, delay_s=0.0013), tr.volts[:, 0]
    )
    assert np.abs(rigid - ref).max() > 1.0


def _friction_truth(plant: Plant, volts: np.ndarray, ticks: int) -> np.ndarray:
    """The measured position at each tick start by ``solve_ivp`` of the continuous model
    (docs/formats.md#axis-model with docs/frf.md's modes): state ``(p, v, q_i, q̇_i)``, the
    Coulomb term switching with the direction of motion at events ``v = 0``, at rest while
    the input is within the Coulomb level."""
    period = RIG.period_s
    m, lam = lag_split(RIG.timer.compute_s + plant.delay_s, period)
    k_g, tau, coul = plant.gain_cps_per_v, plant.tau_s, plant.coulomb_v
    modes = [(2 * math.pi * md.freq_hz, md.damping, md.gain) for md in plant.modes]

    def rhs(_t: float, x: np.ndarray, w: float, s: float) -> np.ndarray:
        acc = (k_g * (w - coul * s) - x[1]) / tau if s != 0.0 else 0.0  # s = 0: stuck
        out = [x[1], acc]
        for i, (om, z, _g) in enumerate(modes):
            q, qd = x[2 + 2 * i], x[3 + 2 * i]
            out += [qd, acc - 2 * z * om * qd - om * om * q]
        return np.array(out)

    def stopper(s: float) -> object:
        def stop(_t: float, x: np.ndarray, _w: float, _s: float) -> float:
            return x[1]

        stop.terminal = True  # type: ignore[attr-defined]
        stop.direction = -s  # type: ignore[attr-defined]  # moving the way s, back through 0
        return stop

    x = np.zeros(2 + 2 * len(modes))
    y = np.empty(ticks)
    for k in range(ticks):
        y[k] = x[0] + sum(g * x[2 + 2 * i] for i, (_o, _z, g) in enumerate(modes))
        u_old = volts[k - m - 1] if k >= m + 1 else 0.0
        u_new = volts[k - m] if k >= m else 0.0
        for w, t, t_end in ((u_old, 0.0, lam), (u_new, lam, period)):
            while t_end - t > 1e-12:
                s = np.sign(x[1]) if x[1] != 0.0 else np.sign(w) * (abs(w) > coul)
                sol = solve_ivp(
                    rhs,
                    (t, t_end),
                    x,
                    args=(w, s),
                    events=stopper(s) if s else None,
                    rtol=1e-11,
                    atol=1e-9,
                    method="DOP853",
                )
                x = sol.y[:, -1].copy()
                if sol.status == 1:  # the speed reached zero: on from rest, the way w pushes
                    x[1] = 0.0
                assert sol.t[-1] > t or sol.status == 0
                t = float(sol.t[-1])
    return y


def test_coulomb_friction_and_a_mode_agree_with_solve_ivp() -> None:
    master = Plant(
        gain_cps_per_v=12288.0, tau_s=0.025, delay_s=0.0013, coulomb_v=0.2, modes=MODES[:1]
    )
    n = 400
    tk = np.arange(n)
    volts = np.where((tk // 25) % 2 == 0, 1.5, -1.5) + 0.3 * np.sin(tk * 0.7)  # reversals
    codes = np.round(volts / RIG.dac.lsb_v).astype(np.int64)
    inputs = Inputs(
        ref_counts=np.zeros((n, 2), dtype=np.int64),
        mode=np.full((n, 2), 2, dtype=np.int8),  # open loop: the D/A gets the added codes
        reset=np.zeros((n, 2), dtype=np.int8),
        dac_add_codes=np.stack([codes, np.zeros(n, dtype=np.int64)], axis=1),
        load_v=np.zeros((n, 2)),
    )
    tr = simulate(Loop.from_rig(RIG), inputs, plants=(master, RIG.axes[1].plant))
    truth = _friction_truth(master, tr.volts[:, 0], n)
    got = tr.true_pos_counts[:, 0]
    assert np.sum(np.diff(np.sign(tr.speed_cps[:, 0])) != 0) >= 10  # it reversed, often
    assert np.abs(got - truth).max() <= 1e-5 * np.abs(truth).max()


def test_the_lean_kernel_gives_the_general_kernels_metrics_on_a_resonant_plant() -> None:
    # one-axis metrics-only batches run in the lean kernel (tests/sim/test_engine.py checks that
    # routing); its metrics must equal the traced general kernel's bit for bit with modes too
    ax = dataclasses.replace(RIG.axes[0], role="master")
    rig1 = dataclasses.replace(RIG, axes=(ax,))
    master = Plant(gain_cps_per_v=12288.0, tau_s=0.025, delay_s=0.0013, modes=MODES)
    n = 5000
    both = _inputs(n, 3)
    inputs = Inputs(
        ref_counts=both.ref_counts[:, :1],
        mode=both.mode[:, :1],
        reset=both.reset[:, :1],
        dac_add_codes=both.dac_add_codes[:, :1],
        load_v=both.load_v[:, :1],
    )
    loop = Loop.from_rig(rig1)
    batch = prepare_batch(loop, plants=[(master,), (ax.plant,)], seeds=5)
    lean = run_batch(batch, inputs).metrics.array
    full = run_batch(batch, inputs, metrics_only=False).metrics.array
    np.testing.assert_array_equal(lean, full)
    assert not np.array_equal(lean[0], lean[1])  # and the mode changes them


def test_a_rigid_plant_is_simulated_as_before_the_modes() -> None:
    # with no modes the discretisation is the rigid one (its state count: p, v and the lag)
    plant = RIG.axes[0].plant
    assert not plant.modes
    assert discretize(plant, RIG.period_s, 0.001).nstates == 3
    res = Plant(gain_cps_per_v=12288.0, tau_s=0.025, modes=MODES[:1])
    assert discretize(res, RIG.period_s, 0.001).nstates == 5


def test_bad_modes_are_refused() -> None:
    with pytest.raises(SpecError, match="damping"):
        Mode(freq_hz=35.0, damping=-0.1, gain=0.5)
    with pytest.raises(SpecError, match="freq_hz"):
        Mode(freq_hz=0.0, damping=0.1, gain=0.5)
    with pytest.raises(ValueError, match="at most"):
        Plant(gain_cps_per_v=1.0, tau_s=0.1, modes=MODES * MAX_MODES)
