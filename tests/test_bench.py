"""`make bench` keeps working: a smoke run of bench/bench.py at its --quick sizes.

Only that the benchmarks run, check what they check (the python-control loop gives the
engine's codes; the batched metrics are the same with 1 and 2 threads) and report in the
documented format. Speed is not asserted here: the figures are measured by `make bench`.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINE = re.compile(r"^bench: (\S+) (\S+) (\S+)$")


def test_quick_bench_prints_figures_and_writes_the_report(tmp_path: Path) -> None:
    out = tmp_path / "bench.json"
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "bench" / "bench.py"),
            "--quick",
            "--only",
            "one_axis",
            "batched",
            "c_runtime",
            "arch",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    printed = {}
    for line in proc.stdout.splitlines():
        m = LINE.match(line)
        assert m, f"not a 'bench: NAME VALUE UNIT' line: {line!r}"
        printed[m.group(1)] = (float(m.group(2)), m.group(3))
    expected = {
        "engine_first_call_s": "s",
        "engine_one_axis_us_per_tick": "us/tick",
        "python_control_one_axis_us_per_tick": "us/tick",
        "engine_speedup_vs_python_control": "x",
        "batch_setup_s": "s",
        "batched_candidate_ticks_per_s": "ticks/s",
        "batched_candidate_ticks_per_s_1thread": "ticks/s",
        "batched_candidate_ticks_per_s_one_mode_1thread": "ticks/s",
        "c_runtime_one_axis_ns_per_tick": "ns/tick",
        "engine_one_axis_ns_per_tick": "ns/tick",
        "engine_vs_c_runtime": "x",
        "gantry_ns_per_cycle": "ns/cycle",
        "linkage_ns_per_tick": "ns/tick",
    }
    assert {k: u for k, (_, u) in printed.items()} == expected
    assert all(v > 0 for v, _ in printed.values())
    # the python-control check ran and found the same codes (it aborts the run otherwise)
    assert "python-control codes and counter equal the engine's" in proc.stderr
    # the exported C runtime around its C plant gave the engine's codes (it aborts otherwise)
    assert "the C loop's 2000 codes equal the engine's" in proc.stderr

    report = json.loads(out.read_text())
    assert report["schema"] == "servotune.bench/1"
    assert report["quick"] is True
    env = report["environment"]
    for key in ("cpu_model", "numba", "numpy", "control", "scipy", "python", "servotune"):
        assert env[key], key
    assert {k: f["unit"] for k, f in report["figures"].items()} == expected
    for name, (value, _) in printed.items():  # printed with 6 significant digits
        assert math.isclose(report["figures"][name]["value"], value, rel_tol=1e-5), name
    assert "median of 3 runs" in report["figures"]["batched_candidate_ticks_per_s"]["note"]
    assert "before the shared tick" in report["figures"]["gantry_ns_per_cycle"]["note"]
