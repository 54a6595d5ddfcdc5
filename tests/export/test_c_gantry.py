"""The C gantry runtime (``servotune_gantry.c``) against the Python gantry simulation, bit for bit.

The oracle is the simulation's numba kernel (``servotune.arch.gantry.run._gantry_kernel``, run
through :func:`~servotune.arch.gantry.run.run_gantry`): it closes the loop around the plants
and records, per cycle, the counter registers the drives latched, the CNC's command and the
operator's resets (the controller's inputs), and the D/A codes, flags, positions, references,
compensator calls and monitor levels (its outputs). The C runtime gets the same inputs, one
``st_gantry_step`` per cycle in a C loop (from the power-up state), and must give the same
outputs at every cycle; by induction it would drive the plants along the same trajectory.

The C sources (``servotune_rt.c`` and ``servotune_gantry.c`` with a harness below) are built
strictly (C99, every warning an error) into a shared library for ctypes, and once with the
undefined-behaviour sanitizer into a program that replays a file.

- Golden run: the example gantry (``plants/gantry.toml``, listening) for 110,000 cycles of
  back-and-forth moves, with load pulses on the slave's side that drive the compensation to
  its limit and trip the sync monitor (three times), an operator's reset while the skew is
  still past the trip threshold (the monitor trips again at once), resets that recover, a
  reset in motion while not tripped, a trip in motion, and the master's counter starting
  near the top of its 24-bit range (wraps both ways). Also under the sanitizer.
- Shorter golden runs (20,000 cycles) in every topology, with a PD compensator, and with bus
  latencies of 0 and 3 cycles.
- The constants: the digest over the layout of ``servotune.export.gantry_layout`` (equal to
  Python's SHA-256, and changed by any one field), and ``st_gantry_check``'s codes.
"""

from __future__ import annotations

import ctypes
import hashlib
from dataclasses import replace
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from c_build import STRICT, UBSAN, cc, needs_cc, run_cc, run_replay

from servotune.arch.gantry.config import MAX_LATENCY_CYCLES, TOPOLOGIES, GantryConfig
from servotune.arch.gantry.result import GantryTrace
from servotune.arch.gantry.run import OP_ENTER, OP_NONE, OP_STEP, run_gantry
from servotune.export.c import RUNTIME_FILES, runtime_source
from servotune.export.gantry_layout import (
    GANTRY_LAYOUT_FIELDS,
    gantry_layout_bytes,
    gantry_layout_sha256,
    gantry_layout_values,
)
from servotune.laws.axis import (
    C_COUNTER_BITS,
    C_DAC_MAX,
    C_DAC_ZERO,
    C_FE_LIMIT,
    C_KIT_F,
    C_KIT_Q,
    C_KP_F,
    C_KP_Q,
    C_LAW,
    C_LOCK_F,
    C_LOCK_Q,
    C_NF,
    C_TAB,
    FLAG_FOLLOWING_ERROR,
    FLAG_SYNC_TRIP,
)
from servotune.laws.sync import SYNC_TRIP
from servotune.scenarios import trapezoid_ref

pytestmark = needs_cc

ROOT = Path(__file__).resolve().parents[2]
GANTRY_FILES = ("servotune_gantry.c", "servotune_gantry.h")
N_CONSTS = len(GANTRY_LAYOUT_FIELDS)  # 84
# per cycle, the C harness writes these (st_gantry_out_t), in this order
OUT_FIELDS = ("code_m", "code_s", "flags_m", "flags_s", "y_m", "y_s", "ref_m", "ref_s",
              "sync_op", "sync_input", "sync_comp", "sync_level", "tripped")  # fmt: skip
N_OUT = len(OUT_FIELDS)

HARNESS = r"""
/* test harness of the gantry runtime, driven from Python (ctypes) or, for the sanitizer run,
 * from a file (main) */
#include <stdio.h>
#include <stdlib.h>

#include "servotune_gantry.h"

/* the 84 numbers of the digest layout, in its order, into the constants (the fields the PI
 * law does not use zero, ref_source -1) */
static void load(const int64_t *h, st_gantry_consts_t *c)
{
    int a;
    c->topology = (int32_t)h[0];
    c->latency = (int32_t)h[1];
    for (a = 0; a < 2; a++) {
        const int64_t *d = h + 2 + 36 * a;
        st_axis_consts_t *x = &c->drive[a];
        int i;
        x->law = (int32_t)d[0];
        x->lock_q = (int32_t)d[1];
        x->lock_f = (int16_t)d[2];
        x->kp_q = (int32_t)d[3];
        x->kp_f = (int16_t)d[4];
        x->kit_q = (int32_t)d[5];
        x->kit_f = (int16_t)d[6];
        x->fe_limit = (int32_t)d[7];
        x->counter_bits = (int16_t)d[8];
        x->dac_zero = (int32_t)d[9];
        x->dac_max = (int32_t)d[10];
        x->kdt_q = 0;
        x->kdt_f = 0;
        x->k1t_q = 0;
        x->k1t_f = 0;
        x->ke_q = 0;
        x->ke_f = 0;
        x->kec_q = 0;
        x->kec_f = 0;
        x->n = 0;
        for (i = 0; i < ST_N_TABLES; i++) {
            x->tf[i] = 0;
            x->tab[i] = NULL;
        }
        x->ref_source = -1;
        x->n_filters = (int32_t)d[11]; /* the drive's output filters, every slot */
        for (i = 0; i < ST_MAX_FILTERS; i++) {
            const int64_t *q = d + 12 + 6 * i;
            x->filter[i].b0 = (int32_t)q[0];
            x->filter[i].b1 = (int32_t)q[1];
            x->filter[i].b2 = (int32_t)q[2];
            x->filter[i].a1 = (int32_t)q[3];
            x->filter[i].a2 = (int32_t)q[4];
            x->filter[i].frac_bits = (int32_t)q[5];
        }
        x->shaper_n = 0; /* nor a reference shaper */
        x->shaper_q = NULL;
    }
    c->sync.kp_q = h[74];
    c->sync.kp_f = h[75];
    c->sync.kit_q = h[76];
    c->sync.kit_f = h[77];
    c->sync.kdt_q = h[78];
    c->sync.kdt_f = h[79];
    c->sync.dead_zone = h[80];
    c->sync.limit = h[81];
    c->sync.warn = h[82];
    c->sync.trip = h[83];
}

int h_check(const int64_t *h)
{
    st_gantry_consts_t c;
    load(h, &c);
    return st_gantry_check(&c);
}

/* st_gantry_check with one drive's unhashed fields set: ref_source and kdt_f */
int h_check_extra(const int64_t *h, int drive, int32_t ref_source, int16_t kdt_f)
{
    st_gantry_consts_t c;
    load(h, &c);
    c.drive[drive].ref_source = ref_source;
    c.drive[drive].kdt_f = kdt_f;
    return st_gantry_check(&c);
}

int h_digest(const int64_t *h, const uint8_t *sha)
{
    st_gantry_consts_t c;
    load(h, &c);
    return st_gantry_check_digest(&c, sha);
}

void h_sha(const int64_t *h, uint8_t *out)
{
    st_gantry_consts_t c;
    load(h, &c);
    st_gantry_sha256(&c, out);
}

int64_t h_define(int i)
{
    const int64_t v[] = {ST_TOPO_PARALLEL, ST_TOPO_FOLLOWING, ST_TOPO_LISTENING, ST_TOPO_CROSS,
                         ST_GANTRY_MAX_LATENCY, ST_SYNC_OP_NONE, ST_SYNC_OP_ENTER,
                         ST_SYNC_OP_STEP, ST_FLAG_SYNC_TRIP, ST_GANTRY_DIGEST_OK};
    return v[i];
}

/* n cycles from power-up: counter (n x 2), command, reset (n each) -> out (n x 13) */
void h_run(const int64_t *h, int64_t n, const int64_t *counter, const int64_t *command,
           const int64_t *reset, int64_t *out)
{
    static st_gantry_state_t s; /* 16 kB: not on the stack */
    st_gantry_consts_t c;
    int64_t k;
    load(h, &c);
    st_gantry_init(&s);
    for (k = 0; k < n; k++) {
        st_gantry_in_t in;
        st_gantry_out_t o;
        int64_t *r = out + 13 * k;
        in.counter[0] = counter[2 * k];
        in.counter[1] = counter[2 * k + 1];
        in.command = command[k];
        in.reset = reset[k] != 0;
        st_gantry_step(&c, &s, &in, &o);
        r[0] = o.code[0];
        r[1] = o.code[1];
        r[2] = o.flags[0];
        r[3] = o.flags[1];
        r[4] = o.y[0];
        r[5] = o.y[1];
        r[6] = o.ref[0];
        r[7] = o.ref[1];
        r[8] = o.sync_op;
        r[9] = o.sync_input;
        r[10] = o.sync_comp;
        r[11] = o.sync_level;
        r[12] = o.tripped;
    }
}

#ifdef H_MAIN
/* file replay: in = 84 constants, n, counter (2n), command (n), reset (n); out = 13n */
int main(int argc, char **argv)
{
    int64_t head[85];
    int64_t *buf;
    int64_t *out;
    size_t n;
    FILE *f;
    if (argc != 3) {
        return 2;
    }
    f = fopen(argv[1], "rb");
    if (f == NULL || fread(head, sizeof head[0], 85, f) != 85 || head[84] < 1) {
        return 3;
    }
    n = (size_t)head[84];
    buf = malloc(4 * n * sizeof *buf);
    out = malloc(13 * n * sizeof *out);
    if (buf == NULL || out == NULL || fread(buf, sizeof *buf, 4 * n, f) != 4 * n) {
        return 4;
    }
    fclose(f);
    h_run(head, (int64_t)n, buf, buf + 2 * n, buf + 3 * n, out);
    f = fopen(argv[2], "wb");
    if (f == NULL || fwrite(out, sizeof *out, 13 * n, f) != 13 * n) {
        return 6;
    }
    fclose(f);
    free(buf);
    free(out);
    return 0;
}
#endif
"""

_SOURCES = ("harness.c", "servotune_rt.c", "servotune_gantry.c")


# --- building ---------------------------------------------------------------------------------


def _gantry_source(name: str) -> str:
    # not (yet) in servotune.export.c.RUNTIME_FILES: read from the package data directly
    return resources.files("servotune.export").joinpath("runtime", name).read_text("utf-8")


def write_sources(d: Path) -> Path:
    """The runtime's and the gantry runtime's sources and the harness, in ``d``."""
    for name in RUNTIME_FILES:
        (d / name).write_text(runtime_source(name))
    for name in GANTRY_FILES:
        (d / name).write_text(_gantry_source(name))
    (d / "harness.c").write_text(HARNESS)
    return d


def build_lib(src: Path) -> ctypes.CDLL:
    """The harness built strictly as a shared library, its functions typed."""
    cc(src, *STRICT, "-O2", "-shared", "-fPIC", *_SOURCES, "-o", "libgantry.so")
    lib = ctypes.CDLL(str(src / "libgantry.so"))
    i64, p, i = ctypes.c_int64, ctypes.c_void_p, ctypes.c_int
    for name, restype, argtypes in (
        ("h_check", i, [p]),
        ("h_check_extra", i, [p, i, ctypes.c_int32, ctypes.c_int16]),
        ("h_digest", i, [p, p]),
        ("h_sha", None, [p, p]),
        ("h_define", i64, [i]),
        ("h_run", None, [p, i64, p, p, p, p]),
    ):
        fn = getattr(lib, name)
        fn.restype = restype
        fn.argtypes = argtypes
    return lib


@pytest.fixture(scope="module")
def src(tmp_path_factory) -> Path:
    return write_sources(tmp_path_factory.mktemp("c_gantry"))


@pytest.fixture(scope="module")
def lib(src: Path) -> ctypes.CDLL:
    return build_lib(src)


# --- the gantry, its constants and scenarios --------------------------------------------------


@pytest.fixture(scope="module")
def gantry() -> GantryConfig:
    from servotune.arch.gantry.load import load_gantry
    from servotune.arch.gantry.synthesis import resolve_gains

    return resolve_gains(load_gantry(ROOT / "plants" / "gantry.toml"))


def _layout_data(cfg: GantryConfig, topology: str) -> dict:
    """The ``data`` of a gantry tables export, as :mod:`servotune.export.gantry_layout`
    documents it."""
    rig = cfg.rig
    return {
        "topology": topology,
        "latency_cycles": cfg.bus.latency_cycles,
        "counter_bits": rig.counter.bits,
        "dac": {"zero_code": rig.dac.zero_code, "code_max": rig.dac.code_max},
        "drives": [{"controller": c.to_dict()} for c in cfg.controllers()],
        "sync": {
            "constants": cfg.sync_constants.to_dict(),
            "warn_counts": cfg.sync.warn_counts,
            "trip_counts": cfg.sync.trip_counts,
        },
    }


def _consts(cfg: GantryConfig, topology: str) -> np.ndarray:
    """The 84 constants the C runtime gets (the export's layout values), checked against the
    constants the simulation's kernel runs (``run_gantry``'s rows and sync vector)."""
    values = np.array(gantry_layout_values(_layout_data(cfg, topology)), dtype=np.int64)
    rig = cfg.rig
    kernel = [TOPOLOGIES.index(topology), cfg.bus.latency_cycles]
    for ctl in cfg.controllers():
        row = ctl.consts(
            counter_bits=rig.counter.bits, dac_bits=rig.dac.bits, dac_zero=rig.dac.zero_code
        )
        kernel += [
            int(row[i])
            for i in (
                C_LAW,
                C_LOCK_Q,
                C_LOCK_F,
                C_KP_Q,
                C_KP_F,
                C_KIT_Q,
                C_KIT_F,
                C_FE_LIMIT,
                C_COUNTER_BITS,
                C_DAC_ZERO,
                C_DAC_MAX,
            )
        ]
        kernel += [int(v) for v in row[C_NF:C_TAB]]  # the output filters, every slot
    k = cfg.sync_constants
    kernel += [
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
    assert values.tolist() == kernel
    return values


def _moves(n: int, dt: float, starts: list[int], distance: int = 150_000) -> np.ndarray:
    """The CNC's command: trapezoidal moves of ±``distance`` (alternating, the first
    positive) starting at each of ``starts``, each held until the next [counts]."""
    cmd = np.zeros(n, dtype=np.int64)
    at = 0
    for i, k0 in enumerate(starts):
        d = distance if i % 2 == 0 else -distance
        cmd[k0:] = at + trapezoid_ref(n - k0, dt, d, 60_000.0, 600_000.0)
        at += d
    return cmd


def _trip_events(level: np.ndarray, resets: np.ndarray) -> list[int]:
    """Cycles where the monitor's trip latches (a trip level with no trip latched; a reset
    clears the latch at the start of its cycle), as the kernel latches it."""
    out, latched = [], False
    for k in np.flatnonzero((level == SYNC_TRIP) | resets).tolist():
        if resets[k]:
            latched = False
        if level[k] == SYNC_TRIP and not latched:
            out.append(k)
            latched = True
    return out


def _seen_skew(tr: GantryTrace, lat: int) -> np.ndarray:
    """The sync error the monitor sees per cycle (measured, ``lat`` cycles old; 0 before)."""
    e = np.zeros(tr.y.shape[0], dtype=np.int64)
    e[lat:] = tr.y[: tr.y.shape[0] - lat, 0] - tr.y[: tr.y.shape[0] - lat, 1]
    return e


N_LONG = 110_000
PERIOD = 3_000  # a move (2.6 s) and its dwell [cycles]
PULSE_V = -3.5  # the slave's load pulses [V]


def _long_scenario(cfg: GantryConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The long run's command, load and resets.

    Moves back and forth every ``PERIOD`` cycles, with three rest windows of 12 s. In each
    window a load pulse of -3.5 V on the slave's side trips the monitor on the rebound (the
    skew negative, past the threshold), and the two drives, stopped, drift back (their
    offsets) until the skew is inside the threshold again. An operator's reset 50 cycles
    after the trip (the skew still past the threshold: the monitor trips again at once), and
    one at the first cycle the skew seen is 50 counts inside it (the drives and the
    compensator enter again). The resets are placed from the kernel's own runs. Before: a
    100 ms pulse that drives the compensation to its limit without a trip, and a reset in
    motion while not tripped; at the end, a pulse during a move that trips the monitor in
    motion, and a reset 600 cycles later (the command has moved on: the drives' following
    error trips).
    """
    dt, lat, trip = cfg.bus.cycle_s, cfg.bus.latency_cycles, cfg.sync.trip_counts
    window = 12_000
    starts, windows, k = [], [], 100
    for block in range(4):
        for _ in range(6):
            starts.append(k)
            k += PERIOD
        if block < 3:
            windows.append(k)
            k += window
    assert len(starts) % 2 == 0  # back home at the end of each block
    cmd = _moves(N_LONG, dt, starts)
    load = np.zeros((N_LONG, 2))
    resets = np.zeros(N_LONG, dtype=bool)
    load[starts[1] - 300 : starts[1] - 200, 1] = PULSE_V  # in a dwell: the compensation limit
    resets[starts[3] + 1_200] = True  # in motion, not tripped
    for w, dur in zip(windows, (200, 300, 500), strict=True):
        load[w + 500 : w + 500 + dur, 1] = PULSE_V
    k_end = starts[-1] + 1_800  # during the last move, at speed
    load[k_end : k_end + 100, 1] = -5.0
    resets[k_end + 600] = True
    for w in windows:
        tr = run_gantry(cfg, cmd, load, resets=resets)
        kt = next((t for t in _trip_events(tr.sync_level, resets) if t >= w), None)
        assert kt is not None and kt < w + 2_000, f"the pulse at cycle {w + 500} did not trip"
        resets[kt + 50] = True
        tr = run_gantry(cfg, cmd, load, resets=resets)
        skew = _seen_skew(tr, lat)
        ok = np.flatnonzero(np.abs(skew[kt + 100 : w + window]) < trip - 50)
        assert ok.size, f"the skew of the trip at cycle {kt} never came back inside the threshold"
        k_ok = kt + 100 + int(ok[0])
        assert k_ok < w + window - 2_000, (kt, k_ok)
        resets[k_ok] = True
    return cmd, load, resets


def _short_scenario(n: int = 20_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A shorter run: moves, two load pulses at rest that trip the monitor (the second one
    in every topology), a reset soon after the first, one 6 s later, and one in motion."""
    starts = [100, 3_100, 14_000, 17_000]
    cmd = _moves(n, 0.001, starts)
    load = np.zeros((n, 2))
    load[6_800:7_000, 1] = PULSE_V
    load[9_000:9_100, 1] = -5.0
    resets = np.zeros(n, dtype=bool)
    resets[[7_400, 12_500, 15_500]] = True
    return cmd, load, resets


# --- running both ---------------------------------------------------------------------------


def _inputs(tr: GantryTrace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (
        np.ascontiguousarray(tr.counter, dtype=np.int64),
        np.ascontiguousarray(tr.command, dtype=np.int64),
        np.ascontiguousarray(tr.resets, dtype=np.int64),
    )


def _c_run(lib: ctypes.CDLL, consts: np.ndarray, tr: GantryTrace) -> np.ndarray:
    counter, command, resets = _inputs(tr)
    n = command.size
    out = np.zeros((n, N_OUT), dtype=np.int64)
    lib.h_run(
        consts.ctypes.data,
        n,
        counter.ctypes.data,
        command.ctypes.data,
        resets.ctypes.data,
        out.ctypes.data,
    )
    return out


def _expected(tr: GantryTrace) -> np.ndarray:
    """The kernel's outputs in the harness's column order; ``tripped`` (not in the trace) is
    the latch of :func:`_trip_events`, held until a reset."""
    n = tr.command.size
    tripped = np.zeros(n, dtype=np.int64)
    events = _trip_events(tr.sync_level, tr.resets)
    later_resets = np.flatnonzero(tr.resets)
    for k in events:
        nxt = later_resets[later_resets > k]
        tripped[k : int(nxt[0]) if nxt.size else n] = 1
    cols = (
        tr.code[:, 0],
        tr.code[:, 1],
        tr.flags[:, 0],
        tr.flags[:, 1],
        tr.y[:, 0],
        tr.y[:, 1],
        tr.ref[:, 0],
        tr.ref[:, 1],
        tr.sync_op,
        tr.sync_input,
        tr.sync_comp,
        tr.sync_level,
        tripped,
    )
    return np.stack([np.asarray(c, dtype=np.int64) for c in cols], axis=1)


def _assert_same(c_out: np.ndarray, py: np.ndarray, run: str) -> None:
    """Every field at every cycle; else the first differing cycle and field."""
    diff = c_out != py
    if diff.any():
        k = int(np.flatnonzero(diff.any(axis=1))[0])
        bad = [
            f"{OUT_FIELDS[j]}: C {c_out[k, j]}, Python {py[k, j]}" for j in np.flatnonzero(diff[k])
        ]
        pytest.fail(f"{run}: C differs from the kernel first at cycle {k}: {'; '.join(bad)}")


# --- tests ------------------------------------------------------------------------------------


def test_defines_match_python(lib: ctypes.CDLL) -> None:
    """The C macros against the Python constants: the topology codes (TOPOLOGIES order), the
    latency bound (MAX_LATENCY_CYCLES), the compensator's ops (run.OP_*), the sync-trip flag."""
    assert [lib.h_define(i) for i in range(10)] == [
        *range(len(TOPOLOGIES)),
        MAX_LATENCY_CYCLES,
        OP_NONE,
        OP_ENTER,
        OP_STEP,
        FLAG_SYNC_TRIP,
        0,
    ]
    assert TOPOLOGIES == ("parallel", "following", "listening", "cross")


@pytest.fixture(scope="module")
def long_run(gantry: GantryConfig) -> tuple[GantryConfig, GantryTrace]:
    # the master's counter starts 60,000 counts below the top of its 24 bits: the moves wrap
    # it up and back down
    bits = gantry.rig.counter.bits
    cfg = replace(gantry, master=replace(gantry.master, counter_init=2**bits - 60_000))
    cmd, load, resets = _long_scenario(cfg)
    return cfg, run_gantry(cfg, cmd, load, resets=resets)


def test_golden_long_run_c_equals_the_kernel(lib, long_run) -> None:
    """110,000 cycles of the example gantry (listening): the C runtime fed the kernel's
    counter registers, commands and resets gives the kernel's codes, flags, positions,
    references, compensator ops, inputs and compensation and monitor levels at every cycle
    (and its trip latch). The scenario is checked to contain what it is for (on the kernel's
    trace): counter wraps both ways, the compensation at its limit, three trips at rest and
    one in motion, the listening slave stopped in the trip cycle and the master one cycle
    later, a reset that trips again at once, resets that recover (the compensator enters
    again), a reset while not tripped, a following-error trip."""
    cfg, tr = long_run
    n, lat = tr.command.size, cfg.bus.latency_cycles
    assert n >= 100_000 and tr.topology == "listening"
    level, resets, flags = tr.sync_level, tr.resets, tr.flags
    # counter wraps of the master, up and down
    jumps = np.diff(tr.counter[:, 0])
    assert np.any(jumps < -(2**23)) and np.any(jumps > 2**23)
    # the compensation at its limit
    assert np.any(np.abs(tr.sync_comp) == cfg.sync.limit_counts)
    # the trips: the first in each window, at rest, and one in motion
    events = _trip_events(level, resets)
    at_reset = [k for k in events if resets[k]]
    fresh = [k for k in events if not resets[k]]
    assert len(fresh) >= 4 and len(at_reset) >= 3, events
    for k in fresh:  # the listening slave stops at once, the master a cycle later
        assert flags[k, 1] & FLAG_SYNC_TRIP and not flags[k, 0] & FLAG_SYNC_TRIP, k
        assert flags[k + 1, 0] & FLAG_SYNC_TRIP and flags[k + 1, 1] & FLAG_SYNC_TRIP, k
        assert np.all(tr.sync_op[k : k + 10] == OP_NONE), k
    moving = [k for k in fresh if tr.command[k] != tr.command[k - 1]]
    assert moving, fresh
    # resets: past the threshold (trips again at once), recovering (the compensator enters
    # again and steps on), and one while not tripped
    reset_at = np.flatnonzero(resets)
    recovered = [k for k in reset_at if tr.sync_op[k] == OP_ENTER and tr.sync_op[k + 1] == OP_STEP]
    assert len(reset_at) >= 7 and len(recovered) >= 4, (reset_at, recovered)
    tripped = _expected(tr)[:, -1]
    assert any(not tripped[k - 1] for k in reset_at), "no reset while not tripped"
    assert np.any(flags & FLAG_FOLLOWING_ERROR)
    assert np.all(np.abs(_seen_skew(tr, lat)[level == SYNC_TRIP]) >= cfg.sync.trip_counts)
    # C == Python
    consts = _consts(cfg, "listening")
    assert lib.h_check(consts.ctypes.data) == 0
    _assert_same(_c_run(lib, consts, tr), _expected(tr), "long run")


def _variants(cfg: GantryConfig):
    """(label, config, topology): every topology, a PD compensator, latencies 0 and 3 cycles
    (the drives' and compensator's gains kept: the point is C == Python, not a good design).

    The PD compensator keeps the PI design's ``kp`` and adds ``kd``; ``resolve_gains`` then has
    nothing left to tune (a PD design of its own, ``kp=None``, takes about ten seconds)."""
    from servotune.arch.gantry.synthesis import resolve_gains

    for topo in TOPOLOGIES:
        yield topo, cfg, topo
    pd = resolve_gains(replace(cfg, sync=replace(cfg.sync, law="pd", ki=None, kd=0.002)))
    k = pd.sync_constants
    assert k.kd_t.q != 0 and k.ki_t.q == 0 and k.kp == cfg.sync_constants.kp
    yield "pd listening", pd, "listening"
    yield "pd cross", pd, "cross"
    yield "latency 3", replace(cfg, bus=replace(cfg.bus, latency_cycles=3)), "listening"
    yield "latency 3 following", replace(cfg, bus=replace(cfg.bus, latency_cycles=3)), "following"
    # the config takes latencies of 1 cycle and more; the kernel and the C runtime also run 0
    # (the sync error of the cycle itself): the config's check is bypassed here
    bus0 = replace(cfg.bus)
    object.__setattr__(bus0, "latency_cycles", 0)
    for topo in ("listening", "following"):
        yield f"latency 0 {topo}", replace(cfg, bus=bus0), topo


def test_golden_short_runs_every_topology_pd_and_latencies(lib, gantry) -> None:
    """20,000 cycles with a tripping load pulse and resets, in every topology, with a PD
    compensator (listening, cross) and with latencies 0 and 3 (listening, following): the C
    outputs equal the kernel's at every cycle. The kernel's traces are checked to exercise the
    compensator (enter and step, the derivative on), the following slave's reference (the
    master's position latency cycles old) and trips."""
    cmd, load, resets = _short_scenario()
    for label, cfg, topo in _variants(gantry):
        tr = run_gantry(cfg, cmd, load, topology=topo, resets=resets)
        lat = cfg.bus.latency_cycles
        if topo in ("listening", "cross"):
            assert np.sum(tr.sync_op == OP_ENTER) >= 1 and np.sum(tr.sync_op == OP_STEP) > 1000
        else:
            assert np.all(tr.sync_op == OP_NONE)
        if topo == "following":
            assert np.array_equal(tr.ref[lat:, 1], tr.y[: tr.y.shape[0] - lat, 0]), label
        assert _trip_events(tr.sync_level, tr.resets), f"{label}: no trip"
        consts = _consts(cfg, topo)
        assert consts[1] == lat
        assert lib.h_check(consts.ctypes.data) == 0, label
        _assert_same(_c_run(lib, consts, tr), _expected(tr), label)


def test_golden_long_run_under_the_undefined_behaviour_sanitizer(src, long_run) -> None:
    """The long run replayed by the harness program built with ``-fsanitize=undefined
    -fno-sanitize-recover``: no sanitizer report, and the same outputs as the kernel."""
    probe = src / "probe.c"
    probe.write_text("int main(void) { return 0; }\n")
    res = run_cc(src, *UBSAN, "probe.c", "-o", "probe")
    if res.returncode != 0:
        pytest.skip(f"the compiler cannot link -fsanitize=undefined here:\n{res.stderr}")
    cc(src, *STRICT, *UBSAN, "-DH_MAIN", *_SOURCES, "-o", "h_ubsan")
    cfg, tr = long_run
    counter, command, resets = _inputs(tr)
    head = np.append(_consts(cfg, "listening"), command.size).astype(np.int64)
    payload = b"".join(a.tobytes() for a in (head, counter, command, resets))
    out = np.frombuffer(run_replay(src / "h_ubsan", payload, timeout=120), dtype=np.int64)
    _assert_same(out.reshape(-1, N_OUT), _expected(tr), "long run under UBSan")


def test_digest_is_the_layout_sha256_and_changes_with_every_field(lib, gantry) -> None:
    """``st_gantry_check_digest`` accepts the SHA-256 that ``gantry_layout_sha256`` gives for
    the export's data (and ``st_gantry_sha256`` hashes exactly ``gantry_layout_bytes``), and
    rejects it when any one of the 84 constants is changed by one."""
    data = _layout_data(gantry, "listening")
    consts = _consts(gantry, "listening")
    sha = bytes.fromhex(gantry_layout_sha256(data))
    assert len(gantry_layout_bytes(data)) == 672
    assert sha == hashlib.sha256(consts.astype("<i8").tobytes()).digest()
    out = ctypes.create_string_buffer(32)
    lib.h_sha(consts.ctypes.data, out)
    assert out.raw == sha
    assert lib.h_digest(consts.ctypes.data, sha) == 0
    for i, name in enumerate(GANTRY_LAYOUT_FIELDS):
        for delta in (1, -1):
            c = consts.copy()
            c[i] += delta
            assert lib.h_digest(c.ctypes.data, sha) != 0, (name, delta)
    assert lib.h_digest(consts.ctypes.data, None) != 0
    for topo in TOPOLOGIES:  # the topology is hashed: another topology, another digest
        d = _layout_data(gantry, topo)
        c = _consts(gantry, topo)
        assert lib.h_digest(c.ctypes.data, bytes.fromhex(gantry_layout_sha256(d))) == 0
        assert (topo == "listening") == (lib.h_digest(c.ctypes.data, sha) == 0)


def checker(lib: ctypes.CDLL, good: np.ndarray):
    """``check(**changes)``: ``st_gantry_check``'s code for ``good`` with the layout fields
    changed (``master__kp_f=40`` is ``master.kp_f``)."""
    at = {name: i for i, name in enumerate(GANTRY_LAYOUT_FIELDS)}

    def check(**changes: int) -> int:
        c = good.copy()
        for name, v in changes.items():
            c[at[name.replace("__", ".")]] = v
        return lib.h_check(c.ctypes.data)

    return check


def test_check_accepts_the_example_and_names_the_bad_field(lib, gantry) -> None:
    """``st_gantry_check`` returns 0 for the example in every topology and at the latency
    bounds, and the documented code (servotune_gantry.h) for one bad field at a time."""
    good = _consts(gantry, "listening")
    check = checker(lib, good)
    assert check() == 0
    for t in range(4):
        assert check(topology=t) == 0
    assert check(latency=0) == 0 and check(latency=MAX_LATENCY_CYCLES) == 0
    cases = [
        ({"topology": 4}, 1),
        ({"topology": -1}, 1),
        ({"latency": -1}, 2),
        ({"latency": MAX_LATENCY_CYCLES + 1}, 2),
        ({"master__law": 2}, 101),
        ({"slave__law": 0}, 201),
        ({"master__lock_f": 33}, 102),
        ({"master__kp_f": -1}, 103),
        ({"slave__kit_f": 33}, 204),
        ({"master__fe_limit": -1}, 105),
        ({"slave__counter_bits": 20}, 206),
        ({"master__dac_max": 65536}, 107),
        ({"slave__dac_zero": 5000}, 207),
        ({"master__dac_zero": -1}, 107),
        ({"sync__kp_q": 2**31}, 301),
        ({"sync__kp_f": 33}, 302),
        ({"sync__kit_q": -(2**31) - 1}, 303),
        ({"sync__kit_f": -1}, 304),
        ({"sync__kdt_q": 2**40}, 305),
        ({"sync__kdt_f": 40}, 306),
        ({"sync__dead_zone": -1}, 307),
        ({"sync__limit": 0}, 308),
        ({"sync__limit": 2**31}, 308),
        ({"sync__warn": -1}, 309),
        ({"sync__trip": -1}, 310),
        # the first bad field is named
        ({"topology": 7, "latency": -1}, 1),
        ({"master__kp_f": 40, "slave__law": 2, "sync__limit": 0}, 103),
        ({"slave__law": 2, "sync__limit": 0}, 201),
    ]
    for changes, code in cases:
        assert check(**changes) == code, changes
    # the fields the layout does not carry: ref_source, an unused fraction
    assert lib.h_check_extra(good.ctypes.data, 0, -1, 0) == 0
    assert lib.h_check_extra(good.ctypes.data, 0, 1, 0) == 108
    assert lib.h_check_extra(good.ctypes.data, 1, 0, 0) == 208
    assert lib.h_check_extra(good.ctypes.data, 1, -1, 33) == 209
