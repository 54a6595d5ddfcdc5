"""A cold start is a visible step (servotune/kernels.py): numba compiling the kernels is said on
stderr before it starts and while it lasts, ``servotune warmup`` compiles them ahead, and a warm
cache says nothing.

The subprocess tests give numba a fresh cache directory (``NUMBA_CACHE_DIR``, which
servotune/_numba_cache.py leaves to rule), so they start cold whatever the tree's cache holds.
"""

from __future__ import annotations

import io
import json
import os
import queue
import re
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numba
import pytest

from servotune import _numba_cache
from servotune import kernels as warmup
from servotune.progress import StderrProgress

ROOT = Path(__file__).resolve().parents[1]
SIMULATE = ["simulate", "plants/pc-dual-servo.toml", "--scenario", "prbs", "--axis", "master",
            "--seconds", "2"]  # fmt: skip

FIRST_LINE_S = 5.0
"""The requirement: a cold command says it is compiling within 5 s of its start, and is never
silent longer than that while it compiles."""


def _env(cache: Path) -> dict[str, str]:
    return {**os.environ, "NUMBA_CACHE_DIR": str(cache)}


def _servotune(args: list[str], cache: Path, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "servotune.cli", *args],
        cwd=ROOT,
        env=_env(cache),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _compiling(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("compiling")]


def test_cold_simulate_says_it_compiles_within_5_s_and_keeps_saying_it(tmp_path: Path) -> None:
    """The first line comes before the compilation, and the next while it lasts: the test
    stops the run once it has seen both."""
    lines: queue.Queue[tuple[float, str]] = queue.Queue()
    t0 = time.monotonic()
    p = subprocess.Popen(
        [sys.executable, "-m", "servotune.cli", *SIMULATE, "-o", str(tmp_path / "log.csv")],
        cwd=ROOT,
        env=_env(tmp_path / "numba"),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )

    def read() -> None:
        for line in p.stderr:
            lines.put((time.monotonic() - t0, line.rstrip("\n")))

    threading.Thread(target=read, daemon=True).start()
    seen: list[tuple[float, str]] = []
    try:
        deadline = t0 + 60.0
        while time.monotonic() < deadline and not any("s on this one…" in s for _, s in seen):
            try:
                seen.append(lines.get(timeout=0.1))
            except queue.Empty:
                continue
    finally:
        p.kill()
        p.wait()
    said = [(t, s) for t, s in seen if s.startswith("compiling simulation kernels (first run only")]
    assert said, f"no compile line; stderr: {seen}"
    assert said[0][1].startswith("compiling simulation kernels (first run only, about ")
    assert said[0][0] <= FIRST_LINE_S, f"first said after {said[0][0]:.1f} s: {seen}"
    beat = next(t for t, s in seen if "s on this one…" in s)
    assert beat - said[0][0] <= FIRST_LINE_S, f"silent for {beat - said[0][0]:.1f} s: {seen}"
    assert not any(s.startswith("wrote") for _, s in seen)  # it was said before the work


@pytest.mark.slow
def test_warmup_compiles_every_group_once_then_nothing_is_compiled_or_said(
    tmp_path: Path,
) -> None:
    """A cold compile of every kernel (100 s measured on the 2-core VM at a load of 1, 135 s
    at 4.5): then a second warmup, one of a single group and a simulate find the kernels cached
    and say nothing about compiling. In ``make test-slow``: CI's fresh install does the same
    (tests/test_wheel.py runs a cold ``warmup``, a second one and the chain after it)."""
    cache = tmp_path / "numba"
    t0 = time.monotonic()
    cold = _servotune(["warmup", "--json"], cache, timeout=1800)
    cold_s = time.monotonic() - t0
    assert cold.returncode == 0, cold.stderr
    doc = json.loads(cold.stdout)
    assert doc["compiled"] == [g.name for g in warmup.GROUPS] and doc["still_cold"] == []
    assert Path(doc["cache_dir"]) == cache
    said = _compiling(cold.stderr)
    assert said[0].startswith("compiling all 7 groups of kernels (first run only, about ")
    n = len(warmup.GROUPS)
    for k, g in enumerate(warmup.GROUPS):  # each group: its start and its end, k of n
        assert f"compiling {g.name} kernels: {k}/{n} groups done, this one about " in cold.stderr
        assert f"compiling {g.name} kernels: {k + 1}/{n} groups done, in " in cold.stderr
    print(f"cold warmup of every group: {cold_s:.1f} s")  # shown with pytest -s

    again = _servotune(["warmup", "--json"], cache, timeout=120)
    assert again.returncode == 0, again.stderr
    doc = json.loads(again.stdout)
    assert doc["compiled"] == [] and doc["cached"] == [g.name for g in warmup.GROUPS]
    assert _compiling(again.stderr) == []
    assert "nothing to compile: every kernel group already compiled" in again.stderr
    one = _servotune(["warmup", "simulation"], cache, timeout=120)
    assert one.returncode == 0 and _compiling(one.stderr) == [], one.stderr
    assert "nothing to compile: simulation already compiled" in one.stderr

    run = _servotune([*SIMULATE, "-o", str(tmp_path / "log.csv")], cache, timeout=120)
    assert run.returncode == 0, run.stderr
    assert _compiling(run.stderr) == [], run.stderr  # warm: not a word about compiling
    assert "wrote 500 ticks" in run.stderr


def test_cached_overloads_reads_the_index_without_compiling(tmp_path: Path) -> None:
    """0 before the first call, 1 after it, for a new dispatcher of the same function (a new
    process's view), and that dispatcher then loads it rather than compile it."""

    def twice(x):
        return 2 * x

    previous = numba.config.CACHE_DIR
    numba.config.CACHE_DIR = str(tmp_path)  # numba picks the directory when decorating
    try:
        first = numba.njit(cache=True)(twice)
        assert _numba_cache.cached_overloads(first) == 0
        assert first(21) == 42
        assert first.stats.cache_misses  # compiled
        fresh = numba.njit(cache=True)(twice)
    finally:
        numba.config.CACHE_DIR = previous
    assert _numba_cache.cached_overloads(fresh) == 1
    assert not fresh.overloads  # counting compiled or loaded nothing
    assert fresh(4) == 8
    assert fresh.stats.cache_hits and not fresh.stats.cache_misses
    assert _numba_cache.cached_overloads(object()) is None  # not a cached dispatcher: not known


def test_numba_compiling_a_servotune_function_is_said_once() -> None:
    """numba's compile event reaches the notices: a function of a servotune module (here one
    made in ``servotune.fake``) compiling is said, once; a call that compiles nothing, or
    another package's function compiling, is not."""
    scope: dict[str, object] = {"__name__": "servotune.fake"}
    exec("def plus_one(x):\n    return x + 1\n", scope)
    lines: list[str] = []
    with warmup.compile_notices(lines.append, heartbeat_s=60.0):
        f = numba.njit(scope["plus_one"])
        assert f(1) == 2
        assert f(2) == 3  # compiled already: nothing more
        assert numba.njit(lambda x: x - 1)(1) == 0  # not servotune's: not said
    assert lines == ["compiling servotune kernels (first run only)…"]
    assert f(2.5) == 3.5  # outside the block: nothing said
    assert len(lines) == 1


def test_a_long_compilation_beats_and_a_group_is_said_once() -> None:
    """While a compilation lasts, a heartbeat line every ``heartbeat_s`` (a step ``0/1`` of
    its own: on a terminal, a bar whose clock runs), then its end; a main kernel's group is
    said with its estimate; a callee compiling inside is part of it; the group is said once."""

    def dispatcher(module: str, name: str) -> SimpleNamespace:
        return SimpleNamespace(py_func=SimpleNamespace(__module__=module, __qualname__=name))

    kernel = dispatcher("servotune.sim.kernel", "batch_kernel")
    callee = dispatcher("servotune.plant", "advance")
    lines: list[str] = []
    with warmup.compile_notices(lines.append, heartbeat_s=0.05):
        warmup.compile_started(kernel)
        warmup.compile_started(callee)  # compiled as part of the kernel: no line of its own
        time.sleep(0.3)
        warmup.compile_ended(callee)
        warmup.compile_ended(kernel)
        warmup.compile_started(callee)  # the same group again, briefly: nothing more said
        warmup.compile_ended(callee)
    about = next(g.about_s for g in warmup.GROUPS if g.name == "simulation")
    assert lines[0] == f"compiling simulation kernels (first run only, about {about} s)…"
    beats = lines[1:-1]
    assert len(beats) >= 2
    assert all(re.fullmatch(r"compiling simulation kernels: 0/1, \d+ s so far…", x) for x in beats)
    assert re.fullmatch(r"compiling simulation kernels: 1/1, in \d+ s", lines[-1])
    assert warmup._group_label("servotune.sim.lean_sync") == "verification"
    assert warmup._group_label("servotune.sim.lean") == "batch"
    assert warmup._group_label("servotune.arch.linkage.kernel") == "linkage"
    assert warmup._group_label("numpy.linalg") is None


def test_unknown_group_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown kernel group 'engine'"):
        warmup.cold_groups(["simulation", "engine"])
    usage = subprocess.run(
        [sys.executable, "-m", "servotune.cli", "warmup", "engine"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert usage.returncode == 2 and "'engine' is no kernel group" in usage.stderr


def test_a_repeated_step_redraws_the_bar_so_its_clock_runs() -> None:
    """On a terminal the heartbeat (the same ``k/n`` again) redraws the bar: its elapsed time
    moves on although no step ended."""
    out = io.StringIO()
    bar = StderrProgress(out, tty=True)
    bar("compiling simulation kernels: 0/1 groups done, this one about 25 s")
    time.sleep(1.1)
    bar("compiling simulation kernels: 0/1 groups done, 1 s on this one…")
    assert "0/1 [00:01<" in out.getvalue()
    bar("compiling simulation kernels: 1/1 groups done, in 1 s")
    assert "1/1 [00:01<" in out.getvalue()


def test_every_group_names_functions_that_exist() -> None:
    """The groups name their kernels and workloads as ``"module:attribute"`` strings (imported
    when needed): a renamed kernel must be renamed there too, or warm_up would fail at a user's
    first run."""
    from importlib import import_module

    for g in warmup.GROUPS:
        for ref in (*g.kernels, g.workload):
            module, _, attr = ref.partition(":")
            assert hasattr(import_module(module), attr.removesuffix("()")), (g.name, ref)
