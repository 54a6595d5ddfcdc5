"""The measured frequency response (servotune.analysis.frf.estimate_frf) against an independent
truth.

The logs come from :mod:`frf_truth` (tests/frf_truth.py): a two-mass axis with Coulomb friction
integrated by ``scipy.integrate.solve_ivp``, a 12-bit D/A written 0.2 ms into the tick, a
quantised encoder, a PI position law, a low-pass load torque and sensor noise, and a periodic
multisine of :func:`servotune.excite.periodic_multisine` added at the D/A. The truth is the
exact discrete-time response of the plant's linear part (``frf_truth.truth_frf``). Nothing of
servotune's plant model or engine is used.

What is claimed and where the numbers come from:

- accuracy: on the excited lines outside ±10 % of the mode the estimate is within 0.5 dB and
  3° of the truth on every line of every seed (the acceptance tolerance of this harness; the
  excitation and record are chosen so it holds on every line, no line is left out);
- coverage: the 95 % circles (radius ``sqrt(F_0.95(2, 2(P−1)))·std``, Pintelon & Schoukens,
  "System Identification: A Frequency Domain Approach", 2nd ed., Wiley 2012, the reference of
  servotune.analysis.frf) hold the truth on 90–98 % of the lines, pooled over seeds. Measured
  over 20 seeds (2026-11-29): 96.6–96.9 % at 4 ms (mean |Ĝ − G|²/std² 0.68–0.70), 93.5 % and
  94.5 % at 1 ms (1.11, 1.03; about 1.06 is exact). Before each period's deviation had its
  straight line removed, the slow load's leakage made the 1 ms circles about 4× too large in
  variance (coverage 99.9–100 %, 0.27–0.29);
- closed loop: where the loop's noise dominates the plant input, the open-loop estimate
  ``S_yu / S_uu`` (H1) is biased and the averaged-spectra ratio is not, shown on a log made
  hard on purpose (a load mode inside the loop's bandwidth, :data:`HARD_PLANT`);
- the comparison can fail: a truth with the mode 5 % off is told apart near the mode.

The friction-free logs of the closed-loop and white-noise checks are stepped exactly
(``integrator="expm"``), which the first tests below show gives the ``solve_ivp`` path's logs.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import pytest
from frf_truth import Case, Log, Noise, TwoMass, design_pi, loop_margins, simulate, truth_frf

from servotune.analysis.frf import Frf, estimate_frf
from servotune.excite import periodic_multisine

DELAY_S = 0.0002
"""Compute delay: the example rig's ``compute_s`` (plants/pc-dual-servo.toml)."""
COULOMB_V = 0.002
"""Coulomb friction as volts: the example rig's ``coulomb_v`` (plants/pc-dual-servo.toml)."""
NOISE = Noise(load_v=0.01, load_corner_hz=2.0, sensor_counts=0.5)
"""A 10 mV rms load torque low-passed at 2 Hz and 0.5 count rms sensor noise."""
CROSSOVER_HZ = 0.8
"""The PI law's crossover on the rigid body (``tau_m = 0.1 s``): 48° phase margin."""
MAX_DB, MAX_DEG = 0.5, 3.0
"""Accuracy tolerance away from the mode (this harness's acceptance claim)."""
MODE_BAND = 0.10
"""Lines within this fraction of f_r are "at the mode"; the accuracy claim is for the others."""
DEFAULT_SEEDS = (0, 1, 2)
SLOW_SEEDS = tuple(range(20))


@dataclass(frozen=True)
class Group:
    """Logs of one tick period, made together: the modes, the encoder and the excitation."""

    period_s: float
    modes: tuple[tuple[float, float], ...]  # (f_r [Hz], zeta)
    counts_per_rev: int
    period_ticks: int
    periods: int  # in the log, the first ``skip`` of them a transient
    skip: int
    amplitude_codes: int
    band_hz: tuple[float, float]

    def plant(self, f_r: float, zeta: float, coulomb_v: float = COULOMB_V) -> TwoMass:
        return TwoMass(
            f_r_hz=f_r,
            zeta=zeta,
            inertia_ratio=0.3,
            counts_per_rev=self.counts_per_rev,
            coulomb_v=coulomb_v,
        )

    def excitation(self) -> np.ndarray:
        m = periodic_multisine(
            self.period_ticks,
            self.periods,
            self.period_s,
            self.amplitude_codes,
            band_hz=self.band_hz,
        )
        return m.codes


GROUPS = {
    # 4 ms (the example rig's tick): a 17-bit encoder, 1 s periods, lines 1 … 100 Hz
    "4ms": Group(
        period_s=0.004,
        modes=((20.0, 0.02), (20.0, 0.08), (60.0, 0.02), (60.0, 0.08)),
        counts_per_rev=2**17,
        period_ticks=250,
        periods=24,
        skip=4,
        amplitude_codes=1000,
        band_hz=(1.0, 100.0),
    ),
    # 1 ms: a stiffer axis with a 20-bit encoder, 0.25 s periods, lines 5 … 450 Hz
    "1ms": Group(
        period_s=0.001,
        modes=((300.0, 0.02), (300.0, 0.08)),
        counts_per_rev=2**20,
        period_ticks=250,
        periods=28,
        skip=8,
        amplitude_codes=1000,
        band_hz=(5.0, 450.0),
    ),
}
CASES = [(g, f, z) for g, grp in GROUPS.items() for f, z in grp.modes]
CASE_IDS = [f"{g}-{f:g}Hz-zeta{z:g}" for g, f, z in CASES]


@dataclass(frozen=True)
class Result:
    frf: Frf
    truth: np.ndarray
    plant: TwoMass
    log: Log


def _estimate(group: Group, plant: TwoMass, log: Log) -> Result:
    frf = estimate_frf(log.u, log.y, log.r, period_s=group.period_s, skip=group.skip)
    truth = truth_frf(plant, group.period_s, DELAY_S, frf.freq_hz)
    return Result(frf=frf, truth=truth, plant=plant, log=log)


@functools.cache
def _results(group_name: str, seeds: tuple[int, ...]) -> dict[tuple[float, float], list[Result]]:
    """Every mode of the group over ``seeds``: simulated together (at most 24 logs a batch)."""
    group = GROUPS[group_name]
    codes = group.excitation()
    jobs = []
    for f_r, zeta in group.modes:
        plant = group.plant(f_r, zeta)
        loop = design_pi(plant, group.period_s, DELAY_S, CROSSOVER_HZ)
        for seed in seeds:
            jobs.append(Case(plant=plant, loop=loop, noise=NOISE, exc_codes=codes, seed=seed))
    batch = max(1, 24 // len(seeds)) * len(seeds)
    logs: list[Log] = []
    for i in range(0, len(jobs), batch):
        logs.extend(simulate(jobs[i : i + batch]))
    out: dict[tuple[float, float], list[Result]] = {}
    for job, log in zip(jobs, logs, strict=True):
        out.setdefault((job.plant.f_r_hz, job.plant.zeta), []).append(
            _estimate(group, job.plant, log)
        )
    return out


def _errors(frf: Frf, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude [dB] and phase [deg] of estimate / truth per line."""
    ratio = frf.response / truth
    return 20.0 * np.log10(np.abs(ratio)), np.degrees(np.angle(ratio))


def _away(frf: Frf, f_r: float) -> np.ndarray:
    return np.abs(frf.freq_hz - f_r) > MODE_BAND * f_r


# --- the harness itself -----------------------------------------------------------------------


@pytest.mark.parametrize("f_r, zeta", [(20.0, 0.02), (60.0, 0.08), (300.0, 0.02), (4.0, 0.08)])
def test_the_plant_has_its_mode_where_asked(f_r: float, zeta: float) -> None:
    plant = TwoMass(f_r_hz=f_r, zeta=zeta, inertia_ratio=0.3)
    eig = np.linalg.eigvals(plant.matrices()[0])
    pair = eig[np.abs(eig.imag) > 0]
    assert pair.size == 2
    np.testing.assert_allclose(np.abs(pair), 2 * math.pi * f_r, rtol=1e-9)
    np.testing.assert_allclose(-pair.real / np.abs(pair), zeta, rtol=1e-9)
    assert plant.antiresonance_hz < (1.0 - MODE_BAND) * f_r  # outside the mode's band


def test_viscous_damping_above_the_asked_zeta_is_refused() -> None:
    with pytest.raises(ValueError, match="damps it more"):
        TwoMass(f_r_hz=20.0, zeta=0.02, inertia_ratio=0.3, tau_m_s=0.025).shaft()


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_the_pi_loops_are_stable_with_margin(case: tuple[str, float, float]) -> None:
    group = GROUPS[case[0]]
    plant = group.plant(case[1], case[2])
    m = loop_margins(plant, design_pi(plant, group.period_s, DELAY_S, CROSSOVER_HZ))
    assert m["pole_radius"] < 1.0
    assert m["gain_margin"] > 10.0  # > 20 dB
    assert m["phase_margin_deg"] > 45.0
    assert m["stability_margin"] > 0.6


@pytest.mark.parametrize("integrator", ["ivp", "expm"])
def test_the_truth_is_what_a_noise_free_linear_log_measures(integrator: str) -> None:
    """Without noise and friction, on an encoder fine enough that counting is exact, the
    estimate is the truth: this pins the truth's zero-order hold, delay and velocity to what
    the simulated rig does, for both integrators."""
    group = GROUPS["4ms"]
    plant = TwoMass(f_r_hz=20.0, zeta=0.02, inertia_ratio=0.3, counts_per_rev=2**40, coulomb_v=0.0)
    loop = design_pi(plant, group.period_s, DELAY_S, CROSSOVER_HZ)
    codes = periodic_multisine(250, 10, group.period_s, 1000, band_hz=group.band_hz).codes
    quiet = Noise(load_v=0.0, sensor_counts=0.0)
    (log,) = simulate(
        [Case(plant=plant, loop=loop, noise=quiet, exc_codes=codes)], integrator=integrator
    )
    frf = estimate_frf(log.u, log.y, log.r, period_s=group.period_s, skip=4)
    truth = truth_frf(plant, group.period_s, DELAY_S, frf.freq_hz)
    assert np.max(np.abs(frf.response / truth - 1.0)) < 2e-3
    # a whole-tick delay instead of 0.2 ms is 8° off at 100 Hz: the check sees the delay
    late = truth_frf(plant, group.period_s, 0.0039, frf.freq_hz)
    assert np.max(np.abs(np.degrees(np.angle(frf.response / late)))) > 5.0


def test_the_two_integrators_make_the_same_noisy_log() -> None:
    """With load and sensor noise but no friction, ``solve_ivp`` (rtol 1e-6) and the exact step
    make the same log but for a count here and there where the position sits on a count's edge,
    and estimates that agree to 0.1 %, within half the estimate's own std (so the friction-free
    logs below may be stepped exactly)."""
    group = GROUPS["4ms"]
    plant = group.plant(20.0, 0.02, coulomb_v=0.0)
    loop = design_pi(plant, group.period_s, DELAY_S, CROSSOVER_HZ)
    codes = periodic_multisine(250, 6, group.period_s, 1000, band_hz=group.band_hz).codes
    case = Case(plant=plant, loop=loop, noise=NOISE, exc_codes=codes, seed=7)
    (ivp,) = simulate([case])
    (exact,) = simulate([case], integrator="expm")
    assert np.mean(ivp.y != exact.y) < 0.01 and np.max(np.abs(ivp.y - exact.y)) <= 1
    a = estimate_frf(ivp.u, ivp.y, ivp.r, period_s=group.period_s, skip=2)
    b = estimate_frf(exact.u, exact.y, exact.r, period_s=group.period_s, skip=2)
    assert np.max(np.abs(a.response / b.response - 1.0)) < 2e-3
    assert np.max(np.abs(a.response - b.response) / b.std) < 0.5


# --- 1. accuracy away from the mode -----------------------------------------------------------


def _check_accuracy(case: tuple[str, float, float], seeds: tuple[int, ...]) -> None:
    name, f_r, zeta = case
    worst_db = worst_deg = 0.0
    for res in _results(name, seeds)[(f_r, zeta)]:
        assert res.log.clipped == 0
        away = _away(res.frf, f_r)
        assert np.sum(away) >= 20
        db, deg = _errors(res.frf, res.truth)
        worst_db = max(worst_db, float(np.max(np.abs(db[away]))))
        worst_deg = max(worst_deg, float(np.max(np.abs(deg[away]))))
    assert worst_db <= MAX_DB and worst_deg <= MAX_DEG, (
        f"{name} f_r={f_r} zeta={zeta}: worst {worst_db:.3f} dB, {worst_deg:.2f} deg over "
        f"{len(seeds)} seeds"
    )


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_accuracy_away_from_the_mode(case: tuple[str, float, float]) -> None:
    _check_accuracy(case, DEFAULT_SEEDS)


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_accuracy_away_from_the_mode_over_20_seeds(case: tuple[str, float, float]) -> None:
    _check_accuracy(case, SLOW_SEEDS)


# --- 2. coverage of the 95 % circles ----------------------------------------------------------

COVERAGE = (0.90, 0.98)
"""The claim: the 95 % circles hold the truth on 90–98 % of the lines, pooled over seeds."""
COVERAGE_3_SEEDS = (0.85, 0.995)
"""The default suite's check on 3 seeds pooled over a group's modes (408 lines at 4 ms, 222 at
1 ms; binomial spread at 95 % about ±1.1 and ±1.5 points): wider both ways."""


def _coverage(results: list[Result]) -> tuple[float, float]:
    """Pooled fraction of lines whose circle holds the truth, and mean |Ĝ − G|² / std²."""
    inside = np.concatenate([r.frf.contains(r.truth) for r in results])
    z2 = np.concatenate([np.abs(r.frf.response - r.truth) ** 2 / r.frf.std**2 for r in results])
    return float(np.mean(inside)), float(np.mean(z2))


@pytest.mark.parametrize("group", ["4ms", "1ms"])
def test_coverage_pooled_over_3_seeds(group: str) -> None:
    results = [r for rs in _results(group, DEFAULT_SEEDS).values() for r in rs]
    cov, z2 = _coverage(results)
    lo, hi = COVERAGE_3_SEEDS
    assert lo <= cov <= hi, f"{group}: coverage {cov:.3f} (E|e|^2/std^2 {z2:.2f})"


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_coverage_over_20_seeds(case: tuple[str, float, float]) -> None:
    name, f_r, zeta = case
    cov, z2 = _coverage(_results(name, SLOW_SEEDS)[(f_r, zeta)])
    lo, hi = COVERAGE
    assert lo <= cov <= hi, f"{name} f_r={f_r} zeta={zeta}: coverage {cov:.3f} (z2 {z2:.2f})"


def test_coverage_with_white_sensor_noise_only() -> None:
    """The variance formula under its own assumption (noise independent from period to
    period): white sensor noise, no load, no friction, the 1 ms group's modes and excitation,
    20 seeds each (the exact integrator: friction-free)."""
    group = GROUPS["1ms"]
    codes = group.excitation()
    noise = Noise(load_v=0.0, sensor_counts=4.0)
    jobs = []
    for f_r, zeta in group.modes:
        plant = group.plant(f_r, zeta, coulomb_v=0.0)
        loop = design_pi(plant, group.period_s, DELAY_S, CROSSOVER_HZ)
        jobs += [
            Case(plant=plant, loop=loop, noise=noise, exc_codes=codes, seed=s) for s in range(20)
        ]
    logs = simulate(jobs, integrator="expm")
    results = [_estimate(group, j.plant, log) for j, log in zip(jobs, logs, strict=True)]
    cov, z2 = _coverage(results)
    lo, hi = COVERAGE
    assert lo <= cov <= hi, f"coverage {cov:.3f} (z2 {z2:.2f})"
    # E|Ĝ − G|² / std² = E[1/s²]·σ² = (P − 1) / (P − 2) for a complex variance of P − 1 dof
    p = results[0].frf.periods
    assert 0.85 <= z2 <= 1.3 * (p - 1) / (p - 2)


# --- 3. the open-loop formula is biased in closed loop ----------------------------------------

HARD_PLANT = TwoMass(f_r_hz=4.0, zeta=0.08, inertia_ratio=0.1, tau_m_s=0.01, coulomb_v=0.0)
"""A light, compliant load whose mode sits inside the position loop's bandwidth (PI crossover
8 Hz): the loop gain is 2 to 3 on the lines near the mode.

Why not the plants above: with ``L`` the loop gain and ``β`` the noise-to-excitation power in
``u`` per line and period, H1 / G = (1 − β / L) / (1 + β), while the averaged estimate's
relative variance is β |1 + L|² / (P |L|²). Their PI laws cross over at 0.8 Hz and |L| at their
20–300 Hz modes is 0.03 to 0.0001, so a 3 dB bias there needs β ≈ |L| and leaves the averaged
estimate about 1 / |L| (30–10⁴) of noise-to-signal per period to average away: 10⁴ periods or
more for 1 dB. With |L| ≈ 2 a 3 dB bias needs β ≈ 0.5, which 480 periods average to about 5 %."""
HARD_PERIOD_S = 0.004
HARD_TICKS, HARD_PERIODS, HARD_SKIP = 250, 484, 4
NEAR = 0.25
"""Lines within ±25 % of f_r are near the mode (1 Hz lines: 3, 4 and 5 Hz)."""


def _h1(log: Log, period_s: float, period_ticks: int, skip: int, freq_hz: np.ndarray) -> np.ndarray:
    """The open-loop estimate per line over the same periods: Σ_p Y_p U_p* / Σ_p |U_p|²."""
    n = period_ticks
    periods = log.r.size // n - skip
    s, e = skip * n, (skip + periods) * n
    y = log.y.astype(float)
    vel = (y[s:e] - y[s - 1 : e - 1]) / period_s
    u_p = np.fft.rfft(log.u[s:e].reshape(periods, n), axis=1)
    y_p = np.fft.rfft(vel.reshape(periods, n), axis=1)
    b = np.rint(freq_hz * n * period_s).astype(int)
    return np.sum(y_p[:, b] * np.conj(u_p[:, b]), axis=0) / np.sum(np.abs(u_p[:, b]) ** 2, axis=0)


@functools.cache
def _hard_logs() -> dict[str, tuple[Frf, np.ndarray, np.ndarray]]:
    loop = design_pi(HARD_PLANT, HARD_PERIOD_S, DELAY_S, 8.0, ratio=8.0)
    codes = periodic_multisine(
        HARD_TICKS, HARD_PERIODS, HARD_PERIOD_S, 300, band_hz=(1.0, 20.0), odd=False
    ).codes
    levels = {"hard": 0.1, "quiet": 0.01}
    jobs = [
        Case(plant=HARD_PLANT, loop=loop, noise=Noise(load_v=v), exc_codes=codes, seed=0)
        for v in levels.values()
    ]
    out = {}
    for name, log in zip(levels, simulate(jobs, integrator="expm"), strict=True):
        assert log.clipped == 0
        frf = estimate_frf(log.u, log.y, log.r, period_s=HARD_PERIOD_S, skip=HARD_SKIP)
        truth = truth_frf(HARD_PLANT, HARD_PERIOD_S, DELAY_S, frf.freq_hz)
        h1 = _h1(log, HARD_PERIOD_S, HARD_TICKS, HARD_SKIP, frf.freq_hz)
        out[name] = (frf, truth, h1)
    return out


def test_the_hard_loop_has_margin_and_gain_at_the_mode() -> None:
    loop = design_pi(HARD_PLANT, HARD_PERIOD_S, DELAY_S, 8.0, ratio=8.0)
    m = loop_margins(HARD_PLANT, loop)
    assert m["pole_radius"] < 1.0 and m["gain_margin"] > 6.0 and m["phase_margin_deg"] > 45.0
    f = HARD_PLANT.f_r_hz * np.array([1.0 - NEAR, 1.0, 1.0 + NEAR])
    z = np.exp(2j * np.pi * f * HARD_PERIOD_S)
    gain = np.abs(
        (loop.kp + loop.ki * HARD_PERIOD_S * z / (z - 1))
        * truth_frf(HARD_PLANT, HARD_PERIOD_S, DELAY_S, f, "position")
    )
    assert np.all(gain > 1.0)


def test_h1_is_biased_near_the_mode_where_the_estimate_is_not() -> None:
    logs = _hard_logs()
    frf, truth, h1 = logs["hard"]
    near = np.abs(frf.freq_hz - HARD_PLANT.f_r_hz) <= NEAR * HARD_PLANT.f_r_hz
    at_mode = np.argmin(np.abs(frf.freq_hz - HARD_PLANT.f_r_hz))
    assert np.sum(near) == 3 and math.isclose(frf.freq_hz[at_mode], HARD_PLANT.f_r_hz)
    h1_db = np.abs(20 * np.log10(np.abs(h1 / truth)))
    est_db = np.abs(20 * np.log10(np.abs(frf.response / truth)))
    # the log is hard: H1 is off by 3 dB or more at the mode
    assert h1_db[at_mode] >= 3.0, f"H1 {h1_db[near]} dB off near the mode"
    # and the averaged-spectra ratio is within 1 dB on every line near it
    assert np.max(est_db[near]) <= 1.0, f"estimate {est_db[near]} dB off near the mode"
    # the same loop with a tenth of the load: H1 is fine, so its bias above is the noise's
    q_frf, q_truth, q_h1 = logs["quiet"]
    assert np.max(np.abs(20 * np.log10(np.abs(q_h1[near] / q_truth[near])))) <= 1.0
    assert np.max(np.abs(20 * np.log10(np.abs(q_frf.response[near] / q_truth[near])))) <= 1.0


# --- 4. the comparison can fail ---------------------------------------------------------------


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_a_truth_with_the_mode_5_percent_off_fails_near_the_mode(
    case: tuple[str, float, float],
) -> None:
    name, f_r, zeta = case
    group = GROUPS[name]
    for res in _results(name, DEFAULT_SEEDS)[(f_r, zeta)]:
        near = ~_away(res.frf, f_r)
        assert np.any(near)
        db, deg = _errors(res.frf, res.truth)
        assert np.all(np.abs(db[near]) <= MAX_DB) and np.all(np.abs(deg[near]) <= MAX_DEG)
        shifted = group.plant(1.05 * f_r, zeta)
        wrong = truth_frf(shifted, group.period_s, DELAY_S, res.frf.freq_hz)
        db, deg = _errors(res.frf, wrong)
        assert np.any((np.abs(db[near]) > MAX_DB) | (np.abs(deg[near]) > MAX_DEG))
