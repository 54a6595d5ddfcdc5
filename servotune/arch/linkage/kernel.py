"""The numba kernel of the event-driven simulation: slave clocks and queues, loops, plants.

Timing model and sync semantics: :mod:`servotune.arch.linkage`.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from servotune.arch.linkage.config import _RING
from servotune.laws.axis import (
    FLAG_COUNTER_FAULT,
    FLAG_FOLLOWING_ERROR,
    FLAG_SATURATED,
    MODE_TASK,
    N_STATE,
    axis_control,
    axis_read,
)
from servotune.plant import advance

__all__: list[str] = []  # private: the names run.py needs are imported by name

# per-axis float parameters
_P_GAIN, _P_TAU, _P_OFFSET, _P_COULOMB, _P_VMAX, _P_LAG = 0, 1, 2, 3, 4, 5
# per-CPU statistics
_S_UNDER, _S_T_UNDER, _S_OVER, _S_T_OVER, _S_SKIP, _S_MIN, _S_MAX, _S_TICKS, _S_RESYNC = range(9)
_NS = 9
# per-axis statistics
_A_FLAGS, _A_T_FAULT, _A_SAT = 0, 1, 2
_NA = 3


@nb.njit(cache=True)
def _to_time(p, v, w, t_ax, t, pf, a):  # fmt: skip
    """Move axis ``a`` from ``t_ax`` to ``t`` with the net input ``w`` held [V]."""
    h = t - t_ax
    if h <= 0.0:
        return p, v
    tau = pf[a, _P_TAU]
    return advance(p, v, w, h, math.exp(-h / tau), -tau * math.expm1(-h / tau), pf[a, _P_GAIN],
                   tau, pf[a, _P_COULOMB], pf[a, _P_VMAX])  # fmt: skip


@nb.njit(cache=True)
def _kernel(
    n_ticks, period, cmd, ax_cpu, pf, consts, counter_init, noise, cpu_eps, cpu_depth,
    block, prefill, frame_s, resync_ticks, bits, dac_lo, lsb,
    actual, q_time, q_level, q_index, cpu_stats, ax_stats,
):  # fmt: skip
    n_ax = cmd.shape[1]
    n_cmd = cmd.shape[0]
    n_cpu = cpu_eps.shape[0]
    n_rec = q_time.shape[1]
    mask = (np.int64(1) << bits) - 1
    t_end = n_ticks * period
    # axis states
    st = np.zeros((n_ax, N_STATE), dtype=np.int64)
    pos = np.zeros(n_ax)
    spd = np.zeros(n_ax)
    t_ax = np.zeros(n_ax)
    w_in = np.zeros(n_ax)  # volts at the motor input now (before offset)
    ring_t = np.zeros((n_ax, _RING))
    ring_v = np.zeros((n_ax, _RING))
    ring_h = np.zeros(n_ax, dtype=np.int64)
    ring_n = np.zeros(n_ax, dtype=np.int64)
    n_read = np.zeros(n_ax, dtype=np.int64)
    last_ref = np.zeros(n_ax, dtype=np.int64)
    for a in range(n_ax):
        last_ref[a] = cmd[0, a]
        ax_stats[a, _A_T_FAULT] = -1.0
    # queues
    present = np.zeros((n_cpu, n_cmd), dtype=np.bool_)
    level = np.zeros(n_cpu, dtype=np.int64)
    head = np.zeros(n_cpu, dtype=np.int64)
    n_pre = min(prefill * block, n_cmd)
    for s in range(n_cpu):
        for i in range(n_pre):
            present[s, i] = True
        level[s] = n_pre
        cpu_stats[s, _S_T_UNDER] = -1.0
        cpu_stats[s, _S_T_OVER] = -1.0
        cpu_stats[s, _S_MIN] = 1e18
        cpu_stats[s, _S_MAX] = n_pre
    # clocks: next index, and the anchor (index, time) of the last sync
    next_j = np.zeros(n_cpu, dtype=np.int64)
    anc_k = np.zeros(n_cpu, dtype=np.int64)
    anc_t = np.zeros(n_cpu)
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
            ts = anc_t[s] + (next_j[s] - anc_k[s]) * period / (1.0 + cpu_eps[s])
            if ts < t_best:
                t_best, kind, which = ts, 1, s
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
                if j < k_r:  # behind: the commands up to k_r - 1 are consumed and dropped
                    for i in range(max(j, head[s]), min(k_r, n_cmd)):
                        if present[s, i]:
                            present[s, i] = False
                            level[s] -= 1
                            cpu_stats[s, _S_SKIP] += 1.0
                    head[s] = max(head[s], k_r)
                    next_j[s] = k_r
                anc_k[s] = k_r
                anc_t[s] = t
                cpu_stats[s, _S_RESYNC] += 1.0
            r_next += 1
        elif kind == 1:  # a slave tick
            s = which
            j = next_j[s]
            lvl = level[s]
            if lvl < cpu_stats[s, _S_MIN]:
                cpu_stats[s, _S_MIN] = lvl
            c = int(cpu_stats[s, _S_TICKS])
            if c < n_rec:
                q_time[s, c] = t
                q_level[s, c] = lvl
                q_index[s, c] = j
            cpu_stats[s, _S_TICKS] += 1.0
            ok = j < n_cmd and present[s, j]
            if ok:
                present[s, j] = False
                level[s] -= 1
            else:
                cpu_stats[s, _S_UNDER] += 1.0
                if cpu_stats[s, _S_T_UNDER] < 0.0:
                    cpu_stats[s, _S_T_UNDER] = t
            head[s] = j + 1
            next_j[s] = j + 1
            for a in range(n_ax):
                if ax_cpu[a] != s:
                    continue
                # the motor up to now, through the pending writes
                while ring_n[a] > 0 and ring_t[a, ring_h[a]] <= t:
                    tw = ring_t[a, ring_h[a]]
                    pos[a], spd[a] = _to_time(pos[a], spd[a], w_in[a] + pf[a, _P_OFFSET],
                                              t_ax[a], tw, pf, a)  # fmt: skip
                    t_ax[a] = tw
                    w_in[a] = ring_v[a, ring_h[a]]
                    ring_h[a] = (ring_h[a] + 1) % _RING
                    ring_n[a] -= 1
                pos[a], spd[a] = _to_time(pos[a], spd[a], w_in[a] + pf[a, _P_OFFSET], t_ax[a],
                                          t, pf, a)  # fmt: skip
                t_ax[a] = t
                nz = noise[a, n_read[a]] if n_read[a] < noise.shape[1] else 0.0
                n_read[a] += 1
                raw = (counter_init[a] + np.int64(math.floor(pos[a] + nz))) & mask
                axis_read(st, consts, a, raw, False)
                ref = cmd[j, a] if ok else last_ref[a]
                last_ref[a] = ref
                code, flags, _e = axis_control(st, consts, a, ref, MODE_TASK, False, 0)
                if flags & FLAG_SATURATED:
                    ax_stats[a, _A_SAT] += 1.0
                fault = flags & (FLAG_COUNTER_FAULT | FLAG_FOLLOWING_ERROR)
                if fault and ax_stats[a, _A_T_FAULT] < 0.0:
                    ax_stats[a, _A_T_FAULT] = t
                ax_stats[a, _A_FLAGS] = float(int(ax_stats[a, _A_FLAGS]) | fault)
                slot = (ring_h[a] + ring_n[a]) % _RING
                ring_t[a, slot] = t + pf[a, _P_LAG]
                ring_v[a, slot] = dac_lo + code * lsb
                ring_n[a] += 1
        elif kind == 2:  # measurement at the master tick
            for a in range(n_ax):
                while ring_n[a] > 0 and ring_t[a, ring_h[a]] <= t:
                    tw = ring_t[a, ring_h[a]]
                    pos[a], spd[a] = _to_time(pos[a], spd[a], w_in[a] + pf[a, _P_OFFSET],
                                              t_ax[a], tw, pf, a)  # fmt: skip
                    t_ax[a] = tw
                    w_in[a] = ring_v[a, ring_h[a]]
                    ring_h[a] = (ring_h[a] + 1) % _RING
                    ring_n[a] -= 1
                pos[a], spd[a] = _to_time(pos[a], spd[a], w_in[a] + pf[a, _P_OFFSET], t_ax[a],
                                          t, pf, a)  # fmt: skip
                t_ax[a] = t
                actual[k_next, a] = pos[a]
            k_next += 1
        else:  # block nb_next has arrived
            i0 = nb_next * block
            i1 = min(i0 + block, n_cmd)
            for s in range(n_cpu):
                dropped = False
                for i in range(i0, i1):
                    if i < head[s]:
                        continue  # too late: its tick has passed (counted as an underrun)
                    if level[s] < cpu_depth[s]:
                        present[s, i] = True
                        level[s] += 1
                    else:
                        dropped = True
                if dropped:
                    cpu_stats[s, _S_OVER] += 1.0
                    if cpu_stats[s, _S_T_OVER] < 0.0:
                        cpu_stats[s, _S_T_OVER] = t
                if level[s] > cpu_stats[s, _S_MAX]:
                    cpu_stats[s, _S_MAX] = level[s]
            nb_next += 1
