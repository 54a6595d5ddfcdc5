"""servotune.verify: specs, verification on the bit-true loop, checks, and the record."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import servotune as st
from servotune.errors import SpecError, TrustError
from servotune.fixed import E_MAX, INT64_MAX, Fixed
from servotune.laws.fuzzy_pid import FuzzyPIDGains
from servotune.laws.pi import PIConstants
from servotune.report.text import format_table
from servotune.rig import EXAMPLE_RIG_PATH, PlantFit, load_rig
from servotune.tuning import Tuning, file_sha256, read_tuning, write_tuning
from servotune.verify import (
    ScenarioSpec,
    SourceFile,
    Spec,
    check_overflow,
    check_record,
    check_speed,
    check_timer,
    load_spec,
    max_safe_gain_q,
    plant_variants,
    read_record,
    record_path,
    verification_record,
    verify,
    verify_files,
    write_record,
)

SPEC_PATH = EXAMPLE_RIG_PATH.with_name("pc-dual-servo.spec.toml")


@pytest.fixture(scope="module")
def rig():
    return load_rig(EXAMPLE_RIG_PATH)


@pytest.fixture(scope="module")
def spec() -> Spec:
    return load_spec(SPEC_PATH)


@pytest.fixture(scope="module")
def tuning_file(tmp_path_factory, default_tuning) -> Path:
    """A good tuning: default-budget ``tune_rig`` of the example rig (seed 0), on disk."""
    path = tmp_path_factory.mktemp("verify") / "tuning.json"
    write_tuning(default_tuning, path)
    return path


@pytest.fixture(scope="module")
def good(tuning_file) -> Tuning:
    return read_tuning(tuning_file)


@pytest.fixture(scope="module")
def good_result(good, rig, spec):
    return verify(good, rig, spec)


def small(spec: Spec, count: int = 4, **scenario_changes: float) -> Spec:
    """The shipped spec with fewer variants, its sync scenario only (changed as given)."""
    sync = dataclasses.replace(spec.scenario("sync"), **scenario_changes)
    mc = dataclasses.replace(spec.montecarlo, count=count)
    return dataclasses.replace(spec, scenarios=(sync,), montecarlo=mc)


def with_slave_task(tuning: Tuning, task) -> Tuning:
    i = tuning.axis_names.index("slave")
    ctls = list(tuning.controllers)
    ctls[i] = dataclasses.replace(ctls[i], task=task)
    return dataclasses.replace(tuning, controllers=tuple(ctls))


# --- the spec file -------------------------------------------------------------------------


def test_shipped_spec_loads(spec) -> None:
    assert spec.name == "pc-dual-servo" and spec.rig == "pc-dual-servo"
    assert [s.name for s in spec.scenarios] == ["sync", "track", "lock", "heldout"]
    sync = spec.scenario("sync")
    assert sync.kind == "sync" and sync.seconds == 2.4 and sync.load_step_v == -0.3
    assert set(sync.limits) == {
        "max_overshoot_pct",
        "max_settling_time_s",
        "max_sync_error_counts",
        "max_rms_sync_error_counts",
        "max_steady_lag_counts",
        "max_saturation_pct",
    }
    # docs/runtime.md#position-lock-and-its-holding-band: the lock holds each motor within ±1 pulse
    # = ±4 counts at x4
    assert spec.scenario("lock").limits == {"max_holding_band_counts": 4.0}
    assert spec.montecarlo.count >= 32 and spec.max_period_error_ppm == 100.0


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "bad.spec.toml"
    p.write_text(text, encoding="utf-8")
    return p


SYNC = "[scenario.sync]\nmax_sync_error_counts = 600.0\n"


@pytest.mark.parametrize(
    ("text", "named"),
    [
        ("[scenario.sync]\nmax_overshot_pct = 5.0\n", "scenario.sync.max_overshot_pct"),
        (SYNC + "[limits]\nx = 1\n", "limits"),
        (SYNC + "[montecarlo]\ncont = 3\n", "montecarlo.cont"),
        ("[scenario.sync]\nmax_sync_error_counts = -1.0\n", "scenario.sync.max_sync_error_counts"),
        ("[scenario.sync]\nmax_overshoot_pct = -0.5\n", "scenario.sync.max_overshoot_pct"),
        ("[scenario.sync]\nmax_saturation_pct = 120\n", "scenario.sync.max_saturation_pct"),
        (SYNC + "max_rms_sync_error_counts = 700.0\n", "scenario.sync.max_rms_sync_error_counts"),
        (SYNC + "max_steady_lag_counts = 601\n", "scenario.sync.max_steady_lag_counts"),
        (SYNC + "max_settling_time_s = 3.0\n", "scenario.sync.max_settling_time_s"),
        (SYNC + "speed_fraction = 1.5\n", "scenario.sync.speed_fraction"),
        ('[scenario.sync]\nmax_overshoot_pct = "5"\n', "scenario.sync.max_overshoot_pct"),
        ("[scenario.sync]\nseconds = 2.4\n", "scenario.sync"),  # no limit at all
        ("[scenario.lock]\nmax_sync_error_counts = 3\n", "scenario.lock.max_sync_error_counts"),
        ("[scenario.lock]\nmax_holding_band_counts = 4\nsettle_s = 12\n", "scenario.lock.settle_s"),
        ("[scenario.mine]\nmax_saturation_pct = 1\n", "scenario.mine"),  # no such kind
        ('[scenario.x]\nkind = "ramp"\nmax_saturation_pct = 1\n', "scenario.x.kind"),
        (SYNC + "[montecarlo]\ngain_spread = 1.5\n", "montecarlo.gain_spread"),
        (SYNC + "[montecarlo]\ncount = 2.5\n", "montecarlo.count"),
        (SYNC + "[montecarlo]\noffset_spread_v = -0.001\n", "montecarlo.offset_spread_v"),
        (SYNC + "[timer]\nmax_period_error_ppm = -3\n", "timer.max_period_error_ppm"),
        ('[spec]\nname = "x"\n', "scenario"),  # no scenario
    ],
)
def test_bad_spec_names_the_key(tmp_path, text, named) -> None:
    with pytest.raises(SpecError) as info:
        load_spec(_write(tmp_path, text))
    msg = str(info.value)
    assert named in msg and "\n" not in msg


def test_bad_spec_values_carry_units(tmp_path) -> None:
    with pytest.raises(SpecError, match=r"max_sync_error_counts must be >= 0 \[counts\], got -1"):
        load_spec(_write(tmp_path, "[scenario.sync]\nmax_sync_error_counts = -1\n"))
    with pytest.raises(SpecError, match=r"gain_spread must be in \[0, 0.9\] \[1\], got 1.5"):
        load_spec(_write(tmp_path, SYNC + "[montecarlo]\ngain_spread = 1.5\n"))


def test_parameters_of_other_kinds_are_not_judged() -> None:
    # settle_s (a lock parameter, default 2 s) does not constrain a 1-s sync run
    sc = ScenarioSpec(name="short", kind="sync", seconds=1.0, max_saturation_pct=2)
    assert sc.limits == {"max_saturation_pct": 2.0} and "settle_s" not in sc.to_dict()
    with pytest.raises(SpecError, match=r"scenario\.l\.speed_fraction does not apply"):
        ScenarioSpec(name="l", kind="lock", speed_fraction=0.9, max_holding_band_counts=4)


def test_spec_file_missing_or_not_toml(tmp_path) -> None:
    missing = tmp_path / "nope.spec.toml"
    with pytest.raises(SpecError, match=r"cannot read spec file .*nope\.spec\.toml"):
        load_spec(missing)
    with pytest.raises(SpecError, match="not valid TOML"):
        load_spec(_write(tmp_path, "[scenario.sync\nmax_overshoot_pct = 5\n"))


def test_spec_for_another_rig_or_axis_is_refused(good, rig, spec) -> None:
    with pytest.raises(SpecError, match="written for rig 'other'"):
        verify(good, rig, dataclasses.replace(small(spec), rig="other"))
    mc = dataclasses.replace(spec.montecarlo, axes=("gantry",))
    with pytest.raises(SpecError, match=r"montecarlo\.axes names 'gantry'"):
        verify(good, rig, dataclasses.replace(small(spec), montecarlo=mc))


def test_a_hold_whose_settling_leaves_no_tick_is_refused(good, rig, spec) -> None:
    """``settle_s < seconds`` passes the spec's own check, yet 0.099 s of a 0.1-s hold leaves
    no whole tick at 4.000235 ms (``seconds`` gives 25 ticks, the window starts at tick
    ceil(0.099 / 0.004000235) = 25): one SpecError before any run (it used to end in numpy's
    "zero-size array" traceback). One tick earlier the hold runs."""
    lock = dataclasses.replace(spec.scenario("lock"), seconds=0.1, settle_s=0.099)
    mc = dataclasses.replace(spec.montecarlo, count=2)
    bad = dataclasses.replace(spec, scenarios=(lock,), montecarlo=mc)
    with pytest.raises(SpecError, match=r"'lock': settle_s \(0\.099 s\) leaves no tick of its 25"):
        verify(good, rig, bad)
    last = dataclasses.replace(lock, settle_s=0.095)  # ceil(23.75) = 24: the last tick
    result = verify(good, rig, dataclasses.replace(bad, scenarios=(last,)))
    assert {r.quantity for r in result.rows} >= {"holding_band_counts"}


def test_plant_variants_widen_to_the_identified_intervals(rig, spec) -> None:
    # the plant set is the identification's intervals, widened by the spec's
    # spreads; an identified gain interval of -35 %/+40 % is wider than the spec's ±20 %
    slave = rig.axis("slave")
    g0, off0 = slave.plant.gain_cps_per_v, slave.plant.offset_v
    fit = PlantFit(
        method="iv",
        structure=("gain_cps_per_v", "offset_v"),
        friction="sym",
        adequate=True,
        ci95={"gain_cps_per_v": (0.65 * g0, 1.4 * g0), "offset_v": (off0 - 0.01, off0 + 0.001)},
    )
    fitted = dataclasses.replace(rig, axes=(rig.axes[0], dataclasses.replace(slave, plant_fit=fit)))
    mc = dataclasses.replace(spec.montecarlo, count=3000)
    v = plant_variants(fitted, mc)[1:]
    gains = np.array([x.plants[1].gain_cps_per_v for x in v]) / g0
    assert gains.min() == pytest.approx(0.65, abs=0.01) and gains.max() == pytest.approx(
        1.4, abs=0.01
    )
    offs = np.array([x.plants[1].offset_v for x in v]) - off0
    # below: the interval (10 mV) is wider than the spread (2 mV); above: the spread is wider
    assert offs.min() == pytest.approx(-0.01, abs=1e-4) and offs.max() == pytest.approx(
        0.002, abs=1e-4
    )
    taus = np.array([x.plants[1].tau_s for x in v]) / slave.plant.tau_s  # no interval: spread
    assert taus.min() == pytest.approx(0.7, abs=0.01) and taus.max() == pytest.approx(1.3, abs=0.01)
    # without a fit record (or a narrower one) the draws are the spec spread's, bit for bit
    plain = plant_variants(rig, mc)
    assert [x.plants[0] for x in plain] == [x.plants[0] for x in plant_variants(fitted, mc)]


def test_plant_variants_stay_in_their_ranges(rig, spec) -> None:
    mc = dataclasses.replace(spec.montecarlo, count=50, axes=("slave",))
    vs = plant_variants(rig, mc)
    assert len(vs) == 51 and vs[0].label == "nominal" and vs[-1].label == "mc50"
    assert vs[0].plants == tuple(a.plant for a in rig.axes)
    m0, s0 = rig.axis("master").plant, rig.axis("slave").plant
    g = np.array([v.plants[1].gain_cps_per_v / s0.gain_cps_per_v for v in vs[1:]])
    tau = np.array([v.plants[1].tau_s / s0.tau_s for v in vs[1:]])
    off = np.array([v.plants[1].offset_v - s0.offset_v for v in vs[1:]])
    assert np.all(np.abs(g - 1) <= 0.2) and np.all(np.abs(tau - 1) <= 0.3)
    assert np.all(np.abs(off) <= 0.002 + 1e-15)
    assert np.ptp(g) > 0.2  # they do spread
    assert all(v.plants[0] == m0 for v in vs)  # the master is not named: it stays nominal
    assert plant_variants(rig, mc) == vs  # deterministic in the seed
    assert plant_variants(rig, mc, seed=1) != vs


# --- verification --------------------------------------------------------------------------


def test_good_tuning_passes_shipped_spec_with_margin(good_result) -> None:
    v = good_result
    assert v.passed, v.failures
    assert v.failures == []
    assert len(v.variants) == 65  # nominal + 64
    for r in v.rows:
        if r.quantity in ("holding_band_counts", "fault_runs", "saturation_pct"):
            continue
        # the spec's limits are the example machine's (its comments); a default-budget tuning
        # keeps at least 5 % on each, so that a small change is not decided by noise
        assert r.relative_margin >= 0.05, r
    # the lock holds every axis within ±1 pulse
    # (docs/runtime.md#position-lock-and-its-holding-band), the physics of the quantised P loop
    assert v.row("lock", "holding_band_counts", "master").worst <= 4
    assert v.check("overflow").passed and v.check("timer_period").passed


def test_fastest_motion_is_the_cruise(good_result, rig) -> None:
    # the moves cruise at 300 r/min = 245.8 counts/tick; overshoots add a little
    unwrap = good_result.check("counter_unwrap")
    assert unwrap.limit == 2**16  # 24-bit counter: the high byte is right up to 65,536/tick
    assert 245 < unwrap.value < 2 * 245.8
    freq = good_result.check("counter_input_frequency")
    assert freq.limit == pytest.approx(46875.0)  # 2.4 MHz / 3072 pulses/rev · 60
    assert 300 < freq.value < 600 and freq.passed


def test_timer_period_is_reported_and_judged_only_with_a_limit(rig) -> None:
    # docs/runtime.md#timer-and-achieved-period: divisor 4773 gives 4.000235 ms, +58.7 ppm
    c = check_timer(rig)
    assert c.passed and c.limit is None and c.value == pytest.approx(58.7, abs=0.05)
    assert not check_timer(rig, 50.0).passed and check_timer(rig, 60.0).passed


def test_cut_slave_gains_fail_max_sync_error(good, rig, spec) -> None:
    g = good.design["slave"]["tuning"]["gains"]
    cut = FuzzyPIDGains(
        kp0=0.1 * g["kp0"],
        ki0=0.1 * g["ki0"],
        kd0=0.1 * g["kd0"],
        k10=0.1 * g["k10"],
        ke=g["ke"],
        kec=g["kec"],
        n=g["n"],
        **{k: 0.1 * np.asarray(g[k]) for k in ("dkp", "dki", "dkd", "dk1")},
    )
    weak = with_slave_task(good, cut.quantize(good.period_s))
    v = verify(weak, rig, dataclasses.replace(spec, montecarlo=small(spec).montecarlo))
    assert not v.passed
    row = v.row("sync", "max_sync_error_counts", "slave")
    assert not row.passed and row.worst > 3 * row.limit and row.margin < 0
    assert any("sync: max_sync_error_counts of slave" in f for f in v.failures)
    assert "FAIL" in format_table(v) and "FAILED" in format_table(v)


def test_too_tight_limit_fails_naming_it(good, rig, spec) -> None:
    v = verify(good, rig, small(spec, max_overshoot_pct=1.0))
    assert not v.passed
    failed = [(r.scenario, r.quantity) for r in v.rows if not r.passed]
    assert set(failed) == {("sync", "overshoot_pct")}
    assert v.failures[0].startswith("sync: overshoot_pct of ")


def test_same_seed_same_result(good, rig, spec) -> None:
    a = verify(good, rig, small(spec), seed=7).to_dict()
    b = verify(good, rig, small(spec), seed=7).to_dict()
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    assert a["seed"] == 7 and a != verify(good, rig, small(spec), seed=8).to_dict()


def test_speed_above_the_counter_input_limit_is_flagged(good, rig, spec) -> None:
    # a card counting at most 10 kHz: 10,000 / 3072 · 60 = 195 r/min, below the 300 r/min cruise
    slow = dataclasses.replace(rig, counter=dataclasses.replace(rig.counter, max_input_hz=1e4))
    v = verify(good, slow, small(spec, count=0))
    c = v.check("counter_input_frequency")
    assert not c.passed and c.limit == pytest.approx(1e4 / 3072 * 60) and c.value > 300
    assert not v.passed and any("counter_input_frequency" in f for f in v.failures)
    assert v.check("counter_unwrap").passed


def test_unwrap_speed_limit_at_its_edge(rig) -> None:
    # 24 bits: the high-byte rule is right up to 2**16 counts per tick, wrong above
    ok, _ = check_speed(rig, 65536.0, 1000.0)
    bad, _ = check_speed(rig, 65537.0, 1000.0)
    assert ok.passed and not bad.passed
    assert ok.facts["limit_rpm"] == pytest.approx(79995, abs=1)  # hw.counter docstring


# --- the overflow bound --------------------------------------------------------------------


def test_overflow_bound_on_known_numbers() -> None:
    # |q · e| with |e| <= 2^31 − 1 fits int64 (<= 2^63 − 1) up to |q| = 2^32 + 2
    q = max_safe_gain_q()
    assert q == 2**32 + 2
    assert q * int(E_MAX) <= int(INT64_MAX) < (q + 1) * int(E_MAX)


def test_good_tuning_keeps_the_overflow_bound(good, rig) -> None:
    c = check_overflow(good, rig)
    assert c.passed and c.value < 63 and c.limit == 63
    slave = c.facts["axes"]["slave"]
    assert {
        "lock_gain",
        "scheduled kp",
        "scheduled ki_t",
        "scheduled kd_t",
        "scheduled k1_t",
        "ke",
        "kec",
    } <= set(slave)
    assert all(t["product_bound"] <= int(INT64_MAX) for t in slave.values())
    assert c.facts["integrator_bound"] == 2**43  # 12-bit D/A: 2^11 LSB at F_U = 32 bits
    assert c.facts["position_overflow_years"] > 1e6


def test_overflow_flags_a_gain_needing_a_right_shift(good, rig, spec) -> None:
    # f = 40 > F_U = 32: the product would have to be shifted right to align with u_q
    master = good.axis_names.index("master")
    ctls = list(good.controllers)
    pi = ctls[master].task
    ctls[master] = dataclasses.replace(
        ctls[master], task=PIConstants(kp=Fixed(q=pi.kp.q, f=40), ki_t=pi.ki_t)
    )
    bad = dataclasses.replace(good, controllers=tuple(ctls))
    c = check_overflow(bad, rig)
    assert not c.passed and "master kp: f = 40" in c.detail
    v = verify(bad, rig, small(spec))
    assert not v.passed and v.rows == ()  # the runs are skipped, the check says why
    assert any("overflow" in f for f in v.failures)


def test_overflow_flags_a_scheduled_gain_beyond_the_bound(good, rig) -> None:
    # constructed directly (the constructor refuses it): a kp table at f_t = 0 whose entry,
    # aligned by 2^(f − 0), lifts the scheduled gain just past 2^32 + 2
    i = good.axis_names.index("slave")
    task = good.controllers[i].task
    (q, _), *rest = task.tables
    big = np.zeros_like(np.asarray(q), dtype=np.int64)
    big[0, 0] = -(-(max_safe_gain_q() + 1 - task.kp.q) >> task.kp.f)  # ceil division
    assert abs(big[0, 0]) < 2**15 and task.kp.q + int(big[0, 0]) * 2**task.kp.f > 2**32 + 2
    broken = object.__new__(type(task))
    for fld in dataclasses.fields(task):
        object.__setattr__(broken, fld.name, getattr(task, fld.name))
    object.__setattr__(broken, "tables", ((big, 0), *rest))
    c = check_overflow(with_slave_task(good, broken), rig)
    assert not c.passed and "slave scheduled kp" in c.detail and "> 2^63" in c.detail


# --- the record ----------------------------------------------------------------------------


def _sources(tuning: Path) -> dict[str, SourceFile]:
    return {
        "tuning": SourceFile.read(tuning, OSError, "tuning file"),
        "rig": SourceFile.read(EXAMPLE_RIG_PATH, OSError, "rig file"),
        "spec": SourceFile.read(SPEC_PATH, OSError, "spec file"),
    }


def test_record_hashes_and_trust(tmp_path, tuning_file, good_result) -> None:
    tuning = tmp_path / "tuning.json"
    tuning.write_bytes(tuning_file.read_bytes())
    src = _sources(tuning)
    record = verification_record(good_result, **src)
    files = record["files"]
    # hashes against hashlib over the files' bytes (file_sha256), not the code under test
    assert files["tuning"]["sha256"] == file_sha256(tuning)
    assert files["rig"]["sha256"] == file_sha256(EXAMPLE_RIG_PATH)
    assert files["spec"]["sha256"] == file_sha256(SPEC_PATH)
    assert record["passed"] is True and record["schema"] == "servotune.verify/3"
    assert record["summary"]["limits_failed"] == 0 and record["tool_version"] == st.__version__
    body = {k: v for k, v in record.items() if k != "sha256"}
    canon = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    # docs/decisions.md#3-digests
    assert record["sha256"] == hashlib.sha256(canon.encode()).hexdigest()
    path = write_record(record, tuning)
    assert path == tmp_path / "tuning.json.verify.json" == record_path(tuning)
    text = path.read_text()
    assert text == json.dumps(json.loads(text), sort_keys=True, indent=2) + "\n"
    assert read_record(tuning) == record
    check_record(record, **src)  # the same bytes: trusted
    # one byte changes in the tuning: the record no longer vouches for it
    raw = bytearray(tuning.read_bytes())
    raw[-1:] = b" \n"
    tuning.write_bytes(bytes(raw))
    with pytest.raises(TrustError, match="the tuning differs from the verified one"):
        check_record(record, **_sources(tuning))


def test_failed_missing_or_edited_record_is_not_trusted(tmp_path, tuning_file, good_result) -> None:
    tuning = tmp_path / "t.json"
    tuning.write_bytes(tuning_file.read_bytes())
    with pytest.raises(TrustError, match="has no verification record"):
        read_record(tuning)
    src = _sources(tuning)
    record = verification_record(good_result, **src)
    # edited by hand (passed flipped): the record's own digest refuses it
    write_record({**record, "passed": False}, tuning)
    with pytest.raises(TrustError, match="digest does not match"):
        read_record(tuning)
    failed = {**record, "passed": False}
    with pytest.raises(TrustError, match="failed its verification"):
        check_record(failed, **src)
    with pytest.raises(TrustError, match=r"verified by servotune 0\.0\.0"):
        check_record({**record, "tool_version": "0.0.0"}, **src)
    record_path(tuning).write_text("{not json")
    with pytest.raises(TrustError, match="not JSON"):
        read_record(tuning)


def test_verify_files_end_to_end(tmp_path, tuning_file, spec) -> None:
    tuning = tmp_path / "tuning.json"
    tuning.write_bytes(tuning_file.read_bytes())
    quick = tmp_path / "quick.spec.toml"
    text = SPEC_PATH.read_text().replace("count = 64", "count = 4")
    quick.write_text(text)
    lines: list[str] = []
    v, record, path = verify_files(tuning, quick, EXAMPLE_RIG_PATH, progress=lines.append)
    assert v.passed and path == record_path(tuning) and any("scenario sync" in s for s in lines)
    assert json.loads(path.read_text()) == record
    first = path.read_bytes()
    verify_files(tuning, quick, EXAMPLE_RIG_PATH)
    assert path.read_bytes() == first  # deterministic bytes: no timestamps
    assert read_record(tuning)["files"]["spec"]["name"] == "quick.spec.toml"
    table = format_table(v)
    assert table.splitlines()[-1] == "PASSED" and "max_sync_error_counts" in table
    assert not any(math.isnan(r.worst) for r in v.rows)


# --- margins: every loop the runtime can run ---------------------------------------------


def _value(fx: dict) -> float:
    return fx["q"] * 2.0 ** -fx["f"]


def _independent_loop(plant, rig, kp: float, ki_t: float, kd_t: float, extra_lag_s: float):
    """L(z) built here with python-control (ZOH ``c2d`` of the continuous model with its lag
    as a 6th-order Padé approximant), not with servotune's loop builder."""
    import control

    t = rig.period_s
    g = control.tf([plant.gain_cps_per_v], [plant.tau_s, 1.0, 0.0])
    num, den = control.pade(rig.timer.compute_s + plant.delay_s + extra_lag_s, 6)
    p = control.c2d(g * control.tf(num, den), t, method="zoh") * rig.dac.lsb_v
    z = control.tf([1.0, 0.0], [1.0], t)
    c = kp + ki_t * z / (z - 1) + kd_t * (z - 1) / z
    return control.minreal(c * p, verbose=False)


def test_default_tuning_keeps_the_margin_limits_on_every_cell_and_corner(tuning_file, rig):
    """The default tuning, read from its file, meets PM >= 45°, GM >= 6 dB, Ms <= 2 on every
    loop over the spec's corners (gain ±20 %, tau ±30 %) one tick late, by python-control on
    loops built here (an independent check of the tool's margins)."""
    import control

    doc = json.loads(tuning_file.read_text())
    loops = []  # (axis, what, kp, ki_t, kd_t)
    for a in doc["axes"]:
        ctl = a["controller"]
        loops.append((a["name"], "lock", _value(ctl["lock_gain"]), 0.0, 0.0))
        task = ctl["task"]
        if ctl["law"] == "pi":
            loops.append((a["name"], "task", _value(task["kp"]), _value(task["ki_t"]), 0.0))
        elif ctl["law"] == "fuzzy_pid":
            n = task["n"]
            cells = set()
            for e in range(2 * n + 1):
                for ec in range(2 * n + 1):
                    gains = []
                    for base, tab in (("kp", "kp"), ("ki_t", "ki"), ("kd_t", "kd")):
                        b, tb = task[base], task["tables"][tab]
                        q = b["q"] + tb["q"][e][ec] * 2 ** (b["f"] - tb["f"])
                        gains.append(q * 2.0 ** -b["f"])
                    cells.add(tuple(gains))
            loops += [(a["name"], "cell", *g) for g in sorted(cells)]
    assert sum(1 for x in loops if x[1] == "cell") > 10  # the table really schedules
    t = rig.period_s
    w = np.linspace(1e-2, np.pi / t * (1 - 1e-9), 4000)
    worst = {"pm": 180.0, "gm": 99.0, "ms": 0.0}
    for name, what, kp, ki_t, kd_t in loops:
        plant = rig.axis(name).plant
        for fg in (0.8, 1.2):
            for ft in (0.7, 1.3):
                p = dataclasses.replace(
                    plant, gain_cps_per_v=plant.gain_cps_per_v * fg, tau_s=plant.tau_s * ft
                )
                lp = _independent_loop(p, rig, kp, ki_t, kd_t, t)
                lw = lp(np.exp(1j * w * t))
                ms = float(np.max(np.abs(1 / (1 + lw))))
                poles = control.feedback(lp, 1).poles()
                assert np.max(np.abs(poles)) < 1, (name, what, fg, ft)
                worst["ms"] = max(worst["ms"], ms)
                if ms > 1.4:  # margins of the loops near the limit (the others are far inside)
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", UserWarning)
                        gm, pm, *_ = control.stability_margins(lp)
                    worst["pm"] = min(worst["pm"], pm)
                    worst["gm"] = min(worst["gm"], 20 * np.log10(gm))
    # tolerance: the Padé lag here against servotune's exact one (about 0.1° at crossover)
    assert worst["ms"] <= 2.0 + 0.01, worst
    assert worst["pm"] >= 45.0 - 0.3, worst
    assert worst["gm"] >= 6.0, worst


def _with_hot_cell(tuning: Tuning, cell: tuple[int, int], factor: float) -> Tuning:
    """The tuning with the slave's Kp at one query-table cell ``factor`` times its base (the
    design gains re-quantised, as ``tune`` would)."""
    d = dict(tuning.design["slave"]["tuning"]["gains"])
    n = d["n"]
    dkp = np.array(d["dkp"], dtype=float)
    dkp[cell[0] + n, cell[1] + n] = (factor - 1.0) * d["kp0"]
    gains = FuzzyPIDGains(**{**d, "dkp": dkp})
    return with_slave_task(tuning, gains.quantize(tuning.period_s))


def test_a_cell_that_breaks_the_margins_fails_verify_with_the_cell_named(good, rig, spec):
    # one corner cell (large error, large error change: never reached in these runs) with
    # Kp × 8: the time-domain limits still pass, the margins do not
    bad = _with_hot_cell(good, (6, 6), 8.0)
    v = verify(bad, rig, small(spec, count=2))
    assert all(r.passed for r in v.rows), [r for r in v.rows if not r.passed]
    check = v.check("margins:slave:task")
    assert not check.passed and not v.passed
    assert "cell E=+6 EC=+6" in check.detail
    assert any("margins:slave:task" in f and "E=+6 EC=+6" in f for f in v.failures)
    # the same tuning without the hot cell passes the margins
    assert verify(good, rig, small(spec, count=2)).check("margins:slave:task").passed


def test_margins_limits_come_from_the_spec(good, rig, spec):
    loose = dataclasses.replace(
        small(spec, count=0),
        margins=st.verify.MarginLimits(
            min_phase_margin_deg=10.0, min_gain_margin_db=1.0, max_sensitivity=10.0
        ),
    )
    bad = _with_hot_cell(good, (6, 6), 2.5)  # Ms between the two limits
    hot = verify(bad, rig, loose).check("margins:slave:task")
    strict = verify(bad, rig, small(spec, count=0)).check("margins:slave:task")
    assert hot.passed != strict.passed  # the same loops, judged by other limits


def test_spec_margins_table_is_read_and_checked(tmp_path) -> None:
    text = SPEC_PATH.read_text().replace(
        "min_phase_margin_deg = 45.0", "min_phase_margin_deg = 50.0"
    )
    p = tmp_path / "s.spec.toml"
    p.write_text(text)
    assert load_spec(p).margins.min_phase_margin_deg == 50.0
    assert load_spec(p).margin_samples == 32  # the example spec's draws inside the plant set
    p.write_text(text.replace("samples = 32", "samples = -1"))
    with pytest.raises(SpecError, match=r"margins\.samples"):
        load_spec(p)
    p.write_text(text.replace("extra_ticks = 1", "extra_ticks = 1\nmax_sensitivty = 2.0"))
    with pytest.raises(SpecError, match=r"margins\.max_sensitivty"):
        load_spec(p)
    p.write_text(text.replace("max_sensitivity = 2.0", "max_sensitivity = 0.5"))
    with pytest.raises(SpecError, match="max_sensitivity"):
        load_spec(p)


# --- Monte Carlo: pass fraction with its interval -----------------------------------------


def test_pass_fraction_is_the_same_on_one_and_two_threads(good, rig, spec) -> None:
    import numba

    s = small(spec, count=40)
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = verify(good, rig, s)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = verify(good, rig, s)
    finally:
        numba.set_num_threads(before)
    assert one.variant_passed == two.variant_passed and one.to_dict() == two.to_dict()
    k, n, frac, lo, hi = one.pass_fraction
    assert n == 40 and k == sum(one.variant_passed[1:]) and lo <= frac <= hi
    assert one.to_dict()["montecarlo"]["count"] == 40


def test_pass_fraction_interval_is_clopper_pearson(good_result) -> None:
    # exact closed forms of the Clopper–Pearson 95 % interval (Clopper & Pearson, Biometrika
    # 26, 1934): all n pass → lower = 0.025^(1/n); none pass → upper = 1 − 0.025^(1/n)
    v = dataclasses.replace(good_result, variant_passed=(True,) * 41)
    k, n, frac, lo, hi = v.pass_fraction
    assert (k, n, frac, hi) == (40, 40, 1.0, 1.0)
    assert lo == pytest.approx(0.025 ** (1 / 40), rel=1e-9)
    v = dataclasses.replace(good_result, variant_passed=(True,) + (False,) * 40)
    assert v.pass_fraction[3] == 0.0
    assert v.pass_fraction[4] == pytest.approx(1 - 0.025 ** (1 / 40), rel=1e-9)
    # one of two: symmetric about 1/2, lower = 1 − sqrt(0.975) (beta(1, 2) quantile)
    v = dataclasses.replace(good_result, variant_passed=(True, True, False))
    assert v.pass_fraction[3] == pytest.approx(1 - 0.975**0.5, rel=1e-9)
    assert v.pass_fraction[3] + v.pass_fraction[4] == pytest.approx(1.0)
