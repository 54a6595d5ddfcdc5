"""servotune tune (CLI and tune_rig), computed live (Figure 4: tests/tune/test_compare.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import servotune as st
from servotune.cli import main
from servotune.fuzzy import check_default_properties
from servotune.laws.fuzzy_pid import TABLE_NAMES
from servotune.tune.slave import SlaveTuneSpec
from servotune.tune.workflow import tune_rig
from servotune.tuning import read_tuning

RIG = Path(__file__).resolve().parents[2] / "plants" / "pc-dual-servo.toml"
FAST = ["--generations", "3", "--population", "6", "--max-overshoot-pct", "300"]


def test_cli_tune_writes_file_and_current_tuning(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setenv("SERVOTUNE_WORKBENCH", str(tmp_path / "wb"))
    out = tmp_path / "tuning.json"
    assert main(["tune", str(RIG), "-o", str(out), *FAST]) == 0
    err = capsys.readouterr().err
    assert "generation 3/3" in err  # progress on stderr
    current = tmp_path / "wb" / "tuning.json"
    assert current.read_bytes() == out.read_bytes()
    t = read_tuning(out)
    rig = st.load_rig(RIG)
    assert t.controller("master").law == 1 and t.controller("slave").law == 2
    # docs/runtime.md#timer-and-achieved-period
    assert t.period_s == rig.period_s and t.timer_divisor == 4773
    prov = t.provenance
    assert prov["seed"] == 0 and prov["tool_version"] == st.__version__
    assert len(prov["rig_sha256"]) == 64
    # same rig, options and seed: the same bytes
    again = tmp_path / "again.json"
    assert main(["tune", str(RIG), "-o", str(again), "--no-current", *FAST]) == 0
    assert again.read_bytes() == out.read_bytes()


def test_cli_tune_to_stdout(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setenv("SERVOTUNE_WORKBENCH", str(tmp_path / "wb"))
    assert main(["tune", str(RIG), "--no-current", *FAST]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["schema"] == "servotune.tuning/2"
    assert not (tmp_path / "wb").exists()


def test_cli_tune_bad_input_one_line(tmp_path, capsys) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[timer]\nperiod_s = -1\n")
    out = tmp_path / "t.json"
    assert main(["tune", str(bad), "-o", str(out), "--no-current"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("servotune tune: error:")
    assert not out.exists()


def test_impossible_tuning_spec_is_refused(tmp_path) -> None:
    spec = SlaveTuneSpec(generations=1, population=6, max_overshoot_pct=0.0, max_saturation_pct=0.0)
    with pytest.raises(st.SpecError, match="no slave tuning met the constraints"):
        tune_rig(RIG, spec=spec)


def test_cli_tuning_that_fails_its_spec_exits_1_writing_nothing(tmp_path, capsys) -> None:
    # exit 1 is "a verification or tuning failed its spec"; 3 is bad input
    out = tmp_path / "t.json"
    budget = ["--generations", "1", "--population", "6"]
    limits = ["--max-overshoot-pct", "0", "--max-saturation-pct", "0"]
    args = ["tune", str(RIG), "-o", str(out), "--no-current", *budget, *limits]
    assert main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("servotune tune: failed: no slave tuning met the constraints")
    assert "Traceback" not in "\n".join(err) and not out.exists()


def test_tuned_tables_keep_the_default_properties(tmp_path) -> None:
    # the int16 tables the runtime gets (ΔKp, ΔKi·T, ...) keep the rule base's properties
    t = tune_rig(RIG, spec=SlaveTuneSpec(generations=2, population=6, max_overshoot_pct=300.0))
    k = t.controller("slave").task
    tables = {name: q for name, (q, _) in zip(TABLE_NAMES, k.tables, strict=True)}
    assert check_default_properties(tables) == []
    assert np.all(tables["k1"] == 0)  # K1 = its base (the feedforward) over the whole table


def test_a_shaper_for_a_master_without_modes_is_one_line(tmp_path, capsys) -> None:
    """``tune --shaper`` on a rig whose master has no modes: refused before any work, one line
    naming the option and the axis, no file."""
    out = tmp_path / "t.json"
    assert main(["tune", str(RIG), "--shaper", "zvd", "-o", str(out), "--no-current"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) <= 2 and "--shaper" in err[-1] and "'master' has no modes" in err[-1]
    assert "Traceback" not in "\n".join(err) and not out.exists()
