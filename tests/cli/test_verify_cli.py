"""servotune verify: exit 0 pass, 1 fail (naming the limit), 3 bad input with nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from servotune.cli import main
from servotune.tuning import write_tuning

ROOT = Path(__file__).resolve().parents[2]
RIG = ROOT / "plants" / "pc-dual-servo.toml"
SPEC = ROOT / "plants" / "pc-dual-servo.spec.toml"


@pytest.fixture(scope="module")
def tunings(tmp_path_factory, default_tuning, quick_tuning) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("tunings")
    good, quick = d / "good.json", d / "quick.json"
    write_tuning(default_tuning, good)
    # a two-generation search: too little tuning for the shipped spec's sync-error limit
    write_tuning(quick_tuning, quick)
    return {"good": good, "quick": quick}


def test_passing_tuning_exits_0_and_records(tunings, capsys, tmp_path) -> None:
    rc = main(
        [
            "verify",
            str(tunings["good"]),
            "--spec",
            str(SPEC),
            "--rig",
            str(RIG),
            "--report",
            str(tmp_path / "rep"),
        ]
    )
    cap = capsys.readouterr()
    # the human summary on stderr, stdout left for products (docs/decisions.md#10-output-streams)
    assert rc == 0 and cap.out == "" and "PASSED\nwrote the verification record" in cap.err
    rec = json.loads(Path(str(tunings["good"]) + ".verify.json").read_text())
    assert rec["passed"] is True
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "Verification: PASSED" in page and "data:image/png;base64," in page


def test_failing_tuning_exits_1_naming_the_limit(tunings, capsys) -> None:
    rc = main(["verify", str(tunings["quick"]), "--spec", str(SPEC), "--rig", str(RIG)])
    cap = capsys.readouterr()
    assert rc == 1 and cap.out == ""
    assert "max_sync_error_counts" in cap.err and "FAIL" in cap.err
    # --json: the record on stdout (the product), nothing else there
    rc = main(["verify", str(tunings["quick"]), "--spec", str(SPEC), "--rig", str(RIG), "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert rc == 1 and doc["passed"] is False


def test_bad_inputs_exit_3_one_line_nothing_written(tunings, tmp_path, capsys) -> None:
    bad_spec = tmp_path / "bad.toml"
    bad_spec.write_text(SPEC.read_text() + "\n[scenario.sync.extra]\nfoo = 1\n")
    cases = [
        [str(tmp_path / "missing.json"), "--spec", str(SPEC)],
        [str(tunings["good"]), "--spec", str(tmp_path / "absent.toml")],
        [str(tunings["good"]), "--spec", str(bad_spec), "--rig", str(RIG)],
    ]
    impossible = tmp_path / "impossible.toml"
    impossible.write_text(
        SPEC.read_text().replace("max_sync_error_counts = ", "max_sync_error_counts = -")
    )
    cases.append([str(tunings["good"]), "--spec", str(impossible), "--rig", str(RIG)])
    wrong_schema = tmp_path / "wrong.json"
    wrong_schema.write_text('{"schema": "servotune.tuning/9"}')
    cases.append([str(wrong_schema), "--spec", str(SPEC), "--rig", str(RIG)])
    for args in cases:
        capsys.readouterr()
        assert main(["verify", *args]) == 3, args
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("servotune verify: error:"), err
    assert (
        main(["export-table", str(tmp_path / "missing.json"), "-o", str(tmp_path / "x.json")]) == 3
    )
    assert not (tmp_path / "x.json").exists()
    assert not (tmp_path / "missing.json.verify.json").exists()
    assert not (tmp_path / "wrong.json.verify.json").exists()


def test_export_table_trusts_only_a_passed_verify(tunings, tmp_path, capsys, monkeypatch) -> None:
    from servotune.export.json import load_tables

    good = tmp_path / "good.json"
    good.write_bytes(tunings["good"].read_bytes())
    assert main(["verify", str(good), "--spec", str(SPEC), "--rig", str(RIG)]) == 0
    out = tmp_path / "fuzzy.json"
    assert main(["export-table", str(good), "--rig", str(RIG), "-o", str(out)]) == 0
    assert load_tables(out)["verified"] is True
    # stdout carries the same bytes
    capsys.readouterr()
    assert main(["export-table", str(good), "--rig", str(RIG)]) == 0
    assert capsys.readouterr().out == out.read_text()
    # the quick tuning failed verify: refused, exit 1, nothing written
    refused = tmp_path / "refused.json"
    assert main(["export-table", str(tunings["quick"]), "--rig", str(RIG), "-o", str(refused)]) == 1
    assert "failed its verification" in capsys.readouterr().err and not refused.exists()
    # a tuning changed after its verify is not trusted either
    good.write_text(good.read_text().replace('"seed": 0', '"seed": 1'))
    assert main(["export-table", str(good), "--rig", str(RIG), "-o", str(refused)]) == 1
    # --unverified exports it, marked so
    assert (
        main(["export-table", str(good), "--rig", str(RIG), "-o", str(refused), "--unverified"])
        == 0
    )
    assert load_tables(refused)["verified"] is False
    # no argument: the workbench's current tuning
    wb = tmp_path / "wb"
    wb.mkdir()
    (wb / "tuning.json").write_bytes(tunings["quick"].read_bytes())
    monkeypatch.setenv("SERVOTUNE_WORKBENCH", str(wb))
    capsys.readouterr()
    assert main(["export-table", "--rig", str(RIG), "--unverified"]) == 0
    assert '"verified": false' in capsys.readouterr().out


def test_export_c_compiles(tunings, tmp_path) -> None:
    import shutil
    import subprocess

    good = tmp_path / "good.json"
    good.write_bytes(tunings["good"].read_bytes())
    assert main(["verify", str(good), "--spec", str(SPEC), "--rig", str(RIG)]) == 0
    out = tmp_path / "c"
    assert (
        main(["export-table", str(good), "--rig", str(RIG), "--format", "c", "-o", str(out)]) == 0
    )
    assert {p.name for p in out.iterdir()} == {
        "servotune_tables.h",
        "servotune_rt.c",
        "servotune_rt.h",
        "servotune_filter.h",  # servotune_rt.h includes it (the law's output filters)
    }
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler")
    src = out / "check.c"
    src.write_text(
        '#include "servotune_tables.h"\n#include "servotune_rt.h"\nint main(void){return 0;}\n'
    )
    subprocess.run(
        [
            cc,
            "-std=c99",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-pedantic",
            "-c",
            str(out / "servotune_rt.c"),
            str(src),
        ],
        cwd=tmp_path,
        check=True,
    )


def _frf_file(path: Path) -> Path:
    """A ``servotune frf`` JSON file of the example rig's period: a Schroeder multisine through
    a first-order lag (scipy ``lfilter``), the estimate of servotune.analysis.frf."""
    from scipy import signal

    from servotune.analysis.frf import estimate_frf
    from servotune.excite import periodic_multisine
    from servotune.rig import load_rig

    period = load_rig(RIG).period_s
    ms = periodic_multisine(500, 6, period, 800, band_hz=(1.0, 50.0))
    u = ms.codes * (20.0 / 4096)
    y = np.rint(signal.lfilter([0.0, 50.0], [1.0, -0.9], u))
    frf = estimate_frf(u, y, ms.codes, period_s=period)
    path.write_text(json.dumps(frf.to_dict()))
    return path


def test_frf_options_draw_the_resonance_section(tunings, tmp_path, capsys) -> None:
    f = _frf_file(tmp_path / "frf.json")
    base = ["verify", str(tunings["good"]), "--spec", str(SPEC), "--rig", str(RIG)]
    bad = [
        ["--frf", f"master={f}"],  # no --report
        ["--report", str(tmp_path / "r0"), "--frf", "master"],  # not AXIS=FILE
        ["--report", str(tmp_path / "r0"), "--frf", f"master={tmp_path / 'absent.json'}"],
        ["--report", str(tmp_path / "r0"), "--frf", f"master={RIG}"],  # not an FRF file
    ]
    record = Path(str(tunings["good"]) + ".verify.json")
    record.unlink(missing_ok=True)
    for extra in bad:
        capsys.readouterr()
        assert main([*base, *extra]) == 3, extra
        err = capsys.readouterr().err.strip().splitlines()
        assert (len(err) == 1 and "--frf" in err[0]) or "frf" in err[0].lower(), err
        assert not record.exists()  # refused before the run
    assert main([*base, "--report", str(tmp_path / "rep"), "--frf", f"master={f}"]) == 0
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "Resonance" in page and "within the measured 95 % bounds" in page
