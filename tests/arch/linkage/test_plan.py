"""The linkage through the chain: plan → verify → export (the plan, spec and verify modules of
servotune.arch.linkage).

Reference values are worked out by hand from the example config plants/linkage-6axis.toml
(6 axes on 2 CPUs, 2 ms, SCI at 460,800 baud, blocks of 5, prefill 2, queues of 20, resync
12.5 s, clocks +80 / −60 ppm) and its spec plants/linkage-6axis.spec.toml, unless a comment
says otherwise. The bit budget uses UART 8N1 framing: 10 bits on the line per byte (a start
bit, 8 data bits, a stop bit).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import shutil
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from servotune.arch.linkage import (
    PLAN_SCHEMA,
    RECORD_SCHEMA,
    LinkagePlan,
    load_linkage,
    load_linkage_spec,
    load_plan_for_export,
    plan_linkage,
    plan_to_string,
    read_plan,
    read_plan_bytes,
    run_linkage,
    run_plan,
    verify_plan_files,
    write_plan,
)
from servotune.digest import bytes_sha256, document_sha256
from servotune.errors import ConfigError, SpecError, TrustError
from servotune.export import c as c_export
from servotune.export import json as json_export
from servotune.export.linkage import linkage_c_header
from servotune.fixed import quantize
from servotune.verify.record import read_record

ROOT = Path(__file__).resolve().parents[3]
PLANTS = ROOT / "plants"
EXAMPLE = PLANTS / "linkage-6axis.toml"
SPEC = PLANTS / "linkage-6axis.spec.toml"
RIG = PLANTS / "pc-dual-servo.toml"
_DATA = tomllib.loads(EXAMPLE.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def plan() -> LinkagePlan:
    return plan_linkage(EXAMPLE)


@pytest.fixture(scope="module")
def verified(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The example planned and verified as a user runs it: the plan file, its record beside."""
    d = tmp_path_factory.mktemp("verified")
    path = d / "linkage.plan.json"
    write_plan(plan_linkage(EXAMPLE), path)
    verify_plan_files(path, SPEC)
    return path


def _config_copy(tmp_path: Path, old: str = "", new: str = "") -> Path:
    """The example config (and its rig) copied into ``tmp_path``, ``old`` replaced by ``new``."""
    text = EXAMPLE.read_text(encoding="utf-8")
    assert old in text
    (tmp_path / "linkage-6axis.toml").write_text(text.replace(old, new), encoding="utf-8")
    shutil.copy(RIG, tmp_path / RIG.name)
    return tmp_path / "linkage-6axis.toml"


def _edited_plan(tmp_path: Path, source: Path, edit: Any) -> Path:
    """A copy of the plan file ``source`` with ``edit`` applied to its JSON (by hand)."""
    d = json.loads(source.read_text(encoding="utf-8"))
    edit(d)
    path = tmp_path / "edited.plan.json"
    path.write_text(json.dumps(d, sort_keys=True, indent=2) + "\n", encoding="utf-8")
    return path


def _spec(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "variant.spec.toml"
    path.write_text(text, encoding="utf-8")
    return path


# --- the plan ---------------------------------------------------------------------------------


def test_plan_is_deterministic_and_round_trips(plan: LinkagePlan, tmp_path: Path) -> None:
    text = plan_to_string(plan)
    assert plan_to_string(plan_linkage(EXAMPLE)) == text  # the same bytes twice
    write_plan(plan, tmp_path / "a.json")
    write_plan(plan_linkage(EXAMPLE), tmp_path / "b.json")
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    assert (tmp_path / "a.json").read_text(encoding="utf-8") == text
    back = read_plan(tmp_path / "a.json")
    assert back == plan and plan_to_string(back) == text
    d = json.loads(text)
    assert d["schema"] == PLAN_SCHEMA == "servotune.linkage-plan/1"
    assert sorted(d) == [
        "axes",
        "bus",
        "clock",
        "config",
        "cpus",
        "design",
        "interpolation",
        "period_s",
        "provenance",
        "rig",
        "schema",
    ]
    assert text.endswith("}\n") and '  "axes": [' in text  # two-space indent, sorted keys
    assert d["config"]["sha256"] == bytes_sha256(EXAMPLE.read_bytes())
    assert d["rig"]["sha256"] == bytes_sha256(RIG.read_bytes())
    assert d["provenance"]["tool"] == "servotune" and "tool_version" in d["provenance"]


def test_plan_holds_the_configs_integers(plan: LinkagePlan) -> None:
    """Each axis's constants are the file's gains quantised at 2 ms (Ki·T folded in); the queue
    depths and the resync interval are the file's, in setpoints and whole master ticks."""
    for name, ctl in zip(plan.axis_names, plan.controllers, strict=True):
        a = _DATA["axis"][name]
        assert ctl.task.kp == quantize(a["kp"])
        assert ctl.task.ki_t == quantize(a["ki"] * 0.002)
        assert ctl.lock_gain == quantize(0.4)  # the default lock gain [codes/count]
        assert ctl.following_error_limit_counts == a["following_error_limit_counts"]
    assert [c.queue_depth for c in plan.cpus] == [20, 20]
    assert plan.resync_ticks == 6250  # 12.5 s / 2 ms
    assert [c.clock_ppm for c in plan.cpus] == [80.0, -60.0]
    assert plan.path.ticks - 1 == round(14.514 / 0.002)  # the path's duration (test_linkage)


def test_bit_budget_by_hand(plan: LinkagePlan) -> None:
    """The SCI bit budget from the config's numbers: a frame is 8 bytes of header, index and
    CRC plus 4 bytes × 6 axes × 5 ticks; 8N1 puts 10 bits per byte on the line."""
    frame_bytes = 8 + 4 * 6 * 5  # 128
    bits = frame_bytes * 10  # 1280
    frame_s = bits / 460_800  # 2.778 ms
    period = 5 * 0.002  # one block every 10 ms
    assert (plan.frame_bytes, plan.bits_per_block) == (128, 1280)
    assert plan.frame_s == pytest.approx(frame_s, rel=1e-15)
    assert plan.broadcast_period_s == pytest.approx(period, rel=1e-15)
    assert plan.utilisation == pytest.approx(0.277_777_8, rel=1e-6)
    bus = json.loads(plan_to_string(plan))["bus"]
    assert bus["bits_per_block"] == 1280 and bus["frame_bytes"] == 128
    assert bus["utilisation"] == pytest.approx(frame_s / period, rel=1e-15)


def test_watermarks_and_drift_by_hand(plan: LinkagePlan) -> None:
    """Drift between syncs: 6250 ticks × 80 ppm ≈ 0.5 tick (s1), × 60 ppm ≈ 0.375 (s2).
    A frame takes 2.778 ms = 1.389 ticks. Low = 2·5 − floor(1.389 + drift) = 9 for both;
    high = 3·5 − 1 − floor(1.389 − drift) = 14 (s1: floor 0.889 = 0), 13 (s2: floor 1.014)."""
    s1, s2 = plan.cpus
    assert plan.drift_ticks(s1) == pytest.approx(6250 * 80e-6, rel=1e-4)
    assert plan.drift_ticks(s2) == pytest.approx(6250 * 60e-6, rel=1e-4)
    assert (s1.low_watermark, s1.high_watermark) == (9, 14)
    assert (s2.low_watermark, s2.high_watermark) == (9, 13)
    # the simulation at the configured clocks (run_linkage on the config, not the plan): the
    # queue before a pop falls to the low watermark exactly, after a block stays within high
    r = run_linkage(load_linkage(EXAMPLE), seed=1)
    for c, p in zip(r.cpus, plan.cpus, strict=True):
        assert c.min_level == p.low_watermark and c.max_level <= p.high_watermark


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(extra=1), r"unknown key extra"),
        (lambda d: d.update(schema="servotune.linkage-plan/0"), r"schema must be"),
        (lambda d: d["bus"].pop("block_size"), r"missing key bus\.block_size"),
        (
            lambda d: d["cpus"][0].update(queue_depth=20.0),
            r"cpus\[0\]\.queue_depth must be an integer in 1\.\.1000000 \[setpoints\], got 20\.0",
        ),
        (
            lambda d: d["bus"].update(utilisation=0.2),
            r"bus\.utilisation is 0\.2 but the plan's own fields give 0\.277",
        ),
        (lambda d: d["cpus"][1].update(drift_ticks=0.1), r"cpus\[1\]\.drift_ticks is 0\.1"),
        (
            lambda d: d["cpus"][1].update(low_watermark=0),
            r"cpus\[1\]\.low_watermark must be an integer in 1\.\.20",
        ),
        (
            lambda d: d["cpus"][0].update(queue_depth=12),
            r"cpus\[0\]\.high_watermark must be an integer in 9\.\.12 \[setpoints\], got 14",
        ),
        (
            lambda d: d["clock"].update(resync_interval_ticks=6250.0),
            r"clock\.resync_interval_ticks must be an integer",
        ),
        (
            lambda d: d["axes"][2]["controller"]["task"]["kp"].update(q=1.5),
            r"axes\[2\]\.controller: q and f must be integers",
        ),
        (lambda d: d["axes"][0].update(cpu="s2"), r"axes\[0\]\.cpu is 's2' but axis 'x' is on"),
        (
            lambda d: d["cpus"][1].update(axes=["y", "b", "x"]),
            r"axis 'x' is on two CPUs: 's1' and 's2'",
        ),
        (lambda d: d["config"].update(sha256="XYZ"), r"config\.sha256 must be 64 lower-case hex"),
        (lambda d: d.update(period_s=2), r"period_s must be a number \[s\], got 2"),
    ],
)
def test_strict_reader_names_the_field(plan: LinkagePlan, edit: Any, message: str) -> None:
    d = copy.deepcopy(plan.to_dict())
    edit(d)
    raw = json.dumps(d).encode()
    with pytest.raises(ConfigError, match=message) as exc:
        read_plan_bytes(raw, "edited.plan.json")
    assert str(exc.value).startswith("linkage plan 'edited.plan.json': ")
    assert "\n" not in str(exc.value)


def test_plan_refuses_what_cannot_run(tmp_path: Path) -> None:
    # the bus cannot carry the blocks: 128 bytes × 10 bits at 115,200 baud = 11.1 ms > 10 ms
    bad = _config_copy(tmp_path, "baud = 460800", "baud = 115200")
    with pytest.raises(ConfigError, match=r"cannot plan: bus overload.*utilisation 111 %"):
        plan_linkage(bad)
    # a +3000 ppm clock with no resync drifts 22 ticks over the 15 s run: the prefill's 9
    # setpoints of margin cannot cover it
    bad = _config_copy(tmp_path, "clock_ppm = 80.0", "clock_ppm = 3000.0")
    bad.write_text(bad.read_text().replace("resync_interval_s = 12.5", "resync_interval_s = 0"))
    why = r"drift \(22\.5\d ticks at \+3000 ppm, no resync in 7507 ticks\)"
    with pytest.raises(
        ConfigError, match=r"cpu s1: the prefill leaves no margin for its clock " + why
    ):
        plan_linkage(bad)
    with pytest.raises(ConfigError, match=r"cannot read linkage config"):
        plan_linkage(tmp_path / "missing.toml")


def test_resync_interval_left_out_is_the_recommended_one(tmp_path: Path) -> None:
    cfg = _config_copy(tmp_path, "resync_interval_s = 12.5", "")
    plan = plan_linkage(cfg)
    # half a tick of drift at the worst clock: 0.5 · 2 ms / 80e-6 = 12.5 s = 6250 ticks
    assert plan.resync_ticks == 6250 and plan.design["clock"]["resync_from"] == "recommended"


def test_run_plan_runs_the_plans_integers(plan: LinkagePlan) -> None:
    """The simulation of a plan runs its integers: unedited, the config's own run bit for bit;
    with one constant or the resync interval edited, what was written."""
    config = load_linkage(EXAMPLE)
    a = run_plan(plan, config, seconds=3.0, seed=2)
    b = run_linkage(config, seconds=3.0, seed=2)
    np.testing.assert_array_equal(a.actual_counts, b.actual_counts)
    x = plan.controllers[0]
    kp = dataclasses.replace(x.task.kp, q=x.task.kp.q // 2)  # half the gain of x
    halved = dataclasses.replace(
        plan,
        controllers=(
            dataclasses.replace(x, task=dataclasses.replace(x.task, kp=kp)),
            *plan.controllers[1:],
        ),
    )
    c = run_plan(halved, config, seconds=3.0, seed=2)
    assert c.axes[0].kp == pytest.approx(0.3617 / 2, rel=1e-6)
    assert not np.array_equal(c.actual_counts[:, 0], a.actual_counts[:, 0])
    np.testing.assert_array_equal(c.actual_counts[:, 1], a.actual_counts[:, 1])  # y: its own CPU
    resync = run_plan(
        dataclasses.replace(plan, resync_ticks=500, drift_window_ticks=500), config, seconds=3.0
    )
    assert resync.resync_interval_s == 1.0 and [c.resyncs for c in resync.cpus] == [2, 2]


# --- verify and export --------------------------------------------------------------------------


def test_plan_verify_export_as_a_user_runs_it(verified: Path, tmp_path: Path) -> None:
    plan_path = verified
    record_path = plan_path.with_name(plan_path.name + ".verify.json")
    record = read_record(plan_path, schema=RECORD_SCHEMA)
    assert record["passed"] is True and record["schema"] == "servotune.linkage-verify/1"
    assert record["files"]["plan"]["sha256"] == bytes_sha256(plan_path.read_bytes())
    assert record["files"]["config"]["sha256"] == bytes_sha256(EXAMPLE.read_bytes())
    assert record["files"]["rig"]["sha256"] == bytes_sha256(RIG.read_bytes())
    assert record["files"]["spec"]["sha256"] == bytes_sha256(SPEC.read_bytes())
    assert record["sha256"] == document_sha256(record) and record_path.is_file()
    checks = {r["check"]: r for r in record["verification"]["rows"]}
    for name in (
        "contour_error",
        "bus_utilisation",
        "phase_drift:s1",
        "underruns:s2",
        "overruns:s1",
        "min_level:s2",
        "low_watermark:s1",
        "fault:c",
        "phase_margin:x",
        "sensitivity:b",
    ):
        assert checks[name]["passed"], name
    assert len(record["verification"]["cases"]) == 5  # nominal and the four ±20 ppm corners
    # the export takes the verified plan, and says so
    plan, rec = load_plan_for_export(plan_path, SPEC)
    assert rec == record
    out = tmp_path / "c"
    out.mkdir()
    c_export.to_file(plan, out, verification=rec)
    header = (out / "servotune_link_plan.h").read_text()
    assert "#define STL_PLAN_VERIFIED 1" in header and " * verified: yes" in header
    assert f'#define STL_PLAN_SHA256 "{record["files"]["plan"]["sha256"]}"' in header
    doc = json.loads(json_export.to_string(plan, verification=rec))
    assert doc["schema"] == "servotune.linkage-export/1" and doc["verified"] is True
    assert doc["sha256"] == document_sha256(doc) and doc["data"] == plan.to_dict()
    assert doc["provenance"]["plan_sha256"] == bytes_sha256(plan_path.read_bytes())
    text = json_export.to_string(plan, verification=rec)
    assert text == json_export.to_string(plan, verification=rec)  # deterministic
    # an edited export no longer matches its digest
    doc["data"]["cpus"][0]["queue_depth"] = 30
    assert doc["sha256"] != document_sha256(doc)
    # unverified: allowed when asked for, and marked
    assert "#define STL_PLAN_VERIFIED 0" in linkage_c_header(plan, None, unverified=True)


def test_export_refuses_an_unverified_or_mismatched_plan(verified: Path, tmp_path: Path) -> None:
    fresh = tmp_path / "fresh.plan.json"
    shutil.copy(verified, fresh)
    with pytest.raises(TrustError, match=r"has no verification record"):
        load_plan_for_export(fresh)
    plan, rec = load_plan_for_export(fresh, unverified=True)
    assert rec is None and plan == read_plan(verified)
    # a record of another spec
    other = _spec(tmp_path, SPEC.read_text(encoding="utf-8") + "\n# edited\n")
    with pytest.raises(TrustError, match=r"the spec differs from the verified one"):
        load_plan_for_export(verified, other)
    # the plan edited after verification (a byte that still parses: the trailing newline)
    shutil.copy(
        verified.with_name(verified.name + ".verify.json"),
        fresh.with_name(fresh.name + ".verify.json"),
    )
    fresh.write_text(fresh.read_text() + "\n")
    with pytest.raises(TrustError, match=r"the plan differs from the verified one"):
        load_plan_for_export(fresh)


def test_hand_edited_plan_fails_verify_naming_the_check(verified: Path, tmp_path: Path) -> None:
    # x's Kp × 4 (f 32 → 30): the loop's phase margin drops below 45°
    path = _edited_plan(
        tmp_path, verified, lambda d: d["axes"][0]["controller"]["task"]["kp"].update(f=30)
    )
    v, record, _ = verify_plan_files(path, SPEC)
    assert not v.passed and record["passed"] is False
    assert v.row("phase_margin:x").passed is False and v.row("phase_margin:x").value < 45.0
    assert any(f.startswith("phase_margin:x: phase margin ") for f in v.failures)
    assert v.row("phase_margin:y").passed  # the other axes are untouched
    with pytest.raises(TrustError, match=r"failed its verification \(phase_margin:x"):
        load_plan_for_export(path)
    # s1's low watermark raised to 10: the queue goes down to 9 before a pop
    path = _edited_plan(tmp_path, verified, lambda d: d["cpus"][0].update(low_watermark=10))
    v, _, _ = verify_plan_files(path, SPEC, write=False)
    assert v.failures == (
        "low_watermark:s1: lowest queue level before a pop 9 setpoints < limit 10 setpoints "
        "(nominal clocks)",
    )
    # s1's queue cut to 14 (its high watermark): the prefill plus the block in flight need 15
    path = _edited_plan(tmp_path, verified, lambda d: d["cpus"][0].update(queue_depth=14))
    v, _, _ = verify_plan_files(path, SPEC, write=False)
    assert [r.check for r in v.rows if not r.passed] == ["before_motion:queue:s1"]
    assert "queue too short on cpu s1: queue_depth 14" in v.failures[0]

    # a field the plan restates from its config, edited: refused before anything runs
    def slower_s1(d: dict[str, Any]) -> None:  # with its derived figures, so that it reads
        eps = 10.0 * 1e-6
        d["cpus"][0].update(clock_ppm=10.0, drift_ticks=6250 * eps / (1.0 - eps))
        d["clock"]["max_drift_ticks"] = d["cpus"][1]["drift_ticks"]  # now s2's

    path = _edited_plan(tmp_path, verified, slower_s1)
    with pytest.raises(
        ConfigError,
        match=r"the plan's cpus\[0\]\.clock_ppm is 10\.0 but its "
        r"config has 80\.0: the plan was edited",
    ):
        verify_plan_files(path, SPEC, write=False)


def test_config_or_rig_edited_after_planning_is_refused(tmp_path: Path) -> None:
    cfg = _config_copy(tmp_path)
    plan_path = tmp_path / "linkage.plan.json"
    write_plan(plan_linkage(cfg), plan_path)
    planned = bytes_sha256(cfg.read_bytes())
    cfg.write_text(cfg.read_text().replace("feed_cps = 22000", "feed_cps = 30000"))
    with pytest.raises(TrustError) as exc:
        verify_plan_files(plan_path, SPEC)
    msg = str(exc.value)
    assert f"sha256 {bytes_sha256(cfg.read_bytes())[:12]}" in msg  # the file as it is now
    assert f"sha256 {planned[:12]}" in msg and "give the verified file" in msg  # and as planned
    # the same when the config is given (--config)
    with pytest.raises(TrustError) as exc:
        verify_plan_files(plan_path, SPEC, config_path=cfg)
    assert f"sha256 {bytes_sha256(cfg.read_bytes())[:12]}" in str(exc.value)
    assert f"sha256 {planned[:12]}" in str(exc.value)
    assert not plan_path.with_name(plan_path.name + ".verify.json").exists()
    # the rig edited instead
    cfg.write_text(cfg.read_text().replace("feed_cps = 30000", "feed_cps = 22000"))
    rig = tmp_path / RIG.name
    rig.write_text(rig.read_text() + "\n# edited\n")
    with pytest.raises(TrustError, match=r"rig file .* is not the rig the plan was made with"):
        verify_plan_files(plan_path, SPEC)


# --- the spec's statements ----------------------------------------------------------------------

_BASE = """
[spec]
config = "linkage-6axis"
[clock]
tolerance_ppm = {tol}
max_phase_drift_ticks = 0.75
[bus]
max_utilisation_pct = {util}
[queue]
max_underrun_ticks = 0
max_overrun_blocks = 0
min_level_setpoints = {min_level}
[contour]
max_contour_error_counts = {contour}
"""


def _verify(verified: Path, tmp_path: Path, **limits: float) -> Any:
    values = {"tol": 20.0, "util": 50.0, "min_level": 5, "contour": 2000.0, **limits}
    spec = _spec(tmp_path, _BASE.format(**values))
    v, _, _ = verify_plan_files(verified, spec, write=False)
    return v


def test_spec_statements_decide_the_verdict(verified: Path, tmp_path: Path) -> None:
    base = _verify(verified, tmp_path)
    assert base.passed, base.failures
    # the example's largest contour error is x's overshoot at the stop of the home move,
    # about 1,440 counts along x (spec comment): under 2,000, over 1,000
    contour = base.row("contour_error")
    assert 1400 < contour.value < 2000
    tight = _verify(verified, tmp_path, contour=1000.0)
    assert [r.check for r in tight.rows if not r.passed] == ["contour_error"]
    assert tight.failures[0].startswith(
        "contour_error: largest distance from the programmed path 1"
    )
    # 27.8 % of the line (test_bit_budget_by_hand): a 30 % limit holds, 25 % does not
    assert _verify(verified, tmp_path, util=30.0).passed
    assert not _verify(verified, tmp_path, util=25.0).row("bus_utilisation").passed
    # a CPU 0.61 tick ahead pops once more before a block arrives: 9 → 8 setpoints. Nominal
    # s1 (+80 ppm: 0.5 tick) keeps 9; at +100 ppm (0.625 tick) it gets 8
    assert _verify(verified, tmp_path, tol=0.0, min_level=9).passed
    wide = _verify(verified, tmp_path, min_level=9)
    row = wide.row("min_level:s1")
    assert not row.passed and row.value == 8 and row.case.startswith("s1 +100 ppm")
    # ±100 ppm: s1 at +180 ppm drifts 6250 × 180e-6 = 1.125 ticks between syncs
    drift = _verify(verified, tmp_path, tol=100.0).row("phase_drift:s1")
    assert not drift.passed and drift.value == pytest.approx(1.125, abs=1e-3)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "[queue]\nmax_underruns = 0\n",
            r"unknown key queue\.max_underruns .*did you mean 'max_underrun_ticks'",
        ),
        (
            "[queue]\nmax_underrun_ticks = 0.0\n",
            r"queue\.max_underrun_ticks must be an integer in 0\.\.1099511627776 \[ticks\]",
        ),
        (
            "[contour]\nmax_contour_error_counts = -1\n",
            r"contour\.max_contour_error_counts must be a number in \[0, 1e\+12\] \[counts\]",
        ),
        ("[bus]\nmax_utilisation_pct = 120\n", r"bus\.max_utilisation_pct must be a number in"),
        ("[clock]\ntolerance_ppm = 20\n", r"the spec sets no limit"),
        ("[margins]\nmax_sensitivity = 0.5\n", r"margins\.max_sensitivity must be"),
        ("[run]\nseed = -1\n[queue]\nmax_overrun_blocks = 0\n", r"run\.seed must be an integer"),
        ("[queue\n", r"is not valid TOML"),
    ],
)
def test_spec_reader_names_the_field(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(SpecError, match=message) as exc:
        load_linkage_spec(_spec(tmp_path, text))
    assert "\n" not in str(exc.value)


def test_example_spec_reads(tmp_path: Path) -> None:
    spec = load_linkage_spec(SPEC)
    assert spec.name == "linkage-6axis" and spec.config == "linkage-6axis"
    assert spec.limits == {
        "max_phase_drift_ticks": 0.75,
        "max_utilisation_pct": 50.0,
        "max_contour_error_counts": 2000.0,
        "max_underrun_ticks": 0,
        "max_overrun_blocks": 0,
        "min_level_setpoints": 5,
        "max_skipped_setpoints": 0,
    }
    assert spec.clock_tolerance_ppm == 20.0 and spec.margins is not None
    assert math.isclose(spec.margins.max_sensitivity, 2.0)


def test_spec_of_another_config_is_refused(verified: Path, tmp_path: Path) -> None:
    spec = _spec(tmp_path, '[spec]\nconfig = "gantry"\n[queue]\nmax_underrun_ticks = 0\n')
    with pytest.raises(
        SpecError,
        match=r"the spec is for config 'gantry', the plan for "
        r"'linkage-6axis'",
    ):
        verify_plan_files(verified, spec, write=False)
