"""The verify → export trust chain through the CLI (docs/decisions.md#2-which-rig,
docs/decisions.md#3-digests).

Every hash here is recomputed with hashlib over the files' bytes, never taken from the code under
test; every refusal is checked as a user sees it: exit code, one line on stderr, nothing written.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
from pathlib import Path

import pytest

import servotune.verify.record as record_module
from servotune.cli import main
from servotune.tuning import write_tuning

ROOT = Path(__file__).resolve().parents[2]
RIG = ROOT / "plants" / "pc-dual-servo.toml"
SPEC = ROOT / "plants" / "pc-dual-servo.spec.toml"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def bench(tmp_path_factory, default_tuning, quick_tuning) -> dict[str, Path]:
    """A rig at a path of the user's choosing, a good and a poor tuning of it, a quick spec."""
    d = tmp_path_factory.mktemp("trust")
    rig = d / "my-rig.toml"
    shutil.copyfile(RIG, rig)
    good, poor = d / "good.json", d / "poor.json"
    # the example rig's tunings (same bytes, so the same SHA-256), made for the copy's path as
    # `tune my-rig.toml` records it
    for tuning, path in ((default_tuning, good), (quick_tuning, poor)):
        write_tuning(dataclasses.replace(tuning, rig_path=rig.as_posix()), path)
    spec = d / "quick.spec.toml"
    spec.write_text(SPEC.read_text().replace("count = 64", "count = 2"))
    other = d / "other-rig.toml"  # another rig: a different drift on the master
    other.write_text(RIG.read_text().replace("offset_v = 0.005", "offset_v = 0.006", 1))
    assert other.read_text() != RIG.read_text()
    return {"dir": d, "rig": rig, "good": good, "poor": poor, "spec": spec, "other": other}


def _copy(src: Path, dst: Path) -> Path:
    dst.write_bytes(src.read_bytes())
    return dst


def _err_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) >= 1 and "Traceback" not in "\n".join(err)
    return err[-1]


def test_the_tuning_records_its_rig_and_verify_finds_it(bench, tmp_path, capsys) -> None:
    data = json.loads(bench["good"].read_text())
    assert data["schema"] == "servotune.tuning/2"
    assert data["rig"] == {
        "name": "pc-dual-servo",
        "path": bench["rig"].as_posix(),
        "sha256": _sha(bench["rig"]),
    }
    t = _copy(bench["good"], tmp_path / "t.json")
    # no --rig: the recorded path is used (not plants/pc-dual-servo.toml of the working dir)
    assert main(["verify", str(t), "--spec", str(bench["spec"])]) == 0
    record = json.loads((tmp_path / "t.json.verify.json").read_text())
    assert record["files"]["rig"] == {"name": "my-rig.toml", "sha256": _sha(bench["rig"])}
    assert record["files"]["tuning"]["sha256"] == _sha(t)
    assert record["files"]["spec"]["sha256"] == _sha(bench["spec"])


def test_verify_refuses_another_rig_and_accepts_a_moved_copy(bench, tmp_path, capsys) -> None:
    t = _copy(bench["good"], tmp_path / "t.json")
    capsys.readouterr()
    assert main(["verify", str(t), "--spec", str(bench["spec"]), "--rig", str(bench["other"])]) == 1
    line = _err_line(capsys)
    assert line.startswith("servotune verify: refused: rig file") and "other-rig.toml" in line
    assert not (tmp_path / "t.json.verify.json").exists()
    moved = _copy(bench["rig"], tmp_path / "moved.toml")
    assert main(["verify", str(t), "--spec", str(bench["spec"]), "--rig", str(moved)]) == 0


def test_export_compares_tuning_rig_spec_and_tool_version(bench, tmp_path, capsys) -> None:
    t = _copy(bench["good"], tmp_path / "t.json")
    assert main(["verify", str(t), "--spec", str(bench["spec"])]) == 0
    out = tmp_path / "fuzzy.json"
    # another rig given to export: refused, exit 1, the rig named, nothing written
    capsys.readouterr()
    assert main(["export-table", str(t), "--rig", str(bench["other"]), "-o", str(out)]) == 1
    assert "rig file" in _err_line(capsys) and not out.exists()
    # another spec than the verified one: refused, the spec named
    other_spec = _copy(SPEC, tmp_path / "other.spec.toml")
    assert main(["export-table", str(t), "--spec", str(other_spec), "-o", str(out)]) == 1
    assert "the spec differs from the verified one" in _err_line(capsys) and not out.exists()
    # the verified spec: accepted; the export names the verified bytes
    assert main(["export-table", str(t), "--spec", str(bench["spec"]), "-o", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["verified"] is True and doc["provenance"]["tuning_sha256"] == _sha(t)
    assert doc["provenance"]["spec_sha256"] == _sha(bench["spec"])
    assert doc["provenance"]["rig"]["sha256"] == _sha(bench["rig"])
    # the record edited by hand (passed kept, tool version changed): its digest refuses it
    rec_path = tmp_path / "t.json.verify.json"
    rec = json.loads(rec_path.read_text())
    rec["tool_version"] = "0.0.1"
    rec_path.write_text(json.dumps(rec))
    out.unlink()
    assert main(["export-table", str(t), "-o", str(out)]) == 1
    assert "digest does not match" in _err_line(capsys) and not out.exists()
    # the poor tuning failed verify: refused
    p = _copy(bench["poor"], tmp_path / "p.json")
    assert main(["verify", str(p), "--spec", str(SPEC)]) == 1  # the full spec fails it
    assert main(["export-table", str(p), "-o", str(out)]) == 1
    assert "failed its verification" in _err_line(capsys) and not out.exists()


def test_a_tuning_swapped_during_verify_is_not_recorded_as_verified(
    bench, tmp_path, capsys, monkeypatch
) -> None:
    """Race: between reading the tuning and writing the record, the file is replaced by the
    poor tuning. The record must describe the bytes that were verified (the good ones), so
    the export of the file as it now is gets refused."""
    t = _copy(bench["good"], tmp_path / "t.json")
    good_sha = _sha(t)
    real_verify = record_module.verify

    def swapping_verify(*args, **kwargs):
        t.write_bytes(bench["poor"].read_bytes())  # swapped while verification runs
        return real_verify(*args, **kwargs)

    monkeypatch.setattr(record_module, "verify", swapping_verify)
    assert main(["verify", str(t), "--spec", str(bench["spec"])]) == 0  # the good bytes pass
    record = json.loads((tmp_path / "t.json.verify.json").read_text())
    assert record["files"]["tuning"]["sha256"] == good_sha != _sha(t)
    capsys.readouterr()
    out = tmp_path / "fuzzy.json"
    assert main(["export-table", str(t), "-o", str(out)]) == 1
    assert "the tuning differs from the verified one" in _err_line(capsys) and not out.exists()


def test_an_older_tuning_schema_gets_one_line_and_exit_3(bench, tmp_path, capsys) -> None:
    data = json.loads(bench["good"].read_text())
    data["schema"] = "servotune.tuning/1"
    old = tmp_path / "old.json"
    old.write_text(json.dumps(data))
    capsys.readouterr()
    assert main(["verify", str(old), "--spec", str(bench["spec"])]) == 3
    line = _err_line(capsys)
    assert "written by an older servotune" in line and "re-run `servotune tune`" in line


@pytest.mark.parametrize(
    ("edit", "fragment"),
    [
        (lambda d: d["axes"][0].update(role="boss"), "axes[0].role must be one of master, slave"),
        (lambda d: d["axes"][1]["controller"]["task"].update(n="6"), "task.n must be an integer"),
        (
            lambda d: d["axes"][1]["controller"]["task"]["tables"]["kp"]["q"][0].__setitem__(
                0, 1.7
            ),
            "task.tables.kp.q[0][0] must be an integer, got 1.7",
        ),
        (lambda d: d["axes"][1]["controller"]["task"].update(n=6.0), "task.n must be an integer"),
        (lambda d: d.update(timer_divisor=4773.0), "timer_divisor must be an integer"),
        (lambda d: d.update(perod_s=0.004), "did you mean 'period_s'?"),
        (lambda d: d["rig"].update(sha256="x" * 64), "rig.sha256 must be 64 lower-case hex"),
    ],
)
def test_wrong_tunings_are_refused_before_verification(bench, tmp_path, capsys, edit, fragment):
    data = json.loads(bench["good"].read_text())
    edit(data)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    capsys.readouterr()
    assert main(["verify", str(bad), "--spec", str(bench["spec"])]) == 3
    line = _err_line(capsys)
    assert line.startswith("servotune verify: error:") and fragment in line, line
    assert str(bad) in line
    assert not (tmp_path / "bad.json.verify.json").exists()


def test_n_infinity_in_a_tuning_is_not_json(bench, tmp_path, capsys) -> None:
    text = bench["good"].read_text().replace('"n": 6', '"n": Infinity', 1)
    assert "Infinity" in text
    bad = tmp_path / "inf.json"
    bad.write_text(text)
    capsys.readouterr()
    assert main(["verify", str(bad), "--spec", str(bench["spec"])]) == 3
    assert "Infinity" in _err_line(capsys)


def test_verify_also_records_the_current_tuning_when_it_is_the_same_bytes(
    bench, tmp_path, capsys, monkeypatch
) -> None:
    # `tune -o tuning.json` also writes the workbench's current tuning (a copy); after
    # `verify tuning.json`, `export-table` without a file exports the copy
    monkeypatch.setenv("SERVOTUNE_WORKBENCH", str(tmp_path / "wb"))
    (tmp_path / "wb").mkdir()
    tuning = _copy(bench["good"], tmp_path / "tuning.json")
    current = _copy(bench["good"], tmp_path / "wb" / "tuning.json")
    assert main(["verify", str(tuning), "--spec", str(bench["spec"])]) == 0
    assert (tmp_path / "tuning.json.verify.json").is_file()
    assert (tmp_path / "wb" / "tuning.json.verify.json").read_bytes() == (
        tmp_path / "tuning.json.verify.json"
    ).read_bytes()
    out = tmp_path / "fuzzy.json"
    assert main(["export-table", "-o", str(out)]) == 0 and out.is_file()
    # a current tuning of other bytes gets no record of this one
    (tmp_path / "wb" / "tuning.json.verify.json").unlink()
    _copy(bench["poor"], current)
    assert main(["verify", str(tuning), "--spec", str(bench["spec"])]) == 0
    assert not (tmp_path / "wb" / "tuning.json.verify.json").exists()
    capsys.readouterr()
    assert main(["export-table", "-o", str(out)]) == 1
    assert "has no verification record" in _err_line(capsys)


def _gain_edited(path: Path) -> None:
    """One plant gain changed in ``path`` (the master's), as a user edits a rig file."""
    text = path.read_text()
    edited = text.replace("gain_cps_per_v = 12288.0", "gain_cps_per_v = 12300.0", 1)
    assert edited != text
    path.write_text(edited)


def test_an_edited_recorded_rig_is_refused_not_replaced_by_a_copy_elsewhere(
    bench, default_tuning, tmp_path, capsys
) -> None:
    # the tuning records its rig at a path of the user's; plants/pc-dual-servo.toml of the
    # working directory (and the package's example rig) hold the same, verified bytes
    rig = _copy(RIG, tmp_path / "mine.toml")
    verified = _sha(rig)
    assert _sha(Path("plants") / "pc-dual-servo.toml") == verified
    t = tmp_path / "t.json"
    write_tuning(dataclasses.replace(default_tuning, rig_path=rig.as_posix()), t)
    assert main(["verify", str(t), "--spec", str(bench["spec"])]) == 0
    _gain_edited(rig)
    edited = _sha(rig)
    out = tmp_path / "fuzzy.json"
    capsys.readouterr()
    assert main(["export-table", str(t), "-o", str(out)]) == 1
    line = _err_line(capsys)
    assert line.startswith("servotune export-table: refused: rig file")
    assert str(rig) in line and verified[:12] in line and edited[:12] in line
    assert "verify again, or give the verified file with --rig" in line
    assert not out.exists()
    # verify refuses it too (the tuning was not made for it), one line
    assert main(["verify", str(t), "--spec", str(bench["spec"])]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "changed since the tuning recorded it" in err
    # the verified bytes given: accepted, no note
    copy = _copy(RIG, tmp_path / "verified.toml")
    assert main(["export-table", str(t), "--rig", str(copy), "-o", str(out)]) == 0
    assert "using rig file" not in capsys.readouterr().err


def test_a_recorded_rig_gone_is_found_elsewhere_and_named(
    bench, default_tuning, tmp_path, capsys
) -> None:
    rig = _copy(RIG, tmp_path / "mine.toml")
    t = tmp_path / "t.json"
    write_tuning(dataclasses.replace(default_tuning, rig_path=rig.as_posix()), t)
    assert main(["verify", str(t), "--spec", str(bench["spec"])]) == 0
    rig.rename(tmp_path / "moved-away.toml")  # the recorded path is gone
    out = tmp_path / "fuzzy.json"
    capsys.readouterr()
    assert main(["export-table", str(t), "-o", str(out)]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("using rig")]
    assert len(notes) == 1, notes
    used = Path("plants") / "pc-dual-servo.toml"  # the first place searched after the record
    assert str(used) in notes[0] and str(rig) in notes[0] and "is gone" in notes[0]
    assert json.loads(out.read_text())["provenance"]["rig"]["sha256"] == _sha(RIG)
    # verify says it as well
    assert main(["verify", str(t), "--spec", str(bench["spec"])]) == 0
    assert f"using rig file {used}" in capsys.readouterr().err
