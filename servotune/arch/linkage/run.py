"""Run a linkage: the axes' quantised gains, the simulation, the checks during motion.

A runner only runs: it takes the gains the config holds (or the controllers given) and tunes
nothing; the caller resolves the gains a file leaves out first
(:func:`servotune.arch.linkage.synthesis.resolve_gains`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from servotune._numba_cache import call_compiled
from servotune.arch.linkage.checks import (
    BusFigures,
    Check,
    LinkageCheckError,
    bus_figures,
    check_linkage,
    recommended_resync_interval_s,
)
from servotune.arch.linkage.config import LinkageConfig
from servotune.arch.linkage.kernel import (
    A_FLAGS,
    A_SAT,
    A_T_FAULT,
    I_INIT,
    I_LAG,
    I_RING,
    NA,
    NE,
    NI,
    NS,
    NT,
    NTF,
    S_MAX,
    S_MIN,
    S_OVER,
    S_RESYNC,
    S_SKIP,
    S_T_OVER,
    S_T_UNDER,
    S_TICKS,
    S_UNDER,
    T_CODE,
    T_POS,
    T_REF,
    T_SPD,
    T_Y,
    linkage_kernel,
)
from servotune.arch.linkage.path import (
    TICK_BYTES,
    TICK_BYTES_PER_AXIS,
    TRACE_BYTES_PER_AXIS,
    Interpolation,
    contour_distances,
    interpolate,
)
from servotune.arch.linkage.result import (
    ArcResult,
    AxisResult,
    AxisTrace,
    CpuResult,
    LinkageResult,
    optional_time,
)
from servotune.budget import check_memory, format_count
from servotune.errors import ConfigError
from servotune.laws.axis import FLAG_COUNTER_FAULT, FLAG_FOLLOWING_ERROR, AxisController
from servotune.plant import NROW, plant_row
from servotune.validate import check_integer, check_number, check_seed, show_value

__all__ = ["axis_controllers", "run_linkage"]


def axis_controllers(config: LinkageConfig) -> dict[str, AxisController]:
    """The quantised constants each axis's slave runs: its lock gain, its PI gains at the
    linkage's nominal ``period_s`` (``Ki·T`` folded in), its following-error limit and its
    output filters (:meth:`~servotune.arch.linkage.config.LinkageConfig.axis_filters`).

    Parameters
    ----------
    config : LinkageConfig
        Every axis with its gains (:func:`~servotune.arch.linkage.synthesis.resolve_gains`
        fills in those a file leaves out).

    Returns
    -------
    dict of str to AxisController
        By axis name, in column order.

    Raises
    ------
    ConfigError
        If an axis has no gains (one line naming it).
    """
    out = {}
    for a in config.axes:
        gains = a.gains
        if gains is None:
            raise ConfigError(
                f"axis {show_value(a.name)} has no PI gains: give them in the linkage file or "
                f"resolve them first (servotune.arch.linkage.resolve_gains)"
            )
        out[a.name] = AxisController.from_gains(
            lock_gain_codes_per_count=a.lock_gain_codes_per_count,
            task_gains=gains,
            period_s=config.period_s,
            following_error_limit_counts=a.following_error_limit_counts,
            filters=config.axis_filters(a.name),
        )
    return out


def _controllers(
    config: LinkageConfig, given: Mapping[str, AxisController]
) -> dict[str, AxisController]:
    """``given`` checked to hold one :class:`AxisController` per axis of ``config``."""
    names = set(config.axis_names)
    bad = sorted(set(given) - names)
    if bad:
        raise ConfigError(
            f"controllers for unknown axis {show_value(bad[0])}; axes: {list(config.axis_names)}"
        )
    missing = [a for a in config.axis_names if a not in given]
    if missing:
        raise ConfigError(f"controllers: no controller for axis {show_value(missing[0])}")
    for name, c in given.items():
        if not isinstance(c, AxisController):
            raise ConfigError(
                f"controllers.{name} must be an AxisController, got {type(c).__name__}"
            )
    return dict(given)


def _pi_values(c: AxisController, period: float) -> tuple[float, float]:
    """``kp`` [codes/count] and ``ki`` [codes/(count·s)] a controller's constants represent."""
    task = c.task
    if task is None:
        return 0.0, 0.0
    return task.kp.value, task.ki_t.value / period


def run_linkage(
    config: LinkageConfig,
    *,
    seconds: float | None = None,
    seed: int = 0,
    trace: bool = False,
    controllers: Mapping[str, AxisController] | None = None,
    resync_ticks: int | None = None,
) -> LinkageResult:
    """Simulate the linkage: master interpolation and broadcast, slave queues, clocks, loops.

    Event-driven in master time (see :mod:`servotune.arch.linkage` for the timing model and the
    sync semantics): block arrivals, every slave's ticks by its own clock, syncs, measurements at
    the master ticks. Each slave tick runs the axis tick of :mod:`servotune.sim.tick` for each
    of its axes (counter latch and read, the runtime's integer law
    :func:`~servotune.laws.axis.axis_control` in task mode, D/A, hold), the plants moving
    exactly over the CPU's ticks (:func:`~servotune.plant.advance_tick` on a row built for the
    CPU's nominal tick, :func:`~servotune.plant.advance_span` over a tick a sync moved).

    Parameters
    ----------
    config : LinkageConfig
        Every axis with its PI gains, unless ``controllers`` are given: a runner tunes
        nothing (:func:`~servotune.arch.linkage.synthesis.resolve_gains` fills in the gains a
        file leaves out, and overrides them).
    seconds : float, optional
        Simulated time [s]; default the path's duration plus ``settle_s``. After the path the
        master keeps broadcasting its end point.
    seed : int
        Seed of the encoder noise, in 0 … 2**64 − 1: one splitmix64 stream for the run
        (:func:`~servotune.sim.tick.draw_noise`), drawn at each read of an axis with noise, in
        event order; same config and seed → same result.
    trace : bool
        Also record every axis's ticks (:attr:`LinkageResult.traces`: reference, D/A code,
        unwrapped and true position, speed per CPU tick; 40 more bytes per tick and axis) and
        each CPU's queue events in order (:attr:`CpuResult.events`: prefill blocks, syncs,
        ticks, block arrivals; 56 more bytes per tick and CPU).
    controllers : mapping of str to AxisController, optional
        The quantised constants each axis runs, by axis name (a plan's, exactly as the runtime
        holds them: nothing is re-quantised); instead of the config's gains.
    resync_ticks : int, optional
        Master ticks between sync broadcasts (0: only the sync at motion start), instead of
        ``config.clock.resync_interval_s`` rounded to whole ticks (a plan's interval).

    Returns
    -------
    LinkageResult
        ``passed`` is False if an underrun, an overrun or a fault occurred during motion.

    Raises
    ------
    LinkageCheckError
        If a check before motion fails (:func:`check_linkage`): nothing is simulated.
    ConfigError
        If an axis has no gains and no ``controllers`` are given (one line naming the axis
        and :func:`~servotune.arch.linkage.synthesis.resolve_gains`), ``seconds`` is not a
        positive number, ``seed`` is not an integer in range, ``controllers`` does not hold
        one controller per axis, or ``resync_ticks`` is not an integer >= 0.
    """
    controllers, shown = _run_controllers(config, controllers)
    if resync_ticks is not None:
        check_integer("resync_ticks", resync_ticks, "ticks", hi=2**40, error=ConfigError)
    period = config.period_s
    ip = interpolate(config)
    pre = check_linkage(config, ip)
    failed = tuple(c for c in pre if not c.passed)
    if failed:
        raise LinkageCheckError(failed)
    if seconds is None:
        seconds = ip.duration_s + config.settle_s
    check_number("seconds", seconds, "s", strict=True, hi=1e6, error=ConfigError)
    seed = check_seed(seed, error=ConfigError)
    n_ticks = _run_ticks(config, seconds, trace)
    resync_s = config.clock.resync_interval_s
    if resync_ticks is not None:
        resync_s = resync_ticks * period
    elif resync_s:
        resync_ticks = max(1, round(resync_s / period))
    else:
        resync_ticks = 0
    sim = _simulate(config, ip, controllers, n_ticks, seed, resync_ticks, trace)
    cpus = _cpu_results(config, sim, trace)
    traces = _axis_traces(config, sim, cpus) if trace else None
    command = sim.cmd[:n_ticks]
    err = command - sim.actual
    axes = _axis_results(config, sim, err, shown)
    contour = call_compiled(contour_distances, sim.path_pad, sim.actual, sim.move_pad, ip.move_axes)
    arcs = _arc_results(config, ip, sim.actual, n_ticks)
    try:
        rec: float | None = recommended_resync_interval_s(config)
    except LinkageCheckError:
        rec = None
    checks = list(pre) + _motion_checks(config, cpus, axes, err, rec, resync_s)
    return LinkageResult(
        name=config.name,
        seed=int(seed),
        period_s=period,
        bus=sim.figs,
        resync_interval_s=resync_ticks * period,
        recommended_resync_interval_s=rec,
        cpus=tuple(cpus),
        axes=tuple(axes),
        arcs=tuple(arcs),
        contour_max_counts=float(contour.max()),
        contour_rms_counts=float(np.sqrt(np.mean(contour**2))),
        checks=tuple(checks),
        interpolation=ip,
        time_s=np.arange(n_ticks, dtype=np.int64) * period,
        command_counts=command,
        path_counts=sim.path_pad[:n_ticks],
        actual_counts=sim.actual,
        contour_counts=contour,
        traces=None if traces is None else tuple(traces),
    )


def _run_ticks(config: LinkageConfig, seconds: float, trace: bool) -> int:
    """Master ticks of a run of ``seconds``, refused if its arrays exceed the memory budget."""
    per_tick = (
        config.n_axes * (TICK_BYTES_PER_AXIS + (TRACE_BYTES_PER_AXIS if trace else 0))
        + len(config.cpus) * (3 + (NE if trace else 0)) * 8
        + TICK_BYTES
    )
    ticks_f = seconds / config.period_s
    check_memory(
        ticks_f * per_tick,
        f"linkage {config.name!r}: simulating {seconds:g} s",
        f"{format_count(ticks_f)} ticks × {per_tick} bytes",
    )
    return max(1, round(ticks_f))


def _run_controllers(
    config: LinkageConfig, controllers: Mapping[str, AxisController] | None
) -> tuple[Mapping[str, AxisController], dict[str, tuple[float, float, bool]]]:
    """What each axis of a run runs, and its ``(kp, ki, tuned)`` as the result shows them.

    ``controllers`` (checked) run as given. Otherwise the config's gains, quantised by
    :func:`axis_controllers` (an axis without gains is refused: nothing is tuned here), shown
    as tuned where :func:`~servotune.arch.linkage.synthesis.resolve_gains` tuned them.
    """
    if controllers is None:
        controllers = axis_controllers(config)  # refuses an axis without gains
        shown = {
            a.name: (g.kp, g.ki, a.gains_tuned) for a in config.axes if (g := a.gains) is not None
        }
        return controllers, shown
    controllers = _controllers(config, controllers)
    period = config.period_s
    shown = {n: (*_pi_values(c, period), False) for n, c in controllers.items()}
    return controllers, shown


@dataclass(frozen=True, slots=True, kw_only=True)
class _Simulated:
    """The kernel's inputs a run's results read and the arrays it filled
    (:func:`_simulate`; the layouts are :mod:`servotune.arch.linkage.kernel`'s)."""

    figs: BusFigures
    cmd: np.ndarray  # commands broadcast, the path's end held after it (ticks, axes)
    path_pad: np.ndarray  # programmed positions, padded the same way
    move_pad: np.ndarray  # move of each padded row
    ax_cpu: np.ndarray  # CPU index of each axis
    n_rec: int  # rows of the per-CPU tick records
    actual: np.ndarray
    q_time: np.ndarray
    q_level: np.ndarray
    q_index: np.ndarray
    cpu_stats: np.ndarray
    ax_stats: np.ndarray
    tr_i: np.ndarray
    tr_f: np.ndarray
    ev: np.ndarray
    ev_count: np.ndarray


def _plant_rows(
    config: LinkageConfig, eps: np.ndarray, ax_cpu: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Each axis's plant row for its CPU's nominal tick ``T/(1 + ε)`` (its tick in master
    time) and its integer state (lag, ring size, counter's initial value).

    Raises
    ------
    ConfigError
        An axis's plant has flexible modes (the linkage simulates rigid plants).
    """
    rig = config.rig
    plant_rows = np.zeros((config.n_axes, NROW))
    ints = np.zeros((config.n_axes, NI), dtype=np.int64)
    for i, a in enumerate(config.axes):
        if a.plant.modes:
            raise ConfigError(
                f"axis {a.name!r}: the linkage simulates rigid plants; its plant has "
                f"{len(a.plant.modes)} mode(s) (docs/frf.md): run it in the single-rig engine"
            )
        tick_s = config.period_s / (1.0 + eps[ax_cpu[i]])
        plant_rows[i], m = plant_row(a.plant, tick_s, rig.timer.compute_s, rig.counts_per_rev)
        ints[i, I_LAG], ints[i, I_RING], ints[i, I_INIT] = m, m + 2, a.counter_init
    return plant_rows, ints


def _simulate(
    config: LinkageConfig,
    ip: Interpolation,
    controllers: Mapping[str, AxisController],
    n_ticks: int,
    seed: int,
    resync_ticks: int,
    trace: bool,
) -> _Simulated:
    """Run the linkage kernel over ``n_ticks`` master ticks: its inputs built from the config
    and the interpolation, its records sized for every tick, block and sync of each CPU."""
    period = config.period_s
    rig, bus = config.rig, config.bus
    n_ax, n_cpu = config.n_axes, len(config.cpus)
    eps = np.array([c.clock_ppm * 1e-6 for c in config.cpus])
    drift_ticks = math.ceil(float(np.max(np.abs(eps))) * n_ticks)
    # commands: the path, then its end held, as far as any slave may ask
    n_cmd = n_ticks + drift_ticks + (bus.prefill_blocks + 2) * bus.block_size + 16
    rows = np.minimum(np.arange(n_cmd, dtype=np.int64), ip.n_ticks - 1)
    cmd = np.ascontiguousarray(ip.commands[rows])
    path_pad = np.ascontiguousarray(ip.positions[rows])
    move_pad = ip.move_of_tick[rows]
    cpu_index = {c.name: i for i, c in enumerate(config.cpus)}
    ax_cpu = np.array([cpu_index[config.cpu_of(a.name).name] for a in config.axes])
    plant_rows, ints = _plant_rows(config, eps, ax_cpu)
    consts = np.stack(
        [
            controllers[a.name].consts(
                counter_bits=rig.counter.bits, dac_bits=rig.dac.bits, dac_zero=rig.dac.zero_code
            )
            for a in config.axes
        ]
    )
    n_rec = n_ticks + drift_ticks + 16
    n_tr = n_rec if trace else 0
    # the event log: every tick, block arrival (prefill included) and sync of each CPU
    n_syncs = n_ticks // resync_ticks + 2 if resync_ticks else 1
    n_ev = n_rec + n_ticks // bus.block_size + bus.prefill_blocks + 2 + n_syncs if trace else 0
    sim = _Simulated(
        figs=bus_figures(config),
        cmd=cmd,
        path_pad=path_pad,
        move_pad=move_pad,
        ax_cpu=ax_cpu,
        n_rec=n_rec,
        actual=np.zeros((n_ticks, n_ax)),
        q_time=np.zeros((n_cpu, n_rec)),
        q_level=np.zeros((n_cpu, n_rec), dtype=np.int64),
        q_index=np.zeros((n_cpu, n_rec), dtype=np.int64),
        cpu_stats=np.zeros((n_cpu, NS)),
        ax_stats=np.zeros((n_ax, NA)),
        tr_i=np.zeros((NT, n_tr, n_ax), dtype=np.int64),
        tr_f=np.zeros((NTF, n_tr, n_ax)),
        ev=np.zeros((n_cpu, n_ev, NE), dtype=np.int64),
        ev_count=np.zeros(n_cpu, dtype=np.int64),
    )
    call_compiled(
        linkage_kernel,
        n_ticks,
        period,
        cmd,
        ax_cpu,
        plant_rows,
        ints,
        consts,
        np.uint64(seed),
        eps,
        np.array([c.queue_depth for c in config.cpus], dtype=np.int64),
        bus.block_size,
        bus.prefill_blocks,
        sim.figs.frame_s,
        resync_ticks,
        rig.counter.bits,
        bool(rig.counter.latched),
        float(rig.counter.read_skew_s),
        float(rig.dac.range_v[0]),
        rig.dac.lsb_v,
        sim.actual,
        sim.q_time,
        sim.q_level,
        sim.q_index,
        sim.cpu_stats,
        sim.ax_stats,
        sim.tr_i,
        sim.tr_f,
        sim.ev,
        sim.ev_count,
    )
    if trace and np.any(sim.ev_count > n_ev):  # sized above for every event: a bug if not
        raise RuntimeError(f"linkage event log overflow: {sim.ev_count.tolist()} > {n_ev}")
    return sim


def _cpu_results(config: LinkageConfig, sim: _Simulated, trace: bool) -> list[CpuResult]:
    """Each CPU's queue record and counts (its events with ``trace``)."""
    cpus = []
    stats = sim.cpu_stats
    for s, c in enumerate(config.cpus):
        n = min(int(stats[s, S_TICKS]), sim.n_rec)
        cpus.append(
            CpuResult(
                name=c.name,
                axes=c.axes,
                clock_ppm=float(c.clock_ppm),
                queue_depth=c.queue_depth,
                tick_time_s=sim.q_time[s, :n].copy(),
                queue_level=sim.q_level[s, :n].copy(),
                tick_index=sim.q_index[s, :n].copy(),
                underruns=int(stats[s, S_UNDER]),
                first_underrun_s=optional_time(stats[s, S_T_UNDER]),
                overruns=int(stats[s, S_OVER]),
                first_overrun_s=optional_time(stats[s, S_T_OVER]),
                min_level=int(stats[s, S_MIN]) if n else 0,
                max_level=int(stats[s, S_MAX]),
                skipped=int(stats[s, S_SKIP]),
                resyncs=int(stats[s, S_RESYNC]),
                events=sim.ev[s, : sim.ev_count[s]].copy() if trace else None,
            )
        )
    return cpus


def _axis_traces(config: LinkageConfig, sim: _Simulated, cpus: list[CpuResult]) -> list[AxisTrace]:
    """Each axis's ticks as its CPU ran them (``trace=True``)."""
    traces = []
    for i, a in enumerate(config.axes):
        n = cpus[sim.ax_cpu[i]].tick_time_s.size
        traces.append(
            AxisTrace(
                name=a.name,
                cpu=cpus[sim.ax_cpu[i]].name,
                ref_counts=sim.tr_i[T_REF, :n, i].copy(),
                code=sim.tr_i[T_CODE, :n, i].copy(),
                pos_counts=sim.tr_i[T_Y, :n, i].copy(),
                true_pos_counts=sim.tr_f[T_POS, :n, i].copy(),
                speed_cps=sim.tr_f[T_SPD, :n, i].copy(),
            )
        )
    return traces


def _axis_results(
    config: LinkageConfig,
    sim: _Simulated,
    err: np.ndarray,
    shown: Mapping[str, tuple[float, float, bool]],
) -> list[AxisResult]:
    """Each axis's gains, tracking error (``err``: command − actual), saturation and fault."""
    axes = []
    for i, a in enumerate(config.axes):
        flags = int(sim.ax_stats[i, A_FLAGS])
        fault = None
        if flags & FLAG_FOLLOWING_ERROR:
            fault = "following_error"
        elif flags & FLAG_COUNTER_FAULT:
            fault = "counter"
        kp, ki, tuned = shown[a.name]
        axes.append(
            AxisResult(
                name=a.name,
                cpu=config.cpu_of(a.name).name,
                kp=float(kp),
                ki=float(ki),
                tuned=tuned,
                max_abs_err_counts=float(np.max(np.abs(err[:, i]))),
                rms_err_counts=float(np.sqrt(np.mean(err[:, i] ** 2))),
                saturated_ticks=int(sim.ax_stats[i, A_SAT]),
                fault=fault,
                first_fault_s=optional_time(sim.ax_stats[i, A_T_FAULT]),
            )
        )
    return axes


def _arc_results(
    config: LinkageConfig, ip: Interpolation, actual: np.ndarray, n_ticks: int
) -> list[ArcResult]:
    """The circular test of each arc run (at least partly) within the ``n_ticks`` simulated:
    the radial deviation of the actual points, over the cruise and over the whole arc."""
    arcs = []
    for g in ip.arcs:
        k0 = ip.move_start_tick(g.move)
        k1 = min(ip.move_ends[g.move], n_ticks - 1)
        if k1 <= k0:
            continue
        i, j = g.plane
        dx = actual[k0 : k1 + 1, i] - g.centre[0]
        dy = actual[k0 : k1 + 1, j] - g.centre[1]
        dev = np.hypot(dx, dy) - g.radius_counts
        ticks = np.arange(k0, k1 + 1)
        cruise = (ticks >= g.cruise_ticks[0]) & (ticks <= g.cruise_ticks[1])
        dc = dev[cruise] if np.any(cruise) else dev
        arcs.append(
            ArcResult(
                move=g.move,
                plane=(config.axis_names[i], config.axis_names[j]),
                centre=g.centre,
                radius_counts=g.radius_counts,
                angle_rad=np.arctan2(dy, dx),
                radial_dev_counts=dev,
                cruise=cruise,
                max_dev_counts=float(dc.max()),
                min_dev_counts=float(dc.min()),
                circularity_counts=float(dc.max() - dc.min()),
                circularity_whole_counts=float(dev.max() - dev.min()),
            )
        )
    return arcs


def _motion_checks(
    config: LinkageConfig,
    cpus: list[CpuResult],
    axes: list[AxisResult],
    err: np.ndarray,
    rec: float | None,
    resync: float,
) -> list[Check]:
    """Underrun, overrun and fault checks of a run, with their reasons (``resync``: the
    interval run [s])."""
    f = bus_figures(config)
    advice = (
        f"resync every <= {rec:g} s (recommended_resync_interval_s)"
        if rec
        else "resync more often or give the queue more margin"
    )
    out: list[Check] = []
    for c in cpus:
        clock = f"its clock runs {c.clock_ppm:+g} ppm"
        sync = f"resync every {resync:g} s" if resync else "no resync after the start"
        if c.underruns == 0:
            out.append(
                Check(
                    name=f"underrun:{c.name}",
                    passed=True,
                    detail=(
                        f"cpu {c.name}: no underrun; worst queue level before a pop {c.min_level} "
                        f"setpoints"
                    ),
                )
            )
        else:
            lead = f.lead_s
            eps = c.clock_ppm * 1e-6
            if c.overruns:
                expect = ", commands lost to the overrun"
            elif eps > 0:
                expect = f", as expected after about lead/ε = {lead / eps:.1f} s"
            else:
                expect = ""
            out.append(
                Check(
                    name=f"underrun:{c.name}",
                    passed=False,
                    detail=(
                        f"underrun on cpu {c.name}: {c.underruns} ticks found no command, "
                        f"the first at {c.first_underrun_s:.3f} s ({clock}, {sync}; a block "
                        f"arrives {lead * 1e3:.2f} ms before it is needed{expect}) — {advice}"
                    ),
                )
            )
        fits = c.overruns == 0
        out.append(
            Check(
                name=f"overrun:{c.name}",
                passed=fits,
                detail=(
                    f"cpu {c.name}: no overrun; highest queue level {c.max_level} of "
                    f"{c.queue_depth} setpoints"
                    if fits
                    else f"overrun on cpu {c.name}: {c.overruns} blocks did not fit its "
                    f"{c.queue_depth}-setpoint queue, the first at {c.first_overrun_s:.3f} s "
                    f"({clock}, {sync}) — {advice}"
                ),
            )
        )
    for i, a in enumerate(axes):
        limit = config.axes[i].following_error_limit_counts
        if a.fault is None:
            lim = f" < limit {limit}" if limit else ""
            out.append(
                Check(
                    name=f"fault:{a.name}",
                    passed=True,
                    detail=(
                        f"axis {a.name}: no fault (largest tracking error "
                        f"{a.max_abs_err_counts:.0f} counts{lim})"
                    ),
                )
            )
        elif a.fault == "following_error":
            out.append(
                Check(
                    name=f"fault:{a.name}",
                    passed=False,
                    detail=(
                        f"following-error trip on axis {a.name} at {a.first_fault_s:.3f} s (limit "
                        f"{limit} counts; the axis went to 0 V) — lower the feed or acceleration, "
                        f"raise the gains or the limit"
                    ),
                )
            )
        else:
            out.append(
                Check(
                    name=f"fault:{a.name}",
                    passed=False,
                    detail=(
                        f"counter fault on axis {a.name} at {a.first_fault_s:.3f} s (the high-byte "
                        f"unwrap saw an impossible jump)"
                    ),
                )
            )
    return out
