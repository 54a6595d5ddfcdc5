"""Planning a linkage: the integers its CPUs run (queues, watermarks, clock sync, gains).

A linkage config (:func:`~servotune.arch.linkage.load_linkage`) describes the machine: the rig,
the axes' plants, the path, the bus, the CPUs and their clocks. Its **plan**
(:func:`plan_linkage`) holds what the CPUs will run, as integers, the way a tuning does for a
single rig: the interpolation period, the bus's block format and its SCI bit budget, each slave
CPU's queue depth and watermarks, the clock-sync interval in master ticks and the drift it
allows, and each axis's quantised PI constants (:class:`~servotune.laws.axis.AxisController`,
nothing re-quantised later). :func:`run_plan` runs the simulation on exactly those integers;
:mod:`~servotune.arch.linkage.verify` judges it under a linkage spec
(:mod:`~servotune.arch.linkage.spec`) and keeps the trust record.

What a plan is (:class:`LinkagePlan`, :class:`PlanCpu`, :class:`PlanPath`) and its file
(``"schema": "servotune.linkage-plan/1"``, :func:`write_plan`, :func:`read_plan`) are
:mod:`~servotune.arch.linkage.plan_file`, re-exported here.

Definitions (``T = period_s``, ``B = block_size``, ``P = prefill_blocks``, 8N1 framing):

- bit budget: ``frame_bytes = frame_overhead_bytes + bytes_per_setpoint · n_axes · B``,
  ``bits_per_block = frame_bytes · bits_per_byte`` (10 for 8N1: start, 8 data, stop),
  ``frame_s = bits_per_block / baud``, ``broadcast_period_s = B·T``,
  ``utilisation = frame_s / broadcast_period_s``;
- drift: between two syncs (``drift_window_ticks`` master ticks: the resync interval, or the
  whole run if only the start sync is sent) a CPU at ``ε = clock_ppm·1e-6`` drifts
  ``drift_ticks = window · |ε| / (1 − |ε|)`` ticks from the master's grid (the larger of the
  two directions: a crystal off by the same amount either way);
- low watermark: ``P·B − floor(frame_s/T + drift_ticks)``: the fewest setpoints the queue
  holds before a pop when every block arrives on time and the CPU runs up to its drift ahead
  (just before each block arrives). A level below it means a block is later than planned;
  a queue that reaches 0 under-runs. The plan needs it >= 1;
- high watermark: ``(P + 1)·B − 1 − floor(frame_s/T − drift_ticks)``: the most setpoints the
  queue holds after a block arrives when the CPU runs up to its drift behind. The plan needs
  ``queue_depth`` >= it (and >= ``(P + 1)·B``, the prefill plus the block in flight).

Edit the plan's integers (a queue depth, a watermark, a PI constant) and
:func:`~servotune.arch.linkage.verify_plan_files` judges what you wrote.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from servotune._version import __version__
from servotune.arch.linkage import plan_file
from servotune.arch.linkage.bus import Bus, Clock, SlaveCpu
from servotune.arch.linkage.checks import (
    bus_figures,
    check_linkage,
    recommended_resync_interval_s,
)
from servotune.arch.linkage.config import LinkageConfig, linkage_from_dict
from servotune.arch.linkage.path import Interpolation, interpolate
from servotune.arch.linkage.plan_file import PLAN_SCHEMA as PLAN_SCHEMA
from servotune.arch.linkage.plan_file import LinkagePlan, PlanCpu, PlanPath, drift_ticks
from servotune.arch.linkage.plan_file import plan_to_string as plan_to_string
from servotune.arch.linkage.plan_file import read_plan as read_plan
from servotune.arch.linkage.plan_file import read_plan_bytes as read_plan_bytes
from servotune.arch.linkage.plan_file import write_plan as write_plan
from servotune.arch.linkage.result import LinkageResult
from servotune.arch.linkage.run import axis_controllers, run_linkage
from servotune.arch.linkage.synthesis import axis_gains, resolve_gains
from servotune.errors import ConfigError, RigError
from servotune.io.files import parse_toml
from servotune.provenance import SourceFile
from servotune.rig import rig_from_dict
from servotune.validate import show_value

__all__ = [
    *plan_file.__all__,  # the plan file's names, re-exported
    "plan_config",
    "plan_linkage",
    "run_plan",
    "watermarks",
]


def watermarks(bus: Bus, period_s: float, n_axes: int, drift: float) -> tuple[int, int]:
    """The low and high watermarks of a queue whose CPU drifts up to ``drift`` ticks either
    way (module docstring) [setpoints]."""
    p, b = bus.prefill_blocks, bus.block_size
    ratio = bus.frame_s(n_axes) / period_s
    return p * b - math.floor(ratio + drift), (p + 1) * b - 1 - math.floor(ratio - drift)


def read_config(config_file: SourceFile) -> tuple[LinkageConfig, SourceFile, dict[str, Any]]:
    """The config parsed from the bytes read, its rig read once, and the parsed TOML."""
    p = Path(config_file.path)
    data = parse_toml(config_file.raw, config_file.path, ConfigError, "linkage config")
    where = f"linkage config {config_file.path!r}"
    rig_ref = data.get("rig")
    if not isinstance(rig_ref, str) or not rig_ref:
        raise ConfigError(
            f"{where}: rig must be the path of a rig file (TOML), got {show_value(rig_ref)}"
        )
    rig_file = SourceFile.read(p.parent / rig_ref, ConfigError, "rig file")
    try:
        rig_data = parse_toml(rig_file.raw, rig_file.path, RigError, "rig file")
        rig = rig_from_dict(rig_data, default_name=Path(rig_ref).stem)
    except RigError as exc:
        raise ConfigError(f"{where}: rig: {exc}") from None
    try:
        config = linkage_from_dict(data, p.parent, p.stem, rig=rig)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return config, rig_file, data


def plan_linkage(config_path: str | Path) -> LinkagePlan:
    """Plan a linkage config: the integers its CPUs run (module docstring).

    The config's bytes are read once and hashed; its rig likewise. Gains the config leaves out
    are tuned as ``servotune linkage`` does (:func:`~servotune.arch.linkage.resolve_gains`)
    and quantised at the nominal period (:func:`~servotune.arch.linkage.axis_controllers`). The
    resync interval is the config's (``clock.resync_interval_s``, rounded to whole ticks), or,
    if the config has none, :func:`~servotune.arch.linkage.recommended_resync_interval_s`.

    Parameters
    ----------
    config_path : str or Path
        The linkage config (TOML).

    Returns
    -------
    LinkagePlan

    Raises
    ------
    ConfigError
        One line naming the file: it cannot be read or is invalid; a check before motion
        fails (bus overload beyond ``max_utilisation``, prefill or queue too short, a speed
        beyond an axis's limit); the prefill leaves no margin for a CPU's drift (low
        watermark < 1) or a queue is shorter than its high watermark; or the path's commands
        do not fit a setpoint.

    Examples
    --------
    >>> from servotune.rig import EXAMPLE_RIG_PATH
    >>> plan = plan_linkage(EXAMPLE_RIG_PATH.parent / "linkage-6axis.toml")
    >>> plan.bits_per_block, plan.resync_ticks, [c.low_watermark for c in plan.cpus]
    (1280, 6250, [9, 9])
    """
    config_file = SourceFile.read(config_path, ConfigError, "linkage config")
    config, rig_file, data = read_config(config_file)
    where = f"linkage config {config_file.path!r}"
    period, bus = config.period_s, config.bus
    ip = interpolate(config)
    failed = [c for c in check_linkage(config, ip) if not c.passed]
    if failed:
        raise ConfigError(f"{where}: cannot plan: " + "; ".join(c.detail for c in failed))
    rec = recommended_resync_interval_s(config)
    clock_t = data.get("clock")
    given = isinstance(clock_t, Mapping) and "resync_interval_s" in clock_t
    if given:
        s = config.clock.resync_interval_s
        resync_ticks = max(1, round(s / period)) if s else 0
    else:
        resync_ticks = round(rec / period)
    run_ticks = max(1, round((ip.duration_s + config.settle_s) / period))
    window = resync_ticks or run_ticks
    cpus = []
    for c in config.cpus:
        drift = drift_ticks(c.clock_ppm, window)
        low, high = watermarks(bus, period, config.n_axes, drift)
        sync = f"a sync every {window} ticks" if resync_ticks else f"no resync in {window} ticks"
        if low < 1:
            raise ConfigError(
                f"{where}: cpu {c.name}: the prefill leaves no margin for its clock drift "
                f"({drift:.2f} ticks at {c.clock_ppm:+g} ppm, {sync}): the queue may run dry "
                f"before a block arrives — raise bus.prefill_blocks or resync more often"
            )
        if c.queue_depth < high:
            raise ConfigError(
                f"{where}: cpu {c.name}: queue_depth {c.queue_depth} is below the "
                f"{high} setpoints the queue may hold when the CPU is behind by its drift "
                f"({drift:.2f} ticks at {c.clock_ppm:+g} ppm, {sync}) — raise queue_depth to "
                f">= {high} or resync more often"
            )
        cpus.append(
            PlanCpu(
                name=c.name,
                axes=c.axes,
                clock_ppm=float(c.clock_ppm),
                queue_depth=c.queue_depth,
                low_watermark=low,
                high_watermark=high,
            )
        )
    config = resolve_gains(config)
    gains = axis_gains(config)  # as resolved: each marked tuned where resolve_gains tuned it
    ctl = axis_controllers(config)
    f = bus_figures(config)
    design = {
        "axes": {n: g.to_dict() for n, g in gains.items()},
        "bus": {
            "lead_s": f.lead_s,
            "nominal_min_level": f.nominal_min_level,
            "required_queue_depth": f.required_queue_depth,
        },
        "clock": {
            "recommended_resync_interval_s": rec,
            "resync_from": "config" if given else "recommended",
        },
        "watermarks": "low = P*B - floor(frame_s/T + drift_ticks); "
        "high = (P+1)*B - 1 - floor(frame_s/T - drift_ticks)",
    }
    try:
        return LinkagePlan(
            config_name=config.name,
            config_path=Path(config_file.path).as_posix(),
            config_sha256=config_file.sha256,
            rig_name=config.rig.name,
            rig_path=Path(rig_file.path).as_posix(),
            rig_sha256=rig_file.sha256,
            period_s=float(period),
            path=PlanPath(
                max_feed_cps=float(config.path.max_feed_cps),
                max_accel_cps2=float(config.path.max_accel_cps2),
                ticks=ip.n_ticks,
                command_min_counts=int(ip.commands.min()),
                command_max_counts=int(ip.commands.max()),
            ),
            bus=bus,
            resync_ticks=resync_ticks,
            drift_window_ticks=window,
            cpus=tuple(cpus),
            axis_names=config.axis_names,
            controllers=tuple(ctl[a] for a in config.axis_names),
            design=design,
            provenance={"tool": "servotune", "tool_version": __version__},
        )
    except ConfigError as exc:
        raise ConfigError(f"{where}: cannot plan: {exc}") from None


# --- running a plan -----------------------------------------------------------------------------


def _plan_matches(plan: LinkagePlan, config: LinkageConfig, ip: Interpolation) -> None:
    """Raise ConfigError unless the fields the plan restates are the config's."""
    pairs: list[tuple[str, object, object]] = [
        ("config.name", plan.config_name, config.name),
        ("rig.name", plan.rig_name, config.rig.name),
        ("period_s", plan.period_s, config.period_s),
        ("axes", list(plan.axis_names), list(config.axis_names)),
        ("interpolation.max_feed_cps", plan.path.max_feed_cps, config.path.max_feed_cps),
        ("interpolation.max_accel_cps2", plan.path.max_accel_cps2, config.path.max_accel_cps2),
        ("interpolation.ticks", plan.path.ticks, ip.n_ticks),
        ("interpolation.command_min_counts", plan.path.command_min_counts, int(ip.commands.min())),
        ("interpolation.command_max_counts", plan.path.command_max_counts, int(ip.commands.max())),
        ("cpus", [c.name for c in plan.cpus], [c.name for c in config.cpus]),
    ]
    for i, (pc, cc) in enumerate(zip(plan.cpus, config.cpus, strict=False)):
        pairs.append((f"cpus[{i}].axes", list(pc.axes), list(cc.axes)))
        pairs.append((f"cpus[{i}].clock_ppm", pc.clock_ppm, cc.clock_ppm))
    for where, mine, theirs in pairs:
        if mine != theirs:
            raise ConfigError(
                f"the plan's {where} is {show_value(mine)} but its config has "
                f"{show_value(theirs)}: the plan was edited or is another config's; plan again"
            )


def plan_config(
    plan: LinkagePlan, config: LinkageConfig, *, clock_ppm: Sequence[float] | None = None
) -> LinkageConfig:
    """The configuration that runs the plan: ``config``'s rig, plants and path with the plan's
    bus, queue depths and resync interval (and ``clock_ppm`` per CPU, default the plan's).

    Run it with the plan's controllers and resync ticks: :func:`run_plan`.

    Raises
    ------
    ConfigError
        The plan restates a field differently from ``config`` (it was edited, or is another
        config's), or ``clock_ppm`` has not one value per CPU.
    """
    _plan_matches(plan, config, interpolate(config))
    ppm = [c.clock_ppm for c in plan.cpus] if clock_ppm is None else list(clock_ppm)
    if len(ppm) != len(plan.cpus):
        raise ConfigError(f"clock_ppm must have one value per CPU ({len(plan.cpus)}), got {ppm}")
    cpus = tuple(
        SlaveCpu(name=c.name, axes=c.axes, queue_depth=c.queue_depth, clock_ppm=float(p))
        for c, p in zip(plan.cpus, ppm, strict=True)
    )
    return replace(
        config, bus=plan.bus, cpus=cpus, clock=Clock(resync_interval_s=plan.resync_interval_s)
    )


def run_plan(
    plan: LinkagePlan,
    config: LinkageConfig,
    *,
    clock_ppm: Sequence[float] | None = None,
    seconds: float | None = None,
    seed: int = 0,
    trace: bool = False,
) -> LinkageResult:
    """Simulate the plan's integers: :func:`~servotune.arch.linkage.run_linkage` on
    :func:`plan_config` with the plan's controllers and resync ticks (nothing re-derived).

    Raises
    ------
    LinkageCheckError
        A check before motion fails on the plan's bus or queues.
    ConfigError
        As :func:`plan_config` and :func:`~servotune.arch.linkage.run_linkage`.
    """
    cfg = plan_config(plan, config, clock_ppm=clock_ppm)
    return run_linkage(
        cfg,
        seconds=seconds,
        seed=seed,
        trace=trace,
        controllers=plan.controller_map,
        resync_ticks=plan.resync_ticks,
    )
