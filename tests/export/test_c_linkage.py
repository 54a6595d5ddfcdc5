"""The slave CPU's receive queue and clock-sync logic in C (``servotune_link.c``) against the
linkage simulation, bit for bit, and the exported plan header.

The reference is the simulation's own event log (:attr:`servotune.arch.linkage.CpuResult.
events`, ``run_linkage(..., trace=True)``): for each slave CPU, in order, the blocks that
arrived (the prefill first), the clock syncs and the ticks, with what the simulation's queue
did at each (levels, commands discarded, setpoints lost or late, the next index) and, from the
axis traces, the command each axis followed at each tick. The C is compiled with the system
compiler (strict C99, every warning an error) into a shared library and, once more, with the
undefined-behaviour sanitizer into a program that replays a file. It is fed only the events'
kinds and arguments (block index and the block's commands, sync tick index, tick) and must
give the simulation's outputs at every event.

The golden run (:func:`_golden_config`) is built to exercise every branch: two CPUs of two
axes, one +3000 ppm fast and one -3000 ppm slow, a one-block prefill and 12-setpoint queues,
a sync every 4 s (12 ticks of drift between syncs apart): the fast CPU runs ahead of the
broadcast (under-runs, blocks arriving after their ticks), the slow one falls behind (queue
full: overruns, commands lost, under-runs where they were lost) and skips commands at each
sync; the corrections at the syncs have both signs. 100,500 master ticks (201 s).
"""

from __future__ import annotations

import copy
import ctypes
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from c_build import STRICT, UBSAN, cc, needs_cc, run_replay

from servotune.arch.linkage import (
    EVENT_COLUMNS,
    LinkageConfig,
    LinkageResult,
    linkage_from_dict,
    plan_linkage,
    run_linkage,
)
from servotune.errors import ExportError
from servotune.export import c as c_export
from servotune.export.c import LINK_RUNTIME_FILES, RUNTIME_FILES, runtime_source
from servotune.export.linkage import LINK_HEADER_NAME, linkage_c_header

pytestmark = needs_cc

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "plants" / "linkage-6axis.toml"
N_TICKS = 100_500
SEED = 5
LOW, HIGH = 3, 11  # the golden queues' watermarks [setpoints] (depth 12)
SYNC, TICK, BLOCK = 0, 1, 2  # EVENT_KINDS codes
N_OUT = 8  # the harness's outputs per event: the 7 log columns, then the C's flags (or wait)
COUNTERS = ("ticks", "underruns", "overruns", "dropped", "late", "stale", "syncs", "skipped",
            "behind", "ahead")  # fmt: skip
# flags of servotune_link.h
UNDERRUN, OVERRUN, LATE, STALE, LOW_FLAG, HIGH_FLAG, BAD = 1, 2, 4, 8, 16, 32, 64

HARNESS = r"""
/* test harness: replay a slave CPU's event log through servotune_link.c */
#include <stdio.h>
#include <stdlib.h>

#include "servotune_link.h"

/* k: n_axes, depth, block_size, low_watermark, high_watermark; ev: n_ev rows of 7 (the
 * simulation's log: only kind and arg are read); cmd: n_cmd rows of n_axes commands (row =
 * command index); out: n_ev rows of 8 (kind, arg, level before, level after, count, late,
 * next, flags or wait); popped: n_axes commands per tick; cnt: the 10 counters at the end.
 * Returns 0, -1 for bad constants, or 1 + the index of an event the inputs cannot serve. */
int h_replay(const int64_t *k, int64_t n_ev, const int64_t *ev, int64_t n_cmd,
             const int32_t *cmd, int64_t *out, int32_t *popped, int64_t *cnt)
{
    stl_consts_t c;
    static stl_state_t s; /* about 6 kB: not on the stack */
    int64_t i;
    int64_t t = 0;
    c.n_axes = (int32_t)k[0];
    c.depth = (int32_t)k[1];
    c.block_size = (int32_t)k[2];
    c.low_watermark = (int32_t)k[3];
    c.high_watermark = (int32_t)k[4];
    if (stl_check_consts(&c) != 0) {
        return -1;
    }
    stl_init(&s);
    for (i = 0; i < n_ev; i++) {
        const int64_t kind = ev[7 * i];
        const int64_t arg = ev[7 * i + 1];
        int64_t *o = out + N_OUT * i;
        o[0] = kind;
        o[1] = arg;
        o[2] = s.level;
        o[5] = 0;
        if (kind == 0) {
            const int64_t skipped = s.skipped;
            o[5] = s.next;
            o[7] = stl_sync(&c, &s, arg);
            o[4] = s.skipped - skipped;
        } else if (kind == 1) {
            o[1] = s.next; /* the index this tick executes: the C's own bookkeeping */
            o[7] = stl_tick(&c, &s, popped + c.n_axes * t);
            o[4] = (o[7] & STL_UNDERRUN) ? 1 : 0;
            t++;
        } else {
            const int64_t dropped = s.dropped;
            const int64_t late = s.late;
            if (arg < 0 || (arg + 1) * c.block_size > n_cmd) {
                return (int)(1 + i);
            }
            o[7] = stl_push(&c, &s, arg, cmd + arg * c.block_size * c.n_axes);
            o[4] = s.dropped - dropped;
            o[5] = s.late - late;
        }
        o[3] = s.level;
        o[6] = s.next;
    }
    cnt[0] = s.ticks;
    cnt[1] = s.underruns;
    cnt[2] = s.overruns;
    cnt[3] = s.dropped;
    cnt[4] = s.late;
    cnt[5] = s.stale;
    cnt[6] = s.syncs;
    cnt[7] = s.skipped;
    cnt[8] = s.behind;
    cnt[9] = s.ahead;
    return 0;
}

/* the edge cases of one call each on a state the test builds: op 0 push (a = block, the
 * commands from cmd), 1 tick, 2 sync (a = tick); out: 8 per op (level, next, result, the
 * popped commands of a tick (up to 4), stale) */
int h_ops(const int64_t *k, int64_t n_ops, const int64_t *op, const int64_t *a,
          const int32_t *cmd, int64_t *out)
{
    stl_consts_t c;
    static stl_state_t s;
    int32_t got[STL_MAX_AXES] = {0};
    int64_t i;
    int j;
    c.n_axes = (int32_t)k[0];
    c.depth = (int32_t)k[1];
    c.block_size = (int32_t)k[2];
    c.low_watermark = (int32_t)k[3];
    c.high_watermark = (int32_t)k[4];
    if (stl_check_consts(&c) != 0) {
        return stl_check_consts(&c);
    }
    stl_init(&s);
    for (i = 0; i < n_ops; i++) {
        int64_t *o = out + 8 * i;
        if (op[i] == 0) {
            o[2] = stl_push(&c, &s, a[i], cmd + i * c.block_size * c.n_axes);
        } else if (op[i] == 1) {
            o[2] = stl_tick(&c, &s, got);
        } else {
            o[2] = stl_sync(&c, &s, a[i]);
        }
        o[0] = s.level;
        o[1] = s.next;
        for (j = 0; j < 4; j++) {
            o[3 + j] = j < c.n_axes ? got[j] : 0;
        }
        o[7] = s.stale;
    }
    return 0;
}

int h_check(const int64_t *k)
{
    stl_consts_t c;
    c.n_axes = (int32_t)k[0];
    c.depth = (int32_t)k[1];
    c.block_size = (int32_t)k[2];
    c.low_watermark = (int32_t)k[3];
    c.high_watermark = (int32_t)k[4];
    return stl_check_consts(&c);
}

#ifdef H_MAIN
/* file replay: in = k (5), n_ev, n_cmd, ev (7 n_ev), cmd (n_axes n_cmd), all int64;
 * out = the return value, the counters (10), out (8 n_ev), popped (n_axes n_ev, as int64) */
int main(int argc, char **argv)
{
    int64_t head[7];
    int64_t *ev;
    int64_t *cmd64;
    int32_t *cmd;
    int64_t *out;
    int32_t *popped;
    int64_t *res;
    int64_t cnt[10];
    int64_t n_ev;
    int64_t n_cmd;
    int64_t i;
    int64_t rc;
    size_t n_pop;
    FILE *f;
    if (argc != 3) {
        return 2;
    }
    f = fopen(argv[1], "rb");
    if (f == NULL || fread(head, sizeof head[0], 7, f) != 7) {
        return 3;
    }
    n_ev = head[5];
    n_cmd = head[6];
    n_pop = (size_t)head[0] * (size_t)n_ev;
    ev = malloc(7 * (size_t)n_ev * sizeof *ev);
    cmd64 = malloc((size_t)head[0] * (size_t)n_cmd * sizeof *cmd64);
    cmd = malloc((size_t)head[0] * (size_t)n_cmd * sizeof *cmd);
    out = malloc(N_OUT * (size_t)n_ev * sizeof *out);
    popped = calloc(n_pop, sizeof *popped);
    res = malloc(n_pop * sizeof *res);
    if (ev == NULL || cmd64 == NULL || cmd == NULL || out == NULL || popped == NULL
        || res == NULL || fread(ev, sizeof *ev, 7 * (size_t)n_ev, f) != 7 * (size_t)n_ev
        || fread(cmd64, sizeof *cmd64, (size_t)head[0] * (size_t)n_cmd, f)
               != (size_t)head[0] * (size_t)n_cmd) {
        return 4;
    }
    fclose(f);
    for (i = 0; i < head[0] * n_cmd; i++) {
        cmd[i] = (int32_t)cmd64[i];
    }
    rc = h_replay(head, n_ev, ev, n_cmd, cmd, out, popped, cnt);
    for (i = 0; i < (int64_t)n_pop; i++) {
        res[i] = popped[i];
    }
    f = fopen(argv[2], "wb");
    if (f == NULL || fwrite(&rc, sizeof rc, 1, f) != 1 || fwrite(cnt, sizeof cnt[0], 10, f) != 10
        || fwrite(out, sizeof *out, N_OUT * (size_t)n_ev, f) != N_OUT * (size_t)n_ev
        || fwrite(res, sizeof *res, n_pop, f) != n_pop) {
        return 6;
    }
    fclose(f);
    free(ev);
    free(cmd64);
    free(cmd);
    free(out);
    free(popped);
    free(res);
    return 0;
}
#endif
""".replace("N_OUT", str(N_OUT))


# --- building -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def src(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("c_linkage")
    for name in LINK_RUNTIME_FILES:
        (d / name).write_text(runtime_source(name))
    (d / "harness.c").write_text(HARNESS)
    return d


@pytest.fixture(scope="module")
def lib(src: Path) -> ctypes.CDLL:
    cc(src, *STRICT, "-O2", "-shared", "-fPIC", "harness.c", "servotune_link.c", "-o", "libh.so")
    lib = ctypes.CDLL(str(src / "libh.so"))
    i64, p, i = ctypes.c_int64, ctypes.c_void_p, ctypes.c_int
    for name, argtypes in (
        ("h_replay", [p, i64, p, i64, p, p, p, p]),
        ("h_ops", [p, i64, p, p, p, p]),
        ("h_check", [p]),
    ):
        fn = getattr(lib, name)
        fn.restype = i
        fn.argtypes = argtypes
    return lib


# --- the golden run -----------------------------------------------------------------------------


def _golden_config() -> LinkageConfig:
    """The example's x, y, z, a on two CPUs built to under-run, overrun and skip (module
    docstring); its path repeated 14 times so the axes move over the whole run."""
    d: dict[str, Any] = copy.deepcopy(tomllib.loads(EXAMPLE.read_text(encoding="utf-8")))
    axes = ("x", "y", "z", "a")
    for gone in ("b", "c"):
        del d["axis"][gone]
    moves = []
    for mv in d["path"]["move"]:
        mv = dict(mv)
        if "to" in mv:
            mv["to"] = {k: v for k, v in mv["to"].items() if k in axes}
        moves.append(mv)
    d["path"]["move"] = moves * 14
    d["bus"]["prefill_blocks"] = 1
    d["cpu"] = [
        {"name": "fast", "clock_ppm": 3000.0, "axes": ["x", "y"], "queue_depth": 12},
        {"name": "slow", "clock_ppm": -3000.0, "axes": ["z", "a"], "queue_depth": 12},
    ]
    d["clock"] = {"resync_interval_s": 4.0}
    return linkage_from_dict(d, EXAMPLE.parent)


@pytest.fixture(scope="module")
def golden() -> tuple[LinkageConfig, LinkageResult]:
    cfg = _golden_config()
    return cfg, run_linkage(cfg, seconds=N_TICKS * cfg.period_s, seed=SEED, trace=True)


def _inputs(cfg: LinkageConfig, res: LinkageResult, s: int) -> dict[str, np.ndarray]:
    """CPU ``s``'s replay inputs: its constants, its event log, and the master's commands of its
    axes by command index (the interpolated path, then its end held: what the blocks carry)."""
    cpu = res.cpus[s]
    ev = np.ascontiguousarray(cpu.events, dtype=np.int64)
    blocks = ev[ev[:, 0] == BLOCK, 1]
    b = cfg.bus.block_size
    n_cmd = (int(blocks.max()) + 1) * b
    commands = res.interpolation.commands
    rows = np.minimum(np.arange(n_cmd), commands.shape[0] - 1)
    cols = [cfg.axis_names.index(a) for a in cpu.axes]
    cmd = commands[rows][:, cols]
    assert np.abs(cmd).max() < 2**31  # int32 setpoints
    k = np.array([len(cpu.axes), cpu.queue_depth, b, LOW, HIGH], dtype=np.int64)
    return {"k": k, "ev": ev, "cmd": np.ascontiguousarray(cmd, dtype=np.int64)}


def _c_replay(lib: ctypes.CDLL, inp: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    ev, cmd = inp["ev"], np.ascontiguousarray(inp["cmd"], dtype=np.int32)
    n_ax = int(inp["k"][0])
    out = np.zeros((ev.shape[0], N_OUT), dtype=np.int64)
    popped = np.zeros((ev.shape[0], n_ax), dtype=np.int32)
    cnt = np.zeros(len(COUNTERS), dtype=np.int64)
    ptr = [x.ctypes.data for x in (inp["k"], ev, cmd, out, popped, cnt)]
    rc = lib.h_replay(ptr[0], ev.shape[0], ptr[1], cmd.shape[0], *ptr[2:])
    assert rc == 0, f"the replay stopped at event {rc - 1}"
    n_ticks = int(np.sum(ev[:, 0] == TICK))
    return {"out": out, "popped": popped[:n_ticks].astype(np.int64), "cnt": cnt}


def _first_difference(name: str, got: np.ndarray, want: np.ndarray, ev: np.ndarray) -> str:
    """The first event where the C and the simulation differ, for the failure message."""
    bad = np.argwhere(got != want)
    i, j = (int(x) for x in bad[0])
    return (
        f"cpu {name}: {bad.shape[0]} differences, the first at event {i} "
        f"({('sync', 'tick', 'block')[ev[i, 0]]} {ev[i, 1]}), column {EVENT_COLUMNS[j]!r}: "
        f"C {got[i, j]}, simulation {want[i, j]}"
    )


def _expected_flags(ev: np.ndarray) -> np.ndarray:
    """The flags servotune_link.h defines, from the simulation's log (ticks and blocks)."""
    kind, before, after, count, late = ev[:, 0], ev[:, 2], ev[:, 3], ev[:, 4], ev[:, 5]
    tick = np.where(count == 1, UNDERRUN, 0) | np.where(before < LOW, LOW_FLAG, 0)
    block = (
        np.where(count > 0, OVERRUN, 0)
        | np.where(late > 0, LATE, 0)
        | np.where(after > HIGH, HIGH_FLAG, 0)
    )
    return np.where(kind == TICK, tick, np.where(kind == BLOCK, block, 0))


def test_golden_run_exercises_every_branch(golden: tuple[LinkageConfig, LinkageResult]) -> None:
    """What the replay must contain: >= 100k ticks per CPU, under-runs, overruns, blocks
    after their ticks, commands lost and skipped, and clock corrections of both signs."""
    _, res = golden
    fast, slow = res.cpus
    for cpu in (fast, slow):
        assert cpu.tick_time_s.size >= 100_000
        assert cpu.underruns >= 1 and cpu.resyncs >= 40
        # the log and the CPU's records agree: one tick event per tick, same indices, levels
        ev = cpu.events
        ticks = ev[ev[:, 0] == TICK]
        assert np.array_equal(ticks[:, 1], cpu.tick_index)
        assert np.array_equal(ticks[:, 2], cpu.queue_level)
        assert int(ticks[:, 4].sum()) == cpu.underruns
        assert int(np.sum(ev[:, 0] == SYNC)) == cpu.resyncs + 1  # and the one at motion start
    sync = {c.name: c.events[c.events[:, 0] == SYNC] for c in (fast, slow)}
    correction = {n: e[:, 1] - e[:, 5] for n, e in sync.items()}  # master tick − next index
    assert correction["fast"].min() < 0 and correction["slow"].max() > 0  # both signs
    assert slow.skipped > 0 and slow.overruns > 0 and fast.skipped == 0
    blocks = fast.events[fast.events[:, 0] == BLOCK]
    assert blocks[:, 5].sum() > 0  # the fast CPU got blocks after their ticks
    assert slow.events[slow.events[:, 0] == BLOCK][:, 4].sum() > 0  # the slow one lost some


def test_golden_replay_is_bit_exact(
    lib: ctypes.CDLL, golden: tuple[LinkageConfig, LinkageResult]
) -> None:
    cfg, res = golden
    assert res.traces is not None
    seen = 0  # the flags raised over both CPUs
    for s, cpu in enumerate(res.cpus):
        inp = _inputs(cfg, res, s)
        ev = inp["ev"]
        c = _c_replay(lib, inp)
        out = c["out"]
        # every event: kind, index, levels, counts, next index, as the simulation's queue
        if not np.array_equal(out[:, :7], ev):
            pytest.fail(_first_difference(cpu.name, out[:, :7], ev, ev))
        # the flags of ticks and blocks, from the simulation's levels and counts
        is_sync = ev[:, 0] == SYNC
        flags = np.where(is_sync, 0, out[:, 7])
        want = _expected_flags(ev)
        bad = np.flatnonzero(flags != want)
        assert bad.size == 0, f"cpu {cpu.name}: flags differ first at event {bad[0]}"
        seen |= int(np.bitwise_or.reduce(want))
        # the commands each axis followed at each tick (held on an under-run)
        ref = np.column_stack([t.ref_counts for t in res.traces if t.cpu == cpu.name])
        assert c["popped"].shape == ref.shape
        diff = np.argwhere(c["popped"] != ref)
        assert diff.size == 0, f"cpu {cpu.name}: command differs first at tick, axis {diff[0]}"
        # the wait after each sync is when the simulation's next tick came:
        # k_r·T + wait·T/(1 + ε) (the sync semantics: the slave's clock restarts at the sync)
        t, eps = cfg.period_s, cpu.clock_ppm * 1e-6
        tick_no = np.cumsum(ev[:, 0] == TICK)  # ticks up to each event
        for i in np.flatnonzero(is_sync):
            if tick_no[i] >= cpu.tick_time_s.size:
                continue  # the run ended before the next tick
            k_r, wait = int(ev[i, 1]), int(out[i, 7])
            assert wait == max(0, int(ev[i, 5]) - k_r)
            assert cpu.tick_time_s[tick_no[i]] == pytest.approx(
                k_r * t + wait * t / (1.0 + eps), rel=0, abs=1e-12
            )
        # the counters at the end are the simulation's
        cnt = dict(zip(COUNTERS, c["cnt"].tolist(), strict=True))
        assert cnt["ticks"] == cpu.tick_time_s.size and cnt["underruns"] == cpu.underruns
        assert cnt["overruns"] == cpu.overruns and cnt["skipped"] == cpu.skipped
        assert cnt["syncs"] == cpu.resyncs + 1 and cnt["stale"] == 0
        assert cnt["behind"] + cnt["ahead"] > 0
    assert seen == UNDERRUN | OVERRUN | LATE | LOW_FLAG | HIGH_FLAG


def test_golden_replay_under_ubsan(src: Path, golden: tuple[LinkageConfig, LinkageResult]) -> None:
    """The same replay built with the undefined-behaviour sanitizer: no report, the same outputs
    (the slow CPU: skips, overruns, under-runs)."""
    cfg, res = golden
    cc(src, *STRICT, *UBSAN, "-DH_MAIN", "harness.c", "servotune_link.c", "-o", "replay_ubsan")
    inp = _inputs(cfg, res, 1)
    ev, cmd = inp["ev"], inp["cmd"]
    head = np.concatenate([inp["k"], [ev.shape[0], cmd.shape[0]]]).astype(np.int64)
    payload = head.tobytes() + ev.tobytes() + cmd.astype(np.int64).tobytes()
    raw = np.frombuffer(run_replay(src / "replay_ubsan", payload, timeout=120), dtype=np.int64)
    assert raw[0] == 0
    out = raw[11 : 11 + N_OUT * ev.shape[0]].reshape(-1, N_OUT)
    if not np.array_equal(out[:, :7], ev):
        pytest.fail(_first_difference(res.cpus[1].name, out[:, :7], ev, ev))
    n_ax = int(inp["k"][0])
    n_ticks = res.cpus[1].tick_time_s.size
    popped = raw[11 + N_OUT * ev.shape[0] :].reshape(-1, n_ax)[:n_ticks]
    ref = np.column_stack([t.ref_counts for t in res.traces if t.cpu == "slow"])
    assert np.array_equal(popped, ref)


# --- edges by hand --------------------------------------------------------------------------------


def _ops(lib: ctypes.CDLL, k: list[int], ops: list[tuple[int, int, list[int]]]) -> np.ndarray:
    kk = np.array(k, dtype=np.int64)
    op = np.array([o for o, _, _ in ops], dtype=np.int64)
    a = np.array([x for _, x, _ in ops], dtype=np.int64)
    width = k[0] * k[2]
    cmd = np.zeros((len(ops), width), dtype=np.int32)
    for i, (_, _, c) in enumerate(ops):
        cmd[i, : len(c)] = c
    out = np.zeros((len(ops), 8), dtype=np.int64)
    assert (
        lib.h_ops(
            kk.ctypes.data,
            len(ops),
            op.ctypes.data,
            a.ctypes.data,
            cmd.ctypes.data,
            out.ctypes.data,
        )
        == 0
    )
    return out


def test_queue_edges_by_hand(lib: ctypes.CDLL) -> None:
    """Each rule of servotune_link.h on a 2-axis queue of depth 4, blocks of 2, watermarks
    2 and 3; the expected values follow the header's rules, worked out here by hand."""
    push, tick, sync = 0, 1, 2
    out = _ops(
        lib,
        [2, 4, 2, 2, 3],
        [
            (push, 0, [10, 20, 11, 21]),  # indices 0, 1: level 2
            (push, 0, [99, 99, 99, 99]),  # the same block again: stale, ignored
            (tick, 0, []),  # executes 0: (10, 20)
            (push, 2, [14, 24, 15, 25]),  # block 2 (indices 4, 5) before block 1: queued
            (push, 1, [12, 22, 13, 23]),  # block 1 (2, 3) now older than the newest: stale
            (tick, 0, []),  # executes 1: (11, 21)
            (tick, 0, []),  # index 2 missing: under-run, holds (11, 21)
            (push, -1, []),  # a negative block index: refused (STL_BAD)
            (sync, 5, []),  # behind (next 3 < 5): 4 discarded, next = 5, wait 0
            (tick, 0, []),  # executes 5: (15, 25); level 1 before: < 2, LOW
            (sync, 4, []),  # ahead (next 6 >= 4): wait 2 ticks
            (sync, -3, []),  # a negative tick: ignored, -1
            (push, 3, [16, 26, 17, 27]),  # indices 6, 7 queued
            (push, 4, [18, 28, 19, 29]),  # 8, 9: level 4 > 3: HIGH
            (push, 5, [30, 40, 31, 41]),  # full: lost (overrun), level stays 4 > 3: HIGH
        ],
    )
    level, nxt, result, stale = out[:, 0], out[:, 1], out[:, 2], out[:, 7]
    assert level.tolist() == [2, 2, 1, 3, 3, 2, 2, 2, 1, 0, 0, 0, 2, 4, 4]
    assert nxt.tolist() == [0, 0, 1, 1, 1, 2, 3, 3, 5, 6, 6, 6, 6, 6, 6]
    assert result[1] == STALE and stale[1] == 2 and stale[4] == 4
    assert out[2, 3:5].tolist() == [10, 20] and out[5, 3:5].tolist() == [11, 21]
    assert result[6] == UNDERRUN and out[6, 3:5].tolist() == [11, 21]  # held
    assert result[7] == BAD
    assert result[8] == 0 and result[10] == 2 and result[11] == -1  # waits
    assert result[9] == LOW_FLAG and out[9, 3:5].tolist() == [15, 25]
    assert result[12] == 0 and result[13] == HIGH_FLAG and result[14] == OVERRUN | HIGH_FLAG
    assert all(result[i] == 0 for i in (0, 2, 3, 5))  # levels 2, 3 before a pop: no LOW


def test_check_consts_names_the_bad_field(lib: ctypes.CDLL) -> None:
    good = [4, 256, 5, 0, 256]
    assert lib.h_check(np.array(good, dtype=np.int64).ctypes.data) == 0
    broken = {0: [0, 5], 1: [0, 257], 2: [0, 257], 3: [-1, 257], 4: [-1, 257]}
    for i, values in broken.items():
        for v in values:
            k = np.array(good, dtype=np.int64)
            k[i] = v
            assert lib.h_check(k.ctypes.data) == i + 1, (i, v)
    k = np.array([2, 10, 5, 6, 5], dtype=np.int64)  # high below low
    assert lib.h_check(k.ctypes.data) == 5


# --- the exported header ----------------------------------------------------------------------


def test_exported_header_compiles_and_holds_the_plan(tmp_path: Path) -> None:
    """The example's plan exported unverified: the header builds strictly with the queue code,
    and every constant a slave needs is the plan's."""
    plan = plan_linkage(EXAMPLE)
    with pytest.raises(ExportError, match="no verification record"):
        c_export.to_file(plan, tmp_path)
    written = c_export.to_file(plan, tmp_path, unverified=True)
    assert [p.name for p in written] == [LINK_HEADER_NAME, *LINK_RUNTIME_FILES, *RUNTIME_FILES]
    header = linkage_c_header(plan, None, unverified=True)
    assert (tmp_path / LINK_HEADER_NAME).read_text() == header
    want: list[int] = [
        plan.n_axes,
        len(plan.cpus),
        plan.bus.block_size,
        plan.bus.prefill_blocks,
        plan.frame_bytes,
        plan.bits_per_block,
        plan.resync_ticks,
        0,
    ]
    macros = [
        "STL_N_AXES",
        "STL_N_CPUS",
        "STL_BLOCK_SIZE",
        "STL_PREFILL_BLOCKS",
        "STL_FRAME_BYTES",
        "STL_BITS_PER_BLOCK",
        "STL_RESYNC_TICKS",
        "STL_PLAN_VERIFIED",
    ]
    lines = []
    for s, c in enumerate(plan.cpus):
        up = f"STL_CPU_{c.name.upper()}"
        lines.append(f"static const stl_consts_t cpu{s} = {up}_CONSTS_INIT;")
        lines.append(f"static const int cols{s}[] = {up}_COLUMNS;")
        macros += [
            f"cpu{s}.n_axes",
            f"cpu{s}.depth",
            f"cpu{s}.block_size",
            f"cpu{s}.low_watermark",
            f"cpu{s}.high_watermark",
            f"stl_check_consts(&cpu{s})",
        ]
        want += [
            len(c.axes),
            c.queue_depth,
            plan.bus.block_size,
            c.low_watermark,
            c.high_watermark,
            0,
        ]
        macros += [f"cols{s}[{j}]" for j in range(len(c.axes))]
        want += [plan.axis_names.index(a) for a in c.axes]
    for name, ctl in zip(plan.axis_names, plan.controllers, strict=True):
        up = f"STL_AXIS_{name.upper()}"
        d = ctl.to_dict()
        macros += [
            f"{up}_KP_Q",
            f"{up}_KP_F",
            f"{up}_KIT_Q",
            f"{up}_KIT_F",
            f"{up}_LOCK_Q",
            f"{up}_LOCK_F",
            f"{up}_FE_LIMIT",
            f"{up}_CPU",
        ]
        want += [
            d["task"]["kp"]["q"],
            d["task"]["kp"]["f"],
            d["task"]["ki_t"]["q"],
            d["task"]["ki_t"]["f"],
            d["lock_gain"]["q"],
            d["lock_gain"]["f"],
            d["following_error_limit_counts"],
            [c.name for c in plan.cpus].index(plan.cpu_of(name).name),
        ]
    harness = "\n".join(
        [
            '#include "servotune_link_plan.h"',
            *lines,
            "long long h_value(int i)",
            "{",
            "    const long long v[] = {" + ", ".join(f"(long long)({m})" for m in macros) + "};",
            "    return v[i];",
            "}",
            "",
        ]
    )
    (tmp_path / "plan_harness.c").write_text(harness)
    cc(
        tmp_path,
        *STRICT,
        "-O2",
        "-shared",
        "-fPIC",
        "plan_harness.c",
        "servotune_link.c",
        "-o",
        "libplan.so",
    )
    lib = ctypes.CDLL(str(tmp_path / "libplan.so"))
    lib.h_value.restype = ctypes.c_longlong
    lib.h_value.argtypes = [ctypes.c_int]
    got = [lib.h_value(i) for i in range(len(macros))]
    assert got == want, [m for m, g, w in zip(macros, got, want, strict=True) if g != w]
