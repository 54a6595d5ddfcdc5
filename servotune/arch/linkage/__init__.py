"""Multi-CPU multi-axis linkage (docs/systems.md#multi-cpu-linkage):
interpolate, broadcast, queue, follow.

One **master CPU** interpolates the path of every axis ahead of time into a queue of position
commands, one per axis per sampling period. It broadcasts that queue in **data blocks** on one
serial bus (SCI): block ``b`` carries the commands of ticks ``b·B … b·B + B − 1`` for every axis
(``B = bus.block_size``), so one block leaves every ``B·period_s`` (the broadcast period). Each
**slave CPU** drives 2–4 axes; it keeps the commands of its own axes in a local queue of the
same structure, pops one command per axis every sampling period *by its own clock*, and closes
each axis's position loop with the runtime law (:mod:`servotune.laws.axis`, task mode, PI).
A **clock-sync broadcast** at motion start (and every ``clock.resync_interval_s`` if > 0)
realigns the slave clocks to the master's.

Submodules, each importing only those above it:

- :mod:`~servotune.arch.linkage.bus`: the serial bus, the clock sync, the slave CPUs (fields
  bounded by :mod:`servotune.arch.bounds` and the clock error's ``MAX_CLOCK_PPM``);
- :mod:`~servotune.arch.linkage.config`: the configuration (:func:`load_linkage`, frozen
  dataclasses validated on load; the path's positions bounded by ``MAX_COUNTS``);
- :mod:`~servotune.arch.linkage.path`: the master's interpolation (:func:`interpolate`) and
  the contour-error search;
- :mod:`~servotune.arch.linkage.kernel`: the compiled kernel of the event-driven simulation
  (its scheduling and routing; the axis tick is :mod:`servotune.sim.tick`'s);
- :mod:`~servotune.arch.linkage.checks`: the checks made before motion (:func:`check_linkage`,
  :func:`bus_figures`, :func:`recommended_resync_interval_s`);
- :mod:`~servotune.arch.linkage.result`: the result (:class:`LinkageResult`; its text summary
  is :func:`servotune.report.text.format_linkage_summary`);
- :mod:`~servotune.arch.linkage.run`: the simulation of the whole system
  (:func:`run_linkage`: it only runs, the gains the config holds), the axes' quantised
  constants (:func:`axis_controllers`) and the checks during motion;
- :mod:`~servotune.arch.linkage.synthesis`: the axes' PI gains (:func:`axis_gains`,
  :class:`AxisGains`, :data:`TUNE_TARGETS`); the gains a file leaves out are resolved by the
  caller, ``run_linkage(resolve_gains(load_linkage(path)))`` (:func:`resolve_gains`);
- :mod:`~servotune.arch.linkage.plan`: the plan of the integers its CPUs run
  (:func:`plan_linkage`, :class:`LinkagePlan`, the plan file) and the simulation of those
  integers (:func:`run_plan`);
- :mod:`~servotune.arch.linkage.spec`: the linkage spec (:func:`load_linkage_spec`,
  :class:`LinkageSpec`);
- :mod:`~servotune.arch.linkage.verify`: a plan verified against a spec, with its trust record
  (:func:`verify_plan_files`), and what an export may use (:func:`load_plan_for_export`).

This package re-exports the public names of all of them.

Timing model (all times in master time, the master's clock being the reference)
-------------------------------------------------------------------------------
- Master tick ``k`` is at ``k·T`` (``T = period_s``); motion starts at ``t = 0`` with the first
  sync. Command row ``k`` is the position the path programs for ``t = k·T``; row 0 is the start,
  every axis at 0 counts (its power-up home).
- **Prefill**: blocks ``0 … P − 1`` (``P = bus.prefill_blocks``) are in every slave queue before
  motion. Block ``b >= P`` starts on the bus at ``(b − P)·B·T`` and has arrived completely
  (and is queued) one frame time later: ``frame_s = 10·bytes/baud`` for 8N1, with
  ``bytes = frame_overhead_bytes + bytes_per_setpoint·n_axes·B``. Bus utilisation is
  ``frame_s / (B·T)``.
- **Slave clocks**: slave ``s`` runs at ``(1 + ε_s)`` times nominal, ``ε_s = clock_ppm·1e-6``
  relative to the master. After a sync at master tick ``k_r`` (time ``t_r = k_r·T``) its tick
  with index ``j`` happens at ``t_r + (j − k_r)·T/(1 + ε_s)``.
- **Sync semantics** (the slave clears its clock counter and takes the master's tick index):
  if the slave is behind (its next index ``j < k_r``), the commands ``j … k_r − 1`` are popped
  and discarded (counted as *skipped*) and its next tick is index ``k_r`` at ``t_r``; if it is
  ahead (``j >= k_r``: indices up to ``j − 1`` already executed), no index is executed twice:
  its next tick is index ``j`` at ``t_r + (j − k_r)·T/(1 + ε_s)``. While the drift between two
  syncs stays below one tick, nothing is ever skipped or repeated; only the tick phase moves.
  The sync frame's own bus latency is the same for every slave and is not modelled.
- **Slave tick** ``j``: pop command ``j`` (an *underrun* if it is not in the queue: the axis
  then holds its previous command); then each of the CPU's axes runs the axis tick of
  :mod:`servotune.sim.tick`, as on the single rig (:mod:`servotune.sim.engine`): its motor
  first moves from the CPU's previous tick to this one, then the counter latches (encoder
  noise from one splitmix64 stream for the run, drawn at each read of an axis with noise, in
  event order), the runtime reads it and runs its law (task mode, the popped command as
  reference), and the D/A write is held in the axis's tick-slot ring. A block that finds its
  slave queue full is an *overrun*: the commands that do not fit are lost.
- **Tick-relative plant**: each CPU counts its own ticks. An axis's plant row is built for its
  CPU's nominal tick ``Tc = T/(1 + ε_s)`` (master time), its lag
  ``compute_s + delay_s = m·Tc + λ`` (:func:`~servotune.plant.plant_row`): the write of the
  CPU's tick ``c`` reaches the motor ``λ`` into its tick ``c + m`` (ring of ``m + 2`` ticks).
  Between two ticks with no sync in between the motor moves over exactly one ``Tc``
  (:func:`~servotune.sim.tick.advance_axis`); across a sync it moves over the actual interval,
  the same held writes switching at ``λ`` (:func:`~servotune.plant.advance_span`).
  *Modelling change* (when the kernels came to share one tick): the write lag was timed in master
  seconds, a write landing ``compute_s + delay_s`` after its tick whatever happened in between; it
  is now counted on the CPU's own ticks. Between syncs that is the same instant (``m·Tc + λ`` is the
  lag, with ``Tc`` the drifting CPU's tick, to rounding). A write still pending when a sync moves
  the CPU's next tick (``m >= 1``, or a tick the sync shortened to less than ``λ``) moves with
  the CPU's ticks, by the sync's phase correction (the drift since the last sync: within
  half a period at the recommended resync interval). Without noise, the positions of
  ``plants/linkage-6axis.toml`` agree with the former kernel's to 1e-9 counts.
- At equal times events run in the order: sync, slave ticks, measurement, block arrival (a
  block arriving at the instant of its tick is late: the conservative reading).

Measurement: the "actual point" of tick ``k`` is every axis's plant position at the master
time ``k·T`` (as a ballbar or laser measures, independent of each slave's clock; computed from
the axis's state at its CPU's last tick, which it leaves unchanged), so clock
skew between slaves shows in the tracking and contour errors. Tracking error
``e = command − actual`` per axis; contour error = distance from the actual point to the
programmed path (polyline of the programmed positions at every tick, searched near the current
tick) in the space of the current move's axes (the plane of an arc, the moving axes of a line);
for each arc the radial deviation ``|actual − centre| − R`` against the angle, read as an
ISO 230-4 circular test (circularity = max − min).
"""

from servotune.arch.linkage.bus import Bus, Clock, SlaveCpu
from servotune.arch.linkage.checks import (
    BusFigures,
    Check,
    LinkageCheckError,
    bus_figures,
    check_linkage,
    recommended_resync_interval_s,
)
from servotune.arch.linkage.config import (
    SCHEMA,
    LinkageAxis,
    LinkageConfig,
    Move,
    Toolpath,
    linkage_from_dict,
    load_linkage,
)
from servotune.arch.linkage.path import ArcGeometry, Interpolation, interpolate
from servotune.arch.linkage.plan import (
    PLAN_SCHEMA,
    LinkagePlan,
    PlanCpu,
    PlanPath,
    drift_ticks,
    plan_config,
    plan_linkage,
    plan_to_string,
    read_plan,
    read_plan_bytes,
    run_plan,
    watermarks,
    write_plan,
)
from servotune.arch.linkage.result import (
    EVENT_COLUMNS,
    EVENT_KINDS,
    ArcResult,
    AxisResult,
    AxisTrace,
    CpuResult,
    LinkageResult,
)
from servotune.arch.linkage.run import axis_controllers, run_linkage
from servotune.arch.linkage.spec import (
    LinkageSpec,
    linkage_spec_from_bytes,
    linkage_spec_from_dict,
    load_linkage_spec,
)
from servotune.arch.linkage.synthesis import TUNE_TARGETS, AxisGains, axis_gains, resolve_gains
from servotune.arch.linkage.verify import (
    RECORD_SCHEMA,
    LinkageRow,
    LinkageVerification,
    clock_cases,
    load_plan_for_export,
    verify_plan,
    verify_plan_files,
)

__all__ = [
    "EVENT_COLUMNS",
    "EVENT_KINDS",
    "PLAN_SCHEMA",
    "RECORD_SCHEMA",
    "SCHEMA",
    "TUNE_TARGETS",
    "ArcGeometry",
    "ArcResult",
    "AxisGains",
    "AxisResult",
    "AxisTrace",
    "Bus",
    "BusFigures",
    "Check",
    "Clock",
    "CpuResult",
    "Interpolation",
    "LinkageAxis",
    "LinkageCheckError",
    "LinkageConfig",
    "LinkagePlan",
    "LinkageResult",
    "LinkageRow",
    "LinkageSpec",
    "LinkageVerification",
    "Move",
    "PlanCpu",
    "PlanPath",
    "SlaveCpu",
    "Toolpath",
    "axis_controllers",
    "axis_gains",
    "bus_figures",
    "check_linkage",
    "clock_cases",
    "drift_ticks",
    "interpolate",
    "linkage_from_dict",
    "linkage_spec_from_bytes",
    "linkage_spec_from_dict",
    "load_linkage",
    "load_linkage_spec",
    "load_plan_for_export",
    "plan_config",
    "plan_linkage",
    "plan_to_string",
    "read_plan",
    "read_plan_bytes",
    "recommended_resync_interval_s",
    "resolve_gains",
    "run_linkage",
    "run_plan",
    "verify_plan",
    "verify_plan_files",
    "watermarks",
    "write_plan",
]
