"""The linkage through the chain as a user runs it: ``servotune plan`` →
``verify`` → ``export-table`` (JSON and C), a plan edited by hand failing verify and then
refused by the export, and the verbs' refusals. The library behind the verbs is tested in
``test_plan.py`` and ``tests/export/test_c_linkage.py``; here the oracle is the plan file's own
bytes (the export must carry exactly its integers).
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
from pathlib import Path

import pytest

from servotune.cli import main

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """The example linkage, its rig and a spec that runs 4 s (the plumbing, not the machine:
    the full run is verified in test_plan.py), planned once."""
    d = tmp_path_factory.mktemp("linkage")
    for name in ("linkage-6axis.toml", "pc-dual-servo.toml"):
        shutil.copy(ROOT / "plants" / name, d / name)
    spec = (ROOT / "plants" / "linkage-6axis.spec.toml").read_text()
    (d / "short.spec.toml").write_text(spec.replace("seed = 0 ", "seed = 0\nseconds = 4.0 ", 1))
    assert main(["plan", str(d / "linkage-6axis.toml"), "-o", str(d / "plan.json")]) == 0
    return d


def _spec(work: Path) -> str:
    return str(work / "short.spec.toml")


def test_plan_verify_export_as_a_user_runs_them(work: Path, capsys, tmp_path: Path) -> None:
    plan = work / "plan.json"
    capsys.readouterr()
    assert main(["verify", str(plan), "--spec", _spec(work)]) == 0
    err = capsys.readouterr().err
    assert "\nPASS\n" in err and (work / "plan.json.verify.json").is_file()
    assert main(["export-table", str(plan)]) == 0
    out, err = capsys.readouterr()
    doc = json.loads(out)  # stdout holds the JSON only
    raw = json.loads(plan.read_text())
    assert doc["verified"] is True
    assert hashlib.sha256(plan.read_bytes()).hexdigest() in out
    text = json.dumps(doc)
    for cpu in raw["cpus"]:  # the plan's queue depths and watermarks travel unchanged
        assert str(cpu["queue_depth"]) in text
    cdir = tmp_path / "c"
    assert main(["export-table", str(plan), "--format", "c", "-o", str(cdir)]) == 0
    header = (cdir / "servotune_link_plan.h").read_text()
    assert "#define STL_PLAN_VERIFIED 1" in header
    assert f"#define STL_RESYNC_TICKS {raw['clock']['resync_interval_ticks']}" in header
    kp = raw["axes"][0]["controller"]["task"]["kp"]["q"]
    assert re.search(rf"STL_AXIS_{raw['axes'][0]['name'].upper()}_KP_Q .*{kp}", header), kp


def test_a_plan_edited_by_hand_fails_verify_and_is_not_exported(work: Path, capsys) -> None:
    doc = json.loads((work / "plan.json").read_text())
    doc["axes"][0]["controller"]["task"]["kp"]["f"] -= 2  # x's Kp ×4
    edited = work / "edited.json"
    edited.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    capsys.readouterr()
    assert main(["verify", str(edited), "--spec", _spec(work)]) == 1
    err = capsys.readouterr().err
    assert "phase_margin:x" in err and "FAIL" in err
    assert main(["export-table", str(edited)]) == 1
    assert "failed its verification (" in capsys.readouterr().err


def test_the_verbs_refuse_what_does_not_apply(work: Path, capsys) -> None:
    assert main(["tune", str(work / "linkage-6axis.toml")]) == 3
    assert "is a linkage config: plan it with `servotune plan" in capsys.readouterr().err
    assert (
        main(["verify", str(work / "plan.json"), "--spec", _spec(work), "--montecarlo", "5"]) == 3
    )
    assert "--montecarlo is for a single rig's tuning" in capsys.readouterr().err
    assert main(["plan", str(work / "pc-dual-servo.toml")]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error" in err


def test_an_edited_recorded_config_is_refused_a_gone_one_found_and_named(
    work: Path, capsys, tmp_path: Path
) -> None:
    # the plan records its config in cfg/; a copy of the same bytes lies beside the plan
    cfg = tmp_path / "cfg"
    cfg.mkdir()
    for name in ("linkage-6axis.toml", "pc-dual-servo.toml"):
        shutil.copy(ROOT / "plants" / name, cfg / name)
    config = cfg / "linkage-6axis.toml"
    shutil.copy(config, tmp_path / "linkage-6axis.toml")
    plan = tmp_path / "plan.json"
    assert main(["plan", str(config), "-o", str(plan)]) == 0
    assert main(["verify", str(plan), "--spec", _spec(work)]) == 0
    verified = hashlib.sha256(config.read_bytes()).hexdigest()
    text = config.read_text()
    config.write_text(text.replace("gain_cps_per_v = 12288.0", "gain_cps_per_v = 12300.0", 1))
    edited = hashlib.sha256(config.read_bytes()).hexdigest()
    assert edited != verified
    out = tmp_path / "export.json"
    capsys.readouterr()
    assert main(["export-table", str(plan), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "refused: config file" in err, err
    assert str(config) in err and verified[:12] in err and edited[:12] in err
    assert "verify again, or give the verified file with --config" in err
    assert not out.exists()
    # the verified bytes given with --config: accepted
    assert (
        main(
            [
                "export-table",
                str(plan),
                "--config",
                str(tmp_path / "linkage-6axis.toml"),
                "-o",
                str(out),
            ]
        )
        == 0
    )
    out.unlink()
    # the recorded config gone: the copy beside the plan is used, and named
    config.unlink()
    capsys.readouterr()
    assert main(["export-table", str(plan), "-o", str(out)]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("using config")]
    assert len(notes) == 1 and str(tmp_path / "linkage-6axis.toml") in notes[0], notes
    assert str(config) in notes[0] and out.is_file()
