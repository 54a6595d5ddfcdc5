"""The gantry configuration: bus, beam, drives, compensator settings, move, load, and the cases.

Frozen dataclasses validated on construction (against the bounds :data:`MAX_CYCLE_S`, ...);
:func:`gantry_from_dict` builds a :class:`GantryConfig` from parsed TOML (the reader that also
resolves the gains, :func:`~servotune.arch.gantry.load.load_gantry`, is in ``load``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from servotune.analysis.margins import MarginLimits
from servotune.arch.bounds import MAX_ACCEL_CPS2, MAX_GAIN, MAX_SECONDS, MAX_SPEED_CPS
from servotune.errors import ConfigError, RigError, SpecError
from servotune.io.sections import build_section
from servotune.laws.axis import AxisController, check_filter_designs
from servotune.laws.filters import Section, SectionQ
from servotune.laws.pi import PIGains
from servotune.laws.shaping import KINDS as SHAPER_KINDS
from servotune.laws.sync import SYNC_LAWS, SyncConstants, SyncGains
from servotune.plant import Plant
from servotune.rig import Rig, filters_from_array, load_rig, plant_from_table
from servotune.validate import check_integer, check_keys, check_number, check_table, show_value

__all__ = [
    "CASES",
    "DRIVE_LOCK_GAIN",
    "MAX_BEAM",
    "MAX_COUNTS",
    "MAX_CYCLE_S",
    "MAX_GAIN",
    "MAX_LATENCY_CYCLES",
    "MAX_LOAD_V",
    "MAX_SECONDS",
    "MAX_SPEED_CPS",
    "MIN_CYCLE_S",
    "SHAPER_CHOICES",
    "TOPOLOGIES",
    "T_CROSS",
    "T_FOLLOWING",
    "T_LISTENING",
    "T_PARALLEL",
    "Beam",
    "GantryAxis",
    "GantryBus",
    "GantryConfig",
    "GantryLoad",
    "GantryMove",
    "SyncSettings",
    "gantry_from_dict",
]


TOPOLOGIES = ("parallel", "following", "listening", "cross")
"""Gantry topologies, in the order of the comparison table."""

CASES = ("load", "mismatch")
"""Comparison cases: ``load`` — both sides with the master's plant, a load step on one side
during the move; ``mismatch`` — each side with its own plant, no load."""

T_PARALLEL, T_FOLLOWING, T_LISTENING, T_CROSS = range(4)

SHAPER_CHOICES = ("none", "auto", *SHAPER_KINDS)
"""What ``[move] shaper`` takes (:mod:`servotune.arch.gantry.shaping`)."""


# Bounds of the configuration's fields (a typo must not size the simulation's arrays)
MAX_CYCLE_S = 0.01
"""Longest bus cycle [s] (10 ms)."""
MIN_CYCLE_S = 1e-6
"""Shortest bus cycle [s]."""
MAX_LATENCY_CYCLES = 1000
"""Largest feedback latency [cycles]."""
# MAX_SECONDS (a run is also at most 5e6 cycles, and at least 100), MAX_GAIN, MAX_SPEED_CPS
# and MAX_ACCEL_CPS2 are every architecture's (servotune.arch.bounds)
MAX_COUNTS = 2**31 - 1
"""Largest count threshold or move distance [counts]."""
MAX_BEAM = 1e3
"""Largest beam stiffness [V/count] or damping [V·s/count]."""
MAX_LOAD_V = 1000.0
"""Largest load step magnitude [V]."""
_MIN_CYCLES = 100
DRIVE_LOCK_GAIN = 0.4
"""A drive's position-lock gain [D/A codes per count] (it holds position in lock mode)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryBus:
    """Fieldbus timing.

    Parameters
    ----------
    cycle_s : float
        Communication (and drive position-loop) cycle [s].
    jitter_s : float
        Sync jitter: each sample instant moves uniformly within ±jitter_s [s].
    latency_cycles : int
        Cycles until the master's feedback reaches the slave and the CNC (>= 1).
    compute_s : float
        Sample → output write inside a drive [s], < cycle_s.
    """

    cycle_s: float = 0.001
    jitter_s: float = 1e-6
    latency_cycles: int = 1
    compute_s: float = 0.0001

    def __post_init__(self) -> None:
        check_number(
            "cycle_s", self.cycle_s, "s", lo=MIN_CYCLE_S, hi=MAX_CYCLE_S, error=ConfigError
        )
        check_number("jitter_s", self.jitter_s, "s", hi=0.01 * self.cycle_s, error=ConfigError)
        check_integer(
            "latency_cycles",
            self.latency_cycles,
            "cycles",
            lo=1,
            hi=MAX_LATENCY_CYCLES,
            error=ConfigError,
        )
        check_number(
            "compute_s", self.compute_s, "s", hi=self.cycle_s, hi_strict=True, error=ConfigError
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class Beam:
    """Mechanical coupling of the two sides through the beam, as motor-input volts.

    The coupling is the beam's **racking mode**: with both sides' drive model
    ``τ v̇ + v = K (u ∓ f)``, ``f = k e + c ė`` on the sync error ``e = p_master − p_slave``,
    the error obeys ``τ ë + (1 + 2 K c) ė + 2 K k e = 0``: a mode at
    ``ω = √(2 K k / τ)`` with damping ``ζ = (1 + 2 K c) / (2 ω τ)`` (the drives' own viscous
    term gives it at least ``1 / (2 ω τ)``). :meth:`racking` gives it for a plant;
    ``racking_hz``/``racking_damping`` set the beam from it instead of ``k``, ``c``
    (a :class:`GantryConfig` resolves them with its master's plant).

    Parameters
    ----------
    stiffness_v_per_count : float
        Spring: the force of a sync error, on both motors with opposite signs [V/count].
    damping_v_s_per_count : float
        Damper on the speed difference [V/(count/s)].
    racking_hz, racking_damping : float or None
        The racking mode's frequency [Hz] and damping ratio [-], instead of the two above
        (both or neither; the stiffness and damping then left 0 in the file).
    """

    stiffness_v_per_count: float = 0.0
    damping_v_s_per_count: float = 0.0
    racking_hz: float | None = None
    racking_damping: float | None = None

    def racking(self, plant: Plant) -> tuple[float, float]:
        """The racking mode's frequency [Hz] and damping ratio of this beam between two sides
        with ``plant``'s drive (its mean gain and time constant); ``(0, inf)`` uncoupled."""
        k_g, tau = plant.mean_gain_cps_per_v, plant.tau_s
        w2 = 2.0 * k_g * self.stiffness_v_per_count / tau
        if w2 <= 0.0:
            return 0.0, math.inf
        w = math.sqrt(w2)
        return w / (2.0 * math.pi), (1.0 + 2.0 * k_g * self.damping_v_s_per_count) / (2 * w * tau)

    def resolved(self, plant: Plant) -> Beam:
        """This beam with ``racking_hz``/``racking_damping`` turned into stiffness and damping
        for two sides with ``plant``'s drive (itself when they are not set)."""
        if self.racking_hz is None:
            return self
        k_g, tau = plant.mean_gain_cps_per_v, plant.tau_s
        w = 2.0 * math.pi * self.racking_hz
        zeta = self.racking_damping
        assert zeta is not None  # checked with racking_hz
        if 2.0 * zeta * w * tau < 1.0:
            raise ConfigError(
                f"beam.racking_damping {zeta:g} is below the drives' own damping of a "
                f"{self.racking_hz:g} Hz racking mode, 1 / (2 ω τ) = {1 / (2 * w * tau):.3g} "
                f"(τ = {tau:g} s): raise it or the frequency"
            )
        return Beam(
            stiffness_v_per_count=w * w * tau / (2.0 * k_g),
            damping_v_s_per_count=(2.0 * zeta * w * tau - 1.0) / (2.0 * k_g),
        )

    def __post_init__(self) -> None:
        if (self.racking_hz is None) != (self.racking_damping is None):
            raise ConfigError("beam.racking_hz and beam.racking_damping go together")
        if self.racking_hz is not None:
            check_number("racking_hz", self.racking_hz, "Hz", strict=True, error=ConfigError)
            check_number(
                "racking_damping", self.racking_damping, "-", strict=True, error=ConfigError
            )
            if self.stiffness_v_per_count or self.damping_v_s_per_count:
                raise ConfigError(
                    "beam: give racking_hz/racking_damping or stiffness_v_per_count/"
                    "damping_v_s_per_count, not both"
                )
        check_number(
            "stiffness_v_per_count",
            self.stiffness_v_per_count,
            "V/count",
            hi=MAX_BEAM,
            error=ConfigError,
        )
        check_number(
            "damping_v_s_per_count",
            self.damping_v_s_per_count,
            "V·s/count",
            hi=MAX_BEAM,
            error=ConfigError,
        )

    @property
    def coupled(self) -> bool:
        """True if the beam couples the sides."""
        return self.stiffness_v_per_count > 0 or self.damping_v_s_per_count > 0


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryAxis:
    """One side's drive.

    Parameters
    ----------
    plant : Plant
        The side's model (volts → counts).
    kp, ki : float or None
        Drive position-loop PI gains [codes/count], [codes/(count·s)]; None: tuned at the bus
        cycle (:func:`resolve_gains`).
    following_error_limit_counts : int
        Drive following-error trip [counts], 0 off.
    counter_init : int
        Counter register at power-up.
    gain_spread, tau_spread : float or None
        This drive's relative spread of gain and time constant in the robustness checks [1],
        0..0.9 (e.g. from its own identification); None: the ``[margins]`` table's.
    filters : tuple of Section
        The drive's output filters as designed (``[[axis.<side>.filters]]``, up to
        :data:`~servotune.laws.axis.MAX_FILTERS`: docs/formats.md#filters), in the order they
        run; the drive runs them realised at the bus cycle (:meth:`GantryConfig.drive_filters`).
    controller : AxisController or None
        The runtime constants a gantry tuning holds (not a config-file key): when set, the
        drive runs exactly these (:meth:`GantryConfig.controllers`), and ``kp``/``ki`` are
        their values (:func:`servotune.arch.gantry.tuning.apply_tuning`).
    """

    plant: Plant
    kp: float | None = None
    ki: float | None = None
    following_error_limit_counts: int = 0
    counter_init: int = 0
    gain_spread: float | None = None
    tau_spread: float | None = None
    filters: tuple[Section, ...] = ()
    controller: AxisController | None = None

    def __post_init__(self) -> None:
        check_filter_designs(self.filters, error=ConfigError)
        for name, unit in (("kp", "codes/count"), ("ki", "codes/(count·s)")):
            if getattr(self, name) is not None:
                check_number(name, getattr(self, name), unit, hi=MAX_GAIN, error=ConfigError)
        for name in ("gain_spread", "tau_spread"):
            if getattr(self, name) is not None:
                check_number(name, getattr(self, name), "1", hi=0.9, error=ConfigError)
        check_integer(
            "following_error_limit_counts",
            self.following_error_limit_counts,
            "counts",
            hi=MAX_COUNTS,
            error=ConfigError,
        )
        check_integer(
            "counter_init", self.counter_init, "register value", hi=2**32 - 1, error=ConfigError
        )

    @property
    def gains(self) -> PIGains:
        """The drive's PI gains (after :func:`resolve_gains`)."""
        if self.kp is None or self.ki is None:
            raise ValueError("drive gains are not resolved; call resolve_gains(config)")
        return PIGains(kp=self.kp, ki=self.ki)


@dataclass(frozen=True, slots=True, kw_only=True)
class SyncSettings:
    """The sync compensator, its synthesis targets and the monitor.

    Parameters
    ----------
    law : str
        ``"pi"`` or ``"pd"``.
    kp, ki, kd : float or None
        Gains [-], [1/s], [s]; None: synthesised (:func:`tune_sync`; PD keeps ``kd``, 0 if
        None, and takes the largest ``kp`` meeting the targets).
    dead_zone_counts, limit_counts : int
        Dead zone and compensation limit [counts].
    warn_counts, trip_counts : int
        Monitor thresholds on |sync error| [counts], 0 off.
    phase_margin_deg, gain_margin_db, max_sensitivity : float
        Synthesis targets for the sync loop.
    constants : SyncConstants or None
        The runtime constants a gantry tuning holds (not a config-file key): when set, the
        compensator runs exactly these (:attr:`GantryConfig.sync_constants`), and the gains,
        dead zone and limit are their values.
    """

    law: str = "pi"
    kp: float | None = None
    ki: float | None = None
    kd: float | None = None
    dead_zone_counts: int = 0
    limit_counts: int = 4096
    warn_counts: int = 0
    trip_counts: int = 0
    phase_margin_deg: float = 50.0
    gain_margin_db: float = 8.0
    max_sensitivity: float = 1.6
    constants: SyncConstants | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.law, str) or self.law not in SYNC_LAWS:
            raise ConfigError(
                f"law must be one of {', '.join(SYNC_LAWS)}, got {show_value(self.law)}"
            )
        for name, unit in (("kp", "-"), ("ki", "1/s"), ("kd", "s")):
            if getattr(self, name) is not None:
                check_number(name, getattr(self, name), unit, hi=MAX_GAIN, error=ConfigError)
        for name in ("dead_zone_counts", "warn_counts", "trip_counts"):
            check_integer(name, getattr(self, name), "counts", hi=MAX_COUNTS, error=ConfigError)
        check_integer(
            "limit_counts", self.limit_counts, "counts", lo=1, hi=MAX_COUNTS, error=ConfigError
        )
        if self.warn_counts and self.trip_counts and self.warn_counts >= self.trip_counts:
            raise ConfigError(
                f"warn_counts must be < trip_counts [counts], got {self.warn_counts} >= "
                f"{self.trip_counts}"
            )
        check_number(
            "phase_margin_deg",
            self.phase_margin_deg,
            "deg",
            strict=True,
            hi=90.0,
            hi_strict=True,
            error=ConfigError,
        )
        check_number(
            "gain_margin_db", self.gain_margin_db, "dB", strict=True, hi=60.0, error=ConfigError
        )
        check_number(
            "max_sensitivity",
            self.max_sensitivity,
            "-",
            lo=1.0,
            strict=True,
            hi=10.0,
            error=ConfigError,
        )

    @property
    def gains(self) -> SyncGains:
        """The compensator's gains (after :func:`resolve_gains`)."""
        if self.kp is None or (self.law == "pi" and self.ki is None):
            raise ValueError("sync gains are not resolved; call resolve_gains(config)")
        return SyncGains(
            law=self.law,
            kp=self.kp,
            ki=self.ki or 0.0 if self.law == "pi" else 0.0,
            kd=self.kd or 0.0 if self.law == "pd" else 0.0,
            dead_zone_counts=self.dead_zone_counts,
            limit_counts=self.limit_counts,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryMargins:
    """What every loop of the gantry must keep, and over which plant set
    (:func:`servotune.arch.gantry.margins.gantry_margins`; the ``[margins]`` table).

    Parameters
    ----------
    min_phase_margin_deg, min_gain_margin_db, max_sensitivity : float
        Limits of every loop (each drive's PI, the sync loop) over the plant set [deg], [dB],
        [1]; defaults 45°, 6 dB, 2.0 (Åström & Hägglund's robust range, as for a single rig).
    extra_cycles : int
        Latency every loop must also take [bus cycles], 0..10.
    gain_spread, tau_spread : float
        Relative spread of the drives' gain and time constant [1], 0..0.9, where a drive
        (``[axis.<name>]``) does not give its own.
    """

    min_phase_margin_deg: float = 45.0
    min_gain_margin_db: float = 6.0
    max_sensitivity: float = 2.0
    extra_cycles: int = 1
    gain_spread: float = 0.2
    tau_spread: float = 0.3

    def __post_init__(self) -> None:
        check_integer("extra_cycles", self.extra_cycles, "cycles", hi=10, error=ConfigError)
        for name in ("gain_spread", "tau_spread"):
            check_number(name, getattr(self, name), "1", hi=0.9, error=ConfigError)
        self.limits  # noqa: B018 (validates the three limits)

    def spreads(self, axis: GantryAxis) -> tuple[float, float]:
        """``(gain_spread, tau_spread)`` of a drive: its own where it gives them, else these."""
        gs = self.gain_spread if axis.gain_spread is None else axis.gain_spread
        ts = self.tau_spread if axis.tau_spread is None else axis.tau_spread
        return gs, ts

    @property
    def limits(self) -> MarginLimits:
        """The three limits as a :class:`~servotune.analysis.margins.MarginLimits`."""
        try:
            return MarginLimits.of(self)
        except SpecError as exc:
            raise ConfigError(str(exc)) from None


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryMove:
    """The CNC's command: a trapezoidal move there, a dwell, and back.

    Parameters
    ----------
    distance_counts : int
        Move length [counts] (signed).
    speed_cps, accel_cps2 : float
        Cruise speed [counts/s] and acceleration [counts/s²].
    start_s : float
        Time of the move's start [s].
    shaper : str
        Input shaping of the command (:mod:`servotune.arch.gantry.shaping`): ``none``,
        ``auto``, ``zv``, ``zvd`` or ``ei``.
    """

    distance_counts: int = 200_000
    speed_cps: float = 60_000.0
    accel_cps2: float = 600_000.0
    start_s: float = 0.05
    shaper: str = "none"

    def __post_init__(self) -> None:
        check_integer(
            "distance_counts",
            self.distance_counts,
            "counts",
            lo=-MAX_COUNTS,
            hi=MAX_COUNTS,
            error=ConfigError,
        )
        if self.distance_counts == 0:
            raise ConfigError("distance_counts must not be 0 [counts]: the study needs a move")
        check_number(
            "speed_cps",
            self.speed_cps,
            "counts/s",
            strict=True,
            hi=MAX_SPEED_CPS,
            error=ConfigError,
        )
        check_number(
            "accel_cps2",
            self.accel_cps2,
            "counts/s²",
            strict=True,
            hi=MAX_ACCEL_CPS2,
            error=ConfigError,
        )
        check_number("start_s", self.start_s, "s", hi=MAX_SECONDS, error=ConfigError)
        if self.shaper not in SHAPER_CHOICES:
            raise ConfigError(
                f"move.shaper must be one of {', '.join(SHAPER_CHOICES)}, "
                f"got {show_value(self.shaper)}"
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryLoad:
    """A load step on one side (the ``load`` case).

    Parameters
    ----------
    axis : str
        ``"master"`` or ``"slave"``.
    time_s : float
        Step time [s].
    volts : float
        Step size, as motor-input volts [V].
    """

    axis: str = "slave"
    time_s: float = 0.5
    volts: float = -0.3

    def __post_init__(self) -> None:
        if self.axis not in ("master", "slave"):
            raise ConfigError(f"axis must be 'master' or 'slave', got {show_value(self.axis)}")
        check_number("time_s", self.time_s, "s", hi=MAX_SECONDS, error=ConfigError)
        check_number("volts", self.volts, "V", lo=-MAX_LOAD_V, hi=MAX_LOAD_V, error=ConfigError)
        if self.volts == 0.0:
            raise ConfigError("volts must not be 0 [V]: the load case needs a load step")


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryConfig:
    """A gantry: hardware, bus, beam, the two drives, the compensator, the test motion.

    Parameters
    ----------
    name : str
    rig : Rig
        Hardware facts (counter bits, D/A, encoder) from the referenced rig file.
    topology : str
        The topology deployed (judged by :func:`compare_topologies`' checks).
    bus, beam, master, slave, sync, move, load, margins :
        See the classes.
    seconds : float
        Length of a run [s].
    """

    name: str = "gantry"
    rig: Rig
    topology: str = "listening"
    bus: GantryBus = field(default_factory=GantryBus)
    beam: Beam = field(default_factory=Beam)
    master: GantryAxis
    slave: GantryAxis
    sync: SyncSettings = field(default_factory=SyncSettings)
    move: GantryMove = field(default_factory=GantryMove)
    load: GantryLoad = field(default_factory=GantryLoad)
    margins: GantryMargins = field(default_factory=GantryMargins)
    seconds: float = 2.0

    def __post_init__(self) -> None:
        if not isinstance(self.name, str):
            raise ConfigError(f"name must be a string, got {show_value(self.name)}")
        if not isinstance(self.topology, str) or self.topology not in TOPOLOGIES:
            raise ConfigError(
                f"topology must be one of {', '.join(TOPOLOGIES)}, got {show_value(self.topology)}"
            )
        object.__setattr__(self, "beam", self.beam.resolved(self.master.plant))
        cyc = self.bus.cycle_s
        check_number("seconds", self.seconds, "s", strict=True, hi=MAX_SECONDS, error=ConfigError)
        if not _MIN_CYCLES <= self.seconds / cyc <= 5e6:
            raise ConfigError(
                f"seconds must be {_MIN_CYCLES} to 5e6 bus cycles ({_MIN_CYCLES * cyc:g} … "
                f"{5e6 * cyc:g} s at cycle_s {cyc:g}) [s], got {show_value(self.seconds)}"
            )
        if not self.move.start_s < self.seconds:
            raise ConfigError(
                f"seconds ({self.seconds:g} s) must be longer than move.start_s "
                f"({show_value(self.move.start_s)} s): the move must start inside the run"
            )

    @property
    def n_cycles(self) -> int:
        """Cycles of a run."""
        return max(1, round(self.seconds / self.bus.cycle_s))

    @property
    def sync_constants(self) -> SyncConstants:
        """The compensator's constants as the runtime holds them: a tuning's
        (``sync.constants``), else the gains quantised at the cycle."""
        if self.sync.constants is not None:
            return self.sync.constants
        return self.sync.gains.quantize(self.bus.cycle_s)

    @property
    def stop_bound_cycles(self) -> int:
        """Cycles from the measured sync error crossing the trip threshold to both axes at 0 V."""
        return self.bus.latency_cycles + 1

    def drive_filters(self, side: str) -> tuple[SectionQ, ...]:
        """Drive ``side``'s (``"master"``/``"slave"``) output filters as it runs them: a
        tuning's (``controller``), else the config's realised at the bus cycle for inputs within
        the rig's D/A range (:meth:`servotune.rig.Rig.realize_filters`)."""
        ax = getattr(self, side)
        if ax.controller is not None:
            return ax.controller.filters
        return self.rig.realize_filters(ax.filters, self.bus.cycle_s)

    def controllers(self) -> tuple[AxisController, AxisController]:
        """The two drives' runtime controllers: a tuning's (``controller``), else PI at the
        bus cycle quantised from the gains (lock gain :data:`DRIVE_LOCK_GAIN`) with the drive's
        output filters (:meth:`drive_filters`)."""
        return tuple(
            ax.controller
            if ax.controller is not None
            else AxisController.from_gains(
                lock_gain_codes_per_count=DRIVE_LOCK_GAIN,
                task_gains=ax.gains,
                period_s=self.bus.cycle_s,
                following_error_limit_counts=ax.following_error_limit_counts,
                filters=self.drive_filters(side),
            )
            for side, ax in (("master", self.master), ("slave", self.slave))
        )  # type: ignore[return-value]


def gantry_from_dict(data: Mapping[str, Any], base_dir: str | Path = ".") -> GantryConfig:
    """Build and validate a :class:`GantryConfig` from parsed TOML.

    Raises
    ------
    ConfigError
        Naming the first invalid table or field, its value and unit.
    """
    check_keys(
        data,
        "",
        (),
        ("gantry", "bus", "beam", "axis", "sync", "move", "load", "margins"),
        error=ConfigError,
        noun="table",
    )

    def table(key: str, required: bool = False) -> Mapping[str, Any]:
        return check_table(data, key, error=ConfigError, required=required)

    meta = dict(table("gantry", required=True))
    if "rig" not in meta:
        raise ConfigError("gantry.rig is missing: the rig file with the hardware facts")
    rig_ref = meta.pop("rig")
    if not isinstance(rig_ref, str) or not 0 < len(rig_ref) <= 4096:
        raise ConfigError(
            f"gantry.rig must be the path of a rig file (at most 4096 characters), got "
            f"{show_value(rig_ref)}"
        )
    rig_path = Path(base_dir) / rig_ref
    try:
        rig = load_rig(rig_path)
    except (RigError, OSError) as exc:  # one line naming the file
        raise ConfigError(f"gantry.rig: {exc}") from None
    axes_t = table("axis", required=True)
    parts = {
        k: build_section(cls, table(k), k, ConfigError)
        for k, cls in (
            ("bus", GantryBus),
            ("beam", Beam),
            ("move", GantryMove),
            ("load", GantryLoad),
            ("margins", GantryMargins),
        )
    }
    drives = {}
    for name in ("master", "slave"):
        at = axes_t.get(name)
        if not isinstance(at, Mapping):
            raise ConfigError(f"missing table [axis.{name}]")
        at = dict(at)
        if not isinstance(at.get("plant"), Mapping):
            raise ConfigError(f"missing table [axis.{name}.plant]")
        plant = plant_from_table(
            at.pop("plant"), f"axis.{name}.plant", rig.dac.range_v, error=ConfigError
        )
        try:  # realisable at the bus cycle, for inputs within the D/A's range
            filters = filters_from_array(
                at.pop("filters", []),
                f"axis.{name}.filters",
                parts["bus"].cycle_s,
                rig.dac.filter_input_bound,
            )
        except RigError as exc:
            raise ConfigError(str(exc)) from None
        drives[name] = build_section(
            GantryAxis,
            at,
            f"axis.{name}",
            ConfigError,
            plant=plant,
            filters=filters,
            controller=None,
        )
    extra = sorted(set(axes_t) - {"master", "slave"})
    if extra:
        raise ConfigError(f"unknown axis [axis.{extra[0]}] (a gantry has master and slave)")
    parts["sync"] = build_section(SyncSettings, table("sync"), "sync", ConfigError, constants=None)
    return build_section(
        GantryConfig,
        meta,
        "gantry",
        ConfigError,
        rig=rig,
        master=drives["master"],
        slave=drives["slave"],
        **parts,
    )


def case_config(cfg: GantryConfig, case: str) -> tuple[GantryConfig, np.ndarray]:
    """The config a case runs (``load``: the slave side a copy of the master's drive and
    plant) and the load per cycle and axis [V]."""
    n = cfg.n_cycles
    load = np.zeros((n, 2))
    if case == "load":
        if not cfg.load.time_s < cfg.seconds:
            raise ConfigError(
                f"gantry.seconds ({cfg.seconds:g} s) must be longer than load.time_s "
                f"({show_value(cfg.load.time_s)} s): the load step must fall inside the run"
            )
        cfg = replace(cfg, slave=replace(cfg.master, counter_init=cfg.slave.counter_init))
        k0 = min(n, round(cfg.load.time_s / cfg.bus.cycle_s))
        load[k0:, 0 if cfg.load.axis == "master" else 1] = cfg.load.volts
    elif case != "mismatch":
        raise ValueError(f"case must be one of {', '.join(CASES)}, got {show_value(case)}")
    return cfg, load
