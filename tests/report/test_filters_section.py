"""The report's output-filters section (servotune.report.filters): shown only for a tuning with
filters, its numbers held to independent ones (scipy's ``freqz`` of the quantised coefficients),
its sentence made from them (other numbers, another sentence), and the shaped move's residual
vibration below the unshaped one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.signal import freqz

from servotune.analysis.filter_effect import filter_effects
from servotune.analysis.margins import tuning_margins
from servotune.examples import example_path
from servotune.laws.filters import notch
from servotune.laws.pi import PIGains
from servotune.report.filters import filters_section, filters_statement
from servotune.rig import load_rig
from servotune.sim.engine import Loop
from servotune.tuning import Tuning


def _tuning(rig, with_filters: bool) -> Tuning:
    master = rig.axis("master")
    filtered = dataclasses.replace(
        rig,
        axes=(
            dataclasses.replace(master, filters=(notch(15.0, 4.5, -20.0),) if with_filters else ()),
            rig.axis("slave"),
        ),
    )
    # the gains tests/tune/test_filters_tuning.py's tuner gives the belt-scale master (rounded)
    ctls = Loop.from_rig(
        filtered, [PIGains(kp=0.195, ki=0.62), PIGains(kp=0.3, ki=1.0)]
    ).controllers
    return Tuning.for_rig(rig, ctls, rig_sha256="0" * 64)


@pytest.fixture(scope="module")
def rig():
    return load_rig(example_path("belt-scale.toml"))


@pytest.fixture(scope="module")
def section(rig):
    tuning = _tuning(rig, True)
    nominal = tuning_margins(tuning, rig).loops
    return tuning, filters_section(tuning, rig, nominal)


def test_absent_without_filters(rig) -> None:
    tuning = _tuning(rig, False)
    assert filters_section(tuning, rig, tuning_margins(tuning, rig).loops) == ("", None)


def test_the_attenuation_is_scipys(rig, section) -> None:
    tuning, (html, data) = section
    sec = tuning.controllers[0].filters[0]
    b = np.array([sec.b0, sec.b1, sec.b2]) / 2.0**sec.frac_bits
    a = np.array([2.0**sec.frac_bits, sec.a1, sec.a2]) / 2.0**sec.frac_bits
    _, h = freqz(b, a, worN=[15.0], fs=1.0 / rig.period_s)
    (mode,) = data["master"]["at_modes"]
    assert mode["gain_db"] == pytest.approx(20 * np.log10(abs(h[0])), abs=1e-9)
    assert f"{mode['gain_db']:+.1f} dB at the mode 15 Hz" in html


def test_the_statement_follows_the_numbers(rig, section) -> None:
    tuning, (_, data) = section
    fx = filter_effects(tuning, rig)[0]
    nominal = [m for m in tuning_margins(tuning, rig).loops if m.axis == "master"]
    task_w = next(m for m in nominal if m.loop == "task")
    task_wo = next(m for m in fx.without if m.loop == "task")
    said = filters_statement(fx, task_w, task_wo)
    assert said == data["master"]["statement"]
    assert f"Ms {task_w.max_sensitivity:.2f} with them" in said
    assert f"without them PM {task_wo.phase_margin_deg:.1f}°" in said
    swapped = filters_statement(
        dataclasses.replace(fx, at_modes=((15.0, -3.25, 0.0),)), task_wo, task_w
    )
    assert "-3.2 dB at the mode 15 Hz" in swapped or "-3.3 dB at the mode 15 Hz" in swapped
    assert f"Ms {task_wo.max_sensitivity:.2f} with them" in swapped and swapped != said


def test_the_shaped_move_leaves_less_vibration(section) -> None:
    _, (html, data) = section
    res = data["master"]["residual_vibration_counts"]
    assert res["shaped (ZVD)"] < 0.5 * res["unshaped"], res
    assert "residual vibration" in html and html.count("<figure>") == 2
