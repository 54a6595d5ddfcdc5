"""The spec's residual-vibration limit and minimum filter attenuation (servotune.verify), each
held to a measurement made here: a synthetic trace whose vibration is known, and scipy's
``freqz`` of the quantised coefficients."""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.signal import bilinear, freqz, lfilter

from servotune.errors import SpecError
from servotune.examples import example_path
from servotune.laws.axis import AxisController
from servotune.laws.filters import notch, realize
from servotune.rig import load_rig
from servotune.verify.checks import check_filter_attenuation
from servotune.verify.scenario_values import residual_vibration
from servotune.verify.spec import spec_from_dict


@pytest.fixture(scope="module")
def rig():
    return load_rig(example_path("belt-scale.toml"))  # a 15 Hz mode on the master


def _trace(rig, amplitude: float, stop: int, n: int = 1500, f_hz: float = 15.0) -> np.ndarray:
    """A 20000-count move that stops at ``stop`` (its reference), followed by a closed loop of
    3 Hz (critically damped, by scipy's bilinear transform), plus a vibration of ``amplitude``
    counts at ``f_hz`` that starts at the stop and decays with a time constant of 1 s."""
    t = np.arange(n) * rig.period_s
    ref = np.minimum(t / (stop * rig.period_s), 1.0) * 20000.0
    w = 2 * math.pi * 3.0
    b, a = bilinear([w * w], [1.0, 2 * w, w * w], fs=1.0 / rig.period_s)
    ts = np.maximum(t - stop * rig.period_s, 0.0)
    ring = np.where(
        t >= stop * rig.period_s, amplitude * np.sin(2 * math.pi * f_hz * ts) * np.exp(-ts), 0.0
    )
    return (lfilter(b, a, ref) + ring)[None, :]


@pytest.mark.parametrize("amplitude", [0.0, 5.0, 50.0])
def test_residual_vibration_measures_the_vibration_not_the_settling(rig, amplitude) -> None:
    stop = 400
    got = float(residual_vibration(_trace(rig, amplitude, stop), rig, 0, stop)[0])
    # measured from two periods of the band's low edge (0.6 · 13.5 Hz) after the stop
    delay = 2 / (0.6 * 13.5)
    want = amplitude * math.exp(-math.ceil(delay / rig.period_s) * rig.period_s)
    assert got == pytest.approx(want, abs=max(0.1 * want, 1.0)), (got, want)


def test_residual_vibration_of_a_trace_with_no_time_left_is_nan(rig) -> None:
    assert np.isnan(residual_vibration(_trace(rig, 5.0, 1495), rig, 0, 1495)[0])


def _tuning(rig, sections):
    ctl = AxisController.from_gains(lock_gain_codes_per_count=0.3, period_s=rig.period_s)
    filtered = dataclasses.replace(ctl, filters=tuple(realize(s, rig.period_s) for s in sections))
    return SimpleNamespace(axis_names=rig.axis_names, controllers=(filtered, ctl))


def _spec(**margins):
    return spec_from_dict(
        {"margins": margins, "scenario": {"lock": {"max_holding_band_counts": 6.0}}}
    )


def test_filter_attenuation_is_scipys_response_at_the_modes_range(rig) -> None:
    sec = notch(15.0, 9.0, -30.0)
    (check,) = check_filter_attenuation(
        _tuning(rig, [sec]), rig, _spec(min_filter_attenuation_db=10.0)
    )
    b, a = realize(sec, rig.period_s).ba()
    f = np.array([13.5, 15.0, 16.5])  # ±10 %: the mode has no interval
    _, h = freqz(b, a, worN=f, fs=1.0 / rig.period_s)
    want = float(np.min(-20 * np.log10(np.abs(h))))
    assert check.value == pytest.approx(want, abs=1e-9)
    assert check.passed == (want >= 10.0) and check.name == "filters:master"


def test_a_narrow_notch_fails_a_wide_attenuation_and_no_filter_fails_any(rig) -> None:
    spec = _spec(min_filter_attenuation_db=10.0)
    (narrow,) = check_filter_attenuation(_tuning(rig, [notch(15.0, 2.0, -30.0)]), rig, spec)
    assert not narrow.passed and "13.5 Hz" in narrow.detail
    (none,) = check_filter_attenuation(_tuning(rig, []), rig, spec)
    assert not none.passed and none.value == pytest.approx(0.0, abs=1e-9)
    assert "no output filter" in none.detail


def test_no_attenuation_limit_no_check(rig) -> None:
    assert check_filter_attenuation(_tuning(rig, []), rig, _spec()) == []


@pytest.mark.parametrize(
    ("margins", "scenario", "message"),
    [
        ({"min_filter_attenuation_db": 0.0}, None, "min_filter_attenuation_db"),
        ({"min_filter_attenuation_db": "10"}, None, "min_filter_attenuation_db"),
        ({}, {"kind": "lock", "max_residual_vibration_counts": 3.0}, "unknown key"),
        ({}, {"kind": "track", "max_residual_vibration_counts": -1.0}, ">= 0"),
    ],
)
def test_bad_filter_and_vibration_limits_are_one_line(margins, scenario, message) -> None:
    sc = scenario or {"kind": "lock", "max_holding_band_counts": 6.0}
    with pytest.raises(SpecError, match=message):
        spec_from_dict({"margins": margins, "scenario": {"s": sc}})


def test_the_vibration_limit_round_trips_and_leaves_other_specs_as_they_were() -> None:
    s = spec_from_dict({"scenario": {"track": {"max_residual_vibration_counts": 20.0}}})
    assert s.scenario("track").limits == {"max_residual_vibration_counts": 20.0}
    plain = spec_from_dict({"scenario": {"track": {"max_overshoot_pct": 8.0}}})
    assert "max_residual_vibration_counts" not in str(plain.to_dict())
    assert "min_filter_attenuation_db" not in str(plain.to_dict())
