"""Progress on long work (issue 20, point 3): a line on stderr within 2 s of starting ``tune``,
none with ``--quiet``, bars (tqdm) on a terminal, stdout left to the product.

The clock here is the test's own (``time.monotonic`` around a real subprocess), and the bar is
read from the bytes tqdm wrote.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from servotune.progress import StderrProgress

ROOT = Path(__file__).resolve().parents[2]
RIG = ROOT / "plants" / "pc-dual-servo.toml"
SERVOTUNE = Path(sys.executable).parent / "servotune"
QUICK = ["--generations", "2", "--population", "6", "--max-overshoot-pct", "300", "--no-current"]


def _env(tmp_path: Path) -> dict[str, str]:
    return {**os.environ, "SERVOTUNE_WORKBENCH": str(tmp_path / "wb")}


def test_tune_reports_progress_within_two_seconds(tmp_path: Path) -> None:
    start = time.monotonic()
    p = subprocess.Popen([str(SERVOTUNE), "tune", str(RIG), "-o", str(tmp_path / "t.json"),
                          *QUICK], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         env=_env(tmp_path))  # fmt: skip
    try:
        first = p.stderr.readline()
        waited = time.monotonic() - start
    finally:
        p.kill()
        p.communicate()
    assert first.startswith("tune "), first
    assert waited < 2.0, f"the first progress line came after {waited:.2f} s"


def test_quiet_silences_progress_and_stdout_holds_only_the_json(tmp_path: Path) -> None:
    res = subprocess.run([str(SERVOTUNE), "tune", str(RIG), "-o", str(tmp_path / "t.json"),
                          "--json", "--quiet", *QUICK], capture_output=True, text=True,
                         env=_env(tmp_path), timeout=300)  # fmt: skip
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
