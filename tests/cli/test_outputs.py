"""Refused before any work: an output where no file can be created, and more worker processes
than the machine has cores.

An output file's directory gets a file created and removed in it before the run (every output
is written as a temporary file there, then renamed), an output directory the same inside it,
or in the parent it will be made in: ``tune -o /proc/x.json`` is one line and exit 3 at once,
not after a whole tuning. ``--workers N`` above the usable cores is one line and exit 3 before
any process starts. ``/proc`` refuses new files even to root (tests run as root in CI, where
a read-only mode does not stop anyone).
"""

from __future__ import annotations

import os
from pathlib import Path

import psutil
import pytest
from conftest import EXAMPLE_RIG, ROOT

from servotune import executor
from servotune.cli import main
from servotune.cli.output import check_dirs, check_outputs
from servotune.errors import SchedulerError, ServotuneError
from servotune.executor import SCHEDULER_ENV, check_workers, local_workers

PLANTS = ROOT / "plants"
BASE = ROOT / "tests" / "corpus" / "base"
SPEC = PLANTS / "pc-dual-servo.spec.toml"
VERIFY_8 = [
    "verify",
    str(BASE / "tuning.json"),
    "--spec",
    str(SPEC),
    "--rig",
    str(EXAMPLE_RIG),
    "--montecarlo",
    "8",
]


@pytest.fixture(autouse=True)
def _quiet_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SERVOTUNE_WORKBENCH", str(tmp_path / "workbench"))
    monkeypatch.delenv(SCHEDULER_ENV, raising=False)


def one_line(capsys: pytest.CaptureFixture[str], args: list[str], *mentions: str) -> str:
    """Run the CLI: exit 3, one stderr line holding every mention, no summary, nothing
    written, no traceback. Returns the line."""
    code = main(args)
    cap = capsys.readouterr()
    lines = [ln for ln in cap.err.splitlines() if ln.strip()]
    assert code == 3, cap.err
    assert len(lines) == 1, cap.err
    assert "wrote" not in cap.err and "Traceback" not in cap.err and cap.out == ""
    for m in mentions:
        assert m in lines[0], (m, lines[0])
    return lines[0]


# --- outputs that cannot be created ----------------------------------------------------------


@pytest.mark.parametrize(
    "args, output",
    [
        (["tune", str(EXAMPLE_RIG), "-o", "/proc/x.json"], "/proc/x.json"),
        (["fit", str(BASE / "log.csv"), "--axis", "master", "-o", "/proc/x.toml"], "/proc/x.toml"),
        (
            ["fit", str(BASE / "log.csv"), "--axis", "master", "--plot", "/proc/x.png"],
            "/proc/x.png",
        ),
        (
            ["fit", str(BASE / "log.csv"), "--axis", "master", "--fleet", "/proc/x.csv"],
            "/proc/x.csv",
        ),
        (
            [
                "excite",
                "--rig",
                str(EXAMPLE_RIG),
                "--kind",
                "prbs",
                "--seconds",
                "4",
                "-o",
                "/proc/x.csv",
            ],
            "/proc/x.csv",
        ),
        (["plan", str(PLANTS / "linkage-6axis.toml"), "-o", "/proc/x.json"], "/proc/x.json"),
    ],
)
def test_an_output_file_that_cannot_be_created_fails_first(capsys, args, output) -> None:
    line = one_line(capsys, args, output, "cannot create a file in '/proc'")
    assert line.startswith(f"servotune {args[0]}: error:")


@pytest.mark.parametrize(
    "args, directory",
    [
        (["demo", str(EXAMPLE_RIG), "--out", "/proc/demo"], "/proc/demo"),  # to be made
        (["demo", str(EXAMPLE_RIG), "--out", "/proc/self"], "/proc/self"),  # there already
        (["export-table", str(BASE / "tuning.json"), "--format", "c", "-o", "/proc/c"], "/proc/c"),
        (["sync", str(PLANTS / "gantry.toml"), "--plot", "/proc/plots"], "/proc/plots"),
        (
            [
                "verify",
                str(BASE / "tuning.json"),
                "--spec",
                str(SPEC),
                "--rig",
                str(EXAMPLE_RIG),
                "--report",
                "/proc/report",
            ],
            "/proc/report",
        ),
    ],
)
def test_an_output_directory_that_cannot_be_filled_fails_first(capsys, args, directory) -> None:
    one_line(capsys, args, directory, "cannot create a file in")


def test_the_verification_record_beside_the_tuning_is_checked_first(tmp_path, capsys) -> None:
    """The record goes beside the tuning: a tuning in a directory where no file can be made
    (here a record path that is a directory) fails before the Monte Carlo."""
    tuning = tmp_path / "t.json"
    tuning.write_bytes((BASE / "tuning.json").read_bytes())
    (tmp_path / "t.json.verify.json").mkdir()
    one_line(
        capsys,
        ["verify", str(tuning), "--spec", str(SPEC), "--rig", str(EXAMPLE_RIG)],
        "t.json.verify.json",
        "is a directory",
    )


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only directory anyway")
def test_a_read_only_directory_fails_first(tmp_path, capsys) -> None:
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    try:
        one_line(capsys, ["tune", str(EXAMPLE_RIG), "-o", str(ro / "t.json")], str(ro / "t.json"))
        one_line(capsys, ["demo", str(EXAMPLE_RIG), "--out", str(ro / "d")], str(ro / "d"))
    finally:
        ro.chmod(0o755)


def test_the_probe_leaves_nothing_behind(tmp_path) -> None:
    before = set(os.listdir(tmp_path))
    check_outputs(str(tmp_path / "out.json"))
    check_dirs(str(tmp_path), str(tmp_path / "new" / "dir"))
    assert set(os.listdir(tmp_path)) == before and not (tmp_path / "new").exists()
    with pytest.raises(ServotuneError, match="cannot create a file"):
        check_outputs("/proc/out.json")


# --- worker processes ------------------------------------------------------------------------


@pytest.fixture
def no_cluster(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """A cluster that would start is recorded instead (and none starts)."""
    started: list[int] = []

    def refuse(workers: int):
        started.append(workers)
        raise AssertionError(f"a cluster of {workers} workers was started")

    monkeypatch.setattr(executor, "local_cluster", refuse)
    return started


def _children() -> set[int]:
    return {p.pid for p in psutil.Process().children(recursive=True)}


@pytest.mark.parametrize(
    "args",
    [
        VERIFY_8,
        [
            "fit",
            str(BASE / "log.csv"),
            str(BASE / "log.csv"),
            "--axis",
            "master",
            "--fleet",
            "FLEET.csv",
        ],
    ],
)
def test_more_workers_than_cores_is_refused_before_any_process(
    tmp_path, capsys, no_cluster, args
) -> None:
    args = [a.replace("FLEET.csv", str(tmp_path / "fleet.csv")) for a in args]
    before = _children()
    too_many = local_workers() + 1
    for n in (too_many, 10_000):
        one_line(capsys, [*args, "--workers", str(n)], f"got {n}", f"at most {local_workers()}")
    assert no_cluster == [] and _children() <= before
    assert not (tmp_path / "fleet.csv").exists()


def test_workers_at_the_cap_pass_the_check(tmp_path, capsys, no_cluster) -> None:
    """At the cap the check passes (the run then stops on its missing tuning, before any
    cluster would start)."""
    check_workers(local_workers())
    check_workers(1)
    check_workers(None)
    missing = tmp_path / "missing.json"
    line = one_line(
        capsys,
        ["verify", str(missing), "--spec", str(SPEC), "--workers", str(local_workers())],
        "missing.json",
    )
    assert "at most" not in line and no_cluster == []


def test_the_rule_in_the_library(monkeypatch) -> None:
    with pytest.raises(SchedulerError, match=rf"at most {local_workers()} \(.*got 10000"):
        check_workers(10_000)
    with pytest.raises(SchedulerError, match="workers must be >= 1, got 0"):
        check_workers(0)
    with pytest.raises(SchedulerError, match="not both"):
        check_workers(1, "tcp://nowhere:8786")
    with pytest.raises(SchedulerError, match="at most"):
        with executor.open_executor(10, workers=10_000):
            pass  # pragma: no cover - refused before
    monkeypatch.setenv(SCHEDULER_ENV, "tcp://nowhere:8786")
    with pytest.raises(SchedulerError, match="not both"):
        check_workers(2)


def test_the_help_states_the_maximum(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["verify", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert f"at most the usable cores ({local_workers()} here)" in out


def test_workers_count_against_the_memory_budget(tmp_path, capsys, no_cluster) -> None:
    """Each worker process of an embedded cluster is counted at WORKER_BYTES (256 MiB): two
    workers under a 300 MiB budget are refused in one line naming both numbers, before any
    process starts; without --workers, the cluster gets the workers the budget holds (here
    none beyond this process: the run stays in-process)."""
    from servotune.budget import BudgetError, set_memory_budget

    if local_workers() < 2:
        pytest.skip("one usable core: no cluster of 2 to refuse")
    args = [
        "--max-memory",
        "300M",
        *VERIFY_8,
        "--workers",
        "2",
    ]
    line = one_line(capsys, args, "cluster of 2 workers", "512 MiB")
    assert "2 × 256 MiB" in line and "300 MiB" in line
    assert no_cluster == []
    try:
        set_memory_budget("300M")
        with pytest.raises(BudgetError, match="2 workers"):
            check_workers(2)
        with executor.open_executor(10**6) as ex:  # large work, no --workers: in-process
            assert ex.name == "in-process"
        set_memory_budget("1G")
        check_workers(2)  # 512 MiB fits
    finally:
        set_memory_budget(None)
    assert no_cluster == []
