"""Progress on long work: a line on stderr as soon as ``tune`` starts (before any slow import),
none with ``--quiet``, bars (tqdm) on a terminal, stdout left to the product.

The bar is read from the bytes tqdm wrote.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

from servotune.progress import StderrProgress

ROOT = Path(__file__).resolve().parents[2]
RIG = ROOT / "plants" / "pc-dual-servo.toml"
SERVOTUNE = Path(sys.executable).parent / "servotune"
QUICK = ["--generations", "2", "--population", "6", "--max-overshoot-pct", "300", "--no-current"]


def _env(tmp_path: Path) -> dict[str, str]:
    return {**os.environ, "SERVOTUNE_WORKBENCH": str(tmp_path / "wb")}


HEAVY = ("casadi", "control", "matplotlib", "scipy.optimize", "scipy.signal", "servotune.tune")
"""The tuner's imports, seconds in a cold process: the first line must not wait for any of them.
(numpy and numba come earlier, with reading the rig: a bad rig is one line with no progress
line before it, so the rig is read first.)"""


def test_tune_reports_progress_before_the_heavy_imports(tmp_path: Path) -> None:
    """The first progress line comes before anything slow is imported.

    The requirement is a line within 2 s of starting ``tune``. A wall clock is not a fair
    judge of that on a loaded machine (the line came after 3.2 s on a busy 2-core box while
    nothing but the interpreter's start preceded it), so the test measures the condition that
    makes it fast: ``python -X importtime`` logs every import on stderr in order, and the line
    must come before the first import of the tuner (casadi, python-control, matplotlib,
    scipy's optimisers and signal tools, ``servotune.tune``), which takes seconds.
    """
    p = subprocess.Popen(
        [
            sys.executable,
            "-X",
            "importtime",
            "-m",
            "servotune.cli",
            "tune",
            str(RIG),
            "-o",
            str(tmp_path / "t.json"),
            *QUICK,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(tmp_path),
    )
    imported: list[str] = []
    try:
        while (line := p.stderr.readline()).startswith("import time:"):
            imported.append(line.rsplit("|", 1)[-1].strip())
    finally:
        p.kill()
        p.communicate()
    assert line.startswith("tune "), line
    assert len(imported) > 10  # importtime really logged the imports before it
    early = sorted({h for h in HEAVY for name in imported if name == h or name.startswith(h + ".")})
    assert not early, f"imported before the first progress line: {early}"


def test_quiet_silences_progress_and_stdout_holds_only_the_json(tmp_path: Path) -> None:
    res = subprocess.run(
        [
            str(SERVOTUNE),
            "tune",
            str(RIG),
            "-o",
            str(tmp_path / "t.json"),
            "--json",
            "--quiet",
            *QUICK,
        ],
        capture_output=True,
        text=True,
        env=_env(tmp_path),
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    json.loads(res.stdout)  # the summary, nothing else
    assert "generation" not in res.stderr and "loading the tuner" not in res.stderr
    assert "wrote the tuning to" in res.stderr  # where the file is: not progress


def test_bars_on_a_terminal_lines_elsewhere_nothing_when_quiet() -> None:
    tty = io.StringIO()
    bar = StderrProgress(tty, tty=True)
    bar("tune: PI for master")
    for k in (1, 2, 3):
        bar(f"tune composite: generation {k}/3, best 1.5")
    out = tty.getvalue()
    assert "tune: PI for master" in out
    assert "tune composite" in out and "3/3" in out and "100%" in out  # a tqdm bar
    assert "best 1.5" not in out  # the bar replaces the lines
    log = io.StringIO()
    plain = StderrProgress(log, tty=False)
    plain("tune composite: generation 1/3, best 1.5")
    assert log.getvalue() == "tune composite: generation 1/3, best 1.5\n"
    quiet = io.StringIO()
    StderrProgress(quiet, quiet=True, tty=True)("tune composite: generation 1/3")
    assert quiet.getvalue() == ""
