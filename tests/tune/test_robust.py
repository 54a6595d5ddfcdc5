"""Robust designs: the lock gains and PIs keep the margin limits over the
plant set; the tuner refuses what it cannot make robust; its screen agrees with python-control.

The verdicts here are python-control's (:func:`servotune.analysis.margins.loop_margins` on loops
built from the designed gains), never the screen the designs were made with.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

import servotune as st
from servotune.analysis.margins import (
    DEFAULT_LIMITS,
    GainSet,
    LoopFigures,
    MarginLimits,
    loop_margins,
    loop_model,
    margin_grid,
)
from servotune.analysis.plant_cases import plant_cases
from servotune.cli import main
from servotune.errors import InfeasibleError, SpecError
from servotune.report.text import format_tuning_summary
from servotune.tune.robust import MarginScreen, design_limits, robust_lock_gain, robust_pi
from servotune.tune.slave import tune_spec_from
from servotune.verify.spec import load_spec

RIG = Path(__file__).resolve().parents[2] / "plants" / "pc-dual-servo.toml"
SPEC = RIG.with_suffix(".spec.toml")


@pytest.fixture(scope="module")
def cases(rig: st.Rig):
    return plant_cases(rig, gain_spread=0.2, tau_spread=0.3, extra_ticks=1)


def _verdict(rig, case, axis: int, g: GainSet) -> LoopFigures:
    plant = case.plants[axis]
    lag = rig.timer.compute_s + plant.delay_s + case.extra_lag_s
    model = loop_model(plant, g, period_s=case.period_s, lag_s=lag, lsb_volts=rig.dac.lsb_v)
    return loop_margins(model, margin_grid(plant, case.period_s))


def test_plant_cases_cover_corners_and_latency(rig, cases) -> None:
    labels = [c.label for c in cases]
    assert labels[0] == "nominal" and len(cases) == 10  # 5 plant sets × (on time, one tick late)
    late = [c for c in cases if c.extra_lag_s > 0]
    assert len(late) == 5 and all(c.extra_lag_s == rig.period_s for c in late)
    gains = sorted({c.plants[1].gain_cps_per_v for c in cases})
    assert gains == pytest.approx([11700 * 0.8, 11700.0, 11700 * 1.2])  # rig file: 11,700


def test_sampled_plant_cases_lie_inside_the_box_and_follow_the_seed(rig) -> None:
    kw = {"gain_spread": 0.2, "tau_spread": 0.3, "extra_ticks": 1, "period_error_ppm": 100.0}
    corners = plant_cases(rig, **kw)
    cases = plant_cases(rig, **kw, samples=50, seed=3)
    assert cases[: len(corners)] == corners  # the corners first, unchanged
    drawn = cases[len(corners) :]
    assert [c.label for c in drawn] == [f"sample{i}" for i in range(50)]
    for c in drawn:
        for a, p in zip(rig.axes, c.plants, strict=True):
            assert 0.8 <= p.gain_cps_per_v / a.plant.gain_cps_per_v <= 1.2
            assert 0.7 <= p.tau_s / a.plant.tau_s <= 1.3
        assert 0.0 <= c.extra_lag_s <= rig.period_s
        assert abs(c.period_s / rig.period_s - 1.0) <= 100e-6
    # inside, not on the corners: the draws fill the box
    ratios = [c.plants[1].gain_cps_per_v / rig.axes[1].plant.gain_cps_per_v for c in drawn]
    assert min(ratios) < 0.9 and max(ratios) > 1.1 and len(set(ratios)) == 50
    assert plant_cases(rig, **kw, samples=50, seed=3) == cases
    assert plant_cases(rig, **kw, samples=50, seed=4)[-1] != cases[-1]


def test_robust_pi_keeps_the_limits_on_every_case(rig, cases) -> None:
    design = robust_pi(rig, "master", cases, DEFAULT_LIMITS)
    g = GainSet(design.gains.kp, design.gains.ki * rig.period_s)
    for case in cases:
        m = _verdict(rig, case, 0, g)
        assert m.stable and not DEFAULT_LIMITS.broken_figures(m), (case.label, m)
    # and it is not needlessly timid: some case sits at the phase-margin limit
    pms = [_verdict(rig, c, 0, g).phase_margin_deg for c in cases]
    assert min(pms) == pytest.approx(45.5, abs=0.5)  # the design aims 0.5° inside


def test_robust_lock_gain_lowers_the_seed_gain_only_as_needed(rig, cases) -> None:
    k = robust_lock_gain(rig, "slave", cases, DEFAULT_LIMITS)
    assert k < 0.4  # the seed's Kp = 0.4 breaks PM >= 45° at +20 % gain one tick late
    worst_pm = min(_verdict(rig, c, 1, GainSet(k)).phase_margin_deg for c in cases)
    assert worst_pm >= 45.0
    seed_pm = min(_verdict(rig, c, 1, GainSet(0.4)).phase_margin_deg for c in cases)
    assert seed_pm < 45.0  # the claim above, by python-control
    loose = MarginLimits(min_phase_margin_deg=30.0)
    assert robust_lock_gain(rig, "slave", cases, loose) == 0.4  # kept where it is robust


def test_the_screen_agrees_with_python_control(rig, cases) -> None:
    screen = MarginScreen(rig, 1, cases)
    rows = np.array([[0.2, 0.002, 0.0], [0.5, 0.01, 0.3], [1.0, 0.004, 1.0], [0.3, 0.0, 0.0]])
    pm, _, ms = screen(rows)
    for i, r in enumerate(rows):
        ms_pc = max(_verdict(rig, c, 1, GainSet(*r)).max_sensitivity for c in cases)
        pm_pc = min(_verdict(rig, c, 1, GainSet(*r)).phase_margin_deg for c in cases)
        assert ms[i] == pytest.approx(ms_pc, rel=0.02), r
        assert pm[i] == pytest.approx(pm_pc, abs=0.5), r


def _spec_with(tmp_path: Path, **margins: float) -> Path:
    """The example spec with its [margins] entries replaced."""
    text = SPEC.read_text()
    for key, value in margins.items():
        text, n = re.subn(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
        assert n == 1, key
    path = tmp_path / "spec.toml"
    path.write_text(text)
    return path


def test_an_impossible_spec_is_refused_with_the_binding_limit(tmp_path, monkeypatch, capsys):
    # the limit comes from the verification spec (`tune --spec`), as `verify` will judge it
    monkeypatch.setenv("SERVOTUNE_WORKBENCH", str(tmp_path / "wb"))
    out = tmp_path / "t.json"
    spec = _spec_with(tmp_path, min_phase_margin_deg=85.0)
    rc = main(
        [
            "tune",
            str(RIG),
            "-o",
            str(out),
            "--spec",
            str(spec),
            "--generations",
            "1",
            "--population",
            "5",
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and "Traceback" not in "\n".join(err)
    # PM 85° is reachable only with gains so low that a variant trips its following-error
    # limit: the message names what breaks
    assert err[-1].startswith("servotune tune: failed: no slave tuning met the constraints")
    assert "the closest breaks: a fault (following-error trip)" in err[-1]
    assert not out.exists() and not (tmp_path / "wb" / "tuning.json").exists()


def test_tune_spec_follows_the_verification_spec(tmp_path) -> None:
    spec = load_spec(
        _spec_with(tmp_path, min_phase_margin_deg=52.0, max_sensitivity=1.7, extra_ticks=2)
    )
    ts = tune_spec_from(spec, generations=3)
    assert (ts.min_phase_margin_deg, ts.max_sensitivity, ts.extra_ticks) == (52.0, 1.7, 2)
    assert ts.gain_spread == spec.montecarlo.gain_spread == 0.2  # the example spec's values
    assert ts.period_error_ppm == spec.max_period_error_ppm == 100.0
    run = spec.scenario("sync")  # tuned on; the others (track, lock, heldout) stay held out
    assert (ts.seconds, ts.speed_fraction, ts.load_step_v) == (
        run.seconds,
        run.speed_fraction,
        run.load_step_v,
    )
    assert ts.generations == 3
    assert tune_spec_from(spec, max_sensitivity=1.9).max_sensitivity == 1.9  # overrides win
    assert tune_spec_from().min_phase_margin_deg == DEFAULT_LIMITS.min_phase_margin_deg
    with pytest.raises(SpecError, match="unknown tuning option"):
        tune_spec_from(spec, pm=50.0)
    other = dataclasses.replace(st.load_rig(RIG), name="another-rig")
    with pytest.raises(SpecError, match="written for rig 'pc-dual-servo', not 'another-rig'"):
        tune_spec_from(spec, rig=other)


def test_tune_flags_win_over_the_spec(tmp_path, monkeypatch) -> None:
    # the CLI's plumbing only: what reaches the tuner (the tuner itself is tested above)
    seen = {}

    def capture(rig_path, *, spec, **_kw):
        seen["spec"] = spec
        raise InfeasibleError("captured")

    monkeypatch.setattr("servotune.tune.workflow.tune_rig", capture)
    spec = _spec_with(tmp_path, min_phase_margin_deg=52.0, max_sensitivity=1.7)
    assert (
        main(["tune", str(RIG), "--no-current", "--spec", str(spec), "--pm", "60", "--gm", "7"])
        == 1
    )
    ts = seen["spec"]
    assert (ts.min_phase_margin_deg, ts.min_gain_margin_db, ts.max_sensitivity) == (60, 7, 1.7)
    assert main(["tune", str(RIG), "--no-current", "--ms", "1.5"]) == 1
    assert (seen["spec"].max_sensitivity, seen["spec"].min_phase_margin_deg) == (1.5, 45.0)


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
    rc = main(
        ["tune", str(RIG), "-o", str(out), "--generations", "1", "--population", "6", "--json"]
    )
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
    w = summary["slave"]["worst"]  # the tuning run's figures over its plant variants
    assert 0 < w["rms_sync_counts"] <= w["max_sync_counts"], w
    assert summary["run"]["load_step_v"] == -0.3  # SlaveTuneSpec's default run
    assert main(["margins", str(out), "--rig", str(RIG)]) == 0


def test_the_tune_summary_prints_what_was_measured() -> None:
    worst = {
        "max_sync_counts": 1234.4,
        "rms_sync_counts": 456.0,
        "saturation_pct": 0.5,
        "overshoot_pct": 12.0,
        "fault": 0.0,
    }
    summary = {
        "axes": {},
        "run": {"speed_fraction": 0.5, "load_step_v": -0.3},
        "slave": {
            "objective": 99.0,
            "worst": worst,
            "binding": ["min_phase_margin_deg"],
            "at_bounds": [],
        },
    }
    text = format_tuning_summary(summary)
    assert "sync error max 1234 counts, RMS 456 counts" in text
    assert "no fault" in text and "sits on: min_phase_margin_deg" in text
    assert "search bounds" not in text
    worst.update(max_sync_counts=2001.0, fault=1.0)
    summary["slave"]["at_bounds"] = ["kp at its upper bound"]
    text = format_tuning_summary(summary)
    assert "sync error max 2001 counts" in text and "a fault" in text
    assert "search bounds reached (widen them): kp at its upper bound" in text


def test_design_limits_aim_inside_and_stay_valid() -> None:
    aim = design_limits(DEFAULT_LIMITS)
    assert aim.min_phase_margin_deg == 45.5 and aim.max_sensitivity == pytest.approx(1.97)
    # an Ms limit near 1 (a user's --ms 1.02): the aim moves at most halfway to 1, never below
    assert design_limits(MarginLimits(max_sensitivity=1.02)).max_sensitivity == pytest.approx(1.01)
