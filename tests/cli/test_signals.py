"""Signals and partial files: Ctrl-C and SIGTERM end a run with one line, exit 130 or
143, no traceback, and no partial or temporary file; an unusable workbench stops before any
output is written."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import servotune.io.files as files
from servotune.cli import main

ROOT = Path(__file__).resolve().parents[2]
RIG = ROOT / "plants" / "pc-dual-servo.toml"


SIGNALS = [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")]


def _files(d: Path) -> set[str]:
    return {p.name for p in d.iterdir()}


@pytest.mark.parametrize(("sig", "code", "word"), SIGNALS)
def test_a_signal_during_the_atomic_write_leaves_no_file(
    sig, code, word, tmp_path, capsys, monkeypatch
) -> None:
    """The signal arrives while the output's temporary file is open (at its fsync): the run
    ends with the signal's exit code and neither the temp file nor the output remains."""
    real_fsync = os.fsync

    def fsync_then_signal(fd: int) -> None:
        real_fsync(fd)
        assert any(n.endswith(".tmp") for n in _files(tmp_path))  # the temp file exists now
        os.kill(os.getpid(), sig)
        time.sleep(1.0)  # the handler runs here

    monkeypatch.setattr(files.os, "fsync", fsync_then_signal)
    out = tmp_path / "log.csv"
    rc = main(["simulate", str(RIG), "--scenario", "prbs", "--seconds", "1", "-o", str(out)])
    assert rc == code
    err = capsys.readouterr().err.strip().splitlines()
    # a cold kernel cache first says it compiles (progress, servotune/kernels.py): not the end
    assert [x for x in err if not x.startswith("compiling ")] == [f"servotune simulate: {word}"]
    assert _files(tmp_path) == set()


@pytest.mark.parametrize(("sig", "code", "word"), SIGNALS)
def test_a_signal_to_a_long_run_ends_it_cleanly(sig, code, word, tmp_path) -> None:
    """A real process (``python -m servotune.cli``) tuning with a large budget gets the signal
    after it started working: one line on stderr, no traceback, no output, no temp file."""
    out = tmp_path / "tuning.json"
    env = {**os.environ, "SERVOTUNE_WORKBENCH": str(tmp_path / "wb")}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "servotune.cli",
            "tune",
            str(RIG),
            "--generations",
            "5000",
            "-o",
            str(out),
        ],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
        env=env,
    )
    try:
        # wait until the optimiser is in its generation loop: before that a cold start may be
        # compiling the kernels (minutes on a loaded 2-core machine), and LLVM holds the
        # interpreter while it compiles, so a signal then waits for the compile to return
        deadline = time.monotonic() + 600
        started = False
        lines = []
        while time.monotonic() < deadline:
            line = proc.stderr.readline()
            lines.append(line)
            if line.startswith("tune composite: generation 1/"):
                started = True
                break
            if not line and proc.poll() is not None:
                break
        assert started, lines
        time.sleep(0.5)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == code, err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1] == f"servotune tune: {word}"
    assert not out.exists()
    leftovers = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert leftovers == [], leftovers


def test_an_unusable_workbench_stops_tune_before_any_output(tmp_path, capsys, monkeypatch) -> None:
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("a file where the workbench directory should be\n")
    monkeypatch.setenv("SERVOTUNE_WORKBENCH", str(blocker / "wb"))
    out = tmp_path / "tuning.json"
    assert main(["tune", str(RIG), "-o", str(out)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "workbench directory" in err[0] and str(blocker / "wb") in err[0]
    assert not out.exists()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_swallowed_sigterm_ends_the_run_at_its_next_progress_line(
    tmp_path, monkeypatch, capsys
) -> None:
    """Python ignores an exception raised in a destructor: a SIGTERM arriving there would be
    lost. The run still ends, with 143 and one line, at the next progress line."""
    steps = []

    class Dying:
        def __del__(self) -> None:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.2)  # the handler raises here, inside the destructor: ignored

    def tune_rig(rig_path, *, progress, **_kw):
        d = Dying()
        del d
        steps.append("after the destructor")  # the signal's exception did not end the run
        progress("tune: the next step")
        steps.append("not reached")

    monkeypatch.setattr("servotune.tune.workflow.tune_rig", tune_rig)
    rc = main(["tune", str(RIG), "--no-current", "-o", str(tmp_path / "t.json")])
    assert rc == 143 and steps == ["after the destructor"]
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == "servotune tune: terminated"
    assert not (tmp_path / "t.json").exists()
