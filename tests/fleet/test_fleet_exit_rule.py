"""``servotune fit LOGS --fleet TABLE``'s exit status (README, "A fleet of machines"): 0 when
at least one log fitted (the failed ones are rows with their error, counted on stderr); 3 and
no table when none did; a log over the memory budget refuses the run before anything is
written."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_fleet import write_fleet_logs

from servotune.cli import main
from servotune.fleet import read_fleet_table


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Path]]:
    """One machine's good log and three bad ones (malformed, empty, missing)."""
    d = tmp_path_factory.mktemp("fleet_exit")
    (good,), _ = write_fleet_logs(d, 1, dates=("2025-03-01",))
    bad = d / "m900_2025-03-01.csv"
    bad.write_text("# machine_id: m900\ntick,time_s\n1,0.0,7\n")
    empty = d / "m901_2025-03-01.csv"
    empty.write_text("")
    return good, [bad, empty, d / "m902_2025-03-01.csv"]


def test_no_log_fitted_exits_3_with_one_line_and_no_table(logs, tmp_path, capsys) -> None:
    _, bad = logs
    out = tmp_path / "fleet.parquet"
    code = main(
        [
            "fit",
            *map(str, bad),
            "--fleet",
            str(out),
            "--fleet-report",
            str(tmp_path / "f.html"),
            "-q",
        ]
    )
    cap = capsys.readouterr()
    assert code == 3 and cap.out == ""
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1, cap.err
    assert lines[0].startswith("servotune fit: error: none of the 3 logs fitted")
    assert "first error: " in lines[0] and "m90" in lines[0]
    assert not out.exists() and not (tmp_path / "f.html").exists()
    assert list(tmp_path.iterdir()) == []  # no temporary file either


def test_one_log_fitted_exits_0_with_the_error_rows(logs, tmp_path, capsys) -> None:
    good, bad = logs
    out = tmp_path / "fleet.csv"
    code = main(["fit", str(good), *map(str, bad), "--fleet", str(out), "--axis", "master"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "3 of 4 logs failed to fit (their rows in the table hold the error)" in err
    rows = {r.file: r for r in read_fleet_table(out)}
    assert len(rows) == 4 and rows[good.name].ok
    for p in bad:
        assert not rows[p.name].ok and p.name in rows[p.name].error


def test_a_tiny_memory_budget_refuses_before_writing(logs, tmp_path, capsys) -> None:
    good, bad = logs
    out = tmp_path / "fleet.parquet"
    code = main(
        [
            "--max-memory",
            "1K",
            "fit",
            str(good),
            *map(str, bad),
            "--fleet",
            str(out),
            "--axis",
            "master",
        ]
    )
    cap = capsys.readouterr()
    assert code == 3 and cap.out == ""
    assert "over the memory budget of 1 KiB" in cap.err
    assert not out.exists() and list(tmp_path.iterdir()) == []
