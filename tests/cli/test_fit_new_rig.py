"""One rig per machine, followed through.

``fit -o NEW.toml`` makes a rig of its own (named after the file or ``--name``, its provenance
in the file, the axes it did not fit marked as not fitted, no text about the example machine),
and a tuning made for another rig is refused by ``verify`` with exit 1, naming both rigs.
The oracle is the written file itself, read back as TOML and as a rig.
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from pathlib import Path

import pytest
from test_house import outside_references

from servotune.cli import main
from servotune.identify import logfit
from servotune.logs import LogMetadataWarning
from servotune.rig import load_rig
from servotune.tuning import write_tuning

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "plants" / "pc-dual-servo.toml"


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("fitlog")
    out = d / "my.csv"
    assert (
        main(
            [
                "simulate",
                str(EXAMPLE),
                "--scenario",
                "prbs",
                "--axis",
                "master",
                "--seconds",
                "8",
                "--seed",
                "1",
                "-o",
                str(out),
            ]
        )
        == 0
    )
    return out


def test_fit_o_makes_a_rig_of_its_own(log: Path, tmp_path: Path, capsys) -> None:
    target = tmp_path / "shop-floor-3.toml"
    assert main(["fit", str(log), "--axis", "master", "-o", str(target)]) == 0
    err = capsys.readouterr().err
    assert "wrote a new rig 'shop-floor-3'" in err
    text = target.read_text()
    data = tomllib.loads(text)
    assert data["rig"]["name"] == "shop-floor-3"
    assert "pc-dual-servo" not in data["rig"]["name"]
    # where the numbers come from: the log by name and digest, the method, the adequacy
    sha = hashlib.sha256(log.read_bytes()).hexdigest()[:12]
    header = text.splitlines()[0]
    assert header.startswith("# Rig shop-floor-3: made by `servotune fit -o`") and sha in header
    plant_line = next(ln for ln in text.splitlines() if ln.startswith("[axis.master.plant]"))
    assert "my.csv" in plant_line and sha in plant_line and "adequate:" in plant_line
    # the axis it did not fit says so; nothing speaks of the example machine or its documents
    slave_line = next(ln for ln in text.splitlines() if ln.startswith("[axis.slave.plant]"))
    assert "NOT FITTED" in slave_line
    assert outside_references(text) == [] and "docs/systems.md" not in text
    rig = load_rig(target)
    assert rig.name == "shop-floor-3" and rig.axis("master").plant_fit is not None


def test_fit_o_with_a_rig_starts_from_that_rig(log: Path, tmp_path: Path, capsys) -> None:
    """``fit --rig MINE -o NEW`` takes NEW's hardware facts from MINE, not from the example rig
    (a machine with a 16-bit D/A and its own speed limit keeps them)."""
    text = EXAMPLE.read_text()
    for old, new in (
        ("bits = 12 ", "bits = 16 "),
        ("speed_limit_rpm = 600", "speed_limit_rpm = 450"),
    ):
        assert old in text
        text = text.replace(old, new)
    mine = tmp_path / "mine.toml"
    mine.write_text(text)
    target = tmp_path / "new.toml"
    argv = ["fit", str(log), "--axis", "master", "--rig", str(mine), "-o", str(target)]
    assert main(argv) == 0
    assert "hardware facts are mine.toml's" in capsys.readouterr().err
    rig = load_rig(target)
    assert rig.dac.bits == 16 and rig.axis("slave").speed_limit_rpm == 450
    assert "from the template mine.toml" in tomllib.loads(target.read_text())["rig"]["description"]


def test_fit_o_name_and_an_existing_rig_keeps_its_name(log: Path, tmp_path: Path) -> None:
    target = tmp_path / "r.toml"
    assert main(["fit", str(log), "--axis", "master", "-o", str(target), "--name", "cell-7"]) == 0
    assert load_rig(target).name == "cell-7"
    # fitting again into it (or --name on an existing file) keeps the file's own name
    assert main(["fit", str(log), "--axis", "master", "-o", str(target), "--name", "other"]) == 0
    assert load_rig(target).name == "cell-7"


def test_verify_with_a_tuning_of_another_rig_fails_naming_both(
    log: Path, tmp_path: Path, capsys, quick_tuning
) -> None:
    mine = tmp_path / "myrig.toml"
    assert main(["fit", str(log), "--axis", "master", "-o", str(mine)]) == 0
    tuning = tmp_path / "tuning.json"  # made for the example rig
    write_tuning(quick_tuning, tuning)
    capsys.readouterr()
    code = main(
        [
            "verify",
            str(tuning),
            "--spec",
            str(ROOT / "plants" / "pc-dual-servo.spec.toml"),
            "--rig",
            str(mine),
        ]
    )
    err = capsys.readouterr().err
    assert code == 1, err
    assert "myrig.toml" in err and "'pc-dual-servo'" in err and err.count("\n") == 1
    assert not (tmp_path / "tuning.json.verify.json").exists()


def test_fit_o_without_a_name_for_an_unprefixed_log_stops_before_fitting(
    log: Path, tmp_path: Path, capsys, monkeypatch
) -> None:
    # the master's columns without their prefix (and without the slave's): a one-axis log
    lines = log.read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    cols = lines[head].split(",")
    keep = [i for i, c in enumerate(cols) if not c.startswith("slave.")]
    rows = [",".join(r.split(",")[i] for i in keep) for r in lines[head:]]
    rows[0] = rows[0].replace("master.", "")
    bare = tmp_path / "bare.csv"
    bare.write_text("\n".join(lines[:head] + rows) + "\n")
    plot, rig = tmp_path / "fit.png", tmp_path / "r.toml"
    fits = []
    real_fit = logfit.fit
    monkeypatch.setattr(logfit, "fit", lambda *a, **k: fits.append(1) or real_fit(*a, **k))
    code = main(["fit", str(bare), "--plot", str(plot), "-o", str(rig)])
    err = capsys.readouterr().err
    assert code == 3 and "--axis NAME" in err and err.count("\n") == 1, err
    assert not plot.exists() and not rig.exists()
    assert fits == [], "the refusal came after the fit ran"
    # named, the same log fits and writes
    assert main(["fit", str(bare), "--axis", "x", "-o", str(rig)]) == 3  # no axis x in the rig
    assert main(["fit", str(bare), "--axis", "master", "-o", str(rig)]) == 0
    assert load_rig(rig).axis("master").plant_fit is not None


def test_a_metadata_typo_warns_and_strict_refuses(log: Path, tmp_path: Path, capsys) -> None:
    typo = tmp_path / "typo.csv"
    typo.write_text(log.read_text().replace("# counter_bits: 24", "# counter_bitz: 24", 1))
    with pytest.warns(LogMetadataWarning, match="'counter_bitz' .*did you mean 'counter_bits'"):
        assert main(["fit", str(typo), "--axis", "master"]) == 0
    capsys.readouterr()
    assert main(["fit", str(typo), "--axis", "master", "--strict"]) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "counter_bitz" in err and "--strict" in err


def _plant_lines(text: str, axis: str) -> dict[str, str]:
    """``key -> whole line`` of the ``[axis.<axis>.plant]`` table's entries."""
    lines = text.splitlines()
    start = lines.index(next(ln for ln in lines if ln.startswith(f"[axis.{axis}.plant]")))
    out = {}
    for ln in lines[start + 1 :]:
        if ln.startswith("["):
            break
        if "=" in ln and not ln.startswith("#"):
            out[ln.split("=")[0].strip()] = ln
    return out


def test_fit_o_into_an_existing_rig_drops_the_comments_it_makes_false(
    log: Path, tmp_path: Path, capsys
) -> None:
    # the example rig, with a source cited beside one value and above another, and comments
    # that only name a quantity
    text = EXAMPLE.read_text()
    text = text.replace(
        "tau_s = 0.025\n",
        "# the drive's velocity loop and the load\n"
        "tau_s = 0.025             # from the drive's data sheet\n",
        1,
    )
    text = text.replace(
        "delay_s = 0.0008\n", "# measured with a scope in 2019\ndelay_s = 0.0008\n", 1
    )
    rig = tmp_path / "existing.toml"
    rig.write_text(text)
    before = _plant_lines(text, "master")
    assert "# 600 r/min at 10 V with 12288 counts/rev" in before["gain_cps_per_v"]
    assert "# analog zero drift" in before["offset_v"]

    assert main(["fit", str(log), "--axis", "master", "-o", str(rig), "--json"]) == 0
    fitted = json.loads(capsys.readouterr().out)
    after_text = rig.read_text()
    after = _plant_lines(after_text, "master")
    rewritten = [k for k in before if k in after and after[k] != before[k]]
    assert {"gain_cps_per_v", "tau_s", "delay_s", "offset_v"} <= set(rewritten)
    for key in rewritten:  # no comment left beside a new value states the old one or a source
        old_value = before[key].split("=")[1].split("#")[0].strip()
        comment = after[key].partition("#")[2]
        assert old_value not in comment and not any(c.isdigit() for c in comment), after[key]
        assert "data sheet" not in comment, after[key]
    assert "600 r/min" not in after_text and "data sheet" not in after_text
    assert "measured with a scope" not in after_text
    # the comments that name a quantity survive, as does every comment outside the table
    assert after["offset_v"].endswith("# analog zero drift")
    assert "# the drive's velocity loop and the load\ntau_s = " in after_text
    outside = [
        ln
        for ln in text.splitlines()
        if "#" in ln and "=" in ln and ln.split("=")[0].strip() not in before
    ]
    assert len(outside) > 8 and all(ln in after_text.splitlines() for ln in outside)
    # the header says where the new numbers come from, and the record holds the fit figures
    header = next(ln for ln in after_text.splitlines() if ln.startswith("[axis.master.plant]"))
    assert "fitted by servotune" in header and log.name in header
    record = load_rig(rig).axis("master").plant_fit
    assert record is not None
    for quantity in ("velocity", "position"):
        pct = fitted["fit_pct"][quantity]
        assert getattr(record, f"{quantity}_fit_pct") == pytest.approx(pct["estimation"], 1e-6)
        cv = pct["validation"]  # None on this short log: a half could not be fitted
        assert getattr(record, f"{quantity}_fit_cv_pct") == (
            None if cv is None else pytest.approx(cv, 1e-6)
        )
