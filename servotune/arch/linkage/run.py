"""Run a linkage: the axes' gains (given or tuned), the simulation, the checks during motion."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from servotune.arch.linkage.checks import (
    Check,
    LinkageCheckError,
    bus_figures,
    check_linkage,
    recommended_resync_interval_s,
)
from servotune.arch.linkage.config import LinkageConfig
from servotune.arch.linkage.kernel import (
    _A_FLAGS,
    _A_SAT,
    _A_T_FAULT,
    _NA,
    _NS,
    _S_MAX,
    _S_MIN,
    _S_OVER,
    _S_RESYNC,
    _S_SKIP,
    _S_T_OVER,
    _S_T_UNDER,
    _S_TICKS,
    _S_UNDER,
    _kernel,
)
from servotune.arch.linkage.path import _TICK_BYTES, _TICK_BYTES_PER_AXIS, _contour, interpolate
from servotune.arch.linkage.result import (
    ArcResult,
    AxisResult,
    CpuResult,
    LinkageResult,
    _optional_time,
)
from servotune.budget import check_memory, format_count
from servotune.errors import ConfigError
from servotune.laws.axis import FLAG_COUNTER_FAULT, FLAG_FOLLOWING_ERROR, AxisController
from servotune.laws.pi import PIGains
from servotune.tune.pi import DEFAULT_TARGETS
from servotune.validate import check_number, show_value

__all__ = [
    "TUNE_TARGETS",
    "axis_gains",
    "run_linkage",
]

TUNE_TARGETS = DEFAULT_TARGETS
"""Robustness targets of :func:`~servotune.tune.pi.tune_pi` for axes without explicit gains."""


def axis_gains(
    config: LinkageConfig, given: Mapping[str, PIGains] | None = None
) -> dict[str, tuple[PIGains, bool]]:
    """PI gains of every axis: ``given``, else the file's, else tuned.

    An axis without gains is tuned with :func:`~servotune.tune.pi.tune_pi` at the linkage's
    ``period_s``, the rig's ``compute_s`` and D/A step, for :data:`TUNE_TARGETS` (phase margin
    50°, gain margin 8 dB, max sensitivity 1.6); about a second per axis. Nothing is cached.

    Parameters
    ----------
    config : LinkageConfig
    given : mapping of str to PIGains, optional
        Gains by axis name that override the file's.

    Returns
    -------
    dict
        Axis name → (gains [codes/count], [codes/(count·s)]; True if tuned).

    Raises
    ------
    ConfigError
        If ``given`` names an axis that does not exist.
    """
    given = dict(given or {})
    bad = sorted(set(given) - set(config.axis_names))
    if bad:
        raise ConfigError(
            f"gains for unknown axis {show_value(bad[0])}; axes: {list(config.axis_names)}"
        )
    out: dict[str, tuple[PIGains, bool]] = {}
    for a in config.axes:
        g = given.get(a.name, a.gains)
        if g is not None:
            out[a.name] = (g, False)
            continue
        from servotune.tune.pi import tune_pi

        r = tune_pi(a.plant, period_s=config.period_s, compute_s=config.rig.timer.compute_s,
                    lsb_v=config.rig.dac.lsb_v, **TUNE_TARGETS)  # fmt: skip
        out[a.name] = (r.gains, True)
    return out


def run_linkage(
    config: LinkageConfig,
    *,
    seconds: float | None = None,
    seed: int = 0,
    gains: Mapping[str, PIGains] | None = None,
) -> LinkageResult:
    """Simulate the linkage: master interpolation and broadcast, slave queues, clocks, loops.

    Event-driven in master time (see :mod:`servotune.arch.linkage` for the timing model and the
    sync semantics): block arrivals, every slave's ticks by its own clock, syncs, measurements at
    the master ticks. Each slave tick runs the runtime's integer law per axis
    (:func:`~servotune.laws.axis.axis_read`, :func:`~servotune.laws.axis.axis_control`) and
    the plants move exactly between D/A writes (:func:`~servotune.plant.advance`).

    Parameters
    ----------
    config : LinkageConfig
    seconds : float, optional
        Simulated time [s]; default the path's duration plus ``settle_s``. After the path the
        master keeps broadcasting its end point.
    seed : int
        Seed of the encoder noise (a numpy Generator); same config and seed → same result.
    gains : mapping of str to PIGains, optional
        Gains overriding the file's (and tuning) per axis name.

    Returns
    -------
    LinkageResult
        ``passed`` is False if an underrun, an overrun or a fault occurred during motion.

    Raises
    ------
    LinkageCheckError
        If a check before motion fails (:func:`check_linkage`): nothing is simulated.
    ConfigError
        If ``seconds`` is not a positive number, or a gain is unknown.
    """
    period = config.period_s
    ip = interpolate(config)
    pre = check_linkage(config, ip)
    failed = tuple(c for c in pre if not c.passed)
    if failed:
        raise LinkageCheckError(failed)
    if seconds is None:
        seconds = ip.duration_s + config.settle_s
    check_number("seconds", seconds, "s", strict=True, hi=1e6, error=ConfigError)
    per_tick = config.n_axes * _TICK_BYTES_PER_AXIS + len(config.cpus) * 3 * 8 + _TICK_BYTES
    ticks_f = seconds / period
    check_memory(
        ticks_f * per_tick,
        f"linkage {config.name!r}: simulating {seconds:g} s",
        f"{format_count(ticks_f)} ticks × {per_tick} bytes",
    )
    n_ticks = max(1, round(ticks_f))
    if resync := config.clock.resync_interval_s:
        resync_ticks = max(1, round(resync / period))
    else:
        resync_ticks = 0
    gains_used = axis_gains(config, gains)
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
    cpr = rig.counts_per_rev
    pf = np.array([[a.plant.gain_cps_per_v, a.plant.tau_s, a.plant.offset_v, a.plant.coulomb_v,
                    a.plant.max_speed_cps(cpr), rig.timer.compute_s + a.plant.delay_s]
                   for a in config.axes])  # fmt: skip
    consts = np.stack(
        [
            AxisController.from_gains(
                lock_gain_codes_per_count=a.lock_gain_codes_per_count,
                task_gains=gains_used[a.name][0],
                period_s=period,
                following_error_limit_counts=a.following_error_limit_counts,
            ).consts(
                counter_bits=rig.counter.bits, dac_bits=rig.dac.bits, dac_zero=rig.dac.zero_code
            )
            for a in config.axes
        ]
    )
    n_rec = n_ticks + drift_ticks + 16
    rng = np.random.default_rng(seed)
    noise = (
        rng.standard_normal((n_ax, n_rec))
        * np.array([a.plant.noise_counts for a in config.axes])[:, None]
    )
    figs = bus_figures(config)
    actual = np.zeros((n_ticks, n_ax))
    q_time = np.zeros((n_cpu, n_rec))
    q_level = np.zeros((n_cpu, n_rec), dtype=np.int64)
    q_index = np.zeros((n_cpu, n_rec), dtype=np.int64)
    cpu_stats = np.zeros((n_cpu, _NS))
    ax_stats = np.zeros((n_ax, _NA))
    _kernel(
        n_ticks, period, cmd, ax_cpu, pf, consts,
        np.array([a.counter_init for a in config.axes], dtype=np.int64), noise, eps,
        np.array([c.queue_depth for c in config.cpus], dtype=np.int64),
        bus.block_size, bus.prefill_blocks, figs["frame_s"], resync_ticks, rig.counter.bits,
        float(rig.dac.range_v[0]), rig.dac.lsb_v,
        actual, q_time, q_level, q_index, cpu_stats, ax_stats,
    )  # fmt: skip

    # per CPU
    cpus = []
    for s, c in enumerate(config.cpus):
        n = min(int(cpu_stats[s, _S_TICKS]), n_rec)
        cpus.append(CpuResult(
            name=c.name, axes=c.axes, clock_ppm=float(c.clock_ppm), queue_depth=c.queue_depth,
            tick_time_s=q_time[s, :n].copy(), queue_level=q_level[s, :n].copy(),
            tick_index=q_index[s, :n].copy(),
            underruns=int(cpu_stats[s, _S_UNDER]),
            first_underrun_s=_optional_time(cpu_stats[s, _S_T_UNDER]),
            overruns=int(cpu_stats[s, _S_OVER]),
            first_overrun_s=_optional_time(cpu_stats[s, _S_T_OVER]),
            min_level=int(cpu_stats[s, _S_MIN]) if n else 0,
            max_level=int(cpu_stats[s, _S_MAX]),
            skipped=int(cpu_stats[s, _S_SKIP]), resyncs=int(cpu_stats[s, _S_RESYNC]),
        ))  # fmt: skip
    # per axis
    command = cmd[:n_ticks]
    err = command - actual
    axes = []
    for i, a in enumerate(config.axes):
        flags = int(ax_stats[i, _A_FLAGS])
        fault = None
        if flags & FLAG_FOLLOWING_ERROR:
            fault = "following_error"
        elif flags & FLAG_COUNTER_FAULT:
            fault = "counter"
        g, was_tuned = gains_used[a.name]
        axes.append(AxisResult(
            name=a.name, cpu=config.cpu_of(a.name).name, kp=float(g.kp), ki=float(g.ki),
            tuned=was_tuned, max_abs_err_counts=float(np.max(np.abs(err[:, i]))),
            rms_err_counts=float(np.sqrt(np.mean(err[:, i] ** 2))),
            saturated_ticks=int(ax_stats[i, _A_SAT]), fault=fault,
            first_fault_s=_optional_time(ax_stats[i, _A_T_FAULT]),
        ))  # fmt: skip
    # contour and circular tests
    contour = _contour(path_pad, actual, move_pad, ip.move_axes)
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
        arcs.append(ArcResult(
            move=g.move, plane=(config.axis_names[i], config.axis_names[j]), centre=g.centre,
            radius_counts=g.radius_counts, angle_rad=np.arctan2(dy, dx), radial_dev_counts=dev,
            cruise=cruise, max_dev_counts=float(dc.max()), min_dev_counts=float(dc.min()),
            circularity_counts=float(dc.max() - dc.min()),
            circularity_whole_counts=float(dev.max() - dev.min()),
        ))  # fmt: skip
    try:
        rec: float | None = recommended_resync_interval_s(config)
    except LinkageCheckError:
        rec = None
    checks = list(pre) + _motion_checks(config, cpus, axes, err, rec)
    return LinkageResult(
        name=config.name, seed=int(seed), period_s=period, bus=figs,
        resync_interval_s=resync_ticks * period, recommended_resync_interval_s=rec,
        cpus=tuple(cpus), axes=tuple(axes), arcs=tuple(arcs),
        contour_max_counts=float(contour.max()),
        contour_rms_counts=float(np.sqrt(np.mean(contour**2))),
        checks=tuple(checks), interpolation=ip,
        time_s=np.arange(n_ticks, dtype=np.int64) * period, command_counts=command,
        path_counts=path_pad[:n_ticks], actual_counts=actual, contour_counts=contour,
    )  # fmt: skip


def _motion_checks(
    config: LinkageConfig,
    cpus: list[CpuResult],
    axes: list[AxisResult],
    err: np.ndarray,
    rec: float | None,
) -> list[Check]:
    """Underrun, overrun and fault checks of a run, with their reasons."""
    f = bus_figures(config)
    resync = config.clock.resync_interval_s
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
            out.append(Check(name=f"underrun:{c.name}", passed=True, detail=(
                f"cpu {c.name}: no underrun; worst queue level before a pop {c.min_level} "
                f"setpoints")))  # fmt: skip
        else:
            lead = f["lead_s"]
            eps = c.clock_ppm * 1e-6
            if c.overruns:
                expect = ", commands lost to the overrun"
            elif eps > 0:
                expect = f", as expected after about lead/ε = {lead / eps:.1f} s"
            else:
                expect = ""
            out.append(Check(name=f"underrun:{c.name}", passed=False, detail=(
                f"underrun on cpu {c.name}: {c.underruns} ticks found no command, the first at "
                f"{c.first_underrun_s:.3f} s ({clock}, {sync}; a block arrives "
                f"{lead * 1e3:.2f} ms before it is needed{expect}) — {advice}")))  # fmt: skip
        if c.overruns == 0:
            out.append(Check(name=f"overrun:{c.name}", passed=True, detail=(
                f"cpu {c.name}: no overrun; highest queue level {c.max_level} of "
                f"{c.queue_depth} setpoints")))  # fmt: skip
        else:
            out.append(Check(name=f"overrun:{c.name}", passed=False, detail=(
                f"overrun on cpu {c.name}: {c.overruns} blocks did not fit its "
                f"{c.queue_depth}-setpoint queue, the first at {c.first_overrun_s:.3f} s "
                f"({clock}, {sync}) — {advice}")))  # fmt: skip
    for i, a in enumerate(axes):
        limit = config.axes[i].following_error_limit_counts
        if a.fault is None:
            lim = f" < limit {limit}" if limit else ""
            out.append(Check(name=f"fault:{a.name}", passed=True, detail=(
                f"axis {a.name}: no fault (largest tracking error "
                f"{a.max_abs_err_counts:.0f} counts{lim})")))  # fmt: skip
        elif a.fault == "following_error":
            out.append(Check(name=f"fault:{a.name}", passed=False, detail=(
                f"following-error trip on axis {a.name} at {a.first_fault_s:.3f} s (limit "
                f"{limit} counts; the axis went to 0 V) — lower the feed or acceleration, "
                f"raise the gains or the limit")))  # fmt: skip
        else:
            out.append(Check(name=f"fault:{a.name}", passed=False, detail=(
                f"counter fault on axis {a.name} at {a.first_fault_s:.3f} s (the high-byte "
                f"unwrap saw an impossible jump)")))  # fmt: skip
    return out
