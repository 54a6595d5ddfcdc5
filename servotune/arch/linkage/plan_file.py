"""The linkage plan as data: :class:`LinkagePlan`, its CPUs and path, and the plan file.

:func:`~servotune.arch.linkage.plan.plan_linkage` makes a plan from a linkage config (the
definitions of its figures, the drift and the watermarks, are in
:mod:`~servotune.arch.linkage.plan`); this module holds what a plan is and how it is written
and read. Everything here is re-exported by :mod:`~servotune.arch.linkage.plan`.

Plan file (``"schema": "servotune.linkage-plan/1"``; JSON, sorted keys, two-space indent,
trailing newline: the same config gives the same bytes)::

    {
      "axes": [{"controller": {...}, "cpu": "s1", "name": "x"}, ...]   config order; the
                      controller as the runtime runs it (AxisController.to_dict(): lock gain,
                      PI kp and ki_t as (q, f) pairs, following-error limit)
      "bus": {"baud", "bits_per_byte", "block_size", "bytes_per_setpoint",
              "frame_overhead_bytes", "max_utilisation", "prefill_blocks",
              derived: "frame_bytes", "bits_per_block", "frame_s", "broadcast_period_s",
              "utilisation"}
      "clock": {"resync_interval_ticks", "drift_window_ticks",
                derived: "resync_interval_s", "max_drift_ticks"}
      "config": {"name", "path", "sha256"}     the linkage config planned (bytes as read)
      "cpus": [{"name", "axes", "clock_ppm", "queue_depth", "low_watermark",
                "high_watermark", derived: "drift_ticks"}, ...]
      "design": {...}                          the design floats behind the integers
      "interpolation": {"max_feed_cps", "max_accel_cps2", "ticks", "command_min_counts",
                        "command_max_counts", derived: "duration_s"}
      "period_s": float                        nominal tick of every CPU [s]
      "provenance": {"tool", "tool_version"}
      "rig": {"name", "path", "sha256"}        the config's rig file
      "schema": "servotune.linkage-plan/1"
    }

The derived figures (``bus.frame_bytes`` … ``bus.utilisation``, ``clock.max_drift_ticks``,
``cpus[].drift_ticks``, ``interpolation.duration_s``) are the properties of
:class:`LinkagePlan`; a CPU's drift is :func:`drift_ticks`.

Reading is strict (:func:`read_plan_bytes`): every key known, every integer an integer, every
range checked, and every derived figure equal to what the plan's own fields give (an edited
``utilisation`` is refused); the fields that restate the config (period, interpolation,
CPUs' axes and clocks) must match it when verified. Edit the plan's integers (a queue depth,
a watermark, a PI constant) and :func:`~servotune.arch.linkage.verify_plan_files` judges
what you wrote.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from servotune.arch.linkage.bus import MAX_CLOCK_PPM, MAX_SECONDS, Bus
from servotune.errors import ConfigError
from servotune.io.files import atomic_write_text, json_safe, json_text, parse_json_as
from servotune.laws.axis import AxisController
from servotune.laws.pi import PIConstants
from servotune.provenance import SourceFile
from servotune.validate import check_integer, check_keys, check_number, is_number, show_value

__all__ = [
    "PLAN_SCHEMA",
    "LinkagePlan",
    "PlanCpu",
    "PlanPath",
    "drift_ticks",
    "plan_to_string",
    "read_plan",
    "read_plan_bytes",
    "write_plan",
]

PLAN_SCHEMA = "servotune.linkage-plan/1"
"""Version tag of the plan file."""

_MAX_NAME = 256
_MAX_PATH = 4096
_HEX = frozenset("0123456789abcdef")


# --- the plan ---------------------------------------------------------------------------------


def _text(v: object, where: str, max_len: int = _MAX_NAME, *, empty: bool = False) -> str:
    if not isinstance(v, str) or len(v) > max_len or (not v and not empty):
        what = "a string" if empty else "a non-empty string"
        raise ConfigError(
            f"{where} must be {what} of at most {max_len} characters, got {show_value(v)}"
        )
    return v


def _sha(v: object, where: str) -> str:
    if not isinstance(v, str) or len(v) != 64 or not set(v) <= _HEX:
        raise ConfigError(f"{where} must be 64 lower-case hex digits, got {show_value(v)}")
    return v


def drift_ticks(clock_ppm: float, window_ticks: int) -> float:
    """Ticks a CPU at ``clock_ppm`` drifts from the master's grid over ``window_ticks``
    master ticks, the larger of the two directions: ``window · |ε| / (1 − |ε|)`` [ticks]."""
    eps = abs(clock_ppm) * 1e-6
    return window_ticks * eps / (1.0 - eps)


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanCpu:
    """One slave CPU as planned.

    Parameters
    ----------
    name : str
        As in the config (:class:`~servotune.arch.linkage.bus.SlaveCpu`).
    axes : tuple of str
        The 2–4 axes it drives, in its queue's column order.
    clock_ppm : float
        Its clock's error as configured [ppm] (> 0: runs fast).
    queue_depth : int
        Receive queue capacity [setpoints per axis].
    low_watermark : int
        A level before a pop below this flags a late block [setpoints], 1..``high_watermark``.
    high_watermark : int
        A level after a block above this flags a CPU behind its plan [setpoints],
        ..``queue_depth``.
    """

    name: str
    axes: tuple[str, ...]
    clock_ppm: float
    queue_depth: int
    low_watermark: int
    high_watermark: int

    def __post_init__(self) -> None:
        _text(self.name, "name")
        if isinstance(self.axes, list):
            object.__setattr__(self, "axes", tuple(self.axes))
        if (
            not isinstance(self.axes, tuple)
            or not 2 <= len(self.axes) <= 4
            or not all(isinstance(a, str) and a for a in self.axes)
            or len(set(self.axes)) != len(self.axes)
        ):
            got = list(self.axes) if isinstance(self.axes, tuple) else self.axes
            raise ConfigError(f"axes must name 2 to 4 different axes, got {show_value(got)}")
        check_number(
            "clock_ppm",
            self.clock_ppm,
            "ppm",
            lo=-MAX_CLOCK_PPM,
            hi=MAX_CLOCK_PPM,
            error=ConfigError,
        )
        check_integer(
            "queue_depth", self.queue_depth, "setpoints", lo=1, hi=1_000_000, error=ConfigError
        )
        check_integer(
            "low_watermark",
            self.low_watermark,
            "setpoints",
            lo=1,
            hi=self.queue_depth,
            error=ConfigError,
        )
        check_integer(
            "high_watermark",
            self.high_watermark,
            "setpoints",
            lo=self.low_watermark,
            hi=self.queue_depth,
            error=ConfigError,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanPath:
    """The master's interpolation as planned (restated from the config; checked against it).

    Parameters
    ----------
    max_feed_cps : float
        Feed limit along the path [counts/s].
    max_accel_cps2 : float
        Acceleration limit [counts/s²].
    ticks : int
        Rows of the interpolation, the start row included (duration ``(ticks − 1)·T``).
    command_min_counts, command_max_counts : int
        Range of the commands broadcast over every axis [counts] (what a setpoint must hold).
    """

    max_feed_cps: float
    max_accel_cps2: float
    ticks: int
    command_min_counts: int
    command_max_counts: int

    def __post_init__(self) -> None:
        check_number(
            "max_feed_cps", self.max_feed_cps, "counts/s", strict=True, hi=1e9, error=ConfigError
        )
        check_number(
            "max_accel_cps2",
            self.max_accel_cps2,
            "counts/s²",
            strict=True,
            hi=1e12,
            error=ConfigError,
        )
        check_integer("ticks", self.ticks, "ticks", lo=1, hi=2**40, error=ConfigError)
        check_integer(
            "command_min_counts",
            self.command_min_counts,
            "counts",
            lo=-(2**62),
            hi=2**62,
            error=ConfigError,
        )
        check_integer(
            "command_max_counts",
            self.command_max_counts,
            "counts",
            lo=self.command_min_counts,
            hi=2**62,
            error=ConfigError,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkagePlan:
    """What the linkage's CPUs run, as integers (the module docstring has the file).

    Parameters
    ----------
    config_name, config_path, config_sha256 : str
        The linkage config planned: its name, its path as given, the SHA-256 of its bytes.
    rig_name, rig_path, rig_sha256 : str
        Its rig file (path relative to where the config was given from).
    period_s : float
        Nominal tick of every CPU [s].
    path : PlanPath
    bus : Bus
        The block format (:class:`~servotune.arch.linkage.Bus`).
    resync_ticks : int
        Master ticks between clock-sync broadcasts; 0: only the sync at motion start.
    drift_window_ticks : int
        Master ticks a CPU drifts before a sync realigns it: ``resync_ticks``, or the planned
        run's length if that is 0.
    cpus : tuple of PlanCpu
    axis_names : tuple of str
        In config order (the columns of a block row).
    controllers : tuple of AxisController
        Per axis, the quantised constants (law PI).
    design : mapping
        Design values behind the integers (floats, for people).
    provenance : mapping
        Tool and version.
    """

    config_name: str
    config_path: str
    config_sha256: str
    rig_name: str
    rig_path: str
    rig_sha256: str
    period_s: float
    path: PlanPath
    bus: Bus
    resync_ticks: int
    drift_window_ticks: int
    cpus: tuple[PlanCpu, ...]
    axis_names: tuple[str, ...]
    controllers: tuple[AxisController, ...]
    design: Mapping[str, Any] = field(default_factory=dict, compare=False)
    provenance: Mapping[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        check_number("period_s", self.period_s, "s", lo=1e-6, hi=1.0, error=ConfigError)
        hi = math.floor(MAX_SECONDS / self.period_s)
        check_integer(
            "clock.resync_interval_ticks", self.resync_ticks, "ticks", hi=hi, error=ConfigError
        )
        check_integer(
            "clock.drift_window_ticks",
            self.drift_window_ticks,
            "ticks",
            lo=1,
            hi=2**40,
            error=ConfigError,
        )
        if self.resync_ticks and self.drift_window_ticks != self.resync_ticks:
            raise ConfigError(
                f"clock.drift_window_ticks must be the resync interval "
                f"({self.resync_ticks} ticks) when there is one, got {self.drift_window_ticks}"
            )
        if len(self.controllers) != len(self.axis_names) or not self.axis_names:
            raise ConfigError("axes: one controller per axis, at least one axis")
        if len(set(self.axis_names)) != len(self.axis_names):
            raise ConfigError(f"axes: names must differ, got {list(self.axis_names)}")
        for i, c in enumerate(self.controllers):
            if not isinstance(c.task, PIConstants):
                raise ConfigError(
                    f"axes[{i}].controller.law must be 'pi' (a linkage axis runs PI), got "
                    f"{show_value(c.to_dict()['law'])}"
                )
        if not self.cpus:
            raise ConfigError("cpus: at least one CPU")
        names = [c.name for c in self.cpus]
        if len(set(names)) != len(names):
            raise ConfigError(f"cpus: names must differ, got {names}")
        seen: dict[str, str] = {}
        for i, c in enumerate(self.cpus):
            for a in c.axes:
                if a not in self.axis_names:
                    raise ConfigError(f"cpus[{i}].axes names {a!r}, which is not in axes")
                if a in seen:
                    raise ConfigError(f"axis {a!r} is on two CPUs: {seen[a]!r} and {c.name!r}")
                seen[a] = c.name
        for a in self.axis_names:
            if a not in seen:
                raise ConfigError(f"axis {a!r} is on no CPU")
        if self.path.command_min_counts < -self.setpoint_limit or (
            self.path.command_max_counts > self.setpoint_limit
        ):
            raise ConfigError(
                f"the path's commands span {self.path.command_min_counts}.."
                f"{self.path.command_max_counts} counts, but a {self.bus.bytes_per_setpoint}-byte "
                f"setpoint holds ±{self.setpoint_limit}: raise bus.bytes_per_setpoint"
            )

    # derived figures (the file's derived fields are these; read_plan checks them)

    @property
    def n_axes(self) -> int:
        """Axes of the linkage (the columns of a block row)."""
        return len(self.axis_names)

    @property
    def setpoint_limit(self) -> int:
        """Largest |command| one setpoint holds (signed, ``bytes_per_setpoint`` bytes) [counts]."""
        return 2 ** (8 * self.bus.bytes_per_setpoint - 1) - 1

    @property
    def frame_bytes(self) -> int:
        """Bytes of one block frame [bytes]."""
        return self.bus.frame_bytes(self.n_axes)

    @property
    def bits_per_block(self) -> int:
        """Bits one block frame takes on the line [bits]."""
        return self.frame_bytes * self.bus.bits_per_byte

    @property
    def frame_s(self) -> float:
        """Time one block frame takes on the line [s]."""
        return self.bus.frame_s(self.n_axes)

    @property
    def broadcast_period_s(self) -> float:
        """Time between two blocks, ``B·T`` [s]."""
        return self.bus.block_size * self.period_s

    @property
    def utilisation(self) -> float:
        """``frame_s / broadcast_period_s`` [1]."""
        return self.frame_s / self.broadcast_period_s

    @property
    def resync_interval_s(self) -> float:
        """``resync_ticks · period_s`` [s] (0: start sync only)."""
        return self.resync_ticks * self.period_s

    @property
    def duration_s(self) -> float:
        """The path's duration, ``(ticks − 1)·T`` [s]."""
        return (self.path.ticks - 1) * self.period_s

    def drift_ticks(self, cpu: PlanCpu) -> float:
        """Ticks ``cpu`` drifts between two syncs (:func:`drift_ticks`)."""
        return drift_ticks(cpu.clock_ppm, self.drift_window_ticks)

    @property
    def max_drift_ticks(self) -> float:
        """The largest drift between two syncs over the CPUs [ticks]."""
        return max(self.drift_ticks(c) for c in self.cpus)

    def cpu(self, name: str) -> PlanCpu:
        """The CPU called ``name``."""
        for c in self.cpus:
            if c.name == name:
                return c
        raise ConfigError(f"no CPU {name!r} in the plan; CPUs: {[c.name for c in self.cpus]}")

    def cpu_of(self, axis: str) -> PlanCpu:
        """The CPU that drives ``axis``."""
        for c in self.cpus:
            if axis in c.axes:
                return c
        raise ConfigError(f"no CPU drives axis {axis!r}")

    @property
    def controller_map(self) -> dict[str, AxisController]:
        """The controllers by axis name."""
        return dict(zip(self.axis_names, self.controllers, strict=True))

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (the file's content, derived figures included)."""
        b = self.bus
        return {
            "axes": [
                {"controller": c.to_dict(), "cpu": self.cpu_of(n).name, "name": n}
                for n, c in zip(self.axis_names, self.controllers, strict=True)
            ],
            "bus": {
                "baud": float(b.baud),
                "bits_per_block": self.bits_per_block,
                "bits_per_byte": b.bits_per_byte,
                "block_size": b.block_size,
                "broadcast_period_s": self.broadcast_period_s,
                "bytes_per_setpoint": b.bytes_per_setpoint,
                "frame_bytes": self.frame_bytes,
                "frame_overhead_bytes": b.frame_overhead_bytes,
                "frame_s": self.frame_s,
                "max_utilisation": float(b.max_utilisation),
                "prefill_blocks": b.prefill_blocks,
                "utilisation": self.utilisation,
            },
            "clock": {
                "drift_window_ticks": self.drift_window_ticks,
                "max_drift_ticks": self.max_drift_ticks,
                "resync_interval_s": self.resync_interval_s,
                "resync_interval_ticks": self.resync_ticks,
            },
            "config": {
                "name": self.config_name,
                "path": self.config_path,
                "sha256": self.config_sha256,
            },
            "cpus": [
                {
                    "axes": list(c.axes),
                    "clock_ppm": float(c.clock_ppm),
                    "drift_ticks": self.drift_ticks(c),
                    "high_watermark": c.high_watermark,
                    "low_watermark": c.low_watermark,
                    "name": c.name,
                    "queue_depth": c.queue_depth,
                }
                for c in self.cpus
            ],
            "design": json_safe(self.design),
            "interpolation": {
                "command_max_counts": self.path.command_max_counts,
                "command_min_counts": self.path.command_min_counts,
                "duration_s": self.duration_s,
                "max_accel_cps2": float(self.path.max_accel_cps2),
                "max_feed_cps": float(self.path.max_feed_cps),
                "ticks": self.path.ticks,
            },
            "period_s": float(self.period_s),
            "provenance": json_safe(self.provenance),
            "rig": {"name": self.rig_name, "path": self.rig_path, "sha256": self.rig_sha256},
            "schema": PLAN_SCHEMA,
        }

    @classmethod
    def from_dict(cls, d: object) -> LinkagePlan:
        """Inverse of :meth:`to_dict`, strict (module docstring).

        Raises
        ------
        ConfigError
            Wrong schema, a missing, unknown or malformed field, or a derived figure that is
            not what the plan's fields give (the message names the field).
        """
        if not isinstance(d, dict):
            raise ConfigError("a linkage plan must hold a JSON object")
        if d.get("schema") != PLAN_SCHEMA:
            raise ConfigError(f"schema must be {PLAN_SCHEMA!r}, got {show_value(d.get('schema'))}")
        top = (
            "axes",
            "bus",
            "clock",
            "config",
            "cpus",
            "interpolation",
            "period_s",
            "rig",
            "schema",
        )
        check_keys(d, "", top, ("design", "provenance"), error=ConfigError)
        src = {key: _read_source(d[key], key) for key in ("config", "rig")}
        bus_d = check_keys(d["bus"], "bus", _BUS_KEYS + _BUS_DERIVED, error=ConfigError)
        bus = _build(Bus, {k: bus_d[k] for k in _BUS_KEYS}, "bus")
        path_d = check_keys(
            d["interpolation"], "interpolation", (*_PATH_KEYS, "duration_s"), error=ConfigError
        )
        path = _build(PlanPath, {k: path_d[k] for k in _PATH_KEYS}, "interpolation")
        clock_keys = (
            "drift_window_ticks",
            "max_drift_ticks",
            "resync_interval_s",
            "resync_interval_ticks",
        )
        clock = check_keys(d["clock"], "clock", clock_keys, error=ConfigError)
        cpus, cpu_drift = _read_cpus(d["cpus"])
        names, cpu_names, ctls = _read_axes(d["axes"])
        period = d["period_s"]
        if type(period) is not float:
            raise ConfigError(f"period_s must be a number [s], got {show_value(period)}")
        for key in ("design", "provenance"):
            if not isinstance(d.get(key, {}), dict):
                raise ConfigError(f"{key} must be an object")
        plan = cls(
            config_name=src["config"][0],
            config_path=src["config"][1],
            config_sha256=src["config"][2],
            rig_name=src["rig"][0],
            rig_path=src["rig"][1],
            rig_sha256=src["rig"][2],
            period_s=period,
            path=path,
            bus=bus,
            resync_ticks=clock["resync_interval_ticks"],
            drift_window_ticks=clock["drift_window_ticks"],
            cpus=tuple(cpus),
            axis_names=tuple(names),
            controllers=tuple(ctls),
            design=d.get("design", {}),
            provenance=d.get("provenance", {}),
        )
        for i, (n, c) in enumerate(zip(names, cpu_names, strict=True)):
            if plan.cpu_of(n).name != c:
                raise ConfigError(
                    f"axes[{i}].cpu is {c!r} but axis {n!r} is on cpu {plan.cpu_of(n).name!r}"
                )
        derived = [(f"bus.{k}", bus_d[k], getattr(plan, k)) for k in _BUS_DERIVED]
        derived += [
            ("interpolation.duration_s", path_d["duration_s"], plan.duration_s),
            ("clock.resync_interval_s", clock["resync_interval_s"], plan.resync_interval_s),
            ("clock.max_drift_ticks", clock["max_drift_ticks"], plan.max_drift_ticks),
        ]
        derived += [
            (f"cpus[{i}].drift_ticks", got, plan.drift_ticks(c))
            for i, (c, got) in enumerate(zip(cpus, cpu_drift, strict=True))
        ]
        _check_derived(derived)
        return plan


# --- the plan file ----------------------------------------------------------------------------

_BUS_KEYS = ("baud", "bits_per_byte", "block_size", "bytes_per_setpoint",
             "frame_overhead_bytes", "max_utilisation", "prefill_blocks")  # fmt: skip
_BUS_DERIVED = ("bits_per_block", "broadcast_period_s", "frame_bytes", "frame_s", "utilisation")
_PATH_KEYS = tuple(f.name for f in fields(PlanPath))
_CPU_KEYS = tuple(f.name for f in fields(PlanCpu))


def _build(cls: type, values: Mapping[str, Any], where: str) -> Any:
    """``cls(**values)``, a failure named under ``where``."""
    try:
        return cls(**values)
    except ConfigError as exc:
        raise ConfigError(f"{where}.{exc}") from None


def _read_source(value: object, key: str) -> tuple[str, str, str]:
    """A plan's ``config`` or ``rig`` entry: ``(name, path, sha256)``."""
    t = check_keys(value, key, ("name", "path", "sha256"), error=ConfigError)
    return (
        _text(t["name"], f"{key}.name"),
        _text(t["path"], f"{key}.path", _MAX_PATH, empty=True),
        _sha(t["sha256"], f"{key}.sha256"),
    )


def _read_cpus(cpus_l: object) -> tuple[list[PlanCpu], list[Any]]:
    """A plan's ``cpus``: each CPU, and the ``drift_ticks`` each states (checked later against
    what the plan gives)."""
    if not isinstance(cpus_l, list) or not 1 <= len(cpus_l) <= 64:
        raise ConfigError("cpus must be a list of 1 to 64 CPUs")
    cpus, cpu_drift = [], []
    for i, c in enumerate(cpus_l):
        c = check_keys(c, f"cpus[{i}]", (*_CPU_KEYS, "drift_ticks"), error=ConfigError)
        cpus.append(_build(PlanCpu, {k: c[k] for k in _CPU_KEYS}, f"cpus[{i}]"))
        cpu_drift.append(c["drift_ticks"])
    return cpus, cpu_drift


def _read_axes(axes_l: object) -> tuple[list[str], list[str], list[AxisController]]:
    """A plan's ``axes``: their names, the CPU each states and their controllers."""
    if not isinstance(axes_l, list) or not 1 <= len(axes_l) <= 256:
        raise ConfigError("axes must be a list of 1 to 256 axes")
    names, cpu_names, ctls = [], [], []
    for i, a in enumerate(axes_l):
        a = check_keys(a, f"axes[{i}]", ("controller", "cpu", "name"), error=ConfigError)
        names.append(_text(a["name"], f"axes[{i}].name"))
        cpu_names.append(_text(a["cpu"], f"axes[{i}].cpu"))
        try:
            ctls.append(AxisController.from_dict(a["controller"]))
        except ValueError as exc:
            raise ConfigError(f"axes[{i}].controller: {exc}") from None
    return names, cpu_names, ctls


def _check_derived(derived: list[tuple[str, Any, Any]]) -> None:
    """Each ``(where, stated, given)`` derived figure: the one stated must be the one the
    plan's own fields give (same kind of number, same value)."""
    for where, got, want in derived:
        same = type(got) is int if isinstance(want, int) else is_number(got)
        if not same or got != want:
            raise ConfigError(
                f"{where} is {show_value(got)} but the plan's own fields give "
                f"{want!r}: the plan was edited; plan the config again"
            )


def plan_to_string(plan: LinkagePlan) -> str:
    """The plan file's text: sorted keys, two-space indent, trailing newline."""
    return json_text(plan.to_dict())


def write_plan(plan: LinkagePlan, path: str | Path) -> None:
    """Write a plan file atomically (temporary file, then rename)."""
    atomic_write_text(path, plan_to_string(plan))


def read_plan_bytes(raw: bytes, src: str) -> LinkagePlan:
    """Parse and check a plan from the file's bytes (``src`` names it in messages).

    Raises
    ------
    ConfigError
        Not UTF-8 JSON, or not a valid plan: one line naming ``src`` and the field.
    """
    return parse_json_as(raw, f"linkage plan {src!r}", ConfigError, LinkagePlan.from_dict)


def read_plan(path: str | Path) -> LinkagePlan:
    """Read and check a plan file (:func:`read_plan_bytes` of its bytes).

    Raises
    ------
    ConfigError
        The file is missing, not JSON, or not a valid plan.
    """
    return read_plan_bytes(SourceFile.read(path, ConfigError, "linkage plan").raw, str(path))
