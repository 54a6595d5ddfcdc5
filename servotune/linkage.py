"""Multi-CPU multi-axis linkage (seed 002, SPEC §1b): interpolate, broadcast, queue, follow.

One **master CPU** interpolates the path of every axis ahead of time into a queue of position
commands, one per axis per sampling period. It broadcasts that queue in **data blocks** on one
serial bus (SCI): block ``b`` carries the commands of ticks ``b·B … b·B + B − 1`` for every axis
(``B = bus.block_size``), so one block leaves every ``B·period_s`` (the broadcast period). Each
**slave CPU** drives 2–4 axes; it keeps the commands of its own axes in a local queue of the
same structure, pops one command per axis every sampling period *by its own clock*, and closes
each axis's position loop with the runtime law (:mod:`servotune.laws.axis`, task mode, PI).
A **clock-sync broadcast** at motion start (and every ``clock.resync_interval_s`` if > 0)
realigns the slave clocks to the master's.

Layers: the configuration (:func:`load_linkage`, frozen dataclasses validated on load), the
master's interpolation (:func:`interpolate`), the checks made before motion
(:func:`check_linkage`), the event-driven simulation of the whole system (:func:`run_linkage`)
and its result (:class:`LinkageResult`, :func:`format_linkage_summary`).

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
  then holds its previous command); for each axis read the counter, run
  :func:`~servotune.laws.axis.axis_read` and :func:`~servotune.laws.axis.axis_control`
  (task mode, the popped command as reference), write the D/A code at ``tick + compute_s``;
  the motor sees it ``delay_s`` later and moves exactly between input changes
  (:func:`~servotune.plant.advance`). A block that finds its slave queue full is an *overrun*:
  the commands that do not fit are lost.
- At equal times events run in the order: sync, slave ticks, measurement, block arrival (a
  block arriving at the instant of its tick is late: the conservative reading).

Measurement: the "actual point" of tick ``k`` is every axis's plant position at the master
time ``k·T`` (as a ballbar or laser measures, independent of each slave's clock), so clock
skew between slaves shows in the tracking and contour errors. Tracking error
``e = command − actual`` per axis; contour error = distance from the actual point to the
programmed path (polyline of the programmed positions at every tick, searched near the current
tick) in the space of the current move's axes (the plane of an arc, the moving axes of a line);
for each arc the radial deviation ``|actual − centre| − R`` against the angle, read as an
ISO 230-4 circular test (circularity = max − min).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numba as nb
import numpy as np

from servotune.budget import check_memory, format_count
from servotune.errors import ConfigError, RigError
from servotune.hw import counter as hw_counter
from servotune.io.files import json_float, read_toml
from servotune.laws.axis import (
    FLAG_COUNTER_FAULT,
    FLAG_FOLLOWING_ERROR,
    FLAG_SATURATED,
    MODE_TASK,
    N_STATE,
    AxisController,
    axis_control,
    axis_read,
)
from servotune.laws.pi import PIGains
from servotune.plant import Plant, advance
from servotune.rig import MAX_LOCK_GAIN, Rig, build_section, check_plant, load_rig
from servotune.tune.pi import DEFAULT_TARGETS
from servotune.validate import check_integer, check_keys, check_number, is_number, show_value

__all__ = [
    "SCHEMA",
    "ArcGeometry",
    "ArcResult",
    "AxisResult",
    "Bus",
    "Check",
    "Clock",
    "CpuResult",
    "Interpolation",
    "LinkageAxis",
    "LinkageCheckError",
    "LinkageConfig",
    "LinkageResult",
    "Move",
    "SlaveCpu",
    "Toolpath",
    "axis_gains",
    "bus_figures",
    "check_linkage",
    "format_linkage_summary",
    "interpolate",
    "linkage_from_dict",
    "load_linkage",
    "recommended_resync_interval_s",
    "run_linkage",
]

SCHEMA = "servotune.linkage/1"
"""Version tag of :meth:`LinkageResult.to_dict`."""

MAX_CLOCK_PPM = 10_000.0
"""Largest clock error accepted [ppm] (1 %, beyond a ceramic resonator's tolerance)."""

TUNE_TARGETS = DEFAULT_TARGETS
"""Robustness targets of :func:`~servotune.tune.pi.tune_pi` for axes without explicit gains."""

_RING = 64  # pending D/A writes per axis (the lag compute_s + delay_s must stay below this)
_CONTOUR_WINDOW = 4000  # largest number of ticks searched either side of the current one


class LinkageCheckError(ConfigError):
    """A check made before motion failed (bus overload, prefill or queue too short, speed).

    The configuration is well formed but the machine cannot run it; ``checks`` holds the failed
    :class:`Check` entries, and the message states every reason with its numbers.
    """

    def __init__(self, checks: tuple[Check, ...]) -> None:
        self.checks = tuple(checks)
        super().__init__("; ".join(c.detail for c in self.checks))


# --- validation helpers --------------------------------------------------------------------


# Bounds of the configuration's fields (a typo must not size the simulation's arrays); the
# checks are servotune.validate's, raising ConfigError.
MAX_COUNTS = 1e12
"""Largest position, centre or distance magnitude [counts]."""
MAX_FEED_CPS = 1e9
"""Largest feed [counts/s]; accelerations up to 1e12 counts/s²."""
MAX_SECONDS = 3600.0
"""Longest dwell, settle or resync interval [s]."""
MAX_GAIN = 1e6
"""Largest PI gain [codes/count, codes/(count·s)]."""
_TICK_BYTES_PER_AXIS = 64  # commands, path, noise, actual, error, contour per tick and axis
_TICK_BYTES = 64  # queue traces, move index per tick (and CPU)


# --- configuration -------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class Bus:
    """The serial bus (SCI) the master broadcasts the command blocks on.

    Parameters
    ----------
    baud : float
        Line rate [bits/s].
    block_size : int
        Commands per axis in one block [setpoints]; one block is broadcast every
        ``block_size · period_s`` (the broadcast period).
    bytes_per_setpoint : int
        Bytes of one axis's command in a block [bytes] (4: an int32 position).
    frame_overhead_bytes : int
        Bytes of a block frame besides the commands (header, block index, CRC) [bytes].
    bits_per_byte : int
        Bits on the line per byte [bits] (10 for 8N1: start, 8 data, stop).
    max_utilisation : float
        Largest accepted frame time / broadcast period [-], in (0, 1].
    prefill_blocks : int
        Blocks the master sends before motion starts [blocks].
    """

    baud: float
    block_size: int
    bytes_per_setpoint: int = 4
    frame_overhead_bytes: int = 8
    bits_per_byte: int = 10
    max_utilisation: float = 1.0
    prefill_blocks: int = 1

    def __post_init__(self) -> None:
        check_number("baud", self.baud, "bits/s", strict=True, hi=1e9, error=ConfigError)
        check_integer("block_size", self.block_size, "setpoints", lo=1, hi=10_000,
                      error=ConfigError)  # fmt: skip
        check_integer("bytes_per_setpoint", self.bytes_per_setpoint, "bytes", lo=1, hi=64,
                      error=ConfigError)  # fmt: skip
        check_integer("frame_overhead_bytes", self.frame_overhead_bytes, "bytes", hi=65_536,
                      error=ConfigError)  # fmt: skip
        check_integer("bits_per_byte", self.bits_per_byte, "bits", lo=8, hi=16, error=ConfigError)
        # <= 1: a frame cannot outlast its period
        check_number("max_utilisation", self.max_utilisation, "-", strict=True, hi=1.0,
                     error=ConfigError)  # fmt: skip
        check_integer("prefill_blocks", self.prefill_blocks, "blocks", hi=10_000,
                      error=ConfigError)  # fmt: skip

    def frame_bytes(self, n_axes: int) -> int:
        """Bytes of one block frame for ``n_axes`` axes [bytes]."""
        return self.frame_overhead_bytes + self.bytes_per_setpoint * n_axes * self.block_size

    def frame_s(self, n_axes: int) -> float:
        """Time one block frame takes on the line [s]."""
        return self.frame_bytes(n_axes) * self.bits_per_byte / self.baud


@dataclass(frozen=True, slots=True, kw_only=True)
class Clock:
    """Clock synchronisation.

    Parameters
    ----------
    resync_interval_s : float
        Time between sync broadcasts during motion [s], rounded to whole master ticks;
        0: only the sync at motion start.
    """

    resync_interval_s: float = 0.0

    def __post_init__(self) -> None:
        check_number("resync_interval_s", self.resync_interval_s, "s", hi=MAX_SECONDS,
                     error=ConfigError)  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class SlaveCpu:
    """One slave CPU.

    Parameters
    ----------
    name : str
        Name of the CPU.
    axes : tuple of str
        The 2–4 axes it drives.
    queue_depth : int
        Local queue capacity per axis [setpoints].
    clock_ppm : float
        Its clock's error relative to the master's [ppm] (> 0: runs fast).
    """

    name: str
    axes: tuple[str, ...]
    queue_depth: int
    clock_ppm: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ConfigError(f"name must be a non-empty string, got {show_value(self.name)}")
        if isinstance(self.axes, list):
            object.__setattr__(self, "axes", tuple(self.axes))
        if not isinstance(self.axes, tuple) or not all(isinstance(a, str) for a in self.axes):
            raise ConfigError(f"axes must be a list of axis names, got {show_value(self.axes)}")
        if not 2 <= len(self.axes) <= 4:
            raise ConfigError(
                f"axes must name 2 to 4 axes (a slave CPU drives 2–4 motors), got "
                f"{show_value(list(self.axes))}"
            )
        if len(set(self.axes)) != len(self.axes):
            raise ConfigError(f"axes must not repeat an axis, got {show_value(list(self.axes))}")
        check_integer("queue_depth", self.queue_depth, "setpoints", lo=1, hi=1_000_000,
                      error=ConfigError)  # fmt: skip
        check_number("clock_ppm", self.clock_ppm, "ppm", lo=-MAX_CLOCK_PPM, hi=MAX_CLOCK_PPM,
                     error=ConfigError)  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkageAxis:
    """One axis of the linkage: its plant and its position loop on the slave.

    Parameters
    ----------
    name : str
        Axis name (the key of ``[axis.<name>]``).
    plant : Plant
        Axis model (SPEC §5).
    kp : float or None
        PI proportional gain [codes/count]; None (with ``ki``): tuned.
    ki : float or None
        PI integral gain [codes/(count·s)]; None (with ``kp``): tuned.
    lock_gain_codes_per_count : float
        Position-lock gain [codes/count] (the runtime's lock module; seed 000: 0.4).
    following_error_limit_counts : int
        Following-error trip threshold [counts]; 0 disables the trip.
    counter_init : int
        Counter register value at the start [counts].
    """

    name: str
    plant: Plant
    kp: float | None = None
    ki: float | None = None
    lock_gain_codes_per_count: float = 0.4
    following_error_limit_counts: int = 0
    counter_init: int = 0

    def __post_init__(self) -> None:
        if (self.kp is None) != (self.ki is None):
            raise ConfigError(
                f"kp and ki must be given together (or neither, to tune them), got "
                f"kp={show_value(self.kp)}, ki={show_value(self.ki)}"
            )
        if self.kp is not None:
            check_number("kp", self.kp, "codes/count", hi=MAX_GAIN, error=ConfigError)
            check_number("ki", self.ki, "codes/(count·s)", hi=MAX_GAIN, error=ConfigError)
        check_number("lock_gain_codes_per_count", self.lock_gain_codes_per_count, "codes/count",
                     strict=True, hi=MAX_LOCK_GAIN, error=ConfigError)  # fmt: skip
        check_integer("following_error_limit_counts", self.following_error_limit_counts,
                      "counts", hi=2**31 - 1, error=ConfigError)  # fmt: skip
        check_integer("counter_init", self.counter_init, "counts", hi=2**32 - 1,
                      error=ConfigError)  # fmt: skip

    @property
    def gains(self) -> PIGains | None:
        """The explicit PI gains, or None if they are to be tuned."""
        if self.kp is None or self.ki is None:
            return None
        return PIGains(kp=float(self.kp), ki=float(self.ki))


@dataclass(frozen=True, slots=True, kw_only=True)
class Move:
    """One move of the path.

    Parameters
    ----------
    kind : str
        ``"line"`` (linear interpolation), ``"arc"`` (circular in ``plane``; every other
        axis named in ``to`` moves linearly along, a helix) or ``"dwell"`` (hold, as G04).
    feed_cps : float or None
        Programmed feed along the path [counts/s] (clamped to the path's limits); lines and
        arcs only.
    dwell_s : float or None
        Dwell: how long every axis holds [s].
    to : dict of str to float
        Target positions [counts] of the axes that move (absolute, from the start at 0); axes
        not named stay. For an arc, the plane axes' end point, or neither of them and
        ``angle_deg``.
    plane : tuple of str
        Arc: the two axes of the plane ``(first, second)``; angles count from the first
        towards the second.
    centre : tuple of float
        Arc: centre in the plane [counts].
    angle_deg : float or None
        Arc: swept angle [deg] in (0, 3600]; 360 is a full circle.
    direction : str
        Arc: ``"ccw"`` (from the first plane axis towards the second) or ``"cw"``.
    """

    kind: str
    feed_cps: float | None = None
    dwell_s: float | None = None
    to: Mapping[str, float] = field(default_factory=dict)
    plane: tuple[str, ...] | None = None
    centre: tuple[float, ...] | None = None
    angle_deg: float | None = None
    direction: str = "ccw"

    def __post_init__(self) -> None:
        for name in ("plane", "centre"):
            if isinstance(getattr(self, name), list):
                object.__setattr__(self, name, tuple(getattr(self, name)))
        if self.kind not in ("line", "arc", "dwell"):
            raise ConfigError(f"kind must be 'line', 'arc' or 'dwell', got {show_value(self.kind)}")
        if self.kind == "dwell":
            check_number("dwell_s", self.dwell_s, "s", strict=True, hi=MAX_SECONDS,
                         error=ConfigError)  # fmt: skip
            for k in ("feed_cps", "plane", "centre", "angle_deg"):
                if getattr(self, k) is not None:
                    raise ConfigError(f"{k} is not for a dwell; a dwell takes kind, dwell_s")
            if self.to:
                raise ConfigError("to is not for a dwell; a dwell takes kind, dwell_s")
            return
        if self.dwell_s is not None:
            raise ConfigError(f"dwell_s is for dwells only, got it on a {self.kind}")
        check_number("feed_cps", self.feed_cps, "counts/s", strict=True, hi=MAX_FEED_CPS,
                     error=ConfigError)  # fmt: skip
        if not isinstance(self.to, Mapping):
            raise ConfigError(
                f"to must be a table of axis = position [counts], got {show_value(self.to)}"
            )
        for k, v in self.to.items():
            check_number(f"to.{k}", v, "counts", lo=-MAX_COUNTS, hi=MAX_COUNTS, error=ConfigError)
        if self.kind == "line":
            if not self.to:
                raise ConfigError("to must name at least one axis target for a line [counts]")
            for k in ("plane", "centre", "angle_deg"):
                if getattr(self, k) is not None:
                    raise ConfigError(f"{k} is for arcs only; a line takes kind, feed_cps, to")
            return
        if (
            not isinstance(self.plane, tuple)
            or len(self.plane) != 2
            or not all(isinstance(a, str) for a in self.plane)
            or self.plane[0] == self.plane[1]
        ):
            raise ConfigError(f"plane must name two different axes, got {show_value(self.plane)}")
        if (
            not isinstance(self.centre, tuple)
            or len(self.centre) != 2
            or not all(is_number(c) and abs(c) <= MAX_COUNTS for c in self.centre)  # NaN fails too
        ):
            raise ConfigError(
                f"centre must be [first, second], each within ±1e12 [counts], got "
                f"{show_value(self.centre)}"
            )
        if self.direction not in ("ccw", "cw"):
            raise ConfigError(f"direction must be 'ccw' or 'cw', got {show_value(self.direction)}")
        in_to = [a in self.to for a in self.plane]
        if any(in_to) and not all(in_to):
            raise ConfigError(
                f"to must give both plane axes {list(self.plane)} (the end point) or neither "
                f"(then angle_deg), got {sorted(self.to)}"
            )
        if all(in_to) == (self.angle_deg is not None):
            raise ConfigError(
                "give the arc's end either as to = {plane axes} or as angle_deg, not both "
                "and not neither"
            )
        if self.angle_deg is not None:
            check_number("angle_deg", self.angle_deg, "deg", strict=True, hi=3600.0,
                         error=ConfigError)  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class Toolpath:
    """The programmed path and the machine's path limits.

    Parameters
    ----------
    max_feed_cps : float
        Feed limit along the path [counts/s]; a move's feed above it is clamped (as a CNC
        clamps a programmed feed to the machine's).
    max_accel_cps2 : float
        Acceleration along the path [counts/s²] (trapezoid ramps), also the limit of an arc's
        centripetal acceleration (its feed is clamped to ``sqrt(a·R)`` in the plane).
    moves : tuple of Move
        The moves, in order; every move starts and ends at rest.
    """

    max_feed_cps: float
    max_accel_cps2: float
    moves: tuple[Move, ...]

    def __post_init__(self) -> None:
        check_number("max_feed_cps", self.max_feed_cps, "counts/s", strict=True,
                     hi=MAX_FEED_CPS, error=ConfigError)  # fmt: skip
        check_number("max_accel_cps2", self.max_accel_cps2, "counts/s²", strict=True,
                     hi=1e3 * MAX_FEED_CPS, error=ConfigError)  # fmt: skip
        if not self.moves:
            raise ConfigError("move: the path needs at least one [[path.move]]")


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkageConfig:
    """A multi-CPU linkage: the rig's hardware, the bus, the slave CPUs, axes and path.

    Build it with :func:`load_linkage` or :func:`linkage_from_dict`.

    Parameters
    ----------
    name : str
        Name (default: the file's stem).
    rig : Rig
        The hardware facts: counter bits, D/A bits and range, encoder pulses/rev and
        multiplier, ``timer.compute_s`` (tick start → D/A write on a slave). The rig's axes and
        timer period are not used.
    rig_file : str
        The rig file as written in the configuration (provenance).
    period_s : float
        Nominal sampling period of every CPU [s].
    bus : Bus
    clock : Clock
    cpus : tuple of SlaveCpu
    axes : tuple of LinkageAxis
        In file order (the column order of every array).
    path : Toolpath
    settle_s : float
        Time simulated after the path ends, by default [s].
    description : str
    """

    name: str
    rig: Rig
    rig_file: str
    period_s: float
    bus: Bus
    clock: Clock
    cpus: tuple[SlaveCpu, ...]
    axes: tuple[LinkageAxis, ...]
    path: Toolpath
    settle_s: float = 0.5
    description: str = ""

    def __post_init__(self) -> None:
        check_number("period_s", self.period_s, "s", lo=1e-6, hi=1.0, error=ConfigError)
        check_number("settle_s", self.settle_s, "s", hi=MAX_SECONDS, error=ConfigError)
        compute_s = self.rig.timer.compute_s
        if compute_s >= self.period_s:
            raise ConfigError(
                f"period_s must be longer than the rig's timer.compute_s ({compute_s:g} s), "
                f"got {show_value(self.period_s)} s"
            )
        names = [a.name for a in self.axes]
        if len(set(names)) != len(names):
            raise ConfigError(f"axis names must be unique, got {show_value(names)}")
        if not self.cpus:
            raise ConfigError("cpu: at least one [[cpu]] is needed")
        cpu_names = [c.name for c in self.cpus]
        if len(set(cpu_names)) != len(cpu_names):
            raise ConfigError(f"cpu names must be unique, got {show_value(cpu_names)}")
        owner: dict[str, str] = {}
        for c in self.cpus:
            for a in c.axes:
                if a not in names:
                    raise ConfigError(
                        f"cpu {show_value(c.name)} drives axis {show_value(a)}, which has no "
                        f"[axis.{a}] table "
                        f"(axes: {names})"
                    )
                if a in owner:
                    raise ConfigError(
                        f"axis {show_value(a)} is on two CPUs: {show_value(owner[a])} and "
                        f"{show_value(c.name)}"
                    )
                owner[a] = c.name
        lost = [a for a in names if a not in owner]
        if lost:
            raise ConfigError(
                f"axis {show_value(lost[0])} is on no CPU; add it to a [[cpu]]'s axes"
            )
        for i, m in enumerate(self.path.moves):
            used = list(m.to) + list(m.plane or ())
            for a in used:
                if a not in names:
                    raise ConfigError(
                        f"path.move[{i}] names axis {show_value(a)}, which has no [axis.{a}] table "
                        f"(axes: {names})"
                    )
        for a in self.axes:
            lag = compute_s + a.plant.delay_s
            if lag >= (_RING - 4) * self.period_s:
                raise ConfigError(
                    f"axis.{a.name}.plant.delay_s: compute_s + delay_s = {lag:g} s must be "
                    f"shorter than {_RING - 4} periods"
                )
            if a.counter_init >= 1 << self.rig.counter.bits:
                raise ConfigError(
                    f"axis.{a.name}.counter_init must fit the {self.rig.counter.bits}-bit "
                    f"counter, got {a.counter_init}"
                )

    @property
    def axis_names(self) -> tuple[str, ...]:
        """Axis names in column order."""
        return tuple(a.name for a in self.axes)

    @property
    def n_axes(self) -> int:
        """Number of axes."""
        return len(self.axes)

    def axis(self, name: str) -> LinkageAxis:
        """The axis called ``name``."""
        for a in self.axes:
            if a.name == name:
                return a
        raise ConfigError(f"no axis {show_value(name)}; axes: {list(self.axis_names)}")

    def cpu_of(self, name: str) -> SlaveCpu:
        """The slave CPU that drives axis ``name``."""
        for c in self.cpus:
            if name in c.axes:
                return c
        raise ConfigError(f"no CPU drives axis {show_value(name)}")


_TOP_KEYS = ("axis", "bus", "clock", "cpu", "description", "name", "path", "period_s", "rig",
             "settle_s")  # fmt: skip


def _table(data: Mapping[str, Any], key: str, required: bool = True) -> Mapping[str, Any]:
    if key not in data:
        if required:
            raise ConfigError(f"missing table [{key}]")
        return {}
    t = data[key]
    if not isinstance(t, Mapping):
        raise ConfigError(f"[{key}] must be a table, got {type(t).__name__}")
    return t


def linkage_from_dict(
    data: Mapping[str, Any], base_dir: str | Path, default_name: str = "linkage"
) -> LinkageConfig:
    """Build and validate a :class:`LinkageConfig` from the parsed contents of a config file.

    Parameters
    ----------
    data : mapping
        The parsed TOML (see :func:`load_linkage` for the layout).
    base_dir : str or Path
        Directory the ``rig`` path is relative to (the config file's directory).
    default_name : str
        Name if the data has no ``name``.

    Returns
    -------
    LinkageConfig

    Raises
    ------
    ConfigError
        If a key is unknown or missing, or a value is invalid; the message names the field
        (``bus.baud``, ``cpu[1].queue_depth``, ``axis.x.plant.tau_s``), the value and the unit.
    """
    check_keys(data, "", (), _TOP_KEYS, error=ConfigError)
    rig_ref = data.get("rig")
    if not isinstance(rig_ref, str) or not rig_ref:
        raise ConfigError(f"rig must be the path of a rig file (TOML), got {show_value(rig_ref)}")
    try:
        rig = load_rig(Path(base_dir) / rig_ref)
    except RigError as exc:
        raise ConfigError(f"rig: {exc}") from None
    bus = build_section(Bus, _table(data, "bus"), "bus", ConfigError)
    clock = build_section(Clock, _table(data, "clock", required=False), "clock", ConfigError)
    cpus_t = data.get("cpu")
    if not isinstance(cpus_t, list) or not cpus_t:
        raise ConfigError("cpu must be one or more [[cpu]] tables")
    cpus = []
    for i, ct in enumerate(cpus_t):
        if not isinstance(ct, Mapping):
            raise ConfigError(f"cpu[{i}] must be a table")
        cpus.append(build_section(SlaveCpu, ct, f"cpu[{i}]", ConfigError))
    axes = []
    for name, at in _table(data, "axis").items():
        if not isinstance(at, Mapping):
            raise ConfigError(f"[axis.{name}] must be a table")
        at = dict(at)
        pt = at.pop("plant", None)
        if not isinstance(pt, Mapping):
            raise ConfigError(f"missing table [axis.{name}.plant]")
        plant = build_section(Plant, pt, f"axis.{name}.plant", ConfigError)
        check_plant(plant, f"axis.{name}.plant", rig.dac.range_v, error=ConfigError)
        axes.append(
            build_section(LinkageAxis, at, f"axis.{name}", ConfigError, name=name, plant=plant)
        )
    pt = dict(_table(data, "path"))
    moves_t = pt.pop("move", None)
    if not isinstance(moves_t, list) or not moves_t:
        raise ConfigError("path.move must be one or more [[path.move]] tables")
    moves = []
    for i, mt in enumerate(moves_t):
        if not isinstance(mt, Mapping):
            raise ConfigError(f"path.move[{i}] must be a table")
        moves.append(build_section(Move, mt, f"path.move[{i}]", ConfigError))
    path = build_section(Toolpath, pt, "path", ConfigError, moves=tuple(moves))
    top: dict[str, Any] = {}
    for key in ("period_s", "settle_s"):
        if key in data:
            top[key] = data[key]
    if "period_s" not in top:
        raise ConfigError("missing key period_s (the nominal sampling period [s])")
    for key in ("name", "description"):
        if key in data and not isinstance(data[key], str):
            raise ConfigError(f"{key} must be a string, got {show_value(data[key])}")
    return LinkageConfig(
        name=str(data.get("name", default_name)),
        description=str(data.get("description", "")),
        rig=rig,
        rig_file=rig_ref,
        bus=bus,
        clock=clock,
        cpus=tuple(cpus),
        axes=tuple(axes),
        path=path,
        **top,
    )


def load_linkage(path: str | Path) -> LinkageConfig:
    """Read and validate a linkage configuration (TOML).

    Layout (units in the names; positions in counts after the counter's multiplication)::

        name = "linkage-6axis"            # optional (default: the file's stem)
        rig = "pc-dual-servo.toml"        # hardware facts, relative to this file
        period_s = 0.002                  # nominal sampling period of every CPU [s]
        settle_s = 0.5                    # simulated after the path ends [s] (default 0.5)

        [bus]                             # the SCI the master broadcasts on
        baud = 460800                     # [bits/s]
        block_size = 5                    # setpoints per axis per block
        bytes_per_setpoint = 4            # [bytes] (default 4)
        frame_overhead_bytes = 8          # [bytes] (default 8)
        bits_per_byte = 10                # 8N1 (default 10)
        max_utilisation = 1.0             # frame time / broadcast period (default 1)
        prefill_blocks = 2                # blocks sent before motion (default 1)

        [clock]
        resync_interval_s = 12.5          # [s]; 0 = only the sync at motion start

        [[cpu]]                           # one per slave CPU
        name = "s1"
        clock_ppm = 80.0                  # [ppm] relative to the master
        queue_depth = 20                  # [setpoints per axis]
        axes = ["x", "z", "a"]            # 2 to 4 axes

        [axis.x]                          # one per axis
        kp = 0.36                         # [codes/count]      } optional: tuned with
        ki = 1.44                         # [codes/(count·s)]  } tune_pi if absent
        following_error_limit_counts = 12288   # optional, 0 = no trip
        lock_gain_codes_per_count = 0.4   # optional
        counter_init = 0                  # optional
        [axis.x.plant]                    # SPEC §5 names: gain_cps_per_v, tau_s, ...

        [path]
        max_feed_cps = 60000              # [counts/s]
        max_accel_cps2 = 200000           # [counts/s²]
        [[path.move]]
        kind = "line"
        to = { x = 40000, z = 10000 }     # absolute targets [counts]
        feed_cps = 40000                  # [counts/s] along the path
        [[path.move]]
        kind = "arc"
        plane = ["x", "y"]
        centre = [0, 0]                   # [counts]
        angle_deg = 360                   # or: to = { x = ..., y = ... } (end point)
        direction = "ccw"
        to = { z = 0 }                    # other axes move linearly along (helix)
        feed_cps = 25000
        [[path.move]]
        kind = "dwell"                    # every axis holds (G04)
        dwell_s = 0.5                     # [s]

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    LinkageConfig

    Raises
    ------
    ConfigError
        If the file (or its rig file) cannot be read, is not TOML, or any field is invalid.
    """
    p = Path(path)
    data = read_toml(p, ConfigError, "linkage config")
    try:
        return linkage_from_dict(data, p.parent, p.stem)
    except ConfigError as exc:
        raise ConfigError(f"linkage config {str(p)!r}: {exc}") from None


# --- interpolation (the master, ahead of time) ---------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class ArcGeometry:
    """An arc of the path as interpolated.

    Parameters
    ----------
    move : int
        Index of the move.
    plane : tuple of int
        Column indices of the plane axes.
    centre : tuple of float
        Centre [counts].
    radius_counts : float
        Programmed radius [counts].
    start_rad, sweep_rad : float
        Start angle and signed swept angle [rad] (> 0: ccw).
    cruise_ticks : tuple of int
        First and last row at the constant (cruise) feed; the whole move if the profile is
        triangular.
    """

    move: int
    plane: tuple[int, int]
    centre: tuple[float, float]
    radius_counts: float
    start_rad: float
    sweep_rad: float
    cruise_ticks: tuple[int, int]


@dataclass(frozen=True, slots=True, kw_only=True)
class Interpolation:
    """The master's interpolated path: one position per axis per tick.

    Attributes
    ----------
    period_s : float
        Tick period [s].
    axis_names : tuple of str
    positions : ndarray, shape (ticks, axes)
        Programmed position at ``k · period_s`` [counts] (row 0: the start, all 0).
    commands : ndarray of int64, shape (ticks, axes)
        ``positions`` rounded to whole counts: what is broadcast [counts]. Each move's last
        row is its target exactly.
    move_of_tick : ndarray of int64, shape (ticks,)
        The move each row belongs to (row 0 belongs to move 0).
    move_ends : tuple of int
        Last row of each move (it starts at the previous move's last row).
    feeds_cps : tuple of float
        Feed of each move after clamping to the limits [counts/s].
    lengths_counts : tuple of float
        Path length of each move in the space of all axes [counts].
    move_axes : ndarray of bool, shape (moves, axes)
        The axes a move's contour error is measured in (arc: its plane; line: the axes it moves).
    arcs : tuple of ArcGeometry
    """

    period_s: float
    axis_names: tuple[str, ...]
    positions: np.ndarray
    commands: np.ndarray
    move_of_tick: np.ndarray
    move_ends: tuple[int, ...]
    feeds_cps: tuple[float, ...]
    lengths_counts: tuple[float, ...]
    move_axes: np.ndarray
    arcs: tuple[ArcGeometry, ...]

    @property
    def n_ticks(self) -> int:
        """Rows (ticks) including the start row."""
        return int(self.positions.shape[0])

    @property
    def duration_s(self) -> float:
        """Time from the start to the end of the last move [s]."""
        return (self.n_ticks - 1) * self.period_s

    def move_start_tick(self, m: int) -> int:
        """Row where move ``m`` starts (the previous move's last row; 0 for the first)."""
        return 0 if m == 0 else self.move_ends[m - 1]


def _trapezoid(
    length: float, feed: float, accel: float, t: np.ndarray
) -> tuple[np.ndarray, float, float, float]:
    """Distance along a move at times ``t`` [s], duration, ramp and cruise times [s].

    Rest to rest: accelerate at ``accel``, cruise at ``feed``, decelerate; a move too short to
    reach the feed is triangular with peak ``sqrt(accel · length)``.
    """
    if feed * feed / accel <= length:
        t_a = feed / accel
        t_c = (length - feed * feed / accel) / feed
    else:
        feed = math.sqrt(accel * length)
        t_a = feed / accel
        t_c = 0.0
    dur = 2.0 * t_a + t_c
    d_a = 0.5 * accel * t_a * t_a
    s = np.where(
        t < t_a,
        0.5 * accel * t * t,
        np.where(t < t_a + t_c, d_a + feed * (t - t_a), length - 0.5 * accel * (dur - t) ** 2),
    )
    return np.clip(np.where(t >= dur, length, s), 0.0, length), dur, t_a, t_c


def _check_ticks(config: LinkageConfig, ticks: float, where: str) -> None:
    """Refuse a path whose interpolation up to ``where`` (``ticks`` long) exceeds the budget."""
    n_ax = config.n_axes
    per_tick = n_ax * _TICK_BYTES_PER_AXIS + _TICK_BYTES
    check_memory(
        ticks * per_tick,
        f"linkage {config.name!r}: interpolating the path up to {where}",
        f"{format_count(ticks)} ticks of {config.period_s:g} s × {per_tick} bytes",
    )


def interpolate(config: LinkageConfig) -> Interpolation:
    """Interpolate the path, as the master does before motion.

    Every move runs from rest to rest with a trapezoidal feed profile (accelerate at
    ``max_accel_cps2``, cruise, decelerate; triangular if too short). The feed is clamped to
    ``max_feed_cps`` and, for an arc, so that the centripetal acceleration in its plane stays
    within ``max_accel_cps2``. Lines are linear in every axis; arcs are circular in their plane
    while the other axes named in ``to`` move linearly (helical interpolation), the feed being
    along the path in the space of all axes. The profile is sampled every period; each move
    takes a whole number of ticks (its last tick reaches the target exactly) and the next move
    starts there.

    Parameters
    ----------
    config : LinkageConfig

    Returns
    -------
    Interpolation

    Raises
    ------
    ConfigError
        If a move does not move, or an arc's start and end are not on one circle (radii
        differing by more than 1 count) or its start is at its centre.

    Examples
    --------
    >>> from servotune.linkage import load_linkage
    >>> from servotune.rig import EXAMPLE_RIG_PATH
    >>> cfg = load_linkage(EXAMPLE_RIG_PATH.parent / "linkage-6axis.toml")
    >>> ip = interpolate(cfg)
    >>> ip.commands.shape[1], ip.commands[0].tolist() == [0] * 6
    (6, True)
    """
    names = config.axis_names
    col = {n: i for i, n in enumerate(names)}
    period = config.period_s
    accel = config.path.max_accel_cps2
    pos = np.zeros(len(names))
    rows: list[np.ndarray] = [pos.copy()[None, :]]
    move_of: list[np.ndarray] = [np.zeros(1, dtype=np.int64)]
    ends: list[int] = []
    feeds: list[float] = []
    lengths: list[float] = []
    arcs: list[ArcGeometry] = []
    move_axes = np.zeros((len(config.path.moves), len(names)), dtype=bool)
    tick = 0
    for m, mv in enumerate(config.path.moves):
        where = f"path.move[{m}]"
        if mv.kind == "dwell":
            assert mv.dwell_s is not None
            _check_ticks(config, tick + mv.dwell_s / period, where)
            n = max(1, round(mv.dwell_s / period))
            rows.append(np.repeat(pos[None, :], n, axis=0))
            move_of.append(np.full(n, m, dtype=np.int64))
            move_axes[m] = True  # a dwell's contour is the distance to the held point
            tick += n
            ends.append(tick)
            feeds.append(0.0)
            lengths.append(0.0)
            continue
        assert mv.feed_cps is not None
        end = pos.copy()
        for ax, v in mv.to.items():
            end[col[ax]] = float(v)
        feed = min(mv.feed_cps, config.path.max_feed_cps)
        plane: tuple[int, int] | None = None
        if mv.kind == "line":
            delta = end - pos
            length = float(np.sqrt(np.sum(delta * delta)))
            move_axes[m] = delta != 0.0
        else:
            assert mv.plane is not None and mv.centre is not None
            plane = (col[mv.plane[0]], col[mv.plane[1]])
            i, j = plane
            cx, cy = float(mv.centre[0]), float(mv.centre[1])
            r = math.hypot(pos[i] - cx, pos[j] - cy)
            if r < 1.0:
                raise ConfigError(
                    f"{where}: the arc starts at its centre ({cx:g}, {cy:g}) [counts]; the "
                    f"start must lie on the circle"
                )
            th0 = math.atan2(pos[j] - cy, pos[i] - cx)
            sign = 1.0 if mv.direction == "ccw" else -1.0
            if mv.angle_deg is not None:
                sweep = math.radians(mv.angle_deg)
                if math.isclose(math.remainder(mv.angle_deg, 360.0), 0.0, abs_tol=1e-9):
                    end[i], end[j] = pos[i], pos[j]  # whole turns end where they start
                else:
                    end[i] = cx + r * math.cos(th0 + sign * sweep)
                    end[j] = cy + r * math.sin(th0 + sign * sweep)
            else:
                r_end = math.hypot(end[i] - cx, end[j] - cy)
                if abs(r_end - r) > 1.0:
                    raise ConfigError(
                        f"{where}: the arc's start is {r:.1f} counts from the centre but its "
                        f"end {r_end:.1f}: not on one circle (within 1 count)"
                    )
                th1 = math.atan2(end[j] - cy, end[i] - cx)
                sweep = (sign * (th1 - th0)) % (2.0 * math.pi)
                if sweep < 1e-9:
                    sweep = 2.0 * math.pi  # end = start: a full circle
            others = end - pos
            others[[i, j]] = 0.0
            arc_len = r * sweep
            length = math.hypot(arc_len, float(np.sqrt(np.sum(others * others))))
            # centripetal acceleration in the plane (speed there = feed · arc_len / length)
            feed = min(feed, math.sqrt(accel * r) * length / arc_len)
            move_axes[m, [i, j]] = True
        if length <= 0.0:
            raise ConfigError(f"{where}: the move does not move any axis (length 0 counts)")
        with np.errstate(over="ignore", invalid="ignore"):  # an absurd move: refused below
            _, dur, t_a, t_c = _trapezoid(length, feed, accel, np.zeros(1))
        _check_ticks(config, tick + dur / period, where)
        n = max(1, math.ceil(dur / period - 1e-9))
        t = np.arange(1, n + 1, dtype=np.int64) * period
        s, *_ = _trapezoid(length, feed, accel, t)
        u = s / length
        seg = pos[None, :] + u[:, None] * (end - pos)[None, :]
        if plane is not None:
            i, j = plane
            th = th0 + u * sign * sweep
            seg[:, i] = cx + r * np.cos(th)
            seg[:, j] = cy + r * np.sin(th)
            c0, c1 = math.ceil(t_a / period - 1e-9), math.floor((t_a + t_c) / period + 1e-9)
            cruise = (tick + c0, tick + c1) if c1 > c0 else (tick, tick + n)
            arcs.append(ArcGeometry(move=m, plane=plane, centre=(cx, cy), radius_counts=r,
                                    start_rad=th0, sweep_rad=sign * sweep,
                                    cruise_ticks=cruise))  # fmt: skip
        seg[-1] = end
        rows.append(seg)
        move_of.append(np.full(n, m, dtype=np.int64))
        tick += n
        ends.append(tick)
        feeds.append(feed)
        lengths.append(length)
        pos = end
    positions = np.concatenate(rows)
    commands = np.rint(positions).astype(np.int64)
    return Interpolation(
        period_s=period,
        axis_names=names,
        positions=positions,
        commands=commands,
        move_of_tick=np.concatenate(move_of),
        move_ends=tuple(ends),
        feeds_cps=tuple(feeds),
        lengths_counts=tuple(lengths),
        move_axes=move_axes,
        arcs=tuple(arcs),
    )


# --- checks before motion ------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class Check:
    """One check of the linkage.

    Parameters
    ----------
    name : str
        ``bus``, ``prefill``, ``queue:<cpu>``, ``speed:<axis>`` (before motion);
        ``underrun:<cpu>``, ``overrun:<cpu>``, ``fault:<axis>`` (during motion).
    passed : bool
    detail : str
        What was checked, with the numbers; for a failure the reason and what to change.
    """

    name: str
    passed: bool
    detail: str

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return {"detail": self.detail, "name": self.name, "passed": self.passed}


def bus_figures(config: LinkageConfig) -> dict[str, float]:
    """The bus and queue figures the checks use (nominal clocks).

    Returns
    -------
    dict
        ``frame_bytes`` [bytes], ``frame_s`` [s], ``broadcast_period_s`` [s],
        ``utilisation`` [-], ``lead_s`` [s] (a block arrives this long before its first
        command is needed: ``P·B·T − frame_s``), ``nominal_min_level`` [setpoints] (the queue
        level before the pop just ahead of each arrival: ``P·B − floor(frame_s/T)``),
        ``required_queue_depth`` [setpoints] (``(P + 1)·B``).

    Examples
    --------
    >>> from servotune.linkage import load_linkage
    >>> from servotune.rig import EXAMPLE_RIG_PATH
    >>> f = bus_figures(load_linkage(EXAMPLE_RIG_PATH.parent / "linkage-6axis.toml"))
    >>> f["frame_bytes"], round(f["utilisation"], 3)
    (128, 0.278)
    """
    bus, period = config.bus, config.period_s
    n = config.n_axes
    frame_s = bus.frame_s(n)
    bp = bus.block_size * period
    return {
        "broadcast_period_s": bp,
        "frame_bytes": bus.frame_bytes(n),
        "frame_s": frame_s,
        "lead_s": bus.prefill_blocks * bp - frame_s,
        "nominal_min_level": bus.prefill_blocks * bus.block_size - math.floor(frame_s / period),
        "required_queue_depth": (bus.prefill_blocks + 1) * bus.block_size,
        "utilisation": frame_s / bp,
    }


def _speed_limits(config: LinkageConfig, a: LinkageAxis) -> tuple[float, str]:
    """Largest speed an axis may be commanded to [counts/s] and what limits it."""
    rig = config.rig
    cpr = rig.counts_per_rev
    drive = a.plant.max_speed_cps(cpr)
    lo, hi = rig.dac.range_v
    reach_v = min(-lo, hi) - abs(a.plant.offset_v) - a.plant.coulomb_v
    dac = a.plant.gain_cps_per_v * reach_v
    unwrap = hw_counter.max_counts_per_tick(rig.counter.bits) / config.period_s
    options = [
        (drive, f"the drive's limit ({a.plant.max_speed_rpm} r/min × {cpr:g} counts/rev)"),
        (dac, f"what the D/A reaches ({reach_v:.3f} V × {a.plant.gain_cps_per_v:g} counts/s/V)"),
        (unwrap, f"the counter's high-byte unwrap limit ({rig.counter.bits}-bit, per tick)"),
    ]
    return min(options, key=lambda o: o[0])


def check_linkage(
    config: LinkageConfig, interpolation: Interpolation | None = None
) -> tuple[Check, ...]:
    """The checks the master makes before motion (nominal clocks).

    - ``bus``: utilisation = frame time / broadcast period <= ``max_utilisation``.
    - ``prefill``: the first block broadcast during motion arrives before its first command is
      needed: ``lead_s = P·B·T − frame_s > 0`` (then every later block does too).
    - ``queue:<cpu>``: the queue holds the prefill plus one block: ``queue_depth >= (P+1)·B``.
    - ``speed:<axis>``: the path's speed on each axis (from the interpolation) stays within the
      drive's speed limit, what the D/A can command and the counter's unwrap limit.

    Parameters
    ----------
    config : LinkageConfig
    interpolation : Interpolation, optional
        The master's path (computed if not given).

    Returns
    -------
    tuple of Check
        Every check, passed or not.
    """
    ip = interpolate(config) if interpolation is None else interpolation
    f = bus_figures(config)
    bus, period = config.bus, config.period_s
    n = config.n_axes
    checks: list[Check] = []
    u = f["utilisation"]
    bits = bus.bits_per_byte
    if u <= bus.max_utilisation:
        checks.append(Check(name="bus", passed=True, detail=(
            f"a block frame ({f['frame_bytes']} bytes) takes {f['frame_s'] * 1e3:.2f} ms of the "
            f"{f['broadcast_period_s'] * 1e3:.2f} ms broadcast period (utilisation "
            f"{u * 100:.1f} % <= {bus.max_utilisation * 100:.0f} %)")))  # fmt: skip
    else:
        m = bus.max_utilisation
        baud_min = f["frame_bytes"] * bits / (m * f["broadcast_period_s"])
        per_block = bus.bytes_per_setpoint * n * bits / bus.baud  # line time per setpoint row
        room = m * period - per_block
        hint = f"raise baud to >= {math.ceil(baud_min)}"
        if room > 0:
            b_min = math.ceil(bus.frame_overhead_bytes * bits / bus.baud / room)
            hint += f" or block_size to >= {b_min}"
        checks.append(Check(name="bus", passed=False, detail=(
            f"bus overload: a block frame ({f['frame_bytes']} bytes × {bits} bits at "
            f"{bus.baud:g} baud) takes {f['frame_s'] * 1e3:.2f} ms but the broadcast period is "
            f"{f['broadcast_period_s'] * 1e3:.2f} ms (utilisation {u * 100:.0f} % > "
            f"{m * 100:.0f} %) — {hint}")))  # fmt: skip
    p_blocks = bus.prefill_blocks
    if f["lead_s"] > 0:
        checks.append(Check(name="prefill", passed=True, detail=(
            f"each block arrives {f['lead_s'] * 1e3:.2f} ms before its first command is "
            f"needed (prefill {p_blocks} blocks; worst queue level before a pop "
            f"{f['nominal_min_level']} setpoints)")))  # fmt: skip
    else:
        p_min = math.floor(f["frame_s"] / f["broadcast_period_s"]) + 1
        checks.append(Check(name="prefill", passed=False, detail=(
            f"prefill too short: the first block broadcast during motion arrives "
            f"{f['frame_s'] * 1e3:.2f} ms after the start but its first command is needed at "
            f"{p_blocks * f['broadcast_period_s'] * 1e3:.2f} ms (prefill {p_blocks} blocks of "
            f"{bus.block_size}) — raise prefill_blocks to >= {p_min}")))  # fmt: skip
    need = int(f["required_queue_depth"])
    for c in config.cpus:
        if c.queue_depth >= need:
            checks.append(Check(name=f"queue:{c.name}", passed=True, detail=(
                f"cpu {c.name}: queue_depth {c.queue_depth} >= the prefill plus one block "
                f"({need} setpoints per axis)")))  # fmt: skip
        else:
            checks.append(Check(name=f"queue:{c.name}", passed=False, detail=(
                f"queue too short on cpu {c.name}: queue_depth {c.queue_depth} setpoints per "
                f"axis, but the prefill ({p_blocks} blocks × {bus.block_size}) plus the block "
                f"in flight need {need} — raise queue_depth to >= {need} or lower "
                f"prefill_blocks / block_size")))  # fmt: skip
    speed = np.abs(np.diff(ip.positions, axis=0)) / period
    for i, a in enumerate(config.axes):
        limit, what = _speed_limits(config, a)
        k = int(np.argmax(speed[:, i])) if speed.shape[0] else 0
        top = float(speed[k, i]) if speed.shape[0] else 0.0
        if top <= limit:
            checks.append(Check(name=f"speed:{a.name}", passed=True, detail=(
                f"axis {a.name}: the path's top speed {top:,.0f} counts/s is within "
                f"{what}: {limit:,.0f} counts/s")))  # fmt: skip
        else:
            mv = int(ip.move_of_tick[k + 1])
            checks.append(Check(name=f"speed:{a.name}", passed=False, detail=(
                f"axis {a.name}: the path commands {top:,.0f} counts/s (move {mv}, "
                f"t = {(k + 1) * period:.3f} s) but {what} is {limit:,.0f} counts/s — lower "
                f"the feed of move {mv} or max_feed_cps")))  # fmt: skip
    return tuple(checks)


def recommended_resync_interval_s(config: LinkageConfig) -> float:
    """The longest resync interval that keeps every slave's drift well within its margins.

    Rule: between two syncs a slave's tick phase drifts by ``|ε|·interval`` against the master
    (``ε = clock_ppm·1e-6``). That drift must stay within half of the smallest of

    - one period ``T`` (so no command is ever skipped or executed twice at a sync, and two
      slaves never differ by more than one tick),
    - the underrun lead ``P·B·T − frame_s`` (how much earlier a fast slave's tick may come
      before a block arrives too late),
    - the overrun slack ``(queue_depth − (P+1)·B + 1)·T + frame_s`` (how much later a slow
      slave's ticks may come before an arriving block no longer fits),

    at the worst ``|clock_ppm|``; the result is rounded down to whole master ticks.

    Parameters
    ----------
    config : LinkageConfig

    Returns
    -------
    float
        Interval [s]; 0.0 if every clock is exact (the start sync suffices).

    Raises
    ------
    LinkageCheckError
        If the lead or a slack is not positive (the prefill or queue checks fail).

    Examples
    --------
    >>> from servotune.linkage import load_linkage
    >>> from servotune.rig import EXAMPLE_RIG_PATH
    >>> recommended_resync_interval_s(load_linkage(EXAMPLE_RIG_PATH.parent / "linkage-6axis.toml"))
    12.5
    """
    f = bus_figures(config)
    period, bus = config.period_s, config.bus
    eps = max(abs(c.clock_ppm) for c in config.cpus) * 1e-6
    if eps == 0.0:
        return 0.0
    slack = min((c.queue_depth - (bus.prefill_blocks + 1) * bus.block_size + 1) * period
                + f["frame_s"] for c in config.cpus)  # fmt: skip
    if f["lead_s"] <= 0.0 or slack <= 0.0:
        failed = tuple(c for c in check_linkage(config) if not c.passed)
        raise LinkageCheckError(failed or (Check(name="prefill", passed=False, detail=(
            "no resync interval works: the queue has no margin for drift")),))  # fmt: skip
    budget = 0.5 * min(period, f["lead_s"], slack)
    ticks = max(1, math.floor(budget / eps / period + 1e-9))
    return ticks * period


# --- tuning --------------------------------------------------------------------------------


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


# --- simulation ----------------------------------------------------------------------------

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


@nb.njit(cache=True)
def _contour(path, actual, move_of_tick, move_axes):  # fmt: skip
    """Distance from each actual point to the programmed polyline, near the current tick."""
    n, n_ax = actual.shape
    n_p = path.shape[0]
    # segments that move: skip runs of equal points quickly
    nxt = np.empty(n_p, dtype=np.int64)
    nxt[n_p - 1] = n_p - 1
    for j in range(n_p - 2, -1, -1):
        same = True
        for a in range(n_ax):
            if path[j + 1, a] != path[j, a]:
                same = False
                break
        nxt[j] = nxt[j + 1] if same else j
    prv = np.empty(n_p, dtype=np.int64)
    prv[0] = 0
    for j in range(1, n_p):
        same = True
        for a in range(n_ax):
            if path[j, a] != path[j - 1, a]:
                same = False
                break
        prv[j] = prv[j - 1] if same else j
    seg_max = 0.0
    for j in range(n_p - 1):
        d2 = 0.0
        for a in range(n_ax):
            d = path[j + 1, a] - path[j, a]
            d2 += d * d
        if d2 > seg_max:
            seg_max = d2
    seg_max = math.sqrt(seg_max)
    out = np.empty(n)
    for k in range(n):
        kk = min(k, n_p - 1)
        m = move_of_tick[kk]
        d2 = 0.0
        for a in range(n_ax):
            if move_axes[m, a]:
                d = actual[k, a] - path[kk, a]
                d2 += d * d
        best = math.sqrt(d2)
        reach = 2.0 * best + seg_max + 1.0
        for direction in (1, -1):
            j = kk if direction == 1 else kk - 1
            steps = 0
            while 0 <= j < n_p - 1 and steps < _CONTOUR_WINDOW:
                if direction == 1:
                    j = nxt[j]
                    if j >= n_p - 1:
                        break
                else:
                    j = prv[j + 1] - 1 if prv[j + 1] > 0 else j
                    if j < 0:
                        break
                # segment j -> j+1 in the move's axes
                ab = 0.0
                aq = 0.0
                far0 = 0.0
                far1 = 0.0
                for a in range(n_ax):
                    if move_axes[m, a]:
                        da = path[j + 1, a] - path[j, a]
                        dq = actual[k, a] - path[j, a]
                        ab += da * da
                        aq += da * dq
                        f0 = path[j, a] - path[kk, a]
                        f1 = path[j + 1, a] - path[kk, a]
                        far0 += f0 * f0
                        far1 += f1 * f1
                u = aq / ab if ab > 0.0 else 0.0
                u = min(max(u, 0.0), 1.0)
                d2 = 0.0
                for a in range(n_ax):
                    if move_axes[m, a]:
                        d = actual[k, a] - (path[j, a] + u * (path[j + 1, a] - path[j, a]))
                        d2 += d * d
                d = math.sqrt(d2)
                if d < best:
                    best = d
                if far0 > reach * reach and far1 > reach * reach:
                    break
                j += direction
                steps += 1
        out[k] = best
    return out


@dataclass(frozen=True, slots=True, kw_only=True)
class CpuResult:
    """What happened on one slave CPU.

    Attributes
    ----------
    name : str
    axes : tuple of str
    clock_ppm : float
        Its clock's error [ppm].
    queue_depth : int
        Capacity [setpoints per axis].
    tick_time_s : ndarray
        Master time of each of its ticks [s].
    tick_index : ndarray of int64
        The command index each tick executed (strictly increasing: none runs twice).
    queue_level : ndarray of int64
        Queue level just before each tick's pop [setpoints].
    underruns : int
        Ticks whose command was not in the queue.
    first_underrun_s : float or None
        Time of the first [s].
    overruns : int
        Blocks that did not fit completely.
    first_overrun_s : float or None
        Time of the first [s].
    min_level : int
        Worst underrun margin: lowest queue level before a pop [setpoints].
    max_level : int
        Highest queue level after an arrival [setpoints].
    skipped : int
        Commands consumed unexecuted at a sync (the slave was behind by whole ticks).
    resyncs : int
        Sync broadcasts during motion (after the start sync).
    """

    name: str
    axes: tuple[str, ...]
    clock_ppm: float
    queue_depth: int
    tick_time_s: np.ndarray = field(repr=False)
    tick_index: np.ndarray = field(repr=False)
    queue_level: np.ndarray = field(repr=False)
    underruns: int
    first_underrun_s: float | None
    overruns: int
    first_overrun_s: float | None
    min_level: int
    max_level: int
    skipped: int
    resyncs: int

    def to_dict(self, arrays: bool = False) -> dict[str, Any]:
        """Plain dict; the per-tick arrays only with ``arrays=True``."""
        d: dict[str, Any] = {
            "axes": list(self.axes),
            "clock_ppm": self.clock_ppm,
            "first_overrun_s": self.first_overrun_s,
            "first_underrun_s": self.first_underrun_s,
            "max_level": self.max_level,
            "min_level": self.min_level,
            "name": self.name,
            "overruns": self.overruns,
            "queue_depth": self.queue_depth,
            "resyncs": self.resyncs,
            "skipped": self.skipped,
            "ticks": int(self.tick_time_s.size),
            "underruns": self.underruns,
        }
        if arrays:
            d["tick_time_s"] = self.tick_time_s.tolist()
            d["tick_index"] = self.tick_index.tolist()
            d["queue_level"] = self.queue_level.tolist()
        return d


@dataclass(frozen=True, slots=True, kw_only=True)
class AxisResult:
    """Tracking of one axis.

    Attributes
    ----------
    name, cpu : str
    kp : float
        [codes/count]
    ki : float
        [codes/(count·s)]
    tuned : bool
        True if the gains were tuned (not given).
    max_abs_err_counts, rms_err_counts : float
        Of ``command − actual`` over every master tick [counts].
    saturated_ticks : int
        Ticks whose D/A output hit a rail.
    fault : str or None
        ``"following_error"`` or ``"counter"`` if a fault latched.
    first_fault_s : float or None
        When [s].
    """

    name: str
    cpu: str
    kp: float
    ki: float
    tuned: bool
    max_abs_err_counts: float
    rms_err_counts: float
    saturated_ticks: int
    fault: str | None
    first_fault_s: float | None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return {k: getattr(self, k) for k in sorted(self.__slots__)}  # type: ignore[attr-defined]


@dataclass(frozen=True, slots=True, kw_only=True)
class ArcResult:
    """The circular test of one arc (ISO 230-4 reading).

    As a ballbar test is read at a constant feed after a run-in, the extremes and the
    circularity are taken over the arc's cruise (constant-feed) ticks; the arrays cover the
    whole move, ramps included, and ``circularity_whole_counts`` reads them all.

    Attributes
    ----------
    move : int
    plane : tuple of str
    centre : tuple of float
        [counts]
    radius_counts : float
        Programmed radius [counts].
    angle_rad : ndarray
        Angle of the actual point about the centre, per tick of the move [rad].
    radial_dev_counts : ndarray
        Actual radius − programmed radius, per tick of the move [counts].
    cruise : ndarray of bool
        Per tick of the move: at the constant feed.
    max_dev_counts, min_dev_counts : float
        Extremes of the radial deviation at the constant feed [counts].
    circularity_counts : float
        ``max − min`` at the constant feed [counts].
    circularity_whole_counts : float
        ``max − min`` over the whole move, ramps included [counts].
    """

    move: int
    plane: tuple[str, str]
    centre: tuple[float, float]
    radius_counts: float
    angle_rad: np.ndarray = field(repr=False)
    radial_dev_counts: np.ndarray = field(repr=False)
    cruise: np.ndarray = field(repr=False)
    max_dev_counts: float
    min_dev_counts: float
    circularity_counts: float
    circularity_whole_counts: float

    def to_dict(self, arrays: bool = False) -> dict[str, Any]:
        """Plain dict; the per-tick arrays only with ``arrays=True``."""
        d: dict[str, Any] = {
            "centre": list(self.centre),
            "circularity_counts": self.circularity_counts,
            "circularity_whole_counts": self.circularity_whole_counts,
            "max_dev_counts": self.max_dev_counts,
            "min_dev_counts": self.min_dev_counts,
            "move": self.move,
            "plane": list(self.plane),
            "radius_counts": self.radius_counts,
        }
        if arrays:
            d["angle_rad"] = self.angle_rad.tolist()
            d["radial_dev_counts"] = self.radial_dev_counts.tolist()
            d["cruise"] = self.cruise.tolist()
        return d


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkageResult:
    """Result of :func:`run_linkage`.

    Attributes
    ----------
    name : str
        The configuration's name.
    seed : int
    period_s : float
        Nominal period [s].
    bus : dict
        :func:`bus_figures` (utilisation, frame and broadcast period [s], lead [s], ...).
    resync_interval_s : float
        Interval used [s] (0: start sync only), after rounding to whole ticks.
    recommended_resync_interval_s : float or None
        :func:`recommended_resync_interval_s` [s] (None if no interval works).
    cpus : tuple of CpuResult
    axes : tuple of AxisResult
    arcs : tuple of ArcResult
    contour_max_counts, contour_rms_counts : float
        Contour error over every master tick [counts].
    checks : tuple of Check
        Before and during motion.
    interpolation : Interpolation
    time_s : ndarray
        Master ticks ``k · period_s`` [s].
    command_counts : ndarray of int64, shape (ticks, axes)
        Commands [counts] (the path, then its end held).
    path_counts : ndarray, shape (ticks, axes)
        Programmed positions [counts].
    actual_counts : ndarray, shape (ticks, axes)
        Plant positions at the master ticks [counts].
    contour_counts : ndarray
        Contour error per master tick [counts].
    """

    name: str
    seed: int
    period_s: float
    bus: dict[str, float]
    resync_interval_s: float
    recommended_resync_interval_s: float | None
    cpus: tuple[CpuResult, ...]
    axes: tuple[AxisResult, ...]
    arcs: tuple[ArcResult, ...]
    contour_max_counts: float
    contour_rms_counts: float
    checks: tuple[Check, ...]
    interpolation: Interpolation = field(repr=False)
    time_s: np.ndarray = field(repr=False)
    command_counts: np.ndarray = field(repr=False)
    path_counts: np.ndarray = field(repr=False)
    actual_counts: np.ndarray = field(repr=False)
    contour_counts: np.ndarray = field(repr=False)

    @property
    def passed(self) -> bool:
        """True if every check passed."""
        return all(c.passed for c in self.checks)

    @property
    def failed_checks(self) -> tuple[Check, ...]:
        """The checks that failed."""
        return tuple(c for c in self.checks if not c.passed)

    @property
    def axis_names(self) -> tuple[str, ...]:
        """Axis names in column order."""
        return tuple(a.name for a in self.axes)

    @property
    def worst_underrun_margin(self) -> int:
        """Lowest queue level before a pop over every slave [setpoints]."""
        return min(c.min_level for c in self.cpus)

    @property
    def tracking_error_counts(self) -> np.ndarray:
        """``command − actual`` per master tick and axis [counts]."""
        return self.command_counts - self.actual_counts

    def to_dict(self, arrays: bool = False) -> dict[str, Any]:
        """Plain JSON-able dict with ``"schema": "servotune.linkage/1"``.

        Parameters
        ----------
        arrays : bool
            Also the per-tick arrays (queue levels, radial deviations); off by default.
        """
        return {
            "arcs": [a.to_dict(arrays) for a in self.arcs],
            "axes": [a.to_dict() for a in self.axes],
            "bus": {
                k: v if isinstance(v, int) else json_float(float(v))
                for k, v in sorted(self.bus.items())
            },
            "checks": [c.to_dict() for c in self.checks],
            "contour_max_counts": self.contour_max_counts,
            "contour_rms_counts": self.contour_rms_counts,
            "cpus": [c.to_dict(arrays) for c in self.cpus],
            "duration_s": self.interpolation.duration_s,
            "name": self.name,
            "passed": self.passed,
            "period_s": self.period_s,
            "recommended_resync_interval_s": self.recommended_resync_interval_s,
            "resync_interval_s": self.resync_interval_s,
            "schema": SCHEMA,
            "seconds": int(self.time_s.size) * self.period_s,
            "seed": self.seed,
            "worst_underrun_margin": self.worst_underrun_margin,
        }


def _optional_time(x: float) -> float | None:
    return None if x < 0.0 else float(x)


def run_linkage(
    config: LinkageConfig,
    *,
    seconds: float | None = None,
    seed: int = 0,
    gains: Mapping[str, PIGains] | None = None,
) -> LinkageResult:
    """Simulate the linkage: master interpolation and broadcast, slave queues, clocks, loops.

    Event-driven in master time (see the module docstring for the timing model and the sync
    semantics): block arrivals, every slave's ticks by its own clock, syncs, measurements at
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


def format_linkage_summary(result: LinkageResult) -> str:
    """A short text summary of a run (what ``servotune linkage`` prints).

    Returns
    -------
    str
        Several lines, no trailing newline.
    """
    b = result.bus
    rec = result.recommended_resync_interval_s
    lines = [
        f"linkage {result.name}: {len(result.axes)} axes on {len(result.cpus)} slave CPUs, "
        f"{result.time_s.size * result.period_s:.3f} s at {result.period_s * 1e3:g} ms, "
        f"seed {result.seed}",
        f"  bus        frame {int(b['frame_bytes'])} bytes = {b['frame_s'] * 1e3:.3f} ms every "
        f"{b['broadcast_period_s'] * 1e3:.3f} ms (utilisation {b['utilisation'] * 100:.1f} %), "
        f"lead {b['lead_s'] * 1e3:.2f} ms",
        f"  clock      resync every {result.resync_interval_s:g} s"
        + (" (start only)" if not result.resync_interval_s else "")
        + (f"; recommended {rec:g} s" if rec is not None else ""),
    ]
    for c in result.cpus:
        first = f" (first {c.first_underrun_s:.3f} s)" if c.first_underrun_s is not None else ""
        firsto = f" (first {c.first_overrun_s:.3f} s)" if c.first_overrun_s is not None else ""
        lines.append(
            f"  cpu {c.name:<6} {c.clock_ppm:+8.1f} ppm  axes {','.join(c.axes):<10} queue "
            f"{c.min_level}..{c.max_level} of {c.queue_depth}  underruns {c.underruns}{first}  "
            f"overruns {c.overruns}{firsto}  skipped {c.skipped}"
        )
    for a in result.axes:
        fault = f"  FAULT {a.fault} at {a.first_fault_s:.3f} s" if a.fault else ""
        lines.append(
            f"  axis {a.name:<5} on {a.cpu:<6} kp {a.kp:.4g} ki {a.ki:.4g}"
            f"{' (tuned)' if a.tuned else ''}  tracking error max {a.max_abs_err_counts:.1f} "
            f"rms {a.rms_err_counts:.1f} counts{fault}"
        )
    lines.append(
        f"  contour    max {result.contour_max_counts:.2f} counts, rms "
        f"{result.contour_rms_counts:.2f} counts"
    )
    for arc in result.arcs:
        lines.append(
            f"  circle     move {arc.move} in {'/'.join(arc.plane)}, R {arc.radius_counts:g}: "
            f"radial deviation {arc.min_dev_counts:+.2f} … {arc.max_dev_counts:+.2f}, "
            f"circularity {arc.circularity_counts:.2f} counts at constant feed "
            f"({arc.circularity_whole_counts:.2f} with the ramps)"
        )
    failed = result.failed_checks
    lines.append("  PASSED" if not failed else "  FAILED: " + "; ".join(c.detail for c in failed))
    return "\n".join(lines)
