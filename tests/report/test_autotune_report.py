"""The live autotune run's report (servotune.report.autotune): what it states follows the record
and the captures it is given — built here by hand, not by a run (tests/hal/test_autotune_live.py
checks a real run's)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from servotune.report.autotune import autotune_report_html, write_autotune_report


def _record(out: Path, **changes) -> None:
    doc = {
        "schema": "servotune.autotune/1",
        "servotune": "0.test",
        "status": "loaded",
        "stopped": "",
        "period_s": 0.004,
        "position_scale": 2000.0,
        "capture_channels": ["feedback", "volts", "command", "excitation", "overruns", "fault"],
        "files_sha256": {"capture.txt": "ab" * 32},
        "previous": {"pid.0.Pgain": "2.5"},
        "loaded": {"Pgain": 2.17, "Igain": 7.35},
        "wiring_check": {
            "volts": 0.33,
            "expected_counts": 400.0,
            "up_counts": 423.0,
            "down_counts": -365.0,
            "ratio": 0.985,
        },
        "fit": {"params": {"gain_cps_per_v": 12287.3, "tau_s": 0.025}, "velocity_fit_pct": 98.5},
        "validation": {
            "measured": {"following_error": 233.4, "overshoot": 227.0},
            "predicted": {"following_error": 233.7, "overshoot": 228.0},
            "tolerance": {"following_error": [0.25, 5.0], "overshoot": [0.25, 5.0]},
            "passed": True,
            "problems": [],
        },
        "seconds": {"machine_s": 11.5, "total_s": 82.7},
    }
    doc.update(changes)
    (out / "autotune.json").write_text(json.dumps(doc))


def _captures(out: Path, trip_at: int | None = None) -> None:
    n = 200
    rec = np.zeros((n, 7))
    rec[:, 0] = np.arange(n)
    rec[:, 4] = 0.3 * np.sin(np.arange(n) / 5)
    rec[:, 2] = rec[:, 4]
    rec[:, 1] = np.cumsum(rec[:, 2]) * 1e-3
    if trip_at is not None:
        rec[trip_at:, 6] = 1
        rec[trip_at:, 2] = 0
    for name in ("wiring-check.txt", "experiment.txt"):
        np.savetxt(out / name, rec, fmt="%.6f")
    t = np.arange(n) * 0.004
    cmd = np.minimum(t, 0.4) * 1000
    np.savetxt(
        out / "validation.csv",
        np.column_stack([t, cmd, cmd - 3, cmd - 2]),
        delimiter=",",
        header="time_s,command_counts,measured_counts,predicted_counts",
        comments="",
        fmt="%.6f",
    )


def test_a_loaded_run_states_its_numbers(tmp_path: Path) -> None:
    _record(tmp_path)
    _captures(tmp_path)
    page = write_autotune_report(tmp_path).read_text()
    assert "servotune autotune: loaded and validated" in page
    assert "233.4" in page and "233.7" in page and "12287.3" in page
    assert "ab" * 32 in page
    assert page.count("<img") == 3  # wiring check, experiment, validation move


def test_the_fitted_modes_are_stated(tmp_path: Path) -> None:
    fit = {"params": {"gain_cps_per_v": 12279.0}, "velocity_fit_pct": 97.9}
    _record(tmp_path, fit={**fit, "modes": []})
    _captures(tmp_path)
    rigid = autotune_report_html(tmp_path)
    mode = {"freq_hz": 35.0012, "damping": 0.03999, "gain": 0.4999}
    _record(tmp_path, fit={**fit, "modes": [mode]})
    resonant = autotune_report_html(tmp_path)
    assert "mode 1" not in rigid
    assert "mode 1" in resonant and "35.0012" in resonant and "0.03999" in resonant


def test_the_statement_follows_the_record(tmp_path: Path) -> None:
    _record(tmp_path)
    _captures(tmp_path)
    loaded = autotune_report_html(tmp_path)
    reason = "the guard tripped on following error (812 counts) 3.1 s into the experiment"
    _record(tmp_path, status="stopped", stopped=reason, validation={}, loaded={})
    (tmp_path / "validation.csv").unlink()
    stopped = autotune_report_html(tmp_path)
    assert "loaded and validated" in loaded and "loaded and validated" not in stopped
    assert f"stopped: {reason}" in stopped
    assert "233.4" in loaded and "233.4" not in stopped
    # another measured number: the table says it
    other = {
        "measured": {"following_error": 999.5, "overshoot": 1.0},
        "predicted": {"following_error": 233.7, "overshoot": 228.0},
        "tolerance": {"following_error": [0.25, 5.0], "overshoot": [0.25, 5.0]},
        "passed": False,
        "problems": ["following error"],
    }
    _record(tmp_path, validation=other)
    assert "999.5" in autotune_report_html(tmp_path)
