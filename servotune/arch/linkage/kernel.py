"""The compiled linkage kernel: events in master time, each slave CPU's axis tick tick-relative.

The kernel schedules (which CPU ticks when, syncs, block arrivals, measurements) and routes
(each axis's reference from its CPU's queue); the axis tick itself is composed from
:mod:`servotune.sim.tick` (noise, latch and read, law and D/A, hold, advance), on a plant row
built for the CPU's nominal tick (:func:`servotune.plant.plant_row`). Timing model and sync
semantics: :mod:`servotune.arch.linkage`. On request it also logs each CPU's queue events in
order (blocks, syncs, ticks and what the queue did at each: ``_E_*`` columns), which the
exported C queue (``servotune_link.c``) replays bit for bit.

Plumbing for speed, the same operations in the same order (bit for bit the same results):

- the arrays the inlined tick functions are passed per axis (law states and constants, plant
  rows, rings) are used through views without a memory info (:func:`_unmanaged`), so their
  rows and slices are not reference-counted: each NRT_incref/NRT_decref call in the loop is
  an atomic operation and spills the floating-point registers (about 13 % of the kernel);
- the ring slot of each axis's tick is counted, not taken modulo the ring length;
- a CPU tick draws its axes' encoder noise first, in the stream's order (by axis), so that
  the draws overlap.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from numba import types
from numba.extending import intrinsic

from servotune._numba_cache import jit
from servotune.laws.axis import (
    FLAG_COUNTER_FAULT,
    FLAG_FOLLOWING_ERROR,
    FLAG_SATURATED,
    MODE_TASK,
    N_STATE,
)
from servotune.plant import R_H1, R_NOISE, R_OFFSET, advance_span
from servotune.sim.tick import advance_axis, draw_noise, held, hold, read_axis, write_axis

__all__ = [
    "A_FLAGS",
    "A_SAT",
    "A_T_FAULT",
    "I_INIT",
    "I_LAG",
    "I_RING",
    "NA",
    "NE",
    "NI",
    "NS",
    "NT",
    "NTF",
    "S_MAX",
    "S_MIN",
    "S_OVER",
    "S_RESYNC",
    "S_SKIP",
    "S_TICKS",
    "S_T_OVER",
    "S_T_UNDER",
    "S_UNDER",
    "T_CODE",
    "T_POS",
    "T_REF",
    "T_SPD",
    "T_Y",
    "linkage_kernel",
]

# The layouts of the kernel's arrays, shared with run.py (which packs the integer parameters
# and reads the statistics and traces by them): row and column indices and their counts, plain
# module-level ints, which numba compiles in as constants.
# per-CPU statistics
S_UNDER, S_T_UNDER, S_OVER, S_T_OVER, S_SKIP, S_MIN, S_MAX, S_TICKS, S_RESYNC = range(9)
NS = 9
# per-axis statistics
A_FLAGS, A_T_FAULT, A_SAT = 0, 1, 2
NA = 3
# per-axis integer parameters: whole CPU ticks of lag, ring length (lag + 2), counter at start
I_LAG, I_RING, I_INIT = 0, 1, 2
NI = 3
# per-tick trace rows: integer (reference, D/A code, unwrapped position) and float (plant
# position and speed at the tick)
T_REF, T_CODE, T_Y = 0, 1, 2
NT = 3
T_POS, T_SPD = 0, 1
NTF = 2
# per-CPU queue event log (run_linkage(trace=True); result.EVENT_COLUMNS names the columns):
# the kind, its argument (sync: the master's tick index; tick: the command index executed;
# block: the block index), the queue level before and after, a count (sync: commands discarded;
# tick: 1 on an underrun; block: setpoints lost to a full queue), the setpoints of a block that
# came too late (sync: the CPU's next index before the sync) and the CPU's next index after
_EV_SYNC, _EV_TICK, _EV_BLOCK = 0, 1, 2
_E_KIND, _E_ARG, _E_BEFORE, _E_AFTER, _E_COUNT, _E_LATE, _E_NEXT = range(7)
NE = 7


@intrinsic
def _pointer(typingctx, address, dtype):
    """``address`` (an array's ``ctypes.data``) as a pointer to ``dtype``, for :func:`numba.carray`.

    Built from numba's documented extension API (``@intrinsic``) and llvmlite's IR builder.
    """
    if not (isinstance(address, types.Integer) and isinstance(dtype, types.DTypeSpec)):
        return None
    el = dtype.dtype

    def codegen(context, builder, sig, args):
        return builder.inttoptr(args[0], context.get_value_type(el).as_pointer())

    return types.CPointer(el)(address, dtype), codegen


@jit(inline="always")
def _unmanaged(arr):
    """``arr``'s memory (C-contiguous) as an array without a memory info: its rows and slices
    are not reference-counted. Only for an array that outlives every use of the result (an
    argument of the calling function: its caller holds it)."""
    if not arr.flags.c_contiguous:
        raise ValueError("_unmanaged needs a C-contiguous array")
    return nb.carray(_pointer(arr.ctypes.data, arr.dtype), arr.shape)


@jit(inline="always")
def _tick_time(anchor_s, ticks, period, eps):
    """Master time [s] of a CPU's tick ``ticks`` after its sync anchor: ``T/(1 + ε)`` apart."""
    return anchor_s + ticks * period / (1.0 + eps)


@jit(inline="always")
def _measure(p, v, ring, slot, c_last, m, h, w_off, row):
    """An axis's position ``h`` [s] after its CPU's tick ``c_last`` (in ``slot`` of its ring),
    from its state there.

    The writes held over that tick (:func:`~servotune.sim.tick.held`) act as in
    :func:`~servotune.sim.tick.advance_axis`; the state itself is not changed (a copy moves).
    """
    if h == 0.0:  # at the tick itself (what advance_span gives for h = 0, without its exp)
        return p
    v_old, v_new = held(ring, slot, m, c_last)
    p_h, _ = advance_span(p, v, v_old + w_off, v_new + w_off, row[R_H1], h, row)
    return p_h


@jit(inline="always")
def _log(ev, n_ev, s, kind, arg, before, after, count, late, nxt):
    """Append one event to CPU ``s``'s log (``_E_*`` columns) if it has room; count it anyway."""
    i = n_ev[s]
    if i < ev.shape[1]:
        ev[s, i, _E_KIND] = kind
        ev[s, i, _E_ARG] = arg
        ev[s, i, _E_BEFORE] = before
        ev[s, i, _E_AFTER] = after
        ev[s, i, _E_COUNT] = count
        ev[s, i, _E_LATE] = late
        ev[s, i, _E_NEXT] = nxt
    n_ev[s] = i + 1


@jit
def linkage_kernel(
    n_ticks,
    period,
    cmd,
    ax_cpu,
    rows,
    ints,
    consts,
    seed,
    cpu_eps,
    cpu_depth,
    block,
    prefill,
    frame_s,
    resync_ticks,
    bits,
    latched,
    skew,
    dac_lo,
    lsb,
    actual,
    q_time,
    q_level,
    q_index,
    cpu_stats,
    ax_stats,
    tr_i,
    tr_f,
    ev,
    n_ev,
):
    """Run the linkage for ``n_ticks`` master ticks (arguments: :func:`run_linkage`'s plumbing).

    ``rows[a]`` is axis ``a``'s plant row for its CPU's nominal tick ``period / (1 + ε)``,
    ``ints[a]`` its ``I_*`` integers. Outputs: ``actual`` (positions at the master ticks),
    the per-CPU queue records ``q_*``, the statistics, and, if ``tr_i``/``tr_f`` have rows,
    the per-axis trace of each CPU tick (``T_*`` rows); if ``ev`` has rows, each CPU's queue
    events in order (``_E_*`` columns; ``n_ev[s]``: how many there were, logged or not).
    """
    # the axis states at their CPU's last tick and the tick-slot rings of their writes,
    # allocated here so that they outlive _events, which uses them (like the plant rows and law
    # constants) without reference counting
    n_ax = cmd.shape[1]
    st = np.zeros((n_ax, N_STATE), dtype=np.int64)
    width = 2
    for a in range(n_ax):
        width = max(width, ints[a, I_RING])
    hist = np.zeros((n_ax, width))
    _events(
        n_ticks,
        period,
        cmd,
        ax_cpu,
        rows,
        ints,
        consts,
        seed,
        cpu_eps,
        cpu_depth,
        block,
        prefill,
        frame_s,
        resync_ticks,
        bits,
        latched,
        skew,
        dac_lo,
        lsb,
        actual,
        q_time,
        q_level,
        q_index,
        cpu_stats,
        ax_stats,
        tr_i,
        tr_f,
        ev,
        n_ev,
        st,
        hist,
    )


@jit
def _events(
    n_ticks,
    period,
    cmd,
    ax_cpu,
    rows,
    ints,
    consts,
    seed,
    cpu_eps,
    cpu_depth,
    block,
    prefill,
    frame_s,
    resync_ticks,
    bits,
    latched,
    skew,
    dac_lo,
    lsb,
    actual,
    q_time,
    q_level,
    q_index,
    cpu_stats,
    ax_stats,
    tr_i,
    tr_f,
    ev,
    n_ev,
    st,
    hist,
):
    """:func:`linkage_kernel`'s event loop, given the zeroed axis states ``st`` and rings ``hist``.

    The arrays the axis tick is passed (law states and constants, plant rows, rings) are used
    through :func:`_unmanaged` views: the caller keeps them alive.
    """
    n_ax = cmd.shape[1]
    n_cmd = cmd.shape[0]
    n_cpu = cpu_eps.shape[0]
    n_rec = q_time.shape[1]
    n_tr = tr_f.shape[1]
    mask = (np.int64(1) << bits) - 1
    nbytes = bits // 8
    t_end = n_ticks * period
    rng = seed
    st = _unmanaged(st)
    hist = _unmanaged(hist)
    rows = _unmanaged(rows)
    consts = _unmanaged(consts)
    pos = np.zeros(n_ax)
    spd = np.zeros(n_ax)
    qs = np.zeros((n_ax, 2))  # modes' states: the linkage runs rigid plants (run_linkage)
    nz = np.zeros(n_ax)  # encoder noise of the reads of a CPU tick
    # each ring's slot of its CPU's last tick (k mod ring length, kept without a division)
    slot = np.zeros(n_ax, dtype=np.int64)
    last_ref = np.zeros(n_ax, dtype=np.int64)
    for a in range(n_ax):
        slot[a] = ints[a, I_RING] - 1
        last_ref[a] = cmd[0, a]
        ax_stats[a, A_T_FAULT] = -1.0
    # queues
    present = np.zeros((n_cpu, n_cmd), dtype=np.bool_)
    level = np.zeros(n_cpu, dtype=np.int64)
    head = np.zeros(n_cpu, dtype=np.int64)
    n_pre = min(prefill * block, n_cmd)
    for s in range(n_cpu):
        for i in range(n_pre):
            present[s, i] = True
        level[s] = n_pre
        cpu_stats[s, S_T_UNDER] = -1.0
        cpu_stats[s, S_T_OVER] = -1.0
        cpu_stats[s, S_MIN] = 1e18
        cpu_stats[s, S_MAX] = n_pre
        # the log: the prefill blocks, then the sync at motion start (master tick 0)
        for b in range(prefill):
            lo, hi = min(b * block, n_pre), min((b + 1) * block, n_pre)
            _log(ev, n_ev, s, _EV_BLOCK, b, lo, hi, 0, 0, 0)
        _log(ev, n_ev, s, _EV_SYNC, 0, n_pre, n_pre, 0, 0, 0)
    # clocks: next index, the anchor (index, time) of the last sync and the time of the next
    # tick they give; each CPU's own tick count, the time of its last tick, and whether a sync
    # moved its schedule since that tick
    next_j = np.zeros(n_cpu, dtype=np.int64)
    anc_k = np.zeros(n_cpu, dtype=np.int64)
    anc_t = np.zeros(n_cpu)
    t_next = np.zeros(n_cpu)
    n_tick = np.zeros(n_cpu, dtype=np.int64)
    t_last = np.zeros(n_cpu)
    stretched = np.zeros(n_cpu, dtype=np.bool_)
    n_blocks = (n_cmd + block - 1) // block
    nb_next = prefill
    r_next = 1
    k_next = 0
    while True:
        t_best = np.inf
        kind = -1
        which = -1
        if resync_ticks > 0:
            tr = r_next * resync_ticks * period
            if tr < t_best:
                t_best, kind = tr, 0
        for s in range(n_cpu):
            if t_next[s] < t_best:
                t_best, kind, which = t_next[s], 1, s
        if k_next < n_ticks:
            tk = k_next * period
            if tk < t_best:
                t_best, kind = tk, 2
        if nb_next < n_blocks:
            ta = (nb_next - prefill) * block * period + frame_s
            if ta < t_best:
                t_best, kind = ta, 3
        if kind < 0 or t_best >= t_end:
            break
        t = t_best
        if kind == 0:  # clock sync broadcast
            k_r = r_next * resync_ticks
            for s in range(n_cpu):
                j = next_j[s]
                lvl = level[s]
                if j < k_r:  # behind: the commands up to k_r - 1 are consumed and dropped
                    for i in range(max(j, head[s]), min(k_r, n_cmd)):
                        if present[s, i]:
                            present[s, i] = False
                            level[s] -= 1
                            cpu_stats[s, S_SKIP] += 1.0
                    head[s] = max(head[s], k_r)
                    next_j[s] = k_r
                _log(ev, n_ev, s, _EV_SYNC, k_r, lvl, level[s], lvl - level[s], j, next_j[s])
                anc_k[s] = k_r
                anc_t[s] = t
                t_next[s] = _tick_time(anc_t[s], next_j[s] - anc_k[s], period, cpu_eps[s])
                stretched[s] = True
                cpu_stats[s, S_RESYNC] += 1.0
            r_next += 1
        elif kind == 1:  # a slave tick: pop the command, then every axis of the CPU ticks
            s = which
            j = next_j[s]
            lvl = level[s]
            if lvl < cpu_stats[s, S_MIN]:
                cpu_stats[s, S_MIN] = lvl
            c = n_tick[s]
            if c < n_rec:
                q_time[s, c] = t
                q_level[s, c] = lvl
                q_index[s, c] = j
            ok = j < n_cmd and present[s, j]
            if ok:
                present[s, j] = False
                level[s] -= 1
            else:
                cpu_stats[s, S_UNDER] += 1.0
                if cpu_stats[s, S_T_UNDER] < 0.0:
                    cpu_stats[s, S_T_UNDER] = t
            head[s] = j + 1
            next_j[s] = j + 1
            _log(ev, n_ev, s, _EV_TICK, j, lvl, level[s], 0 if ok else 1, 0, j + 1)
            t_next[s] = _tick_time(anc_t[s], next_j[s] - anc_k[s], period, cpu_eps[s])
            h = t - t_last[s]
            regular = not stretched[s]
            # 1. the encoder noise of the CPU's reads, drawn first (in the stream's order: by axis)
            for a in range(n_ax):
                if ax_cpu[a] == s:
                    rng, nz[a] = draw_noise(rng, rows[a, R_NOISE])
            for a in range(n_ax):
                if ax_cpu[a] != s:
                    continue
                row = rows[a]
                m = ints[a, I_LAG]
                ring = hist[a, : ints[a, I_RING]]
                w_off = row[R_OFFSET]
                prev = slot[a]
                now = prev + 1 if prev + 1 < ring.shape[0] else 0
                # 5. the motor over the CPU's previous tick: one regular tick on the row, else
                # the interval a sync made (the same held writes, switching at λ)
                if c > 0:
                    if regular:
                        pos[a], spd[a] = advance_axis(
                            pos[a], spd[a], qs[a], ring, prev, m, c - 1, w_off, row
                        )
                    else:
                        v_old, v_new = held(ring, prev, m, c - 1)
                        pos[a], spd[a] = advance_span(
                            pos[a], spd[a], v_old + w_off, v_new + w_off, row[R_H1], h, row
                        )
                # 1-2. sample and read
                _raw, y = read_axis(
                    st,
                    consts,
                    a,
                    pos[a],
                    spd[a],
                    nz[a],
                    ints[a, I_INIT],
                    mask,
                    latched,
                    nbytes,
                    skew,
                    False,
                )
                # 3-4. the law on the popped command (the previous one on an underrun), D/A, hold
                ref = cmd[j, a] if ok else last_ref[a]
                last_ref[a] = ref
                code, flags, _e, volts = write_axis(
                    st, consts, a, ref, MODE_TASK, False, 0, dac_lo, lsb
                )
                hold(ring, now, volts)
                slot[a] = now
                if flags & FLAG_SATURATED:
                    ax_stats[a, A_SAT] += 1.0
                fault = flags & (FLAG_COUNTER_FAULT | FLAG_FOLLOWING_ERROR)
                if fault and ax_stats[a, A_T_FAULT] < 0.0:
                    ax_stats[a, A_T_FAULT] = t
                ax_stats[a, A_FLAGS] = float(int(ax_stats[a, A_FLAGS]) | fault)
                if c < n_tr:
                    tr_i[T_REF, c, a] = ref
                    tr_i[T_CODE, c, a] = code
                    tr_i[T_Y, c, a] = y
                    tr_f[T_POS, c, a] = pos[a]
                    tr_f[T_SPD, c, a] = spd[a]
            n_tick[s] = c + 1
            t_last[s] = t
            stretched[s] = False
        elif kind == 2:  # measurement at the master tick: a copy of each axis moves to t
            for a in range(n_ax):
                s = ax_cpu[a]
                c_last = n_tick[s] - 1
                if c_last < 0:
                    actual[k_next, a] = pos[a]
                    continue
                row = rows[a]
                actual[k_next, a] = _measure(
                    pos[a],
                    spd[a],
                    hist[a, : ints[a, I_RING]],
                    slot[a],
                    c_last,
                    ints[a, I_LAG],
                    t - t_last[s],
                    row[R_OFFSET],
                    row,
                )
            k_next += 1
        else:  # block nb_next has arrived
            i0 = nb_next * block
            i1 = min(i0 + block, n_cmd)
            for s in range(n_cpu):
                dropped = False
                lvl = level[s]
                n_late = 0
                n_lost = 0
                for i in range(i0, i1):
                    if i < head[s]:
                        n_late += 1
                        continue  # too late: its tick has passed (counted as an underrun)
                    if level[s] < cpu_depth[s]:
                        present[s, i] = True
                        level[s] += 1
                    else:
                        dropped = True
                        n_lost += 1
                _log(ev, n_ev, s, _EV_BLOCK, nb_next, lvl, level[s], n_lost, n_late, next_j[s])
                if dropped:
                    cpu_stats[s, S_OVER] += 1.0
                    if cpu_stats[s, S_T_OVER] < 0.0:
                        cpu_stats[s, S_T_OVER] = t
                if level[s] > cpu_stats[s, S_MAX]:
                    cpu_stats[s, S_MAX] = level[s]
            nb_next += 1
    for s in range(n_cpu):
        cpu_stats[s, S_TICKS] = n_tick[s]
