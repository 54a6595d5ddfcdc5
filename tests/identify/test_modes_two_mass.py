"""The mode fit (servotune.identify.modes.fit_modes) on logs of a plant that is not its model:
the two-mass axis of tests/frf_truth.py (integrated by ``scipy.integrate.solve_ivp``, nothing of
servotune's plant model or engine), measured by servotune.analysis.frf.estimate_frf.

**Why the model class misses it.** That axis has viscous friction to ground on the motor (``b``,
the drives' speed loop and bearings). The modal model ``K / (s (τ s + 1)) · (1 + g s² / (s² +
2 ζ ω s + ω²))`` has the anti-resonance ``ω_a = ω / √(1 + g)`` with the damping
``ζ_a = ζ / √(1 + g)``: the pole pair's and the zero pair's damping are tied. In the two-mass
axis the zero pair (the load swinging on a still motor) has only the shaft's damping,
``ζ_a = c / (2 √(k J_l))``, while the pole pair has the shaft's and the motor's friction's: at
20 Hz, ζ 0.02, ``ζ_a`` is 0.0071 where the modal model has 0.0176. No one-mode model fits the
notch: on a well-averaged response (24 periods) it leaves tens of standard deviations there, and
before the order rule asked every mode to be a resonance (``MIN_PEAK``, the module docstring of
servotune.identify.modes), ``auto`` added a second "mode" that lowered that misfit by more than
the 20 % held-out margin: in 5 of 10 seeds at 20 Hz, ζ 0.02 a critically damped one at 0.93 Hz,
below the lowest line (1 Hz), that halved the real mode's gain (0.17 for 0.3), and in 1 of 6 at
300 Hz, ζ 0.08 (1 ms) one of 382 Hz, ζ 0.16, gain 0.004 (``|g| / 2ζ`` 0.014).

What holds, and is checked here on 3 seeds per case (measured over 10 seeds at 4 ms and 6 at
1 ms, 2026-11-29: 64 of 64 one mode):

- ``auto`` picks exactly one mode, its frequency within 1 % of the plant's (measured: 0.2 %,
  20.03-20.04 Hz for 20 Hz; 60.13 Hz for 60 Hz ζ 0.08);
- its damping within 25 % (measured: +20 to +23 % at 20 Hz, ζ 0.02, where the motor's friction
  is most of the pole pair's damping, +6 % at 20 Hz, ζ 0.08; within 2 % at 60 and 300 Hz): the
  misfit at the anti-resonance biases it, and the fit's reduced chi-square (far above 1) says
  the model does not explain the response;
- the structural cause: the plant's anti-resonance damping is below what the modal model ties it
  to, and the one-mode model's largest misfit on the true (noise-free) response lies within 10 %
  of the anti-resonance;
- a second mode, fitted when asked for (``n_modes=2``), is no resonance of the lines: outside
  them, or ``|g| / (2 ζ)`` below ``MIN_PEAK``.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest
from frf_truth import Case, Noise, TwoMass, design_pi, simulate, truth_frf

from servotune.analysis.frf import Frf, estimate_frf
from servotune.excite import periodic_multisine
from servotune.identify.modes import MIN_PEAK, fit_modes

DELAY_S = 0.0002
"""Compute delay: the example rig's ``compute_s`` (plants/pc-dual-servo.toml)."""
NOISE = Noise(load_v=0.01, load_corner_hz=2.0, sensor_counts=0.5)
"""tests/analysis/test_frf_truth.py's disturbances."""
CROSSOVER_HZ = 0.8
"""tests/analysis/test_frf_truth.py's PI crossover on the rigid body."""
SEEDS = (0, 1, 2)
# (period, counts/rev, ticks per period, periods, skipped, band) and the modes: the groups of
# tests/analysis/test_frf_truth.py
GROUPS = {
    0.004: ((2**17, 250, 24, 4, (1.0, 100.0)), ((20.0, 0.02), (20.0, 0.08), (60.0, 0.08))),
    0.001: ((2**20, 250, 28, 8, (5.0, 450.0)), ((300.0, 0.08),)),
}
CASES = [(t, f, z) for t, (_, modes) in GROUPS.items() for f, z in modes]
IDS = [f"{t * 1e3:g}ms-{f:g}Hz-zeta{z:g}" for t, f, z in CASES]
FREQ_RTOL, DAMPING_RTOL = 0.01, 0.25


def _plant(period_s: float, f_r: float, zeta: float) -> TwoMass:
    cpr = GROUPS[period_s][0][0]
    return TwoMass(f_r_hz=f_r, zeta=zeta, inertia_ratio=0.3, counts_per_rev=cpr)


@functools.cache
def _measured(period_s: float) -> dict[tuple[float, float], list[Frf]]:
    """Every case of one period over :data:`SEEDS`, simulated together, measured."""
    (_, ticks, periods, skip, band), modes = GROUPS[period_s]
    codes = periodic_multisine(ticks, periods, period_s, 1000, band_hz=band).codes
    jobs = []
    for f_r, zeta in modes:
        plant = _plant(period_s, f_r, zeta)
        loop = design_pi(plant, period_s, DELAY_S, CROSSOVER_HZ)
        jobs += [Case(plant=plant, loop=loop, noise=NOISE, exc_codes=codes, seed=s) for s in SEEDS]
    out: dict[tuple[float, float], list[Frf]] = {}
    for job, log in zip(jobs, simulate(jobs), strict=True):
        frf = estimate_frf(log.u, log.y, log.r, period_s=period_s, skip=skip)
        out.setdefault((job.plant.f_r_hz, job.plant.zeta), []).append(frf)
    return out


@pytest.mark.parametrize(("period_s", "f_r", "zeta"), CASES, ids=IDS)
def test_auto_finds_the_one_mode_and_no_other(period_s: float, f_r: float, zeta: float) -> None:
    for frf in _measured(period_s)[f_r, zeta]:
        fit = fit_modes(frf, compute_s=DELAY_S)
        (mode,) = fit.modes
        assert mode.freq_hz == pytest.approx(f_r, rel=FREQ_RTOL)
        assert mode.damping == pytest.approx(zeta, rel=DAMPING_RTOL)
        assert 2 in fit.held_out  # a second mode was tried, and refused


@pytest.mark.parametrize(("period_s", "f_r", "zeta"), CASES, ids=IDS)
def test_a_second_mode_asked_for_is_no_resonance(period_s: float, f_r: float, zeta: float) -> None:
    for frf in _measured(period_s)[f_r, zeta]:
        fit = fit_modes(frf, n_modes=2, compute_s=DELAY_S)
        extra = max(fit.modes, key=lambda m: abs(math.log(m.freq_hz / f_r)))
        lines = frf.freq_hz[~frf.aliased]
        outside = not lines.min() <= extra.freq_hz <= lines.max()
        assert outside or abs(extra.gain) < MIN_PEAK * 2.0 * extra.damping, extra


@pytest.mark.parametrize(("f_r", "zeta"), [(20.0, 0.02), (20.0, 0.08), (60.0, 0.02)])
def test_the_modal_model_ties_the_anti_resonance_damping(f_r: float, zeta: float) -> None:
    """The cause: the motor's friction to ground damps the pole pair, not the zero pair."""
    plant = _plant(0.004, f_r, zeta)
    k, c, _ = plant.shaft()
    zeta_a = c / (2.0 * math.sqrt(k * plant.j_l))
    g = (f_r / plant.antiresonance_hz) ** 2 - 1.0
    assert zeta_a < 0.9 * zeta / math.sqrt(1.0 + g)
    if (f_r, zeta) == (20.0, 0.02):  # the numbers of the module docstring
        assert zeta_a == pytest.approx(0.0071, abs=5e-5)
        assert zeta / math.sqrt(1.0 + g) == pytest.approx(0.0176, abs=5e-5)


@pytest.mark.parametrize(("f_r", "zeta"), [(20.0, 0.02), (20.0, 0.08), (60.0, 0.08)])
def test_the_one_mode_model_misses_the_true_response_at_the_anti_resonance(
    f_r: float, zeta: float
) -> None:
    plant = _plant(0.004, f_r, zeta)
    frf = _measured(0.004)[f_r, zeta][0]  # its lines and weights, the true response
    truth = dataclasses.replace(frf, response=truth_frf(plant, 0.004, DELAY_S, frf.freq_hz))
    fit = fit_modes(truth, n_modes=1, compute_s=DELAY_S)
    misfit = np.abs(fit.response(frf.freq_hz) - truth.response) / frf.std
    worst = frf.freq_hz[int(np.argmax(misfit))]
    assert abs(worst / plant.antiresonance_hz - 1.0) < 0.10
    assert np.max(misfit) > 10.0  # far above the measurement's own noise
