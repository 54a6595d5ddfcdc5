"""The rig model (docs/formats.md#rig-file): timer, counter, D/A, encoder and axes, each checked
when built.

Every field is validated in ``__post_init__``; an error names the field, the value and the unit.
The bounds of the hardware's and the axes' values are the module constants (``MAX_*``; a
plant's are :func:`servotune.rig.file.check_plant`'s). Reading, checking and writing rig files
(``plants/*.toml``) is :mod:`servotune.rig.file`, a plant table edited in place
:mod:`servotune.rig.edit`; the package :mod:`servotune.rig` re-exports every name here: import the
model from there.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

from servotune.errors import RigError
from servotune.hw import counter as hw_counter
from servotune.hw import dac as hw_dac
from servotune.hw import timer as hw_timer
from servotune.laws.axis import check_filter_designs, filter_input_bound
from servotune.laws.filters import Section, SectionQ, realize
from servotune.plant import Plant
from servotune.validate import check_integer, check_number, is_finite, is_number, show_value

__all__ = [
    "FIT_METHODS",
    "FIT_PCT_KEYS",
    "FRICTION_FORMS",
    "ROLES",
    "Axis",
    "Counter",
    "Dac",
    "Encoder",
    "PlantFit",
    "Rig",
    "Timer",
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
"""Largest speed limit [r/min]."""
MIN_SPEED_LIMIT_RPM = 1e-3
"""Smallest speed limit [r/min] (below it no motion is worth a limit, and counts/tick underflow)."""
MAX_COUNTS = 2**62
"""Largest travel or following-error bound [counts] (int64 arithmetic stays exact)."""
MAX_CHANNEL = 255
"""Largest card channel number."""


def _positive(name: str, value: Any, unit: str, hi: float | None = None) -> None:
    check_number(name, value, unit, lo=0.0, strict=True, hi=hi, error=RigError)


def _nonneg(name: str, value: Any, unit: str, hi: float | None = None) -> None:
    check_number(name, value, unit, lo=0.0, hi=hi, error=RigError)


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

    @property
    def filter_input_bound(self) -> int:
        """The largest magnitude an output filter's input takes: the law holds it to the D/A's
        range, ``−zero … code_max − zero`` codes, with ``FILTER_F`` fraction bits
        (:func:`servotune.laws.filters.realize`)."""
        return filter_input_bound(self.zero_code, self.code_max)


@dataclass(frozen=True, slots=True, kw_only=True)
class Encoder:
    """Encoder.

    Parameters
    ----------
    pulses_per_rev : float
        Quadrature cycles per revolution of the motor shaft [pulses/rev].
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
FIT_PCT_KEYS = ("velocity_fit_pct", "velocity_fit_cv_pct", "position_fit_pct",
                "position_fit_cv_pct")  # fmt: skip
"""The fit figures a plant's fit record may hold (:class:`PlantFit`), in the order written."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PlantFit:
    """How an axis's plant was identified: ``[axis.<name>.plant.fit]``
    (docs/decisions.md#6-the-fit-record).

    ``servotune fit -o`` writes it beside the fitted values; robust tuning and Monte-Carlo
    studies read their plant set from the intervals. A rig file without it is a hand-written
    (or older) model. Rig files carry no format version: the table is an optional addition,
    every older rig file reads as before, and a servotune that predates it refuses a file that
    has it with one line naming the unknown key (exit 3) — never a silent misread
    (docs/decisions.md#17-file-versions).

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
    velocity_fit_pct, position_fit_pct : float or None
        Fit % (MATLAB ``compare``, 100 is perfect) of the whole-log model's simulated speed
        and position on the whole log [%]; None: not recorded (the key is left out).
    velocity_fit_cv_pct, position_fit_cv_pct : float or None
        The same, split-half cross-validated [%]; None: not recorded (or a half could not be
        fitted).
    """

    method: str
    structure: tuple[str, ...]
    friction: str
    adequate: bool
    reason: str = ""
    interval: str = ""
    velocity_fit_pct: float | None = None
    velocity_fit_cv_pct: float | None = None
    position_fit_pct: float | None = None
    position_fit_cv_pct: float | None = None
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
        for name in FIT_PCT_KEYS:
            value = getattr(self, name)
            if value is not None and not (is_number(value) and is_finite(value) and value <= 100):
                raise ValueError(
                    f"{name} must be a finite number of percent, at most 100 (100: a perfect "
                    f"fit), got {show_value(value)}"
                )
            if value is not None:
                object.__setattr__(self, name, float(value))
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
        """Plain dict, the keys of the TOML table (a fit % not recorded is left out)."""
        out = {
            "adequate": self.adequate,
            "ci95": {k: list(v) for k, v in self.ci95.items()},
            "friction": self.friction,
            "interval": self.interval,
            "method": self.method,
            "reason": self.reason,
            "structure": list(self.structure),
        }
        for name in FIT_PCT_KEYS:
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        return out


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
    filters : tuple of Section
        Up to four output filters of the axis's law (``[[axis.<name>.filters]]``,
        docs/runtime.md#filters-in-the-law), in the order they run; the runtime runs them
        quantised at the rig's achieved period (:func:`servotune.laws.filters.realize`).
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
    filters: tuple[Section, ...] = ()

    def __post_init__(self) -> None:
        p = f"axis.{self.name}"
        check_filter_designs(self.filters, f"{p}.filters", RigError)
        if self.role not in ROLES:
            raise RigError(f"{p}.role must be 'master' or 'slave', got {show_value(self.role)}")
        _positive(
            f"{p}.lock_gain_codes_per_count",
            self.lock_gain_codes_per_count,
            "codes/count",
            hi=MAX_LOCK_GAIN,
        )
        check_number(
            f"{p}.speed_limit_rpm",
            self.speed_limit_rpm,
            "r/min",
            lo=MIN_SPEED_LIMIT_RPM,
            hi=MAX_SPEED_RPM,
            error=RigError,
        )
        check_integer(
            f"{p}.following_error_limit_counts",
            self.following_error_limit_counts,
            "counts",
            lo=0,
            hi=MAX_COUNTS,
            error=RigError,
        )
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
        check_integer(
            f"{p}.counter_init",
            self.counter_init,
            "register value",
            lo=0,
            hi=2**32 - 1,
            error=RigError,
        )
        for ch in ("counter_channel", "dac_channel"):
            check_integer(
                f"{p}.{ch}", getattr(self, ch), "channel", lo=0, hi=MAX_CHANNEL, error=RigError
            )


@dataclass(frozen=True, slots=True, kw_only=True)
class Rig:
    """The hardware around the loop and its axes.

    Use :func:`servotune.rig.load_rig` to read a rig file; derive variants with
    ``dataclasses.replace``.
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

    def runtime_filters(self, index: int) -> tuple[SectionQ, ...]:
        """Axis ``index``'s output filters as the runtime runs them: quantised at the achieved
        period for inputs within the D/A's range (:meth:`realize_filters`)."""
        return self.realize_filters(self.axes[index].filters, self.period_s)

    def realize_filters(self, sections: Sequence[Section], period_s: float) -> tuple[SectionQ, ...]:
        """Output filters designed in continuous time, quantised at ``period_s`` for inputs
        within this rig's D/A range (:func:`servotune.laws.filters.realize`)."""
        bound = self.dac.filter_input_bound
        return tuple(realize(f, period_s, bound) for f in sections)
