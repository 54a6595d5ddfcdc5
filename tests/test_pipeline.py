"""The demo job (`make demo`): what it writes and that it is deterministic."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import EXAMPLE_RIG

import servotune as st
import servotune.export
from servotune.pipeline import run_demo


def test_demo_writes_its_products(tmp_path: Path) -> None:
    summary = run_demo(EXAMPLE_RIG, tmp_path, seed=0)
    for name in ("demo_summary.json", "lock_hold.png", "track.png", "track_log.csv",
                 "fit_master.png", "fit_slave.png", "fitted-rig.toml", "tuning.json",
                 "tuning.json.verify.json", "figure4.png", "figure4.json", "fuzzy.json",
                 "c/servotune_tables.h", "c/servotune_rt.c", "report.html", "sync.json",
                 "sync_load.png", "sync_mismatch.png", "linkage.json", "linkage_queues.png",
                 "linkage_circle.png"):  # fmt: skip
        assert (tmp_path / name).stat().st_size > 0, name
    # the whole chain: tuned on the fitted rig, verified on the example rig, exported
    assert summary["verification"]["passed"], summary["verification"]["failures"]
    assert st.export.load_tables(tmp_path / "fuzzy.json")["verified"] is True
    page = (tmp_path / "report.html").read_text()
    for section in ("Verification: PASSED", "Loops (Bode", "Query tables", "Identification",
                    "Figure 4", "Gantry with a listening slave", "Multi-CPU linkage"):  # fmt: skip
        assert section in page, section
    assert summary["architectures"]["gantry"]["passed"]
    assert summary["architectures"]["linkage"]["passed"]
    assert json.loads((tmp_path / "sync.json").read_text())["schema"] == "servotune.sync/1"
    table = summary["comparison"]
    assert set(table) == {"pid", "pid_ff", "composite"}
    on_disk = json.loads((tmp_path / "demo_summary.json").read_text())
    assert on_disk["schema"] == "servotune.demo/1"
    for name, hold in summary["lock_hold"].items():
        lo, hi = hold["observed_counts"]
        assert -4 <= lo <= hi <= 4, name  # seed 000: ±1 pulse
    for name, ident in summary["identification"].items():
        for key, err in ident["relative_error"].items():
            assert abs(err) < 0.02, (name, key, err)
    fitted = st.load_rig(tmp_path / "fitted-rig.toml")
    assert fitted.axis("slave").plant.tau_s == pytest.approx(
        summary["identification"]["slave"]["params"]["tau_s"], rel=1e-6
    )
    first = (tmp_path / "demo_summary.json").read_bytes()
    first_tables = (tmp_path / "fuzzy.json").read_bytes()
    run_demo(EXAMPLE_RIG, tmp_path, seed=0)
    assert (tmp_path / "demo_summary.json").read_bytes() == first  # same input + seed → same bytes
    assert (tmp_path / "fuzzy.json").read_bytes() == first_tables


def test_demo_needs_an_existing_directory(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        run_demo(EXAMPLE_RIG, tmp_path / "missing")
