"""Benchmarks of the servotune engine.

Usage::

    python bench/bench.py [--out reports/bench.json] [--only NAME ...] [--quick]

Each benchmark is a function registered in :data:`BENCHES` (name → function returning a list
of :class:`Figure`). Every figure is printed on stdout as one line ``bench: NAME VALUE UNIT``;
with ``--out`` the figures and the environment are also written to a JSON report (schema
``servotune.bench/1``). Progress goes to stderr. ``--quick`` runs smaller sizes through the same
code paths (a smoke test).

The machine may be a noisy VM: every timing is the median of several runs.
"""

from __future__ import annotations

import argparse
import ctypes
import dataclasses
import gc
import json
import math
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from importlib import metadata
from pathlib import Path
from typing import Any, NamedTuple

import control
import numba
import numpy as np

import servotune
from servotune.arch.gantry import simulate_gantry
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.synthesis import resolve_gains
from servotune.arch.linkage import load_linkage, run_linkage
from servotune.export.c import runtime_source
from servotune.export.c import to_file as write_c
from servotune.export.hal_component import PLANT_HEADER
from servotune.fixed import F_U
from servotune.hw.counter import unwrap_step
from servotune.hw.dac import code_from_uq
from servotune.laws.axis import FLAG_SATURATED
from servotune.laws.pi import pi_enter, pi_step
from servotune.plant import lag_split, plant_row
from servotune.sim.engine import METRIC_NAMES
from servotune.tuning import Tuning

SCHEMA = "servotune.bench/1"
ROOT = Path(__file__).resolve().parents[1]
RIG_PATH = ROOT / "plants" / "pc-dual-servo.toml"
PI_GAINS = servotune.PIGains(kp=0.5, ki=5.0)
"""PI of the benchmark loop: 31° phase margin, gain margin 8.3 on the master's linear plant."""
CANDIDATE_SEED = 2024
"""Seed of ``numpy.random.default_rng`` drawing the batched plant candidates."""
ARCH_BASELINE_NS = {"gantry": 200.0, "linkage": 1380.0}
"""ns per cycle (gantry) and per tick (linkage) of :func:`bench_arch`'s runs before the kernels
were composed from the shared tick: commit 5e122fc, median of 5, on the project's 2-core VM."""
PC_RUN_BUDGET_S = 60.0
"""Above this total, the python-control loop is timed over 3 runs instead of 5."""


class Figure(NamedTuple):
    """One benchmark figure.

    Attributes
    ----------
    name : str
        Figure name (a key of the report's ``figures``).
    value : float
        The measured value.
    unit : str
        Its unit.
    note : str or None
        Optional remark stored with the figure in the report.
    """

    name: str
    value: float
    unit: str
    note: str | None = None


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class Sizes:
    """Problem sizes and repetitions of the benchmarks.

    Attributes
    ----------
    one_axis_ticks : int
        Ticks of the one-axis loop (engine and python-control).
    engine_runs : int
        Timed runs of the engine (median).
    pc_runs : int
        Timed runs of the python-control loop (median), if they fit ``PC_RUN_BUDGET_S``.
    batch_candidates : int
        Candidates of the batched run.
    batch_ticks : int
        Ticks per candidate of the batched run.
    batch_runs : int
        Timed runs of the batched run (median), per thread count.
    fit_samples : int
        Samples of the log given to ``servotune fit``.
    fit_runs : int
        Timed runs of ``servotune fit`` (median).
    """

    one_axis_ticks: int
    engine_runs: int
    pc_runs: int
    batch_candidates: int
    batch_ticks: int
    batch_runs: int
    fit_samples: int
    fit_runs: int


FULL = Sizes(
    one_axis_ticks=100_000,
    engine_runs=5,
    pc_runs=5,
    batch_candidates=1_000,
    batch_ticks=10_000,
    batch_runs=5,
    fit_samples=1_000_000,
    fit_runs=3,
)
QUICK = Sizes(
    one_axis_ticks=2_000,
    engine_runs=3,
    pc_runs=3,
    batch_candidates=40,
    batch_ticks=2_000,
    batch_runs=3,
    fit_samples=20_000,
    fit_runs=1,
)


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class Options:
    """What every benchmark function receives.

    Attributes
    ----------
    quick : bool
        Smoke-test sizes.
    rig_path : Path
        The rig file the benchmarks build their loops from.
    scale_plants : int, optional
        Plant sets of the ``scale`` benchmark (default :data:`SCALE_PLANTS`, the whole target
        run: about 4.5 minutes here for its four runs; fewer for a quick look, extrapolated).
    """

    quick: bool = False
    rig_path: Path = RIG_PATH
    scale_plants: int | None = None

    @property
    def sizes(self) -> Sizes:
        """The sizes for this run (:data:`QUICK` or :data:`FULL`)."""
        return QUICK if self.quick else FULL


BenchFn = Callable[[Options], list[Figure]]
BENCHES: dict[str, BenchFn] = {}
"""The registry: benchmark name → function. Add entries with :func:`register`."""


def register(name: str) -> Callable[[BenchFn], BenchFn]:
    """Decorator adding a benchmark function to :data:`BENCHES` under ``name``.

    Parameters
    ----------
    name : str
        The name ``--only`` selects it by.

    Returns
    -------
    callable
        The decorator (it returns the function unchanged).
    """

    def deco(fn: BenchFn) -> BenchFn:
        if name in BENCHES:
            raise ValueError(f"benchmark {name!r} registered twice")
        BENCHES[name] = fn
        return fn

    return deco


class BenchMismatchError(RuntimeError):
    """Two implementations that must agree bit for bit did not."""


# --- helpers ---------------------------------------------------------------------------------


def progress(msg: str) -> None:
    """Print a progress line on stderr."""
    print(f"[bench] {msg}", file=sys.stderr, flush=True)


def timed_runs(fn: Callable[[], Any], runs: int) -> tuple[list[float], Any]:
    """Call ``fn`` ``runs`` times and time each call.

    Parameters
    ----------
    fn : callable
        The work, without arguments.
    runs : int
        Number of calls.

    Returns
    -------
    times : list of float
        Wall time of each call [s].
    result : object
        What the last call returned.
    """
    times = []
    result = None
    for _ in range(runs):
        gc.collect()
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return times, result


def one_axis_rig(path: Path = RIG_PATH) -> servotune.Rig:
    """The rig reduced to its master axis with a linear, noise-free plant.

    Parameters
    ----------
    path : Path
        Rig file.

    Returns
    -------
    Rig
        One axis: no Coulomb friction, no encoder noise, no drive speed limit (so the exact ZOH
        model is the whole plant); gain, time constant, delay and offset are kept, and the
        following-error trip is disabled.
    """
    rig = servotune.load_rig(path)
    master = rig.axis("master")
    plant = dataclasses.replace(master.plant, coulomb_v=0.0, noise_counts=0.0, max_speed_rpm=None)
    axis = dataclasses.replace(master, plant=plant, following_error_limit_counts=0)
    return dataclasses.replace(rig, axes=(axis,))


def reference_counts(n_ticks: int, period_s: float) -> np.ndarray:
    """Task reference with holds, steps and ramps, relative to the start [counts].

    One cycle (about 12.6 s) holds 0, steps to +6,000 (the D/A saturates), ramps at 50,000
    counts/s to +46,000 (the master's counter, starting at 0xFFC000, wraps upward at +16,384),
    steps back to +40,000, ramps at 80,000 counts/s to −20,000 (wrapping downward) and steps
    to 0 (saturating for several ticks). Cycles repeat until ``n_ticks``.

    Parameters
    ----------
    n_ticks : int
        Length [ticks].
    period_s : float
        Tick period [s]; ramp samples are at integer tick index × period.

    Returns
    -------
    ndarray of int64, shape (n_ticks,)
    """
    parts: list[np.ndarray] = []
    level = 0
    total = 0

    def hold(ticks: int) -> None:
        parts.append(np.full(ticks, level, dtype=np.int64))

    def ramp(target: int, rate_cps: float) -> None:
        nonlocal level
        dist = target - level
        ticks = math.ceil(abs(dist) / (rate_cps * period_s))
        k = np.arange(1, ticks + 1, dtype=np.int64)
        moved = np.floor(rate_cps * (k * period_s) + 0.5).astype(np.int64)
        parts.append(level + np.sign(dist) * np.minimum(moved, abs(dist)))
        level = target

    while total < n_ticks:
        start = len(parts)
        hold(250)
        level = 6_000
        hold(500)
        ramp(46_000, 50_000.0)
        hold(500)
        level = 40_000
        hold(500)
        ramp(-20_000, 80_000.0)
        hold(500)
        level = 0
        hold(500)
        total += sum(p.size for p in parts[start:])
    return np.concatenate(parts)[:n_ticks]


def one_axis_setup(opts: Options) -> tuple[servotune.Loop, servotune.Inputs]:
    """The one-axis PI loop and its task-mode inputs.

    Parameters
    ----------
    opts : Options

    Returns
    -------
    loop : Loop
    inputs : Inputs
        Task mode from tick 0 on the reference of :func:`reference_counts`.
    """
    rig = one_axis_rig(opts.rig_path)
    loop = servotune.Loop.from_rig(rig, [PI_GAINS])
    n = opts.sizes.one_axis_ticks
    ref = reference_counts(n, rig.period_s)
    inputs = servotune.Inputs.hold(n, 1).replace_axis(0, mode=1, ref_counts=ref)
    return loop, inputs


# --- the one-axis loop in python-control ------------------------------------------------------


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class PlantMap:
    """The exact one-tick map of :func:`servotune.discretize` in the engine's evaluation order.

    ``p' = p + phi_b·v + go_p·w_old + gn_p·w_new``, ``v' = phi_a·v + go_v·w_old + gn_v·w_new``,
    with ``w_new`` the drive input written ``m`` ticks ago and ``w_old`` the one before it (it
    acts for the first λ of the tick). Coefficients are read from the state-space matrices.
    """

    phi_b: float
    phi_a: float
    go_p: float
    go_v: float
    gn_p: float
    gn_v: float
    m: int
    n_hist: int
    has_old: bool

    @classmethod
    def from_plant(cls, plant: servotune.Plant, period_s: float, lag_s: float) -> PlantMap:
        """Read the coefficients off ``discretize(plant, period_s, lag_s)``.

        Parameters
        ----------
        plant : Plant
        period_s : float
            Tick period [s].
        lag_s : float
            Tick start → motor input [s] (compute time + drive delay).

        Returns
        -------
        PlantMap
        """
        ss = servotune.discretize(plant, period_s, lag_s)
        a, b = np.asarray(ss.A), np.asarray(ss.B)
        m, lam = lag_split(lag_s, period_s)
        has_old = lam > 0.0
        g_new = b[:2, 0] if m == 0 else a[:2, 1 + m]
        g_old = a[:2, 2 + m] if has_old else np.zeros(2)
        return cls(
            phi_b=float(a[0, 1]),
            phi_a=float(a[1, 1]),
            go_p=float(g_old[0]),
            go_v=float(g_old[1]),
            gn_p=float(g_new[0]),
            gn_v=float(g_new[1]),
            m=m,
            n_hist=a.shape[0] - 2,
            has_old=has_old,
        )


def plant_system(rig: servotune.Rig) -> tuple[control.NonlinearIOSystem, list[float]]:
    """The axis model as a discrete python-control system: D/A volts → counter register.

    The drive input is the D/A volts plus the plant's offset; the state is position, speed and
    the held past drive inputs; the output is the latched register
    ``(counter_init + floor(position)) & (2**bits − 1)``.

    Parameters
    ----------
    rig : Rig
        One-axis rig with a linear plant.

    Returns
    -------
    sys : NonlinearIOSystem
        Inputs ``volts``, outputs ``raw``, ``dt`` = the tick period.
    x0 : list of float
        Initial state: at rest, and every past drive input the offset alone (the engine's D/A
        history starts at 0 V).
    """
    axis = rig.axes[0]
    plant = axis.plant
    pm = PlantMap.from_plant(plant, rig.period_s, rig.timer.compute_s + plant.delay_s)
    offset = plant.offset_v
    init = axis.counter_init
    mask = (1 << rig.counter.bits) - 1

    def update(t: float, x: np.ndarray, u: np.ndarray, params: dict) -> list[float]:
        w_now = u[0] + offset
        hist = x[2:]
        w_new = w_now if pm.m == 0 else hist[pm.m - 1]
        w_old = hist[pm.m] if pm.has_old else w_new
        p = x[0] + pm.phi_b * x[1] + pm.go_p * w_old + pm.gn_p * w_new
        v = pm.phi_a * x[1] + pm.go_v * w_old + pm.gn_v * w_new
        return [p, v, *([w_now, *hist[: pm.n_hist - 1]] if pm.n_hist else [])]

    def output(t: float, x: np.ndarray, u: np.ndarray, params: dict) -> list[int]:
        return [(init + math.floor(x[0])) & mask]

    sys_ = control.nlsys(
        update,
        output,
        inputs=["volts"],
        outputs=["raw"],
        states=["pos", "speed", *(f"w{j}" for j in range(1, pm.n_hist + 1))],
        dt=rig.period_s,
        name="plant",
    )
    return sys_, [0.0, 0.0] + [offset] * pm.n_hist


def controller_system(loop: servotune.Loop) -> tuple[control.NonlinearIOSystem, list[float]]:
    """The runtime's task-mode PI tick as a discrete python-control system.

    Reads the counter register, unwraps it (:func:`~servotune.hw.counter.unwrap_step`), forms
    ``e = (y0 + ref) − y`` with ``y0`` the first read, runs the integer PI
    (:func:`~servotune.laws.pi.pi_enter` on the first tick, as ``axis_control`` does for an axis
    entering task mode from lock with ``u_last = 0``, then :func:`~servotune.laws.pi.pi_step`)
    and codes the D/A (:func:`~servotune.hw.dac.code_from_uq`). A counter fault latches 0 V.
    Direct feedthrough: the code of tick k uses the register latched at tick k.

    Parameters
    ----------
    loop : Loop
        One-axis loop with PI gains.

    Returns
    -------
    sys : NonlinearIOSystem
        Inputs ``raw``, ``ref``; outputs ``code``, ``volts``; states integrator, previous high
        byte, wraps, first read, started flag, fault flag.
    x0 : list of float
        Initial state (all zero).
    """
    rig = loop.rig
    pi = loop.controllers[0].task
    if pi is None:
        raise ValueError("the benchmark loop needs PI gains on its axis")
    kp_q, kp_f, kit_q, kit_f = pi.kp.q, pi.kp.f, pi.ki_t.q, pi.ki_t.f
    bits = rig.counter.bits
    zero, cmax = rig.dac.zero_code, rig.dac.code_max
    lo_v, lsb_v = rig.dac.range_v[0], rig.dac.lsb_v

    def tick(x: np.ndarray, u: np.ndarray) -> tuple[int, list[int]]:
        integ, hi, wraps, y0, started, fault = (int(s) for s in x)
        raw, ref = int(u[0]), int(u[1])
        if not started:
            hi = (raw >> (bits - 8)) & 0xFF
            y = y0 = raw
            u_q, integ = pi_enter(kp_q, kp_f, 0, y0 + ref - y, 0, zero, cmax)
        else:
            y, hi, wraps, bad = unwrap_step(raw, hi, wraps, bits)
            fault = fault or int(bad)
            u_q, integ = pi_step(kp_q, kp_f, kit_q, kit_f, integ, y0 + ref - y, 0, zero, cmax)
        code = zero if fault else code_from_uq(u_q, F_U, zero, cmax)
        return code, [integ, hi, wraps, y0, 1, fault]

    def update(t: float, x: np.ndarray, u: np.ndarray, params: dict) -> list[int]:
        return tick(x, u)[1]

    def output(t: float, x: np.ndarray, u: np.ndarray, params: dict) -> list[float]:
        code = tick(x, u)[0]
        return [code, lo_v + code * lsb_v]

    sys_ = control.nlsys(
        update,
        output,
        inputs=["raw", "ref"],
        outputs=["code", "volts"],
        states=["integ", "hi_prev", "wraps", "y0", "started", "fault"],
        dt=rig.period_s,
        name="ctl",
    )
    return sys_, [0.0] * 6


def python_control_loop(loop: servotune.Loop) -> tuple[control.InterconnectedSystem, list[float]]:
    """Controller and plant joined with :func:`control.interconnect`.

    Parameters
    ----------
    loop : Loop
        One-axis loop.

    Returns
    -------
    sys : InterconnectedSystem
        Input ``ref`` [counts]; outputs ``code`` and ``raw`` (the counter register).
    x0 : list of float
        Initial state (controller states first).
    """
    ctl, x0_ctl = controller_system(loop)
    plant, x0_plant = plant_system(loop.rig)
    sys_ = control.interconnect(
        [ctl, plant],
        connections=[["plant.volts", "ctl.volts"], ["ctl.raw", "plant.raw"]],
        inplist=["ctl.ref"],
        inputs=["ref"],
        outlist=["ctl.code", "plant.raw"],
        outputs=["code", "raw"],
        dt=loop.rig.period_s,
        name="one_axis",
    )
    return sys_, x0_ctl + x0_plant


def run_python_control(
    sys_: control.InterconnectedSystem, x0: Sequence[float], ref: np.ndarray, period_s: float
) -> control.TimeResponseData:
    """Simulate the python-control loop over a reference.

    Parameters
    ----------
    sys_ : InterconnectedSystem
        From :func:`python_control_loop`.
    x0 : sequence of float
        Initial state.
    ref : ndarray of int64
        Reference per tick [counts].
    period_s : float
        Tick period [s].

    Returns
    -------
    TimeResponseData
    """
    timepts = np.arange(ref.size, dtype=np.int64) * period_s
    return control.input_output_response(sys_, timepts, ref.astype(np.float64), list(x0))


def check_same(label: str, got: np.ndarray, want: np.ndarray) -> None:
    """Raise :class:`BenchMismatchError` at the first tick where two sequences differ.

    Parameters
    ----------
    label : str
        What is compared (for the message).
    got, want : ndarray
        Sequences of equal length.
    """
    got, want = np.asarray(got), np.asarray(want)
    if got.shape != want.shape:
        raise BenchMismatchError(f"{label}: shapes differ, {got.shape} vs {want.shape}")
    bad = np.flatnonzero(got != want)
    if bad.size:
        k = int(bad[0])
        raise BenchMismatchError(
            f"{label}: {bad.size} ticks differ, first at tick {k}: "
            f"python-control {got[k].item()!r}, engine {want[k].item()!r}"
        )


def check_python_control(resp: control.TimeResponseData, trace: servotune.Trace) -> float:
    """Check the python-control run against the engine's trace, tick for tick.

    Parameters
    ----------
    resp : TimeResponseData
        From :func:`run_python_control`.
    trace : Trace
        From :func:`servotune.simulate` of the same loop and inputs.

    Returns
    -------
    float
        Largest |position difference| of the plant states [counts] (0 if bit-exact).

    Raises
    ------
    BenchMismatchError
        If a D/A code or a counter register differs.
    """
    out = np.asarray(resp.outputs)
    check_same("D/A code", out[0].astype(np.int64), trace.code[:, 0].astype(np.int64))
    check_same("counter register", out[1].astype(np.int64), trace.counter[:, 0])
    pos = np.asarray(resp.states)[resp.state_labels.index("plant_pos")]
    return float(np.max(np.abs(pos - trace.true_pos_counts[:, 0])))


def warm_runtime_functions() -> None:
    """Compile (or load from cache) the numba runtime functions the controller calls."""
    unwrap_step(0, 0, 0, 24)
    pi_enter(1, 0, 0, 0, 0, 2048, 4095)
    pi_step(1, 0, 1, 0, 0, 0, 0, 2048, 4095)
    code_from_uq(0, F_U, 2048, 4095)


# --- benchmarks ------------------------------------------------------------------------------


def time_engine(
    loop: servotune.Loop, inputs: servotune.Inputs, runs: int
) -> tuple[float, list[float], servotune.Trace]:
    """Time :func:`servotune.simulate`: the first call apart, then ``runs`` calls.

    Parameters
    ----------
    loop : Loop
    inputs : Inputs
    runs : int
        Timed calls after the first.

    Returns
    -------
    first_s : float
        Wall time of the first call (numba compile or cache load included) [s].
    times : list of float
        Wall time of each later call [s].
    trace : Trace
        The trajectory.
    """
    t0 = time.perf_counter()
    trace = servotune.simulate(loop, inputs, seed=0)
    first_s = time.perf_counter() - t0
    sat = int(np.count_nonzero(trace.flags[:, 0] & FLAG_SATURATED))
    progress(
        f"one_axis: codes {int(trace.code.min())}..{int(trace.code.max())}, "
        f"{sat} saturated ticks, max |e| {int(np.abs(trace.err_counts).max())} counts"
    )
    times, _ = timed_runs(lambda: servotune.simulate(loop, inputs, seed=0), runs)
    return first_s, times, trace


def time_python_control(
    loop: servotune.Loop, inputs: servotune.Inputs, trace: servotune.Trace, runs: int
) -> list[float]:
    """Time the python-control loop, checking every run against the engine's trace.

    Parameters
    ----------
    loop : Loop
    inputs : Inputs
    trace : Trace
        The engine's trajectory for the same loop and inputs.
    runs : int
        Timed runs wanted; 3 if that many would exceed ``PC_RUN_BUDGET_S``.

    Returns
    -------
    list of float
        Wall time of each run [s].

    Raises
    ------
    BenchMismatchError
        If a run's codes or counter registers differ from the engine's.
    """
    sys_, x0 = python_control_loop(loop)
    ref = np.asarray(inputs.ref_counts[:, 0])
    period = loop.rig.period_s
    n = ref.size
    warm_runtime_functions()
    times: list[float] = []
    dpos = 0.0
    while len(times) < runs:
        progress(f"one_axis: python-control run {len(times) + 1}/{runs} ({n} ticks)")
        t, resp = timed_runs(lambda: run_python_control(sys_, x0, ref, period), 1)
        times += t
        dpos = max(dpos, check_python_control(resp, trace))
        if len(times) == 1 and runs > 3 and t[0] * runs > PC_RUN_BUDGET_S:
            runs = 3
            progress(f"one_axis: {t[0]:.1f} s per run, timing python-control over {runs} runs")
    progress(f"one_axis: python-control codes and counter equal the engine's over {n} ticks")
    progress(f"one_axis: largest plant position difference {dpos:.3g} counts")
    return times


@register("one_axis")
def bench_one_axis(opts: Options) -> list[Figure]:
    """One-axis loop: engine vs the same loop in python-control (bit-exact check, timings).

    Parameters
    ----------
    opts : Options

    Returns
    -------
    list of Figure
        ``engine_first_call_s``, ``engine_one_axis_us_per_tick``,
        ``python_control_one_axis_us_per_tick``, ``engine_speedup_vs_python_control``.
    """
    sz = opts.sizes
    loop, inputs = one_axis_setup(opts)
    n = inputs.n_ticks
    progress(f"one_axis: engine, {n} ticks (first call includes compile or cache load)")
    first_s, times, trace = time_engine(loop, inputs, sz.engine_runs)
    eng_us = statistics.median(times) / n * 1e6
    progress(f"one_axis: engine {eng_us:.4g} us/tick (runs {[f'{t:.4f}' for t in times]} s)")
    pc_times = time_python_control(loop, inputs, trace, sz.pc_runs)
    pc_us = statistics.median(pc_times) / n * 1e6
    note = None
    if len(pc_times) < sz.pc_runs:
        note = (
            f"median of {len(pc_times)} runs, not {sz.pc_runs}: one run of {n} ticks took "
            f"{pc_times[0]:.1f} s"
        )
    return [
        Figure("engine_first_call_s", first_s, "s"),
        Figure("engine_one_axis_us_per_tick", eng_us, "us/tick"),
        Figure("python_control_one_axis_us_per_tick", pc_us, "us/tick", note),
        Figure("engine_speedup_vs_python_control", pc_us / eng_us, "x"),
    ]


FILTER_STAGES = (
    ("notch", 35.0, 10.0, -20.0),
    ("notch", 60.0, 12.0, -15.0),
    ("lowpass2", 90.0, 0.6),
    ("notch", 20.0, 4.0, -10.0),
)
"""Four output filter sections (docs/runtime.md#filters-in-the-law) for the filter bench."""


@register("filters")
def bench_filters(opts: Options) -> list[Figure]:
    """The one-axis loop with four output filter sections against the same loop without
    (same inputs, same engine): the per-tick cost of the filters.

    Returns
    -------
    list of Figure
        ``engine_4_filters_us_per_tick``, ``filters_cost_ratio`` (goal <= 1.3).
    """
    from servotune.laws.filters import lowpass2, notch, realize

    loop, inputs = one_axis_setup(opts)
    period = loop.rig.period_s
    secs = tuple(
        realize(notch(*f[1:]) if f[0] == "notch" else lowpass2(*f[1:]), period)
        for f in FILTER_STAGES
    )
    filtered = dataclasses.replace(
        loop, controllers=(dataclasses.replace(loop.controllers[0], filters=secs),)
    )
    n = inputs.n_ticks

    def run(lp: servotune.Loop) -> None:
        servotune.simulate(lp, inputs, seed=0)  # the trace dropped at once: its memory is
        # reused by the next run, as in an optimiser's loop (a trace kept alive made every run
        # fault in fresh pages, which cost more than the filters)

    for lp in (loop, filtered):  # compiled (or loaded) before any timing
        run(lp)
    # the two loops alternate, several rounds, and each keeps its fastest run: this VM's
    # noise (other processes, frequency changes) only ever adds time, and alternating puts
    # both under the same conditions (single medians varied 1.1-1.5x between sittings)
    best = {"plain": math.inf, "filtered": math.inf}
    for _ in range(3 * opts.sizes.engine_runs):
        for name, lp in (("plain", loop), ("filtered", filtered)):
            times, _ = timed_runs(lambda lp=lp: run(lp), 1)
            best[name] = min(best[name], times[0] / n * 1e6)
    for name, v in best.items():
        progress(f"filters: {name} {v:.4g} us/tick (fastest of {3 * opts.sizes.engine_runs})")
    return [
        Figure("engine_4_filters_us_per_tick", best["filtered"], "us/tick"),
        Figure("filters_cost_ratio", best["filtered"] / best["plain"], "x", "goal <= 1.3"),
    ]


def candidate_plants(
    nominal: servotune.Plant, n: int, seed: int = CANDIDATE_SEED
) -> list[tuple[servotune.Plant]]:
    """Plant candidates: gain within ±20 %, time constant within ±30 % (uniform).

    Parameters
    ----------
    nominal : Plant
    n : int
        Number of candidates.
    seed : int
        Seed of ``numpy.random.default_rng``.

    Returns
    -------
    list of 1-tuples of Plant
        Per candidate, the plants of the one-axis rig.
    """
    rng = np.random.default_rng(seed)
    gain = nominal.gain_cps_per_v * rng.uniform(0.8, 1.2, n)
    tau = nominal.tau_s * rng.uniform(0.7, 1.3, n)
    return [
        (dataclasses.replace(nominal, gain_cps_per_v=float(g), tau_s=float(t)),)
        for g, t in zip(gain, tau, strict=True)
    ]


@register("batched")
def bench_batched(opts: Options) -> list[Figure]:
    """Batched candidates: the one-axis loop for many plant variants, metrics only.

    Parameters
    ----------
    opts : Options

    Returns
    -------
    list of Figure
        ``batch_setup_s``, ``batched_candidate_ticks_per_s`` (2 threads) and
        ``batched_candidate_ticks_per_s_1thread``.
    """
    sz = opts.sizes
    rig = one_axis_rig(opts.rig_path)
    loop = servotune.Loop.from_rig(rig, [PI_GAINS])
    n_c, n_t = sz.batch_candidates, sz.batch_ticks
    ref = reference_counts(n_t, rig.period_s)
    inputs = servotune.Inputs.hold(n_t, 1).replace_axis(0, mode=1, ref_counts=ref)
    plants = candidate_plants(rig.axes[0].plant, n_c)
    progress(f"batched: prepare_batch for {n_c} candidates")
    setup_times, batch = timed_runs(
        lambda: servotune.prepare_batch(loop, plants=plants, seeds=1), sz.batch_runs
    )
    setup_s = statistics.median(setup_times)
    servotune.run_batch(batch, inputs, metrics_only=True, threads=2)  # warm-up
    figures = [Figure("batch_setup_s", setup_s, "s")]
    metrics = {}
    rate_name = "batched_candidate_ticks_per_s"
    for threads, name in ((2, rate_name), (1, f"{rate_name}_1thread")):
        progress(f"batched: {n_c} candidates x {n_t} ticks, {threads} thread(s)")
        times, res = timed_runs(
            lambda th=threads: servotune.run_batch(batch, inputs, metrics_only=True, threads=th),
            sz.batch_runs,
        )
        metrics[threads] = res.metrics.array
        rate = n_c * n_t / statistics.median(times)
        progress(f"batched: {rate:.4g} ticks/s (runs {[f'{t:.3f}' for t in times]} s)")
        spread = f"median of {len(times)} runs; single runs {n_c * n_t / max(times):.3g}"
        spread += f" to {n_c * n_t / min(times):.3g} ticks/s"
        figures.append(Figure(name, rate, "ticks/s", spread))
    check_batch_metrics(metrics[2], metrics[1])
    # the same candidates, each with a belt's 35 Hz mode (docs/frf.md): the resonant plant's
    # cost per tick beside the rigid one's (goal: at most 1.5x)
    from servotune.resonance import Mode

    belt = (Mode(freq_hz=35.0, damping=0.03, gain=0.5),)
    resonant = [(dataclasses.replace(p, modes=belt),) for (p,) in plants]
    res_batch = servotune.prepare_batch(loop, plants=resonant, seeds=1)
    servotune.run_batch(res_batch, inputs, metrics_only=True, threads=1)  # warm-up
    progress(f"batched: {n_c} one-mode candidates x {n_t} ticks, 1 thread")
    times, _ = timed_runs(
        lambda: servotune.run_batch(res_batch, inputs, metrics_only=True, threads=1),
        sz.batch_runs,
    )
    rate_m = n_c * n_t / statistics.median(times)
    rigid = next(f.value for f in figures if f.name == f"{rate_name}_1thread")
    ratio = rigid / rate_m
    progress(f"batched: one mode {rate_m:.4g} ticks/s, {ratio:.2f}x the rigid time per tick")
    figures.append(
        Figure(
            f"{rate_name}_one_mode_1thread",
            rate_m,
            "ticks/s",
            f"{ratio:.2f}x the rigid plant's time per tick",
        )
    )
    return figures


def check_batch_metrics(m2: np.ndarray, m1: np.ndarray) -> None:
    """Check batched metrics: finite, and the same with 2 threads as with 1.

    Parameters
    ----------
    m2, m1 : ndarray, shape (candidates, axes, metrics)
        Metrics of the 2-thread and the 1-thread runs.

    Raises
    ------
    BenchMismatchError
        If a metric is not finite or the thread counts disagree.
    """
    if not np.all(np.isfinite(m2)):
        raise BenchMismatchError("batched: non-finite metrics")
    if not np.array_equal(m2, m1):
        raise BenchMismatchError("batched: metrics differ between 2 threads and 1 thread")
    worst = m2.max(axis=(0, 1))
    progress(
        "batched: worst over candidates: "
        + ", ".join(f"{k} {v:.4g}" for k, v in zip(METRIC_NAMES, worst, strict=True))
    )


C_LOOP_SOURCE = Path(__file__).with_name("c_loop.c")
"""The C loop: the exported runtime around a C copy of the plant (see its header comment)."""
C_LOOP_FLAGS = ("-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror")
"""Strict C99 at -O2; no contraction into fused multiply-adds (the engine's operations)."""


def build_c_loop(loop: servotune.Loop, out_dir: Path) -> ctypes.CDLL:
    """Export the loop's tuning as C and build :data:`C_LOOP_SOURCE` around it.

    Parameters
    ----------
    loop : Loop
        One axis.
    out_dir : Path
        An empty directory for the sources and the library.

    Returns
    -------
    ctypes.CDLL
        With ``c_loop`` (see its C comment).
    """
    cc = shutil.which("cc")
    if cc is None:
        raise BenchMismatchError("no C compiler (cc) on PATH: the C runtime cannot be built")
    tuning = Tuning.for_rig(loop.rig, loop.controllers, rig_sha256="0" * 64)
    write_c(tuning, out_dir, rig=loop.rig, unverified=True)
    (out_dir / PLANT_HEADER).write_text(runtime_source(PLANT_HEADER))
    shutil.copy(C_LOOP_SOURCE, out_dir / "c_loop.c")
    res = subprocess.run(
        [
            cc,
            *C_LOOP_FLAGS,
            "-shared",
            "-fPIC",
            "c_loop.c",
            "servotune_rt.c",
            "-lm",
            "-o",
            "libloop.so",
        ],
        cwd=out_dir,
        capture_output=True,
        text=True,
    )
    if res.returncode != 0:
        raise BenchMismatchError(f"building the C loop failed:\n{res.stderr}")
    lib = ctypes.CDLL(str(out_dir / "libloop.so"))
    p_d, p_i = ctypes.POINTER(ctypes.c_double), ctypes.c_void_p
    lib.c_loop.argtypes = [
        ctypes.c_int64,
        p_d,
        ctypes.c_int64,
        ctypes.c_int64,
        ctypes.c_int,
        ctypes.c_double,
        ctypes.c_double,
        p_i,
        p_i,
    ]
    lib.c_loop.restype = ctypes.c_int
    return lib


@register("c_runtime")
def bench_c_runtime(opts: Options) -> list[Figure]:
    """The engine against the project's exported C runtime driving a C copy of the same plant.

    Both run the one-axis loop of :func:`one_axis_setup` on the same reference; every D/A code
    must agree (else :class:`BenchMismatchError`).

    Parameters
    ----------
    opts : Options

    Returns
    -------
    list of Figure
        ``c_runtime_one_axis_ns_per_tick``, ``engine_one_axis_ns_per_tick`` (this run) and
        ``engine_vs_c_runtime`` (engine time / C time).
    """
    loop, inputs = one_axis_setup(opts)
    rig = loop.rig
    n = inputs.n_ticks
    ref = np.ascontiguousarray(inputs.ref_counts[:, 0], dtype=np.int64)
    row, lag = plant_row(rig.axes[0].plant, rig.period_s, rig.timer.compute_s, rig.counts_per_rev)
    row = np.ascontiguousarray(row)
    codes = np.zeros(n, dtype=np.int32)
    with tempfile.TemporaryDirectory(prefix="servotune-bench-") as tmp:
        lib = build_c_loop(loop, Path(tmp))
        args = (
            n,
            row.ctypes.data_as(ctypes.POINTER(ctypes.c_double)),
            lag,
            rig.axes[0].counter_init,
            rig.counter.bits,
            rig.dac.range_v[0],
            rig.dac.lsb_v,
            ref.ctypes.data,
            codes.ctypes.data,
        )
        if lib.c_loop(*args) != 0:
            raise BenchMismatchError("c_loop: the lag needs a longer ring")
        c_times, _ = timed_runs(lambda: lib.c_loop(*args), opts.sizes.engine_runs)
    trace = servotune.simulate(loop, inputs, seed=0)
    if not np.array_equal(codes, trace.code[:, 0]):
        k = int(np.argmax(codes != trace.code[:, 0]))
        raise BenchMismatchError(f"c_runtime: codes differ from the engine's at tick {k}")
    progress(f"c_runtime: the C loop's {n} codes equal the engine's")
    e_times, _ = timed_runs(
        lambda: servotune.simulate(loop, inputs, seed=0), opts.sizes.engine_runs
    )
    c_ns = statistics.median(c_times) / n * 1e9
    e_ns = statistics.median(e_times) / n * 1e9
    progress(f"c_runtime: C {c_ns:.4g} ns/tick, engine {e_ns:.4g} ns/tick")
    return [
        Figure("c_runtime_one_axis_ns_per_tick", c_ns, "ns/tick"),
        Figure("engine_one_axis_ns_per_tick", e_ns, "ns/tick", "simulate(), traces included"),
        Figure("engine_vs_c_runtime", e_ns / c_ns, "x", "engine time over C time; < 1.5 wanted"),
    ]


@register("arch")
def bench_arch(opts: Options) -> list[Figure]:
    """The gantry and linkage kernels (docs/systems.md): ns per tick, beside their baseline.

    The baseline is :data:`ARCH_BASELINE_NS`: the same runs timed on the kernels as they were
    before they were composed from the shared tick (commit 5e122fc, this 2-core VM).

    Parameters
    ----------
    opts : Options

    Returns
    -------
    list of Figure
        ``gantry_ns_per_cycle`` (one run of the deployed topology, both drives) and
        ``linkage_ns_per_tick`` (the 6-axis example, per master tick, every axis).
    """
    runs = opts.sizes.engine_runs
    gantry = resolve_gains(load_gantry(ROOT / "plants" / "gantry.toml"))
    gantry = dataclasses.replace(gantry, seconds=2.0 if opts.quick else 20.0)
    simulate_gantry(gantry, seed=0)  # compile or cache load
    times, trace = timed_runs(lambda: simulate_gantry(gantry, seed=0), runs)
    g_ns = statistics.median(times) / trace.code.shape[0] * 1e9
    progress(f"arch: gantry {trace.code.shape[0]} cycles, {g_ns:.4g} ns/cycle")
    linkage = load_linkage(ROOT / "plants" / "linkage-6axis.toml")
    seconds = 2.0 if opts.quick else 20.0
    run_linkage(linkage, seconds=seconds)
    times, _ = timed_runs(lambda: run_linkage(linkage, seconds=seconds), runs)
    n_ticks = round(seconds / linkage.period_s)
    l_ns = statistics.median(times) / n_ticks * 1e9
    progress(f"arch: linkage {n_ticks} ticks x {linkage.n_axes} axes, {l_ns:.4g} ns/tick")
    return [
        Figure(
            "gantry_ns_per_cycle",
            g_ns,
            "ns/cycle",
            f"before the shared tick: {ARCH_BASELINE_NS['gantry']:.4g} ns/cycle",
        ),
        Figure(
            "linkage_ns_per_tick",
            l_ns,
            "ns/tick",
            f"before the shared tick: {ARCH_BASELINE_NS['linkage']:.4g} ns/tick",
        ),
    ]


# --- report ----------------------------------------------------------------------------------


def cpu_model() -> str:
    """CPU model name from ``/proc/cpuinfo`` (else :func:`platform.processor`)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() in ("model name", "Model", "cpu model"):
                return value.strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def environment() -> dict[str, Any]:
    """Versions and machine the figures were measured on."""

    def version(dist: str) -> str:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return "unknown"

    return {
        "control": control.__version__,
        "cpu_model": cpu_model(),
        "logical_cpus": os.cpu_count(),
        "numba": numba.__version__,
        "numba_threads": numba.config.NUMBA_NUM_THREADS,
        "numpy": np.__version__,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "scipy": version("scipy"),
        "servotune": servotune.__version__,
    }


def report(figures: Sequence[Figure], quick: bool) -> dict[str, Any]:
    """The JSON report (schema ``servotune.bench/1``).

    Parameters
    ----------
    figures : sequence of Figure
    quick : bool
        Whether the figures come from ``--quick`` sizes.

    Returns
    -------
    dict
    """
    figs: dict[str, dict[str, Any]] = {}
    for f in figures:
        entry: dict[str, Any] = {"unit": f.unit, "value": float(f.value)}
        if f.note:
            entry["note"] = f.note
        figs[f.name] = entry
    return {"environment": environment(), "figures": figs, "quick": quick, "schema": SCHEMA}


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Write JSON atomically (a temporary file in the same folder, then :func:`os.replace`).

    Parameters
    ----------
    path : Path
    data : dict
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=2, sort_keys=True)
            fh.write("\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)  # mkstemp creates the file private (0600)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """Command-line arguments."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="write the JSON report here (e.g. reports/bench.json)")
    ap.add_argument(
        "--only",
        nargs="+",
        choices=sorted(BENCHES),
        metavar="NAME",
        help=f"run only these benchmarks ({', '.join(BENCHES)})",
    )
    ap.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    ap.add_argument(
        "--scale-plants",
        type=int,
        default=None,
        metavar="N",
        help="plant sets of the 'scale' benchmark (default 1000000: the whole "
        "target run, about 4.5 minutes on 2 cores; fewer: extrapolated)",
    )
    return ap.parse_args(argv)


@register("fit")
def bench_fit(opts: Options) -> list[Figure]:
    """``servotune fit`` on a long closed-loop log with friction, per method, beside scipy.

    The log is the example rig's master under a closed-loop multi-level PRBS (lock module
    active, drift, Coulomb friction, noise, counter wraps), made by the virtual rig and written
    once (not timed) as a single-axis identification log (the master's columns, with the
    excitation ``exc_code`` that ``servotune simulate`` logs). Each run is a fresh
    ``servotune fit LOG --axis master --json [--method M]`` process (Python start-up, imports,
    the compiled code's cache and reading the million-row CSV included), estimating on the
    whole log with structure selection, split-half cross-validation, the bootstrap and the
    diagnostics. Beside them, in this process: a bare ``scipy.optimize.least_squares`` of the
    same model (the identifier's simulation of the increments, all samples, scipy's own
    two-point Jacobian, trust-region reflective) from the least-squares start of the true
    structure.

    Returns
    -------
    list of Figure
        ``fit_1M_samples_s`` (the default method), ``fit_1M_samples_iv_s``,
        ``fit_1M_samples_oe_s`` and ``fit_1M_samples_scipy_least_squares_s`` (``<n>`` for
        other sizes); goal under 2 s for the default, at most 5 s.
    """
    import subprocess

    from scipy.optimize import least_squares

    from servotune.identify import model as id_model
    from servotune.logs import read_log, write_log
    from servotune.pipeline import log_metadata, run_scenario, trace_log_columns

    n = opts.sizes.fit_samples
    tag = "1M" if n == 1_000_000 else str(n)
    rig = servotune.load_rig(opts.rig_path)
    seconds = n * rig.period_s
    scen = servotune.build_scenario(rig, "prbs", axis="master", seconds=seconds, closed_loop=True)
    progress(f"fit: simulating and writing a {n}-sample log")
    trace = run_scenario(rig, scen, seed=7)
    truth = rig.axis("master").plant
    figures = []
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "long.csv"
        cols = {
            k: v
            for k, v in trace_log_columns(trace, scen.inputs.dac_add_codes).items()
            if k.startswith("master.")
        }
        write_log(path, period_s=rig.period_s, columns=cols, metadata=log_metadata(rig, seed=7))
        exe = str(Path(sys.executable).parent / "servotune")
        base = [exe, "fit", str(path), "--axis", "master", "--json"]
        subprocess.run(base, check=True, capture_output=True)  # warm the numba cache
        for label, extra in (("", []), ("_iv", ["--method", "iv"]), ("_oe", ["--method", "oe"])):
            times = []
            for i in range(opts.sizes.fit_runs):
                t0 = time.perf_counter()
                r = subprocess.run(base + extra, check=True, capture_output=True, text=True)
                times.append(time.perf_counter() - t0)
                progress(f"fit{label}: run {i + 1}: {times[-1]:.2f} s")
            doc = json.loads(r.stdout)
            err = abs(doc["params"]["gain_cps_per_v"] / truth.gain_cps_per_v - 1)
            if err > 0.02:
                raise RuntimeError(f"fit{label} on the bench log is off by {err:.1%} in gain")
            note = f"method {doc['method']}; goal < 2 s, at most 5 s" if not label else None
            figures.append(
                Figure(f"fit_{tag}_samples{label}_s", statistics.median(times), "s", note)
            )
        # the same model fitted by a bare scipy least_squares on all samples
        ax = read_log(path).axis("master")
        u, y = ax.cmd_v, ax.pos_counts
        dy = np.diff(y).astype(float)
        free = id_model.free_mask(id_model.OPTIONAL_PARAMS, "sym")
        x0 = id_model.ls_start(u, y, rig.period_s, rig.timer.compute_s, free)
        inputs = np.ascontiguousarray(u[:-1])[None, :]
        v0 = float(np.mean(dy[:5]) / rig.period_s)

        def residual(z: np.ndarray) -> np.ndarray:
            x = x0.copy()
            x[free] = z
            sim = id_model.simulate_increments(
                inputs, [x], free, [0], period_s=rig.period_s, compute_s=rig.timer.compute_s, v0=v0
            )
            return (dy - sim[0])[50:]

        lo, hi = id_model.lower_bounds()[free], id_model.upper_bounds(rig.period_s)[free]
        z0 = np.clip(x0[free], lo, hi)
        times = []
        for i in range(opts.sizes.fit_runs):
            t0 = time.perf_counter()
            sol = least_squares(
                residual, z0, bounds=(lo, hi), method="trf", x_scale=np.maximum(np.abs(z0), 1e-3)
            )
            times.append(time.perf_counter() - t0)
            progress(f"fit scipy least_squares: run {i + 1}: {times[-1]:.2f} s ({sol.nfev} nfev)")
        note = "in-process, the fit call only (no reading, no process)"
        figures.append(
            Figure(f"fit_{tag}_samples_scipy_least_squares_s", statistics.median(times), "s", note)
        )
    return figures


@register("capture")
def bench_capture(opts: Options) -> list[Figure]:
    """Reading long captures and logs, one of each kind the tool reads: a halsampler capture
    (three pins), a halscope file (three channels), a servotune log (``tick,dac_code,counter``)
    and a CSV mapped by ``--map`` (four columns, one not mapped): 10,000,000 lines each (the
    quick preset 1,000,000), written here, then read once, warm.

    Returns
    -------
    list of Figure
        Per kind, ``capture_<kind>_read_s`` (the read) and ``capture_<kind>_mb_per_s``.
    """
    from servotune.io.hal import read_halsampler, read_halscope, read_mapped_csv
    from servotune.logs import read_log

    lines = 1_000_000 if opts.quick else 10_000_000
    i = np.arange(100_000)
    sine = [f"{x:f}" for x in np.sin(i / 7)]
    kinds: dict[str, tuple[str, str, Callable[[Path], Any]]] = {
        "halsampler": (
            "",
            "".join(f"{s} {k % 13 - 6} {k // 5} \n" for s, k in zip(sine, i.tolist(), strict=True)),
            lambda p: read_halsampler(p, columns=["cmd", "pos", "ref"]).n_samples,
        ),
        "halscope": (
            "# Sampling period is 1000000 ns\ncmd;pos;ref\n",
            "".join(f"{s};{k % 13 - 6};{k // 5}\n" for s, k in zip(sine, i.tolist(), strict=True)),
            lambda p: read_halscope(p).n_samples,
        ),
        "log": (
            "# period_s: 0.004\ntick,dac_code,counter\n",
            None,  # the tick runs on: written below
            lambda p: read_log(p).axis().pos_counts.size,
        ),
        "mapped_csv": (
            "# period_s: 0.001\nu,y,r,note\n",
            "".join(
                f"{s},{k // 5},{k % 13},{k % 3}\n" for s, k in zip(sine, i.tolist(), strict=True)
            ),
            lambda p: read_mapped_csv(p, {"cmd": "u", "pos": "y", "ref": "r"}).n_samples,
        ),
    }
    figures: list[Figure] = []
    for kind, (head, block, read) in kinds.items():
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "capture.txt"
            with open(path, "w") as f:
                f.write(head)
                for b in range(lines // 100_000):
                    if block is None:
                        k = i + b * 100_000
                        f.write(
                            "".join(f"{t},{2048 + t % 400},{t * 3 % 2**24}\n" for t in k.tolist())
                        )
                    else:
                        f.write(block)
            size = path.stat().st_size
            read(path)  # the page cache and the compiled parser warm
            times, n = timed_runs(lambda: read(path), 1)  # noqa: B023 (called here)
        if n != lines:
            raise RuntimeError(f"{kind}: read {n} samples of {lines}")
        progress(f"capture {kind}: {lines:,} lines, {size / 1e6:.0f} MB in {times[0]:.1f} s")
        figures += [
            Figure(
                f"capture_{kind}_read_s", times[0], "s", f"{lines:,} lines, {size / 1e6:.0f} MB"
            ),
            Figure(f"capture_{kind}_mb_per_s", size / 1e6 / times[0], "MB/s", None),
        ]
    return figures


@register("frf")
def bench_frf(opts: Options) -> list[Figure]:
    """The frequency response of a 1,000,000-sample closed-loop log
    (:func:`servotune.analysis.frf.estimate_frf`, the period found from the excitation): a
    Schroeder multisine of 2,500-tick periods through a first-order lag with noise, generated
    here (the quick preset 100,000 samples).

    Returns
    -------
    list of Figure
        ``frf_1m_s`` (the estimate, warm) and ``mode_fit_s`` (the modes of a belt-driven axis,
        a 35 Hz mode, fitted to its response with the order chosen: 0 to 3 modes tried).
    """
    from scipy import signal as sp_signal

    from servotune.analysis.frf import estimate_frf
    from servotune.excite import periodic_multisine

    n = 100_000 if opts.quick else 1_000_000
    m = periodic_multisine(2500, n // 2500, 0.004, 800, band_hz=(0.5, 100))
    u = m.codes * (20.0 / 4096)
    y = sp_signal.lfilter([0.0, 50.0], [1.0, -0.9], u)
    y = np.rint(y + np.random.default_rng(0).normal(0.0, 0.5, n)).astype(np.int64)
    times, f = timed_runs(lambda: estimate_frf(u, y, m.codes, period_s=0.004), 3)
    progress(f"frf: {n:,} samples, {f.freq_hz.size} lines in {min(times):.3f} s")
    # the modes of a belt-driven axis (a 35 Hz mode) fitted to its response, order "auto"
    import control

    from servotune.identify.modes import fit_modes

    w = 2 * np.pi * 35.0
    s = control.tf("s")
    belt = 12288.0 / (s * (0.025 * s + 1)) * (1 + 0.5 * s**2 / (s**2 + 0.06 * w * s + w**2))
    d = control.sample_system(control.ss(belt), 0.004, method="zoh")
    m8 = periodic_multisine(2500, 8, 0.004, 800, band_hz=(0.5, 50))
    u8 = m8.codes * (20.0 / 4096)
    _, yb, _ = sp_signal.dlsim((d.A, d.B, d.C, d.D, 0.004), u8)
    yb = np.rint(yb[:, 0] + np.random.default_rng(0).normal(0.0, 0.5, u8.size))
    fb = estimate_frf(u8, yb, m8.codes, period_s=0.004)
    mode_times, fit = timed_runs(lambda: fit_modes(fb, n_modes="auto"), 3)
    progress(f"mode fit: {fb.freq_hz.size} lines, {len(fit.modes)} mode in {min(mode_times):.2f} s")
    return [
        Figure("frf_1m_s", min(times), "s", f"{n:,} samples, {f.freq_hz.size} lines"),
        Figure("mode_fit_s", min(mode_times), "s", f"{fb.freq_hz.size} lines, order auto"),
    ]


def _time_tune(rig_path: Path, runs: int, what: str) -> list[float]:
    import subprocess

    exe = str(Path(sys.executable).parent / "servotune")
    times = []
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "tuning.json"
        cmd = [exe, "tune", str(rig_path), "-o", str(out), "--no-current"]
        subprocess.run(cmd, check=True, capture_output=True)  # warm the numba cache
        first = out.read_bytes()
        for i in range(runs):
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            times.append(time.perf_counter() - t0)
            progress(f"{what}: run {i + 1}: {times[-1]:.2f} s")
            if out.read_bytes() != first:
                raise RuntimeError("servotune tune gave different bytes for the same seed")
    return times


@register("tune")
def bench_tune(opts: Options) -> list[Figure]:
    """``servotune tune`` end to end on the example rig (default budget, fresh process).

    Each run is ``servotune tune RIG -o FILE --no-current``: start-up, PI synthesis of both
    axes, query tables, the slave's optimisation over batched runs, the tuning file.

    Returns
    -------
    list of Figure
        ``tune_example_rig_s``; goal under 60 s.
    """
    times = _time_tune(opts.rig_path, opts.sizes.fit_runs, "tune")
    return [Figure("tune_example_rig_s", statistics.median(times), "s", "goal < 60 s")]


@register("tune_filters")
def bench_tune_filters(opts: Options) -> list[Figure]:
    """``servotune tune`` on the resonant example rig (plants/belt-scale.toml), where it also
    chooses the master's filters (eight robust PI designs: four candidates, then the best of
    them with four leads) before the slave's law.

    Returns
    -------
    list of Figure
        ``tune_resonant_rig_s``; goal under 60 s.
    """
    from servotune.examples import example_path

    times = _time_tune(example_path("belt-scale.toml"), opts.sizes.fit_runs, "tune_filters")
    return [Figure("tune_resonant_rig_s", statistics.median(times), "s", "goal < 60 s")]


@register("demo")
def bench_demo(opts: Options) -> list[Figure]:
    """``servotune demo`` (the quick preset ``make demo`` runs) end to end, warm, in a fresh
    process: simulate, fit, tune, Figure 4, gantry and linkage, verify, export, report.

    Returns
    -------
    list of Figure
        ``demo_quick_warm_s``; goal under 30 s
        (docs/decisions.md#9-the-demo-preset).
    """
    import subprocess

    exe = str(Path(sys.executable).parent / "servotune")
    times = []
    with tempfile.TemporaryDirectory() as d:
        cmd = [exe, "demo", str(opts.rig_path), "--out", d]
        subprocess.run(cmd, check=True, capture_output=True)  # warm the numba cache
        for i in range(max(1, opts.sizes.fit_runs // 2)):
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            times.append(time.perf_counter() - t0)
            progress(f"demo: run {i + 1}: {times[-1]:.2f} s")
    return [Figure("demo_quick_warm_s", statistics.median(times), "s", "goal < 30 s")]


@register("montecarlo")
def bench_montecarlo(opts: Options) -> list[Figure]:
    """Monte-Carlo verification: the example rig's default tuning against its shipped spec over
    10,000 sampled plants (200 with ``--quick``), in the bit-true batched engine.

    Returns
    -------
    list of Figure
        ``montecarlo_10000_plants_s`` (the whole ``verify``: every scenario on every plant, the
        checks and the margins; target under 60 s) and ``montecarlo_plant_ticks_per_s`` (plants
        × axes × ticks of all scenarios over that time).
    """
    from servotune.tune.workflow import tune_rig
    from servotune.verify import load_spec, verify

    n = 200 if opts.quick else 10_000
    rig = servotune.load_rig(opts.rig_path)
    spec = load_spec(opts.rig_path.with_suffix(".spec.toml"))
    spec = dataclasses.replace(spec, montecarlo=dataclasses.replace(spec.montecarlo, count=n))
    progress("montecarlo: tuning the example rig (not timed)")
    tuning = tune_rig(opts.rig_path)
    verify(
        tuning,
        rig,
        dataclasses.replace(spec, montecarlo=dataclasses.replace(spec.montecarlo, count=2)),
    )  # compile or cache load
    t0 = time.perf_counter()
    v = verify(tuning, rig, spec)
    dt = time.perf_counter() - t0
    k, count, frac, lo, hi = v.pass_fraction
    ticks = sum(round(sc.seconds / rig.period_s) for sc in spec.scenarios)
    rate = (count + 1) * len(rig.axes) * ticks / dt
    progress(
        f"montecarlo: {count} plants in {dt:.1f} s, {k} keep every limit "
        f"({100 * frac:.2f} %, 95 % CI {100 * lo:.2f}–{100 * hi:.2f} %)"
    )
    tag = "10000" if n == 10_000 else str(n)
    return [
        Figure(
            f"montecarlo_{tag}_plants_s",
            dt,
            "s",
            f"pass fraction {100 * frac:.2f} % [{100 * lo:.2f}, {100 * hi:.2f}]; target < 60 s",
        ),
        Figure("montecarlo_plant_ticks_per_s", rate, "axis·ticks/s", None),
    ]


SCALE_PLANTS = 1_000_000
"""Plant sets the ``scale`` benchmark measures on: the target run, measured, not extrapolated
(``--scale-plants`` fewer: then the time for :data:`SCALE_TARGET` is extrapolated and says so)."""
SCALE_TARGET = 1_000_000
"""The target run: plant sets of the example rig through its sync scenario (docs/scale.md)."""


@register("scale")
def bench_scale(opts: Options) -> list[Figure]:
    """Monte-Carlo verification at scale: the example rig's default tuning over plant sets drawn
    from its spec's spread, through the spec's ``sync`` scenario (the slave-tuning move), on
    the in-process executor (the batched engine on 2 numba threads, the Python around it on
    one) and on a ``LocalCluster`` of 2 and of 1 worker processes (one thread each); the
    three results must be identical.

    A plant·tick is one axis's plant advanced one tick: a plant set of the example rig is two
    plants (master and slave), the sync scenario 600 ticks (2.4 s at 4 ms). Each rate is over
    the Monte-Carlo part of ``verify``: the wall time of the run minus that of a run with no
    plant sets but the nominal ones (the checks and the loop margins, about half a second),
    each after a warm-up run on the same executor (compiled code loaded, workers' imports
    done). The loop margins run while the chunks run, so the difference is the time the plant
    sets add; the wall times are reported beside the rates.
    Measured on :data:`SCALE_PLANTS` plant sets (``--scale-plants``; on fewer, the time for
    :data:`SCALE_TARGET` is extrapolated at the measured rate and says so). The clusters are
    the one ``open_executor`` starts (:func:`servotune.executor.local_cluster`).

    Returns
    -------
    list of Figure
        ``scale_plant_sets`` (measured), ``scale_inprocess_plant_ticks_per_s``,
        ``scale_cluster2_plant_ticks_per_s``, ``scale_cluster1_plant_ticks_per_s``, their wall
        times ``scale_*_s``, ``scale_cluster2_vs_inprocess`` (rate ratio; target >= 0.85),
        ``scale_cluster_2_vs_1_workers``, ``scale_cluster_start_s`` (cluster up and the first
        task back), ``scale_whole_spec_inprocess_plant_ticks_per_s`` and ``_s`` (every scenario
        of the spec, in-process), ``scale_1e6_plants_cluster2_s_extrapolated``.
    """
    from servotune.executor import InProcessExecutor
    from servotune.tune.workflow import tune_rig
    from servotune.verify import load_spec, verify

    n = 300 if opts.quick else (opts.scale_plants or SCALE_PLANTS)
    rig = servotune.load_rig(opts.rig_path)
    spec = load_spec(opts.rig_path.with_suffix(".spec.toml"))
    sync = next(sc for sc in spec.scenarios if sc.name == "sync")
    ticks = round(sync.seconds / rig.period_s)
    per_set = len(rig.axes) * ticks  # plant·ticks of one plant set

    def spec_of(count: int, scenarios: tuple[Any, ...] = (sync,)) -> Any:
        mc = dataclasses.replace(spec.montecarlo, count=count)
        return dataclasses.replace(spec, scenarios=scenarios, montecarlo=mc)

    progress("scale: tuning the example rig (not timed)")
    tuning = tune_rig(opts.rig_path)

    def measure(
        ex: Any, label: str, scenarios: tuple[Any, ...] = (sync,)
    ) -> tuple[float, float, dict[str, Any]]:
        verify(tuning, rig, spec_of(2, scenarios), executor=ex)  # warm-up: compiled code, imports
        t0 = time.perf_counter()
        verify(tuning, rig, spec_of(0, scenarios), executor=ex)
        base = time.perf_counter() - t0
        t0 = time.perf_counter()
        v = verify(tuning, rig, spec_of(n, scenarios), executor=ex)
        wall = time.perf_counter() - t0
        per = len(rig.axes) * sum(round(sc.seconds / rig.period_s) for sc in scenarios)
        rate = n * per / max(wall - base, 1e-9)
        progress(
            f"scale: {label}: {n:,} plant sets in {wall:.1f} s ({base:.1f} s of it the "
            f"checks), {rate:.3g} plant·ticks/s"
        )
        return rate, wall, v.to_dict()

    rates: dict[str, float] = {}
    walls: dict[str, float] = {}
    docs: dict[str, Any] = {}
    rates["inprocess"], walls["inprocess"], docs["inprocess"] = measure(
        InProcessExecutor(), "in-process"
    )
    # the whole shipped spec (every scenario: the moves, the hold, the held-out move), in-process
    whole_rate, whole_wall, _ = measure(
        InProcessExecutor(), "in-process, whole spec", spec.scenarios
    )
    whole_ticks = sum(round(sc.seconds / rig.period_s) for sc in spec.scenarios)
    start_s = math.nan
    from servotune.executor import local_cluster

    for workers in (2, 1):  # the cluster open_executor starts (it runs 1 worker in-process)
        t0 = time.perf_counter()
        with local_cluster(workers) as ex:
            ex.map(abs, [-1])  # the cluster answers
            if workers == 2:
                start_s = time.perf_counter() - t0
            key = f"cluster{workers}"
            rates[key], walls[key], docs[key] = measure(ex, ex.name)
    for key in ("cluster2", "cluster1"):
        if json.dumps(docs[key], sort_keys=True) != json.dumps(docs["inprocess"], sort_keys=True):
            raise BenchMismatchError(f"scale: the {key} result differs from the in-process one")
    ratio = rates["cluster2"] / rates["inprocess"]
    growth = rates["cluster2"] / rates["cluster1"]
    target_s = SCALE_TARGET * per_set / rates["cluster2"]
    measured = f"measured on {n:,} plant sets ({n * per_set:.3g} plant·ticks)"
    figures = [
        Figure(
            "scale_plant_sets",
            n,
            "plant_sets",
            f"sync scenario, {ticks} ticks, "
            f"{len(rig.axes)} plants per set; identical results on every executor",
        )
    ]
    for key, label in (
        ("inprocess", "in-process: engine on 2 threads, Python on 1"),
        ("cluster2", "LocalCluster, 2 workers x 1 thread"),
        ("cluster1", "LocalCluster, 1 worker x 1 thread"),
    ):
        figures.append(
            Figure(
                f"scale_{key}_plant_ticks_per_s",
                rates[key],
                "plant·ticks/s",
                f"{label}; {measured}; target >= 5e7",
            )
        )
        figures.append(Figure(f"scale_{key}_s", walls[key], "s", f"{label}; {measured}"))
    figures += [
        Figure("scale_cluster2_vs_inprocess", ratio, "x", "rate ratio; target >= 0.85"),
        Figure("scale_cluster_2_vs_1_workers", growth, "x", "rate ratio; ideal 2"),
        Figure("scale_cluster_start_s", start_s, "s", "2 workers up and a first task back"),
        Figure(
            "scale_whole_spec_inprocess_plant_ticks_per_s",
            whole_rate,
            "plant·ticks/s",
            f"every scenario of the spec ({whole_ticks} ticks per plant set), in-process; "
            f"measured on {n:,} plant sets",
        ),
        Figure(
            "scale_whole_spec_inprocess_s",
            whole_wall,
            "s",
            f"every scenario of the spec, in-process, {n:,} plant sets",
        ),
        Figure(
            "scale_1e6_plants_cluster2_s_extrapolated",
            target_s,
            "s",
            f"EXTRAPOLATED from {n:,} plant sets at the 2-worker rate, not measured"
            if n < SCALE_TARGET
            else "measured (scale_cluster2_s less the checks)",
        ),
    ]
    return figures


def main(argv: Sequence[str] | None = None) -> int:
    """Run the selected benchmarks, print the figures, write the report.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments (default ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status.
    """
    args = parse_args(argv)
    opts = Options(quick=args.quick, scale_plants=args.scale_plants)
    names = [n for n in BENCHES if args.only is None or n in args.only]
    figures: list[Figure] = []
    for name in names:
        progress(f"{name} ...")
        t0 = time.perf_counter()
        for fig in BENCHES[name](opts):
            print(f"bench: {fig.name} {fig.value:.6g} {fig.unit}", flush=True)
            figures.append(fig)
        progress(f"{name} done in {time.perf_counter() - t0:.1f} s")
    if args.out is not None:
        write_json(args.out, report(figures, args.quick))
        progress(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
