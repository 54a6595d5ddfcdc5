"""Margins of every loop a tuning can run, checked independently.

The oracle never calls servotune's loop builder or margin function: each loop is rebuilt here
from the tuning file's JSON constants (``q·2^-f``) and the rig's plant numbers, the plant
discretised by python-control's own ``c2d`` (ZOH) with the sub-tick input lag as a 6th-order
Padé approximant (servotune uses the exact modified z-transform), and the margins taken with
python-control's default ``stability_margins`` method on the transfer function (servotune uses
an interpolated frequency response), Ms and Mt on a separate linear grid.
"""

from __future__ import annotations

import hashlib
import json
import math
import warnings
from pathlib import Path

import control
import numpy as np
import pytest

import servotune as st
from servotune.analysis.margins import MarginLimits, tuning_margins
from servotune.cli import main
from servotune.laws.fuzzy_pid import FuzzyPIDGains
from servotune.laws.pi import PIGains
from servotune.pipeline import default_pi_gains
from servotune.sim.engine import Loop
from servotune.tune.workflow import rule_tables
from servotune.tuning import Tuning, write_tuning

ROOT = Path(__file__).resolve().parents[2]
RIG = ROOT / "plants" / "pc-dual-servo.toml"


def _tuning(rig: st.Rig, slave_scale: float = 1.0, master_kp_scale: float = 1.0) -> Tuning:
    """The example rig's loop-shaping PI on the master; a composite law on the slave whose
    tables (default rule base) change Kp by ±60 %, Ki by ±50 %, Kd by ±80 %."""
    g_m, g_s = default_pi_gains(rig)
    tabs = rule_tables("default")
    kd0 = 0.05 * g_s.kp * rig.period_s  # Kd/T = 5 % of Kp at the base
    slave = FuzzyPIDGains(
        kp0=g_s.kp * slave_scale,
        ki0=g_s.ki * slave_scale,
        kd0=kd0 * slave_scale,
        k10=0.0,
        ke=0.01,
        kec=0.2,
        n=6,
        dkp=0.6 * g_s.kp * slave_scale * tabs["kp"],
        dki=0.5 * g_s.ki * slave_scale * tabs["ki"],
        dkd=0.8 * kd0 * slave_scale * tabs["kd"],
    )
    master = PIGains(kp=g_m.kp * master_kp_scale, ki=g_m.ki)
    loop = Loop.from_rig(rig, [master, slave])
    sha = hashlib.sha256(RIG.read_bytes()).hexdigest()
    return Tuning.for_rig(rig, loop.controllers, rig_sha256=sha, rig_path=RIG)


def _value(fx: dict) -> float:
    return fx["q"] * 2.0 ** -fx["f"]


def _cell_gains(task: dict, e: int, ec: int) -> tuple[float, float, float]:
    """Scheduled (Kp, Ki·T, Kd/T) at cell (E, EC), from the file's integers
    (docs/runtime.md#fuzzy-levels-and-scheduled-gains)."""
    n = task["n"]
    out = []
    for base, tab in (("kp", "kp"), ("ki_t", "ki"), ("kd_t", "kd")):
        b, t = task[base], task["tables"][tab]
        q = b["q"] + t["q"][e + n][ec + n] * 2 ** (b["f"] - t["f"])
        out.append(q * 2.0 ** -b["f"])
    return out[0], out[1], out[2]


def _oracle(plant: st.Plant, rig: st.Rig, kp: float, ki_t: float, kd_t: float) -> dict:
    t = rig.period_s
    lag = rig.timer.compute_s + plant.delay_s
    g = control.tf([plant.gain_cps_per_v], [plant.tau_s, 1.0, 0.0])
    num, den = control.pade(lag, 6)
    p = control.c2d(g * control.tf(num, den), t, method="zoh") * rig.dac.lsb_v
    z = control.tf([1.0, 0.0], [1.0], t)
    c = kp + ki_t * z / (z - 1) + kd_t * (z - 1) / z
    loop = control.minreal(c * p, verbose=False)
    with warnings.catch_warnings():  # python-control may fall back to its FRD method
        warnings.simplefilter("ignore", UserWarning)
        gm, pm, _, _, _, _ = control.stability_margins(loop)
    w = np.linspace(1e-3, math.pi / t * (1 - 1e-9), 20001)
    lw = loop(np.exp(1j * w * t))
    cl_poles = control.feedback(loop, 1).poles()
    return {
        "pm": pm,
        "gm_db": 20 * math.log10(gm) if np.isfinite(gm) else math.inf,
        "ms": float(np.max(np.abs(1 / (1 + lw)))),
        "mt": float(np.max(np.abs(lw / (1 + lw)))),
        "stable": bool(np.max(np.abs(cl_poles)) < 1),
    }


@pytest.fixture(scope="module")
def case(rig: st.Rig, tmp_path_factory) -> dict:
    d = tmp_path_factory.mktemp("margins")
    tuning = _tuning(rig)
    path = d / "tuning.json"
    write_tuning(tuning, path)
    return {"path": path, "tuning": tuning, "margins": tuning_margins(tuning, rig)}


def test_every_loop_is_there(case, rig) -> None:
    m = case["margins"]
    # per axis a lock loop; the master's PI; the slave's 13 × 13 cells (n = 6)
    assert [x.name for x in m.select("master")] == ["master lock", "master task"]
    cells = [x.cell for x in m.select("slave", "task")]
    assert len(cells) == 169 and set(cells) == {(e, c) for e in range(-6, 7) for c in range(-6, 7)}
    assert len(list(m.select("slave", "lock"))) == 1


def test_margins_agree_with_an_independent_python_control_loop(case, rig) -> None:
    doc = json.loads(case["path"].read_text())
    axes = {a["name"]: a["controller"] for a in doc["axes"]}
    m = case["margins"]
    checks = []
    master_task = axes["master"]["task"]
    checks.append(
        (
            next(m.select("master", "task")),
            rig.axis("master").plant,
            (_value(master_task["kp"]), _value(master_task["ki_t"]), 0.0),
        )
    )
    checks.append(
        (
            next(m.select("slave", "lock")),
            rig.axis("slave").plant,
            (_value(axes["slave"]["lock_gain"]), 0.0, 0.0),
        )
    )
    worst = m.worst("slave", "task")
    picks = {worst.cell, (0, 0), (6, 6), (-6, 3)}
    for x in m.select("slave", "task"):
        if x.cell in picks:
            checks.append((x, rig.axis("slave").plant, _cell_gains(axes["slave"]["task"], *x.cell)))
    assert len(checks) == 2 + len(picks)
    for got, plant, gains in checks:
        want = _oracle(plant, rig, *gains)
        assert got.stable == want["stable"], got.name
        # tolerances: the Padé lag and the grids differ from servotune's exact lag and grid
        assert got.phase_margin_deg == pytest.approx(want["pm"], abs=0.3), got.name
        assert got.gain_margin_db == pytest.approx(want["gm_db"], abs=0.1), got.name
        assert got.max_sensitivity == pytest.approx(want["ms"], rel=5e-3), got.name
        assert got.max_complementary_sensitivity == pytest.approx(want["mt"], rel=5e-3), got.name


def test_plant_response_is_python_controls_own_route(rig) -> None:
    """``plant_response`` takes the transfer function's coefficients from scipy directly: the
    bits of ``control.ss2tf`` without slycot (its fallback is that call), on every corner and
    sample of the example rig's plant set; with slycot installed python-control would take
    ``tb04ad`` (then the two agree to rounding)."""
    import importlib.util

    from servotune.analysis.margins import margin_grid
    from servotune.analysis.plant_cases import plant_cases, plant_response
    from servotune.modal import discretize

    cases = plant_cases(
        rig, gain_spread=0.2, tau_spread=0.3, extra_ticks=1, period_error_ppm=100, samples=8
    )
    exact = importlib.util.find_spec("slycot") is None
    n = 0
    for c in cases:
        for plant in c.plants:
            w = margin_grid(plant, c.period_s)
            lag = rig.timer.compute_s + plant.delay_s + c.extra_lag_s
            tf = control.ss2tf(discretize(plant, c.period_s, lag) * rig.dac.lsb_v)
            want = control.frequency_response(tf, w).complex.ravel()
            got = plant_response(plant, rig, c, w)
            if exact:
                np.testing.assert_array_equal(got, want)
            else:
                np.testing.assert_allclose(got, want, rtol=1e-9)
            n += 1
    assert n >= 2 * 16  # both axes, the corners and the samples


def test_the_worst_cell_is_the_one_with_the_largest_ms(case) -> None:
    m = case["margins"]
    cells = list(m.select("slave", "task"))
    assert m.worst("slave", "task").max_sensitivity == max(x.max_sensitivity for x in cells)
    # the cells really differ (the tables schedule the gains): a constant answer would pass
    assert min(x.max_sensitivity for x in cells) < 0.9 * max(x.max_sensitivity for x in cells)


def test_an_unstable_cell_is_named_unstable(rig, tmp_path) -> None:
    # slave gains × 20: past the worst cell's gain margin (about 23 dB at × 1)
    m = tuning_margins(_tuning(rig, slave_scale=20.0), rig)
    bad = [x for x in m.select("slave", "task") if not x.stable]
    assert bad and not m.passed
    worst, broken = m.failures()[0]
    assert not worst.stable and broken[0].startswith("unstable")
    # the oracle agrees that the cell is unstable
    doc = _tuning(rig, slave_scale=20.0).to_dict()
    task = next(a for a in doc["axes"] if a["name"] == "slave")["controller"]["task"]
    assert not _oracle(rig.axis("slave").plant, rig, *_cell_gains(task, *worst.cell))["stable"]


def test_limits_decide_the_verdict(case) -> None:
    m = case["margins"]
    lo_ms = max(x.max_sensitivity for x in m.loops)
    lo_pm = min(x.phase_margin_deg for x in m.loops)
    lo_gm = min(x.gain_margin_db for x in m.loops)
    loose = MarginLimits(
        min_phase_margin_deg=lo_pm - 0.1,
        min_gain_margin_db=lo_gm - 0.1,
        max_sensitivity=lo_ms + 0.01,
    )
    tight = MarginLimits(
        min_phase_margin_deg=lo_pm - 0.1,
        min_gain_margin_db=lo_gm - 0.1,
        max_sensitivity=lo_ms - 0.01,
    )
    assert tuning_margins(case["tuning"], st.load_rig(RIG), limits=loose).passed
    t = tuning_margins(case["tuning"], st.load_rig(RIG), limits=tight)
    failing = {(x.name, x.plant) for x, _ in t.failures()}
    assert not t.passed
    assert failing == {(x.name, x.plant) for x in m.loops if x.max_sensitivity > lo_ms - 0.01}
    assert t.failures()[0][0].max_sensitivity == lo_ms


def test_cli_names_the_worst_cell_and_exits_1(case, capsys) -> None:
    worst = case["margins"].worst("slave", "task")
    ms = f"{worst.max_sensitivity - 0.01:.4f}"  # this tuning meets the defaults: tighten Ms
    rc = main(["margins", str(case["path"]), "--rig", str(RIG), "--ms", ms])
    out = capsys.readouterr().out
    assert rc == 1
    assert f"at E={worst.cell[0]:+d} EC={worst.cell[1]:+d}" in out
    assert "margins: FAIL" in out and worst.name in out.splitlines()[-1]
    assert "feedforward (K1) acts on the reference only" in out


def test_cli_json_and_a_passing_verdict(case, capsys) -> None:
    m = case["margins"]
    ms = max(x.max_sensitivity for x in m.loops) + 0.1
    pm = min(x.phase_margin_deg for x in m.loops) - 1
    gm = min(x.gain_margin_db for x in m.loops) - 1
    rc = main(
        [
            "margins",
            str(case["path"]),
            "--rig",
            str(RIG),
            "--json",
            "--ms",
            str(ms),
            "--pm",
            str(pm),
            "--gm",
            str(gm),
        ]
    )
    doc = json.loads(capsys.readouterr().out)
    assert rc == 0 and doc["passed"] is True and doc["failures"] == []
    assert len(doc["loops"]) == 172 and doc["worst"]["slave"] == m.worst("slave").name
    one = doc["loops"][1]
    assert one["loop"] == "task" and one["axis"] == "master"
    assert one["delay_margin_ticks"] == pytest.approx(one["delay_margin_s"] / one["period_s"])


def test_cli_bad_limit_is_one_line_exit_3(case, capsys) -> None:
    rc = main(["margins", str(case["path"]), "--rig", str(RIG), "--ms", "0.5"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 3 and len(err) == 1 and "max_sensitivity" in err[0]


def test_cell_grid_lays_the_cells_out_row_e_column_ec(case) -> None:
    m = case["margins"]
    grid = m.cell_grid("slave", "max_sensitivity")
    assert grid.shape == (13, 13) and not np.isnan(grid).any()
    for x in m.select("slave", "task"):
        assert grid[x.cell[0] + 6, x.cell[1] + 6] == x.max_sensitivity
    with pytest.raises(ValueError, match="no scheduled task loop"):
        m.cell_grid("master", "max_sensitivity")
