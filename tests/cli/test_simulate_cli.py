"""`servotune simulate`: logs of the virtual rig (docs/formats.md#log-file), determinism and bad
input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLE_RIG

import servotune as st
from servotune.cli import main
from servotune.logs import read_log


def _sim(tmp_path: Path, *extra: str, name: str = "log.csv") -> Path:
    out = tmp_path / name
    args = ["simulate", str(EXAMPLE_RIG), "--seconds", "3", "--seed", "4", "-o", str(out), *extra]
    assert main(args) == 0
    return out


@pytest.mark.parametrize("scenario", ["prbs", "steps", "chirp", "track"])
def test_scenarios_write_readable_logs(tmp_path: Path, scenario: str) -> None:
    out = _sim(tmp_path, "--scenario", scenario)
    log = read_log(out)
    assert log.metadata["rig"] == "pc-dual-servo"
    assert log.metadata["scenario"] == scenario
    assert log.period_s == pytest.approx(0.0040002346670242545, rel=1e-15)
    assert set(log.axes) == {"master", "slave"}
    m = log.axis("master")
    assert m.dac_code is not None and m.counter is not None
    assert m.counter_faults.size == 0
    assert log.n_samples == 750  # 3 s / 4.000235 ms, rounded
    moved = np.ptp(m.pos_counts)
    assert moved > 50, f"{scenario}: the master should move, moved {moved}"


def test_excitation_reverses_and_open_loop_vs_closed_loop(tmp_path: Path) -> None:
    open_log = read_log(_sim(tmp_path, "--scenario", "prbs", name="o.csv")).axis("master")
    closed = read_log(_sim(tmp_path, "--scenario", "prbs", "--closed-loop", name="c.csv"))
    c = closed.axis("master")
    v = np.diff(open_log.pos_counts)
    assert np.any(v > 5) and np.any(v < -5)  # direction reversals
    assert set(np.unique(open_log.mode)) == {0, 2}  # lock lead-in, then open loop
    assert set(np.unique(c.mode)) == {0}  # lock module active throughout
    # with the lock active the axis stays closer to home
    assert np.ptp(c.pos_counts) < np.ptp(open_log.pos_counts)


def test_log_matches_engine_and_is_deterministic(tmp_path: Path, rig: st.Rig) -> None:
    a = _sim(tmp_path, "--scenario", "track", name="a.csv")
    b = _sim(tmp_path, "--scenario", "track", name="b.csv")
    assert a.read_bytes() == b.read_bytes()
    log = read_log(a)
    # the unwrapped counter column equals the runtime's position
    from servotune.pipeline import run_scenario

    scen = st.build_scenario(rig, "track", axis="master", seconds=3.0)
    tr = run_scenario(rig, scen, seed=4)
    np.testing.assert_array_equal(log.axis("master").pos_counts, tr.pos_counts[:, 0])
    np.testing.assert_array_equal(log.axis("slave").dac_code, tr.code[:, 1])
    # the master's counter starts at 0xFFC000 and the move wraps it
    raw = log.axis("master").counter
    assert raw[0] >= 0xFFC000 - 2 and np.any(np.diff(raw) < -(1 << 23))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--scenario", "nope"], "unknown scenario 'nope'"),
        (["--scenario", "prbs", "--axis", "z"], "no axis 'z'"),
        (["--scenario", "prbs", "--seconds", "0.01"], "need at least 10"),
        (["--scenario", "prbs", "--seconds", "-1"], "seconds must be > 0"),
    ],
)
def test_bad_requests_one_line_exit_3(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    out = tmp_path / "x.csv"
    assert main(["simulate", str(EXAMPLE_RIG), "-o", str(out), *args]) == 3
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists()


def test_output_into_missing_directory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "missing" / "x.csv"
    assert (
        main(["simulate", str(EXAMPLE_RIG), "--scenario", "prbs", "--seconds", "1", "-o", str(out)])
        == 3
    )
    err = capsys.readouterr().err
    assert "does not exist" in err and err.count("\n") == 1
    assert not out.parent.exists()
    assert list(tmp_path.iterdir()) == []  # nothing half-written


def test_debug_shows_traceback(tmp_path: Path) -> None:
    with pytest.raises(st.SpecError):
        main(
            [
                "--debug",
                "simulate",
                str(EXAMPLE_RIG),
                "--scenario",
                "nope",
                "-o",
                str(tmp_path / "x.csv"),
            ]
        )


def test_installed_console_script_runs() -> None:
    import shutil
    import subprocess
    import sys

    exe = shutil.which("servotune") or str(Path(sys.executable).parent / "servotune")
    r = subprocess.run(
        [exe, "rig", str(EXAMPLE_RIG), "--json"],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert '"timer_divisor": 4773' in r.stdout
