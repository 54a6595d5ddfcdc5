"""Robust designs (issue 18, point 4): the lock gains and PIs keep the margin limits over the
plant set; the tuner refuses what it cannot make robust; its screen agrees with python-control.

The verdicts here are python-control's (:func:`servotune.verify.margins.loop_margins` on loops
built from the designed gains), never the screen the designs were made with.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import servotune as st
from servotune.cli import main
from servotune.tune.robust import MarginScreen, robust_lock_gain, robust_pi
from servotune.verify.margins import (
    DEFAULT_LIMITS,
    GainSet,
    MarginLimits,
    _grid,
    loop_margins,
    loop_model,
    plant_cases,
)

RIG = Path(__file__).resolve().parents[2] / "plants" / "pc-dual-servo.toml"


@pytest.fixture(scope="module")
def cases(rig: st.Rig):
    return plant_cases(rig, gain_spread=0.2, tau_spread=0.3, extra_ticks=1)


def _verdict(rig, case, axis: int, g: GainSet) -> dict:
    plant = case.plants[axis]
    lag = rig.timer.compute_s + plant.delay_s + case.extra_lag_s
    model = loop_model(plant, g, period_s=case.period_s, lag_s=lag, lsb_volts=rig.dac.lsb_v)
    return loop_margins(model, _grid(plant, case.period_s))


def test_plant_cases_cover_corners_and_latency(rig, cases) -> None:
    labels = [c.label for c in cases]
    assert labels[0] == "nominal" and len(cases) == 10  # 5 plant sets × (on time, one tick late)
    late = [c for c in cases if c.extra_lag_s > 0]
    assert len(late) == 5 and all(c.extra_lag_s == rig.period_s for c in late)
    gains = sorted({c.plants[1].gain_cps_per_v for c in cases})
    assert gains == pytest.approx([11700 * 0.8, 11700.0, 11700 * 1.2])  # rig file: 11,700


def test_robust_pi_keeps_the_limits_on_every_case(rig, cases) -> None:
    design = robust_pi(rig, "master", cases, DEFAULT_LIMITS)
    g = GainSet(design.gains.kp, design.gains.ki * rig.period_s)
    for case in cases:
        m = _verdict(rig, case, 0, g)
        assert m["stable"] and not DEFAULT_LIMITS.broken_figures(m), (case.label, m)
    # and it is not needlessly timid: some case sits at the phase-margin limit
    pms = [_verdict(rig, c, 0, g)["phase_margin_deg"] for c in cases]
    assert min(pms) == pytest.approx(45.5, abs=0.5)  # the design aims 0.5° inside


def test_robust_lock_gain_lowers_the_seed_gain_only_as_needed(rig, cases) -> None:
    k = robust_lock_gain(rig, "slave", cases, DEFAULT_LIMITS)
    assert k < 0.4  # the seed's Kp = 0.4 breaks PM >= 45° at +20 % gain one tick late
    worst_pm = min(_verdict(rig, c, 1, GainSet(k))["phase_margin_deg"] for c in cases)
    assert worst_pm >= 45.0
    seed_pm = min(_verdict(rig, c, 1, GainSet(0.4))["phase_margin_deg"] for c in cases)
    assert seed_pm < 45.0  # the claim above, by python-control
    loose = MarginLimits(min_phase_margin_deg=30.0)
    assert robust_lock_gain(rig, "slave", cases, loose) == 0.4  # kept where it is robust


def test_the_screen_agrees_with_python_control(rig, cases) -> None:
    screen = MarginScreen(rig, 1, cases)
    rows = np.array([[0.2, 0.002, 0.0], [0.5, 0.01, 0.3], [1.0, 0.004, 1.0], [0.3, 0.0, 0.0]])
    pm, _, ms = screen(rows)
    for i, r in enumerate(rows):
        ms_pc = max(_verdict(rig, c, 1, GainSet(*r))["max_sensitivity"] for c in cases)
        pm_pc = min(_verdict(rig, c, 1, GainSet(*r))["phase_margin_deg"] for c in cases)
        assert ms[i] == pytest.approx(ms_pc, rel=0.02), r
        assert pm[i] == pytest.approx(pm_pc, abs=0.5), r


def test_an_impossible_margin_is_refused_with_the_binding_limit(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SERVOTUNE_WORKBENCH", str(tmp_path / "wb"))
    out = tmp_path / "t.json"
    rc = main(["tune", str(RIG), "-o", str(out), "--pm", "85", "--generations", "1",
               "--population", "5"])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and "Traceback" not in "\n".join(err)
    # PM 85° is reachable only with gains so low that a variant trips its following-error
    # limit: the message names what breaks
    assert err[-1].startswith("servotune tune: failed: no slave tuning met the constraints")
    assert "the closest breaks: a fault (following-error trip)" in err[-1]
    assert not out.exists() and not (tmp_path / "wb" / "tuning.json").exists()


def test_robust_pi_honours_other_limits(rig, cases) -> None:
    # (margins alone never make a PI infeasible: small enough gains keep any of them; what
    # cannot be met is the tracking, see the CLI test above)
    tight = MarginLimits(min_phase_margin_deg=60.0, min_gain_margin_db=10.0, max_sensitivity=1.5)
    design = robust_pi(rig, "master", cases, tight)
    g = GainSet(design.gains.kp, design.gains.ki * rig.period_s)
    for case in cases:
        assert not tight.broken_figures(_verdict(rig, case, 0, g)), case.label


def test_tune_never_writes_a_tuning_that_breaks_its_margins(tmp_path, monkeypatch, capsys):
    # a tiny budget: the tuner either finds a tuning that keeps every limit (then its margins,
    # by python-control over the plant set, pass) or refuses with exit 1, writing nothing
    monkeypatch.setenv("SERVOTUNE_WORKBENCH", str(tmp_path / "wb"))
    out = tmp_path / "t.json"
    rc = main(["tune", str(RIG), "-o", str(out), "--generations", "1", "--population", "6",
               "--json"])  # fmt: skip
    cap = capsys.readouterr()
    if rc == 1:
        assert not out.exists()
        return
    assert rc == 0
    summary = json.loads(cap.out)
    assert summary["schema"] == "servotune.tune-summary/1"
    for name in ("master", "slave"):
        w = summary["axes"][name]["worst_loop"]
        assert w["phase_margin_deg"] >= 45.0 and w["max_sensitivity"] <= 2.0, w
        assert summary["axes"][name]["gains"]["kp"] > 0
    assert main(["margins", str(out), "--rig", str(RIG)]) == 0
