"""Fieldbus gantry with a listening slave (seed 003, SPEC §1c): topologies, bus, beam, monitor.

Two drives move the two sides of a gantry beam from one command. Each drive is a servotune
axis (SPEC §5 plant, the runtime's PI law in the SPEC §6 arithmetic) that takes a position
command from the fieldbus and closes its own position loop at the **bus cycle**. The beam may
couple the sides (a spring and a damper between them: the sync error loads both motors).

Topologies (``TOPOLOGIES``):

- ``parallel``: both drives get the CNC's command; nothing corrects the sync error.
- ``following``: the slave is commanded with the master's feedback (as it sees it on the bus).
- ``listening``: the patent's. The slave listens to the bus: it reads the command sent to the
  master and the master's feedback; a SISO **sync compensator** (:mod:`servotune.laws.sync`)
  acts on the sync error and its output is added to the slave's position command.
- ``cross``: cross-coupled: the CNC runs the same compensator and splits its output between
  the two commands (the master's with the opposite sign).

Bus (``GantryBus``): a sync frame every ``cycle_s``; every drive samples its encoder at the
sync interrupt plus a random jitter (uniform within ±``jitter_s``; the sample is moved by
speed × jitter, the write timing is not jittered) and writes its output ``compute_s`` later.
The master's feedback of cycle k reaches the slave (and the CNC) ``latency_cycles`` later,
tagged with its cycle, so the sync error the law sees at cycle k is the measured one of cycle
``k − latency_cycles``: ``y_m(k−L) − y_s(k−L)``.

Monitor: the station that forms the sync error (the listening slave, else the CNC) compares it
with a warning and a trip threshold (:func:`~servotune.laws.sync.sync_monitor`). On a trip the
detecting slave stops at once and every other drive with the next frame: both axes are
latched at 0 V (:data:`~servotune.laws.axis.FLAG_SYNC_TRIP`) at most ``latency_cycles + 1``
cycles after the measured sync error first crossed the trip threshold (``stop_bound_cycles``).

Plant motion: exact per axis between input changes (:func:`~servotune.plant.advance`, friction
and speed limit included); with a coupled beam each cycle is split into sub-steps over which
the beam force is held (``beam_substeps``, chosen so the beam's mode is resolved).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numba as nb
import numpy as np

from servotune._version import __version__
from servotune.budget import check_memory
from servotune.errors import ConfigError, RigError
from servotune.fixed import shift_round
from servotune.hw import dac as hw_dac
from servotune.io.files import json_safe, read_toml
from servotune.laws.axis import (
    FLAG_SYNC_TRIP,
    MODE_TASK,
    N_STATE,
    S_FAULT,
    AxisController,
    axis_control,
    axis_read,
)
from servotune.laws.pi import PIGains
from servotune.laws.sync import (
    SYNC_LAWS,
    SYNC_TRIP,
    SYNC_WARN,
    SyncConstants,
    SyncGains,
    sync_enter,
    sync_monitor,
    sync_step,
)
from servotune.plant import Plant, advance, lag_split, step_coefficients
from servotune.rig import Rig, build_section, check_plant, load_rig
from servotune.validate import check_integer, check_keys, check_number, show_value

__all__ = [
    "CASES",
    "TOPOLOGIES",
    "Beam",
    "GantryAxis",
    "GantryBus",
    "GantryConfig",
    "GantryLoad",
    "GantryMove",
    "GantryTrace",
    "SyncComparison",
    "SyncSettings",
    "compare_topologies",
    "format_comparison",
    "gantry_from_dict",
    "load_gantry",
    "move_profile",
    "predicted_load_reduction",
    "resolve_gains",
    "simulate_gantry",
    "sync_loop_models",
    "tune_sync",
]

TOPOLOGIES = ("parallel", "following", "listening", "cross")
"""Gantry topologies, in the order of the comparison table."""

CASES = ("load", "mismatch")
"""Comparison cases: ``load`` — both sides with the master's plant, a load step on one side
during the move; ``mismatch`` — each side with its own plant, no load."""

T_PARALLEL, T_FOLLOWING, T_LISTENING, T_CROSS = range(4)
OP_NONE, OP_ENTER, OP_STEP = 0, 1, 2
_MAX_SUBSTEPS = 64


# --- configuration --------------------------------------------------------------------------


# Bounds of the configuration's fields (a typo must not size the simulation's arrays)
MAX_CYCLE_S = 0.01
"""Longest bus cycle [s] (10 ms)."""
MIN_CYCLE_S = 1e-6
"""Shortest bus cycle [s]."""
MAX_LATENCY_CYCLES = 1000
"""Largest feedback latency [cycles]."""
MAX_SECONDS = 3600.0
"""Longest run [s] (also at most 5e6 cycles, and at least 100)."""
MAX_GAIN = 1e6
"""Largest drive or sync gain (any unit)."""
MAX_COUNTS = 2**31 - 1
"""Largest count threshold or move distance [counts]."""
MAX_SPEED_CPS = 1e9
"""Largest speed [counts/s]; acceleration up to 1e12 counts/s²."""
MAX_BEAM = 1e3
"""Largest beam stiffness [V/count] or damping [V·s/count]."""
MAX_LOAD_V = 1000.0
"""Largest load step magnitude [V]."""
_MIN_CYCLES = 100
_TRACE_BYTES_PER_CYCLE = 208  # a GantryTrace and its kernel inputs, per cycle


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
        check_number("cycle_s", self.cycle_s, "s", lo=MIN_CYCLE_S, hi=MAX_CYCLE_S,
                     error=ConfigError)  # fmt: skip
        check_number("jitter_s", self.jitter_s, "s", hi=0.01 * self.cycle_s, error=ConfigError)
        check_integer("latency_cycles", self.latency_cycles, "cycles", lo=1,
                      hi=MAX_LATENCY_CYCLES, error=ConfigError)  # fmt: skip
        check_number("compute_s", self.compute_s, "s", hi=self.cycle_s, hi_strict=True,
                     error=ConfigError)  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class Beam:
    """Mechanical coupling of the two sides through the beam, as motor-input volts.

    Parameters
    ----------
    stiffness_v_per_count : float
        Spring: the force of a sync error, on both motors with opposite signs [V/count].
    damping_v_s_per_count : float
        Damper on the speed difference [V/(count/s)].
    """

    stiffness_v_per_count: float = 0.0
    damping_v_s_per_count: float = 0.0

    def __post_init__(self) -> None:
        check_number("stiffness_v_per_count", self.stiffness_v_per_count, "V/count", hi=MAX_BEAM,
                     error=ConfigError)  # fmt: skip
        check_number("damping_v_s_per_count", self.damping_v_s_per_count, "V·s/count",
                     hi=MAX_BEAM, error=ConfigError)  # fmt: skip

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
    """

    plant: Plant
    kp: float | None = None
    ki: float | None = None
    following_error_limit_counts: int = 0
    counter_init: int = 0

    def __post_init__(self) -> None:
        for name, unit in (("kp", "codes/count"), ("ki", "codes/(count·s)")):
            if getattr(self, name) is not None:
                check_number(name, getattr(self, name), unit, hi=MAX_GAIN, error=ConfigError)
        check_integer("following_error_limit_counts", self.following_error_limit_counts,
                      "counts", hi=MAX_COUNTS, error=ConfigError)  # fmt: skip
        check_integer("counter_init", self.counter_init, "register value", hi=2**32 - 1,
                      error=ConfigError)  # fmt: skip

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
        check_integer("limit_counts", self.limit_counts, "counts", lo=1, hi=MAX_COUNTS,
                      error=ConfigError)  # fmt: skip
        if self.warn_counts and self.trip_counts and self.warn_counts >= self.trip_counts:
            raise ConfigError(
                f"warn_counts must be < trip_counts [counts], got {self.warn_counts} >= "
                f"{self.trip_counts}"
            )
        check_number("phase_margin_deg", self.phase_margin_deg, "deg", strict=True, hi=90.0,
                     hi_strict=True, error=ConfigError)  # fmt: skip
        check_number("gain_margin_db", self.gain_margin_db, "dB", strict=True, hi=60.0,
                     error=ConfigError)  # fmt: skip
        check_number("max_sensitivity", self.max_sensitivity, "-", lo=1.0, strict=True, hi=10.0,
                     error=ConfigError)  # fmt: skip

    @property
    def gains(self) -> SyncGains:
        """The compensator's gains (after :func:`resolve_gains`)."""
        if self.kp is None or (self.law == "pi" and self.ki is None):
            raise ValueError("sync gains are not resolved; call resolve_gains(config)")
        return SyncGains(law=self.law, kp=self.kp,
                         ki=self.ki or 0.0 if self.law == "pi" else 0.0,
                         kd=self.kd or 0.0 if self.law == "pd" else 0.0,
                         dead_zone_counts=self.dead_zone_counts,
                         limit_counts=self.limit_counts)  # fmt: skip


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
    """

    distance_counts: int = 200_000
    speed_cps: float = 60_000.0
    accel_cps2: float = 600_000.0
    start_s: float = 0.05

    def __post_init__(self) -> None:
        check_integer("distance_counts", self.distance_counts, "counts", lo=-MAX_COUNTS,
                      hi=MAX_COUNTS, error=ConfigError)  # fmt: skip
        check_number("speed_cps", self.speed_cps, "counts/s", strict=True, hi=MAX_SPEED_CPS,
                     error=ConfigError)  # fmt: skip
        check_number("accel_cps2", self.accel_cps2, "counts/s²", strict=True,
                     hi=1e3 * MAX_SPEED_CPS, error=ConfigError)  # fmt: skip
        check_number("start_s", self.start_s, "s", hi=MAX_SECONDS, error=ConfigError)


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
    bus, beam, master, slave, sync, move, load :
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
    seconds: float = 2.0

    def __post_init__(self) -> None:
        if not isinstance(self.name, str):
            raise ConfigError(f"name must be a string, got {show_value(self.name)}")
        if not isinstance(self.topology, str) or self.topology not in TOPOLOGIES:
            raise ConfigError(
                f"topology must be one of {', '.join(TOPOLOGIES)}, got {show_value(self.topology)}"
            )
        cyc = self.bus.cycle_s
        check_number("seconds", self.seconds, "s", strict=True, hi=MAX_SECONDS, error=ConfigError)
        if not _MIN_CYCLES <= self.seconds / cyc <= 5e6:
            raise ConfigError(
                f"seconds must be {_MIN_CYCLES} to 5e6 bus cycles ({_MIN_CYCLES * cyc:g} … "
                f"{5e6 * cyc:g} s at cycle_s {cyc:g}) [s], got {show_value(self.seconds)}"
            )

    @property
    def n_cycles(self) -> int:
        """Cycles of a run."""
        return max(1, round(self.seconds / self.bus.cycle_s))

    @property
    def sync_constants(self) -> SyncConstants:
        """The compensator's constants as the runtime holds them (quantised at the cycle)."""
        return self.sync.gains.quantize(self.bus.cycle_s)

    @property
    def stop_bound_cycles(self) -> int:
        """Cycles from the measured sync error crossing the trip threshold to both axes at 0 V."""
        return self.bus.latency_cycles + 1

    def controllers(self) -> tuple[AxisController, AxisController]:
        """The two drives' runtime controllers (PI at the bus cycle)."""
        return tuple(
            AxisController.from_gains(lock_gain_codes_per_count=0.4, task_gains=ax.gains,
                                      period_s=self.bus.cycle_s,
                                      following_error_limit_counts=ax.following_error_limit_counts)
            for ax in (self.master, self.slave)
        )  # type: ignore[return-value]  # fmt: skip


def gantry_from_dict(data: Mapping[str, Any], base_dir: str | Path = ".") -> GantryConfig:
    """Build and validate a :class:`GantryConfig` from parsed TOML.

    Raises
    ------
    ConfigError
        Naming the first invalid table or field, its value and unit.
    """
    check_keys(data, "", (), ("gantry", "bus", "beam", "axis", "sync", "move", "load"),
               error=ConfigError, noun="table")  # fmt: skip

    def table(key: str, required: bool = False) -> Mapping[str, Any]:
        t = data.get(key, None)
        if t is None:
            if required:
                raise ConfigError(f"missing table [{key}]")
            return {}
        if not isinstance(t, Mapping):
            raise ConfigError(f"[{key}] must be a table, got {type(t).__name__}")
        return t

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
    drives = {}
    for name in ("master", "slave"):
        at = axes_t.get(name)
        if not isinstance(at, Mapping):
            raise ConfigError(f"missing table [axis.{name}]")
        at = dict(at)
        if not isinstance(at.get("plant"), Mapping):
            raise ConfigError(f"missing table [axis.{name}.plant]")
        plant = build_section(Plant, at.pop("plant"), f"axis.{name}.plant", ConfigError)
        check_plant(plant, f"axis.{name}.plant", rig.dac.range_v, error=ConfigError)
        drives[name] = build_section(GantryAxis, at, f"axis.{name}", ConfigError, plant=plant)
    extra = sorted(set(axes_t) - {"master", "slave"})
    if extra:
        raise ConfigError(f"unknown axis [axis.{extra[0]}] (a gantry has master and slave)")
    parts = {
        k: build_section(cls, table(k), k, ConfigError)
        for k, cls in (("bus", GantryBus), ("beam", Beam), ("sync", SyncSettings),
                       ("move", GantryMove), ("load", GantryLoad))
    }  # fmt: skip
    return build_section(GantryConfig, meta, "gantry", ConfigError, rig=rig,
                         master=drives["master"], slave=drives["slave"], **parts)  # fmt: skip


def load_gantry(path: str | Path, *, resolve: bool = True) -> GantryConfig:
    """Read a gantry config (TOML, e.g. ``plants/gantry.toml``).

    Parameters
    ----------
    path : str or Path
    resolve : bool
        Tune the gains the file leaves out (:func:`resolve_gains`).

    Raises
    ------
    ConfigError
        If the file is missing, not TOML, or invalid (the message names the field).
    """
    p = Path(path)
    data = read_toml(p, ConfigError, "gantry config")
    try:
        cfg = gantry_from_dict(data, base_dir=p.parent)
    except ConfigError as exc:
        raise ConfigError(f"gantry config {str(p)!r}: {exc}") from None
    cfg = replace(cfg, name=cfg.name if cfg.name != "gantry" else p.stem.removesuffix(".sync"))
    return resolve_gains(cfg) if resolve else cfg


# --- models and synthesis -------------------------------------------------------------------


def _pi_tf(kp: float, ki_t: float, dt: float) -> Any:
    """``Kp + Ki·T·z/(z−1)``: the runtime PI (:func:`~servotune.laws.pi.pi_step`)."""
    import control

    return control.tf([kp + ki_t, -kp], [1.0, -1.0], dt)


def _compensator_tf(g: SyncGains, dt: float) -> Any:
    """The sync law as a discrete transfer function: the runtime PI, or ``Kp + Kd/T·(1 − z⁻¹)``."""
    import control

    if g.law == "pi":
        return _pi_tf(g.kp, g.ki * dt, dt)
    return control.tf([g.kp + g.kd / dt, -g.kd / dt], [1.0, 0.0], dt)


def _sync_open_loop(comp: Any, t_slave: Any, cfg: GantryConfig) -> Any:
    """``C(z)·z^-L·T_s(z)``: the compensator, the bus latency, the slave's closed drive loop."""
    import control

    dt = cfg.bus.cycle_s
    delay = control.tf([1.0], [1.0] + [0.0] * cfg.bus.latency_cycles, dt)
    return control.ss(comp) * control.ss(delay) * t_slave


def sync_loop_models(cfg: GantryConfig) -> dict[str, Any]:
    """Linear discrete models of the sync loop (friction, quantisation and beam left out).

    Returns
    -------
    dict
        ``t_master``, ``t_slave``: drive closed loops (command → position [counts/count]);
        ``load_slave``: load volts on the slave side → slave position [counts/V];
        ``compensator``: the sync law ``C(z)``; ``loop``: ``C(z)·z^-L·T_s(z)``;
        ``sensitivity``: ``1/(1 + loop)``, the factor by which the listening compensator
        scales the parallel topology's sync error.
    """
    import control

    from servotune.plant import discretize

    dt = cfg.bus.cycle_s
    lsb = hw_dac.lsb_v(cfg.rig.dac.bits, cfg.rig.dac.range_v)
    out: dict[str, Any] = {}
    for key, ax in (("master", cfg.master), ("slave", cfg.slave)):
        p_u = control.ss(discretize(ax.plant, dt, cfg.bus.compute_s + ax.plant.delay_s))
        c = control.ss(_pi_tf(ax.gains.kp, ax.gains.ki * dt, dt))
        out[f"t_{key}"] = control.feedback(c * lsb * p_u, 1)
        # a load d adds to the drive input without the compute/delay lag:
        # y = P_d·d + P_u·lsb·u with u = −C·y, so y = P_d·d / (1 + C·lsb·P_u)
        p_d = control.ss(discretize(ax.plant, dt, 0.0))
        one = control.ss(control.tf([1.0], [1.0], dt))
        out[f"load_{key}"] = p_d * control.feedback(one, c * lsb * p_u)
    comp = _compensator_tf(cfg.sync.gains, dt)
    loop = _sync_open_loop(comp, out["t_slave"], cfg)
    out["compensator"] = comp
    out["loop"] = loop
    out["sensitivity"] = control.feedback(control.ss(control.tf([1.0], [1.0], dt)), loop)
    return out


def tune_sync(cfg: GantryConfig) -> SyncSettings:
    """Synthesise the sync compensator on the linear sync loop (:func:`sync_loop_models`).

    PI: :func:`~servotune.tune.pi.tune_pi` on the slave's closed drive loop ``T_s(z)`` with
    the bus latency as whole cycles of lag (largest Ki under the phase margin, gain margin and
    sensitivity targets). PD: ``kd`` kept (0 if unset) and the largest ``kp`` whose loop meets
    the same targets (bisection on python-control's margins).

    Raises
    ------
    SpecError
        If no compensator meets the targets.
    """
    import control

    from servotune.errors import SpecError
    from servotune.tune.pi import tune_pi

    s = cfg.sync
    dt = cfg.bus.cycle_s
    t_s = sync_loop_models(replace(cfg, sync=replace(s, kp=0.0, ki=0.0, kd=0.0)))["t_slave"]
    if s.law == "pi":
        r = tune_pi(t_s, period_s=dt, compute_s=cfg.bus.latency_cycles * dt,
                    phase_margin_deg=s.phase_margin_deg, gain_margin_db=s.gain_margin_db,
                    max_sensitivity=s.max_sensitivity)  # fmt: skip
        return replace(s, kp=float(r.kp), ki=float(r.ki), kd=0.0)
    kd = s.kd or 0.0

    def meets(kp: float) -> bool:
        g = SyncGains(law="pd", kp=kp, kd=kd, limit_counts=s.limit_counts)
        loop = _sync_open_loop(_compensator_tf(g, dt), t_s, cfg)
        cl = control.feedback(loop, 1)
        if np.any(np.abs(cl.poles()) >= 1.0):
            return False
        w = np.geomspace(1e-2, math.pi / dt, 2000)
        resp = loop.frequency_response(w)
        gm, pm = control.stability_margins(resp)[:2]
        gm_db = 20 * math.log10(gm) if np.isfinite(gm) and gm > 0 else math.inf
        ms = float(np.max(1.0 / np.abs(1.0 + np.squeeze(resp.complex))))
        pm_ok = not np.isfinite(pm) or pm >= s.phase_margin_deg
        return pm_ok and gm_db >= s.gain_margin_db and ms <= s.max_sensitivity

    lo, hi = 0.0, 1.0
    if not meets(1e-6):
        raise SpecError(f"no PD sync compensator with kd={kd:g} s meets the sync-loop targets")
    while meets(hi) and hi < 1e6:
        lo, hi = hi, hi * 2
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if meets(mid) else (lo, mid)
    return replace(s, kp=lo, ki=0.0, kd=kd)


def resolve_gains(cfg: GantryConfig) -> GantryConfig:
    """Fill in the gains the config leaves out: each drive's PI tuned at the bus cycle
    (:func:`~servotune.tune.pi.tune_pi`, PM 50°, GM 8 dB, Ms 1.6), then the compensator
    (:func:`tune_sync`)."""
    from servotune.tune.pi import DEFAULT_TARGETS, tune_pi

    lsb = hw_dac.lsb_v(cfg.rig.dac.bits, cfg.rig.dac.range_v)
    drives = []
    for ax in (cfg.master, cfg.slave):
        if ax.kp is None or ax.ki is None:
            r = tune_pi(ax.plant, period_s=cfg.bus.cycle_s, compute_s=cfg.bus.compute_s,
                        lsb_v=lsb, **DEFAULT_TARGETS)  # fmt: skip
            ax = replace(ax, kp=float(r.kp) if ax.kp is None else ax.kp,
                         ki=float(r.ki) if ax.ki is None else ax.ki)  # fmt: skip
        drives.append(ax)
    cfg = replace(cfg, master=drives[0], slave=drives[1])
    s = cfg.sync
    if s.kp is None or (s.law == "pi" and s.ki is None):
        cfg = replace(cfg, sync=tune_sync(cfg))
    return cfg


# --- the run --------------------------------------------------------------------------------


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


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryTrace:
    """One gantry run. Arrays have one row per cycle; axis columns are (master, slave).

    Attributes
    ----------
    topology, case : str
    cycle_s : float
    command : ndarray of int64 — the CNC's command [counts]
    ref : ndarray of int64 (n, 2) — each drive's position command [counts]
    y : ndarray of int64 (n, 2) — measured positions [counts]
    position : ndarray (n, 2) — true positions at the sample instants [counts]
    code, flags : ndarray of int64 (n, 2) — D/A codes and ``FLAG_*`` bits
    sync_error : ndarray of int64 — measured ``y_master − y_slave`` [counts]
    sync_op, sync_input, sync_comp, sync_level : ndarray of int64
        Per cycle: the compensator call (0 none, 1 enter, 2 step), the sync error it saw, its
        compensation [counts], the monitor level (0 ok, 1 warn, 2 trip).
    trip_cycle : int
        Cycle the monitor tripped, -1 if it did not.
    stop_bound_cycles : int
    """

    topology: str
    case: str
    cycle_s: float
    command: np.ndarray
    ref: np.ndarray
    y: np.ndarray
    position: np.ndarray
    code: np.ndarray
    flags: np.ndarray
    sync_error: np.ndarray
    sync_op: np.ndarray
    sync_input: np.ndarray
    sync_comp: np.ndarray
    sync_level: np.ndarray
    trip_cycle: int
    stop_bound_cycles: int

    @property
    def time_s(self) -> np.ndarray:
        """Sample instants [s]."""
        return np.arange(self.command.size, dtype=np.int64) * self.cycle_s

    def metrics(self) -> dict[str, float | int | bool]:
        """Max and RMS |sync error| [counts], warning cycles, trip."""
        e = self.sync_error.astype(float)
        return {
            "max_sync_error_counts": float(np.max(np.abs(e))),
            "rms_sync_error_counts": float(np.sqrt(np.mean(e * e))),
            "warning_cycles": int(np.count_nonzero(self.sync_level == SYNC_WARN)),
            "tripped": self.trip_cycle >= 0,
            "trip_time_s": self.trip_cycle * self.cycle_s if self.trip_cycle >= 0 else None,
        }


def _case_config(cfg: GantryConfig, case: str) -> tuple[GantryConfig, np.ndarray]:
    """The config a case runs (``load``: the slave side a copy of the master's drive and
    plant) and the load per cycle and axis [V]."""
    n = cfg.n_cycles
    load = np.zeros((n, 2))
    if case == "load":
        cfg = replace(cfg, slave=replace(cfg.master, counter_init=cfg.slave.counter_init))
        k0 = min(n, round(cfg.load.time_s / cfg.bus.cycle_s))
        load[k0:, 0 if cfg.load.axis == "master" else 1] = cfg.load.volts
    elif case != "mismatch":
        raise ValueError(f"case must be one of {', '.join(CASES)}, got {show_value(case)}")
    return cfg, load


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


def predicted_load_reduction(cfg: GantryConfig) -> dict[str, float]:
    """What the loop gains predict for the ``load`` case: max |sync error| of the parallel
    topology (the slave's closed-loop load response) and of the listening one (that error
    shaped by the sync loop's sensitivity ``1/(1 + C·z^-L·T_s)``), linear and noise-free.

    Returns
    -------
    dict
        ``parallel_max_counts``, ``listening_max_counts`` and their ``ratio``.
    """
    import control

    cfg, load = _case_config(cfg, "load")
    models = sync_loop_models(cfg)
    n = cfg.n_cycles
    side = 0 if cfg.load.axis == "master" else 1
    d = load[:, side]
    resp = control.forced_response(models["load_slave"], U=d)
    e_par = np.squeeze(resp.outputs) * (1.0 if side == 0 else -1.0)
    e_lis = np.squeeze(control.forced_response(models["sensitivity"], U=e_par).outputs)
    p, li = float(np.max(np.abs(e_par[:n]))), float(np.max(np.abs(e_lis[:n])))
    return {"parallel_max_counts": p, "listening_max_counts": li, "ratio": li / p}


@dataclass(frozen=True, slots=True, kw_only=True)
class SyncComparison:
    """Max/RMS sync error per topology and case (:func:`compare_topologies`)."""

    config: GantryConfig
    rows: tuple[dict[str, Any], ...]
    traces: tuple[GantryTrace, ...]
    predicted: dict[str, float]
    failed: tuple[str, ...]

    @property
    def passed(self) -> bool:
        """True if the deployed topology tripped in no case."""
        return not self.failed

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (``schema`` ``servotune.sync/1``)."""
        c = self.config
        return json_safe({
            "schema": "servotune.sync/1",
            "name": c.name,
            "topology": c.topology,
            "cycle_s": c.bus.cycle_s,
            "latency_cycles": c.bus.latency_cycles,
            "stop_bound_cycles": c.stop_bound_cycles,
            "drives": {"master": c.master.gains.to_dict(), "slave": c.slave.gains.to_dict()},
            "sync": c.sync.gains.to_dict() | {"warn_counts": c.sync.warn_counts,
                                              "trip_counts": c.sync.trip_counts},
            "sync_constants": c.sync_constants.to_dict(),
            "results": list(self.rows),
            "predicted_load": self.predicted,
            "passed": self.passed,
            "failed": list(self.failed),
            "version": __version__,
        })  # fmt: skip


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


def format_comparison(cmp: SyncComparison) -> str:
    """The comparison as a text table (one row per topology, max/RMS per case)."""
    c = cmp.config
    head = f"{'topology':<11}" + "".join(
        f"{case + ' max':>13}{case + ' RMS':>13}" for case in CASES
    )
    lines = [f"gantry {c.name}: sync error [counts], bus cycle {c.bus.cycle_s * 1e3:g} ms, "
             f"latency {c.bus.latency_cycles} cycle(s), deployed: {c.topology}", head]  # fmt: skip
    for topo in TOPOLOGIES:
        cells = ""
        for case in CASES:
            r = next(r for r in cmp.rows if r["topology"] == topo and r["case"] == case)
            mark = " TRIP" if r["tripped"] else ""
            cells += f"{r['max_sync_error_counts']:>13.1f}{r['rms_sync_error_counts']:>13.1f}{mark}"
        lines.append(f"{topo:<11}{cells}")
    if cmp.predicted:
        p = cmp.predicted
        lines.append(f"predicted (linear) load-case max: parallel {p['parallel_max_counts']:.1f}, "
                     f"listening {p['listening_max_counts']:.1f} (x{p['ratio']:.3f})")  # fmt: skip
    lines.append("PASS" if cmp.passed else "FAIL: " + "; ".join(cmp.failed))
    return "\n".join(lines)
