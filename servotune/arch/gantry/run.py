"""Run the gantry: the CNC's move, the numba kernel of one run, every topology in every case.

Timing, topologies and the monitor's stop: :mod:`servotune.arch.gantry`.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from servotune.arch.gantry.config import (
    CASES,
    T_CROSS,
    T_FOLLOWING,
    T_LISTENING,
    TOPOLOGIES,
    GantryConfig,
    GantryMove,
    _case_config,
)
from servotune.arch.gantry.design import predicted_load_reduction
from servotune.arch.gantry.result import GantryTrace, SyncComparison
from servotune.budget import check_memory
from servotune.fixed import shift_round
from servotune.hw import dac as hw_dac
from servotune.laws.axis import (
    FLAG_SYNC_TRIP,
    MODE_TASK,
    N_STATE,
    S_FAULT,
    axis_control,
    axis_read,
)
from servotune.laws.sync import SYNC_TRIP, sync_enter, sync_monitor, sync_step
from servotune.plant import Plant, advance, lag_split, step_coefficients
from servotune.validate import show_value

__all__ = [
    "compare_topologies",
    "move_profile",
    "simulate_gantry",
]


OP_NONE, OP_ENTER, OP_STEP = 0, 1, 2
_MAX_SUBSTEPS = 64
_TRACE_BYTES_PER_CYCLE = 208  # a GantryTrace and its kernel inputs, per cycle


def move_profile(move: GantryMove, cycle_s: float, n_cycles: int) -> np.ndarray:
    """The CNC's command per cycle [counts]: a trapezoidal (or triangular) move of
    ``distance_counts`` starting at the cycle nearest ``start_s``, then held
    (:func:`~servotune.scenarios.trapezoid_ref`)."""
    from servotune.scenarios import trapezoid_ref

    return trapezoid_ref(n_cycles, cycle_s, move.distance_counts, move.speed_cps,
                         move.accel_cps2, start_tick=round(move.start_s / cycle_s))  # fmt: skip


def _substeps(cfg: GantryConfig, plants: tuple[Plant, Plant]) -> int:
    """Sub-steps per cycle over which the beam force is held: the beam's mode (stiffness) and
    its damping rate each resolved to 0.05 rad per sub-step."""
    if not cfg.beam.coupled:
        return 1
    rate = 0.0
    for p in plants:
        g_t = p.gain_cps_per_v / p.tau_s
        rate = max(rate, math.sqrt(2 * g_t * cfg.beam.stiffness_v_per_count),
                   2 * g_t * cfg.beam.damping_v_s_per_count)  # fmt: skip
    return int(min(_MAX_SUBSTEPS, max(1, math.ceil(rate * cfg.bus.cycle_s / 0.05))))


def _segments(cfg: GantryConfig, plants: tuple[Plant, Plant]) -> tuple[np.ndarray, ...]:
    """Sub-intervals of one cycle: their lengths, whether each axis's new write acts in them,
    and the exact-step coefficients; plus each axis's whole cycles of lag."""
    dt = cfg.bus.cycle_s
    n = _substeps(cfg, plants)
    lags = [lag_split(cfg.bus.compute_s + p.delay_s, dt) for p in plants]
    cuts = sorted({0.0, dt, *(j * dt / n for j in range(1, n)), *(lam for _, lam in lags)})
    cuts = [c for c in cuts if 0.0 <= c <= dt]
    hs = np.diff(np.array(cuts))
    keep = hs > dt * 1e-12
    starts = np.array(cuts[:-1])[keep]
    hs = hs[keep]
    new = np.array([[s >= lam - dt * 1e-12 for _, lam in lags] for s in starts], dtype=np.bool_)
    coef = np.array([[step_coefficients(h, p.tau_s) for p in plants] for h in hs])
    m = np.array([mm for mm, _ in lags], dtype=np.int64)
    return hs, new, coef[:, :, 0].copy(), coef[:, :, 1].copy(), m


@nb.njit(cache=True)
def _gantry_kernel(
    topo, lat, cmd, load, noise, jit, consts, counter_init, bits, dac_lo, lsb,
    plant, hs, new, seg_a, seg_b, lag_m, k_beam, c_beam,
    sc, warn, trip,
    code, y_out, ref_out, flags_out, pos_out, op_out, in_out, comp_out, level_out,
):  # fmt: skip
    nt = cmd.shape[0]
    mask = (np.int64(1) << bits) - 1
    st = np.zeros((2, N_STATE), dtype=np.int64)
    pos = np.zeros(2)
    spd = np.zeros(2)
    volts = np.zeros((nt, 2))
    integ = np.int64(0)
    e_prev = np.int64(0)
    trip_k = -1
    stop_k = np.full(2, -1, dtype=np.int64)
    for k in range(nt):
        # 1-2. sample at the sync interrupt (+ jitter) and unwrap, both drives
        for a in range(2):
            cnt = np.int64(math.floor(pos[a] + spd[a] * jit[k, a] + noise[k, a]))
            raw = (counter_init[a] + cnt) & mask
            y_out[k, a] = axis_read(st, consts, a, raw, False)
            pos_out[k, a] = pos[a]
        # the sync error as the slave / the CNC sees it: measured, latency cycles old
        comp = np.int64(0)
        if k >= lat:
            e_seen = y_out[k - lat, 0] - y_out[k - lat, 1]
            lv = sync_monitor(e_seen, warn, trip)
            level_out[k] = lv
            if lv == SYNC_TRIP and trip_k < 0:
                trip_k = k
                stop_k[1] = k if topo == T_LISTENING else k + 1
                stop_k[0] = k + 1
            if (topo == T_LISTENING or topo == T_CROSS) and trip_k < 0:
                in_out[k] = e_seen
                if k == lat:
                    integ, e_prev = sync_enter(sc[0], sc[1], sc[6], sc[7], e_seen)
                    op_out[k] = OP_ENTER
                else:
                    comp, integ, e_prev = sync_step(
                        sc[0], sc[1], sc[2], sc[3], sc[4], sc[5], sc[6], sc[7], integ, e_prev,
                        e_seen,
                    )  # fmt: skip
                    op_out[k] = OP_STEP
                comp_out[k] = comp
        for a in range(2):
            if stop_k[a] >= 0 and k >= stop_k[a]:
                st[a, S_FAULT] |= FLAG_SYNC_TRIP
        # references by topology
        r_m = cmd[k]
        r_s = cmd[k]
        if topo == T_FOLLOWING and k >= lat:
            r_s = y_out[k - lat, 0]
        elif topo == T_LISTENING:
            r_s = cmd[k] + comp
        elif topo == T_CROSS:
            half = shift_round(comp, 1)
            r_m = cmd[k] - half
            r_s = cmd[k] + (comp - half)
        ref_out[k, 0] = r_m
        ref_out[k, 1] = r_s
        # 3-4. the drives' laws and D/A
        for a in range(2):
            r = r_m if a == 0 else r_s
            c, fl, _ = axis_control(st, consts, a, r, MODE_TASK, False, 0)
            code[k, a] = c
            flags_out[k, a] = fl
            volts[k, a] = dac_lo + c * lsb
        # 5-6. the plants over the cycle, the beam force held per sub-step
        w_new = np.zeros(2)
        w_old = np.zeros(2)
        for a in range(2):
            m = lag_m[a]
            off = plant[a, 2] + load[k, a]
            w_new[a] = (volts[k - m, a] if k >= m else 0.0) + off
            w_old[a] = (volts[k - m - 1, a] if k >= m + 1 else 0.0) + off
        for i in range(hs.shape[0]):
            f_beam = k_beam * (pos[0] - pos[1]) + c_beam * (spd[0] - spd[1])
            for a in range(2):
                w = w_new[a] if new[i, a] else w_old[a]
                w += -f_beam if a == 0 else f_beam
                pos[a], spd[a] = advance(
                    pos[a], spd[a], w, hs[i], seg_a[i, a], seg_b[i, a], plant[a, 0],
                    plant[a, 1], plant[a, 3], plant[a, 4],
                )  # fmt: skip
    return trip_k


def simulate_gantry(
    cfg: GantryConfig, topology: str | None = None, *, case: str = "load", seed: int = 0
) -> GantryTrace:
    """Run the gantry for ``cfg.seconds`` in one topology and one case (:data:`CASES`).

    In the ``load`` case both sides are copies of the master's drive (plant and gains), so only
    the load makes a sync error; in ``mismatch`` each side has its own plant and gains.

    Parameters
    ----------
    cfg : GantryConfig
        With resolved gains (:func:`resolve_gains`).
    topology : str, optional
        One of :data:`TOPOLOGIES`; default ``cfg.topology``.
    case : str
    seed : int
        Seeds the encoder noise and the sync jitter.

    Returns
    -------
    GantryTrace
    """
    topology = cfg.topology if topology is None else topology
    if topology not in TOPOLOGIES:
        raise ValueError(
            f"topology must be one of {', '.join(TOPOLOGIES)}, got {show_value(topology)}"
        )
    n = cfg.n_cycles
    check_memory(n * _TRACE_BYTES_PER_CYCLE, f"a gantry run of {cfg.seconds:g} s",
                 f"{n:,} cycles × {_TRACE_BYTES_PER_CYCLE} bytes")  # fmt: skip
    cfg, load = _case_config(cfg, case)
    plants = (cfg.master.plant, cfg.slave.plant)
    rig = cfg.rig
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal((n, 2)) * np.array([p.noise_counts for p in plants])
    jit = rng.uniform(-1.0, 1.0, (n, 2)) * cfg.bus.jitter_s
    dac_zero = hw_dac.zero_code(rig.dac.bits, rig.dac.range_v)
    ctrls = cfg.controllers()
    consts = np.stack([c.consts(counter_bits=rig.counter.bits, dac_bits=rig.dac.bits,
                                dac_zero=dac_zero) for c in ctrls])  # fmt: skip
    cpr = rig.encoder.pulses_per_rev * rig.counter.multiplier
    plant_arr = np.array([[p.gain_cps_per_v, p.tau_s, p.offset_v, p.coulomb_v,
                           p.max_speed_cps(cpr)] for p in plants])  # fmt: skip
    hs, new, seg_a, seg_b, lag_m = _segments(cfg, plants)
    sc_q = cfg.sync_constants
    sc = np.array([sc_q.kp.q, sc_q.kp.f, sc_q.ki_t.q, sc_q.ki_t.f, sc_q.kd_t.q, sc_q.kd_t.f,
                   sc_q.dead_zone_counts, sc_q.limit_counts], dtype=np.int64)  # fmt: skip
    cmd = move_profile(cfg.move, cfg.bus.cycle_s, n)
    i2 = lambda: np.zeros((n, 2), dtype=np.int64)  # noqa: E731
    i1 = lambda: np.zeros(n, dtype=np.int64)  # noqa: E731
    code, y, ref, flags = i2(), i2(), i2(), i2()
    pos = np.zeros((n, 2))
    op, e_in, comp, level = i1(), i1(), i1(), i1()
    init = np.array([cfg.master.counter_init, cfg.slave.counter_init], dtype=np.int64)
    trip_k = _gantry_kernel(
        TOPOLOGIES.index(topology), cfg.bus.latency_cycles, cmd, load, noise, jit, consts,
        init, rig.counter.bits, rig.dac.range_v[0], hw_dac.lsb_v(rig.dac.bits, rig.dac.range_v),
        plant_arr, hs, new, seg_a, seg_b, lag_m, cfg.beam.stiffness_v_per_count,
        cfg.beam.damping_v_s_per_count, sc, cfg.sync.warn_counts, cfg.sync.trip_counts,
        code, y, ref, flags, pos, op, e_in, comp, level,
    )  # fmt: skip
    return GantryTrace(topology=topology, case=case, cycle_s=cfg.bus.cycle_s, command=cmd,
                       ref=ref, y=y, position=pos, code=code, flags=flags,
                       sync_error=y[:, 0] - y[:, 1], sync_op=op, sync_input=e_in,
                       sync_comp=comp, sync_level=level, trip_cycle=int(trip_k),
                       stop_bound_cycles=cfg.stop_bound_cycles)  # fmt: skip


def compare_topologies(cfg: GantryConfig, *, seed: int = 0) -> SyncComparison:
    """Every topology in every case (:data:`CASES`): max/RMS sync error, warnings, trips.

    The check: the deployed topology (``cfg.topology``) must not trip in any case.
    """
    n_runs = len(CASES) * len(TOPOLOGIES)  # every trace is kept
    check_memory(
        n_runs * cfg.n_cycles * _TRACE_BYTES_PER_CYCLE,
        f"comparing the gantry topologies over {cfg.seconds:g} s",
        f"{n_runs} runs × {cfg.n_cycles:,} cycles × {_TRACE_BYTES_PER_CYCLE} bytes",
    )
    rows, traces, failed = [], [], []
    for case in CASES:
        for topo in TOPOLOGIES:
            tr = simulate_gantry(cfg, topo, case=case, seed=seed)
            traces.append(tr)
            m = tr.metrics()
            rows.append({"case": case, "topology": topo, **m})
            if topo == cfg.topology and m["tripped"]:
                failed.append(f"sync trip in the {case} case at {m['trip_time_s']:.3f} s "
                              f"(|sync error| >= {cfg.sync.trip_counts} counts)")  # fmt: skip
    predicted = predicted_load_reduction(cfg) if not cfg.beam.coupled else {}
    return SyncComparison(config=cfg, rows=tuple(rows), traces=tuple(traces), predicted=predicted,
                          failed=tuple(failed))  # fmt: skip
