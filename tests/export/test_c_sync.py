"""The C runtime's sync compensator (``st_sync_*``) against servotune/laws/sync.py, bit for bit.

The runtime is compiled with the system C compiler (strict C99 flags, as in
``test_c_runtime.py``) together with a small harness into a shared library (ctypes), and once
more with ``-fsanitize=undefined -fno-sanitize-recover`` into a program that replays a file.

- Edge replay: thousands of sequences of random ``sync_enter`` / ``sync_step`` / monitor-only
  ticks on constants at the edges of their ranges (gains with f from 0 to 32 and q at
  ±(2^31 − 1), PI, PD and both, dead zones 0, 1 and beyond ±2^31, limits 1 and 2^31 − 1,
  thresholds 0 and nonzero), from zero, random and out-of-range states, with sync errors near
  ±(2^31 − 1), at the int64 extremes and in between. Every output (compensation, integrator,
  dead-zoned error, monitor level) must equal the Python laws'.
- The same replay under the undefined-behaviour sanitizer.
- Golden gantry replay: the C law driven cycle by cycle with the sync errors the gantry
  simulation's law saw (``servotune.arch.gantry``) gives its compensation and monitor level at
  every cycle; by induction, the C law in the loop reproduces the trajectory.
"""

from __future__ import annotations

import ctypes
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from c_build import UBSAN, needs_cc, run_cc, run_replay, shared_harness, ubsan_harness

from servotune.export.c import RUNTIME_FILES, runtime_source
from servotune.fixed import Fixed
from servotune.laws.axis import (
    FAULT_MASK,
    FLAG_SYNC_TRIP,
    MODE_TASK,
    N_STATE,
    S_FAULT,
    S_INIT,
    AxisController,
    axis_control,
)
from servotune.laws.pi import PIConstants
from servotune.laws.sync import (
    SYNC_OK,
    SYNC_TRIP,
    SYNC_WARN,
    dead_zone,
    sync_enter,
    sync_monitor,
    sync_step,
)

pytestmark = needs_cc

ROOT = Path(__file__).resolve().parents[2]
INT64_MAX = 2**63 - 1
INT64_MIN = -(2**63)
E_MAX = 2**31 - 1
N_SEQ = 4000

# replay layout: per sequence the 10 constants (st_sync_consts_t order), the initial integ and
# e_prev, the first step and the number of steps; per step an op and a sync error
OP_MONITOR, OP_ENTER, OP_STEP = 0, 1, 2  # 0: the law is not run (the monitor is)
N_HEAD, N_OUT = 14, 5  # outputs per step: comp, integ, e_prev (= e_d), level, dead_zone(e)

HARNESS = r"""
/* test harness for the sync compensator, driven from Python (ctypes) or, for the sanitizer
 * run, from a file (main) */
#include <stdio.h>
#include <stdlib.h>

#include "servotune_rt.h"

static void load(const int64_t *h, st_sync_consts_t *c)
{
    c->kp_q = h[0];
    c->kp_f = h[1];
    c->kit_q = h[2];
    c->kit_f = h[3];
    c->kdt_q = h[4];
    c->kdt_f = h[5];
    c->dead_zone = h[6];
    c->limit = h[7];
    c->warn = h[8];
    c->trip = h[9];
}

int h_check(const int64_t *h)
{
    st_sync_consts_t c;
    load(h, &c);
    return st_check_sync_consts(&c);
}

int64_t h_dead_zone(int64_t e, int64_t dz) { return st_dead_zone(e, dz); }
int h_monitor(int64_t e, int64_t warn, int64_t trip) { return st_sync_monitor(e, warn, trip); }

int64_t h_define(int i)
{
    const int64_t v[] = {ST_FLAG_SYNC_TRIP, ST_FAULT_MASK, ST_SYNC_OK, ST_SYNC_WARN,
                         ST_SYNC_TRIP};
    return v[i];
}

/* seq: n_seq rows of 14 (consts, integ, e_prev, first, n); op, e: per step; out: 5 per step */
void h_replay(int64_t n_seq, const int64_t *seq, const int64_t *op, const int64_t *e,
              int64_t *out)
{
    int64_t i;
    int64_t k;
    for (i = 0; i < n_seq; i++) {
        const int64_t *h = seq + 14 * i;
        st_sync_consts_t c;
        st_sync_state_t s;
        load(h, &c);
        s.integ = h[10];
        s.e_prev = h[11];
        for (k = h[12]; k < h[12] + h[13]; k++) {
            int64_t comp = 0;
            if (op[k] == 1) {
                st_sync_enter(&c, &s, e[k]);
            } else if (op[k] == 2) {
                comp = st_sync_step(&c, &s, e[k]);
            }
            out[5 * k + 0] = comp;
            out[5 * k + 1] = s.integ;
            out[5 * k + 2] = s.e_prev;
            out[5 * k + 3] = st_sync_monitor(e[k], c.warn, c.trip);
            out[5 * k + 4] = st_dead_zone(e[k], c.dead_zone);
        }
    }
}

/* a PI axis with a latched fault: ticks in task mode, reset on tick `reset_at`; out: code,
 * flags, e per tick */
void h_axis_fault(int64_t fault, int n, int reset_at, int64_t *out)
{
    st_axis_consts_t c = {0};
    st_axis_state_t s = {0};
    int k;
    c.law = ST_LAW_PI;
    c.lock_q = 1;
    c.kp_q = 3;
    c.kit_q = 1;
    c.kit_f = 4;
    c.counter_bits = 24;
    c.dac_zero = 2048;
    c.dac_max = 4095;
    c.ref_source = -1;
    s.init = 1;
    s.fault = fault;
    for (k = 0; k < n; k++) {
        int32_t code;
        int32_t flags;
        out[3 * k + 2] = st_axis_control(&s, &c, 100 + k, ST_MODE_TASK, k == reset_at, 0,
                                         &code, &flags);
        out[3 * k + 0] = code;
        out[3 * k + 1] = flags;
    }
}

#ifdef H_MAIN
/* file replay: in = n_seq, n_steps, seq (14 n_seq), op, e (n_steps each); out = 5 n_steps */
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
    if (f == NULL || fread(head, sizeof head[0], 2, f) != 2) {
        return 3;
    }
    cells = 14 * (size_t)head[0] + 2 * (size_t)head[1];
    buf = malloc(cells * sizeof *buf);
    out = malloc(5 * (size_t)head[1] * sizeof *out);
    if (buf == NULL || out == NULL || fread(buf, sizeof *buf, cells, f) != cells) {
        return 4;
    }
    fclose(f);
    h_replay(head[0], buf, buf + 14 * head[0], buf + 14 * head[0] + head[1], out);
    f = fopen(argv[2], "wb");
    if (f == NULL || fwrite(out, sizeof *out, 5 * (size_t)head[1], f) != 5 * (size_t)head[1]) {
        return 6;
    }
    fclose(f);
    free(buf);
    free(out);
    return 0;
}
#endif
"""


# --- building ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def src(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("c_sync")
    for name in RUNTIME_FILES:
        (d / name).write_text(runtime_source(name))
    (d / "harness.c").write_text(HARNESS)
    return d


@pytest.fixture(scope="module")
def lib(src: Path) -> ctypes.CDLL:
    lib = shared_harness(src, "libh.so")
    i64, p, i = ctypes.c_int64, ctypes.c_void_p, ctypes.c_int
    for name, restype, argtypes in (
        ("h_check", i, [p]),
        ("h_dead_zone", i64, [i64, i64]),
        ("h_monitor", i, [i64, i64, i64]),
        ("h_define", i64, [i]),
        ("h_replay", None, [i64, p, p, p, p]),
        ("h_axis_fault", None, [i64, i, i, p]),
    ):
        fn = getattr(lib, name)
        fn.restype = restype
        fn.argtypes = argtypes
    return lib


# --- the replay: inputs, and the Python laws on them ----------------------------------------


def _edge_replay(seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``N_SEQ`` sequences: (seq rows, ops, sync errors)."""
    rng = np.random.default_rng(seed)

    def pick(edges: list[int], lo: int, hi: int, p_edge: float = 0.6) -> int:
        if rng.random() < p_edge:
            return int(edges[rng.integers(len(edges))])
        return int(rng.integers(lo, hi, endpoint=True))

    q_edges = [0, 1, -1, E_MAX, -E_MAX, -(2**31), 2**31 - 2, 3, 12345]
    f_edges = [0, 1, 16, 31, 32]
    dz_edges = [0, 0, 1, 2, 1000, E_MAX - 1, E_MAX, 2**31, 2**40, INT64_MAX]
    lim_edges = [1, 2, 4096, E_MAX, E_MAX - 1]
    thr_edges = [0, 0, 1, 100, E_MAX, 2**31, INT64_MAX]
    e_edges = [
        0,
        1,
        -1,
        E_MAX,
        -E_MAX,
        E_MAX - 1,
        -(E_MAX - 1),
        2**31,
        -(2**31),
        2**31 + 1,
        -(2**31 + 1),
        2**40,
        -(2**40),
        2**62,
        -(2**62),
        INT64_MAX,
        -INT64_MAX,
        INT64_MIN,
    ]
    seq, ops, errs = [], [], []
    for _ in range(N_SEQ):
        law = rng.integers(3)  # 0 PI, 1 PD, 2 both terms
        gains = []
        for used in (True, law != 1, law != 0):
            q = pick(q_edges, -E_MAX, E_MAX) if used or rng.random() < 0.1 else 0
            gains += [q, pick(f_edges, 0, 32)]
        dz = pick(dz_edges, 0, 5000)
        limit = pick(lim_edges, 1, 1 << int(rng.integers(1, 32)))
        limit = min(limit, E_MAX)
        warn, trip = pick(thr_edges, 0, 5000), pick(thr_edges, 0, 20000)
        rail = limit << 32
        integ = int(
            rng.choice(
                [
                    0,
                    rail,
                    -rail,
                    int(rng.integers(-rail, rail, endpoint=True)),
                    int(rng.integers(INT64_MIN, INT64_MAX, endpoint=True)),
                    INT64_MIN,
                ],
                p=[0.4, 0.1, 0.1, 0.3, 0.05, 0.05],
            )
        )
        e_prev = pick([0, E_MAX, -E_MAX], -E_MAX, E_MAX, p_edge=0.5)
        if rng.random() < 0.02:  # a state the law never leaves (numba and C both wrap)
            e_prev = pick([INT64_MAX, INT64_MIN], INT64_MIN, INT64_MAX)
        n = int(rng.integers(1, 60))
        op = rng.choice([OP_MONITOR, OP_ENTER, OP_STEP], n, p=[0.1, 0.1, 0.8])
        if rng.random() < 0.7:
            op[0] = OP_ENTER
        # errors: a random walk near an edge, small or large steps, with edge values mixed in
        centre = int(rng.choice([0, 0, dz if dz < 2**40 else 0, E_MAX, -E_MAX, 2**40]))
        scale = int(rng.choice([3, 100, 10_000, 2**20, 2**31]))
        walk = np.cumsum(rng.integers(-scale, scale, n, endpoint=True))
        e = [min(max(centre + int(w), INT64_MIN), INT64_MAX) for w in walk]
        for k in np.flatnonzero(rng.random(n) < 0.15):
            e[k] = int(rng.choice(e_edges))
        for k in np.flatnonzero(rng.random(n) < 0.05):
            e[k] = int(rng.integers(INT64_MIN, INT64_MAX, endpoint=True))
        seq.append([*gains, dz, limit, warn, trip, integ, e_prev, len(ops), n])
        ops += op.tolist()
        errs += e
    return (
        np.array(seq, dtype=np.int64),
        np.array(ops, dtype=np.int64),
        np.array(errs, dtype=np.int64),
    )


def _python_replay(seq: np.ndarray, op: np.ndarray, e: np.ndarray) -> np.ndarray:
    """The same replay through the Python laws (what the simulation runs)."""
    out = np.zeros((op.size, N_OUT), dtype=np.int64)
    for row in seq.tolist():
        kp_q, kp_f, kit_q, kit_f, kdt_q, kdt_f, dz, limit, warn, trip = row[:10]
        integ, e_prev, first, n = row[10:]
        for k in range(first, first + n):
            ek = int(e[k])
            comp = 0
            if op[k] == OP_ENTER:
                integ, e_prev = sync_enter(kp_q, kp_f, dz, limit, ek)
            elif op[k] == OP_STEP:
                comp, integ, e_prev = sync_step(
                    kp_q, kp_f, kit_q, kit_f, kdt_q, kdt_f, dz, limit, integ, e_prev, ek
                )
            out[k] = (comp, integ, e_prev, sync_monitor(ek, warn, trip), dead_zone(ek, dz))
    return out


def _c_replay(lib: ctypes.CDLL, seq: np.ndarray, op: np.ndarray, e: np.ndarray) -> np.ndarray:
    out = np.zeros((op.size, N_OUT), dtype=np.int64)
    lib.h_replay(len(seq), seq.ctypes.data, op.ctypes.data, e.ctypes.data, out.ctypes.data)
    return out


@pytest.fixture(scope="module")
def replay() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    seq, op, e = _edge_replay()
    return seq, op, e, _python_replay(seq, op, e)


def _assert_equal(c: np.ndarray, py: np.ndarray, op: np.ndarray, e: np.ndarray) -> None:
    for i, name in enumerate(("comp", "integ", "e_d", "level", "dead_zone")):
        bad = np.flatnonzero(c[:, i] != py[:, i])
        assert bad.size == 0, (
            f"{name} differs at {bad.size} steps, first step {bad[0]} "
            f"(op {op[bad[0]]}, e {e[bad[0]]}): C {c[bad[0], i]}, Python {py[bad[0], i]}"
        )


# --- tests ------------------------------------------------------------------------------------


def test_defines_match_python(lib: ctypes.CDLL) -> None:
    assert [lib.h_define(i) for i in range(5)] == [
        FLAG_SYNC_TRIP,
        FAULT_MASK,
        SYNC_OK,
        SYNC_WARN,
        SYNC_TRIP,
    ]


def test_check_sync_consts_names_the_bad_field(lib: ctypes.CDLL) -> None:
    good = [E_MAX, 32, -E_MAX, 0, -(2**31), 32, INT64_MAX, E_MAX, 0, INT64_MAX]
    assert lib.h_check(np.array(good, dtype=np.int64).ctypes.data) == 0
    low = [0, 0, 0, 0, 0, 0, 0, 1, 0, 0]
    assert lib.h_check(np.array(low, dtype=np.int64).ctypes.data) == 0
    # one field out of its range at a time: 1 + its index in st_sync_consts_t
    broken = {0: 2**31, 1: 33, 2: -(2**31) - 1, 3: -1, 4: 2**40, 5: 40, 6: -1, 7: 0, 8: -1, 9: -5}
    for i, v in broken.items():
        c = np.array(good, dtype=np.int64)
        c[i] = v
        assert lib.h_check(c.ctypes.data) == i + 1, i
    c = np.array(good, dtype=np.int64)
    c[7] = 2**31  # limit past 2^31 - 1: the rails would not fit int64
    assert lib.h_check(c.ctypes.data) == 8


def test_dead_zone_and_monitor_match_python_at_the_edges(lib: ctypes.CDLL) -> None:
    values = [0, 1, -1, 2, -2, 5, -5, E_MAX - 1, E_MAX, E_MAX + 1, 2**40, INT64_MAX]
    values += [-v for v in values] + [INT64_MIN]
    dzs = [0, 1, 2, 5, E_MAX - 1, E_MAX, E_MAX + 1, 2**40, INT64_MAX]
    for x in values:
        for dz in dzs:
            assert lib.h_dead_zone(x, dz) == dead_zone(x, dz), (x, dz)
        for warn in (0, 1, 5, E_MAX, INT64_MAX):
            for trip in (0, 1, 5, 6, E_MAX + 1, INT64_MAX):
                assert lib.h_monitor(x, warn, trip) == sync_monitor(x, warn, trip), (x, warn, trip)
    # the dead zone's edges: ±dz → 0, ±(dz + 1) → ±1; clamp first: beyond ±(2^31 − 1) acts
    # as ±(2^31 − 1)
    assert [lib.h_dead_zone(v, 5) for v in (5, -5, 6, -6)] == [0, 0, 1, -1]
    assert lib.h_dead_zone(INT64_MIN, 1) == -(E_MAX - 1)
    # thresholds are inclusive; 0 switches a level off
    assert [lib.h_monitor(v, 5, 9) for v in (4, 5, -8, 9, -9)] == [0, 1, 1, 2, 2]
    assert [lib.h_monitor(v, 0, 0) for v in (0, E_MAX, -INT64_MAX)] == [0, 0, 0]


def test_edge_replay_matches_python(lib: ctypes.CDLL, replay) -> None:
    seq, op, e, py = replay
    assert op.size >= 100_000
    # what the replay must exercise (counted on the Python outputs)
    limit = np.repeat(seq[:, 7], seq[:, 13])
    steps = op == OP_STEP
    comp = py[:, 0]
    assert np.sum(steps & (comp == limit)) > 100 and np.sum(steps & (comp == -limit)) > 100
    assert np.sum(steps & (np.abs(comp) < limit) & (comp != 0)) > 1000
    assert np.sum(steps & (limit == 1)) > 100 and np.sum(steps & (limit == E_MAX)) > 1000
    integ_rail = limit * 2**32
    assert np.sum(np.abs(py[:, 1]) == integ_rail) > 100
    assert np.sum(np.abs(e) > E_MAX) > 1000 and np.any(e == INT64_MIN)
    for level in (SYNC_OK, SYNC_WARN, SYNC_TRIP):
        assert np.sum(py[:, 3] == level) > 1000, level
    assert np.sum(op == OP_ENTER) > 1000 and np.sum(op == OP_MONITOR) > 1000
    _assert_equal(_c_replay(lib, seq, op, e), py, op, e)


def test_edge_replay_under_the_undefined_behaviour_sanitizer(src: Path, replay) -> None:
    seq, op, e, py = replay
    probe = src / "probe.c"
    probe.write_text("int main(void) { return 0; }\n")
    res = run_cc(src, *UBSAN, "probe.c", "-o", "probe")
    if res.returncode != 0:
        pytest.skip(f"the compiler cannot link -fsanitize=undefined here:\n{res.stderr}")
    head = np.array([len(seq), op.size], dtype=np.int64)
    payload = b"".join(a.tobytes() for a in (head, seq, op, e))
    out_bytes = run_replay(ubsan_harness(src, "h_ubsan"), payload, timeout=300)
    out = np.frombuffer(out_bytes, dtype=np.int64).reshape(-1, N_OUT)
    _assert_equal(out, py, op, e)


def test_sync_trip_latches_like_any_fault(lib: ctypes.CDLL) -> None:
    # ST_FLAG_SYNC_TRIP in an axis's latched fault holds it at mid-scale until a reset, in C
    # as in axis_control
    ctl = AxisController(
        lock_gain=Fixed(q=1, f=0), task=PIConstants(kp=Fixed(q=3, f=0), ki_t=Fixed(q=1, f=4))
    )
    c = ctl.consts(counter_bits=24, dac_bits=12, dac_zero=2048)[None, :]
    n, reset_at = 6, 3
    out = np.zeros((n, 3), dtype=np.int64)
    lib.h_axis_fault(FLAG_SYNC_TRIP, n, reset_at, out.ctypes.data)
    st = np.zeros((1, N_STATE), dtype=np.int64)
    st[0, S_INIT], st[0, S_FAULT] = 1, FLAG_SYNC_TRIP
    py = [list(axis_control(st, c, 0, 100 + k, MODE_TASK, k == reset_at, 0)) for k in range(n)]
    assert out.tolist() == py
    assert out[:reset_at].tolist() == [[2048, FLAG_SYNC_TRIP, 0]] * reset_at
    assert np.all(out[reset_at + 1 :, 1] & FAULT_MASK == 0) and out[-1, 0] != 2048


# --- the golden gantry replay ---------------------------------------------------------------


@pytest.fixture(scope="module")
def gantry():
    import servotune.arch.gantry as mod
    from servotune.arch.gantry.load import load_gantry
    from servotune.arch.gantry.synthesis import resolve_gains

    return mod, resolve_gains(load_gantry(ROOT / "plants" / "gantry.toml"))


def _gantry_variants(config):
    """The example gantry as configured, with thresholds low enough to trip the monitor in
    the mismatch case, as a PD compensator (the derivative term in the loop), and with a
    wider dead zone and a limit the compensation reaches (clamp and conditional integration)."""
    s = config.sync
    yield "as configured", config
    yield "tripping", replace(config, sync=replace(s, warn_counts=150, trip_counts=400))
    yield "pd", replace(config, sync=replace(s, law="pd", ki=None, kd=0.002))
    yield "limited", replace(config, sync=replace(s, dead_zone_counts=5, limit_counts=60))


def test_golden_gantry_replay_c_law_gives_the_simulated_compensation(lib, gantry) -> None:
    mod, config = gantry
    lat = config.bus.latency_cycles
    ran, tripped_in_law, at_limit = [], 0, 0
    for variant, cfg in _gantry_variants(config):
        k = cfg.sync_constants
        head = [
            k.kp.q,
            k.kp.f,
            k.ki_t.q,
            k.ki_t.f,
            k.kd_t.q,
            k.kd_t.f,
            k.dead_zone_counts,
            k.limit_counts,
            cfg.sync.warn_counts,
            cfg.sync.trip_counts,
        ]
        assert lib.h_check(np.array(head, dtype=np.int64).ctypes.data) == 0
        for topology in mod.TOPOLOGIES:
            for case in mod.CASES:
                run = f"{variant}, {topology}, {case}"
                trace = mod.simulate_gantry(cfg, topology, case=case, seed=0)
                op = np.ascontiguousarray(trace.sync_op, dtype=np.int64)
                e_in = np.ascontiguousarray(trace.sync_input, dtype=np.int64)
                # the monitor sees the measured sync error, latency cycles old, every cycle;
                # the law (when it runs) the same value
                e_mon = np.zeros(op.size, dtype=np.int64)
                e_mon[lat:] = trace.sync_error[: op.size - lat]
                assert np.array_equal(e_in[op != 0], e_mon[op != 0]), run
                # the C law cycle by cycle from the power-up state: op, and the error it saw
                law = _c_replay(lib, np.array([[*head, 0, 0, 0, op.size]], np.int64), op, e_in)
                # the C monitor on every cycle's error
                mon = _c_replay(lib, np.array([[*head, 0, 0, 0, op.size]], np.int64), 0 * op, e_mon)
                for name, c_val, py_val in (
                    ("sync_comp", law[:, 0], trace.sync_comp),
                    ("sync_level", mon[:, 3], trace.sync_level),
                ):
                    bad = np.flatnonzero(c_val != np.asarray(py_val))
                    assert bad.size == 0, f"{run}: {name} differs first at cycle {bad[0]}"
                if np.any(op == OP_STEP):
                    assert np.sum(op == OP_ENTER) == 1 and op[lat] == OP_ENTER, run
                    ran.append(run)
                    at_limit += int(np.sum(np.abs(law[:, 0]) == k.limit_counts))
                    if trace.trip_cycle >= 0:
                        tripped_in_law += 1
                        assert np.all(op[trace.trip_cycle :] == OP_MONITOR), run
                        assert np.any(trace.sync_level[trace.trip_cycle :] == SYNC_TRIP), run
    # the law ran (listening and cross topologies), with the derivative term on, at its
    # limit, and until a trip
    assert any(r.startswith("as configured, listening") for r in ran), ran
    assert any(r.startswith("pd,") for r in ran) and tripped_in_law >= 1, ran
    assert at_limit >= 10, at_limit
