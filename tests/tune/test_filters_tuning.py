"""Tuning with output filters on the resonant example rig (plants/belt-scale.toml), judged on
an independent plant: the rig's master plant written out below and integrated by
``scipy.integrate.solve_ivp``, its frequency response measured from a periodic multisine, and
the loops rebuilt with python-control (``FrequencyResponseData`` of the measured response times
the controller and the filter, discretised here from their constants).

**The plant** (the rig file's own words, docs/frf.md#modes): a speed-command drive, rigid speed
``v' = (K·u − v)/τ``, rigid position ``p' = v``, and the mode ``q'' = v' − 2ζω q' − ω² q``; the
scale reads ``y = p + g·q``. The D/A output ``u = lsb·code`` is written ``lag = compute_s +
delay_s`` after the tick and held (zero-order hold); ``y`` is sampled at the tick. Nothing of
servotune's plant model, discretisation or margins is used.

A study (marker ``study``, ``make test-study``, run by ``.ci/run`` after ``make test``): its plant
integrated tick by tick and four robust designs per filter choice take about a minute of one
core (docs/decisions.md#8-test-time).
"""

from __future__ import annotations

import dataclasses
import math

import control
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.signal import freqz, lfilter

from servotune.analysis.plant_cases import mode_factors
from servotune.examples import example_path
from servotune.laws.filters import realize, section_from_dict
from servotune.rig import load_rig
from servotune.tune.filters import choose_filters
from servotune.tune.pi import tune_pi
from servotune.tune.slave import SlaveTuneSpec

N_TICKS = 1000
"""Multisine period [ticks] (4 s: 0.25 Hz resolution)."""
LINES = np.arange(1, 480)
"""Excited lines (harmonics of 0.25 Hz up to 119.75 Hz, below Nyquist)."""
pytestmark = pytest.mark.study

PM_TOL_DEG = 0.6
"""The design's targets hold to python-control's on the exact loop; measured on a response
sampled at 0.25 Hz spacing, between the lines (the tuner's own tolerance is 0.5°)."""


@dataclasses.dataclass(frozen=True)
class Axis:
    gain: float  # [counts/s/V]
    tau: float  # [s]
    lag: float  # tick → D/A write → motor [s]
    f: float  # mode [Hz]
    zeta: float
    g: float
    lsb: float  # [V/code]
    period: float  # [s]

    def rhs(self, u: float):
        w = 2 * math.pi * self.f

        def f(_t, x):
            _, v, q, dq = x
            dv = (self.gain * u - v) / self.tau
            return [v, dv, dq, dv - 2 * self.zeta * w * dq - w * w * q]

        return f

    def run(self, codes: np.ndarray, x0=None) -> np.ndarray:
        """Positions [counts] at ticks 1..n for D/A codes 0..n−1 (held from tick + lag)."""
        x = np.zeros(4) if x0 is None else np.array(x0, float)
        t, u_prev, out = 0.0, 0.0, []
        for code in codes:
            # [t_k, t_k + lag): the previous output; [t_k + lag, t_k+1): this one
            for u, dt in ((u_prev, self.lag), (code * self.lsb, self.period - self.lag)):
                sol = solve_ivp(self.rhs(u), (0.0, dt), x, rtol=1e-10, atol=1e-9)
                x = sol.y[:, -1]
            u_prev = code * self.lsb
            t += self.period
            out.append(x[0] + self.g * x[2])
        return np.array(out)


def _axis(rig, freq_factor: float = 1.0) -> Axis:
    a = rig.axes[0]
    p, (m,) = a.plant, a.plant.modes
    return Axis(
        gain=p.gain_cps_per_v,
        tau=p.tau_s,
        lag=rig.timer.compute_s + p.delay_s,
        f=m.freq_hz * freq_factor,
        zeta=m.damping,
        g=m.gain,
        lsb=rig.dac.lsb_v,
        period=rig.period_s,
    )


def _measured_frf(axis: Axis) -> control.FrequencyResponseData:
    """Codes → counts, from three periods of a Schroeder multisine (the last one, after the
    mode's transient has decayed: 1/(ζω) = 0.35 s)."""
    k = np.arange(N_TICKS)
    phases = -math.pi * LINES * (LINES - 1) / LINES.size
    x = np.sum(np.cos(2 * math.pi * np.outer(k, LINES) / N_TICKS + phases[None, :]), axis=1)
    codes = 40.0 * x / np.max(np.abs(x))  # ±40 codes: a linear plant, any level
    y = _axis_run(axis, np.tile(codes, 3))
    # y_k is sampled at the start of tick k+1: the response to the codes of ticks ≤ k, so the
    # frequency response from code_k to y at tick k is Y·e^{-jωT} shifted by one tick
    u_f = np.fft.fft(codes)[LINES]
    y_last = y[2 * N_TICKS - 1 : 3 * N_TICKS - 1]  # y at ticks 2N .. 3N−1
    y_f = np.fft.fft(y_last)[LINES]
    w = 2 * math.pi * LINES / (N_TICKS * axis.period)
    return control.frd(y_f / u_f, w)


def _axis_run(axis: Axis, codes: np.ndarray) -> np.ndarray:
    return axis.run(codes)


def _controller(kp: float, ki_t: float, period: float) -> control.TransferFunction:
    """The runtime's PI as documented (docs/runtime.md): ``Kp + Ki·T·z/(z − 1)``."""
    return control.tf([kp + ki_t, -kp], [1.0, -1.0], period)


def _filter(sections, period: float) -> control.TransferFunction:
    out = control.tf([1.0], [1.0], period)
    for s in sections:
        b = np.array([s.b0, s.b1, s.b2], float) * 2.0**-s.frac_bits
        a = np.array([1.0, s.a1 * 2.0**-s.frac_bits, s.a2 * 2.0**-s.frac_bits])
        out = out * control.tf(b, a, period)
    return out


def _times(
    frd: control.FrequencyResponseData, *tfs: control.TransferFunction
) -> control.FrequencyResponseData:
    """A measured response times discrete transfer functions, evaluated on its frequencies."""
    w = frd.omega
    resp = frd.frequency_response(w).complex.ravel()
    for tf in tfs:
        resp = resp * np.array([complex(tf(z)) for z in np.exp(1j * w * tf.dt)])
    return control.frd(resp, w)


def _figures(loop_frd: control.FrequencyResponseData) -> tuple[float, float, float, float]:
    """PM [deg], GM [dB], Ms and the gain crossover [rad/s] of an FRD loop."""
    gm, pm, _, _, wcg, _ = control.stability_margins(loop_frd)
    resp = loop_frd.frequency_response(loop_frd.omega).complex.ravel()
    ms = float(np.max(1.0 / np.abs(1.0 + resp)))
    gm_db = math.inf if gm is None or not np.isfinite(gm) else 20 * math.log10(gm)
    return float(pm), gm_db, ms, float(wcg)


@pytest.fixture(scope="module")
def design():
    rig = load_rig(example_path("belt-scale.toml"))
    spec = SlaveTuneSpec()
    cases = spec.plant_cases(rig)
    screen = spec.plant_cases(rig, sampled=True)
    choice = choose_filters(rig, "master", cases, spec.limits, screen)
    nominal = _axis(rig)
    lo, hi = mode_factors(rig.axes[0].plant.modes[0])
    frds = {
        "nominal": _measured_frf(nominal),
        "mode-10%": _measured_frf(_axis(rig, lo)),
        "mode+10%": _measured_frf(_axis(rig, hi)),
    }
    return rig, spec, choice, frds


def test_the_measured_response_is_the_plant(design) -> None:
    """The multisine measurement recovers the continuous plant's response well below the mode
    (the rigid part; a ZOH-sampled type-1 plant is ≈ K·lsb/(jω(1+jωτ))·e^{-jω(lag+T/2)})."""
    rig, _, _, frds = design
    a = _axis(rig)
    w = frds["nominal"].omega[:8]  # 0.25 … 2 Hz
    got = frds["nominal"].frequency_response(w).complex.ravel()
    s = 1j * w
    want = a.gain * a.lsb / (s * (1 + a.tau * s)) * np.exp(-s * (a.lag + a.period / 2))
    assert np.allclose(np.abs(got / want), 1.0, atol=0.03)


def test_a_plain_pi_tuned_on_the_rigid_model_fails_the_margins(design) -> None:
    rig, spec, _, frds = design
    a = rig.axes[0]
    rigid = tune_pi(
        dataclasses.replace(a.plant, modes=()),
        period_s=rig.period_s,
        compute_s=rig.timer.compute_s,
        lsb_v=rig.dac.lsb_v,
        phase_margin_deg=spec.limits.min_phase_margin_deg,
        gain_margin_db=spec.limits.min_gain_margin_db,
        max_sensitivity=spec.limits.max_sensitivity,
    )
    c = _controller(rigid.kp, rigid.ki * rig.period_s, rig.period_s)
    pm, gm, ms, _ = _figures(_times(frds["nominal"], c))
    lim = spec.limits
    # measured when written: PM 44.5°, Ms 2.20 (the mode's peak raises the sensitivity)
    assert (
        pm < lim.min_phase_margin_deg or gm < lim.min_gain_margin_db or ms > lim.max_sensitivity
    ), (pm, gm, ms)


def test_the_tuner_places_a_notch_on_the_mode_and_a_lead(design) -> None:
    """A notch at the mode, then a lead (a biquad whose gain rises from 1 at DC to its
    ``ratio²`` well above its centre and whose phase peaks there), checked on the realised
    integers with scipy's ``freqz``."""
    rig, _, choice, _ = design
    sec, lead = choice.sections
    (mode,) = rig.axes[0].plant.modes
    assert choice.chosen == "notch+lead" and choice.name.startswith("notch x")
    assert sec.kind == "notch" and dict(sec.params)["center_hz"] == mode.freq_hz
    assert "notch" in choice.why and "lead" in choice.why and "bandwidth" in choice.why
    q = realize(lead, rig.period_s)
    b, a = q.ba()
    centre = dict(lead.params)["warp_hz"]
    w = 2 * math.pi * np.array([0.01, centre, 0.45 / rig.period_s]) * rig.period_s
    h = freqz(b, a, worN=w)[1]
    ratio = float(choice.name.split("lead ")[1].split("@")[0])
    assert abs(h[0]) == pytest.approx(1.0, rel=0.01)
    assert np.angle(h[1], deg=True) == pytest.approx(
        2 * math.degrees(math.asin((ratio - 1) / (ratio + 1))), abs=1.0
    )
    assert 1.0 < abs(h[2]) < ratio**2 * 1.01


def _filtered_loop(design, frd, extra_ticks: int = 0):
    rig, _, choice, _ = design
    secs = [realize(s, rig.period_s) for s in choice.sections]
    g = choice.pi.gains
    c = _controller(g.kp, g.ki * rig.period_s, rig.period_s)
    delay = control.tf([1.0], [1.0] + [0.0] * extra_ticks, rig.period_s)
    return _times(frd, c, _filter(secs, rig.period_s), delay)


@pytest.mark.parametrize("which", ["nominal", "mode-10%", "mode+10%"])
@pytest.mark.parametrize("extra_ticks", [0, 1])
def test_the_filtered_tuning_keeps_every_margin_on_the_measured_response(
    design, which: str, extra_ticks: int
) -> None:
    _, spec, _, frds = design
    pm, gm, ms, _ = _figures(_filtered_loop(design, frds[which], extra_ticks))
    lim = spec.limits
    assert pm >= lim.min_phase_margin_deg - PM_TOL_DEG, pm
    assert gm >= lim.min_gain_margin_db - 0.1, gm
    assert ms <= lim.max_sensitivity * 1.01, ms


def _bandwidth(loop: control.FrequencyResponseData) -> float:
    """The lowest frequency where ``|T| = |L/(1 + L)|`` falls below −3 dB [rad/s]
    (interpolated in log-frequency between the measured lines)."""
    w = loop.omega
    resp = loop.frequency_response(w).complex.ravel()
    t_db = 20 * np.log10(np.abs(resp / (1 + resp)))
    i = int(np.argmax(t_db < -3.0))
    assert i > 0
    f = (t_db[i - 1] + 3.0) / (t_db[i - 1] - t_db[i])
    return float(np.exp(np.log(w[i - 1]) + f * (np.log(w[i]) - np.log(w[i - 1]))))


def test_the_filter_buys_bandwidth_over_the_best_plain_pi(design) -> None:
    """The goal is ≥ 1.5× the bandwidth of the best plain PI at the same margins, measured on
    the integrated plant's response. The notch alone gives 1.19× on this rig (20.7 against
    17.4 rad/s on the model: behind the notch the phase margin at the crossover binds); the
    lead on top of it 1.50× when written (26.2 rad/s). The tuner's reported ratio is held to
    the measured one."""
    rig, _, choice, frds = design
    plain = next(c for c in choice.candidates if c["name"] == "none")
    chosen = next(c for c in choice.candidates if c["name"] == choice.name)
    c = _controller(plain["kp"], plain["ki"] * rig.period_s, rig.period_s)
    bw_plain = _bandwidth(_times(frds["nominal"], c))
    bw_filtered = _bandwidth(_filtered_loop(design, frds["nominal"]))
    measured = bw_filtered / bw_plain
    reported = chosen["bandwidth_rad_s"] / plain["bandwidth_rad_s"]
    assert measured >= 1.5, measured
    assert measured == pytest.approx(reported, rel=0.03), (measured, reported)
    assert f"{reported:.2f}x" in choice.why


def _closed_loop(design, kp: float, ki: float, sections, n: int, target: float) -> np.ndarray:
    """A float PI (and filter) around the integrated plant: a step of ``target`` counts."""
    rig, *_ = design
    axis = _axis(rig)
    b = [np.array([s.b0, s.b1, s.b2], float) * 2.0**-s.frac_bits for s in sections]
    a = [np.array([1.0, s.a1 * 2.0**-s.frac_bits, s.a2 * 2.0**-s.frac_bits]) for s in sections]
    zi = [np.zeros(2) for _ in sections]
    x = np.zeros(4)
    y, integ, u_prev, out = 0.0, 0.0, 0.0, []
    for _ in range(n):
        e = target - y
        integ += ki * rig.period_s * e
        u = kp * e + integ
        for i in range(len(sections)):
            (u,), zi[i] = lfilter(b[i], a[i], [u], zi=zi[i])
        code = float(np.clip(np.round(u), -2048, 2047))
        for uu, dt in ((u_prev, axis.lag), (code * axis.lsb, axis.period - axis.lag)):
            x = solve_ivp(axis.rhs(uu), (0.0, dt), x, rtol=1e-10, atol=1e-9).y[:, -1]
        u_prev = code * axis.lsb
        y = x[0] + axis.g * x[2]
        out.append(y)
    return np.array(out)


def _ringing(y: np.ndarray, f_hz: float, period: float) -> float:
    """Amplitude [counts] of the mode's frequency in the last second (a least-squares sine)."""
    tail = y[-int(1.0 / period) :]
    t = np.arange(tail.size) * period
    basis = np.column_stack(
        [np.sin(2 * math.pi * f_hz * t), np.cos(2 * math.pi * f_hz * t), np.ones_like(t), t]
    )
    coef = np.linalg.lstsq(basis, tail, rcond=None)[0]
    return float(math.hypot(coef[0], coef[1]))


def test_a_step_settles_without_ringing(design) -> None:
    """A 400-count step through the filters and the tuned PI on the integrated plant: after 2 s
    the mode's frequency is below one count and the position within 2 counts."""
    rig, _, choice, _ = design
    (mode,) = rig.axes[0].plant.modes
    n = int(3.0 / rig.period_s)
    secs = [realize(s, rig.period_s) for s in choice.sections]
    g = choice.pi.gains
    filtered = _closed_loop(design, g.kp, g.ki, secs, n, 400.0)
    ring = _ringing(filtered, mode.freq_hz, rig.period_s)
    assert ring < 1.0, ring  # below one count: settled (the D/A's quantisation dithers)
    assert abs(filtered[-1] - 400.0) < 2.0
    # the same loop with the mode undamped by the loop would ring: the measure sees it
    shaken = filtered + 5.0 * np.sin(2 * math.pi * mode.freq_hz * rig.period_s * np.arange(n))
    assert _ringing(shaken, mode.freq_hz, rig.period_s) == pytest.approx(5.0, abs=1.0)


def test_filter_design_inputs_round_trip() -> None:
    d = {"kind": "notch", "center_hz": 15.0, "width_hz": 4.5, "depth_db": -20.0}
    assert section_from_dict(d).to_dict() == d


def test_margins_no_filter_stage_can_meet_are_one_line_naming_the_mode(
    tmp_path, capsys, monkeypatch
) -> None:
    """``servotune tune`` on the resonant rig with Ms <= 1.02 (no loop of a type-1 plant
    reaches it): exit 1, one line naming the axis's mode and the margin, no file written."""
    from servotune.cli import main

    monkeypatch.delenv("SERVOTUNE_WORKBENCH", raising=False)
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "t.json"
    argv = ["-q", "tune", str(example_path("belt-scale.toml")), "--ms", "1.02", "-o", str(out)]
    capsys.readouterr()
    rc = main([*argv, "--no-current"])
    err = capsys.readouterr().err
    assert rc == 1, err
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1, err
    assert "15 Hz" in lines[0] and "Ms" in lines[0], lines[0]
    assert "Traceback" not in err
    assert not out.exists()


# --- margins on a measured response (servotune.analysis.frf_margins) -------------------------


def _as_frf(
    frd: control.FrequencyResponseData,
    lsb: float,
    period: float,
    *,
    velocity=False,
    radius: float = 0.0,
):
    """The test's measured response (codes → counts) as a ``servotune frf`` result: counts per V,
    or counts/s per V (the backward difference over T)."""
    from servotune.analysis.frf import Frf

    w = frd.omega
    g = frd.frequency_response(w).complex.ravel() / lsb
    if velocity:
        g = g * (1 - np.exp(-1j * w * period)) / period
    n = w.size
    z = np.zeros(n)
    e = np.empty(0)
    return Frf(
        freq_hz=w / (2 * math.pi),
        response=g,
        std=z,
        radius95=radius * np.abs(g),
        coherence=np.ones(n),
        noise=z,
        output_level=z,
        aliased=np.zeros(n, bool),
        odd_hz=e,
        odd_level=e,
        odd_noise=e,
        even_hz=e,
        even_level=e,
        even_noise=e,
        output="velocity" if velocity else "position",
        period_s=period,
        period_ticks=N_TICKS,
        periods=1,
        skipped=0,
    )


@pytest.mark.parametrize("velocity", [False, True])
def test_frf_margins_are_python_controls_on_the_measured_loop(design, velocity: bool) -> None:
    """servotune's margins on a measured response equal the ones this test builds itself
    (python-control on ``C·F·lsb·Ĝ``), from a position or a velocity response."""
    from servotune.analysis.frf_margins import frf_loop
    from servotune.analysis.margins import GainSet

    rig, _, choice, frds = design
    secs = tuple(realize(s, rig.period_s) for s in choice.sections)
    g = choice.pi.gains
    frf = _as_frf(frds["nominal"], rig.dac.lsb_v, rig.period_s, velocity=velocity)
    got = frf_loop(
        frf, GainSet(g.kp, g.ki * rig.period_s), lsb_v=rig.dac.lsb_v, filters=secs, extra_ticks=1
    )
    pm, gm, ms, wc = _figures(_filtered_loop(design, frds["nominal"], 1))
    assert got.phase_margin_deg == pytest.approx(pm, abs=1e-6)
    assert got.gain_margin_db == pytest.approx(gm, abs=1e-6)
    assert got.max_sensitivity == pytest.approx(ms, rel=1e-9)
    assert got.crossover_rad_s == pytest.approx(wc, rel=1e-6)


def test_frf_bounds_make_the_margins_worse_not_better(design) -> None:
    from servotune.analysis.frf_margins import frf_loop
    from servotune.analysis.margins import GainSet

    rig, _, choice, frds = design
    g = choice.pi.gains
    gs = GainSet(g.kp, g.ki * rig.period_s)
    tight = frf_loop(_as_frf(frds["nominal"], rig.dac.lsb_v, rig.period_s), gs, lsb_v=rig.dac.lsb_v)
    loose = frf_loop(
        _as_frf(frds["nominal"], rig.dac.lsb_v, rig.period_s, radius=0.2), gs, lsb_v=rig.dac.lsb_v
    )
    assert loose.nominal_max_sensitivity == pytest.approx(tight.max_sensitivity)
    assert loose.max_sensitivity > tight.max_sensitivity * 1.05
    assert loose.phase_margin_deg < tight.phase_margin_deg


def test_a_candidate_the_measured_response_refuses_is_not_chosen(design) -> None:
    """The measured response of a machine whose mode lies at 10 Hz (outside the model's ±10 %
    of 15 Hz): the model's notch at 15 Hz does not keep the limits there, and the choice says
    so (or nothing does, and the tune stops naming the mode)."""
    from servotune.errors import InfeasibleError

    rig, spec, choice, _ = design
    off = _measured_frf(dataclasses.replace(_axis(rig), f=10.0))
    frf = _as_frf(off, rig.dac.lsb_v, rig.period_s)
    cases = spec.plant_cases(rig)
    try:
        on_frf = choose_filters(rig, "master", cases, spec.limits, frf=frf)
    except InfeasibleError as exc:
        assert "15 Hz" in str(exc) and "measured response" in str(exc)
        return
    refused = [c for c in on_frf.candidates if "measured response" in str(c.get("infeasible", ""))]
    assert refused, on_frf.candidates
    assert on_frf.sections != choice.sections


def test_a_lead_that_softens_the_lock_is_not_kept(design, monkeypatch) -> None:
    """With a larger lead ratio (1.25: more bandwidth, more gain above the crossover) the lock
    loop's robust gain falls below 0.8 of the notch's: the candidate is recorded with that
    reason and not chosen (the lock holds the axis against the drive's offset). The lock gains
    are rebuilt here with ``robust_lock_gain`` on the candidates' own sections."""
    from servotune.tune import filters as tf
    from servotune.tune.robust import robust_lock_gain

    rig, spec, _, _ = design
    monkeypatch.setattr(tf, "LEAD_RATIOS", (1.25,))
    monkeypatch.setattr(tf, "LEAD_CENTRES", (1.7,))
    cases = spec.plant_cases(rig)
    screen = spec.plant_cases(rig, sampled=True)
    choice = choose_filters(rig, "master", cases, spec.limits, screen)
    (lead,) = [c for c in choice.candidates if "+lead" in c["name"]]
    assert "lock gain" in lead.get("infeasible", ""), lead
    assert choice.chosen == "notch"

    def lock(c: dict) -> float:
        secs = tuple(section_from_dict(s) for s in c["sections"])
        axes = (dataclasses.replace(rig.axes[0], filters=secs), *rig.axes[1:])
        return robust_lock_gain(dataclasses.replace(rig, axes=axes), "master", screen, spec.limits)

    notch = next(c for c in choice.candidates if c["name"] == choice.name)
    assert lock(lead) < tf.LEAD_LOCK_KEEP * lock(notch)
