"""The linkage configuration: axes, path, the whole machine, and its TOML reader.

Frozen dataclasses validated on construction; :func:`load_linkage` reads a file,
:func:`linkage_from_dict` its parsed contents. They only load: the gains a file leaves out are
resolved by the caller (:func:`servotune.arch.linkage.synthesis.resolve_gains`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from servotune.arch.bounds import MAX_ACCEL_CPS2, MAX_GAIN, MAX_SECONDS, MAX_SPEED_CPS
from servotune.arch.linkage.bus import Bus, Clock, SlaveCpu
from servotune.errors import ConfigError, RigError
from servotune.io.files import parse_toml_as, read_bytes
from servotune.io.sections import build_section
from servotune.laws.axis import check_filter_designs
from servotune.laws.filters import Section, SectionQ
from servotune.laws.pi import PIGains
from servotune.plant import Plant
from servotune.rig import MAX_LOCK_GAIN, Rig, filters_from_array, load_rig, plant_from_table
from servotune.validate import (
    check_integer,
    check_keys,
    check_number,
    check_table,
    is_number,
    name_and_description,
    show_value,
)

__all__ = [
    "MAX_COUNTS",
    "SCHEMA",
    "LinkageAxis",
    "LinkageConfig",
    "Move",
    "Toolpath",
    "linkage_from_dict",
    "load_linkage",
]

SCHEMA = "servotune.linkage/1"
"""Version tag of :meth:`LinkageResult.to_dict`."""

MAX_COUNTS = 1e12
"""Largest position, centre or distance magnitude of the path [counts]."""
_MAX_LAG_TICKS = 60  # longest lag compute_s + delay_s accepted [periods]


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkageAxis:
    """One axis of the linkage: its plant and its position loop on the slave.

    Parameters
    ----------
    name : str
        Axis name (the key of ``[axis.<name>]``).
    plant : Plant
        Axis model (docs/formats.md#axis-model).
    kp : float or None
        PI proportional gain [codes/count]; None (with ``ki``): to be resolved by the caller
        (:func:`~servotune.arch.linkage.synthesis.resolve_gains` tunes it).
    ki : float or None
        PI integral gain [codes/(count·s)]; None (with ``kp``): as ``kp``.
    lock_gain_codes_per_count : float
        Position-lock gain [codes/count] (the runtime's lock module; 0.4 on the
        example rig).
    following_error_limit_counts : int
        Following-error trip threshold [counts]; 0 disables the trip.
    counter_init : int
        Counter register value at the start [counts].
    filters : tuple of Section
        The axis's output filters as designed (``[[axis.<name>.filters]]``, up to
        :data:`~servotune.laws.axis.MAX_FILTERS`: docs/formats.md#filters), in the order they
        run; the slave runs them realised at ``period_s`` (:meth:`LinkageConfig.axis_filters`).
    gains_tuned : bool
        True if ``kp`` and ``ki`` were tuned by
        :func:`~servotune.arch.linkage.synthesis.resolve_gains` (the file gave none), as a run
        shows them. Not a file key: :func:`linkage_from_dict` refuses it.
    """

    name: str
    plant: Plant
    kp: float | None = None
    ki: float | None = None
    lock_gain_codes_per_count: float = 0.4
    following_error_limit_counts: int = 0
    counter_init: int = 0
    filters: tuple[Section, ...] = ()
    gains_tuned: bool = False

    def __post_init__(self) -> None:
        check_filter_designs(self.filters, error=ConfigError)
        if (self.kp is None) != (self.ki is None):
            raise ConfigError(
                f"kp and ki must be given together (or neither, to tune them), got "
                f"kp={show_value(self.kp)}, ki={show_value(self.ki)}"
            )
        if self.kp is not None:
            check_number("kp", self.kp, "codes/count", hi=MAX_GAIN, error=ConfigError)
            check_number("ki", self.ki, "codes/(count·s)", hi=MAX_GAIN, error=ConfigError)
        check_number(
            "lock_gain_codes_per_count",
            self.lock_gain_codes_per_count,
            "codes/count",
            strict=True,
            hi=MAX_LOCK_GAIN,
            error=ConfigError,
        )
        check_integer(
            "following_error_limit_counts",
            self.following_error_limit_counts,
            "counts",
            hi=2**31 - 1,
            error=ConfigError,
        )
        check_integer("counter_init", self.counter_init, "counts", hi=2**32 - 1, error=ConfigError)
        if not isinstance(self.gains_tuned, bool):
            raise ConfigError(
                f"gains_tuned must be True or False, got {show_value(self.gains_tuned)}"
            )
        if self.gains_tuned and self.kp is None:
            raise ConfigError("gains_tuned marks tuned gains: it needs kp and ki")

    @property
    def gains(self) -> PIGains | None:
        """The PI gains, or None if they are still to be resolved."""
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
            check_number(
                "dwell_s", self.dwell_s, "s", strict=True, hi=MAX_SECONDS, error=ConfigError
            )
            for k in ("feed_cps", "plane", "centre", "angle_deg"):
                if getattr(self, k) is not None:
                    raise ConfigError(f"{k} is not for a dwell; a dwell takes kind, dwell_s")
            if self.to:
                raise ConfigError("to is not for a dwell; a dwell takes kind, dwell_s")
            return
        if self.dwell_s is not None:
            raise ConfigError(f"dwell_s is for dwells only, got it on a {self.kind}")
        check_number(
            "feed_cps", self.feed_cps, "counts/s", strict=True, hi=MAX_SPEED_CPS, error=ConfigError
        )
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
            check_number(
                "angle_deg", self.angle_deg, "deg", strict=True, hi=3600.0, error=ConfigError
            )


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
        check_number(
            "max_feed_cps",
            self.max_feed_cps,
            "counts/s",
            strict=True,
            hi=MAX_SPEED_CPS,
            error=ConfigError,
        )
        check_number(
            "max_accel_cps2",
            self.max_accel_cps2,
            "counts/s²",
            strict=True,
            hi=MAX_ACCEL_CPS2,
            error=ConfigError,
        )
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
    axes: tuple[LinkageAxis, ...]
    cpus: tuple[SlaveCpu, ...]
    rig: Rig
    rig_file: str
    period_s: float
    bus: Bus
    clock: Clock
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
            if lag >= _MAX_LAG_TICKS * self.period_s:
                raise ConfigError(
                    f"axis.{a.name}.plant.delay_s: compute_s + delay_s = {lag:g} s must be "
                    f"shorter than {_MAX_LAG_TICKS} periods"
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

    def axis_filters(self, name: str) -> tuple[SectionQ, ...]:
        """Axis ``name``'s output filters as its slave runs them: realised at ``period_s`` for
        inputs within the rig's D/A range (:meth:`servotune.rig.Rig.realize_filters`)."""
        return self.rig.realize_filters(self.axis(name).filters, self.period_s)

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
    return check_table(data, key, error=ConfigError, required=required)


def _sections(cls: type, tables: Any, where: str) -> list[Any]:
    """An array of tables (``[[cpu]]``, ``[[path.move]]``), each built as a ``cls``."""
    if not isinstance(tables, list) or not tables:
        raise ConfigError(f"{where} must be one or more [[{where}]] tables")
    out = []
    for i, t in enumerate(tables):
        if not isinstance(t, Mapping):
            raise ConfigError(f"{where}[{i}] must be a table")
        out.append(build_section(cls, t, f"{where}[{i}]", ConfigError))
    return out


def linkage_from_dict(
    data: Mapping[str, Any],
    base_dir: str | Path,
    default_name: str = "linkage",
    *,
    rig: Rig | None = None,
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
    rig : Rig, optional
        The rig the ``rig`` path names, already read (a caller that hashes the bytes it
        parsed, as :func:`~servotune.arch.linkage.plan.plan_linkage` does); default: read it.

    Returns
    -------
    LinkageConfig
        The configuration, with its rig.

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
    if rig is None:
        try:
            rig = load_rig(Path(base_dir) / rig_ref)
        except RigError as exc:
            raise ConfigError(f"rig: {exc}") from None
    bus = build_section(Bus, _table(data, "bus"), "bus", ConfigError)
    clock = build_section(Clock, _table(data, "clock", required=False), "clock", ConfigError)
    cpus = _sections(SlaveCpu, data.get("cpu"), "cpu")
    axes = []
    raw_filters = {}
    for name, at in _table(data, "axis").items():
        if not isinstance(at, Mapping):
            raise ConfigError(f"[axis.{name}] must be a table")
        at = dict(at)
        raw_filters[name] = at.pop("filters", [])
        pt = at.pop("plant", None)
        if not isinstance(pt, Mapping):
            raise ConfigError(f"missing table [axis.{name}.plant]")
        plant = plant_from_table(pt, f"axis.{name}.plant", rig.dac.range_v, error=ConfigError)
        # gains_tuned is fixed, so not a key of the file (an unknown key, refused)
        axes.append(
            build_section(
                LinkageAxis,
                at,
                f"axis.{name}",
                ConfigError,
                name=name,
                plant=plant,
                gains_tuned=False,
            )
        )
    pt = dict(_table(data, "path"))
    moves = _sections(Move, pt.pop("move", None), "path.move")
    path = build_section(Toolpath, pt, "path", ConfigError, moves=tuple(moves))
    top: dict[str, Any] = {}
    for key in ("period_s", "settle_s"):
        if key in data:
            top[key] = data[key]
    if "period_s" not in top:
        raise ConfigError("missing key period_s (the nominal sampling period [s])")
    config = LinkageConfig(
        **name_and_description(data, "", default_name, error=ConfigError),
        path=path,
        axes=tuple(axes),
        cpus=tuple(cpus),
        rig=rig,
        rig_file=rig_ref,
        bus=bus,
        clock=clock,
        **top,
    )
    if not any(raw_filters.values()):
        return config
    try:  # realisable at the period (checked above), for inputs within the D/A's range
        filtered = tuple(
            replace(
                a,
                filters=filters_from_array(
                    raw_filters[a.name],
                    f"axis.{a.name}.filters",
                    config.period_s,
                    rig.dac.filter_input_bound,
                ),
            )
            for a in config.axes
        )
    except RigError as exc:
        raise ConfigError(str(exc)) from None
    return replace(config, axes=filtered)


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
        kp = 0.36                         # [codes/count]      } optional: if absent,
        ki = 1.44                         # [codes/(count·s)]  } resolve_gains tunes them
        following_error_limit_counts = 12288   # optional, 0 = no trip
        lock_gain_codes_per_count = 0.4   # optional
        counter_init = 0                  # optional
        [axis.x.plant]                    # the axis model's names: gain_cps_per_v, ...
        [[axis.x.filters]]                # optional, up to 4 (docs/formats.md#filters)

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
        The configuration, with the rig its ``rig`` path names, read and checked. Gains the
        file leaves out stay unset: the caller resolves them
        (:func:`~servotune.arch.linkage.synthesis.resolve_gains`), a loader only loads.

    Raises
    ------
    ConfigError
        If the file (or its rig file) cannot be read, is not TOML, or any field is invalid.
    """
    p = Path(path)
    raw = read_bytes(p, ConfigError, "linkage config")
    return parse_toml_as(
        raw, str(p), ConfigError, "linkage config", lambda d: linkage_from_dict(d, p.parent, p.stem)
    )
