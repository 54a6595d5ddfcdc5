"""Real data: the EMPS drive's two logs (docs/decisions.md#7-real-data-emps), read, fitted,
compared.

The data live outside the repository, in ``shared/data/real/EMPS`` beside it (its README names the
source: Janot, Gautier, Brunot, "Data Set and Reference Models of EMPS", 2019), or where the
environment variable ``SERVOTUNE_REAL_DATA`` points; CI has them. Without them every test that
needs them skips and says why; the reader's error cases and unit mapping run anyway.

What is shown:

- both files read, each with the SHA-256 the data directory publishes;
- in the PULSES experiment the pulses are part of the logged drive command ``vir``: they are a
  measured input (the comparison keeps the pulse stretches, and fits as well on them);
- the model fitted on one log, simulated open loop from the other log's command, reproduces that
  log's velocity: fit % in MATLAB ``compare``'s convention, the simulation made by scipy's
  ``solve_ivp`` on the fitted *continuous* model (not the identifier's closed-form tick step);
- the two logs' estimates agree within their reported 95 % intervals;
- the estimates, in the benchmark's physical units, are near the benchmark's own (IDIM-LS).

The fit uses the benchmark's model structure (gain, tau, offset, Coulomb, the same both ways:
``servotune.identify.emps.MODEL_STRUCTURE``), so both logs estimate the same parameters; each test
runs for output error (``method="oe"``) and for the default method.
"""

from __future__ import annotations

import hashlib
import inspect
import math
import os
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from numpy.testing import assert_allclose
from scipy.integrate import solve_ivp
from scipy.signal import butter, decimate, filtfilt

import servotune as st
from servotune.errors import IdentificationError, LogFormatError
from servotune.identify import FitResult, fit_arrays
from servotune.identify.emps import (
    ENCODER_QUANTUM_M,
    LOG_DAC_BITS,
    LOG_DAC_RANGE_V,
    MODEL_FRICTION,
    MODEL_STRUCTURE,
    PULSE_V_PER_UNIT,
    REFERENCE_MODEL,
    EmpsLog,
    EmpsPhysics,
    read_emps,
)
from servotune.identify.fitting import AGREEMENT_PARAMS
from servotune.identify.quality import fit_pct
from servotune.plant import Plant, advance, step_coefficients

REAL = Path(
    os.environ.get("SERVOTUNE_REAL_DATA")
    or Path(__file__).resolve().parents[3] / "shared" / "data" / "real"
)
FILES = {"EMPS": "DATA_EMPS.mat", "PULSES": "DATA_EMPS_PULSES.mat"}
OTHER = {"EMPS": "PULSES", "PULSES": "EMPS"}

MIN_CROSS_FIT_PCT = 90.0
"""Least velocity fit % of a model on the log it was not fitted on.

Measured (oe, benchmark structure, 2025-11-25): fitted on EMPS → PULSES 93.4 %, fitted on PULSES
→ EMPS 93.8 % (the estimator of the previous release: 92.8 % and 93.9 %). Why 90: a model of the
right class reproduces the other log to 93–94 %, while one that misses a term does not — the
gain-and-offset model that the automatic selection picked on EMPS at one point, with no Coulomb
friction, reached 84 % on its own log. Three points below the measurement leave room for honest
changes of the estimator and stop a model that lost its friction."""
MAX_PULSE_STRETCH_LOSS_PCT = 1.0
"""Most the PULSES log's velocity fit % may drop by keeping the pulse stretches in the comparison
(measured: 93.42 % with them, 93.43 % without)."""
REFERENCE_RTOL = 0.10
"""Largest relative difference of gain, tau and Coulomb level from the benchmark's IDIM-LS
estimate (measured, oe: 0.4–6 %; the previous release: 7–8 %). A different estimator on the same
data: the check is against unit and mapping errors (factors of 2e7 or gtau), not a benchmark."""
REFERENCE_OFFSET_ATOL_V = 0.03
"""Largest difference of the offset from IDIM-LS's [V] (measured 0.010–0.013 V; the offset is a
3 N force, so a relative bound means little)."""

METHODS = [
    pytest.param("oe", id="oe"),
    pytest.param("auto", id="default"),  # the IV estimator (instruments: reference, pulses)
]


def _data_dir() -> Path:
    d = REAL / "EMPS"
    if not d.is_dir():
        pytest.skip(
            f"the real EMPS data are not here ({d}); put shared/data/real beside the repository "
            "or set SERVOTUNE_REAL_DATA (CI has them)"
        )
    return d


@pytest.fixture(scope="module")
def emps() -> dict[str, EmpsLog]:
    """Both experiments, read from the shared data directory."""
    d = _data_dir()
    return {name: read_emps(d / f) for name, f in FILES.items()}


@pytest.fixture(scope="module")
def fitted(emps: dict[str, EmpsLog]) -> Callable[[str, str], FitResult]:
    """``fitted(log, method)``: that log's fit with the benchmark's structure (each made once)."""
    cache: dict[tuple[str, str], FitResult | Exception] = {}

    def get(name: str, method: str) -> FitResult:
        if (name, method) not in cache:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # residual tests fail on real data: not here
                    cache[name, method] = st.fit(
                        emps[name].to_log(),
                        method=method,
                        structure=MODEL_STRUCTURE,
                        friction=MODEL_FRICTION,
                    )
            except IdentificationError as exc:  # a failed fit fails every test that needs it
                cache[name, method] = exc
        got = cache[name, method]
        if isinstance(got, Exception):
            raise got
        return got

    return get


# --- the independent simulation ---------------------------------------------------------------


def _speed_by_solve_ivp(plant: Plant, log: EmpsLog) -> np.ndarray:
    """Mean speed over each tick [counts/s] of the fitted continuous model
    (docs/formats.md#axis-model), driven open loop by the log's command held over each tick,
    integrated by scipy's ``solve_ivp`` (RK45).

    Between reversals the direction ``d`` is fixed and the model is linear,
    ``tau·dv/dt + v = K_d·(w(t) − c_d)`` with ``w(t) = u(t − delay) + offset`` and ``c_d`` the
    signed Coulomb level of that way. The held input jumps every tick, which costs an adaptive
    solver many rejected steps; the state ``x = tau·v − K_d·(W(t) − c_d·t)`` with ``W`` the
    integral of ``w`` (continuous, piecewise linear) has ``dx/dt = −v`` and no jump. A zero of the
    speed ends a run (an event): the motor sticks while ``−c_neg <= w <= c_pos`` — until the first
    input beyond those levels — or goes on the other way. Steps are at most one tick, so a speed
    cannot cross zero and back inside one step unseen. The log's first position and mean speed
    over its first five ticks start it.
    """
    period = log.period_s
    y = log.pos_counts
    n = y.size
    w = log.cmd_v + plant.offset_v
    gain = {1: plant.gains_cps_per_v[0], -1: plant.gains_cps_per_v[1]}
    level = {1: plant.coulombs_v[0], -1: -plant.coulombs_v[1]}
    tau, delay = plant.tau_s, plant.delay_s
    w_cum = np.concatenate([[0.0], np.cumsum(w) * period])
    ticks = np.arange(n, dtype=np.int64) * period
    t_end = float(ticks[-1])

    def index(t: float) -> int:  # the command sample acting at time t
        return min(max(math.floor((t - delay) / period + 1e-9), 0), n - 1)

    def w_integral(t: float) -> float:
        if t <= delay:
            return w[0] * t
        r = (t - delay) / period
        j = min(math.floor(r), n - 1)
        return w[0] * delay + w_cum[j] + w[j] * (r - j) * period

    def way_from_rest(t: float) -> int:
        wt = w[index(t)]
        return 1 if wt > level[1] else -1 if wt < level[-1] else 0

    pos = np.empty(n)
    pos[0] = y[0]
    t, p, v = 0.0, float(y[0]), float(np.mean(np.diff(y[:6]))) / period
    d = int(np.sign(v)) or way_from_rest(0.0)
    while t < t_end:
        i0 = int(np.searchsorted(ticks, t, side="right"))
        if d == 0:  # at rest until an input beyond a breakaway level
            j = index(t)
            away = np.flatnonzero((w[j:] > level[1]) | (w[j:] < level[-1]))
            t1 = t_end if away.size == 0 else min(max(t, (j + away[0]) * period + delay), t_end)
            pos[i0 : int(np.searchsorted(ticks, t1, side="right"))] = p
            t, d = t1, (way_from_rest(t1) if t1 < t_end else 0)
            continue
        g, c = gain[d], level[d]
        from_rest = v == 0.0  # no zero crossing before the input changes: no event until then
        t1 = min((index(t) + 1) * period + delay, t_end) if from_rest else t_end

        def speed(tt: float, x: float, g: float = g, c: float = c) -> float:
            return (x + g * (w_integral(tt) - c * tt)) / tau

        def rhs(tt: float, s: np.ndarray, speed=speed) -> tuple[float, float]:
            vv = speed(tt, s[1])
            return vv, -vv

        def reverses(tt: float, s: np.ndarray, speed=speed) -> float:
            return speed(tt, s[1])

        reverses.terminal, reverses.direction = True, -d
        sol = solve_ivp(
            rhs,
            (t, t1),
            (p, tau * v - g * (w_integral(t) - c * t)),
            events=None if from_rest else reverses,
            dense_output=True,
            max_step=period,
            rtol=1e-8,
            atol=1e-6,
        )
        assert sol.status >= 0, sol.message
        if sol.status == 1:
            t1 = float(sol.t_events[0][0])
            p, v, d = float(sol.y_events[0][0][0]), 0.0, way_from_rest(t1)
        else:
            p, v = float(sol.y[0, -1]), speed(t1, sol.y[1, -1])
        i1 = int(np.searchsorted(ticks, t1, side="right"))
        if i1 > i0:
            pos[i0:i1] = sol.sol(ticks[i0:i1])[0]
        t = t1
    return np.diff(pos) / period


def test_the_independent_simulation_matches_the_closed_form_step() -> None:
    """The solve_ivp simulation against servotune.plant.advance (the exact tick step) on a
    synthetic command with stops, reversals and an asymmetric plant: the same speeds to 1e-6
    relative (what lets the real-data fit % stand on it)."""
    period = 1e-3
    k = np.arange(4000)
    cmd = 1.5 * np.sin(2 * np.pi * k / 1500) + 0.3 * np.sin(2 * np.pi * k / 97)
    plant = Plant(
        gain_cps_per_v=3.5e6,
        tau_s=0.45,
        offset_v=0.1,
        coulomb_v=0.6,
        gain_neg_cps_per_v=3.0e6,
        coulomb_neg_v=0.7,
    )
    log = EmpsLog(
        period_s=period,
        time_logged_s=k * period,
        pos_m=np.zeros(k.size),
        ref_m=np.zeros(k.size),
        cmd_v=cmd,
        kp_per_s=1.0,
        kv_v_s_per_m=1.0,
        gtau_n_per_v=1.0,
    )
    got = _speed_by_solve_ivp(plant, log)
    a, b = step_coefficients(period, plant.tau_s)
    p, v, exact = 0.0, 0.0, []
    for u in cmd[:-1]:
        p1, v = advance(
            p,
            v,
            u + plant.offset_v,
            period,
            a,
            b,
            plant.gain_cps_per_v,
            plant.tau_s,
            plant.coulomb_v,
            math.inf,
            plant.gain_neg_cps_per_v,
            plant.coulomb_neg_v,
        )
        exact.append((p1 - p) / period)
        p = p1
    exact = np.array(exact)
    assert np.count_nonzero(exact == 0.0) > 10  # it does stick
    assert_allclose(got, exact, rtol=0, atol=1e-6 * np.max(np.abs(exact)))


# --- the files ----------------------------------------------------------------------------------


def test_files_are_the_published_ones() -> None:
    d = _data_dir()
    sums = {}
    for line in (REAL / "SHA256SUMS").read_text().splitlines():
        digest, _, rel = line.partition("  ")
        sums[rel] = digest
    for f in FILES.values():
        assert hashlib.sha256((d / f).read_bytes()).hexdigest() == sums[f"EMPS/{f}"], f


def test_read_both_logs(emps: dict[str, EmpsLog]) -> None:
    for name, log in emps.items():
        # the data README: 24841 samples at 1 ms, kp = 160.18 1/s, kv = 243.45 V/(m/s),
        # gtau = 35.15 N/V, drive command within +-10 V
        assert log.n_samples == 24841 and log.period_s == 1e-3, name
        assert (log.kp_per_s, log.kv_v_s_per_m) == (160.18, 243.45)
        assert_allclose(log.gtau_n_per_v, 35.15, atol=0.005)
        assert np.max(np.abs(log.cmd_v)) < 10.0
        assert_allclose(log.time_s[-1], 24.84, rtol=1e-12)
        assert_allclose(log.pos_counts * ENCODER_QUANTUM_M, log.pos_m, rtol=0, atol=2.5e-8)
    assert emps["EMPS"].on_encoder_grid and emps["EMPS"].force_pulses_n is None
    # the README: the PULSES file's qm is not on the encoder grid
    assert not emps["PULSES"].on_encoder_grid
    assert emps["PULSES"].grid_error_counts <= 0.5
    assert set(np.unique(emps["PULSES"].force_pulses_n)) == {0.0, 5.0}


def test_pulses_are_part_of_the_logged_command(emps: dict[str, EmpsLog]) -> None:
    """Why the pulses count as a measured input: ``vir`` is the README's loop law plus the pulses
    (1.014 V per unit of pulses_N, residual 0.005 V rms), and without pulses it is the law alone
    (0.004 V rms). Adding them to the command again would count them twice."""
    plain = emps["EMPS"].injected_v[2:]
    assert np.sqrt(np.mean(plain**2)) < 0.01
    pulses = emps["PULSES"].force_pulses_n[2:]
    injected = emps["PULSES"].injected_v[2:]
    slope, icept = np.polyfit(pulses, injected, 1)
    assert_allclose(slope, PULSE_V_PER_UNIT, rtol=0.02)
    assert abs(icept) < 0.01
    assert np.sqrt(np.mean((injected - slope * pulses - icept) ** 2)) < 0.01


def test_conversions_to_the_identifier(emps: dict[str, EmpsLog]) -> None:
    pulsed = emps["PULSES"]
    ax = pulsed.to_log().axis()
    assert ax.cmd_v is pulsed.cmd_v  # as logged, pulses included
    np.testing.assert_array_equal(ax.pos_counts, pulsed.pos_counts)
    np.testing.assert_array_equal(ax.ref_counts, np.rint(pulsed.ref_m / ENCODER_QUANTUM_M))
    lsb_v = (LOG_DAC_RANGE_V[1] - LOG_DAC_RANGE_V[0]) / 2**LOG_DAC_BITS
    assert_allclose(ax.exc_code * lsb_v, pulsed.force_pulses_n * PULSE_V_PER_UNIT, atol=lsb_v)
    assert emps["EMPS"].to_log().axis().exc_code is None
    # every key of fit_inputs() is a parameter of today's fit_arrays
    accepted = inspect.signature(fit_arrays).parameters
    assert set(pulsed.fit_inputs()) <= set(accepted)


# --- fitted on one log, compared on the other ------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("fitted_on", ["EMPS", "PULSES"])
def test_model_reproduces_the_other_log(
    emps: dict[str, EmpsLog], fitted: Callable[[str, str], FitResult], fitted_on: str, method: str
) -> None:
    res = fitted(fitted_on, method)
    other = emps[OTHER[fitted_on]]
    speed = _speed_by_solve_ivp(res.plant, other)
    measured = np.diff(other.pos_counts) / other.period_s
    pct = fit_pct(measured, speed)
    assert pct >= MIN_CROSS_FIT_PCT, f"velocity fit {pct:.1f} % on {OTHER[fitted_on]}"
    if other.force_pulses_n is not None:  # the pulse stretches fit as well as the rest
        calm = other.force_pulses_n[1:] == 0
        assert pct >= fit_pct(measured[calm], speed[calm]) - MAX_PULSE_STRETCH_LOSS_PCT


@pytest.mark.parametrize("method", METHODS)
def test_the_two_logs_agree_within_their_intervals(
    fitted: Callable[[str, str], FitResult], method: str
) -> None:
    """Each parameter's two estimates differ by no more than their 95 % intervals allow: the
    difference of two independent estimates has the half-width ``hypot(h_a, h_b)``.

    Measured (oe with moving-block bootstrap intervals, 2025-11-25): |difference| / allowed =
    0.29 (gain), 0.36 (tau), 0.15 (offset), 0.22 (Coulomb). The previous release's estimator
    (white-residual intervals) gave 2.13, 2.65, 2.45, 2.02: intervals 2–2.6× too narrow."""
    a, b = fitted("EMPS", method), fitted("PULSES", method)
    assert a.structure == b.structure
    ratios = {}
    for p in a.structure:
        half = [(r.ci95[p][1] - r.ci95[p][0]) / 2 for r in (a, b)]
        ratios[p] = abs(a.params[p] - b.params[p]) / math.hypot(*half)
    assert max(ratios.values()) <= 1.0, ratios


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("name", ["EMPS", "PULSES"])
def test_estimates_are_near_the_benchmarks_own(
    emps: dict[str, EmpsLog], fitted: Callable[[str, str], FitResult], name: str, method: str
) -> None:
    got = fitted(name, method).plant
    ref = REFERENCE_MODEL.to_plant(emps[name].gtau_n_per_v)
    for p in ("gain_cps_per_v", "tau_s", "coulomb_v"):
        assert_allclose(getattr(got, p), getattr(ref, p), rtol=REFERENCE_RTOL, err_msg=p)
    assert_allclose(got.offset_v, ref.offset_v, atol=REFERENCE_OFFSET_ATOL_V)


@pytest.fixture(scope="module")
def default_fits(emps: dict[str, EmpsLog]) -> dict[tuple[str, str], FitResult]:
    """Each log fitted as ``servotune fit`` fits it with no option (structure, friction and
    method chosen by the tool), and with ``--method oe`` alone."""
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name in FILES:
            out[name, "default"] = st.fit(emps[name].to_log())
            out[name, "oe"] = st.fit(emps[name].to_log(), method="oe")
    return out


def _idim_ls(log: EmpsLog) -> EmpsPhysics:
    """The benchmark's own estimator (IDIM-LS, Janot, Gautier & Brunot 2019, the data set's
    ``Identification_EMPS`` recipe) on ``log``: the position low-passed forward and backward
    (4th-order Butterworth at 100 Hz), speed and acceleration by central differences, the
    inverse model ``M·a + Fv·v + Fc·sign(v) + offset = gtau·vir`` sampled after decimation by
    10 (scipy's anti-aliased ``decimate``; 10 samples dropped at each end) and solved by least
    squares. Written here, independently of servotune's identifier."""
    fs = 1.0 / log.period_s
    b, a = butter(4, 100.0 / (fs / 2.0))
    q = filtfilt(b, a, log.pos_m)
    v, acc = np.zeros_like(q), np.zeros_like(q)
    v[1:-1] = (q[2:] - q[:-2]) / (2.0 * log.period_s)
    acc[1:-1] = (q[2:] - 2.0 * q[1:-1] + q[:-2]) / log.period_s**2
    cols = [decimate(c, 10) for c in (acc, v, np.sign(v), log.gtau_n_per_v * log.cmd_v)]
    x = np.column_stack([*cols[:3], np.ones(cols[0].size)])[10:-10]
    (m, fv, fc, off), *_ = np.linalg.lstsq(x, cols[3][10:-10], rcond=None)
    return EmpsPhysics(mass_kg=m, viscous_n_s_per_m=fv, coulomb_n=fc, offset_n=off)


def test_the_idim_ls_recipe_gives_the_published_model(emps: dict[str, EmpsLog]) -> None:
    """:func:`_idim_ls` on DATA_EMPS is the benchmark's published estimate (REFERENCE_MODEL:
    M 95.1089 kg, Fv 203.5034 N·s/m, Fc 20.3935 N, offset −3.1648 N) within 1 % (the offset
    within 0.1 N): the recipe is theirs, so applied to PULSES it is their model of that log."""
    got = _idim_ls(emps["EMPS"])
    for name in ("mass_kg", "viscous_n_s_per_m", "coulomb_n"):
        assert getattr(got, name) == pytest.approx(getattr(REFERENCE_MODEL, name), rel=0.01)
    assert abs(got.offset_n - REFERENCE_MODEL.offset_n) < 0.1


@pytest.mark.parametrize("fitted_on", ["EMPS", "PULSES"])
def test_the_default_fit_predicts_the_other_log_as_the_alternatives_do(
    emps: dict[str, EmpsLog], default_fits: dict[tuple[str, str], FitResult], fitted_on: str
) -> None:
    """The default (no option) on the real drive: fitted on one log, simulated by solve_ivp on
    the other's command. Before the held-out check of the structure, BIC kept gain, tau and
    delay (refined IV had no solution with friction) and the default reached 71.7 % (EMPS →
    PULSES) and 80.0 % (PULSES → EMPS). The benchmark's IDIM-LS is compared as it would be
    used, estimated on the same log: the published model where that log is DATA_EMPS (92.63 %
    on PULSES), the benchmark's recipe (:func:`_idim_ls`) on PULSES (94.01 % on EMPS; the
    published model on EMPS is in its own estimation data, 95.01 %, which no model fitted on
    PULSES reaches: the drive needed about 4.5 % more viscous force in the PULSES run, measured
    between the two logs at equal speeds away from the pulses).
    Measured (2026-11-29): fitted on EMPS, iv with its structure chosen by held-out prediction
    reached 93.57 % against oe's 93.92 %; the default now keeps least squares there, because it
    agrees with iv within iv's intervals (next test), so the two are equal (93.92 %); fitted on
    PULSES, iv has no solution and the default is least squares (94.03 %)."""
    other = emps[OTHER[fitted_on]]
    measured = np.diff(other.pos_counts) / other.period_s

    def pct(plant: Plant) -> float:
        return fit_pct(measured, _speed_by_solve_ivp(plant, other))

    got = pct(default_fits[fitted_on, "default"].plant)
    oe_pct = pct(default_fits[fitted_on, "oe"].plant)
    assert got >= MIN_CROSS_FIT_PCT, got
    assert got >= oe_pct, (got, oe_pct)
    gtau = emps[fitted_on].gtau_n_per_v
    idim = REFERENCE_MODEL if fitted_on == "EMPS" else _idim_ls(emps[fitted_on])
    ref = pct(idim.to_plant(gtau))
    assert got >= ref, (got, ref)


def test_the_default_keeps_least_squares_only_where_it_agrees_with_iv(
    emps: dict[str, EmpsLog], default_fits: dict[tuple[str, str], FitResult]
) -> None:
    """On DATA_EMPS (a stiff position loop, little disturbance) least squares places gain and
    tau inside the consistent iv estimate's own 95 % intervals and predicts held-out samples
    better, so the default takes it and says so. The other side of the rule, a closed-loop log
    whose disturbance biases least squares by about -10 %, keeps iv:
    tests/identify/test_closed_loop_iv.py (50 logs, every one iv)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ivr = st.fit(emps["EMPS"].to_log(), method="iv")
    got = default_fits["EMPS", "default"]
    assert got.method == "oe", got.method_reason
    assert "agrees with instrumental variables" in got.method_reason
    for p in AGREEMENT_PARAMS:
        lo, hi = ivr.ci95[p]
        assert lo <= got.params[p] <= hi, (p, got.params[p], ivr.ci95[p])
    assert got.fit_pct["velocity"]["validation"] > ivr.fit_pct["velocity"]["validation"]


# --- the reader without the real data -----------------------------------------------------------


def _write_mat(path: Path, n: int = 50, **changes: object) -> Path:
    """A small file in the EMPS layout: a loop law that holds exactly (``vir`` = the README's
    formula), positions on the encoder grid."""
    period = 1e-3
    qm = np.rint(2000 * np.sin(np.arange(n) / 7.0)) * ENCODER_QUANTUM_M
    qg = qm + 1e-6
    dq = np.zeros(n)
    dq[2:] = (qm[2:] - qm[:-2]) / (2 * period)
    kp, kv = 160.18, 243.45
    data = {
        "t": np.arange(n) * period,
        "qm": qm,
        "qg": qg,
        "vir": kv * (kp * (qg - qm) - dq),
        "kp": kp,
        "kv": kv,
        "gtau": 35.15,
    }
    data.update(changes)
    scipy.io.savemat(path, {k: v for k, v in data.items() if v is not None})
    return path


def test_a_small_file_reads_in_the_stated_units(tmp_path: Path) -> None:
    log = read_emps(_write_mat(tmp_path / "small.mat"))
    assert log.period_s == 1e-3 and log.on_encoder_grid and log.force_pulses_n is None
    np.testing.assert_array_equal(log.pos_counts, np.rint(2000 * np.sin(np.arange(50) / 7.0)))
    assert_allclose(log.injected_v[2:], 0.0, atol=1e-9)  # the file's vir is the loop law
    assert np.isnan(log.injected_v[:2]).all()
    assert log.path == str(tmp_path / "small.mat")


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "no such file"),
        (b"", "not a readable MATLAB"),
        (b"MATLAB 5.0 MAT-file" + b"\x00" * 30, "not a readable MATLAB"),
        ("truncated", "not a readable MATLAB"),
        ({"qm": None}, "no variable qm"),
        ({"qm": "abc"}, "'qm' is not a real numeric"),
        ({"vir": np.zeros(49)}, "differ in length"),
        ({"t": np.r_[np.arange(25), np.arange(26, 51)] * 1e-3}, "not uniform"),
        ({"gtau": 0.0}, "gtau_n_per_v must be a number > 0"),
        ({"qg": np.full(50, np.nan)}, "'qg' is not finite at sample 0"),
    ],
    ids=[
        "missing",
        "empty",
        "header-only",
        "truncated",
        "no-qm",
        "text-qm",
        "short-vir",
        "time-gap",
        "gtau-zero",
        "nan-qg",
    ],
)
def test_a_bad_file_is_one_error_naming_it(tmp_path: Path, content: object, message: str) -> None:
    path = tmp_path / "bad.mat"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content == "truncated":
        raw = _write_mat(tmp_path / "good.mat").read_bytes()
        path.write_bytes(raw[: len(raw) // 2])
    elif isinstance(content, dict):
        _write_mat(path, **content)
    with pytest.raises(LogFormatError, match=message) as info:
        read_emps(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


# --- the physics mapping ------------------------------------------------------------------------


def test_physical_units_map_to_the_axis_model() -> None:
    """gain = gtau/(Fv·q), tau = m/Fv, coulomb = Fc/gtau, offset = −offset/gtau (module doc)."""
    plant = REFERENCE_MODEL.to_plant(35.15)
    # hand computation from the benchmark's M = 95.1089 kg, Fv = 203.5034 N/(m/s),
    # Fc = 20.3935 N, offset = -3.1648 N (Simulation_EMPS.m) and gtau = 35.15 N/V
    assert_allclose(plant.gain_cps_per_v, 35.15 / 203.5034 / 5e-8, rtol=1e-12)
    assert_allclose(plant.tau_s, 95.1089 / 203.5034, rtol=1e-12)
    assert_allclose(plant.coulomb_v, 20.3935 / 35.15, rtol=1e-12)
    assert_allclose(plant.offset_v, 3.1648 / 35.15, rtol=1e-12)
    asym = EmpsPhysics(
        mass_kg=90.0,
        viscous_n_s_per_m=200.0,
        coulomb_n=20.0,
        offset_n=-4.0,
        viscous_neg_n_s_per_m=250.0,
        coulomb_neg_n=25.0,
    )
    p = asym.to_plant(40.0)
    assert_allclose(p.gains_cps_per_v, (40 / 200 / 5e-8, 40 / 250 / 5e-8), rtol=1e-12)
    assert_allclose(p.coulombs_v, (0.5, 0.625), rtol=1e-12)
    for phys, gtau in ((REFERENCE_MODEL, 35.15), (asym, 40.0)):
        back = EmpsPhysics.from_plant(phys.to_plant(gtau), gtau).to_dict()
        for f, v in phys.to_dict().items():
            assert back[f] == v if v is None else math.isclose(back[f], v, rel_tol=1e-12), f
    with pytest.raises(ValueError, match="mass_kg must be a number > 0"):
        EmpsPhysics(mass_kg=0.0, viscous_n_s_per_m=1.0, coulomb_n=0.0, offset_n=0.0)
