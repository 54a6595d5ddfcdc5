"""The reference C runtime (servotune/export/runtime) against the Python laws, bit for bit.

The runtime and a tuning's exported ``servotune_tables.h`` are compiled with the system C
compiler (strict C99 flags) into a shared library, together with a small harness (below) that
initialises ``st_consts_t`` from ``SERVOTUNE_TABLES_INIT`` and drives ``st_tick``.

- Golden run: the C runtime closes the loop around the simulator's plants (``plant_row`` and
  ``advance_tick`` exactly as ``engine._run_group`` uses them, noise off) for 110,000 ticks,
  and every tick's D/A codes and flags (and positions, errors, modes, counter registers) must
  equal :func:`servotune.sim.engine.simulate` on the same inputs. The scenario has counter wraps
  both ways on both axes, D/A saturation, lock/task handovers both ways, a reset in task mode,
  excitation in lock and open loop, a following-error trip of the master and a counter fault
  (a load kick too fast for the high-byte rule) of the slave, and resets.
- Replay: raw counter sequences with injected jumps, random modes (one invalid), resets,
  extreme references and added commands, on constants at the edges of their ranges (three
  axes, 16/24/32-bit counters, 8/12/16-bit D/As), fed to both the Python tick functions
  (``axis_read``/``axis_control``) and the C runtime.
- The golden run and the replays once more under ``-fsanitize=undefined
  -fno-sanitize-recover``: any undefined behaviour aborts the harness.
- The plant's C mirror (``servotune_plant.h``, the HAL plant component's) against the
  simulator's compiled plant step (:func:`servotune.plant.advance_tick_modal`) for 120,000
  ticks from the same inputs: a linear plant with two modes (docs/frf.md) and a fractional
  delay, the same with Coulomb friction, asymmetric gain and a speed limit under an input that
  reverses often (speed zero crossings inside a piece, sticking), and that plant without modes
  (also through ``st_plant_advance_tick``); position, speed, every mode state and the measured
  position and speed equal as float64 bits every tick.
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from c_build import (
    HARNESS_HEAD,
    STRICT,
    TICK_C,
    cc,
    export_harness,
    needs_cc,
    run_replay,
    shared_harness,
    ubsan_harness,
)

from servotune._numba_cache import jit
from servotune.export.c import PLANT_RUNTIME_FILES, runtime_source
from servotune.export.json import constants_crc32, tables_document
from servotune.fixed import Fixed, align, clamp_e, sat_add, shift_round
from servotune.hw.counter import unwrap_step
from servotune.laws.axis import (
    FLAG_COUNTER_FAULT,
    FLAG_FOLLOWING_ERROR,
    FLAG_SATURATED,
    MODE_LOCK,
    MODE_OPEN,
    MODE_TASK,
    N_STATE,
    S_MODE,
    AxisController,
    axis_control,
    axis_read,
)
from servotune.laws.fuzzy_pid import FuzzyPIDConstants
from servotune.laws.pi import PIConstants
from servotune.plant import (
    R_GAIN,
    R_H1,
    R_LINEAR,
    R_MODES,
    R_OFFSET,
    R_VMAX,
    Plant,
    advance_tick,
    advance_tick_modal,
    plant_row,
)
from servotune.resonance import MAX_MODES, Mode, modes_output, modes_speed
from servotune.rig import (
    EXAMPLE_RIG_PATH,
    Axis,
    Counter,
    Dac,
    Encoder,
    Rig,
    Timer,
    load_rig,
)
from servotune.scenarios import Inputs, trapezoid_ref
from servotune.sim.engine import Loop, Trace, simulate
from servotune.sim.tick import noise_draws
from servotune.tuning import Tuning

pytestmark = needs_cc

INT64_MAX = 2**63 - 1

HARNESS = (
    HARNESS_HEAD
    + r"""
uint32_t h_table_crc32(int a, int i)
{
    const st_axis_consts_t *x = &consts.axis[a];
    return x->tab[i] != NULL ? st_table_crc32(x->n, x->tf[i], x->tab[i]) : 0;
}

/* st_check_consts on a copy with one field broken */
int h_check_broken(int what)
{
    st_consts_t c = consts;
    if (what == 0) {
        c.n_axes = ST_MAX_AXES + 1;
    } else if (what == 1) {
        c.axis[0].kp_f = 33;
    } else if (what == 2) {
        c.axis[1].tf[0] = (int16_t)(c.axis[1].kp_f + 1);
    } else if (what == 3) {
        c.axis[1].tf[0] = 0; /* scheduled gains out of 0 .. 2^32 - 1 */
    } else if (what == 4) {
        c.axis[1].ref_source = 1;
    }
    return st_check_consts(&c);
}

"""
    + TICK_C
    + r"""
/* primitives, for the edge tests */
int64_t h_shift_round(int64_t x, int f) { return st_shift_round(x, f); }
int64_t h_sat_add(int64_t a, int64_t b) { return st_sat_add(a, b); }
int64_t h_align(int64_t x, int k) { return st_align(x, k); }
int64_t h_clamp_e(int64_t x) { return st_clamp_e(x); }
int h_unwrap_step(int64_t raw, int64_t hi_prev, int64_t wraps, int bits, int64_t *res)
{
    int64_t pos = 0;
    const int fault = st_unwrap_step(raw, &hi_prev, &wraps, bits, &pos);
    res[0] = pos;
    res[1] = hi_prev;
    res[2] = wraps;
    return fault;
}

#ifdef H_MAIN
/* file replay: in = n, axes, then raw, ref, mode, reset, u_add (int64, n * axes each);
 * out = the (n, axes, 5) outputs */
int main(int argc, char **argv)
{
    int64_t head[2];
    int64_t *buf;
    int64_t *out;
    size_t cells;
    FILE *f;
    if (argc != 3) {
        return 2;
    }
    f = fopen(argv[1], "rb");
    if (f == NULL || fread(head, sizeof head[0], 2, f) != 2 || head[1] != consts.n_axes) {
        return 3;
    }
    cells = (size_t)head[0] * (size_t)head[1];
    buf = malloc(5 * cells * sizeof *buf);
    out = malloc(5 * cells * sizeof *out);
    if (buf == NULL || out == NULL || fread(buf, sizeof *buf, 5 * cells, f) != 5 * cells) {
        return 4;
    }
    fclose(f);
    if (h_check() != 0) {
        return 5;
    }
    h_reset();
    h_run(head[0], buf, buf + cells, buf + 2 * cells, buf + 3 * cells, buf + 4 * cells, out);
    f = fopen(argv[2], "wb");
    if (f == NULL || fwrite(out, sizeof *out, 5 * cells, f) != 5 * cells) {
        return 6;
    }
    fclose(f);
    free(buf);
    free(out);
    return 0;
}
#endif
"""
)


# --- building ---------------------------------------------------------------------------------


def _export(tuning: Tuning, out_dir: Path, rig: Rig | None = None) -> Path:
    return export_harness(tuning, out_dir, HARNESS, rig)


class Runtime:
    """The compiled harness (shared library) through ctypes."""

    def __init__(self, src_dir: Path) -> None:
        lib = shared_harness(src_dir, "libharness.so")
        i64, p = ctypes.c_int64, ctypes.c_void_p
        for name, res, args in (
            ("h_tick", None, [p] * 6),
            ("h_run", None, [i64] + [p] * 6),
            ("h_consts_crc32", ctypes.c_uint32, []),
            ("h_table_crc32", ctypes.c_uint32, [ctypes.c_int, ctypes.c_int]),
            ("h_shift_round", i64, [i64, ctypes.c_int]),
            ("h_sat_add", i64, [i64, i64]),
            ("h_align", i64, [i64, ctypes.c_int]),
            ("h_clamp_e", i64, [i64]),
            ("h_unwrap_step", ctypes.c_int, [i64, i64, i64, ctypes.c_int, p]),
            ("h_check_broken", ctypes.c_int, [ctypes.c_int]),
        ):
            fn = getattr(lib, name)
            fn.restype = res
            fn.argtypes = args
        self.lib = lib
        self.n_axes = lib.h_n_axes()

    def run(self, raw, ref, mode, reset, u_add) -> np.ndarray:
        """Replay per-tick inputs (arrays (ticks, axes)); outputs (ticks, axes, 5):
        code, flags, e, y, mode."""
        arrs = [np.ascontiguousarray(x, dtype=np.int64) for x in (raw, ref, mode, reset, u_add)]
        n = arrs[0].shape[0]
        out = np.zeros((n, self.n_axes, 5), dtype=np.int64)
        self.lib.h_reset()
        self.lib.h_run(n, *(a.ctypes.data for a in arrs), out.ctypes.data)
        return out


def _replay_python(controllers, refs, hw: dict, raw, ref, mode, reset, u_add) -> np.ndarray:
    """The same replay through the Python tick functions (what the engine calls)."""
    rows = [
        c.consts(
            counter_bits=hw["counter_bits"],
            dac_bits=hw["dac"]["bits"],
            dac_zero=hw["dac"]["zero_code"],
        )
        for c in controllers
    ]
    n_ax = len(rows)
    c = np.zeros((n_ax, max(len(r) for r in rows)), dtype=np.int64)
    for a, r in enumerate(rows):
        c[a, : len(r)] = r
    st = np.zeros((n_ax, N_STATE), dtype=np.int64)
    n = raw.shape[0]
    out = np.zeros((n, n_ax, 5), dtype=np.int64)
    y = [0] * n_ax
    for k in range(n):
        for a in range(n_ax):
            y[a] = axis_read(st, c, a, int(raw[k, a]), bool(reset[k, a]))
        for a in range(n_ax):
            r = int(ref[k, a]) if refs[a] < 0 else y[refs[a]]
            code, flags, e = axis_control(
                st, c, a, r, int(mode[k, a]), bool(reset[k, a]), int(u_add[k, a])
            )
            out[k, a] = (code, flags, e, y[a], st[a, S_MODE])
    return out


def _ubsan_replay(src_dir: Path, raw, ref, mode, reset, u_add) -> np.ndarray:
    """Replay through the harness built with the undefined-behaviour sanitizer."""
    arrs = [np.ascontiguousarray(x, dtype=np.int64) for x in (raw, ref, mode, reset, u_add)]
    n, n_ax = arrs[0].shape
    payload = np.array([n, n_ax], dtype=np.int64).tobytes() + b"".join(a.tobytes() for a in arrs)
    out = run_replay(ubsan_harness(src_dir, "harness_ubsan"), payload, timeout=120)
    return np.frombuffer(out, dtype=np.int64).reshape(n, n_ax, 5)


# --- the tuning and the golden scenario -------------------------------------------------------

N_GOLDEN = 110_000
MASTER_FE_LIMIT = 20_000  # [counts]: trips on the 40,000-count reference step below


@pytest.fixture(scope="module")
def tuning(quick_tuning) -> Tuning:
    """A real tuning (tiny budget, seed 0: deterministic), the master's following-error limit
    lowered so that a reference step can trip it."""
    t = quick_tuning
    ctl = list(t.controllers)
    ctl[0] = dataclasses.replace(ctl[0], following_error_limit_counts=MASTER_FE_LIMIT)
    return dataclasses.replace(t, controllers=tuple(ctl))


def golden_rig() -> Rig:
    """The example rig without encoder noise (reproducible); no drive speed limit on the slave
    so that a load kick can move it faster than the high-byte rule can follow."""
    r = load_rig(EXAMPLE_RIG_PATH)
    m, s = r.axes
    m = dataclasses.replace(m, plant=dataclasses.replace(m.plant, noise_counts=0.0))
    s = dataclasses.replace(
        s, plant=dataclasses.replace(s.plant, noise_counts=0.0, max_speed_rpm=None)
    )
    return dataclasses.replace(r, axes=(m, s))


def golden_inputs(rig: Rig) -> Inputs:
    """110,000 ticks (7.3 min): moves, steps, a trip, excitation, a counter fault, resets."""
    n, period = N_GOLDEN, rig.period_s
    v_max = rig.axes[0].speed_limit_rpm / 60.0 * rig.counts_per_rev  # [counts/s]
    ref = np.zeros(n, dtype=np.int64)
    mode = np.zeros((n, 2), dtype=np.int64)
    reset = np.zeros((n, 2), dtype=bool)
    u_add = np.zeros((n, 2), dtype=np.int64)
    load = np.zeros((n, 2))

    def move(t0: int, dist: int, speed_fraction: float, accel_s: float) -> None:
        # both axes in task over the move (the slave follows the master), lock around it
        v = speed_fraction * v_max
        ref[:] += trapezoid_ref(n, period, dist, v, v / accel_s, start_tick=t0)
        dur = math.ceil((abs(dist) / v + accel_s) / period)
        mode[t0 - 100 : t0 + dur + 400, :] = MODE_TASK

    # long moves back and forth across both registers' wraps (master starts at 0xFFC000,
    # slave at 0x000400), some accelerating hard enough to saturate the D/A
    pattern = [
        (60_000, 0.5, 0.1),
        (-100_000, 0.8, 0.05),
        (45_000, 0.9, 0.02),
        (-30_000, 0.3, 0.2),
        (80_000, 0.7, 0.03),
        (-55_000, 0.95, 0.02),
    ]
    t = 1000
    while t < 70_000:
        for dist, frac, acc in pattern:
            move(t, dist, frac, acc)
            t += 2500
    # reference steps inside the following-error limit: the D/A saturates; a reset in task
    for t0, step in ((75_000, 6000), (77_000, -6000)):
        ref[t0:] += step
        mode[t0 - 100 : t0 + 1000, :] = MODE_TASK
    reset[76_000, 0] = True
    # a step past the master's following-error limit trips it; reset in lock later
    ref[80_000:] += 40_000
    mode[79_900:80_300, :] = MODE_TASK
    ref[80_500:] -= 40_000
    reset[81_000, 0] = True
    # excitation added to the lock, then open loop (the lock latches the new position after)
    rng = np.random.default_rng(1)
    u_add[85_000:87_000, 0] = np.repeat(rng.choice([-300, 300], 200), 10)
    mode[88_000:88_500, 0] = MODE_OPEN
    u_add[88_000:88_250, 0] = 250
    u_add[88_250:88_500, 0] = -250
    move(90_000, 70_000, 0.9, 0.02)
    move(93_000, -70_000, 0.9, 0.02)
    # a load kick on the slave (in lock): a following-error trip, then counter faults (the
    # high byte jumps by more than one between reads); reset once it has stopped
    load[100_000, 1] = 30_000.0
    reset[101_000, 1] = True
    reset[105_000, 1] = True
    return Inputs(
        ref_counts=np.stack([ref, np.zeros(n, dtype=np.int64)], axis=1),
        mode=mode,
        reset=reset,
        dac_add_codes=u_add,
        load_v=load,
    )


@pytest.fixture(scope="module")
def golden(tuning: Tuning) -> tuple[Rig, Inputs, Trace]:
    rig = golden_rig()
    inputs = golden_inputs(rig)
    return rig, inputs, simulate(Loop(rig=rig, controllers=tuning.controllers), inputs)


@pytest.fixture(scope="module")
def build(tuning: Tuning, tmp_path_factory) -> Path:
    return _export(tuning, tmp_path_factory.mktemp("c_runtime"))


@pytest.fixture(scope="module")
def runtime(build: Path) -> Runtime:
    return Runtime(build)


def _closed_loop(rt: Runtime, rig: Rig, inputs: Inputs) -> tuple[np.ndarray, np.ndarray]:
    """The C runtime in the loop with the simulator's plants, as engine._run_group does it
    (latched counter, no noise): returns the outputs (ticks, axes, 5) and the registers read."""
    n, n_ax = inputs.n_ticks, inputs.n_axes
    rows, lags = zip(
        *(
            plant_row(ax.plant, rig.period_s, rig.timer.compute_s, rig.counts_per_rev)
            for ax in rig.axes
        ),
        strict=True,
    )
    ring = max(lags) + 2
    hist = [[0.0] * ring for _ in range(n_ax)]  # volts written, by slot
    pos, spd = [0.0] * n_ax, [0.0] * n_ax
    init = [ax.counter_init for ax in rig.axes]
    offset = [float(r[R_OFFSET]) for r in rows]
    mask = (1 << rig.counter.bits) - 1
    dac_lo, lsb = rig.dac.range_v[0], rig.dac.lsb_v
    load = inputs.load_v.tolist()
    ins = [
        np.ascontiguousarray(x, dtype=np.int64)
        for x in (inputs.ref_counts, inputs.mode, inputs.reset, inputs.dac_add_codes)
    ]
    out = np.zeros((n, n_ax, 5), dtype=np.int64)
    raw = np.zeros(n_ax, dtype=np.int64)
    regs = np.zeros((n, n_ax), dtype=np.int64)
    tick, p_raw, stride = rt.lib.h_tick, raw.ctypes.data, n_ax * 8
    bases = [a.ctypes.data for a in ins]
    p_out = out.ctypes.data
    slot = ring - 1
    for k in range(n):
        slot = 0 if slot + 1 == ring else slot + 1
        for a in range(n_ax):  # 1. the counter latches floor(position)
            raw[a] = (init[a] + math.floor(pos[a] + 0.0)) & mask
        regs[k] = raw
        off = k * stride
        tick(p_raw, bases[0] + off, bases[1] + off, bases[2] + off, bases[3] + off, p_out + 5 * off)
        codes = out[k, :, 0].tolist()
        for a in range(n_ax):  # 5-6. hold the writes, move the plants to the next tick
            hist[a][slot] = dac_lo + codes[a] * lsb
            m = lags[a]
            w_off = offset[a] + load[k][a]
            j_new = slot - m if slot >= m else slot - m + ring
            v_new = hist[a][j_new] if k >= m else 0.0
            j_old = j_new - 1 if j_new >= 1 else ring - 1
            v_old = hist[a][j_old] if k >= m + 1 else 0.0
            pos[a], spd[a] = advance_tick(pos[a], spd[a], v_old + w_off, v_new + w_off, rows[a])
    return out, regs


def _coverage(trace: Trace) -> dict[str, list[int]]:
    """Per axis: counter wraps up and down, saturated ticks, handovers, fault onsets."""
    hi = (trace.counter >> 16) & 0xFF
    dh = np.diff(hi, axis=0)
    to_task = (trace.mode[1:] == MODE_TASK) & (trace.mode[:-1] != MODE_TASK)
    to_lock = (trace.mode[1:] == MODE_LOCK) & (trace.mode[:-1] == MODE_TASK)

    def onsets(bit: int) -> np.ndarray:
        on = (trace.flags & bit) != 0
        return np.sum(on[1:] & ~on[:-1], axis=0)

    return {
        "wraps_up": np.sum(dh == -255, axis=0).tolist(),
        "wraps_down": np.sum(dh == 255, axis=0).tolist(),
        "saturated_ticks": np.sum((trace.flags & FLAG_SATURATED) != 0, axis=0).tolist(),
        "lock_to_task": np.sum(to_task, axis=0).tolist(),
        "task_to_lock": np.sum(to_lock, axis=0).tolist(),
        "following_error_trips": onsets(FLAG_FOLLOWING_ERROR).tolist(),
        "counter_faults": onsets(FLAG_COUNTER_FAULT).tolist(),
    }


# --- tests ------------------------------------------------------------------------------------


def test_runtime_and_tables_compile_cleanly(build: Path) -> None:
    # the runtime alone, and a unit including the tables without using them (no warnings)
    cc(build, *STRICT, "-O2", "-c", "servotune_rt.c", "-o", "rt.o")
    (build / "only_tables.c").write_text('#include "servotune_tables.h"\nint unused_ok;\n')
    cc(build, *STRICT, "-c", "only_tables.c", "-o", "only_tables.o")


def test_crcs_and_constants_check_agree_with_python(runtime: Runtime, tuning: Tuning) -> None:
    doc = tables_document(tuning, unverified=True)
    assert runtime.lib.h_check() == 0
    assert runtime.lib.h_consts_crc32() == doc["data"]["constants_crc32"]
    assert runtime.lib.h_consts_crc32() == constants_crc32(tuning)
    tables = doc["data"]["axes"][1]["task"]["tables"]
    for i, name in enumerate(("kp", "ki", "kd", "k1")):
        assert runtime.lib.h_table_crc32(1, i) == tables[name]["crc32"]
    # st_check_consts names the broken field: 1 + 100·axis + field code
    assert [runtime.lib.h_check_broken(w) for w in range(5)] == [1, 4, 115, 116, 117]


def test_primitives_match_python_at_the_edges(runtime: Runtime) -> None:
    lib = runtime.lib
    rng = np.random.default_rng(7)
    edges = [
        0,
        1,
        -1,
        2,
        -2,
        3,
        -3,
        5,
        -5,
        2**31 - 1,
        -(2**31 - 1),
        2**31,
        -(2**31),
        2**32,
        2**62,
        -(2**62),
        INT64_MAX,
        -INT64_MAX,
        INT64_MAX - 1,
        0x7FFF_FFFF_8000_0000,
        -0x7FFF_FFFF_8000_0000,
        3 * 2**31,
        -(3 * 2**31),
    ]
    values = edges + [int(v) for v in rng.integers(-(2**63) + 1, 2**63 - 1, 200)]
    for x in values:
        assert lib.h_clamp_e(x) == clamp_e(x)
        for f in (1, 2, 16, 31, 32, 62):
            assert lib.h_shift_round(x, f) == shift_round(x, f), (x, f)
        for k in (0, 1, 16, 31, 32, 62):
            assert lib.h_align(x, k) == align(x, k), (x, k)
        for b in [*edges, -(2**63)]:
            assert lib.h_sat_add(x, b) == sat_add(x, b), (x, b)
    assert lib.h_sat_add(-(2**63), 0) == -INT64_MAX  # the most negative value is never produced
    # round half away from zero: ±1.5 → ±2, ±2.5 → ±3 (docs/runtime.md#rounding)
    assert [lib.h_shift_round(v, 1) for v in (3, -3, 5, -5)] == [2, -2, 3, -3]


def test_unwrap_step_matches_python_at_the_edges(runtime: Runtime) -> None:
    res = np.zeros(3, dtype=np.int64)
    for bits in (16, 24, 32):
        top = 1 << bits
        lows = (0, 1, (1 << (bits - 8)) - 1)
        for hi_prev in range(256):
            for hi in (0, 1, 2, 127, 253, 254, 255, (hi_prev + 1) % 256, (hi_prev - 1) % 256):
                for low in lows:
                    raw = (hi << (bits - 8)) | low
                    assert raw < top
                    fault = runtime.lib.h_unwrap_step(raw, hi_prev, -3, bits, res.ctypes.data)
                    py = unwrap_step(raw, hi_prev, -3, bits)
                    assert (res.tolist(), bool(fault)) == ([py[0], py[1], py[2]], py[3])


def test_golden_run_c_runtime_in_the_loop_equals_the_simulator(
    runtime: Runtime, golden: tuple[Rig, Inputs, Trace]
) -> None:
    rig, inputs, trace = golden
    assert inputs.n_ticks >= 100_000
    cov = _coverage(trace)
    # what the scenario must exercise (counts from the engine's trace; see the module docstring)
    assert min(cov["wraps_up"]) >= 10 and min(cov["wraps_down"]) >= 10
    assert min(cov["saturated_ticks"]) >= 100
    assert min(cov["lock_to_task"]) >= 30 and min(cov["task_to_lock"]) >= 30
    assert cov["following_error_trips"][0] >= 1 and cov["counter_faults"][1] >= 1
    assert np.any(trace.mode == MODE_OPEN)
    out, regs = _closed_loop(runtime, rig, inputs)
    # bit for bit, every tick: D/A codes and flags, and the registers read (so the plants saw
    # the same commands), positions, errors and modes
    for i, (name, ref) in enumerate(
        (
            ("code", trace.code),
            ("flags", trace.flags),
            ("err_counts", trace.err_counts),
            ("pos_counts", trace.pos_counts),
            ("mode", trace.mode),
        )
    ):
        bad = np.flatnonzero(np.any(out[:, :, i] != ref, axis=1))
        assert bad.size == 0, f"{name} differs first at tick {bad[0]}"
    assert np.array_equal(regs, trace.counter)


# --- replays with injected faults and constants at their edges --------------------------------


def _edge_tuning(bits: int, dac: Dac) -> tuple[Tuning, Rig]:
    """Three axes at the edges of the constants' ranges: a PI master whose products saturate,
    a fuzzy-PID slave whose scheduled gains span 0 … 2^32 − 1, a lock-only slave."""
    rng = np.random.default_rng(bits)
    n = 5
    size = 2 * n + 1

    def tab(lo: int, hi: int) -> np.ndarray:
        return rng.integers(lo, hi + 1, (size, size)).astype(np.int16)

    big = 2**31 - 1
    fuzzy = FuzzyPIDConstants(
        kp=Fixed(q=big, f=32),
        ki_t=Fixed(q=big, f=32),
        kd_t=Fixed(q=12345, f=10),
        k1_t=Fixed(q=big, f=32),
        ke=Fixed(q=1, f=0) if bits != 16 else Fixed(q=3, f=1),  # 1 or 1.5 levels/count
        kec=Fixed(q=big, f=32),
        n=n,
        tables=(
            (tab(-32767, 32767), 16),
            (tab(-32767, 32767), 16),
            (tab(-12, 32767), 0),
            (tab(-32767, 32767), 16),
        ),
    )
    ctls = (
        AxisController(
            lock_gain=Fixed(q=1717986918, f=32),
            task=PIConstants(kp=Fixed(q=big, f=0), ki_t=Fixed(q=-big, f=5)),
        ),
        AxisController(lock_gain=Fixed(q=big, f=0), task=fuzzy, following_error_limit_counts=big),
        AxisController(lock_gain=Fixed(q=-7, f=3), following_error_limit_counts=3),
    )
    plant = Plant(gain_cps_per_v=1000.0, tau_s=0.01)
    rig = Rig(
        name="edges",
        timer=Timer(period_s=0.001),
        counter=Counter(bits=bits),
        dac=dac,
        encoder=Encoder(pulses_per_rev=1000),
        axes=tuple(
            Axis(
                name=f"a{i}",
                role="master" if i == 0 else "slave",
                plant=plant,
                counter_channel=i,
                dac_channel=i,
            )
            for i in range(3)
        ),
    )
    tuning = Tuning.for_rig(rig, ctls, rig_sha256="0" * 64)
    return tuning, rig


def _edge_inputs(bits: int, n: int = 12_000, n_ax: int = 3) -> tuple[np.ndarray, ...]:
    """Counter walks with injected jumps (faults) and wraps, random modes (3 is not a mode:
    treated as open), resets, extreme references and added commands."""
    rng = np.random.default_rng(100 + bits)
    unit = 1 << (bits - 8)  # the largest motion per tick the high-byte rule allows
    steps = rng.integers(-unit // 2, unit // 2 + 1, (n, n_ax))
    steps[rng.random((n, n_ax)) < 0.6] //= 64  # mostly slow
    jumps = rng.random((n, n_ax)) < 0.004
    steps[jumps] = rng.integers(2 * unit, 1 << bits, int(jumps.sum()))
    # the lock-only axis creeps count by count: its following-error trip at exactly ±(limit + 1)
    steps[:, 2] = np.where(jumps[:, 2], steps[:, 2], rng.integers(-1, 2, n))
    start = rng.integers(0, 1 << bits, n_ax)
    raw = (start + np.cumsum(steps, axis=0)) % (1 << bits)
    seg = np.repeat(rng.choice([0, 1, 1, 2, 3], n // 50 + 1), 50)[:n]
    mode = np.stack([np.roll(seg, 17 * a) for a in range(n_ax)], axis=1)
    reset = rng.random((n, n_ax)) < 0.004
    extreme = np.array([2**40, -(2**40), 2**62, -(2**62), INT64_MAX, -INT64_MAX, -(2**63)])
    ref = np.cumsum(rng.integers(-3000, 3001, (n, n_ax)), axis=0)
    pick = rng.random((n, n_ax)) < 0.01
    ref[pick] = rng.choice(extreme, int(pick.sum()))
    u_add = np.where(rng.random((n, n_ax)) < 0.1, rng.integers(-6000, 6001, (n, n_ax)), 0)
    pick = rng.random((n, n_ax)) < 0.005
    u_add[pick] = rng.choice(extreme, int(pick.sum()))
    return raw, ref, mode, reset.astype(np.int64), u_add


EDGE_CASES = [
    pytest.param(24, Dac(bits=12, range_v=(-10.0, 10.0)), id="24bit-counter-12bit-dac"),
    pytest.param(16, Dac(bits=16, range_v=(-10.0, 10.0)), id="16bit-counter-16bit-dac"),
    pytest.param(32, Dac(bits=8, range_v=(0.0, 10.0)), id="32bit-counter-unipolar-8bit-dac"),
]


@pytest.mark.parametrize(("bits", "dac"), EDGE_CASES)
def test_replay_with_injected_faults_matches_the_python_tick(bits, dac, tmp_path) -> None:
    tuning, rig = _edge_tuning(bits, dac)
    doc = tables_document(tuning, rig=rig, unverified=True)
    src = _export(tuning, tmp_path, rig=rig)
    rt = Runtime(src)
    assert rt.lib.h_check() == 0 and rt.lib.h_consts_crc32() == doc["data"]["constants_crc32"]
    ins = _edge_inputs(bits)
    hw = {"counter_bits": bits, "dac": doc["data"]["dac"]}
    refs = [ax["ref_source"] for ax in doc["data"]["axes"]]
    py = _replay_python(tuning.controllers, refs, hw, *ins)
    c = rt.run(*ins)
    for i, name in enumerate(("code", "flags", "e", "y", "mode")):
        bad = np.argwhere(c[:, :, i] != py[:, :, i])
        assert bad.size == 0, f"{name} differs first at (tick, axis) {tuple(bad[0])}"
    flags = py[:, :, 1]
    assert np.any(flags & FLAG_COUNTER_FAULT) and np.any(flags & FLAG_FOLLOWING_ERROR)
    assert np.any(flags & FLAG_SATURATED) and np.any(py[:, :, 0] == dac.code_max)
    assert np.any(py[:, :, 0] == 0)
    trip = (py[1:, 2, 1] & FLAG_FOLLOWING_ERROR) & ~py[:-1, 2, 1] != 0
    assert set(py[1:, 2, 2][trip].tolist()) == {-4, 4}  # limit 3 counts: trips at ±4 exactly
    # the same replay under the undefined-behaviour sanitizer
    assert np.array_equal(_ubsan_replay(src, *ins), py)


def test_golden_run_under_the_undefined_behaviour_sanitizer(
    build: Path, golden: tuple[Rig, Inputs, Trace]
) -> None:
    # the whole golden run replayed from the engine's counter registers: with the same codes
    # out, the plants see the same commands, so this is the closed loop tick for tick
    _, inputs, trace = golden
    out = _ubsan_replay(
        build,
        trace.counter,
        inputs.ref_counts,
        inputs.mode,
        inputs.reset.astype(np.int64),
        inputs.dac_add_codes,
    )
    assert np.array_equal(out[:, :, 0], trace.code)
    assert np.array_equal(out[:, :, 1], trace.flags)
    assert np.array_equal(out[:, :, 3], trace.pos_counts)


# --- the plant's C mirror (servotune_plant.h) against the simulator's plant step ---------------

PLANT_HARNESS = r"""
/* n ticks of one plant from rest: tick k moves it with w_old = w[2k], w_new = w[2k + 1];
 * out[12k ...] = p, v, q[0..7], the measured position and speed at the tick's end */
#include <stdint.h>

#include "servotune_plant.h"

void h_plant_run(int64_t n, const double *row, const double *w, double *out)
{
    double p = 0.0;
    double v = 0.0;
    double q[2 * ST_MAX_MODES] = {0.0};
    int64_t k;
    int j;
    for (k = 0; k < n; k++) {
        double *o = out + 12 * k;
        st_plant_advance_tick_modal(&p, &v, q, w[2 * k], w[2 * k + 1], row);
        o[0] = p;
        o[1] = v;
        for (j = 0; j < 2 * ST_MAX_MODES; j++) {
            o[2 + j] = q[j];
        }
        o[10] = st_modes_output(p, q, row, ST_R_MODES);
        o[11] = st_modes_speed(v, q, row, ST_R_MODES);
    }
}

/* n encoder-noise draws of sigma from the stream seeded seed */
void h_noise(uint64_t seed, double sigma, int64_t n, double *out)
{
    uint64_t state = seed;
    int64_t k;
    for (k = 0; k < n; k++) {
        out[k] = st_noise(&state, sigma);
    }
}

/* the same ticks through st_plant_advance_tick (no mode state): out[2k ...] = p, v */
void h_plant_run_rigid(int64_t n, const double *row, const double *w, double *out)
{
    double p = 0.0;
    double v = 0.0;
    int64_t k;
    for (k = 0; k < n; k++) {
        st_plant_advance_tick(&p, &v, w[2 * k], w[2 * k + 1], row);
        out[2 * k] = p;
        out[2 * k + 1] = v;
    }
}
"""


@jit
def _plant_run_reference(row: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """:func:`servotune.plant.advance_tick_modal` over the ticks of ``h_plant_run`` (the same
    outputs), compiled as the simulator compiles it."""
    p = 0.0
    v = 0.0
    q = np.zeros(2 * MAX_MODES)
    for k in range(w.shape[0]):
        p, v = advance_tick_modal(p, v, q, w[k, 0], w[k, 1], row)
        out[k, 0] = p
        out[k, 1] = v
        for j in range(2 * MAX_MODES):
            out[k, 2 + j] = q[j]
        out[k, 10] = modes_output(p, q, row, R_MODES)
        out[k, 11] = modes_speed(v, q, row, R_MODES)


@pytest.fixture(scope="module")
def plant_lib(tmp_path_factory) -> ctypes.CDLL:
    """The plant header and its harness, built strictly at -O2 without FMA contraction."""
    d = tmp_path_factory.mktemp("c_plant")
    header = PLANT_RUNTIME_FILES[0]
    (d / header).write_text(runtime_source(header))
    (d / "plant_harness.c").write_text(PLANT_HARNESS)
    flags = (*STRICT, "-O2", "-ffp-contract=off", "-shared", "-fPIC")
    cc(d, *flags, "plant_harness.c", "-o", "libplant.so", "-lm")
    lib = ctypes.CDLL(str(d / "libplant.so"))
    for name in ("h_plant_run", "h_plant_run_rigid"):
        fn = getattr(lib, name)
        fn.restype = None
        fn.argtypes = [ctypes.c_int64] + [ctypes.c_void_p] * 3
    lib.h_noise.restype = None
    lib.h_noise.argtypes = [ctypes.c_uint64, ctypes.c_double, ctypes.c_int64, ctypes.c_void_p]
    return lib


@pytest.mark.parametrize("seed", [0, 7, 2**64 - 1])
def test_the_c_encoder_noise_is_the_simulators_stream(plant_lib: ctypes.CDLL, seed: int) -> None:
    """``st_noise`` (the HAL plant component's encoder noise) draws what the engine's
    :func:`~servotune.sim.tick.draw_noise` draws from the same seed
    (:func:`~servotune.sim.tick.noise_draws`), bit for bit; sigma 0 gives zeros."""
    n, sigma = 200_000, 0.3
    got = np.zeros(n)
    plant_lib.h_noise(seed, sigma, n, got.ctypes.data)
    ref = noise_draws(np.uint64(seed), sigma, n)
    assert np.array_equal(got.view(np.int64), ref.view(np.int64))
    # a normal stream of standard deviation sigma (200,000 draws: the sample's within 1 %)
    assert abs(np.std(got) / sigma - 1.0) < 0.01 and abs(np.mean(got)) < 0.01 * sigma
    plant_lib.h_noise(seed, 0.0, 10, got.ctypes.data)
    assert not np.any(got[:10])


# a belt-driven axis's two modes: tests/plant/test_resonant_engine.py's MODES (a 35 Hz mode,
# a lighter 80 Hz one with its anti-resonance below it), the first one's gain raised to 0.6
PLANT_MODES = (
    Mode(freq_hz=35.0, damping=0.03, gain=0.6),
    Mode(freq_hz=80.0, damping=0.05, gain=-0.3),
)
PLANT_PERIOD_S = 0.004
PLANT_COUNTS_PER_REV = 4000.0
LINEAR_PLANT = Plant(gain_cps_per_v=12288.0, tau_s=0.025, delay_s=0.0015, modes=PLANT_MODES)
FRICTION_PLANT = dataclasses.replace(
    LINEAR_PLANT,
    coulomb_v=0.3,
    coulomb_neg_v=0.5,
    gain_neg_cps_per_v=0.8 * 12288.0,
    max_speed_rpm=1500.0,  # 100,000 counts/s: reached from 8.1 V up (10.2 V down)
)


def _plant_inputs(n: int, seed: int) -> np.ndarray:
    """The net inputs of ``n`` ticks, (n, 2) = w_old, w_new: levels held 1–12 ticks, a third of
    them inside or near the Coulomb band (the motor sticks or creeps), the rest up to ±14 V
    (past the speed limit), reversing often; w_old is the previous tick's w_new (lag 0 + λ)."""
    rng = np.random.default_rng(seed)
    levels, k = [], 0
    while k < n:
        hold = int(rng.integers(1, 13))
        big = rng.random() < 0.67
        level = rng.uniform(-14.0, 14.0) if big else rng.uniform(-0.8, 0.8)
        levels.append(np.full(hold, level))
        k += hold
    w_new = np.concatenate(levels)[:n]
    w_old = np.concatenate([[0.0], w_new[:-1]])
    return np.ascontiguousarray(np.stack([w_old, w_new], axis=1))


def _c_plant_run(lib: ctypes.CDLL, row: np.ndarray, w: np.ndarray) -> np.ndarray:
    out = np.zeros((w.shape[0], 12))
    lib.h_plant_run(w.shape[0], row.ctypes.data, w.ctypes.data, out.ctypes.data)
    return out


@pytest.mark.parametrize(
    ("plant", "what"),
    [
        pytest.param(LINEAR_PLANT, "linear", id="linear-two-modes"),
        pytest.param(FRICTION_PLANT, "friction", id="friction-asymmetric-limited-two-modes"),
        pytest.param(
            dataclasses.replace(FRICTION_PLANT, modes=()), "friction", id="friction-rigid"
        ),
    ],
)
def test_the_c_plant_moves_modes_bit_for_bit_with_the_simulators_step(
    plant_lib: ctypes.CDLL, plant: Plant, what: str
) -> None:
    n = 120_000
    row, lag = plant_row(plant, PLANT_PERIOD_S, 0.0, PLANT_COUNTS_PER_REV)
    row = np.ascontiguousarray(row)
    assert lag == 0 and 0.0 < row[R_H1] < PLANT_PERIOD_S  # the delay is a fraction of a tick
    w = _plant_inputs(n, seed=5)
    ref = np.zeros((n, 12))
    _plant_run_reference(row, w, ref)
    got = _c_plant_run(plant_lib, row, w)
    # every number of every tick, as float64 bits
    names = ("p", "v", *(f"q[{j}]" for j in range(2 * MAX_MODES)), "position", "speed")
    for j, name in enumerate(names):
        bad = np.flatnonzero(got[:, j].view(np.int64) != ref[:, j].view(np.int64))
        assert bad.size == 0, f"{name} differs first at tick {bad[0]}"
    if not plant.modes:  # the rigid step is today's st_plant_advance_tick, bit for bit
        rigid = np.zeros((n, 2))
        plant_lib.h_plant_run_rigid(n, row.ctypes.data, w.ctypes.data, rigid.ctypes.data)
        assert np.array_equal(rigid.view(np.int64), got[:, :2].view(np.int64))
        assert np.array_equal(got[:, 10].view(np.int64), got[:, 0].view(np.int64))
        assert not np.any(got[:, 2:10])
    # what the inputs exercised (counted on the reference): the modes rang, the speed reversed
    # (zero crossings inside a piece: the coefficients computed on the fly), stuck, and met the
    # speed limit; the linear plant stayed in its one-tick map
    v = ref[:, 1]
    reversals = int(np.sum(np.sign(v[1:]) * np.sign(v[:-1]) < 0))
    vmax = row[R_VMAX]
    if plant.modes:
        assert np.abs(ref[:, 10] - ref[:, 0]).max() > 1.0
    if what == "linear":  # no speed limit: the linear plant's one-tick map every tick
        assert row[R_LINEAR] == 1.0 and vmax == math.inf and reversals >= 1000
    else:
        assert reversals >= 1000 and int(np.sum(v == 0.0)) >= 1000
        assert np.abs(v).max() > 0.99 * vmax
        assert np.any(np.abs(w[:, 1]) * row[R_GAIN] > vmax)
