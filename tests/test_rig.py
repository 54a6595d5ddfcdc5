"""Rig files: the example rig and validation messages (field, value, unit)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import EXAMPLE_RIG

import servotune as st
from servotune.cli import main
from servotune.rig import describe_rig


def test_example_rig_facts(rig: st.Rig) -> None:
    f = describe_rig(rig)
    assert f["timer_divisor"] == 4773  # SPEC §1a
    assert f["achieved_period_s"] == pytest.approx(0.004000235, abs=1e-9)  # SPEC §1a
    assert f["period_error_ppm"] == pytest.approx(58.7, abs=0.05)  # SPEC §1a
    assert f["counts_per_rev"] == 12288  # 3072 pulses/rev, x4
    assert f["dac_lsb_mv"] == pytest.approx(4.8828125)  # 20 V / 4096
    assert f["binding_speed_limit"] == "input_frequency"  # 46,875 < 79,995 r/min
    for a in f["axes"].values():
        assert a["speed_limit_ok"]
        assert a["time_to_wrap_at_speed_limit_s"] == pytest.approx(2**24 / 122880)
        assert a["lock_band_within_one_pulse"]
    # issue 2: 600 r/min at 10 V is 12,288 counts/s/V; tau at most ~30 ms; drift about 5 mV
    assert rig.axis("master").plant.gain_cps_per_v == 12288
    assert all(a.plant.tau_s <= 0.030 for a in rig.axes)
    assert rig.axis("master").plant != rig.axis("slave").plant


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "rig.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("period_s = 0.004 ", "period_s = -0.004 ",
         r"timer.period_s must be a number > 0 \[s\], got -0.004"),
        ("period_s = 0.004 ", "period_s = 1.0 ", r"timer.period_s.*divisor outside 2..65536"),
        ("bits = 24", "bits = 20", "counter.bits must be 16, 24 or 32, got 20"),
        ("multiplier = 4", "multiplier = 3", "counter.multiplier must be 1, 2 or 4, got 3"),
        ("tau_s = 0.025", "tau_s = 0", r"axis.master.plant.tau_s must be > 0 \[s\], got 0"),
        ("tau_s = 0.025", "tau_sec = 0.025", "unknown key axis.master.plant.tau_sec"),
        ('role = "slave"', 'role = "follower"', "axis.slave.role must be 'master' or 'slave'"),
        ("counter_init = 0xFFC000", "counter_init = 0x1FFC000",
         "axis.master.counter_init must fit"),
        ("pulses_per_rev = 3072", "pulses_per_rev = -3072",
         r"encoder.pulses_per_rev must be a number > 0 \[pulses/rev\]"),
        ("range_v = [-10.0, 10.0]", "range_v = [10.0, -10.0]",
         r"dac.range_v must be \[low, high\]"),
    ],
)  # fmt: skip
def test_rig_errors_name_field_value_unit(tmp_path: Path, old: str, new: str, message: str) -> None:
    text = EXAMPLE_RIG.read_text()
    assert old in text
    p = _write(tmp_path, text.replace(old, new, 1))
    with pytest.raises(st.RigError, match=message):
        st.load_rig(p)


def test_missing_table_and_bad_toml(tmp_path: Path) -> None:
    with pytest.raises(st.RigError, match=r"missing table \[timer\]"):
        st.load_rig(_write(tmp_path, "[counter]\nbits = 24\n"))
    with pytest.raises(st.RigError, match="not valid TOML"):
        st.load_rig(_write(tmp_path, "[timer\n"))
    with pytest.raises(st.RigError, match="cannot read rig file"):
        st.load_rig(tmp_path / "nope.toml")


def test_cli_rig_text_and_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["rig", str(EXAMPLE_RIG), "--json"]) == 0
    facts = json.loads(capsys.readouterr().out)
    assert facts["timer_divisor"] == 4773
    assert main(["rig", str(EXAMPLE_RIG)]) == 0
    out = capsys.readouterr().out
    assert "4.000235 ms (+58.7 ppm" in out
    assert "lock holding band" in out


def test_cli_rig_bad_file_is_one_line_exit_3(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    p = _write(tmp_path, EXAMPLE_RIG.read_text().replace("tau_s = 0.025", "tau_s = -1", 1))
    assert main(["rig", str(p)]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "axis.master.plant.tau_s" in err and "Traceback" not in err
