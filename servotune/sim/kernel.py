"""The general batch kernel: every axis of every candidate, traced or not, ideal or bit-true.

Each tick composes :mod:`servotune.sim.tick` (sample, read, law, D/A, hold, advance) for every
axis; candidates are interleaved ``LANES`` per thread and run in parallel (numba ``prange``).
Layouts of the per-candidate integer and gain rows are the ``I_*`` and ``G_*`` indices.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from servotune._numba_cache import jit
from servotune.laws.axis import MODE_LOCK, MODE_TASK, N_STATE, S_MODE
from servotune.laws.pi import pi_ideal_step
from servotune.plant import R_NOISE, R_OFFSET
from servotune.resonance import MAX_MODES
from servotune.sim.tick import (
    accumulate,
    advance_axis,
    draw_noise,
    finish,
    hold,
    read_axis,
    sensed,
    write_axis,
)

__all__ = ["G_KIT", "G_KP", "G_LOCK", "I_INIT", "I_LAG", "LANES", "NPI", "batch_kernel"]

# The layouts of the per-candidate rows, shared with the engine and the lean kernels, which
# pack and read them: plain module-level ints, which numba compiles in as constants.
# plant rows (float64, per candidate and axis): servotune.plant.plant_row; integer parameters:
# whole ticks of lag, counter register at start
I_LAG, I_INIT = 0, 1
NPI = 2
# ideal-law gains (float64): lock, kp, ki*T
G_LOCK, G_KP, G_KIT = 0, 1, 2

LANES = 2
"""Candidates interleaved per thread: independent lanes let the CPU overlap their tick chains."""


@jit
def _run_group(
    b0,
    n_group,
    pf,
    pi,
    consts,
    gains,
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
    ideal,
    ring,
    m_from,
    period,
    out_i,
    out_f,
    metrics,
):
    # lane ln = g * n_ax + a runs axis a of candidate b0 + g; lanes never interact across
    # candidates and each candidate draws its own noise stream, so grouping changes no result
    n_ax = pf.shape[1]
    n_l = n_group * n_ax
    nt = ref.shape[0]
    rec = out_i.shape[2] > 0
    mask = (np.int64(1) << bits) - 1
    nbytes = bits // 8
    st = np.zeros((n_l, N_STATE), dtype=np.int64)
    hist = np.zeros((n_l, ring))
    pos = np.zeros(n_l)
    spd = np.zeros(n_l)
    qs = np.zeros((n_l, 2 * MAX_MODES))  # the modes' states (a rigid plant: unused)
    y = np.zeros(n_l, dtype=np.int64)
    yf = np.zeros(n_l)
    integ_f = np.zeros(n_l)
    target_f = np.zeros(n_l)
    mode_f = np.zeros(n_l, dtype=np.int64)
    rng = seeds[b0 : b0 + n_group].copy()
    pfb = pf[b0 : b0 + n_group].copy().reshape(n_l, pf.shape[2])
    pib = pi[b0 : b0 + n_group].copy().reshape(n_l, pi.shape[2])
    cb = consts[b0 : b0 + n_group].copy().reshape(n_l, consts.shape[2])
    gb = gains[b0 : b0 + n_group].copy().reshape(n_l, gains.shape[2])
    mt = np.zeros((n_l, metrics.shape[2]))
    lane_ax = np.empty(n_l, dtype=np.int64)
    lane_g = np.empty(n_l, dtype=np.int64)
    for ln in range(n_l):
        lane_g[ln] = ln // n_ax
        lane_ax[ln] = ln - lane_g[ln] * n_ax
        mt[ln, 4] = -1.0
    slot = ring - 1
    for k in range(nt):
        slot += 1
        if slot == ring:
            slot = 0
        # 1-2. sample and unwrap, every axis
        for ln in range(n_l):
            a = lane_ax[ln]
            g_l = lane_g[ln]
            rng[g_l], nz = draw_noise(rng[g_l], pfb[ln, R_NOISE])
            p_s, v_s = sensed(pos[ln], spd[ln], qs[ln], pfb[ln])
            if ideal:
                yf[ln] = p_s + nz
                continue
            raw, y[ln] = read_axis(
                st,
                cb,
                ln,
                p_s,
                v_s,
                nz,
                pib[ln, I_INIT],
                mask,
                latched,
                nbytes,
                skew,
                reset[k, a],
            )
            if rec:
                out_i[1, b0 + g_l, k, a] = raw
        # 3-4. control law and D/A, every axis
        for ln in range(n_l):
            a = lane_ax[ln]
            s = src[a]
            base = ln - a
            if ideal:
                r = float(ref[k, a]) if s < 0 else yf[base + s]
                md = mode[k, a]
                if md == MODE_LOCK:
                    if mode_f[ln] != MODE_LOCK or k == 0:
                        target_f[ln] = yf[ln]
                    e_f = target_f[ln] - yf[ln]
                    u = gb[ln, G_LOCK] * e_f
                elif md == MODE_TASK:
                    e_f = r - yf[ln]
                    u, integ_f[ln] = pi_ideal_step(gb[ln, G_KP], gb[ln, G_KIT], integ_f[ln], e_f)
                else:
                    e_f = 0.0
                    u = float(u_add[k, a])
                mode_f[ln] = md
                volts = u * lsb
                code = 0
                flags = 0
                e = np.int64(math.floor(e_f + 0.5))
                cur_mode = md
            else:
                r = ref[k, a] if s < 0 else y[base + s]
                code, flags, e, volts = write_axis(
                    st, cb, ln, r, mode[k, a], reset[k, a], u_add[k, a], dac_lo, lsb
                )
                cur_mode = st[ln, S_MODE]
            hold(hist[ln], slot, volts)
            if rec:
                b = b0 + lane_g[ln]
                out_i[0, b, k, a] = code
                out_i[2, b, k, a] = y[ln]
                out_i[3, b, k, a] = e
                out_i[4, b, k, a] = cur_mode
                out_i[5, b, k, a] = flags
                out_f[0, b, k, a] = volts
                out_f[1, b, k, a], out_f[2, b, k, a] = sensed(pos[ln], spd[ln], qs[ln], pfb[ln])
            accumulate(mt, ln, k, e, flags, cur_mode, m_from, period)
        # 5-6. hold the writes and move the plants to the next tick
        for ln in range(n_l):
            a = lane_ax[ln]
            w_off = pfb[ln, R_OFFSET] + load[k, a]
            pos[ln], spd[ln] = advance_axis(
                pos[ln], spd[ln], qs[ln], hist[ln], slot, pib[ln, I_LAG], k, w_off, pfb[ln]
            )
    for ln in range(n_l):
        finish(mt, ln, metrics, b0 + lane_g[ln], lane_ax[ln])


@jit(parallel=True)
def batch_kernel(
    pf,
    pi,
    consts,
    gains,
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
    ideal,
    ring,
    m_from,
    period,
    out_i,
    out_f,
    metrics,
    lanes,
):
    """Run every candidate of a batch (arguments: :mod:`servotune.sim.engine`'s plumbing),
    ``lanes`` candidates interleaved per thread, the groups in parallel."""
    n = pf.shape[0]
    n_groups = (n + lanes - 1) // lanes
    for gi in nb.prange(n_groups):
        b0 = gi * lanes
        _run_group(
            b0,
            min(lanes, n - b0),
            pf,
            pi,
            consts,
            gains,
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
            ideal,
            ring,
            m_from,
            period,
            out_i,
            out_f,
            metrics,
        )
