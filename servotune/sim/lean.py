"""The lean kernel: one axis, metrics only, the integer runtime (candidate sweeps).

It composes the same tick steps as :mod:`servotune.sim.kernel` (:mod:`servotune.sim.tick`),
with the same float operations in the same order, so its metrics equal the general kernel's bit
for bit (``tests/sim/test_engine.py``); only the plumbing differs, for speed.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from servotune._numba_cache import jit
from servotune.laws.axis import MODE_TASK, N_STATE, S_MODE, axis_control, axis_read
from servotune.plant import NROW, R_NOISE, R_OFFSET, advance_tick_modal
from servotune.resonance import MAX_MODES
from servotune.sim.kernel import I_INIT, I_LAG
from servotune.sim.tick import N_METRICS, accumulate, draw_noise, finish, latch, sensed

__all__ = ["CONSTS_CAPACITY"]

_NQ = 2 * MAX_MODES  # a plant's modes' state (servotune.resonance)

CONSTS_CAPACITY = 4096
"""Largest constants vector (int64 words: the law's constants and its tables) the lean kernel
holds in its frame; fuzzy-PID tables up to n = 15 levels fit. Wider ones run in the general
kernel (same results)."""

# --- the lean kernel: one axis, metrics only, integer runtime ------------------------------
#
# Sweeps of many candidates of a one-axis loop for metrics only run here rather than in
# _run_group. It calls the same law and plant functions (axis_read, axis_control,
# advance_tick) and the same counter and metric helpers, with the same float operations in the
# same order, so its metrics equal _run_group's bit for bit (tests/sim/test_engine.py checks it);
# only the plumbing differs, each choice for speed (about 2x over _run_group here):
# - one candidate per loop, its law state and metric sums in small arrays in the function's
#   frame (frame_buffer viewed by numba.carray), indexed by constants, which LLVM promotes to
#   registers; _run_group's heap arrays are
#   stored and reloaded every tick, as LLVM cannot prove they do not alias the other arrays.
#   Interleaving two candidates per loop, as _run_group does, gained nothing here (measured):
#   this loop is bound by instruction throughput, not by the latency of one candidate's tick
#   chain, and two candidates' state overflows the registers (paired timings: 4-8 % slower).
#   Neither did a volts table or packing the per-tick inputs (within +-3 %). What did help a
#   little: 1-D input columns with an unsigned tick index (+4 %), and the common tick (task
#   mode, no reset, no excitation) called with those inputs as constants (+5 %);
# - no reference counting on the state: the frame arrays have no memory info, so passing them
#   to the inlined law functions leaves no NRT_incref/NRT_decref calls in the tick loop (heap
#   arrays there cost about 2x: every such call spills the floating-point registers);
# - no trace, ideal-law or slave-reference branches, and no ring buffer: a lag of 0 or 1 whole
#   ticks needs only the last two writes, kept in scalars;
# - threads take candidates one at a time (numba's dynamic scheduling, chunk size 1), so a
#   thread slowed by other work on its core does not hold up the batch.


@intrinsic
def frame_buffer(typingctx, n, dtype):
    """A zeroed buffer of ``n`` elements of ``dtype`` in the calling function's frame.

    Returns a pointer for :func:`numba.carray`, which views it as an array without a memory
    info: no reference counting, and LLVM may keep its elements in registers. Built from numba's
    documented extension API (``@intrinsic``) and llvmlite's IR builder (an ``alloca`` in the
    entry block). The buffer lives as long as the calling function's frame: call this only from
    a function that is never inlined into another, and never return the array or store it
    where it outlives that call.
    """
    if not (isinstance(n, types.IntegerLiteral) and isinstance(dtype, types.DTypeSpec)):
        return None
    count = n.literal_value
    el = dtype.dtype

    def codegen(context, builder, sig, args):
        ll_el = context.get_value_type(el)
        buf_ty = ir.ArrayType(ll_el, count)
        with builder.goto_entry_block():
            buf = builder.alloca(buf_ty)
        builder.store(ir.Constant(buf_ty, None), buf)
        return builder.bitcast(buf, ll_el.as_pointer())

    return types.CPointer(el)(n, dtype), codegen


@jit
def _run_lean(
    b,
    pf,
    pi,
    consts,
    seeds,
    ref,
    mode,
    reset,
    u_add,
    load,
    bits,
    latched,
    skew,
    dac_lo,
    lsb,
    m_from,
    period,
    metrics,
):
    """Run candidate ``b`` of a one-axis batch and write its metrics (as in :func:`kernel_lean`).

    Needs whole ticks of lag 0 or 1 (``Batch.ring <= 3``); integer runtime, no traces. The
    per-tick inputs ``ref`` … ``load`` are the axis's 1-D columns (contiguous: plain indexing).
    """
    nt = ref.shape[0]
    mask = (np.int64(1) << bits) - 1
    nbytes = bits // 8
    st = nb.carray(frame_buffer(N_STATE, np.int64), (1, N_STATE))
    mt = nb.carray(frame_buffer(N_METRICS, np.float64), (1, N_METRICS))
    mt[0, 4] = -1.0
    # the candidate's constants and plant row copied into the frame too: a view of the shared
    # arrays would be reference-counted on every pass into the law functions, and the threads'
    # atomic counts on the one memory info contend (measured: 2 threads no faster than 1)
    cb = nb.carray(frame_buffer(CONSTS_CAPACITY, np.int64), (1, CONSTS_CAPACITY))
    for j in range(consts.shape[2]):
        cb[0, j] = consts[b, 0, j]
    row = nb.carray(frame_buffer(NROW, np.float64), NROW)
    for j in range(NROW):
        row[j] = pf[b, 0, j]
    noise = row[R_NOISE]
    offset = row[R_OFFSET]
    init = pi[b, 0, I_INIT]
    lag = pi[b, 0, I_LAG]
    rng = seeds[b]
    pos = 0.0
    spd = 0.0
    q = nb.carray(frame_buffer(_NQ, np.float64), _NQ)  # a resonant plant's modes
    v1 = 0.0  # volts written one tick ago
    v2 = 0.0  # and two ticks ago
    for k in range(nt):
        i = np.uint64(k)  # an unsigned index: no negative-index wraparound code per access
        rng, nz = draw_noise(rng, noise)
        p_s, v_s = sensed(pos, spd, q, row)
        raw = latch(p_s, v_s, nz, init, mask, latched, nbytes, skew)
        rs = reset[i]
        md = mode[i]
        ua = u_add[i]
        if not rs and md == MODE_TASK and ua == 0:
            # the common tick, with these inputs as constants: the same calls with the same
            # values, which LLVM folds (no reset, lock or excitation paths); ~5 % faster
            axis_read(st, cb, 0, raw, False)
            code, flags, e = axis_control(st, cb, 0, ref[i], MODE_TASK, False, 0)
        else:
            axis_read(st, cb, 0, raw, rs)
            code, flags, e = axis_control(st, cb, 0, ref[i], md, rs, ua)
        volts = dac_lo + code * lsb
        accumulate(mt, 0, k, e, flags, st[0, S_MODE], m_from, period)
        # the writes of ticks k - lag (from λ on) and k - lag - 1 (before λ); 0 V before tick 0
        if lag == 0:
            v_new = volts
            v_old = v1
        else:
            v_new = v1
            v_old = v2
        v2 = v1
        v1 = volts
        w_off = offset + load[i]
        pos, spd = advance_tick_modal(pos, spd, q, v_old + w_off, v_new + w_off, row)
    finish(mt, 0, metrics, b, 0)


@jit(parallel=True)
def kernel_lean(
    pf,
    pi,
    consts,
    seeds,
    ref,
    mode,
    reset,
    u_add,
    load,
    bits,
    latched,
    skew,
    dac_lo,
    lsb,
    m_from,
    period,
    metrics,
):
    """Every candidate of a one-axis batch through :func:`_run_lean`, in parallel.

    Called with numba's parallel chunk size 1 (:func:`_run_lean_batch`), threads take
    candidates one at a time as they become free (dynamic scheduling): split evenly in advance,
    a run on a shared machine would wait for the thread whose core is busiest. Each candidate
    writes only its own metrics row, so which thread runs it changes no result.
    """
    for b in nb.prange(pf.shape[0]):
        _run_lean(
            b,
            pf,
            pi,
            consts,
            seeds,
            ref,
            mode,
            reset,
            u_add,
            load,
            bits,
            latched,
            skew,
            dac_lo,
            lsb,
            m_from,
            period,
            metrics,
        )
