"""The multi-CPU linkage (servotune.arch.linkage; docs/systems.md): interpolation, checks, clocks,
contour.

Reference values are computed by hand from the example config plants/linkage-6axis.toml
(6 axes, 2 ms, SCI at 460,800 baud 8N1, blocks of 5, prefill 2, queues of 20) unless a comment
says otherwise.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import EXAMPLE_RIG, ROOT

from servotune.arch.linkage import (
    SCHEMA,
    Clock,
    LinkageCheckError,
    LinkageConfig,
    LinkageResult,
    axis_gains,
    bus_figures,
    interpolate,
    linkage_from_dict,
    load_linkage,
    recommended_resync_interval_s,
    run_linkage,
)
from servotune.cli import main
from servotune.errors import ConfigError
from servotune.tune.pi import tune_pi

EXAMPLE = ROOT / "plants" / "linkage-6axis.toml"
PLANTS = EXAMPLE.parent
_DATA = tomllib.loads(EXAMPLE.read_text(encoding="utf-8"))


def example_data() -> dict[str, Any]:
    """A fresh copy of the example's parsed TOML, to modify."""
    return copy.deepcopy(_DATA)


def config_from(data: dict[str, Any]) -> LinkageConfig:
    return linkage_from_dict(data, PLANTS)


@pytest.fixture(scope="module")
def config() -> LinkageConfig:
    return load_linkage(EXAMPLE)


@pytest.fixture(scope="module")
def result(config: LinkageConfig) -> LinkageResult:
    return run_linkage(config, seed=3)


# --- the example, bus figures ---------------------------------------------------------------


def test_example_bus_figures_and_resync(config: LinkageConfig) -> None:
    f = bus_figures(config)
    assert f.frame_bytes == 8 + 4 * 6 * 5  # overhead + 4 bytes × 6 axes × 5 setpoints
    assert f.frame_s == pytest.approx(128 * 10 / 460_800, rel=1e-12)  # 2.778 ms
    assert f.broadcast_period_s == pytest.approx(0.010, rel=1e-12)
    assert f.utilisation == pytest.approx(0.27778, rel=1e-4)
    assert f.lead_s == pytest.approx(2 * 0.010 - 128 * 10 / 460_800, rel=1e-12)
    assert f.nominal_min_level == 2 * 5 - 1  # floor(2.778 ms / 2 ms) = 1 pop during a frame
    assert f.required_queue_depth == (2 + 1) * 5
    # the result and linkage.json carry the same figures under the same keys
    assert sorted(f.to_dict()) == [
        "broadcast_period_s",
        "frame_bytes",
        "frame_s",
        "lead_s",
        "nominal_min_level",
        "required_queue_depth",
        "utilisation",
    ]
    # half a period of drift at the worst clock (80 ppm): 0.5 · 2 ms / 80e-6 = 12.5 s
    assert recommended_resync_interval_s(config) == pytest.approx(12.5, abs=1e-12)
    assert config.clock.resync_interval_s == recommended_resync_interval_s(config)
    assert [c.axes for c in config.cpus] == [("x", "z", "a"), ("y", "b", "c")]


def test_example_passes(result: LinkageResult) -> None:
    assert result.passed, [c.detail for c in result.failed_checks]
    assert len(result.axes) == 6 and len(result.cpus) == 2
    assert {c.name for c in result.checks} >= {"bus", "prefill", "underrun:s1", "overrun:s2"}
    assert result.worst_underrun_margin == 9  # = the nominal P·B − floor(frame/T)
    assert all(c.underruns == 0 and c.overruns == 0 and c.skipped == 0 for c in result.cpus)
    assert all(c.resyncs == 1 for c in result.cpus)  # at 12.5 s in a 15.0 s run
    assert result.arcs and result.arcs[0].plane == ("x", "y")


# --- interpolation ---------------------------------------------------------------------------


def _one_move(**move: Any) -> LinkageConfig:
    d = example_data()
    d["path"]["move"] = [move]
    return config_from(d)


def test_trapezoid_reaches_feed_and_respects_accel() -> None:
    cfg = _one_move(kind="line", to={"x": 200_000}, feed_cps=50_000)
    ip = interpolate(cfg)
    s = ip.positions[:, 0]
    v = np.diff(s) / cfg.period_s
    acc = np.diff(v) / cfg.period_s
    a_max = cfg.path.max_accel_cps2
    np.testing.assert_allclose(v.max(), 50_000, rtol=1e-9)  # the cruise reaches the feed
    assert np.all(np.abs(acc) <= a_max * (1 + 1e-9))
    assert np.abs(acc).max() == pytest.approx(a_max, rel=1e-6)  # ramps at the limit
    # duration 2·v/a + (L − v²/a)/v = 0.5 + 3.75 s = 4.25 s = 2125 ticks
    assert ip.n_ticks - 1 == 2125
    assert np.all(ip.commands[:, 1:] == 0)  # the other axes stay
    assert ip.commands[-1, 0] == 200_000
    # a short move is triangular: peak sqrt(a·L) = sqrt(2e5 · 5000) = 31,623 < the feed
    ip2 = interpolate(_one_move(kind="line", to={"x": 5000}, feed_cps=50_000))
    v2 = np.diff(ip2.positions[:, 0]) / cfg.period_s
    assert 0.95 * math.sqrt(a_max * 5000) < v2.max() <= math.sqrt(a_max * 5000)
    # the feed is clamped to max_feed_cps (60,000)
    ip3 = interpolate(_one_move(kind="line", to={"x": 400_000}, feed_cps=90_000))
    assert ip3.feeds_cps == (60_000,)
    assert np.diff(ip3.positions[:, 0]).max() / cfg.period_s == pytest.approx(60_000, rel=1e-9)


def test_arc_radius_exact_and_endpoints_exact(config: LinkageConfig) -> None:
    ip = interpolate(config)
    (arc,) = ip.arcs
    assert arc.radius_counts == 40_000 and arc.sweep_rad == pytest.approx(2 * math.pi)
    k0, k1 = ip.move_start_tick(arc.move), ip.move_ends[arc.move]
    xy = ip.positions[k0 : k1 + 1][:, [0, 1]]
    np.testing.assert_allclose(np.hypot(xy[:, 0], xy[:, 1]), 40_000, rtol=0, atol=1e-8)
    cmd = ip.commands[k0 : k1 + 1][:, [0, 1]]
    assert np.all(np.abs(np.hypot(cmd[:, 0], cmd[:, 1]) - 40_000) <= math.sqrt(0.5))  # rounding
    # the other axes move linearly along the circle (helix): z from 10000 to -10000
    z = ip.positions[k0 : k1 + 1, 2]
    frac = np.unwrap(np.arctan2(xy[:, 1], xy[:, 0])) / (2 * math.pi)
    np.testing.assert_allclose(z, 10_000 - 20_000 * frac, atol=1e-6)
    # every move ends exactly on its target
    names = config.axis_names
    for m, mv in enumerate(config.path.moves):
        for ax, target in mv.to.items():
            assert ip.commands[ip.move_ends[m], names.index(ax)] == target
    assert ip.commands[0].tolist() == [0] * 6 and ip.commands[-1].tolist() == [0] * 6
    assert ip.commands[ip.move_ends[2], 0] == 40_000 and ip.commands[ip.move_ends[2], 1] == 0


def test_arc_to_an_end_point_clockwise() -> None:
    d = example_data()
    d["path"]["move"] = [
        {"kind": "line", "to": {"x": 30_000}, "feed_cps": 30_000},
        {
            "kind": "arc",
            "plane": ["x", "y"],
            "centre": [0, 0],
            "to": {"x": 0, "y": -30_000},
            "direction": "cw",
            "feed_cps": 20_000,
        },
    ]
    ip = interpolate(config_from(d))
    (arc,) = ip.arcs
    assert arc.sweep_rad == pytest.approx(-math.pi / 2)  # a quarter, clockwise
    mid = (ip.move_start_tick(1) + ip.move_ends[1]) // 2
    ang = math.degrees(math.atan2(ip.positions[mid, 1], ip.positions[mid, 0]))
    assert -60 < ang < -30
    assert ip.commands[-1, :2].tolist() == [0, -30_000]
    d["path"]["move"][1]["to"] = {"x": 0, "y": -30_010}
    with pytest.raises(ConfigError, match=r"path\.move\[1\].*not on one circle"):
        interpolate(config_from(d))


# --- must-show (a): rejected before motion, with the reason ---------------------------------


def test_bus_too_slow_is_rejected_before_motion() -> None:
    d = example_data()
    d["bus"]["baud"] = 115_200
    with pytest.raises(LinkageCheckError) as exc:
        run_linkage(config_from(d))
    msg = str(exc.value)
    # 128 bytes × 10 bits / 115,200 baud = 11.11 ms > 10 ms; baud needed 1280 bits / 10 ms
    assert "bus overload" in msg
    assert "takes 11.11 ms but the broadcast period is 10.00 ms (utilisation 111 % > 100 %)" in msg
    assert "raise baud to >= 128000" in msg
    # one row of 6 × 4 bytes already takes 2.08 ms > 2 ms: no block size helps at this baud
    assert "block_size" not in msg
    assert [c.name for c in exc.value.checks] == ["bus"]
    assert isinstance(exc.value, ConfigError)


def test_queue_or_prefill_too_short_is_rejected_before_motion() -> None:
    d = example_data()
    d["cpu"][0]["queue_depth"] = 12
    with pytest.raises(
        LinkageCheckError,
        match=(
            r"queue too short on cpu s1: queue_depth 12 setpoints per axis, but the prefill "
            r"\(2 blocks × 5\) plus the block in flight need 15 — raise queue_depth to >= 15"
        ),
    ):
        run_linkage(config_from(d))
    d = example_data()
    d["bus"]["prefill_blocks"] = 0
    with pytest.raises(LinkageCheckError, match=r"prefill too short.*raise prefill_blocks to >= 1"):
        run_linkage(config_from(d))


def test_path_too_fast_for_a_drive_is_rejected() -> None:
    d = example_data()
    d["axis"]["x"]["plant"]["max_speed_rpm"] = 100  # 100/60 × 12288 = 20,480 counts/s
    with pytest.raises(LinkageCheckError) as exc:
        run_linkage(config_from(d))
    (check,) = exc.value.checks
    assert check.name == "speed:x"
    assert "the drive's limit (100 r/min × 12288 counts/rev) is 20,480 counts/s" in check.detail
    assert "lower the feed of move" in check.detail


# --- must-show (b): clock drift, underrun, resync ------------------------------------------


def _drifting(resync_s: float) -> LinkageConfig:
    """The example with cheap resonators (+3000 / −2000 ppm) and a one-block prefill."""
    d = example_data()
    d["cpu"][0]["clock_ppm"] = 3000.0
    d["cpu"][1]["clock_ppm"] = -2000.0
    d["bus"]["prefill_blocks"] = 1
    d["clock"]["resync_interval_s"] = resync_s
    return config_from(d)


def test_drift_without_resync_underruns_and_recommended_resync_prevents_it() -> None:
    cfg = _drifting(0.0)
    f = bus_figures(cfg)
    period, bp = cfg.period_s, f.broadcast_period_s
    lead = f.lead_s  # 10 ms − 2.778 ms = 7.22 ms
    t_under = lead / 3000e-6  # the fast slave's ticks come lead earlier after lead/ε ≈ 2.41 s
    slack = (20 - 10 + 1) * period + f.frame_s  # 24.78 ms (recommended_resync_interval_s)
    t_over = slack / 2000e-6  # the slow one has 24.78 ms of room: ≈ 12.39 s
    r = run_linkage(cfg, seconds=14.0)
    s1, s2 = r.cpus
    assert s1.underruns > 0 and not r.passed
    assert t_under <= s1.first_underrun_s <= t_under * (1 + 3000e-6) + bp + period
    assert s2.overruns > 0
    assert t_over - bp - period <= s2.first_overrun_s <= t_over + bp + period
    failed = {c.name: c.detail for c in r.failed_checks}
    assert "underrun on cpu s1" in failed["underrun:s1"]
    assert f"lead/ε = {t_under:.1f} s" in failed["underrun:s1"]
    assert "overrun on cpu s2" in failed["overrun:s2"]

    rec = recommended_resync_interval_s(cfg)
    assert rec == pytest.approx(166 * period)  # floor(0.5 · 2 ms / 3000e-6 / 2 ms) ticks
    ok = run_linkage(_drifting(rec), seconds=14.0)  # > 5× the underrun time
    assert ok.passed, [c.detail for c in ok.failed_checks]
    for c in ok.cpus:
        assert c.underruns == 0 and c.overruns == 0 and c.skipped == 0
        assert c.resyncs == math.floor(14.0 / rec)
    assert ok.worst_underrun_margin >= 1


def test_sync_semantics_skip_behind_wait_ahead() -> None:
    """With 2.5 ticks of drift per resync: the slow slave skips 2–3 commands at each sync,
    the fast one waits (skips nothing, executes no index twice)."""
    d = example_data()
    d["cpu"][0]["clock_ppm"] = 5000.0
    d["cpu"][1]["clock_ppm"] = -5000.0
    for c in d["cpu"]:
        c["queue_depth"] = 40
    d["clock"]["resync_interval_s"] = 1.0  # 500 ticks: drift 2.5 ticks per interval
    r = run_linkage(config_from(d), seconds=6.0)
    fast, slow = r.cpus
    assert fast.resyncs == slow.resyncs == 5
    assert fast.skipped == 0
    assert 2 * 5 <= slow.skipped <= 3 * 5
    # no index runs twice; the fast slave runs every index, the slow one jumps at the syncs
    assert np.all(np.diff(fast.tick_index) == 1) and fast.tick_index[0] == 0
    jumps = np.diff(slow.tick_index)
    assert np.all(jumps >= 1) and int(np.sum(jumps - 1)) == slow.skipped
    # a sync realigns the phase: right after it both slaves tick on the master's grid
    for r_s in (1.0, 2.0, 3.0, 4.0, 5.0):
        k_r = round(r_s / 0.002)
        j_slow = int(np.searchsorted(slow.tick_index, k_r))
        assert slow.tick_index[j_slow] == k_r and slow.tick_time_s[j_slow] == pytest.approx(r_s)
    assert fast.underruns == 0 and slow.underruns == 0 and fast.overruns == 0


# --- must-show (c): the circle and its contour error ----------------------------------------


def test_contour_error_matches_the_tracking_errors_on_the_circle(result: LinkageResult) -> None:
    ip = result.interpolation
    (arc,) = ip.arcs
    c0, c1 = arc.cruise_ticks
    k = np.arange(c0, c1 + 1)
    p = result.path_counts[k][:, :2]
    e = p - result.actual_counts[k][:, :2]  # programmed − actual, in the x/y plane
    r_hat = p / arc.radius_counts  # centre (0, 0)
    t_hat = np.stack([-r_hat[:, 1], r_hat[:, 0]], axis=1)  # ccw tangent
    e_n = np.sum(e * r_hat, axis=1)
    e_t = np.sum(e * t_hat, axis=1)
    predicted = np.abs(-e_n + e_t**2 / (2 * arc.radius_counts))
    contour = result.contour_counts[k]
    # tolerance: the polyline's chords sag (v·T)²/(8R) = 44²/320000 = 0.006 counts inside the
    # circle, and the third-order terms e_n·e_t²/(2R²) stay below 0.01 counts at these errors
    assert np.abs(e_t).max() < 1500 and np.abs(e_n).max() < 300
    np.testing.assert_allclose(contour, predicted, rtol=0, atol=0.05)
    # the circular test reads the same deviation
    res = result.arcs[0]
    dev = res.radial_dev_counts[res.cruise]
    np.testing.assert_allclose(np.abs(dev), contour, rtol=0, atol=0.05)
    assert res.circularity_counts == pytest.approx(dev.max() - dev.min())
    # contour never exceeds the tracking error in the move's axes, anywhere on the run
    rows = np.minimum(np.arange(result.time_s.size), ip.n_ticks - 1)  # the end is held
    mask = ip.move_axes[ip.move_of_tick[rows]]
    e_all = np.where(mask, result.path_counts - result.actual_counts, 0.0)
    assert np.all(result.contour_counts <= np.sqrt(np.sum(e_all**2, axis=1)) + 1e-9)
    # where y still lags after its ramp (tangential error ~900 counts) the contour is far
    # below |e|: a lag along the path is no contour error
    e_abs = np.hypot(e[:, 0], e[:, 1])
    assert np.any((e_abs > 500) & (contour < 0.2 * e_abs))


def test_counter_wrap_is_transparent(config: LinkageConfig) -> None:
    """Axis x's 24-bit counter starting 100 counts below the top wraps at once (the high-byte
    unwrap, docs/runtime.md#counter-overflow-high-byte-rule); the motion is the same bit for bit."""
    x = dataclasses.replace(config.axes[0], counter_init=(1 << 24) - 100)
    wrapped = dataclasses.replace(config, axes=(x, *config.axes[1:]))
    a = run_linkage(config, seconds=2.0, seed=1)
    b = run_linkage(wrapped, seconds=2.0, seed=1)
    np.testing.assert_array_equal(a.actual_counts, b.actual_counts)
    assert b.axes[0].fault is None


# --- determinism, faults, tuning, bad input -------------------------------------------------


def test_same_seed_same_result_other_seed_differs(config: LinkageConfig) -> None:
    a = run_linkage(config, seconds=3.0, seed=7)
    b = run_linkage(config, seconds=3.0, seed=7)
    c = run_linkage(config, seconds=3.0, seed=8)
    ja = json.dumps(a.to_dict(arrays=True), sort_keys=True)
    assert ja == json.dumps(b.to_dict(arrays=True), sort_keys=True)
    np.testing.assert_array_equal(a.actual_counts, b.actual_counts)
    assert not np.array_equal(a.actual_counts, c.actual_counts)  # the noise follows the seed
    d = a.to_dict()
    assert d["schema"] == SCHEMA and "tick_time_s" not in d["cpus"][0]
    assert a.traces is None and "traces" not in d  # per-tick traces only on request


@pytest.mark.parametrize("seed", [-1, 2**64, 1.5, "7"])
def test_seed_must_be_an_unsigned_64_bit_integer(config: LinkageConfig, seed: Any) -> None:
    # the noise stream's state is a splitmix64 word (servotune.sim.tick.draw_noise)
    with pytest.raises(ConfigError, match=r"seed must be an integer in 0\.\.18446744073709551615"):
        run_linkage(config, seconds=0.1, seed=seed)


def test_following_error_trip_fails_the_run() -> None:
    d = example_data()
    d["axis"]["x"]["following_error_limit_counts"] = 300  # the x ramps lag ~1500 counts
    r = run_linkage(config_from(d), seconds=2.0)
    assert not r.passed
    (check,) = r.failed_checks
    assert check.name == "fault:x" and "following-error trip on axis x" in check.detail
    assert r.axes[0].fault == "following_error" and 0 < r.axes[0].first_fault_s < 2.0


def test_gains_absent_are_tuned_with_tune_pi() -> None:
    d = example_data()
    del d["axis"]["x"]["kp"], d["axis"]["x"]["ki"]
    cfg = config_from(d)
    gains = axis_gains(cfg)
    g = gains["x"].gains
    assert gains["x"].tuned and not gains["y"].tuned
    assert gains["y"].to_dict() == {"ki": 1.051, "kp": 0.3168, "tuned": False}  # the file's
    ref = tune_pi(
        cfg.axes[0].plant,
        period_s=0.002,
        compute_s=0.0002,
        phase_margin_deg=50,
        gain_margin_db=8,
        max_sensitivity=1.6,
    )
    assert (g.kp, g.ki) == (ref.kp, ref.ki)
    # the example's stored gains are these, rounded to 4 significant digits
    assert _DATA["axis"]["x"]["kp"] == float(f"{ref.kp:.4g}")
    assert _DATA["axis"]["x"]["ki"] == float(f"{ref.ki:.4g}")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d["bus"].update(bauds=1), r"unknown key bus\.bauds"),
        (
            lambda d: d["bus"].update(baud=-1),
            r"bus\.baud must be a number in \(0, 1e\+09\] \[bits/s\], got -1",
        ),
        (
            lambda d: d["bus"].update(block_size=5.0),
            r"bus\.block_size must be an integer in 1\.\.10000 \[setpoints\], got 5\.0",
        ),
        (lambda d: d["bus"].update(baud=True), r"bus\.baud must be a number .*got True"),
        (lambda d: d["bus"].update(baud="fast"), r"bus\.baud must be a number .*got 'fast'"),
        (
            lambda d: d["bus"].update(prefill_blocks=10**400),
            r"bus\.prefill_blocks must be a number within ±2\*\*63 \(int64\), "
            r"got an integer of 401",
        ),
        (
            lambda d: d["path"]["move"][0]["to"].update(x=1e300),
            r"path\.move\[0\]\.to\.x must be a number in \[-1e\+12, 1e\+12\] \[counts\]",
        ),
        (
            lambda d: d["path"]["move"][1].update(dwell_s=1e12),
            r"path\.move\[1\]\.dwell_s must be a number in \(0, 3600\] \[s\], got 1000000000000\.0",
        ),
        (
            lambda d: d["path"]["move"][2].update(centre=[1e300, 0]),
            r"path\.move\[2\]\.centre must be \[first, second\]",
        ),
        (
            lambda d: d["axis"]["x"]["plant"].update(delay_s=1e300),
            r"axis\.x\.plant\.delay_s must be a number in \[0, 1\] \[s\]",
        ),
        (lambda d: d.update(settle_s=1e12), r"settle_s must be a number in \[0, 3600\]"),
        (lambda d: d.update(period_s=0), r"period_s must be a number in \[1e-06, 1\]"),
        (lambda d: d.update(rig=7), r"rig must be the path of a rig file \(TOML\), got 7"),
        (lambda d: d.update(bus=[]), r"\[bus\] must be a table"),
        (
            lambda d: d["cpu"][0].update(axes=["x", "z", "a", "y", "b"]),
            r"cpu\[0\]\.axes must name 2 to 4 axes",
        ),
        (lambda d: d["cpu"][1].update(axes=["y", "b"]), r"axis 'c' is on no CPU"),
        (lambda d: d["axis"]["x"]["plant"].update(tau_s=-0.01), r"axis\.x\.plant\.tau_s must be"),
        (lambda d: d["axis"]["y"].pop("ki"), r"axis\.y\.kp and ki must be given together"),
        (
            lambda d: d["cpu"][0].update(clock_ppm=20000),
            r"cpu\[0\]\.clock_ppm must be a number in \[-10000, 10000\] \[ppm\]",
        ),
        (lambda d: d["path"]["move"][0].update(kind="spline"), r"path\.move\[0\]\.kind must be"),
        (lambda d: d.update(rig="missing.toml"), r"rig: cannot read rig file"),
    ],
)
def test_bad_config_names_the_field(change: Any, message: str) -> None:
    d = example_data()
    change(d)
    with pytest.raises(ConfigError, match=message) as exc:
        config_from(d)
    assert not isinstance(exc.value, LinkageCheckError)


def test_recommended_resync_is_zero_for_exact_clocks(config: LinkageConfig) -> None:
    cpus = tuple(dataclasses.replace(c, clock_ppm=0.0) for c in config.cpus)
    exact = dataclasses.replace(config, cpus=cpus, clock=Clock())
    assert recommended_resync_interval_s(exact) == 0.0


# --- command line ----------------------------------------------------------------------------


def test_cli_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["linkage", str(EXAMPLE), "--json", "--seconds", "3"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["schema"] == "servotune.linkage/1" and out["passed"] is True
    assert out["bus"]["frame_bytes"] == 128 and out["resync_interval_s"] == 12.5


def _write_variant(tmp_path: Path, old: str, new: str) -> Path:
    text = EXAMPLE.read_text(encoding="utf-8")
    assert old in text
    text = text.replace(old, new).replace(
        'rig = "pc-dual-servo.toml"', f"rig = {json.dumps(str(EXAMPLE_RIG))}"
    )
    p = tmp_path / "variant.toml"
    p.write_text(text, encoding="utf-8")
    return p


def test_cli_failed_check_exits_1_with_the_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = _write_variant(tmp_path, "baud = 460800", "baud = 115200")
    assert main(["linkage", str(cfg)]) == 1
    cap = capsys.readouterr()
    assert cap.out == ""
    assert "servotune linkage: check failed: bus overload" in cap.err
    assert "utilisation 111 % > 100 %" in cap.err


def test_cli_bad_input_exits_3_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = _write_variant(tmp_path, "block_size = 5", "block_size = 0")
    assert main(["linkage", str(cfg)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"servotune linkage: error: linkage config {str(cfg)!r}: ")
    assert "bus.block_size must be an integer in 1..10000 [setpoints], got 0" in err
    bad = tmp_path / "bad.toml"
    bad.write_text("period_s = [", encoding="utf-8")
    assert main(["linkage", str(bad)]) == 3
    assert "is not valid TOML" in capsys.readouterr().err


def test_cli_plot_writes_pngs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "figs"
    assert main(["linkage", str(EXAMPLE), "--plot", str(out)]) == 0
    cap = capsys.readouterr()
    assert "PASSED" in cap.out and "circularity" in cap.out
    for name in ("linkage_queues.png", "linkage_circle.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_plant_with_modes_is_refused_by_the_linkage(config: LinkageConfig) -> None:
    # the linkage's stretched ticks run rigid plants only (docs/frf.md): a resonant axis is
    # refused by name rather than simulated without its mode
    import dataclasses

    from servotune.resonance import Mode

    ax = config.axes[2]
    resonant = dataclasses.replace(
        ax, plant=dataclasses.replace(ax.plant, modes=(Mode(freq_hz=20.0, damping=0.05, gain=0.3),))
    )
    axes = tuple(resonant if a is ax else a for a in config.axes)
    with pytest.raises(ConfigError, match=rf"axis '{ax.name}': the linkage simulates rigid plants"):
        run_linkage(dataclasses.replace(config, axes=axes), seconds=0.1)
