"""Lightly damped modes: the sampled modal model's response and the fit of modes to an FRF
(servotune.identify.modes).

The response is checked against references that share no code with it: python-control's
zero-order-hold sampling of the continuous transfer function (a delay of whole ticks), and a
simulation of the held, delayed input at an eighth of the tick (``scipy.signal.cont2discrete``
and ``dlsim``: a delay of a fraction of a tick), whose periodic steady state gives the response
line by line. The fits are run on synthetic measurements: that (checked) response at the lines
of a multisine plus complex Gaussian noise of known standard deviation, so the truth is known.
"""

from __future__ import annotations

import dataclasses
import json
import math

import control
import numpy as np
import pytest
from scipy import signal

from servotune.analysis.frf import Frf
from servotune.errors import SpecError
from servotune.excite import periodic_multisine
from servotune.identify.modes import ModeFit, fit_modes
from servotune.modal import Mode, discretize_lti, modal_response
from servotune.plant import Plant

K, TAU = 12288.0, 0.025  # the example rig's master: counts/s per V, s
DELAY, COMPUTE = 0.0008, 0.0005  # s
TWO = (Mode(freq_hz=60.0, damping=0.05, gain=0.4), Mode(freq_hz=230.0, damping=0.03, gain=0.15))


def _continuous(modes: tuple[Mode, ...]) -> control.TransferFunction:
    """K / (s (τ s + 1)) · (1 + Σ g s² / (s² + 2 ζ ω s + ω²)), no delay."""
    s = control.tf("s")
    factor = control.tf([1.0], [1.0])
    for m in modes:
        w = 2.0 * math.pi * m.freq_hz
        factor = factor + m.gain * s**2 / (s**2 + 2.0 * m.damping * w * s + w**2)
    return K / (s * (TAU * s + 1.0)) * factor


def _response(freq: np.ndarray, period_s: float, modes, delay_s: float, **kw) -> np.ndarray:
    return modal_response(
        freq, gain_cps_per_v=K, tau_s=TAU, delay_s=delay_s, period_s=period_s, modes=modes, **kw
    )


# --- the response --------------------------------------------------------------------------


@pytest.mark.parametrize("period_s", [0.004, 0.001])
@pytest.mark.parametrize("ticks", [0, 1, 3])
def test_a_whole_tick_delay_is_python_control_s_zoh_sampling(period_s: float, ticks: int) -> None:
    modes = TWO if period_s == 0.001 else (Mode(freq_hz=35.0, damping=0.02, gain=0.5),)
    sampled = control.sample_system(control.ss(_continuous(modes)), period_s, method="zoh")
    sampled = sampled * control.tf([1.0], [1.0] + [0.0] * ticks, dt=period_s)  # z^-ticks
    f = np.linspace(0.2, 0.49 / period_s, 400)
    z = np.exp(2j * math.pi * f * period_s)
    want = np.asarray(sampled(z)).ravel()
    got = _response(f, period_s, modes, ticks * period_s, output="position")
    np.testing.assert_allclose(got, want, rtol=1e-9)
    velocity = _response(f, period_s, modes, ticks * period_s)  # the backward difference / T
    np.testing.assert_allclose(velocity, want * (1.0 - 1.0 / z) / period_s, rtol=1e-9)


def _fine_step_response(
    sys_c: control.TransferFunction, period_s: float, sub: int, lag_steps: int, bins: np.ndarray
) -> np.ndarray:
    """The position response at ``bins / (N T)`` (N = 500 ticks a period): a multisine written
    every tick, held, reaching the plant ``lag_steps`` fine steps (of ``T / sub``) later, the
    plant simulated exactly at the fine step (ZOH is exact for an input constant over each fine
    step), the output sampled every tick; the last of 6 periods is the steady state."""
    n_per, periods = 500, 6
    ss = control.ss(sys_c)
    disc = signal.cont2discrete((ss.A, ss.B, ss.C, ss.D), period_s / sub, method="zoh")
    k = np.arange(n_per * periods)
    phases = np.random.default_rng(0).uniform(0, 2 * np.pi, bins.size)
    u = np.cos(2 * np.pi * np.outer(k, bins) / n_per + phases).sum(axis=1)
    n = np.arange(u.size * sub)
    w = np.where(n >= lag_steps, u[np.maximum(n - lag_steps, 0) // sub], 0.0)
    _, y, _ = signal.dlsim((*disc[:4], period_s / sub), w)
    y_ticks = y[::sub, 0]  # C x at every tick (no feedthrough)
    last = slice(n_per * (periods - 1), None)
    return np.fft.fft(y_ticks[last])[bins] / np.fft.fft(u[last])[bins]


@pytest.mark.parametrize("lag_steps", [3, 19, 12])
def test_a_fractional_delay_matches_a_simulation_at_a_finer_step(lag_steps: int) -> None:
    period_s, sub = 0.001, 8
    bins = np.array([3, 7, 19, 30, 47, 61, 89, 113, 115, 151, 199, 233])  # 6 … 466 Hz
    want = _fine_step_response(_continuous(TWO), period_s, sub, lag_steps, bins)
    lag = lag_steps * period_s / sub  # 0.375, 2.375, 1.5 ticks
    f = bins / (500 * period_s)
    compute = min(COMPUTE, lag)  # the total lag split into the plant's delay and compute time
    got = _response(f, period_s, TWO, lag - compute, compute_s=compute, output="position")
    np.testing.assert_allclose(got, want, rtol=1e-8)


def test_without_modes_it_is_the_engine_s_sampled_plant() -> None:
    period_s, lag = 0.004, 0.0023  # 0.575 ticks
    sampled = discretize_lti(control.tf([K], [TAU, 1.0, 0.0]), period_s, lag)
    f = np.linspace(0.5, 120.0, 50)
    z = np.exp(2j * math.pi * f * period_s)
    want = np.asarray(sampled(z)).ravel()
    np.testing.assert_allclose(_response(f, period_s, (), lag, output="position"), want, rtol=1e-9)


def test_a_mode_is_a_two_mass_system_seen_from_the_motor() -> None:
    """Motor and load inertias coupled by a spring and a damper, torque in, motor angle out:
    1 / ((J_m + J_l) s²) times the modal factor with g = J_l / J_m."""
    j_m, j_l, k, c = 2e-4, 3e-4, 400.0, 0.01  # kg m², kg m², N m/rad, N m s/rad
    s = control.tf("s")
    physical = (j_l * s**2 + c * s + k) / (s**2 * (j_m * j_l * s**2 + (j_m + j_l) * (c * s + k)))
    w = math.sqrt(k * (j_m + j_l) / (j_m * j_l))
    mode = Mode(
        freq_hz=w / (2 * math.pi), damping=c * (j_m + j_l) / (j_m * j_l) / (2 * w), gain=j_l / j_m
    )
    modal = (
        1 / ((j_m + j_l) * s**2) * (1 + mode.gain * s**2 / (s**2 + 2 * mode.damping * w * s + w**2))
    )
    jw = 2j * math.pi * np.linspace(1.0, 400.0, 50)
    np.testing.assert_allclose(np.asarray(modal(jw)), np.asarray(physical(jw)), rtol=1e-9)
    assert mode.antiresonance_hz == pytest.approx(math.sqrt(k / j_l) / (2 * math.pi))
    assert Mode(freq_hz=50.0, damping=0.1, gain=-0.36).antiresonance_hz == pytest.approx(62.5)


def test_nearly_critical_damping_is_still_exact() -> None:
    modes = (Mode(freq_hz=40.0, damping=0.9999999, gain=0.3),)  # a nearly repeated pole pair
    sampled = control.sample_system(control.ss(_continuous(modes)), 0.004, method="zoh")
    f = np.linspace(0.5, 120.0, 60)
    want = np.asarray(sampled(np.exp(2j * math.pi * f * 0.004))).ravel()
    np.testing.assert_allclose(_response(f, 0.004, modes, 0.0, output="position"), want, rtol=1e-7)


@pytest.mark.parametrize(
    ("fields", "name"),
    [
        ({"freq_hz": 0.0}, "freq_hz"),
        ({"damping": 1.0}, "damping"),
        ({"damping": 0.0}, "damping"),
        ({"gain": -1.0}, "gain"),
        ({"freq_hz": math.nan}, "freq_hz"),
    ],
)
def test_a_mode_out_of_range_is_refused_naming_its_field(fields: dict, name: str) -> None:
    kw = {"freq_hz": 50.0, "damping": 0.05, "gain": 0.2} | fields
    with pytest.raises(SpecError, match=f"^Mode {name} must be") as err:
        Mode(**kw)
    assert "\n" not in str(err.value)


def test_a_mode_at_or_above_nyquist_and_bad_settings_are_refused() -> None:
    f = np.array([10.0, 20.0])
    with pytest.raises(SpecError, match="below the Nyquist frequency 125 Hz"):
        _response(f, 0.004, (Mode(freq_hz=125.0, damping=0.05, gain=0.2),), 0.0)
    with pytest.raises(SpecError, match=r"within .* Nyquist"):
        _response(np.array([10.0, 130.0]), 0.004, (), 0.0)
    with pytest.raises(SpecError, match="output must be one of"):
        _response(f, 0.004, (), 0.0, output="torque")
    with pytest.raises(SpecError, match="delay_s must be"):
        _response(f, 0.004, (), -0.001)


# --- the fit -------------------------------------------------------------------------------


def _frf(freq: np.ndarray, resp: np.ndarray, std: np.ndarray, period_s: float, output: str):
    empty = np.zeros(0)
    return Frf(
        freq_hz=freq,
        response=resp,
        std=std,
        radius95=2.45 * std,
        coherence=np.ones(freq.size),
        noise=std,
        output_level=np.abs(resp),
        aliased=freq > 0.8 * 0.5 / period_s,
        odd_hz=empty,
        odd_level=empty,
        odd_noise=empty,
        even_hz=empty,
        even_level=empty,
        even_noise=empty,
        output=output,
        period_s=period_s,
        period_ticks=0,
        periods=8,
        skipped=1,
    )


def _measured(
    modes, seed: int, *, period_s: float = 0.004, rel: float = 0.1, output: str = "velocity"
) -> Frf:
    """The true response at a random odd multisine's lines plus complex Gaussian noise of
    standard deviation ``rel · |G|`` (``E |noise|² = std²``)."""
    ticks = 2048 if period_s == 0.004 else 4096
    band = (1.0, 110.0) if period_s == 0.004 else (2.0, 450.0)
    f = periodic_multisine(ticks, 2, period_s, 100, band_hz=band).freq_hz
    g = _response(f, period_s, modes, DELAY, compute_s=COMPUTE, output=output)
    std = rel * np.abs(g)
    rng = np.random.default_rng(seed)
    noise = (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)) * std / math.sqrt(2)
    return _frf(f, g + noise, std, period_s, output)


def _random_mode(rng: np.random.Generator, f_max: float) -> Mode:
    return Mode(
        freq_hz=float(np.exp(rng.uniform(math.log(10.0), math.log(f_max)))),
        damping=float(np.exp(rng.uniform(math.log(0.01), math.log(0.1)))),
        gain=float(np.exp(rng.uniform(math.log(0.1), math.log(1.0)))),
    )


def _recovery(period_s: float, f_max: float, seeds: int) -> dict[str, np.ndarray]:
    """Per seed: a random mode, measured and fitted (one mode): the relative errors of its
    frequency and damping and whether the 95 % intervals (theirs, the gain's) hold the truth."""
    rng = np.random.default_rng(int(period_s * 1e6) + seeds)
    out: dict[str, list] = {"f_err": [], "z_err": [], "f_in": [], "z_in": [], "g_in": []}
    for seed in range(seeds):
        truth = _random_mode(rng, f_max)
        fit = fit_modes(_measured((truth,), seed, period_s=period_s), n_modes=1, compute_s=COMPUTE)
        (m,) = fit.modes
        out["f_err"].append(m.freq_hz / truth.freq_hz - 1.0)
        out["z_err"].append(m.damping / truth.damping - 1.0)
        for key, value, interval in (
            ("f_in", truth.freq_hz, m.freq_hz_95),
            ("z_in", truth.damping, m.damping_95),
            ("g_in", truth.gain, m.gain_95),
        ):
            out[key].append(interval[0] <= value <= interval[1])
    return {k: np.array(v) for k, v in out.items()}


def _check_recovery(r: dict[str, np.ndarray]) -> None:
    assert np.max(np.abs(r["f_err"])) < 0.01, r["f_err"]
    assert np.max(np.abs(r["z_err"])) < 0.20, r["z_err"]
    for key in ("f_in", "z_in", "g_in"):  # 95 % intervals: binomial spread over the seeds
        assert np.mean(r[key]) >= 0.8, (key, r[key])


@pytest.mark.parametrize(("period_s", "f_max"), [(0.004, 100.0), (0.001, 400.0)])
def test_one_mode_is_recovered_with_honest_intervals(period_s: float, f_max: float) -> None:
    _check_recovery(_recovery(period_s, f_max, 20))


@pytest.mark.slow
@pytest.mark.parametrize(("period_s", "f_max"), [(0.004, 100.0), (0.001, 400.0)])
def test_one_mode_is_recovered_over_many_seeds(period_s: float, f_max: float) -> None:
    r = _recovery(period_s, f_max, 100)
    _check_recovery(r)
    for key in ("f_in", "z_in", "g_in"):
        assert np.mean(r[key]) >= 0.88, (key, np.mean(r[key]))


def test_noiseless_lines_give_the_modes_and_the_rigid_part_exactly() -> None:
    frf = _measured(TWO, 0, period_s=0.001, rel=0.0)
    fit = fit_modes(frf, n_modes=2, compute_s=COMPUTE)
    for got, want in zip(fit.modes, TWO, strict=True):
        assert got.freq_hz == pytest.approx(want.freq_hz, rel=1e-6)
        assert got.damping == pytest.approx(want.damping, rel=1e-5)
        assert got.gain == pytest.approx(want.gain, rel=1e-5)
    assert fit.gain_cps_per_v == pytest.approx(K, rel=1e-6)
    assert fit.tau_s == pytest.approx(TAU, rel=1e-6)
    assert fit.delay_s == pytest.approx(DELAY, abs=1e-9)
    np.testing.assert_allclose(fit.response(frf.freq_hz), frf.response, rtol=1e-6)


def test_a_position_response_a_given_start_and_a_mode_below_its_anti_resonance() -> None:
    truth = (Mode(freq_hz=40.0, damping=0.03, gain=-0.3),)  # anti-resonance above, at 47.8 Hz
    frf = _measured(truth, 3, output="position")
    start = Plant(gain_cps_per_v=10000.0, tau_s=0.03, delay_s=0.0)
    fit = fit_modes(frf, n_modes=1, rigid=start, compute_s=COMPUTE)
    (m,) = fit.modes
    assert m.freq_hz == pytest.approx(40.0, rel=0.01)
    assert m.damping == pytest.approx(0.03, rel=0.2)
    assert m.gain == pytest.approx(-0.3, rel=0.05)
    assert fit.output == "position" and fit.order_rule == "given" and fit.held_out == {}
    assert 0.7 < fit.reduced_chi_square < 1.3


def test_two_modes_are_recovered() -> None:
    truth = (Mode(freq_hz=18.0, damping=0.03, gain=0.4), Mode(freq_hz=70.0, damping=0.02, gain=0.1))
    fit = fit_modes(_measured(truth, 1), n_modes=2, compute_s=COMPUTE)
    for got, want in zip(fit.modes, truth, strict=True):
        assert got.freq_hz == pytest.approx(want.freq_hz, rel=0.01)
        assert got.damping == pytest.approx(want.damping, rel=0.2)


def test_aliased_lines_are_left_out() -> None:
    frf = _measured((Mode(freq_hz=30.0, damping=0.03, gain=0.3),), 2)
    assert np.any(frf.aliased)
    spoiled = frf.response.copy()
    spoiled[frf.aliased] *= -5.0  # what a mode above Nyquist might fold onto them
    clean = fit_modes(frf, n_modes=1, compute_s=COMPUTE)
    dirty = fit_modes(dataclasses.replace(frf, response=spoiled), n_modes=1, compute_s=COMPUTE)
    assert dirty.modes[0].freq_hz == pytest.approx(clean.modes[0].freq_hz, rel=1e-9)
    assert dirty.lines == clean.lines == int(np.sum(~frf.aliased))


def _auto_fits(modes, seeds: range) -> list[ModeFit]:
    return [fit_modes(_measured(modes, s), compute_s=COMPUTE) for s in seeds]


def test_auto_picks_no_mode_on_rigid_data_and_one_on_one_mode_data() -> None:
    assert [len(fit.modes) for fit in _auto_fits((), range(100, 110))] == [0] * 10
    fits = _auto_fits((Mode(freq_hz=30.0, damping=0.03, gain=0.3),), range(200, 205))
    assert [len(fit.modes) for fit in fits] == [1] * 5
    for fit in fits:  # one mode cut the held-out error to about the noise; a second did not
        assert fit.order_rule == "auto" and sorted(fit.held_out) == [0, 1, 2]
        assert fit.held_out[1] < 0.8 * fit.held_out[0] and fit.held_out[2] > 0.8 * fit.held_out[1]
        assert 0.7 < fit.held_out[1] < 1.3


@pytest.mark.slow
def test_auto_picks_no_mode_on_rigid_data_over_many_seeds() -> None:
    orders = [len(fit.modes) for fit in _auto_fits((), range(1000, 1100))]
    assert orders.count(0) >= 95, orders


@pytest.mark.slow
def test_auto_picks_one_mode_on_one_mode_data_over_many_seeds() -> None:
    rng = np.random.default_rng(5)
    hits = 0
    for seed in range(50):
        mode = _random_mode(rng, 100.0)
        hits += len(fit_modes(_measured((mode,), seed), compute_s=COMPUTE).modes) == 1
    assert hits >= 48, hits


def test_to_dict_is_plain_data_with_units_in_the_keys() -> None:
    fit = fit_modes(_measured(TWO[:1], 4), n_modes=1, compute_s=COMPUTE)
    assert isinstance(fit, ModeFit)
    d = json.loads(json.dumps(fit.to_dict()))
    (mode,) = d["modes"]
    assert set(mode) == {
        "freq_hz",
        "freq_hz_95",
        "damping",
        "damping_95",
        "gain",
        "gain_95",
        "antiresonance_hz",
    }
    lo, hi = mode["freq_hz_95"]
    assert lo < mode["freq_hz"] < hi
    assert set(d["rigid"]) == {
        "gain_cps_per_v",
        "gain_cps_per_v_95",
        "tau_s",
        "tau_s_95",
        "delay_s",
        "delay_s_95",
    }
    assert d["dof"] == 2 * d["lines"] - 6 and d["compute_s"] == COMPUTE


def test_bad_requests_are_one_line_errors() -> None:
    frf = _measured((), 0)
    few = _frf(frf.freq_hz[:8], frf.response[:8], frf.std[:8], 0.004, "velocity")
    above = _frf(np.array([10.0, 20.0, 130.0]), np.ones(3, complex), np.ones(3), 0.004, "velocity")
    cases = [
        ({"frf": few, "n_modes": 2}, "8 lines not flagged aliased: too few for 2 modes"),
        ({"frf": above, "n_modes": 0}, r"within .* Nyquist"),
        ({"frf": frf, "n_modes": -1}, "n_modes must be"),
        ({"frf": frf, "n_modes": "two"}, "n_modes must be"),
        ({"frf": frf, "max_modes": -1}, "max_modes must be"),
        ({"frf": frf, "compute_s": -0.001}, "compute_s must be"),
        ({"frf": frf, "rigid": object()}, "rigid must have gain_cps_per_v"),
    ]
    for kw, message in cases:
        with pytest.raises(SpecError, match=message) as err:
            fit_modes(kw.pop("frf"), **kw)
        assert "\n" not in str(err.value)
