"""Run the gantry: the CNC's move, the numba kernel of one run, every topology in every case.

Timing, topologies and the monitor's stop: :mod:`servotune.arch.gantry`.

The kernel composes the axis tick of :mod:`servotune.sim.tick` (the single-rig engine's, in the
same order): per cycle and per drive, master then slave, the encoder noise is drawn
(:func:`~servotune.sim.tick.draw_noise`) and the count latched and unwrapped
(:func:`~servotune.sim.tick.read_axis`); then the sync monitor and compensator run, the
topology routes the two position commands, and each drive's law writes its D/A
(:func:`~servotune.sim.tick.write_axis`) into its tick-slot ring
(:func:`~servotune.sim.tick.hold`); last the plants move over the cycle. What the gantry adds
is only its scheduling and routing:

- **sample instant**: a drive latches its encoder at the sync interrupt plus the jitter, so
  the latched position is ``pos + speed·jitter`` (passed to ``read_axis`` as the position, with
  the counter latched and no byte skew: a drive reads its own counter whole at the sample
  instant; the rig file's ``counter.latched``/``read_skew_s`` describe the PC's counter card,
  not a drive). With ``jitter_s = 0`` the read is the engine's, bit for bit.
- **noise**: one splitmix64 stream per run, state ``seed``, drawn per cycle for the master then
  the slave, only for a drive whose ``noise_counts > 0``: the engine's stream of a
  one-candidate run (``simulate(loop, inputs, seed=seed)``). The sync jitter is bus physics,
  not encoder noise: it keeps its own numpy draw (``default_rng(seed).uniform``), drawn only
  when ``jitter_s > 0``.
- **plant**: each drive's plant row (:func:`~servotune.plant.plant_row` at the bus cycle, the
  drive's compute time and the rig's counts per revolution). An uncoupled beam moves each side
  exactly over the cycle (:func:`~servotune.sim.tick.advance_axis`, as the engine); a coupled
  beam splits the cycle into sub-steps over which the beam force is held
  (:func:`~servotune.plant.advance` on each, the held writes switching at each drive's λ).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from servotune._numba_cache import call_compiled, jit
from servotune.arch.gantry.config import (
    CASES,
    T_CROSS,
    T_FOLLOWING,
    T_LISTENING,
    TOPOLOGIES,
    GantryConfig,
    GantryMove,
    case_config,
)
from servotune.arch.gantry.design import predicted_load_reduction
from servotune.arch.gantry.margins import gantry_margins, margin_failures
from servotune.arch.gantry.result import (
    GantryMonteCarlo,
    GantryTrace,
    GantryVariant,
    SyncComparison,
)
from servotune.arch.gantry.shaping import gantry_shaper
from servotune.budget import check_memory
from servotune.errors import ConfigError
from servotune.executor import Executor, InProcessExecutor, chunk_bounds
from servotune.fixed import shift_round
from servotune.laws.axis import FLAG_SYNC_TRIP, MODE_TASK, N_STATE, S_FAULT
from servotune.laws.shaping import Shaper, shape_reference
from servotune.laws.sync import SYNC_TRIP, sync_enter, sync_monitor, sync_step
from servotune.plant import (
    NROW,
    R_COULOMB,
    R_COULOMB_NEG,
    R_GAIN,
    R_GAIN_NEG,
    R_H1,
    R_NOISE,
    R_OFFSET,
    R_TAU,
    R_VMAX,
    Plant,
    advance,
    plant_row,
    step_coefficients,
)
from servotune.resonance import MAX_MODES
from servotune.scenarios import trapezoid_ref
from servotune.sim.tick import (
    advance_axis,
    draw_noise,
    held,
    hold,
    read_axis,
    sensed,
    write_axis,
)
from servotune.validate import check_seed, show_value

__all__ = [
    "compare_topologies",
    "gantry_command",
    "gantry_montecarlo",
    "move_profile",
    "run_gantry",
    "simulate_gantry",
]


OP_NONE, OP_ENTER, OP_STEP = 0, 1, 2
_MAX_SUBSTEPS = 64
# a GantryTrace (145 bytes) and its kernel inputs (load and jitter, 32 bytes; the jitter's
# draw before scaling, 16 bytes; the resets, 1 byte), per cycle
_TRACE_BYTES_PER_CYCLE = 194


def move_profile(move: GantryMove, cycle_s: float, n_cycles: int) -> np.ndarray:
    """The CNC's command per cycle [counts]: a trapezoidal (or triangular) move of
    ``distance_counts`` starting at the cycle nearest ``start_s``, then held
    (:func:`~servotune.scenarios.trapezoid_ref`)."""
    return trapezoid_ref(
        n_cycles,
        cycle_s,
        move.distance_counts,
        move.speed_cps,
        move.accel_cps2,
        start_tick=round(move.start_s / cycle_s),
    )


def gantry_command(
    cfg: GantryConfig, n_cycles: int, design: tuple[Shaper | None, list[str]] | None = None
) -> np.ndarray:
    """The CNC's command as the drives get it: :func:`move_profile`, shaped by the move's
    shaper where it has one (:func:`~servotune.arch.gantry.shaping.gantry_shaper`, designed
    for ``cfg``'s drives; ``design``: that design when the caller has already made it)."""
    cmd = move_profile(cfg.move, cfg.bus.cycle_s, n_cycles)
    shaper, _ = gantry_shaper(cfg) if design is None else design
    return cmd if shaper is None else shape_reference(cmd, shaper)


def _substeps(cfg: GantryConfig, plants: tuple[Plant, Plant]) -> int:
    """Sub-steps per cycle over which the beam force is held: the beam's mode (stiffness) and
    its damping rate each resolved to 0.05 rad per sub-step."""
    if not cfg.beam.coupled:
        return 1
    rate = 0.0
    for p in plants:
        g_t = max(p.gains_cps_per_v) / p.tau_s  # the faster direction's
        rate = max(
            rate,
            math.sqrt(2 * g_t * cfg.beam.stiffness_v_per_count),
            2 * g_t * cfg.beam.damping_v_s_per_count,
        )
    return int(min(_MAX_SUBSTEPS, max(1, math.ceil(rate * cfg.bus.cycle_s / 0.05))))


def _segments(
    cfg: GantryConfig, plants: tuple[Plant, Plant], rows: np.ndarray
) -> tuple[np.ndarray, ...]:
    """Sub-intervals of one cycle for a coupled beam: their lengths [s], whether each axis's
    newer write acts in them (from its λ, ``rows[a, R_H1]``), and the exact-step coefficients
    ``a = exp(-h/tau)``, ``b = tau (1 - a)`` per sub-interval and axis."""
    dt = cfg.bus.cycle_s
    n = _substeps(cfg, plants)
    lams = [float(rows[a, R_H1]) for a in range(2)]
    cuts = sorted({0.0, dt, *(j * dt / n for j in range(1, n)), *lams})
    cuts = [c for c in cuts if 0.0 <= c <= dt]
    hs = np.diff(np.array(cuts))
    keep = hs > dt * 1e-12
    starts = np.array(cuts[:-1])[keep]
    hs = hs[keep]
    new = np.array([[s >= lam - dt * 1e-12 for lam in lams] for s in starts], dtype=np.bool_)
    coef = np.array([[step_coefficients(h, p.tau_s) for p in plants] for h in hs])
    return hs, new, coef[:, :, 0].copy(), coef[:, :, 1].copy()


def _scratch(ring_n: int) -> tuple[np.ndarray, ...]:
    """The kernel's working arrays, zeroed: the drives' law states, their tick-slot rings
    (``ring_n`` slots), positions and speeds, their modes' states, the held inputs of a
    coupled cycle, the cycles each drive stops at (-1: running)."""
    return (
        np.zeros((2, N_STATE), dtype=np.int64),
        np.zeros((2, ring_n)),
        np.zeros(2),
        np.zeros(2),
        np.zeros((2, 2 * MAX_MODES)),
        np.zeros(2),
        np.zeros(2),
        np.full(2, -1, dtype=np.int64),
    )


# The working arrays come from :func:`_scratch`: nothing is allocated inside the kernel.
@jit
def _gantry_kernel(
    topo,
    lat,
    cmd,
    load,
    jit_s,
    resets,
    seed,
    consts,
    counter_init,
    bits,
    dac_lo,
    lsb,
    rows,
    lag_m,
    coupled,
    hs,
    new,
    seg_a,
    seg_b,
    k_beam,
    c_beam,
    sc,
    warn,
    trip,
    code,
    y_out,
    raw_out,
    ref_out,
    flags_out,
    pos_out,
    op_out,
    in_out,
    comp_out,
    level_out,
    st,
    ring,
    pos,
    spd,
    q,
    w_old,
    w_new,
    stop_k,
):
    """One gantry run (:func:`run_gantry`): fills the per-cycle outputs ``code`` …
    ``level_out`` and returns the cycle the monitor first tripped (-1 if it did not).

    Inputs: the topology (``T_*``) and latency [cycles]; per cycle the CNC's command [counts],
    the load per side [V], the sample jitter per side [s] and the operator's reset (nonzero:
    the trip and the drives' latched faults cleared, the compensator entered again); the
    noise stream's seed; the
    drives' law constants, counter registers at power-up, counter bits, D/A low rail [V] and
    LSB [V]; the plant rows (:func:`~servotune.plant.plant_row`) and whole cycles of lag;
    the beam (coupled, its sub-steps from :func:`_segments`, stiffness and damping); the
    compensator's constants and the monitor's thresholds. Working arrays: :func:`_scratch`.
    """
    nt = cmd.shape[0]
    mask = (np.int64(1) << bits) - 1
    nbytes = bits // 8
    ring_n = ring.shape[1]
    rng = seed
    integ = np.int64(0)
    e_prev = np.int64(0)
    trip_k = -1
    first_trip = -1
    enter = True
    slot = ring_n - 1
    for k in range(nt):
        slot += 1
        if slot == ring_n:
            slot = 0
        rs = resets[k] != 0
        if rs:  # the operator's reset: the trip cleared, the drives' faults with their laws
            # (and their counter reads re-initialised, as the engine's reset does)
            trip_k = -1
            stop_k[0] = -1
            stop_k[1] = -1
            enter = True
        # 1-2. sample at the sync interrupt (+ jitter: the position moved by speed × jitter),
        # latched whole, and unwrap, both drives
        for a in range(2):
            rng, nz = draw_noise(rng, rows[a, R_NOISE])
            p_m, v_m = sensed(pos[a], spd[a], q[a], rows[a])
            pos_out[k, a] = p_m
            p_s = p_m + v_m * jit_s[k, a]
            raw_out[k, a], y_out[k, a] = read_axis(
                st, consts, a, p_s, 0.0, nz, counter_init[a], mask, True, nbytes, 0.0, rs
            )
        # the sync error as the slave / the CNC sees it: measured, latency cycles old
        comp = np.int64(0)
        if k >= lat:
            e_seen = y_out[k - lat, 0] - y_out[k - lat, 1]
            lv = sync_monitor(e_seen, warn, trip)
            level_out[k] = lv
            if lv == SYNC_TRIP and trip_k < 0:
                trip_k = k
                if first_trip < 0:
                    first_trip = k
                stop_k[1] = k if topo == T_LISTENING else k + 1
                stop_k[0] = k + 1
            if (topo == T_LISTENING or topo == T_CROSS) and trip_k < 0:
                in_out[k] = e_seen
                if enter:
                    integ, e_prev = sync_enter(sc[0], sc[1], sc[6], sc[7], e_seen)
                    op_out[k] = OP_ENTER
                    enter = False
                else:
                    comp, integ, e_prev = sync_step(
                        sc[0],
                        sc[1],
                        sc[2],
                        sc[3],
                        sc[4],
                        sc[5],
                        sc[6],
                        sc[7],
                        integ,
                        e_prev,
                        e_seen,
                    )
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
        # 3-4. the drives' laws and D/A; each write kept in its drive's tick-slot ring
        for a in range(2):
            r = r_m if a == 0 else r_s
            # a drive the monitor stops in this very cycle keeps its fault: the reset is refused
            stopped = stop_k[a] >= 0 and k >= stop_k[a]
            c, fl, _, volts = write_axis(
                st, consts, a, r, MODE_TASK, rs and not stopped, 0, dac_lo, lsb
            )
            code[k, a] = c
            flags_out[k, a] = fl
            hold(ring[a], slot, volts)
        # 5. the plants over the cycle: each side exactly (as the engine), or with a coupled
        # beam in sub-steps over which the beam force is held
        if not coupled:
            for a in range(2):
                w_off = rows[a, R_OFFSET] + load[k, a]
                pos[a], spd[a] = advance_axis(
                    pos[a], spd[a], q[a], ring[a], slot, lag_m[a], k, w_off, rows[a]
                )
        else:
            for a in range(2):
                v_old, v_new = held(ring[a], slot, lag_m[a], k)
                w_off = rows[a, R_OFFSET] + load[k, a]
                w_old[a] = v_old + w_off
                w_new[a] = v_new + w_off
            for i in range(hs.shape[0]):
                f_beam = k_beam * (pos[0] - pos[1]) + c_beam * (spd[0] - spd[1])
                for a in range(2):
                    w = w_new[a] if new[i, a] else w_old[a]
                    w += -f_beam if a == 0 else f_beam
                    pos[a], spd[a] = advance(
                        pos[a],
                        spd[a],
                        w,
                        hs[i],
                        seg_a[i, a],
                        seg_b[i, a],
                        rows[a, R_GAIN],
                        rows[a, R_TAU],
                        rows[a, R_COULOMB],
                        rows[a, R_VMAX],
                        rows[a, R_GAIN_NEG],
                        rows[a, R_COULOMB_NEG],
                        q[a],
                        rows[a],
                        -1,
                    )
    return first_trip


def simulate_gantry(
    cfg: GantryConfig,
    topology: str | None = None,
    *,
    case: str = "load",
    seed: int = 0,
    command: np.ndarray | None = None,
) -> GantryTrace:
    """Run the gantry for ``cfg.seconds`` in one topology and one case (:data:`CASES`).

    In the ``load`` case both sides are copies of the master's drive (plant and gains), so only
    the load makes a sync error; in ``mismatch`` each side has its own plant and gains. The
    CNC's command is :func:`gantry_command` (the move, shaped where ``[move] shaper`` asks); no
    reset (:func:`run_gantry` takes any command, load and resets).

    Parameters
    ----------
    cfg : GantryConfig
        With resolved gains (:func:`resolve_gains`).
    topology : str, optional
        One of :data:`TOPOLOGIES`; default ``cfg.topology``.
    case : str
    seed : int
        Seeds the encoder noise (the splitmix64 stream of :mod:`servotune.sim.tick`, as
        ``simulate(..., seed=seed)``) and the sync jitter (``numpy.random.default_rng``).
    command : ndarray of int64, shape (cfg.n_cycles,), optional
        The command, already made (:func:`gantry_command` of the nominal config: a Monte
        Carlo's drawn plants keep the nominal design's shaper); default made here.

    Returns
    -------
    GantryTrace
    """
    n = cfg.n_cycles
    check_memory(
        n * _TRACE_BYTES_PER_CYCLE,
        f"a gantry run of {cfg.seconds:g} s",
        f"{n:,} cycles × {_TRACE_BYTES_PER_CYCLE} bytes",
    )
    cmd = gantry_command(cfg, n) if command is None else command
    cfg, load = case_config(cfg, case)
    return run_gantry(cfg, cmd, load, topology=topology, seed=seed, case=case)


def _checked_run(
    cfg: GantryConfig,
    command: np.ndarray,
    load: np.ndarray,
    topology: str | None,
    resets: np.ndarray | None,
) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`run_gantry`'s topology (``cfg``'s by default), command, load and resets, checked
    and as the kernel takes them (resets default to none).

    Raises
    ------
    ValueError
        An unknown topology, or arrays of inconsistent shapes.
    """
    topology = cfg.topology if topology is None else topology
    if topology not in TOPOLOGIES:
        raise ValueError(
            f"topology must be one of {', '.join(TOPOLOGIES)}, got {show_value(topology)}"
        )
    cmd = np.ascontiguousarray(command, dtype=np.int64)
    n = cmd.shape[0]
    load = np.ascontiguousarray(load, dtype=np.float64)
    if cmd.ndim != 1 or n < 1 or load.shape != (n, 2):
        raise ValueError(
            f"command must have shape (n,) and load (n, 2), got {cmd.shape} and {load.shape}"
        )
    rs = np.zeros(n, dtype=np.int8) if resets is None else np.asarray(resets, dtype=np.int8)
    if rs.shape != (n,):
        raise ValueError(f"resets must have shape ({n},), got {rs.shape}")
    return topology, cmd, load, rs


def _plant_rows(cfg: GantryConfig, plants: tuple[Plant, Plant]) -> tuple[np.ndarray, np.ndarray]:
    """Each drive's plant row at the bus cycle and its whole ticks of lag."""
    rig = cfg.rig
    dt = cfg.bus.cycle_s
    rows = np.zeros((2, NROW))
    lag_m = np.zeros(2, dtype=np.int64)
    for a, p in enumerate(plants):
        rows[a], lag_m[a] = plant_row(p, dt, cfg.bus.compute_s, rig.counts_per_rev)
    return rows, lag_m


def _sync_jitter(cfg: GantryConfig, n: int, seed: int) -> np.ndarray:
    """Each drive's sample-instant jitter per cycle [s] (drawn only when ``jitter_s > 0``)."""
    if cfg.bus.jitter_s > 0:
        return np.random.default_rng(seed).uniform(-1.0, 1.0, (n, 2)) * cfg.bus.jitter_s
    return np.zeros((n, 2))


def _drive_constants(cfg: GantryConfig) -> np.ndarray:
    """Both drives' law constants, one row each."""
    rig = cfg.rig
    return np.stack(
        [
            c.consts(
                counter_bits=rig.counter.bits, dac_bits=rig.dac.bits, dac_zero=rig.dac.zero_code
            )
            for c in cfg.controllers()
        ]
    )


def _sync_constant_row(cfg: GantryConfig) -> np.ndarray:
    """The sync compensator's quantised constants in the kernel's order."""
    sc_q = cfg.sync_constants
    return np.array(
        [
            sc_q.kp.q,
            sc_q.kp.f,
            sc_q.ki_t.q,
            sc_q.ki_t.f,
            sc_q.kd_t.q,
            sc_q.kd_t.f,
            sc_q.dead_zone_counts,
            sc_q.limit_counts,
        ],
        dtype=np.int64,
    )


def run_gantry(
    cfg: GantryConfig,
    command: np.ndarray,
    load: np.ndarray,
    *,
    topology: str | None = None,
    resets: np.ndarray | None = None,
    seed: int = 0,
    case: str = "custom",
) -> GantryTrace:
    """Run the gantry on a given command, load and reset sequence (the golden runs' driver;
    :func:`simulate_gantry` runs the cases).

    Parameters
    ----------
    cfg : GantryConfig
        With resolved gains; each side runs its own drive and plant (no case copying).
    command : ndarray of int64, shape (n,)
        The CNC's command per cycle [counts].
    load : ndarray, shape (n, 2)
        Load per cycle on the master's and the slave's side [V].
    topology : str, optional
        Default ``cfg.topology``.
    resets : ndarray of bool, shape (n,), optional
        The operator's reset per cycle: the monitor's trip and both drives' latched faults are
        cleared (each drive's law re-enters bumplessly), and the compensator enters again.
    seed : int
        As :func:`simulate_gantry`.
    case : str
        The label the trace carries.
    """
    check_seed(seed)
    topology, cmd, load, rs = _checked_run(cfg, command, load, topology, resets)
    n = cmd.shape[0]
    plants = (cfg.master.plant, cfg.slave.plant)
    rig = cfg.rig
    rows, lag_m = _plant_rows(cfg, plants)
    jit_s = _sync_jitter(cfg, n, seed)
    consts = _drive_constants(cfg)
    hs, new, seg_a, seg_b = _segments(cfg, plants, rows)
    sc = _sync_constant_row(cfg)
    i2 = lambda: np.zeros((n, 2), dtype=np.int64)  # noqa: E731
    i1 = lambda: np.zeros(n, dtype=np.int64)  # noqa: E731
    code, y, raw, ref, flags = i2(), i2(), i2(), i2(), i2()
    pos = np.zeros((n, 2))
    op, e_in, comp, level = i1(), i1(), i1(), i1()
    init = np.array([cfg.master.counter_init, cfg.slave.counter_init], dtype=np.int64)
    trip_k = call_compiled(
        _gantry_kernel,
        TOPOLOGIES.index(topology),
        cfg.bus.latency_cycles,
        cmd,
        load,
        jit_s,
        rs,
        np.uint64(seed),
        consts,
        init,
        rig.counter.bits,
        rig.dac.range_v[0],
        rig.dac.lsb_v,
        rows,
        lag_m,
        cfg.beam.coupled,
        hs,
        new,
        seg_a,
        seg_b,
        cfg.beam.stiffness_v_per_count,
        cfg.beam.damping_v_s_per_count,
        sc,
        cfg.sync.warn_counts,
        cfg.sync.trip_counts,
        code,
        y,
        raw,
        ref,
        flags,
        pos,
        op,
        e_in,
        comp,
        level,
        *_scratch(int(lag_m.max()) + 2),
    )
    return GantryTrace(
        topology=topology,
        case=case,
        cycle_s=cfg.bus.cycle_s,
        command=cmd,
        ref=ref,
        y=y,
        counter=raw,
        position=pos,
        code=code,
        flags=flags,
        sync_error=y[:, 0] - y[:, 1],
        sync_op=op,
        sync_input=e_in,
        sync_comp=comp,
        sync_level=level,
        resets=rs.astype(bool),
        trip_cycle=int(trip_k),
        stop_bound_cycles=cfg.stop_bound_cycles,
    )


_MC_MAX = 1_000_000  # plant pairs of a Monte-Carlo run
MC_CHUNK = 64
"""Plant pairs per task of :func:`gantry_montecarlo` on an executor (about 80 ms of work)."""
MC_CLUSTER_MIN_PAIRS = 10_000
"""From this many plant pairs (about 12 s on one core) a Monte Carlo is worth an embedded
``LocalCluster`` (:func:`servotune.executor.open_executor`'s ``min_items``)."""


def compare_topologies(cfg: GantryConfig, *, seed: int = 0, montecarlo: int = 0) -> SyncComparison:
    """Every topology in every case (:data:`CASES`): max/RMS sync error, warnings, trips; and
    the margins of every loop over the plant set (:func:`~servotune.arch.gantry.margins.
    gantry_margins`).

    The checks: the deployed topology (``cfg.topology``) must not trip in any case, and every
    loop it runs must keep ``cfg.margins``' limits over the plant set (a failure names the
    loop, the plant case and the limit); with ``montecarlo`` > 0, no drawn plant pair may trip
    (:func:`gantry_montecarlo`, seeded by ``seed``).
    """
    n_runs = len(CASES) * len(TOPOLOGIES)  # every trace is kept
    check_memory(
        n_runs * cfg.n_cycles * _TRACE_BYTES_PER_CYCLE,
        f"comparing the gantry topologies over {cfg.seconds:g} s",
        f"{n_runs} runs × {cfg.n_cycles:,} cycles × {_TRACE_BYTES_PER_CYCLE} bytes",
    )
    rows, traces, failed = [], [], []
    design = gantry_shaper(cfg)
    cmd = gantry_command(cfg, cfg.n_cycles, design)
    for case in CASES:
        for topo in TOPOLOGIES:
            tr = simulate_gantry(cfg, topo, case=case, seed=seed, command=cmd)
            traces.append(tr)
            m = tr.metrics()
            rows.append(m)
            if topo == cfg.topology and m.tripped:
                failed.append(
                    f"sync trip in the {case} case at {m.trip_time_s:.3f} s "
                    f"(|sync error| >= {cfg.sync.trip_counts} counts)"
                )
    predicted = predicted_load_reduction(cfg) if not cfg.beam.coupled else None
    margins = gantry_margins(cfg)
    failed += margin_failures(margins, cfg.margins.limits)
    mc = gantry_montecarlo(cfg, montecarlo, seed=seed) if montecarlo else None
    if mc is not None and not mc.passed:
        k, n, *_ = mc.pass_fraction
        w = mc.worst
        drawn = ", ".join(f"{key.replace('_', ' ')} x{v:.3f}" for key, v in w.factors.items())
        failed.append(
            f"Monte Carlo: {n - k} of {n} plant pairs trip (first by size: {w.label}: {drawn})"
        )
    return SyncComparison(
        config=cfg,
        rows=tuple(rows),
        traces=tuple(traces),
        predicted=predicted,
        failed=tuple(failed),
        margins=margins,
        montecarlo=mc,
        shaper=tuple(design[1]),
    )


def gantry_montecarlo(
    cfg: GantryConfig,
    count: int,
    *,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
    executor: Executor | None = None,
    chunk_size: int = MC_CHUNK,
) -> GantryMonteCarlo:
    """Run the deployed topology in every case over ``count`` drawn plant pairs inside the
    drives' spreads (``[margins]``, or a drive's own; each drive's gain and tau independently
    uniform in ``× [1 − s, 1 + s]``), ``cfg``'s resolved gains kept, on the bit-true gantry
    loop. A pair passes if the monitor trips in no case; the same config, count and seed give
    the same result, whatever the ``executor`` (default in-process; e.g. a Dask cluster,
    :mod:`servotune.executor`) and the ``chunk_size`` (plant pairs per task): each pair's
    factors are drawn up front and its noise is seeded by its index.

    Raises
    ------
    ConfigError
        If ``count`` is not in 1..1,000,000 (a ``ValueError``).
    """
    if not isinstance(count, int) or not 1 <= count <= _MC_MAX:
        raise ConfigError(
            f"the Monte-Carlo count must be an integer in 1..{_MC_MAX:,} [plant "
            f"pairs], got {count!r}"
        )
    check_seed(seed)
    say = progress or (lambda _msg: None)
    m = cfg.margins
    rng = np.random.default_rng([seed, 0x67616E74])  # a stream of its own ("gant")
    draws = rng.uniform(-1.0, 1.0, (count, 4))
    spreads = np.array([*m.spreads(cfg.master), *m.spreads(cfg.slave)])
    factors = 1.0 + draws * spreads
    chunks = [(a, factors[a:b]) for a, b in chunk_bounds(count, chunk_size)]
    ex = InProcessExecutor() if executor is None else executor
    parts = ex.map(
        _montecarlo_chunk,
        chunks,
        shared=(cfg, seed),
        done=lambda k: say(f"sync: Monte Carlo {min(count, k * chunk_size)}/{count} ({ex.name})"),
    )
    return GantryMonteCarlo(seed=seed, variants=tuple(v for part in parts for v in part))


def _montecarlo_chunk(
    chunk: tuple[int, np.ndarray], shared: tuple[GantryConfig, int]
) -> list[GantryVariant]:
    """Plant pairs ``start, start + 1, …`` of :func:`gantry_montecarlo` from their drawn
    factors (an executor's task): each depends only on the config, the seed and its index."""
    start, factors = chunk
    cfg, seed = shared
    cmd = gantry_command(cfg, cfg.n_cycles)  # the nominal design's shaper for every pair
    out = []
    for j, (fmg, fmt, fsg, fst) in enumerate(factors.tolist()):
        i = start + j
        plants = {}
        for name, fg, ft in (("master", fmg, fmt), ("slave", fsg, fst)):
            p = getattr(cfg, name).plant
            changes = {"gain_cps_per_v": p.gain_cps_per_v * fg, "tau_s": p.tau_s * ft}
            if p.gain_neg_cps_per_v is not None:
                changes["gain_neg_cps_per_v"] = p.gain_neg_cps_per_v * fg
            plants[name] = replace(getattr(cfg, name), plant=replace(p, **changes))
        c = replace(cfg, **plants)
        worst, tripped = 0.0, False
        for case in CASES:
            r = simulate_gantry(c, case=case, seed=seed + 1 + i, command=cmd).metrics()
            worst = max(worst, r.max_sync_error_counts)
            tripped |= r.tripped
        out.append(
            GantryVariant(
                index=i,
                factors={
                    "master_gain": float(fmg),
                    "master_tau": float(fmt),
                    "slave_gain": float(fsg),
                    "slave_tau": float(fst),
                },
                max_sync_error_counts=worst,
                tripped=tripped,
            )
        )
    return out
