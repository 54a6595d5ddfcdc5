"""The gantry through the whole chain: ``tune`` → ``verify`` → ``export-table``
as a user runs them, what verify catches, and the trust chain to the export.

Oracles that are not the code under test: the tuning file's integers read as plain JSON; the
drive loop's phase margin rebuilt with python-control's own ``pade``/``c2d``/``stability_margins``
from those integers (``q·2^-f``); the export's constants compared with the tuning file's bytes.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import warnings
from pathlib import Path

import control
import numpy as np
import pytest

from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.run import simulate_gantry
from servotune.arch.gantry.tuning import apply_tuning, read_gantry_tuning
from servotune.cli import main
from servotune.errors import DigestError
from servotune.export.gantry import check_gantry_tables

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    """A workspace with the example gantry, its rig and spec, tuned once (``tune -o``)."""
    d = tmp_path_factory.mktemp("gantry")
    for name in ("gantry.toml", "gantry.spec.toml", "pc-dual-servo.toml"):
        shutil.copy(ROOT / "plants" / name, d / name)
    assert main(["tune", str(d / "gantry.toml"), "-o", str(d / "g.json"), "--no-current"]) == 0
    return d


def _verify(work: Path, tuning: Path, spec: Path | None = None, *extra: str) -> int:
    spec = spec or work / "gantry.spec.toml"
    return main(["verify", str(tuning), "--spec", str(spec), "--montecarlo", "8", *extra])


def _copy(work: Path, name: str, edit=None) -> Path:
    """A copy of the tuning (edited by ``edit`` on its JSON) and no record."""
    doc = json.loads((work / "g.json").read_text())
    if edit is not None:
        edit(doc)
    p = work / name
    p.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    return p


def test_tune_verify_export_as_a_user_runs_them(work: Path, capsys, tmp_path: Path) -> None:
    tuning = _copy(work, "user.json")
    capsys.readouterr()
    assert _verify(work, tuning) == 0
    err = capsys.readouterr().err
    assert "\nPASS\n" in err and (work / "user.json.verify.json").is_file()
    # JSON on stdout, nothing else there
    assert main(["export-table", str(tuning)]) == 0
    out, err = capsys.readouterr()
    doc = check_gantry_tables(out)
    assert doc["verified"] is True
    raw = json.loads(tuning.read_text())
    assert doc["data"]["sync"]["constants"] == raw["sync"]["constants"]
    assert [d["controller"] for d in doc["data"]["drives"]] == [
        raw["drives"]["master"],
        raw["drives"]["slave"],
    ]
    assert (
        doc["provenance"]["tuning_sha256"]
        == __import__("hashlib").sha256(tuning.read_bytes()).hexdigest()
    )
    # the C export carries the same integers into st_sync_consts_t / the drives' constants
    cdir = tmp_path / "c"
    assert main(["export-table", str(tuning), "--format", "c", "-o", str(cdir)]) == 0
    header = (cdir / "servotune_gantry_consts.h").read_text()
    k = raw["sync"]["constants"]
    assert f"#define ST_GANTRY_SYNC_KP_Q INT32_C({k['kp']['q']})" in header
    assert f"#define ST_GANTRY_SYNC_KIT_Q INT32_C({k['ki_t']['q']})" in header
    assert f"#define ST_GANTRY_SYNC_TRIP {raw['sync']['trip_counts']}" in header
    assert f"#define ST_MASTER_KP_Q INT32_C({raw['drives']['master']['task']['kp']['q']})" in header
    assert f'#define ST_GANTRY_SHA256 "{doc["data"]["c_layout_sha256"]}"' in header
    for name in ("servotune_gantry.c", "servotune_gantry.h", "servotune_rt.c", "servotune_rt.h"):
        assert (cdir / name).is_file()


def test_an_edited_export_is_refused_by_its_digest(work: Path, capsys) -> None:
    tuning = _copy(work, "digest.json")
    assert _verify(work, tuning) == 0
    capsys.readouterr()
    assert main(["export-table", str(tuning)]) == 0
    text = capsys.readouterr().out
    check_gantry_tables(text)
    edited = re.sub(r'"trip_counts": \d+', '"trip_counts": 1999', text, count=1)
    assert edited != text
    with pytest.raises(DigestError, match="sha256 does not match"):
        check_gantry_tables(edited)
    # the same through the CLI, as a user checks a file
    (work / "ok.json").write_text(text)
    (work / "edited.json").write_text(edited)
    assert main(["check-table", str(work / "ok.json")]) == 0
    assert "both digests match" in capsys.readouterr().err
    assert main(["check-table", str(work / "edited.json")]) == 1
    assert "does not match its content" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("case", "edit", "named"),
    [
        # a compensator gain tripled by hand: the sync loop loses its margins
        (
            "sync gain",
            lambda d: d["sync"]["constants"]["kp"].update(
                q=d["sync"]["constants"]["kp"]["q"] * 3 // 2,
                f=d["sync"]["constants"]["kp"]["f"] - 1,
            ),
            "margins: the sync loop",
        ),
        # a trip threshold raised above the beam's skew limit (spec: 2000 counts)
        (
            "trip",
            lambda d: d["sync"].update(trip_counts=2500),
            "trip threshold: below the skew limit 2500 counts",
        ),
        # a drive's integral gain ×64
        (
            "drive",
            lambda d: d["drives"]["slave"]["task"]["ki_t"].update(
                f=d["drives"]["slave"]["task"]["ki_t"]["f"] - 6
            ),
            "margins: the slave's drive loop",
        ),
    ],
)
def test_a_tuning_edited_by_hand_fails_verify(work, capsys, case, edit, named) -> None:
    tuning = _copy(work, f"edited-{case.replace(' ', '-')}.json", edit)
    capsys.readouterr()
    assert _verify(work, tuning) == 1, case
    err = capsys.readouterr().err
    assert named in err, err[-600:]
    # and what failed verify is not exported
    assert main(["export-table", str(tuning)]) == 1
    assert "failed its verification" in capsys.readouterr().err


def test_one_cycle_more_bus_latency_than_verified_fails_naming_loop_and_margin(
    work: Path, capsys
) -> None:
    tuning = _copy(work, "latency.json")
    spec = work / "latency2.spec.toml"
    text = (work / "gantry.spec.toml").read_text()
    spec.write_text(re.sub(r"(?m)^latency_cycles = 1", "latency_cycles = 2", text))
    capsys.readouterr()
    assert _verify(work, tuning, spec) == 1
    err = capsys.readouterr().err
    assert "margins: the sync loop on plant gain+,tau++1cycle: PM 44." in err
    assert "bus latency: the bus's = the runtime's delay line 2 cycles (limit == 1)" in err
    # at the latency it was tuned for it passes
    assert _verify(work, tuning) == 0


def test_a_changed_gantry_or_tuning_is_refused(work: Path, capsys) -> None:
    tuning = _copy(work, "trust.json")
    assert _verify(work, tuning) == 0
    # the tuning edited after verify: export refuses, naming the tuning
    doc = json.loads(tuning.read_text())
    doc["sync"]["warn_counts"] = 301
    tuning.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    capsys.readouterr()
    assert main(["export-table", str(tuning)]) == 1
    assert "the tuning differs from the verified one" in capsys.readouterr().err
    # another gantry config than the one tuned: verify refuses, naming both hashes
    other = work / "other.toml"
    other.write_text(
        (work / "gantry.toml").read_text().replace("jitter_s = 1e-6", "jitter_s = 2e-6")
    )
    assert _verify(work, work / "g.json", None, "--config", str(other)) == 1
    err = capsys.readouterr().err
    assert "is not the gantry the tuning was made for" in err and err.count("\n") == 1


def test_single_rig_options_are_refused_for_a_gantry(work: Path, capsys) -> None:
    assert main(["tune", str(work / "gantry.toml"), "--generations", "3"]) == 3
    assert "--generations tunes a single rig" in capsys.readouterr().err
    assert (
        main(
            [
                "verify",
                str(work / "g.json"),
                "--spec",
                str(work / "gantry.spec.toml"),
                "--rig",
                str(work / "pc-dual-servo.toml"),
            ]
        )
        == 3
    )
    assert "--rig is for a single rig's tuning" in capsys.readouterr().err


def _pm_independent(plant, kp: float, ki_t: float, dt: float, lag_s: float, lsb: float) -> float:
    """The drive loop's phase margin from python-control's primitives (Padé lag, ZOH c2d)."""
    g = control.tf([plant.gain_cps_per_v], [plant.tau_s, 1.0, 0.0])
    num, den = control.pade(lag_s, 6)
    p = control.c2d(g * control.tf(num, den), dt, method="zoh") * lsb
    z = control.tf([1.0, 0.0], [1.0], dt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return float(control.stability_margins((kp + ki_t * z / (z - 1)) * p)[1])


def test_verify_takes_the_margins_of_the_integers_that_run(work: Path, capsys) -> None:
    # the slave's Ki·T divided by 4 by hand: the margin verify reports is the one of those
    # integers (rebuilt here from the file's q·2^-f), not of the designed gains
    def quarter(d):
        d["drives"]["slave"]["task"]["ki_t"]["q"] //= 4

    tuning = _copy(work, "quarter.json", quarter)
    capsys.readouterr()
    assert main(
        [
            "verify",
            str(tuning),
            "--spec",
            str(work / "gantry.spec.toml"),
            "--montecarlo",
            "0",
            "--json",
        ]
    ) in (0, 1)
    record = json.loads(capsys.readouterr().out)
    rows = {r["subject"]: r for r in record["verification"]["rows"]}
    row = rows["the slave's drive loop, phase margin"]
    raw = json.loads(tuning.read_text())["drives"]["slave"]["task"]
    kp = raw["kp"]["q"] * 2.0 ** -raw["kp"]["f"]
    ki_t = raw["ki_t"]["q"] * 2.0 ** -raw["ki_t"]["f"]
    cfg = load_gantry(work / "gantry.toml")
    corner = row["detail"].removeprefix("plant ")
    assert corner == "gain+,tau++1cycle"
    plant = cfg.slave.plant
    plant = type(plant)(
        **{
            **{f: getattr(plant, f) for f in plant.__dataclass_fields__},
            "gain_cps_per_v": plant.gain_cps_per_v * 1.2,
            "tau_s": plant.tau_s * 1.3,
        }
    )
    lag = cfg.bus.compute_s + plant.delay_s + cfg.bus.cycle_s
    pm = _pm_independent(plant, kp, ki_t, cfg.bus.cycle_s, lag, cfg.rig.dac.lsb_v)
    assert math.isclose(row["value"], pm, abs_tol=0.5), (row["value"], pm)
    designed = json.loads((work / "g.json").read_text())["design"]["worst_margins"]["slave"]
    assert row["value"] > designed["phase_margin_deg"] + 1.0  # less integral: more phase


def test_the_config_runs_the_tunings_integers(work: Path) -> None:
    tuning = read_gantry_tuning(work / "g.json")
    cfg = load_gantry(work / "gantry.toml")
    run = apply_tuning(cfg, tuning)
    assert run.controllers() == tuning.drives and run.sync_constants == tuning.sync
    # a hand-edited compensator constant reaches the bit-true loop
    from dataclasses import replace

    from servotune.fixed import Fixed

    k = tuning.sync
    edited = replace(tuning, sync=replace(k, kp=Fixed(q=k.kp.q // 2, f=k.kp.f)))
    a = simulate_gantry(run, case="mismatch")
    b = simulate_gantry(apply_tuning(cfg, edited), case="mismatch")
    assert not np.array_equal(a.sync_comp, b.sync_comp)


def _own_gantry(tmp_path: Path) -> tuple[Path, Path]:
    """A gantry config (and its rig) at a path of the user's, tuned; the working directory's
    plants/gantry.toml holds the same bytes."""
    d = tmp_path / "mine"
    d.mkdir()
    for name in ("gantry.toml", "pc-dual-servo.toml"):
        shutil.copy(ROOT / "plants" / name, d / name)
    tuning = tmp_path / "g.json"
    assert main(["tune", str(d / "gantry.toml"), "-o", str(tuning), "--no-current"]) == 0
    return d / "gantry.toml", tuning


def test_an_edited_recorded_gantry_is_refused_a_gone_one_found_and_named(
    work: Path, capsys, tmp_path: Path
) -> None:
    import hashlib

    config, tuning = _own_gantry(tmp_path)
    verified = hashlib.sha256(config.read_bytes()).hexdigest()
    assert hashlib.sha256(Path("plants/gantry.toml").read_bytes()).hexdigest() == verified
    assert _verify(work, tuning) == 0
    text = config.read_text()
    config.write_text(text.replace("gain_cps_per_v = 12288.0", "gain_cps_per_v = 12300.0", 1))
    edited = hashlib.sha256(config.read_bytes()).hexdigest()
    assert edited != verified
    out = tmp_path / "tables.json"
    capsys.readouterr()
    assert main(["export-table", str(tuning), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "refused: gantry file" in err, err
    assert str(config) in err and verified[:12] in err and edited[:12] in err
    assert "verify again, or give the verified file with --config" in err
    assert not out.exists()
    # the recorded config gone: plants/gantry.toml (the verified bytes) is used, and named
    config.unlink()
    assert main(["export-table", str(tuning), "-o", str(out)]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("using gantry")]
    assert len(notes) == 1 and "plants/gantry.toml" in notes[0] and str(config) in notes[0]
    assert out.is_file()
