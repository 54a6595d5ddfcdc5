"""The fieldbus gantry (servotune.arch.gantry): topologies, compensator, monitor, beam."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import control
import numpy as np
import pytest

from servotune.arch.gantry import (
    TOPOLOGIES,
    GantryMetrics,
    SyncLoopModels,
    compare_topologies,
    move_profile,
    predicted_load_reduction,
    simulate_gantry,
    sync_loop_models,
)
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.synthesis import resolve_gains, tune_sync
from servotune.cli import main
from servotune.errors import ConfigError, SpecError
from servotune.hw import dac as hw_dac
from servotune.laws.axis import FLAG_SYNC_TRIP
from servotune.report.text import format_comparison
from servotune.tune.pi import tune_pi

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "plants" / "gantry.toml"


@pytest.fixture(scope="module")
def gantry():
    return resolve_gains(load_gantry(CONFIG))


@pytest.fixture(scope="module")
def comparison(gantry):
    return compare_topologies(gantry, seed=0)


# --- must show -----------------------------------------------------------------------------


def test_listening_compensator_cuts_the_load_step_sync_error_as_the_loop_gains_predict(
    gantry, comparison
) -> None:
    par = comparison.row("parallel", "load").max_sync_error_counts
    lis = comparison.row("listening", "load").max_sync_error_counts
    pred = predicted_load_reduction(gantry)
    # the prediction: the parallel error is the slave drive's closed-loop load response, and
    # the listening compensator scales it by the sync loop's sensitivity 1/(1 + C·z^-L·T_s)
    assert lis < par
    assert pred.ratio < 0.8
    # live (integer law, quantised D/A and encoder, friction, noise, jitter) vs linear model
    assert par == pytest.approx(pred.parallel_max_counts, rel=0.05)
    assert lis == pytest.approx(pred.listening_max_counts, rel=0.08)
    assert lis / par == pytest.approx(pred.ratio, abs=0.05)


def test_prediction_tracks_a_weaker_compensator(gantry) -> None:
    # halve the compensator: the predicted ratio moves, and the live one moves with it
    s = gantry.sync
    weak = dataclasses.replace(gantry, sync=dataclasses.replace(s, kp=s.kp / 2, ki=s.ki / 2))
    pred = predicted_load_reduction(weak)
    assert pred.ratio > predicted_load_reduction(gantry).ratio + 0.05
    par = simulate_gantry(weak, "parallel", case="load").metrics().max_sync_error_counts
    lis = simulate_gantry(weak, "listening", case="load").metrics().max_sync_error_counts
    assert lis / par == pytest.approx(pred.ratio, abs=0.05)


@pytest.mark.parametrize("latency", [1, 3])
@pytest.mark.parametrize("topology", ["parallel", "listening"])
def test_a_trip_stops_both_axes_within_the_stated_cycles(gantry, latency, topology) -> None:
    cfg = dataclasses.replace(
        gantry,
        bus=dataclasses.replace(gantry.bus, latency_cycles=latency),
        sync=dataclasses.replace(gantry.sync, warn_counts=40, trip_counts=80),
    )
    tr = simulate_gantry(cfg, topology, case="load")
    e = np.abs(tr.sync_error)
    k0 = int(np.argmax(e >= 80))  # first measured crossing
    assert e[k0] >= 80 and tr.trip_cycle == k0 + latency
    bound = cfg.stop_bound_cycles
    assert bound == latency + 1
    zero = hw_dac.zero_code(cfg.rig.dac.bits, cfg.rig.dac.range_v)
    stopped = k0 + bound
    assert np.all(tr.code[stopped:] == zero)
    assert np.all(tr.flags[stopped:] & FLAG_SYNC_TRIP)
    # not earlier than the monitor could know, and the master at least a cycle after detection
    assert not np.any(tr.flags[: tr.trip_cycle] & FLAG_SYNC_TRIP)
    assert tr.code[tr.trip_cycle, 0] != zero
    # the warning level came first
    assert np.any(tr.sync_level[: tr.trip_cycle] == 1)


def test_comparison_table_covers_every_topology_and_case(gantry, comparison) -> None:
    assert {(r.topology, r.case) for r in comparison.rows} == {
        (t, c) for t in TOPOLOGIES for c in ("load", "mismatch")
    }
    # mismatched plants: the listening compensator also cuts the error parallel leaves
    assert (
        comparison.row("listening", "mismatch").rms_sync_error_counts
        < 0.6 * comparison.row("parallel", "mismatch").rms_sync_error_counts
    )
    # following the master's feedback adds the slave's own lag: worse than parallel here
    assert (
        comparison.row("following", "mismatch").max_sync_error_counts
        > comparison.row("parallel", "mismatch").max_sync_error_counts
    )
    assert comparison.passed  # the deployed (listening) topology does not trip
    text = format_comparison(comparison)
    assert all(t in text for t in TOPOLOGIES) and text.endswith("PASS")


def test_results_are_named_objects_and_sync_json_keeps_its_keys(gantry, comparison) -> None:
    # named results (GantryMetrics, LoadPrediction, SyncLoopModels), the JSON's
    # rows and prediction keyed as before; schema servotune.sync/2 added the margins
    doc = json.loads(json.dumps(comparison.to_dict(), sort_keys=True))
    assert set(doc) == {
        "schema",
        "name",
        "topology",
        "cycle_s",
        "latency_cycles",
        "stop_bound_cycles",
        "drives",
        "sync",
        "sync_constants",
        "results",
        "predicted_load",
        "passed",
        "failed",
        "version",
        "margins",
        "montecarlo",
    }
    row_keys = {
        "case",
        "topology",
        "max_sync_error_counts",
        "rms_sync_error_counts",
        "warning_cycles",
        "tripped",
        "trip_time_s",
    }
    assert all(set(r) == row_keys for r in doc["results"])
    assert [r.to_dict() for r in comparison.rows] == doc["results"]
    assert set(doc["predicted_load"]) == {"parallel_max_counts", "listening_max_counts", "ratio"}
    m = comparison.row("listening", "load")
    assert isinstance(m, GantryMetrics) and (m.topology, m.case) == ("listening", "load")
    assert comparison.traces[comparison.rows.index(m)].metrics() == m
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.tripped = True  # type: ignore[misc]
    with pytest.raises(KeyError, match="no run of the topology 'ring'"):
        comparison.row("ring", "load")
    models = sync_loop_models(gantry)
    assert isinstance(models, SyncLoopModels)
    assert set(models.to_dict()) == {
        "t_master",
        "t_slave",
        "load_master",
        "load_slave",
        "compensator",
        "loop",
        "sensitivity",
    }
    assert all(sys.dt == gantry.bus.cycle_s for sys in models.to_dict().values())


def test_same_seed_same_result_other_seed_other_noise(gantry) -> None:
    a = simulate_gantry(gantry, "listening", case="mismatch", seed=3)
    b = simulate_gantry(gantry, "listening", case="mismatch", seed=3)
    c = simulate_gantry(gantry, "listening", case="mismatch", seed=4)
    assert np.array_equal(a.code, b.code) and np.array_equal(a.sync_comp, b.sync_comp)
    assert not np.array_equal(a.code, c.code)


# --- the pieces ----------------------------------------------------------------------------


def test_compensator_synthesis_meets_its_targets_on_the_sync_loop(gantry) -> None:
    # tune_sync's own contract, on the nominal loop (resolve_gains may then redesign it for
    # the plant set: tests/arch/gantry/test_margins.py)
    gantry = dataclasses.replace(gantry, sync=tune_sync(gantry))
    loop = sync_loop_models(gantry).loop
    w = np.geomspace(1e-2, math.pi / gantry.bus.cycle_s, 4000)
    resp = loop.frequency_response(w)
    gm, pm = control.stability_margins(resp)[:2]
    ms = np.max(1 / np.abs(1 + np.squeeze(resp.complex)))
    assert pm >= gantry.sync.phase_margin_deg - 0.5
    assert 20 * math.log10(gm) >= gantry.sync.gain_margin_db - 0.1
    assert ms <= gantry.sync.max_sensitivity * 1.01
    # and one target binds: tune_pi maximised Ki up to a limit
    assert (
        min(
            pm - gantry.sync.phase_margin_deg,
            20 * math.log10(gm) - gantry.sync.gain_margin_db,
            100 * (gantry.sync.max_sensitivity - ms),
        )
        < 1.0
    )
    assert np.all(np.abs(control.feedback(loop, 1).poles()) < 1)


def test_pd_synthesis_takes_the_largest_kp_meeting_the_targets(gantry) -> None:
    cfg = dataclasses.replace(
        gantry, sync=dataclasses.replace(gantry.sync, law="pd", kp=None, ki=None, kd=0.002)
    )
    s = tune_sync(cfg)
    assert s.law == "pd" and s.kd == 0.002 and s.ki == 0.0 and s.kp > 0

    def pm(kp: float) -> float:
        c = dataclasses.replace(cfg, sync=dataclasses.replace(s, kp=kp))
        loop = sync_loop_models(c).loop
        w = np.geomspace(1e-2, math.pi / c.bus.cycle_s, 4000)
        return control.stability_margins(loop.frequency_response(w))[1]

    assert pm(s.kp) >= cfg.sync.phase_margin_deg - 0.5
    assert pm(s.kp * 1.1) < cfg.sync.phase_margin_deg or s.kp * 1.1 > 1e6


def test_impossible_sync_targets_are_refused(gantry) -> None:
    # a derivative gain that alone destabilises the sync loop: no kp can meet the targets
    # (1 s with the robust drive gains; 0.5 s was enough against the faster nominal design)
    cfg = dataclasses.replace(
        gantry, sync=dataclasses.replace(gantry.sync, law="pd", kp=None, ki=None, kd=1.0)
    )
    with pytest.raises(SpecError, match=r"no PD sync compensator with kd=1 s"):
        tune_sync(cfg)
    with pytest.raises(ValueError, match=r"phase_margin_deg must be a number in \(0, 90\)"):
        dataclasses.replace(gantry.sync, phase_margin_deg=90.0)


def test_tune_pi_takes_a_discrete_plant_with_whole_cycles_of_lag() -> None:
    plant = control.ss(control.tf([0.2], [1.0, -0.8], 0.001))
    r = tune_pi(plant, period_s=0.001, compute_s=0.002, phase_margin_deg=60)
    loop = (
        control.tf([r.kp + r.ki * 0.001, -r.kp], [1, -1], 0.001)
        * plant
        * control.tf([1], [1, 0, 0], 0.001)
    )
    w = np.geomspace(1e-2, math.pi / 0.001, 4000)
    assert control.stability_margins(loop.frequency_response(w))[1] == pytest.approx(60, abs=0.5)
    with pytest.raises(ValueError, match="whole periods"):
        tune_pi(plant, period_s=0.001, compute_s=0.0015, phase_margin_deg=60)
    with pytest.raises(ValueError, match="dt = period_s"):
        tune_pi(plant, period_s=0.002, phase_margin_deg=60)


def test_move_profile_is_a_trapezoid_with_the_configured_limits(gantry) -> None:
    mv = gantry.move
    dt = gantry.bus.cycle_s
    cmd = move_profile(mv, dt, 5000)
    assert cmd[0] == 0 and cmd[-1] == mv.distance_counts
    v = np.diff(cmd) / dt
    assert v.max() == pytest.approx(mv.speed_cps, rel=0.001)
    # second difference: the acceleration step plus at most 2 counts of rounding
    assert np.abs(np.diff(cmd, 2)).max() <= mv.accel_cps2 * dt**2 + 2
    short = dataclasses.replace(mv, distance_counts=-1000)  # triangular, reversed
    c2 = move_profile(short, dt, 2000)
    assert c2[-1] == -1000 and np.diff(c2).min() / dt > -mv.speed_cps


def test_coupled_beam_moves_as_the_exact_linear_model(gantry) -> None:
    # drives off (zero gains: 0 V out), no friction, noise or jitter; the two sides' offsets
    # drive them apart, against the beam's spring and damper
    def quiet(ax, gain, tau, off):
        p = dataclasses.replace(
            ax.plant, gain_cps_per_v=gain, tau_s=tau, offset_v=off, coulomb_v=0.0, noise_counts=0.0
        )
        return dataclasses.replace(ax, plant=p, kp=0.0, ki=0.0, following_error_limit_counts=0)

    k_b, c_b = 2e-3, 2e-5
    cfg = dataclasses.replace(
        gantry,
        seconds=0.5,
        master=quiet(gantry.master, 12000.0, 0.025, 0.5),
        slave=quiet(gantry.slave, 11000.0, 0.03, -0.2),
        bus=dataclasses.replace(gantry.bus, jitter_s=0.0),
        beam=dataclasses.replace(gantry.beam, stiffness_v_per_count=k_b, damping_v_s_per_count=c_b),
        sync=dataclasses.replace(gantry.sync, warn_counts=0, trip_counts=0),
    )
    tr = simulate_gantry(cfg, "parallel", case="mismatch")
    # exact: x = (p_m, v_m, p_s, v_s), v' = (g·(w ∓ k·Δp ∓ c·Δv) − v)/τ, ZOH-discretised
    (gm, tm), (gs, ts) = (12000.0, 0.025), (11000.0, 0.03)
    a = np.array(
        [
            [0, 1, 0, 0],
            [-gm * k_b / tm, -(1 + gm * c_b) / tm, gm * k_b / tm, gm * c_b / tm],
            [0, 0, 0, 1],
            [gs * k_b / ts, gs * c_b / ts, -gs * k_b / ts, -(1 + gs * c_b) / ts],
        ]
    )
    b = np.array([[0, 0], [gm / tm, 0], [0, 0], [0, gs / ts]])
    sys = control.c2d(control.ss(a, b, np.eye(4)[[0, 2]], 0), cfg.bus.cycle_s)
    u = np.tile([0.5, -0.2], (cfg.n_cycles, 1)).T
    ref = control.forced_response(sys, U=u).outputs.T
    assert tr.position.shape == ref.shape
    span = np.abs(ref).max()
    assert np.abs(tr.position - ref).max() < 1e-3 * span


# --- config and CLI ------------------------------------------------------------------------


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "g.toml"
    p.write_text(
        text.replace(
            'rig = "pc-dual-servo.toml"', f'rig = "{ROOT / "plants" / "pc-dual-servo.toml"}"'
        )
    )
    return p


@pytest.mark.parametrize(
    "old, new, msg",
    [
        ("cycle_s = 0.001", "cycle_s = -0.001", r"bus.cycle_s must be a number in \[1e-06, 0.01\]"),
        (
            "cycle_s = 0.001",
            "cycle_s = 10",
            r"bus.cycle_s must be a number in \[1e-06, 0.01\] \[s\]",
        ),
        ("cycle_s = 0.001", 'cycle_s = "1ms"', r"bus.cycle_s must be a number .* got '1ms'"),
        (
            "latency_cycles = 1",
            "latency_cycles = 0",
            "latency_cycles must be an integer in 1..1000",
        ),
        (
            "latency_cycles = 1",
            "latency_cycles = 1e9",
            r"latency_cycles must be an integer in 1\.\.1000 \[cycles\], got 1000000000.0",
        ),
        (
            "latency_cycles = 1",
            "latency_cycles = 1000000000",
            r"latency_cycles must be an integer in 1\.\.1000",
        ),
        (
            "latency_cycles = 1",
            "latency_cycles = true",
            r"latency_cycles must be an integer .* got True",
        ),
        ("seconds = 2.0", "seconds = 1e300", r"gantry.seconds must be a number in \(0, 3600\]"),
        ("distance_counts = 150000", "distance_counts = 1" + "0" * 400, "an integer of 401 digits"),
        (
            "offset_v = 0.005",
            "offset_v = 1000.0",
            r"axis.master.plant.offset_v must be a number in \[-10, 10\]",
        ),
        ("speed_cps = 60000.0", "speed_cps = inf", "speed_cps must be a number"),
        ("[load]", "[load]\nextra = 1", "unknown key load.extra"),
        ('law = "pi"', 'law = "pid"', "law must be one of pi, pd"),
        ("tau_s = 0.025", "tau_z = 0.025", "unknown key axis.master.plant.tau_z"),
        ('topology = "listening"', 'topology = "ring"', "topology must be one of"),
        ("warn_counts = 300", "warn_counts = 3000", "warn_counts must be < trip_counts"),
        ('rig = "pc-dual-servo.toml"', 'rig = "nope.toml"', "gantry.rig: cannot read rig file"),
        ('rig = "pc-dual-servo.toml"', "rig = 5", "gantry.rig must be the path of a rig file"),
    ],
)
def test_bad_config_is_one_clear_error(tmp_path, old, new, msg) -> None:
    text = CONFIG.read_text()
    assert old in text
    with pytest.raises(ConfigError, match=msg):
        load_gantry(_write(tmp_path, text.replace(old, new)))


def test_cli_sync_json_plots_and_exit_codes(gantry, tmp_path, capsys) -> None:
    assert main(["sync", str(CONFIG), "--json", "--plot", str(tmp_path / "plots")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["schema"] == "servotune.sync/2" and out["passed"] is True
    assert len(out["results"]) == 2 * len(TOPOLOGIES)
    assert (tmp_path / "plots" / "sync_load.png").stat().st_size > 1000
    # a trip of the deployed topology is a failed check: exit 1 and the reason
    text = (
        CONFIG.read_text()
        .replace("warn_counts = 300", "warn_counts = 20")
        .replace("trip_counts = 1500", "trip_counts = 40")
    )
    assert main(["sync", str(_write(tmp_path, text))]) == 1
    err = capsys.readouterr().err
    assert "check failed: sync trip" in err
    # malformed: exit 3, one line, no traceback
    bad = tmp_path / "bad.toml"
    bad.write_text("[gantry\n")
    assert main(["sync", str(bad)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not valid TOML" in err and "Traceback" not in err


def test_resolve_keeps_given_gains(gantry) -> None:
    cfg = dataclasses.replace(gantry, master=dataclasses.replace(gantry.master, kp=0.3, ki=1.0))
    out = resolve_gains(cfg)
    assert (out.master.kp, out.master.ki) == (0.3, 1.0)
    assert out.sync == cfg.sync  # already resolved: not re-tuned


def test_the_gantry_package_and_its_tuning_import_in_either_order() -> None:
    # arch.gantry.synthesis imports the gantry's config and models; arch.gantry.load imports it:
    # no cycle, whichever a fresh interpreter imports first
    import subprocess
    import sys

    names = ("servotune.arch.gantry.synthesis", "servotune.arch.gantry.load")
    for first in (*names, "servotune.arch.gantry"):
        code = f"import {first}; import servotune.arch.gantry.synthesis, servotune.arch.gantry.load"
        res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        assert res.returncode == 0, (first, res.stderr[-500:])
