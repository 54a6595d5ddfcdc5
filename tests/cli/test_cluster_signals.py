"""A signal to a run whose Monte Carlo is on an embedded 2-worker ``LocalCluster``: Ctrl-C (to
the whole process group, as a terminal sends it) or SIGTERM (to the run) once the workers run.
The run ends with its one line (``servotune verify: interrupted`` / ``terminated``) and exit
130 / 143: no Dask log lines (cancelled tasks, closed connections, never-retrieved task
exceptions) before it, no process of the group left, no verification record."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PROGRESS = ("verify:", "verify montecarlo:", "compiling ", "compiled ")  # progress lines


def _group_alive(pgid: int) -> list[str]:
    """The processes still in the process group ``pgid`` (their command lines)."""
    out = subprocess.run(
        ["ps", "-eo", "pgid=,pid=,args="], capture_output=True, text=True, check=True
    ).stdout
    rows = [line.split(None, 2) for line in out.splitlines()]
    return [r[2] for r in rows if len(r) == 3 and int(r[0]) == pgid]


@pytest.mark.parametrize(
    ("sig", "code", "word", "to_group"),
    [(signal.SIGINT, 130, "interrupted", True), (signal.SIGTERM, 143, "terminated", False)],
    ids=["ctrl-c", "sigterm"],
)
def test_a_signal_to_a_clustered_monte_carlo_is_one_line(
    sig, code, word, to_group, quick_workbench, quick_tuning
) -> None:
    w = quick_workbench(f"cluster-{word}", quick_tuning)
    record = Path(f"{w['tuning']}.verify.json")
    cmd = [
        sys.executable,
        "-m",
        "servotune.cli",
        "verify",
        str(w["tuning"]),
        "--spec",
        str(w["spec"]),
        "--montecarlo",
        "400000",
        "--workers",
        "2",
    ]
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        cwd=w["dir"],
        start_new_session=True,
    )
    lines: list[str] = []
    try:
        assert proc.stderr is not None
        for line in proc.stderr:  # until the first chunk is back: the workers run
            lines.append(line.rstrip("\n"))
            if line.startswith("verify montecarlo: "):
                break
        assert any(x.startswith("verify montecarlo: ") for x in lines), lines
        if to_group:
            os.killpg(proc.pid, sig)
        else:
            os.kill(proc.pid, sig)
        _, rest = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    lines += rest.splitlines()
    assert proc.returncode == code, lines
    other = [x for x in lines if not x.startswith(PROGRESS)]
    assert other == [f"servotune verify: {word}"], other  # one line, no Dask noise before it
    deadline = time.monotonic() + 20
    while (alive := _group_alive(proc.pid)) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert alive == [], alive  # the workers and the nannies' processes are gone
    assert not record.exists()
