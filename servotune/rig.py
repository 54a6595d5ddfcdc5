"""The rig: timer, counter, D/A, encoder and axes; loading and validating ``plants/*.toml``.

A rig file (SPEC §5) describes the hardware around the loop and one ``[axis.<name>]`` table per
axis with its plant under ``[axis.<name>.plant]``. Every field is validated on load; an error
names the field, the value and the unit. Unknown keys are errors (a misspelt key would otherwise
be silently ignored). The TOML machinery (tables built into dataclasses, a plant table edited in
place) is :mod:`servotune.io.rig`; this module holds the model and checks files against it.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from servotune.errors import RigError
from servotune.hw import counter as hw_counter
from servotune.hw import dac as hw_dac
from servotune.hw import timer as hw_timer
from servotune.io.files import atomic_write_bytes, parse_toml_as, read_bytes
from servotune.io.rig import FLOAT_SIGNIFICANT_DIGITS as FLOAT_SIGNIFICANT_DIGITS
from servotune.io.rig import build_section, edit_plant_text
from servotune.laws.lock import lock_holding_band
from servotune.plant import Plant
from servotune.validate import (
    check_integer,
    check_keys,
    check_number,
    check_strings,
    check_table,
    is_finite,
    is_number,
    show_value,
)

__all__ = [
    "EXAMPLE_RIG_PATH",
    "ROLES",
    "Axis",
    "Counter",
    "Dac",
    "Encoder",
    "PlantFit",
    "Rig",
    "Timer",
    "check_plant",
    "describe_rig",
    "load_rig",
    "plant_from_table",
    "rig_from_dict",
    "write_plant",
]


ROLES = ("master", "slave")
"""The roles an axis can have (rig file ``role``, tuning file ``axes[].role``)."""

MAX_CLOCK_HZ = 1e10
"""Largest timer clock and counter input frequency accepted [Hz]."""
MAX_READ_SKEW_S = 1e-3
"""Largest time between two counter byte reads [s]."""
MAX_DAC_RANGE_V = 1000.0
"""Largest magnitude of either end of a D/A range [V]."""
MAX_PULSES = 1e9
"""Largest encoder resolution [pulses/rev, counts/mm]."""
MAX_LOCK_GAIN = 65536.0
"""Largest position-lock gain [codes/count] (a 16-bit D/A's whole span per count)."""
MAX_SPEED_RPM = 1e6
MIN_SPEED_LIMIT_RPM = 1e-3  # below: no motion worth a limit (and counts/tick underflow)
"""Largest speed limit [r/min]."""
MAX_COUNTS = 2**62
"""Largest travel or following-error bound [counts] (int64 arithmetic stays exact)."""
MAX_CHANNEL = 255
"""Largest card channel number."""
MAX_PLANT_GAIN = 1e9
"""Largest plant gain [counts/s/V]."""
MIN_TAU_S, MAX_TAU_S = 1e-6, 1000.0
"""Plant time-constant range [s]."""
MAX_DELAY_S = 1.0
"""Largest plant dead time [s] (the simulation keeps the pending D/A writes of that long)."""
MAX_NOISE_COUNTS = 1e6
"""Largest encoder noise [counts]."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Timer:
    """Interrupt timer (8253 PIT).

    Parameters
    ----------
    period_s : float
        Requested tick period [s].
    clock_hz : float
        Timer input clock [Hz].
    compute_s : float
        Time from the tick start to the D/A write (interrupt compute time) [s], < the period.
    """

    period_s: float
    clock_hz: float = hw_timer.PC_PIT_CLOCK_HZ
    compute_s: float = 0.0

    def __post_init__(self) -> None:
        _positive("timer.period_s", self.period_s, "s")
        _positive("timer.clock_hz", self.clock_hz, "Hz", hi=MAX_CLOCK_HZ)
        _nonneg("timer.compute_s", self.compute_s, "s")
        try:
            d = hw_timer.divisor(self.period_s, self.clock_hz)
        except ValueError as exc:
            raise RigError(f"timer.period_s: {exc}") from None
        if self.compute_s >= hw_timer.achieved_period_s(d, self.clock_hz):
            raise RigError(
                f"timer.compute_s must be shorter than the tick period, got "
                f"{show_value(self.compute_s)} s"
            )

    @property
    def divisor(self) -> int:
        """Timer divisor (round to nearest)."""
        return int(hw_timer.divisor(self.period_s, self.clock_hz))

    @property
    def achieved_period_s(self) -> float:
        """Period the timer produces [s]."""
        return float(hw_timer.achieved_period_s(self.divisor, self.clock_hz))

    @property
    def period_error_ppm(self) -> float:
        """Achieved vs requested period [ppm]."""
        return (self.achieved_period_s - self.period_s) / self.period_s * 1e6


@dataclass(frozen=True, slots=True, kw_only=True)
class Counter:
    """Quadrature up/down counter card.

    Parameters
    ----------
    bits : int
        Register width (24 on the PCL833).
    multiplier : int
        Quadrature multiplication x1, x2 or x4.
    latched : bool
        True if the three bytes are latched together; False models reads that can tear.
    max_input_hz : float
        Largest encoder pulse frequency per channel before multiplication [Hz].
    read_skew_s : float
        Time between two byte reads, used when not latched [s].
    """

    bits: int = 24
    multiplier: int = 4
    latched: bool = True
    max_input_hz: float = 2.4e6
    read_skew_s: float = 2e-6

    def __post_init__(self) -> None:
        if type(self.bits) is not int or self.bits not in (16, 24, 32):
            raise RigError(
                f"counter.bits must be the integer 16, 24 or 32 [bits], got {show_value(self.bits)}"
            )
        if type(self.multiplier) is not int or self.multiplier not in hw_counter.MULTIPLIERS:
            raise RigError(
                f"counter.multiplier must be the integer 1, 2 or 4 [-], got "
                f"{show_value(self.multiplier)}"
            )
        if not isinstance(self.latched, bool):
            raise RigError(f"counter.latched must be true or false, got {show_value(self.latched)}")
        _positive("counter.max_input_hz", self.max_input_hz, "Hz", hi=MAX_CLOCK_HZ)
        _nonneg("counter.read_skew_s", self.read_skew_s, "s", hi=MAX_READ_SKEW_S)


@dataclass(frozen=True, slots=True, kw_only=True)
class Dac:
    """D/A converter.

    Parameters
    ----------
    bits : int
        Resolution (12 on the PCL728).
    range_v : tuple of float
        Output range [V], e.g. (-10, 10); 0 V must fall exactly on a code.
    """

    bits: int = 12
    range_v: tuple[float, float] = (-10.0, 10.0)

    def __post_init__(self) -> None:
        check_integer("dac.bits", self.bits, "bits", lo=8, hi=16, error=RigError)
        r = self.range_v
        lim = MAX_DAC_RANGE_V
        if (
            not isinstance(r, tuple | list)
            or len(r) != 2
            or not all(is_number(x) and is_finite(x) and abs(x) <= lim for x in r)
            or not r[0] < r[1]
        ):
            raise RigError(
                f"dac.range_v must be [low, high] with low < high, each within ±{lim:g} [V], "
                f"got {show_value(list(r) if isinstance(r, tuple) else r)}"
            )
        try:
            hw_dac.zero_code(self.bits, self.range_v)
        except ValueError as exc:
            raise RigError(f"dac.range_v: {exc}") from None

    @property
    def lsb_v(self) -> float:
        """One D/A step [V]."""
        return hw_dac.lsb_v(self.bits, self.range_v)

    @property
    def zero_code(self) -> int:
        """Code for 0 V."""
        return hw_dac.zero_code(self.bits, self.range_v)

    @property
    def code_max(self) -> int:
        """Largest code."""
        return 2**self.bits - 1


@dataclass(frozen=True, slots=True, kw_only=True)
class Encoder:
    """Encoder.

    Parameters
    ----------
    pulses_per_rev : float
        Quadrature cycles per motor revolution [pulses/rev].
    counts_per_mm : float or None
        For a linear axis, counts per millimetre of travel [counts/mm].
    """

    pulses_per_rev: float
    counts_per_mm: float | None = None

    def __post_init__(self) -> None:
        _positive("encoder.pulses_per_rev", self.pulses_per_rev, "pulses/rev", hi=MAX_PULSES)
        if self.counts_per_mm is not None:
            _positive("encoder.counts_per_mm", self.counts_per_mm, "counts/mm", hi=MAX_PULSES)


FIT_METHODS = ("iv", "oe")
"""Identification methods a plant's fit record may name (``servotune fit --method``)."""
FRICTION_FORMS = ("sym", "asym")
"""Friction forms a plant's fit record may name (``servotune fit --friction``)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PlantFit:
    """How an axis's plant was identified: ``[axis.<name>.plant.fit]`` (DECISIONS 6).

    ``servotune fit -o`` writes it beside the fitted values; robust tuning and Monte-Carlo
    studies read their plant set from the intervals. A rig file without it is a hand-written
    (or older) model. Rig files carry no format version: the table is an optional addition,
    every older rig file reads as before, and a servotune that predates it refuses a file that
    has it with one line naming the unknown key (exit 3) — never a silent misread
    (DECISIONS 17).

    Parameters
    ----------
    method : str
        ``"iv"`` or ``"oe"`` (:mod:`servotune.identify`).
    structure : tuple of str
        The plant parameters that were estimated (the others were left out: 0, or for the
        negative direction's the positive one's).
    friction : str
        ``"sym"`` or ``"asym"``.
    adequate : bool
        Whether every residual test passed.
    reason : str
        Why not, when not adequate (``""`` otherwise).
    interval : str
        How the intervals were made.
    ci95 : dict of str to (float, float)
        95 % interval of each estimated parameter [the parameter's unit].
    """

    method: str
    structure: tuple[str, ...]
    friction: str
    adequate: bool
    reason: str = ""
    interval: str = ""
    ci95: Mapping[str, tuple[float, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # ValueError: build_section prefixes the table's path (axis.<name>.plant.fit.<field>)
        if self.method not in FIT_METHODS:
            raise ValueError(
                f"method must be one of {', '.join(FIT_METHODS)}, got {show_value(self.method)}"
            )
        if self.friction not in FRICTION_FORMS:
            raise ValueError(
                f"friction must be one of {', '.join(FRICTION_FORMS)}, got "
                f"{show_value(self.friction)}"
            )
        if not isinstance(self.adequate, bool):
            raise ValueError(f"adequate must be true or false, got {show_value(self.adequate)}")
        for name in ("reason", "interval"):
            if not isinstance(getattr(self, name), str):
                raise ValueError(f"{name} must be a string, got {show_value(getattr(self, name))}")
        known = [f.name for f in fields(Plant)]
        structure = tuple(self.structure) if isinstance(self.structure, tuple | list) else None
        if structure is None or any(p not in known for p in structure):
            raise ValueError(
                f"structure must be a list of plant parameters ({', '.join(known)}), got "
                f"{show_value(self.structure)}"
            )
        object.__setattr__(self, "structure", structure)
        if not isinstance(self.ci95, Mapping):
            raise ValueError(f"ci95 must be a table of [low, high], got {show_value(self.ci95)}")
        ci = {}
        for k, v in self.ci95.items():
            if k not in structure:
                raise ValueError(
                    f"ci95.{k} is not an estimated parameter (structure: {', '.join(structure)})"
                )
            pair = list(v) if isinstance(v, tuple | list) else v
            if (
                not isinstance(pair, list)
                or len(pair) != 2
                or not all(is_number(x) and math.isfinite(x) for x in pair)
                or pair[0] > pair[1]
            ):
                raise ValueError(
                    f"ci95.{k} must be [low, high], finite numbers with low <= high, got "
                    f"{show_value(pair)}"
                )
            ci[k] = (float(pair[0]), float(pair[1]))
        object.__setattr__(self, "ci95", ci)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict, the keys of the TOML table."""
        return {"adequate": self.adequate, "ci95": {k: list(v) for k, v in self.ci95.items()},
                "friction": self.friction, "interval": self.interval, "method": self.method,
                "reason": self.reason, "structure": list(self.structure)}  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class Axis:
    """One axis: its role, runtime limits and plant.

    Parameters
    ----------
    name : str
        Axis name (the key of ``[axis.<name>]``).
    role : str
        ``"master"`` or ``"slave"``.
    plant : Plant
        Axis model.
    lock_gain_codes_per_count : float
        Position-lock P gain [codes/count].
    speed_limit_rpm : float
        Largest speed the axis may be commanded to [r/min].
    following_error_limit_counts : int
        Following-error trip threshold [counts] (0 disables the trip).
    travel_counts : tuple of int or None
        Allowed travel relative to the start position [counts]; None for a rotary axis.
    counter_init : int
        Counter register value at the start (lets logs wrap within travel).
    counter_channel, dac_channel : int
        Card channels.
    plant_fit : PlantFit or None
        How the plant was identified (``[axis.<name>.plant.fit]``), if it was.
    """

    name: str
    role: str
    plant: Plant
    lock_gain_codes_per_count: float = 0.4
    speed_limit_rpm: float = 600.0
    following_error_limit_counts: int = 0
    travel_counts: tuple[int, int] | None = None
    counter_init: int = 0
    counter_channel: int = 0
    dac_channel: int = 0
    plant_fit: PlantFit | None = None

    def __post_init__(self) -> None:
        p = f"axis.{self.name}"
        if self.role not in ROLES:
            raise RigError(f"{p}.role must be 'master' or 'slave', got {show_value(self.role)}")
        _positive(f"{p}.lock_gain_codes_per_count", self.lock_gain_codes_per_count,
                  "codes/count", hi=MAX_LOCK_GAIN)  # fmt: skip
        check_number(f"{p}.speed_limit_rpm", self.speed_limit_rpm, "r/min",
                     lo=MIN_SPEED_LIMIT_RPM, hi=MAX_SPEED_RPM, error=RigError)  # fmt: skip
        check_integer(f"{p}.following_error_limit_counts", self.following_error_limit_counts,
                      "counts", lo=0, hi=MAX_COUNTS, error=RigError)  # fmt: skip
        if self.travel_counts is not None:
            t = self.travel_counts
            if (
                not isinstance(t, tuple | list)
                or len(t) != 2
                or not all(type(x) is int and abs(x) <= MAX_COUNTS for x in t)
                or not t[0] < 0 < t[1]
            ):
                shown = show_value(list(t) if isinstance(t, tuple) else t)
                raise RigError(
                    f"{p}.travel_counts must be [low, high], integers with low < 0 < high, each "
                    f"within ±2**62 [counts], got {shown}"
                )
        check_integer(f"{p}.counter_init", self.counter_init, "register value", lo=0,
                      hi=2**32 - 1, error=RigError)  # fmt: skip
        for ch in ("counter_channel", "dac_channel"):
            check_integer(f"{p}.{ch}", getattr(self, ch), "channel", lo=0, hi=MAX_CHANNEL,
                          error=RigError)  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class Rig:
    """The hardware around the loop and its axes.

    Use :func:`load_rig` to read a rig file; derive variants with ``dataclasses.replace``.
    """

    name: str
    timer: Timer
    counter: Counter
    dac: Dac
    encoder: Encoder
    axes: tuple[Axis, ...]
    description: str = ""

    def __post_init__(self) -> None:
        if not self.axes:
            raise RigError("a rig needs at least one [axis.<name>] table")
        names = [a.name for a in self.axes]
        if len(set(names)) != len(names):
            raise RigError(f"axis names must be unique, got {show_value(names)}")
        masters = [a.name for a in self.axes if a.role == "master"]
        if len(self.axes) > 1 and len(masters) != 1:
            raise RigError(
                f"a multi-axis rig needs exactly one role = 'master' axis, got "
                f"{show_value(masters)}"
            )
        for a in self.axes:
            if a.counter_init > (1 << self.counter.bits) - 1:
                raise RigError(
                    f"axis.{a.name}.counter_init must fit the {self.counter.bits}-bit counter "
                    f"(0..{(1 << self.counter.bits) - 1}), got {a.counter_init}"
                )
        for ch in ("counter_channel", "dac_channel"):
            used = [getattr(a, ch) for a in self.axes]
            if len(set(used)) != len(used):
                raise RigError(f"two axes share one {ch}: {show_value(used)}")

    @property
    def period_s(self) -> float:
        """The tick period the loop runs at: the achieved timer period [s]."""
        return self.timer.achieved_period_s

    @property
    def counts_per_rev(self) -> float:
        """Counts per motor revolution after multiplication [counts/rev]."""
        return self.encoder.pulses_per_rev * self.counter.multiplier

    def axis(self, name: str) -> Axis:
        """The axis called ``name``.

        Raises
        ------
        RigError
            If there is no such axis (the message lists the ones there are).
        """
        for a in self.axes:
            if a.name == name:
                return a
        raise RigError(
            f"no axis {show_value(name)} in rig {show_value(self.name)}; axes: "
            f"{[a.name for a in self.axes]}"
        )

    @property
    def axis_names(self) -> tuple[str, ...]:
        """Axis names in file order (the master first is not required)."""
        return tuple(a.name for a in self.axes)


# --- loading -------------------------------------------------------------------------------


def _positive(name: str, value: Any, unit: str, hi: float | None = None) -> None:
    check_number(name, value, unit, lo=0.0, strict=True, hi=hi, error=RigError)


def _nonneg(name: str, value: Any, unit: str, hi: float | None = None) -> None:
    check_number(name, value, unit, lo=0.0, hi=hi, error=RigError)


def check_plant(
    plant: Plant,
    path: str,
    dac_range_v: tuple[float, float] | None = None,
    *,
    error: type[Exception] = RigError,
) -> None:
    """Bounds of a plant read from a file, beyond :class:`~servotune.plant.Plant`'s own checks.

    The plant's own validation keeps the values finite and of the right sign; this keeps them
    within what a servo axis can be (so a typo such as ``offset_v = 1000`` or
    ``delay_s = 1e300`` is refused instead of sizing the simulation's arrays): gain up to 1e9
    counts/s/V, tau_s in 1 µs … 1000 s, delay_s up to 1 s, offset_v and coulomb_v within the
    D/A range (``dac_range_v``; ±1000 V if not given), max_speed_rpm up to 1e6 r/min,
    noise_counts up to 1e6 counts; the negative direction's gain_neg_cps_per_v and
    coulomb_neg_v, where given, as gain_cps_per_v and coulomb_v.

    Parameters
    ----------
    plant : Plant
    path : str
        The plant's table for the messages (``"axis.master.plant"``).
    dac_range_v : (float, float), optional
        The D/A output range [V].
    error : type of Exception
        What to raise.

    Raises
    ------
    error
        ``"axis.master.plant.offset_v must be a number in [-10, 10] [V], got 1000.0"``.
    """
    lo_v, hi_v = dac_range_v if dac_range_v is not None else (-MAX_DAC_RANGE_V, MAX_DAC_RANGE_V)
    span = max(abs(lo_v), abs(hi_v))
    checks = (
        ("gain_cps_per_v", "counts/s/V", 0.0, True, MAX_PLANT_GAIN),
        ("tau_s", "s", MIN_TAU_S, False, MAX_TAU_S),
        ("delay_s", "s", 0.0, False, MAX_DELAY_S),
        ("offset_v", "V", -span, False, span),
        ("coulomb_v", "V", 0.0, False, span),
        ("noise_counts", "counts", 0.0, False, MAX_NOISE_COUNTS),
        # the negative direction's (asymmetric model), where given
        ("gain_neg_cps_per_v", "counts/s/V", 0.0, True, MAX_PLANT_GAIN),
        ("coulomb_neg_v", "V", 0.0, False, span),
    )
    for name, unit, lo, strict, hi in checks:
        if getattr(plant, name) is None:  # a *_neg field left to the positive direction's
            continue
        check_number(f"{path}.{name}", getattr(plant, name), unit, lo=lo, strict=strict, hi=hi,
                     error=error)  # fmt: skip
    if plant.max_speed_rpm is not None:
        check_number(f"{path}.max_speed_rpm", plant.max_speed_rpm, "r/min", lo=0.0, strict=True,
                     hi=MAX_SPEED_RPM, error=error)  # fmt: skip


def plant_from_table(
    table: Mapping[str, Any],
    path: str,
    dac_range_v: tuple[float, float] | None = None,
    *,
    error: type[Exception] = RigError,
) -> Plant:
    """The :class:`~servotune.plant.Plant` of a file's ``[axis.<name>.plant]`` table (``path``),
    built and bounded (:func:`check_plant`); ``error`` names ``path.field``, value and unit."""
    plant = build_section(Plant, table, path, error)
    check_plant(plant, path, dac_range_v, error=error)
    return plant


def _table(
    data: Mapping[str, Any], key: str, path: str, required: bool = True
) -> Mapping[str, Any]:
    return check_table(data, key, error=RigError, required=required, path=path)


def rig_from_dict(data: Mapping[str, Any], default_name: str = "rig") -> Rig:
    """Build and validate a :class:`Rig` from the parsed contents of a rig file.

    Raises
    ------
    RigError
        Naming the first invalid field, its value and unit.
    """
    check_keys(data, "", (), ("rig", "timer", "counter", "dac", "encoder", "axis"),
               error=RigError, noun="table")  # fmt: skip
    meta = _table(data, "rig", "rig", required=False)
    check_keys(meta, "rig", (), ("name", "description"), error=RigError)
    timer = build_section(Timer, _table(data, "timer", "timer"), "timer")
    ctr = build_section(Counter, _table(data, "counter", "counter"), "counter")
    dac = build_section(Dac, _table(data, "dac", "dac"), "dac")
    enc = build_section(Encoder, _table(data, "encoder", "encoder"), "encoder")
    axes_t = _table(data, "axis", "axis")
    axes = []
    for name, at in axes_t.items():
        if not isinstance(at, Mapping):
            raise RigError(f"[axis.{name}] must be a table")
        at = dict(at)
        if "plant" not in at:
            raise RigError(f"missing table [axis.{name}.plant]")
        pt = at.pop("plant")
        if not isinstance(pt, Mapping):
            raise RigError(f"[axis.{name}.plant] must be a table")
        pt = dict(pt)
        fit_t = pt.pop("fit", None)  # the fit record (servotune fit -o), not a plant field
        plant = plant_from_table(pt, f"axis.{name}.plant", dac.range_v)
        plant_fit = None
        if fit_t is not None:
            if not isinstance(fit_t, Mapping):
                raise RigError(f"[axis.{name}.plant.fit] must be a table")
            plant_fit = build_section(PlantFit, fit_t, f"axis.{name}.plant.fit")
        axes.append(build_section(Axis, at, f"axis.{name}", name=name, plant=plant,
                                  plant_fit=plant_fit))  # fmt: skip
    check_strings(meta, "rig", ("name", "description"), error=RigError)
    return Rig(
        name=str(meta.get("name", default_name)),
        description=str(meta.get("description", "")),
        timer=timer,
        counter=ctr,
        dac=dac,
        encoder=enc,
        axes=tuple(axes),
    )


def load_rig(path: str | Path) -> Rig:
    """Read and validate a rig file (TOML).

    Parameters
    ----------
    path : str or Path
        The rig file, e.g. ``plants/pc-dual-servo.toml``.

    Returns
    -------
    Rig

    Raises
    ------
    RigError
        If the file is missing, not TOML, or any field is invalid.
    """
    p = Path(path)
    raw = read_bytes(p, RigError, "rig file")
    return parse_toml_as(raw, str(p), RigError, "rig file", lambda d: rig_from_dict(d, p.stem))


def describe_rig(rig: Rig) -> dict[str, Any]:
    """Derived facts of a rig (what ``servotune rig`` prints).

    Returns
    -------
    dict
        Timer divisor, achieved period and its error, counts per revolution, D/A LSB, the
        counter's speed limits (high-byte unwrap and input frequency) against each axis's speed
        limit, the time to wrap the counter at that speed, and the lock module's predicted
        holding band (SPEC §1a) for each axis's drift and friction.
    """
    t, c = rig.timer, rig.counter
    unwrap_rpm = hw_counter.unwrap_speed_limit_rpm(c.bits, rig.counts_per_rev, rig.period_s)
    input_rpm = hw_counter.input_speed_limit_rpm(c.max_input_hz, rig.encoder.pulses_per_rev)
    axes = {}
    for a in rig.axes:
        v_cps = a.speed_limit_rpm / 60.0 * rig.counts_per_rev
        try:
            lo, hi = lock_holding_band(
                a.lock_gain_codes_per_count, a.plant.offset_v, rig.dac.lsb_v, a.plant.coulomb_v
            )
        except ValueError as exc:
            raise RigError(
                f"axis.{a.name}: lock_gain_codes_per_count "
                f"{show_value(a.lock_gain_codes_per_count)} "
                f"[codes/count] with plant.offset_v {show_value(a.plant.offset_v)} [V]: {exc}"
            ) from None
        axes[a.name] = {
            "counts_per_tick_at_speed_limit": v_cps * rig.period_s,
            "lock_band_counts": [lo, hi],
            "lock_band_within_one_pulse": max(abs(lo), abs(hi)) <= c.multiplier,
            "role": a.role,
            "speed_limit_ok": a.speed_limit_rpm < min(unwrap_rpm, input_rpm),
            "speed_limit_rpm": a.speed_limit_rpm,
            # a subnormal speed limit underflows to 0 counts/s: it never wraps (inf; JSON null)
            "time_to_wrap_at_speed_limit_s": (1 << c.bits) / v_cps if v_cps > 0 else math.inf,
        }
    return {
        "achieved_period_s": rig.period_s,
        "axes": axes,
        "binding_speed_limit": "input_frequency" if input_rpm < unwrap_rpm else "unwrap",
        "counts_per_rev": rig.counts_per_rev,
        "dac_lsb_mv": rig.dac.lsb_v * 1e3,
        "input_frequency_speed_limit_rpm": input_rpm,
        "period_error_ppm": t.period_error_ppm,
        "requested_period_s": t.period_s,
        "rig": rig.name,
        "timer_divisor": t.divisor,
        "unwrap_max_counts_per_tick": hw_counter.max_counts_per_tick(c.bits),
        "unwrap_speed_limit_rpm": unwrap_rpm,
    }


# --- writing a plant section ---------------------------------------------------------------

EXAMPLE_RIG_PATH = Path(__file__).resolve().parents[1] / "plants" / "pc-dual-servo.toml"
"""The example rig of seed 000, the template :func:`write_plant` starts a new rig file from."""


def write_plant(
    path: str | Path,
    axis: str,
    plant: Plant,
    *,
    template: str | Path = EXAMPLE_RIG_PATH,
    provenance: str | None = None,
    fit: PlantFit | None = None,
    new_name: str | None = None,
    new_header: str = "",
) -> None:
    """Write one axis's model into the ``[axis.<axis>.plant]`` table of a rig file.

    What ``servotune fit LOG -o RIG.toml`` does with the fitted plant. The file is edited, not
    regenerated: every comment and the layout of the rest of the file stay byte for byte; only
    the entries of that one table change.

    - The fitted parameters ``gain_cps_per_v`` [counts/s/V], ``tau_s`` [s], ``delay_s`` [s],
      ``offset_v`` [V] and ``coulomb_v`` [V] are always written (added if missing).
    - ``gain_neg_cps_per_v`` [counts/s/V] and ``coulomb_neg_v`` [V], the negative direction's
      (asymmetric model), are written when ``plant`` sets them and removed when it leaves them
      None (a symmetric plant), so the table records which structure was fitted.
    - ``max_speed_rpm`` [r/min] and ``noise_counts`` [counts] describe the drive and the encoder
      rather than the fit: the file's values stay unless ``plant`` sets them (differs from the
      :class:`~servotune.plant.Plant` default, ``None`` and ``0.0``); then they are replaced.
    - Numbers are rounded to 7 significant digits (:data:`FLOAT_SIGNIFICANT_DIGITS`, relative
      error <= 5e-7) and written as the shortest text that reads back exactly as the rounded
      number (``12288.049999999999`` → ``12288.05``). An entry that already holds the rounded
      value keeps its text; a replaced entry keeps its trailing comment.
    - Same inputs, same bytes.

    Parameters
    ----------
    path : str or Path
        The rig file to write. If it does not exist it is created from ``template``; its
        directory must exist.
    axis : str
        Axis name, the ``<axis>`` of ``[axis.<axis>]``; the axis must already be in the file.
    plant : Plant
        The model to write (units as in :class:`~servotune.plant.Plant`).
    template : str or Path
        Rig file a new ``path`` starts from; default the example rig
        ``plants/pc-dual-servo.toml`` (:data:`EXAMPLE_RIG_PATH`).
    provenance : str or None
        One line saying where the numbers come from, e.g. ``"fitted by servotune 0.1.0 from
        log.csv, fit 98.1 %"``. It becomes the trailing comment of the table header
        (``[axis.master.plant]  # fitted by ...``), replacing whatever comment was there, so
        repeated writes do not accumulate lines. ``""`` removes that comment; ``None`` (default)
        leaves it as it is.
    new_name, new_header : str
        For a ``path`` that does not exist yet: make it a rig of its own named ``new_name``,
        with ``new_header`` (lines) as its leading comment, a description naming the template,
        and every other axis's plant marked as the template's, not fitted
        (:func:`servotune.io.rig.new_rig_text`). Without ``new_name`` the template is copied
        as it is.

    Raises
    ------
    FileNotFoundError
        If the directory of ``path`` does not exist (it is named in the message; nothing is
        created).
    RigError
        If the file or the template cannot be read or is not TOML, if ``axis`` is not in it
        (the message lists the axes there are), if ``provenance`` is not one line, or if the
        result would not load with :func:`load_rig` (then nothing is written).
    OSError
        If writing fails; ``path`` is then unchanged and no temporary file is left.

    Examples
    --------
    >>> import tempfile
    >>> from servotune.plant import Plant
    >>> rig_file = Path(tempfile.mkdtemp()) / "my-rig.toml"
    >>> fitted = Plant(gain_cps_per_v=12288.049999999999, tau_s=0.0262, delay_s=0.0009,
    ...                offset_v=0.0048, coulomb_v=0.0021)
    >>> write_plant(rig_file, "master", fitted, provenance="fitted by servotune from log.csv")
    >>> p = load_rig(rig_file).axis("master").plant
    >>> p.gain_cps_per_v, p.tau_s, p.max_speed_rpm  # max_speed_rpm kept from the template
    (12288.05, 0.0262, 700)
    >>> [line for line in rig_file.read_text().splitlines() if "fitted by" in line]
    ['[axis.master.plant]  # fitted by servotune from log.csv']
    """
    if not isinstance(plant, Plant):
        raise TypeError(f"plant must be a servotune.plant.Plant, got {type(plant).__name__}")
    target = Path(path)
    new = None if new_name is None else {"name": new_name, "header": new_header}
    new_text, written = edit_plant_text(target, axis, plant, template=template,
                                        provenance=provenance, new=new,
                                        fit=None if fit is None else fit.to_dict())  # fmt: skip

    # The result must load as a rig, with the values just written, before anything is written.
    try:
        data = tomllib.loads(new_text)
    except tomllib.TOMLDecodeError as exc:
        raise RigError(
            f"writing [axis.{axis}.plant] would make {str(target)!r} invalid TOML ({exc}); "
            f"nothing written"
        ) from None
    try:
        loaded_axis = rig_from_dict(data, default_name=target.stem).axis(axis)
        loaded = loaded_axis.plant
    except RigError as exc:
        raise RigError(
            f"{str(target)!r} would not load after writing [axis.{axis}.plant] ({exc}); "
            f"nothing written"
        ) from None
    wrong = sorted(k for k, v in written.items() if k != "fit" and getattr(loaded, k) != v)
    if (loaded_axis.plant_fit.to_dict() if loaded_axis.plant_fit else None) != written.get("fit"):
        wrong.append("fit")
    if wrong:
        raise RigError(
            f"[axis.{axis}.plant] in {str(target)!r} reads back different values for "
            f"{', '.join(wrong)} (duplicate or dotted keys?); nothing written"
        )
    atomic_write_bytes(target, new_text.encode("utf-8"))
