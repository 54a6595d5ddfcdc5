"""The lean two-axis kernel: a master and an axis following it, verification figures only.

A Monte-Carlo verification runs a million plant sets of a two-axis rig (master, slave reading
the master's position as its reference) through a move, or holds both axes (the position-lock
module against their drift), and needs per plant set only a few figures: each axis's overshoot
and settling time of the move (MATLAB ``stepinfo`` read at the samples,
:func:`servotune.metrics.step_info`), its share of saturated ticks, whether it latched a fault,
the sync error's peak, RMS and mean over a steady window, the holding band of a hold, and the
fastest motion. This kernel computes exactly those, tick by tick, without traces: it composes the
shared tick (:mod:`servotune.sim.tick`: sample, read, law and D/A, advance) in the order of the
general kernel (:mod:`servotune.sim.kernel`), with the same float operations, so every figure
equals the one computed from the general kernel's traces bit for bit
(``tests/sim/test_lean_sync.py``). The plumbing is the lean one-axis kernel's
(:mod:`servotune.sim.lean`): one plant set per loop, its state in the function's frame, lags of
at most one whole tick held in scalars, threads taking plant sets one at a time.

Sums are numpy's: the mean of the squared sync error and of the steady window are summed as
``numpy.add.reduce`` sums one contiguous row (pairwise, :func:`pairwise_sum`), so the RMS and
the mean are the bits ``numpy.mean`` gives on the traces.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from servotune._numba_cache import call_compiled, jit
from servotune.errors import SimulationError
from servotune.laws.axis import FAULT_MASK, FLAG_SATURATED, MODE_TASK, N_STATE, axis_read
from servotune.plant import NROW, R_MODES, R_NOISE, R_OFFSET, advance_tick_inlined
from servotune.sim.kernel import I_INIT, I_LAG
from servotune.sim.lean import CONSTS_CAPACITY, frame_buffer
from servotune.sim.tick import draw_noise, draw_uniforms, latch, write_axis

__all__ = [
    "FIGURE_NAMES",
    "N_FIGURES",
    "SyncWindows",
    "pairwise_sum",
    "run_sync_figures",
]

FIGURE_NAMES = (
    "overshoot_pct",
    "settling_time_s",
    "saturation_pct",
    "fault",
    "max_sync_error_counts",
    "rms_sync_error_counts",
    "steady_lag_counts",
    "holding_band_counts",
)
"""Per plant set and axis (``figures[b, a, j]``): overshoot [%] and settling time [s] of the
move (``inf`` if still outside the band at the last tick), saturated share of the counted ticks
[%], 1.0 if a fault latched, and for a following axis its sync error against the master
[counts]: peak and RMS over its counted ticks, mean over the steady window (0 for the master);
the holding band over the holding window (:attr:`SyncWindows.hold_from`; 0 without one)
[counts]: the largest ``|target − plant count|``, the target being the runtime's (its read plus
its error) and the plant count the plant's whole count in the runtime's frame (``floor`` of the
true position less the count of the first read), NaN where a position in the window is not
finite or beyond ±4e18 counts (near int64's end, where the traced path's integer cast is not
defined, so the caller runs that path instead).
The overshoot is NaN where :func:`servotune.metrics.step_info` refuses the move as a step
response (a position in the window not finite, a step ``target − y0`` zero or not finite): the
traced path raises its ``ValueError`` there, so the caller runs that path instead."""
N_FIGURES = len(FIGURE_NAMES)
_F_OVER, _F_SETTLE, _F_SAT, _F_FAULT, _F_SYNC_MAX, _F_SYNC_RMS, _F_STEADY, _F_HOLD = range(
    N_FIGURES
)
_HOLD_SPAN = 4.0e18  # [counts] |position| a holding figure takes (int64 holds ±9.2e18)
N_FAST = 6
"""Per plant set: the largest motion in one tick [counts], its tick and axis; the largest
speed [counts/s], its tick and axis (the first in (tick, axis) order; -1 if never > 0)."""
_PW_BLOCK = 128  # numpy's PW_BLOCKSIZE
_ST_WORDS = 2 * N_STATE  # frame buffers (literal sizes): both axes' law state, plant rows
_ROW_WORDS = 2 * NROW


@jit(inline="always")
def _pairwise_block(a: np.ndarray, lo: int, n: int) -> float:
    """numpy's pairwise sum of ``n <= 128`` elements: a plain loop below 8, else eight partial
    sums combined as a tree, then the rest."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    end = n - n % 8
    while i < end:
        j = lo + i
        r0 += a[j]
        r1 += a[j + 1]
        r2 += a[j + 2]
        r3 += a[j + 3]
        r4 += a[j + 4]
        r5 += a[j + 5]
        r6 += a[j + 6]
        r7 += a[j + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@jit
def pairwise_sum(a: np.ndarray, lo: int, n: int) -> float:
    """``a[lo : lo + n]`` summed as numpy sums a contiguous float64 row (``numpy.add.reduce``:
    pairwise, blocks of 128 in eight partial sums; ``numpy/_core/src/umath/loops_utils.h.src``,
    ``pairwise_sum``), so the result has numpy's bits.

    numpy's recursion (halves rounded down to a multiple of 8, left sum + right sum) runs on an
    explicit stack: numba's on-disk cache cannot load a self-recursive function.
    """
    if n <= _PW_BLOCK:
        return _pairwise_block(a, lo, n)
    los = np.empty(64, dtype=np.int64)
    ns = np.empty(64, dtype=np.int64)
    phase = np.zeros(64, dtype=np.int64)
    vals = np.empty(64)
    sp = 0
    vsp = 0
    los[0] = lo
    ns[0] = n
    while sp >= 0:
        m = ns[sp]
        if m <= _PW_BLOCK:
            vals[vsp] = _pairwise_block(a, los[sp], m)
            vsp += 1
            sp -= 1
            continue
        n2 = m // 2
        n2 -= n2 % 8
        if phase[sp] == 0:  # the left half first
            phase[sp] = 1
            los[sp + 1], ns[sp + 1], phase[sp + 1] = los[sp], n2, 0
            sp += 1
        elif phase[sp] == 1:  # then the right half
            phase[sp] = 2
            los[sp + 1], ns[sp + 1], phase[sp + 1] = los[sp] + n2, m - n2, 0
            sp += 1
        else:  # left + right
            vsp -= 1
            vals[vsp - 1] = vals[vsp - 1] + vals[vsp]
            sp -= 1
    return vals[0]


# --- encoder noise read through a bounded approximation ---------------------------------------
# A sample needs only floor(q + noise) (q: the position the counter sees, servotune.sim.tick.latch).
# The normal draw is the stream's (splitmix64, Box-Muller: servotune.sim.tick.normal); instead of
# libm's log and cos it is first evaluated by polynomials whose error is far below _NZ_MARGIN
# (atanh series of log about 1.5: truncation < 3e-16 where -2 ln u1 cancels to ~1e-16, whose
# square root then errs by < 3e-8; cos Taylor on [-pi/2, pi/2]: < 7e-11; |g_approx - g| is
# measured < 2e-8 over 2e7 draws and the edges of u1 and u2).
# Where q + noise is farther than the margin from an integer the floor is the same whatever
# the last bits of the noise; otherwise (or if anything is not finite) the draw is evaluated
# exactly as servotune.sim.tick.normal does, so every read is the general kernel's bit for bit.
_NZ_MARGIN = 1e-5  # [counts] per (1 + sigma), plus 1e-15·|q| for the sum's rounding
_LN2 = 0.6931471805599453
_LN1_5 = 0.4054651081081644
_TWO_PI = 6.283185307179586
_TWO_GOLDEN = np.uint64(0x3C6EF372FE94F82A)  # 2 · 0x9E3779B97F4A7C15: the two outputs of a draw


@intrinsic
def _f64_bits(typingctx, x):
    """The IEEE bits of a float64 as an int64."""
    if not isinstance(x, types.Float) or x.bitwidth != 64:
        return None

    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.int64(x), codegen


@intrinsic
def _bits_f64(typingctx, x):
    """The float64 of IEEE bits held in an int64."""
    if not isinstance(x, types.Integer) or x.bitwidth != 64:
        return None

    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(x), codegen


@jit(inline="always")
def _approx_normal(u1: float, u2: float) -> float:
    """``sqrt(-2 ln u1) · cos(2 pi u2)`` to about 1e-8 (``0 < u1 < 1``, ``0 <= u2 < 1``)."""
    bits = _f64_bits(u1)
    e = ((bits >> 52) & 0x7FF) - 1023
    m = _bits_f64((bits & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000)  # [1, 2)
    f = (m - 1.5) / (m + 1.5)  # |f| <= 0.2
    f2 = f * f
    at = 1.0 / 15.0
    at = at * f2 + 1.0 / 13.0
    at = at * f2 + 1.0 / 11.0
    at = at * f2 + 1.0 / 9.0
    at = at * f2 + 1.0 / 7.0
    at = at * f2 + 1.0 / 5.0
    at = at * f2 + 1.0 / 3.0
    at = at * f2 + 1.0
    ln = (e * _LN2 + _LN1_5) + 2.0 * f * at
    s = math.sqrt(max(-2.0 * ln, 0.0))
    j = np.int64(u2 * 2.0 + 0.5)  # the nearest half turn: 0, 1, 2
    t2 = ((u2 - j * 0.5) * _TWO_PI) ** 2  # |t| <= pi/2; u2 - j/2 exact
    c = 1.0 / 20922789888000.0
    c = c * t2 - 1.0 / 87178291200.0
    c = c * t2 + 1.0 / 479001600.0
    c = c * t2 - 1.0 / 3628800.0
    c = c * t2 + 1.0 / 40320.0
    c = c * t2 - 1.0 / 720.0
    c = c * t2 + 1.0 / 24.0
    c = c * t2 - 0.5
    c = c * t2 + 1.0
    return s * ((1.0 - 2.0 * float(j & 1)) * c)


@jit(fastmath={"contract"}, error_model="numpy")
def _approx_draws(seed: np.uint64, n: int, out: np.ndarray) -> None:
    """The stream's first ``n`` normal draws approximated (:func:`_approx_normal`) into ``out``.

    Each draw's uniforms come straight from its place in the stream
    (:func:`servotune.sim.tick.draw_uniforms`), so the loop has no branch and no carried chain
    and the compiler runs several draws at a time in vector registers (numpy's error model: no
    division-by-zero check, whose branch would stop that; ``m + 1.5`` is never 0); fused
    multiply-adds are allowed (they change only the approximation's last bits).
    """
    for d in range(n):
        u1, u2 = draw_uniforms(seed, d)
        out[d] = _approx_normal(u1, u2)


@jit(inline="always")
def _noisy_floor(q: float, nz: float, margin: float) -> tuple[bool, np.int64]:
    """``floor(q + nz)`` and whether it holds for every noise within ``margin`` of ``nz``.

    The floor stays a float for the test (``math.floor`` gives an integer, whose conversion
    back would lengthen the tick's chain); beyond ±2**53, where the two could differ, and for
    a value not finite, the test fails and the caller takes the exact read."""
    x = q + nz
    fl = np.floor(x)
    m = margin + 1e-15 * abs(q)
    ok = ((x - fl) > m) & ((fl + 1.0 - x) > m)
    if ok:
        return True, np.int64(fl)
    return False, np.int64(0)


@jit(inline="always")
def _latch_noisy(rng, sigma, nz_a, p, v, init, mask, latched, nbytes, skew):
    """:func:`servotune.sim.tick.latch` of ``p`` plus the noise ``sigma`` times
    :func:`servotune.sim.tick.normal` drawn from ``rng`` (``sigma > 0``), ``nz_a`` that noise
    approximated (:func:`_approx_draws`): the floor taken on ``nz_a`` where it is safe."""
    margin = _NZ_MARGIN * (1.0 + sigma)
    if latched:
        ok, c0 = _noisy_floor(p, nz_a, margin)
        if ok:
            return (init + c0) & mask
    else:
        raw = np.int64(0)
        ok = True
        for j in range(nbytes):
            okj, cj = _noisy_floor(p + v * (j * skew), nz_a, margin)
            if not okj:
                ok = False
                break
            rj = (init + cj) & mask
            raw |= rj & (np.int64(0xFF) << (8 * j))
        if ok:
            return raw
    _, nz = draw_noise(rng, sigma)
    return latch(p, v, nz, init, mask, latched, nbytes, skew)


@jit
def _run_sync(
    b,
    pf,
    pi,
    consts,
    seeds,
    src,
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
    counted,
    step_from,
    target,
    threshold,
    has_step,
    master,
    follower,
    steady_lo,
    steady_hi,
    hold_from,
    period,
    figures,
    fast,
):
    """Run plant set ``b`` of a two-axis batch and write its figures (see :func:`_kernel_sync`)."""
    nt = ref.shape[0]
    mask = (np.int64(1) << bits) - 1
    nbytes = bits // 8
    width = consts.shape[1]
    st = nb.carray(frame_buffer(_ST_WORDS, np.int64), (2, N_STATE))
    # per axis: position, speed, the last two writes, the read
    pos = nb.carray(frame_buffer(2, np.float64), 2)
    spd = nb.carray(frame_buffer(2, np.float64), 2)
    v1 = nb.carray(frame_buffer(2, np.float64), 2)
    v2 = nb.carray(frame_buffer(2, np.float64), 2)
    y = nb.carray(frame_buffer(2, np.int64), 2)
    cb = nb.carray(frame_buffer(CONSTS_CAPACITY, np.int64), (2, width))
    for a in range(2):
        for j in range(width):
            cb[a, j] = consts[a, j]
    # per axis, the figures' running values: ticks counted, the fault, a refusal of step_info
    n_cnt = nb.carray(frame_buffer(2, np.int64), 2)
    fault = nb.carray(frame_buffer(2, np.int64), 2)
    refused = nb.carray(frame_buffer(2, np.int64), 2)  # step_info would raise (FIGURE_NAMES)
    rows = nb.carray(frame_buffer(_ROW_WORDS, np.float64), (2, NROW))
    for a in range(2):
        for j in range(NROW):
            rows[a, j] = pf[b, a, j]
    last_out = nb.carray(frame_buffer(2, np.int64), 2)
    for a in range(2):
        last_out[a] = -1
    # ... and the step's start, size, band, largest deviation, saturated ticks
    y0 = nb.carray(frame_buffer(2, np.float64), 2)
    size = nb.carray(frame_buffer(2, np.float64), 2)
    band = nb.carray(frame_buffer(2, np.float64), 2)
    dev_max = nb.carray(frame_buffer(2, np.float64), 2)
    n_sat = nb.carray(frame_buffer(2, np.int64), 2)
    # ... the first read's count (the runtime's frame), the holding window's largest
    # |target - plant count|, whether a position there was refused
    first = nb.carray(frame_buffer(2, np.int64), 2)
    hold_max = nb.carray(frame_buffer(2, np.int64), 2)
    hold_bad = nb.carray(frame_buffer(2, np.int64), 2)
    # the squared sync errors over the follower's counted ticks, then |e| over the steady window
    buf = np.empty(nt + max(steady_hi - steady_lo, 0))
    n_sq = 0
    n_st = 0
    sync_max = 0.0
    step_best = 0.0
    step_k = -1
    step_a = -1
    speed_best = 0.0
    speed_k = -1
    speed_a = -1
    # the noise draws approximated ahead, in stream order: tick by tick, axis 0 first, an axis
    # without noise drawing none (``per_tick`` draws a tick)
    per_tick = (1 if rows[0, R_NOISE] > 0.0 else 0) + (1 if rows[1, R_NOISE] > 0.0 else 0)
    nzb = np.empty(per_tick * nt)
    _approx_draws(seeds[b], per_tick * nt, nzb)
    rng = seeds[b]
    for k in range(nt):
        i = np.uint64(k)  # an unsigned index: no negative-index wraparound code
        # 1-2. sample and unwrap, every axis (noise drawn in axis order)
        for a in range(2):
            sigma = rows[a, R_NOISE]
            if sigma > 0.0:
                d = per_tick * k + (a if per_tick == 2 else 0)
                raw = _latch_noisy(
                    rng,
                    sigma,
                    nzb[d] * sigma,
                    pos[a],
                    spd[a],
                    pi[b, a, I_INIT],
                    mask,
                    latched,
                    nbytes,
                    skew,
                )
                rng += _TWO_GOLDEN  # the two splitmix64 steps of the draw
            else:
                raw = latch(pos[a], spd[a], 0.0, pi[b, a, I_INIT], mask, latched, nbytes, skew)
            if k == 0:  # the runtime's frame: its first read is count 0
                first[a] = (raw - pi[b, a, I_INIT]) & mask
                if first[a] >= np.int64(1) << (bits - 1):
                    first[a] -= np.int64(1) << bits
            if reset[i, a]:
                y[a] = axis_read(st, cb, a, raw, True)
            else:  # the common read, with the flag a constant (below)
                y[a] = axis_read(st, cb, a, raw, False)
        # the figures of the tick start's state (the traces' true position and speed)
        if counted[i, follower]:
            e = pos[master] - pos[follower]
            ae = abs(e)
            if ae > sync_max:
                sync_max = ae
            buf[n_sq] = e * e
            n_sq += 1
        if steady_lo <= k < steady_hi:
            buf[nt + n_st] = abs(pos[master] - pos[follower])
            n_st += 1
        for a in range(2):
            sp = abs(spd[a])
            if sp > speed_best:
                speed_best = sp
                speed_k = k
                speed_a = a
            if has_step[a] and k >= step_from:
                if k == step_from:
                    y0[a] = pos[a]
                    size[a] = abs(target - y0[a])
                    band[a] = threshold * size[a]
                    dev_max[a] = 0.0
                    st_size = target - y0[a]
                    if st_size == 0.0 or not math.isfinite(st_size):
                        refused[a] = 1
                if not math.isfinite(pos[a]):
                    refused[a] = 1
                dev = pos[a] - y0[a] if target - y0[a] > 0.0 else y0[a] - pos[a]
                if dev > dev_max[a]:
                    dev_max[a] = dev
                if abs(pos[a] - target) > band[a]:
                    last_out[a] = k - step_from
        # 3-4. control law and D/A, every axis
        for a in range(2):
            s = src[a]
            r = ref[i, a] if s < 0 else y[s]
            rs = reset[i, a]
            md = mode[i, a]
            ua = u_add[i, a]
            if not rs and md == MODE_TASK and ua == 0:
                # the common tick, its inputs as constants: the same call with the same values,
                # which LLVM folds (no reset, lock or excitation paths), as in sim.lean
                _, flags, e_a, volts = write_axis(st, cb, a, r, MODE_TASK, False, 0, dac_lo, lsb)
            else:
                _, flags, e_a, volts = write_axis(st, cb, a, r, md, rs, ua, dac_lo, lsb)
            fault[a] |= flags & FAULT_MASK
            if k >= hold_from:
                if abs(pos[a]) < _HOLD_SPAN:  # also False for NaN
                    dh = abs(y[a] + e_a - (np.int64(math.floor(pos[a])) - first[a]))
                    if dh > hold_max[a]:
                        hold_max[a] = dh
                else:
                    hold_bad[a] = 1
            if counted[i, a]:
                n_cnt[a] += 1
                if flags & FLAG_SATURATED:
                    n_sat[a] += 1
            # the writes of ticks k - lag and k - lag - 1 acting in this tick; 0 V before tick 0
            if pi[b, a, I_LAG] == 0:
                v_new = volts
                v_old = v1[a]
            else:
                v_new = v1[a]
                v_old = v2[a]
            v2[a] = v1[a]
            v1[a] = volts
            w_off = rows[a, R_OFFSET] + load[i, a]
            p_old = pos[a]
            pos[a], spd[a] = advance_tick_inlined(
                p_old, spd[a], v_old + w_off, v_new + w_off, rows[a]
            )
            if k + 1 < nt:
                step = abs(pos[a] - p_old)
                if step > step_best:
                    step_best = step
                    step_k = k
                    step_a = a
    n_win = nt - step_from
    for a in range(2):
        if has_step[a]:
            over = dev_max[a] - size[a]
            if not over > 0.0:
                over = 0.0
            figures[b, a, _F_OVER] = np.nan if refused[a] else 100.0 * over / size[a]
            if last_out[a] < 0:
                figures[b, a, _F_SETTLE] = 0.0
            elif last_out[a] == n_win - 1:
                figures[b, a, _F_SETTLE] = np.inf
            else:
                figures[b, a, _F_SETTLE] = float(last_out[a] + 1) * period
        if n_cnt[a] > 0:
            figures[b, a, _F_SAT] = 100.0 * (float(n_sat[a]) / n_cnt[a])
        figures[b, a, _F_FAULT] = 1.0 if fault[a] != 0 else 0.0
        if hold_from < nt:
            figures[b, a, _F_HOLD] = np.nan if hold_bad[a] else float(hold_max[a])
    if n_sq > 0:
        figures[b, follower, _F_SYNC_MAX] = sync_max
        figures[b, follower, _F_SYNC_RMS] = np.sqrt(pairwise_sum(buf, 0, n_sq) / n_sq)
    if n_st > 0:
        figures[b, follower, _F_STEADY] = pairwise_sum(buf, nt, n_st) / n_st
    fast[b, 0] = step_best
    fast[b, 1] = step_k
    fast[b, 2] = step_a
    fast[b, 3] = speed_best
    fast[b, 4] = speed_k
    fast[b, 5] = speed_a


@jit(parallel=True)
def _kernel_sync(
    pf,
    pi,
    consts,
    seeds,
    src,
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
    counted,
    step_from,
    target,
    threshold,
    has_step,
    master,
    follower,
    steady_lo,
    steady_hi,
    hold_from,
    period,
    figures,
    fast,
):
    """Every plant set through :func:`_run_sync`, in parallel, one at a time per thread (numba's
    chunk size 1): each writes only its own rows, so which thread runs it changes no result."""
    for b in nb.prange(pf.shape[0]):
        _run_sync(
            b,
            pf,
            pi,
            consts,
            seeds,
            src,
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
            counted,
            step_from,
            target,
            threshold,
            has_step,
            master,
            follower,
            steady_lo,
            steady_hi,
            hold_from,
            period,
            figures,
            fast,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class SyncWindows:
    """Where the figures of :func:`run_sync_figures` are read.

    Attributes
    ----------
    counted : ndarray of bool, shape (n_ticks, 2)
        Per tick and axis, whether it counts for the saturation share and (the follower's
        column) the sync error's peak and RMS (the axis's task ticks).
    step_from : int
        First tick of the step response (the last tick before the master's reference moves).
    target : float
        The step's final value [counts].
    threshold : float
        Half-width of the settling band as a fraction of the step [1].
    has_step : ndarray of bool, shape (2,)
        Which axes get overshoot and settling time.
    steady : tuple of int
        ``[lo, hi)`` ticks of the steady window of the sync error.
    hold_from : int
        First tick of the holding window (to the last tick); ``n_ticks``: no holding band.
    """

    counted: np.ndarray
    step_from: int
    target: float
    threshold: float
    has_step: np.ndarray
    steady: tuple[int, int]
    hold_from: int


def run_sync_figures(
    pf: np.ndarray,
    pi: np.ndarray,
    consts: np.ndarray,
    seeds: np.ndarray,
    ref_source: np.ndarray,
    inputs_arrays: tuple[np.ndarray, ...],
    converter: tuple[int, bool, float, float, float],
    windows: SyncWindows,
    period_s: float,
    threads: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The verification figures of every plant set of a two-axis batch (no traces).

    Parameters
    ----------
    pf, pi : ndarray, shapes (n, 2, NROW), (n, 2, 2)
        Plant rows and integer parameters per plant set and axis (as
        :func:`servotune.sim.engine.prepare_batch` holds them); whole ticks of lag 0 or 1.
    consts : ndarray of int64, shape (2, width)
        The law constants of each axis (the same for every plant set), ``2·width`` at most
        ``CONSTS_CAPACITY``.
    seeds : ndarray of uint64, shape (n,)
        Noise stream seeds.
    ref_source : ndarray of int64, shape (2,)
        ``-1`` for the scenario's reference, else the axis whose read is the reference.
    inputs_arrays : tuple of ndarray
        ref, mode, reset, u_add, load, each shape (n_ticks, 2).
    converter : tuple
        Counter bits, latched, read skew [s], D/A low end [V], LSB [V].
    windows : SyncWindows
    period_s : float
        Tick period [s].
    threads : int, optional
        Threads (default numba's).

    Returns
    -------
    figures : ndarray, shape (n, 2, N_FIGURES)
        :data:`FIGURE_NAMES`.
    fast : ndarray, shape (n, N_FAST)
        :data:`N_FAST`.
    """
    if pf.size and np.any(pf[..., R_MODES] != 0.0):
        raise SimulationError("the lean two-axis kernel runs rigid plants; these have modes")
    n = pf.shape[0]
    master = int(np.flatnonzero(ref_source < 0)[0])
    follower = 1 - master
    figures = np.zeros((n, 2, N_FIGURES))
    fast = np.zeros((n, N_FAST))
    if n == 0:
        return figures, fast
    old_threads = nb.get_num_threads()
    if threads is not None:
        nb.set_num_threads(max(1, min(int(threads), nb.config.NUMBA_NUM_THREADS)))
    previous = nb.set_parallel_chunksize(1)
    lo, hi = windows.steady
    try:
        call_compiled(
            _kernel_sync,
            pf,
            pi,
            np.ascontiguousarray(consts, dtype=np.int64),
            seeds,
            np.asarray(ref_source, dtype=np.int64),
            *(np.ascontiguousarray(x) for x in inputs_arrays),
            *converter,
            np.ascontiguousarray(windows.counted, dtype=np.bool_),
            int(windows.step_from),
            float(windows.target),
            float(windows.threshold),
            np.ascontiguousarray(windows.has_step, dtype=np.bool_),
            master,
            follower,
            int(lo),
            int(hi),
            int(windows.hold_from),
            float(period_s),
            figures,
            fast,
        )
    finally:
        nb.set_parallel_chunksize(previous)
        nb.set_num_threads(old_threads)
    return figures, fast
