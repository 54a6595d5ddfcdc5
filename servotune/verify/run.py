"""Specifications and verification: does a tuning meet its spec on the bit-true closed loop?

A **spec file** (TOML, ``plants/<rig>.spec.toml``) states limits per scenario and the plant
spread they must hold over. :func:`verify` runs the tuning's controllers, exactly as the runtime
runs them (the engine: :func:`~servotune.engine.prepare_batch`,
:func:`~servotune.engine.run_batch`), on every scenario for the nominal plants and every
Monte Carlo variant, and reports per limit the worst value, the variant it came from and the
margin. It also checks what no scenario can show by a number alone: the fastest simulated
motion against the counter's speed limits, the timer's period error, and that no runtime sum
can overflow with the tuning's constants.

Spec file
---------
Every key is optional unless marked; unknown keys are errors; every limit is an upper bound
(``worst <= limit`` passes)::

    [spec]
    name = "pc-dual-servo"        # default: the file name without .spec.toml
    description = "..."
    rig = "pc-dual-servo"         # if given, the rig's name must match

    [timer]
    max_period_error_ppm = 100.0  # |achieved − requested period| [ppm]; reported either way

    [montecarlo]                  # plant variants besides the nominal plants
    count = 40                    # number of random variants
    seed = 0                      # variants and noise streams (verify(seed=...) overrides it)
    gain_spread = 0.2             # gain_cps_per_v × U(1 − s, 1 + s) [1]
    tau_spread = 0.3              # tau_s × U(1 − s, 1 + s) [1]
    offset_spread_v = 0.002       # offset_v + U(−s, s) [V]
    coulomb_spread = 0.5          # coulomb_v × U(1 − s, 1 + s) [1]
    axes = ["master", "slave"]    # axes whose plants vary; default every axis

    [scenario.<name>]             # at least one; kind defaults to the table name
    kind = "sync"                 # "sync", "track" or "lock"
    ...parameters and limits of the kind (below)

Kinds, their parameters and limits:

``sync`` (:func:`~servotune.scenarios.sync_move`: master start, constant speed, stop; a load
step on the slave halfway through the constant speed): ``seconds`` [s] (2.4),
``speed_fraction`` [1] (0.5), ``accel_s`` [s] (0.1), ``load_step_v`` [V] (−0.3),
``settling_band_pct`` [%] (2, MATLAB's SettlingTimeThreshold).
``track`` (the ``track`` scenario: a trapezoidal master move, no load): ``seconds`` (3.0),
``settling_band_pct``. Limits of both:

- ``max_overshoot_pct`` [%]: MATLAB ``stepinfo`` overshoot of each axis's position, the move
  taken as the step (from the position where the reference starts moving to the reference's
  final value): how far the axis runs past the stop, as a share of the move.
- ``max_settling_time_s`` [s]: ``stepinfo`` settling time of the same step (from the move's
  start, band ``settling_band_pct`` of the move), to the end of the run; never settling fails.
- ``max_sync_error_counts`` [counts]: max |master − slave position| over the slave's task ticks.
- ``max_rms_sync_error_counts`` [counts]: RMS of the same.
- ``max_steady_lag_counts`` [counts]: mean |sync error| over the second half of the
  constant-speed part before the load step (the first half lets the acceleration transient
  decay).
- ``max_saturation_pct`` [%]: share of each axis's task ticks with the D/A on a rail.

``lock`` (every axis held by the position-lock module): ``seconds`` (10.0), ``settle_s`` [s]
(2.0). Limits: ``max_holding_band_counts`` [counts], max |lock target − position| after
``settle_s``; ``max_saturation_pct`` (over all ticks).

Positions are the plant's (noise-free, ``floor`` to whole counts for the lock band) in the
runtime's frame; every scenario also requires that no run latches a fault.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from servotune.engine import Loop, prepare_batch, run_batch
from servotune.errors import SpecError
from servotune.fixed import E_MAX, F_U, INT64_MAX
from servotune.hw import counter as hw_counter
from servotune.io.files import json_float, parse_toml, read_bytes
from servotune.laws.axis import (
    FAULT_MASK,
    FLAG_SATURATED,
    MODE_TASK,
    AxisController,
)
from servotune.laws.fuzzy_pid import TABLE_NAMES, FuzzyPIDConstants
from servotune.plant import Plant
from servotune.rig import Rig
from servotune.scenarios import Inputs, build_scenario, sync_move
from servotune.tuning import Tuning
from servotune.validate import check_keys, check_number, show_value

__all__ = [
    "KINDS",
    "LIMITS",
    "Check",
    "MonteCarlo",
    "Row",
    "ScenarioSpec",
    "Spec",
    "Variant",
    "Verification",
    "check_overflow",
    "check_speed",
    "check_timer",
    "format_table",
    "load_spec",
    "max_safe_gain_q",
    "plant_variants",
    "spec_from_bytes",
    "spec_from_dict",
    "verify",
]

LIMITS: Mapping[str, tuple[str, str]] = {
    "max_overshoot_pct": ("overshoot_pct", "%"),
    "max_settling_time_s": ("settling_time_s", "s"),
    "max_sync_error_counts": ("max_sync_error_counts", "counts"),
    "max_rms_sync_error_counts": ("rms_sync_error_counts", "counts"),
    "max_steady_lag_counts": ("steady_lag_counts", "counts"),
    "max_saturation_pct": ("saturation_pct", "%"),
    "max_holding_band_counts": ("holding_band_counts", "counts"),
}
"""Spec limit key → (quantity it bounds, unit)."""

_MOVE_LIMITS = (
    "max_overshoot_pct",
    "max_settling_time_s",
    "max_sync_error_counts",
    "max_rms_sync_error_counts",
    "max_steady_lag_counts",
    "max_saturation_pct",
)
KINDS: Mapping[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "sync": (
        ("seconds", "speed_fraction", "accel_s", "load_step_v", "settling_band_pct"),
        _MOVE_LIMITS,
    ),
    "track": (("seconds", "settling_band_pct"), _MOVE_LIMITS),
    "lock": (("seconds", "settle_s"), ("max_holding_band_counts", "max_saturation_pct")),
}
"""Scenario kind → (its parameters, its limits)."""

_DEFAULT_SECONDS = {"sync": 2.4, "track": 3.0, "lock": 10.0}
_UNITS = {
    "seconds": "s",
    "speed_fraction": "1",
    "accel_s": "s",
    "load_step_v": "V",
    "settling_band_pct": "%",
    "settle_s": "s",
    **{k: u for k, (_, u) in LIMITS.items()},
}
_MAX_SECONDS = 600.0
_MAX_VARIANTS = 10_000
_CHUNK = 64  # candidates per engine batch (bounds the memory of the traces)
_FAULT_QUANTITY = "fault_runs"


# --- the spec ------------------------------------------------------------------------------


def _number(key: str, value: Any, unit: str) -> float:
    try:
        check_number(key, value, unit, lo=-math.inf, error=SpecError)
    except SpecError:
        raise SpecError(
            f"{key} must be a finite number [{unit}], got {show_value(value)}"
        ) from None
    return float(value)


@dataclass(frozen=True, slots=True, kw_only=True)
class ScenarioSpec:
    """One scenario of a spec: what to run and the limits its results must keep.

    Parameters
    ----------
    name : str
        The table name (``[scenario.<name>]``).
    kind : str
        ``"sync"``, ``"track"`` or ``"lock"`` (see the module docstring).
    seconds : float
        Run length [s]; default 2.4 (sync), 3.0 (track), 10.0 (lock).
    speed_fraction : float
        sync: master cruise speed as a fraction of its speed limit [1], in (0, 1].
    accel_s : float
        sync: time to reach the cruise speed [s].
    load_step_v : float
        sync: load step on the slaves [V] (negative opposes the motion).
    settling_band_pct : float
        sync, track: settling band as a share of the move [%], in (0, 100).
    settle_s : float
        lock: start transient excluded from the holding band [s], < ``seconds``.
    max_overshoot_pct, max_settling_time_s, max_sync_error_counts, max_rms_sync_error_counts,
    max_steady_lag_counts, max_saturation_pct, max_holding_band_counts : float or None
        Limits (units in the names; see :data:`LIMITS`); None: not checked.

    Raises
    ------
    SpecError
        Naming the key, the value and the unit of an invalid or impossible entry.
    """

    name: str
    kind: str
    seconds: float | None = None
    speed_fraction: float = 0.5
    accel_s: float = 0.1
    load_step_v: float = -0.3
    settling_band_pct: float = 2.0
    settle_s: float = 2.0
    max_overshoot_pct: float | None = None
    max_settling_time_s: float | None = None
    max_sync_error_counts: float | None = None
    max_rms_sync_error_counts: float | None = None
    max_steady_lag_counts: float | None = None
    max_saturation_pct: float | None = None
    max_holding_band_counts: float | None = None

    def __post_init__(self) -> None:
        p = f"scenario.{self.name}"
        if self.kind not in KINDS:
            raise SpecError(
                f"{p}.kind must be one of {', '.join(sorted(KINDS))}, got {show_value(self.kind)}"
            )
        params, limits = KINDS[self.kind]
        defaults = {f.name: f.default for f in fields(self)}
        for f in fields(self):
            if f.name in ("name", "kind", "seconds"):
                continue
            value = getattr(self, f.name)
            allowed = f.name in params or f.name in limits
            if not allowed and value != defaults[f.name]:
                raise SpecError(
                    f"{p}.{f.name} does not apply to a {show_value(self.kind)} scenario "
                    f"(it takes {', '.join(params + limits)})"
                )
            if value is not None:
                object.__setattr__(self, f.name, _number(f"{p}.{f.name}", value, _UNITS[f.name]))
        seconds = _DEFAULT_SECONDS[self.kind] if self.seconds is None else self.seconds
        seconds = _number(f"{p}.seconds", seconds, "s")
        if not 0 < seconds <= _MAX_SECONDS:
            raise SpecError(
                f"{p}.seconds must be in (0, {_MAX_SECONDS:g}] [s], got {show_value(seconds)}"
            )
        object.__setattr__(self, "seconds", seconds)
        if not 0 < self.speed_fraction <= 1:
            raise SpecError(
                f"{p}.speed_fraction must be in (0, 1] [1], got {show_value(self.speed_fraction)}"
            )
        if not self.accel_s > 0:
            raise SpecError(f"{p}.accel_s must be > 0 [s], got {show_value(self.accel_s)}")
        if not 0 < self.settling_band_pct < 100:
            raise SpecError(
                f"{p}.settling_band_pct must be in (0, 100) [%], got "
                f"{show_value(self.settling_band_pct)}"
            )
        if "settle_s" in params and not 0 <= self.settle_s < seconds:
            raise SpecError(
                f"{p}.settle_s must be >= 0 and shorter than seconds ({seconds:g} s) [s], "
                f"got {show_value(self.settle_s)}"
            )
        present = [k for k in limits if getattr(self, k) is not None]
        if not present:
            raise SpecError(f"{p} sets no limit; give at least one of {', '.join(limits)}")
        for k in present:
            v = getattr(self, k)
            if v < 0:
                raise SpecError(f"{p}.{k} must be >= 0 [{_UNITS[k]}], got {show_value(v)}")
        if self.max_saturation_pct is not None and self.max_saturation_pct > 100:
            raise SpecError(
                f"{p}.max_saturation_pct must be <= 100 [%], got "
                f"{show_value(self.max_saturation_pct)}"
            )
        if self.max_settling_time_s is not None and self.max_settling_time_s >= seconds:
            raise SpecError(
                f"{p}.max_settling_time_s must be shorter than the run ({seconds:g} s) [s], "
                f"got {show_value(self.max_settling_time_s)}"
            )
        # an RMS or a mean of |e| never exceeds its maximum: a larger limit is a mistake
        top = self.max_sync_error_counts
        for k in ("max_rms_sync_error_counts", "max_steady_lag_counts"):
            v = getattr(self, k)
            if top is not None and v is not None and v > top:
                raise SpecError(
                    f"{p}.{k} must be <= max_sync_error_counts ({top:g} counts) [counts], got "
                    f"{show_value(v)}"
                )

    @property
    def limits(self) -> dict[str, float]:
        """The limits this scenario sets: key → value (units in the key)."""
        return {k: getattr(self, k) for k in KINDS[self.kind][1] if getattr(self, k) is not None}

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of the parameters and limits of its kind."""
        params = KINDS[self.kind][0]
        out: dict[str, Any] = {"kind": self.kind, "name": self.name}
        out.update({k: getattr(self, k) for k in params})
        out.update(self.limits)
        return out


@dataclass(frozen=True, slots=True, kw_only=True)
class MonteCarlo:
    """The plant variants a spec must hold over (besides the nominal plants).

    Parameters
    ----------
    count : int
        Number of random variants (0: the nominal plants only).
    seed : int
        Seeds the variants and the noise streams.
    gain_spread : float
        ``gain_cps_per_v × U(1 − s, 1 + s)`` [1], in [0, 0.9].
    tau_spread : float
        ``tau_s × U(1 − s, 1 + s)`` [1], in [0, 0.9].
    offset_spread_v : float
        ``offset_v + U(−s, s)`` [V], in [0, 1].
    coulomb_spread : float
        ``coulomb_v × U(1 − s, 1 + s)`` [1], in [0, 1].
    axes : tuple of str
        Axes whose plants vary; empty: every axis.
    """

    count: int = 0
    seed: int = 0
    gain_spread: float = 0.0
    tau_spread: float = 0.0
    offset_spread_v: float = 0.0
    coulomb_spread: float = 0.0
    axes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for k, hi in (("count", _MAX_VARIANTS), ("seed", 2**63 - 1)):
            v = getattr(self, k)
            if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v <= hi:
                raise SpecError(
                    f"montecarlo.{k} must be an integer in 0..{hi}, got {show_value(v)}"
                )
        for k, hi, unit in (
            ("gain_spread", 0.9, "1"),
            ("tau_spread", 0.9, "1"),
            ("offset_spread_v", 1.0, "V"),
            ("coulomb_spread", 1.0, "1"),
        ):
            v = _number(f"montecarlo.{k}", getattr(self, k), unit)
            if not 0 <= v <= hi:
                raise SpecError(
                    f"montecarlo.{k} must be in [0, {hi:g}] [{unit}], got {show_value(v)}"
                )
            object.__setattr__(self, k, v)
        axes = self.axes
        if isinstance(axes, str) or not all(isinstance(a, str) for a in axes):
            raise SpecError(f"montecarlo.axes must be a list of axis names, got {show_value(axes)}")
        if len(set(axes)) != len(axes):
            raise SpecError(f"montecarlo.axes names an axis twice: {show_value(list(axes))}")
        object.__setattr__(self, "axes", tuple(axes))

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return {f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v
                for f in fields(self)}  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class Spec:
    """A verification spec (see the module docstring for the file).

    Parameters
    ----------
    name : str
    scenarios : tuple of ScenarioSpec
        At least one, unique names.
    montecarlo : MonteCarlo
    description : str
    rig : str or None
        Rig name the spec is written for (checked by :func:`verify` if given).
    max_period_error_ppm : float or None
        Limit on the timer's |period error| [ppm]; None: reported, not judged.
    """

    name: str
    scenarios: tuple[ScenarioSpec, ...]
    montecarlo: MonteCarlo = field(default_factory=MonteCarlo)
    description: str = ""
    rig: str | None = None
    max_period_error_ppm: float | None = None

    def __post_init__(self) -> None:
        if not self.scenarios:
            raise SpecError("a spec needs at least one [scenario.<name>] table")
        names = [s.name for s in self.scenarios]
        if len(set(names)) != len(names):
            raise SpecError(f"scenario names must be unique, got {show_value(names)}")
        if self.max_period_error_ppm is not None:
            v = _number("timer.max_period_error_ppm", self.max_period_error_ppm, "ppm")
            if v < 0:
                raise SpecError(
                    f"timer.max_period_error_ppm must be >= 0 [ppm], got {show_value(v)}"
                )
            object.__setattr__(self, "max_period_error_ppm", v)

    def scenario(self, name: str) -> ScenarioSpec:
        """The scenario called ``name``."""
        for s in self.scenarios:
            if s.name == name:
                return s
        raise SpecError(
            f"no scenario {show_value(name)}; scenarios: {[s.name for s in self.scenarios]}"
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return {
            "description": self.description,
            "max_period_error_ppm": self.max_period_error_ppm,
            "montecarlo": self.montecarlo.to_dict(),
            "name": self.name,
            "rig": self.rig,
            "scenarios": [s.to_dict() for s in self.scenarios],
        }


def _table(data: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    t = data.get(key, {})
    if not isinstance(t, Mapping):
        raise SpecError(f"[{key}] must be a table, got {type(t).__name__}")
    return t


def _only(table: Mapping[str, Any], path: str, allowed: Sequence[str]) -> None:
    check_keys(dict(table), path, (), tuple(allowed), error=SpecError)


def spec_from_dict(data: Mapping[str, Any], default_name: str = "spec") -> Spec:
    """Build and validate a :class:`Spec` from the parsed contents of a spec file.

    Raises
    ------
    SpecError
        Naming the first unknown key or invalid value (with its unit).
    """
    _only(data, "", ("spec", "timer", "montecarlo", "scenario"))
    meta = _table(data, "spec")
    _only(meta, "spec", ("name", "description", "rig"))
    for k in ("name", "description", "rig"):
        if k in meta and not isinstance(meta[k], str):
            raise SpecError(f"spec.{k} must be a string, got {show_value(meta[k])}")
    timer = _table(data, "timer")
    _only(timer, "timer", ("max_period_error_ppm",))
    mc_t = dict(_table(data, "montecarlo"))
    _only(mc_t, "montecarlo", [f.name for f in fields(MonteCarlo)])
    if "axes" in mc_t:
        if not isinstance(mc_t["axes"], list):
            raise SpecError(f"montecarlo.axes must be a list of axis names, got {mc_t['axes']!r}")
        mc_t["axes"] = tuple(mc_t["axes"])
    montecarlo = MonteCarlo(**mc_t)
    scen_t = data.get("scenario")
    if not isinstance(scen_t, Mapping) or not scen_t:
        raise SpecError("a spec needs at least one [scenario.<name>] table")
    scenarios = []
    for name, t in scen_t.items():
        if not isinstance(t, Mapping):
            raise SpecError(f"[scenario.{name}] must be a table")
        kind = t.get("kind", name)
        if kind not in KINDS:
            kinds = ", ".join(sorted(KINDS))
            if "kind" in t:
                raise SpecError(
                    f"scenario.{name}.kind must be one of {kinds}, got {show_value(kind)}"
                )
            raise SpecError(
                f"scenario.{name}: {show_value(name)} is not a scenario kind ({kinds}); add "
                f"kind = ..."
            )
        params, limits = KINDS[kind]
        _only(t, f"scenario.{name}", ("kind", *params, *limits))
        kwargs = {k: v for k, v in t.items() if k != "kind"}
        scenarios.append(ScenarioSpec(name=str(name), kind=kind, **kwargs))
    return Spec(
        name=meta.get("name", default_name),
        description=meta.get("description", ""),
        rig=meta.get("rig"),
        max_period_error_ppm=timer.get("max_period_error_ppm"),
        montecarlo=montecarlo,
        scenarios=tuple(scenarios),
    )


def load_spec(path: str | Path) -> Spec:
    """Read and validate a spec file (TOML).

    Parameters
    ----------
    path : str or Path
        The spec file, e.g. ``plants/pc-dual-servo.spec.toml``.

    Returns
    -------
    Spec

    Raises
    ------
    SpecError
        If the file is missing, not TOML, or any entry is unknown, invalid or impossible (the
        message names the key, the value and the unit).

    Examples
    --------
    >>> from servotune.rig import EXAMPLE_RIG_PATH
    >>> spec = load_spec(EXAMPLE_RIG_PATH.with_name("pc-dual-servo.spec.toml"))
    >>> [s.name for s in spec.scenarios]
    ['sync', 'track', 'lock']
    """
    return spec_from_bytes(read_bytes(path, SpecError, "spec file"), path)


def spec_from_bytes(raw: bytes, path: str | Path) -> Spec:
    """A spec from a spec file's bytes (``path`` names it in messages and gives the default
    name); see :func:`load_spec`."""
    p = Path(path)
    data = parse_toml(raw, str(path), SpecError, "spec file")
    stem = p.name.removesuffix(".toml").removesuffix(".spec")
    try:
        return spec_from_dict(data, default_name=stem)
    except SpecError as exc:
        raise SpecError(f"spec file {str(path)!r}: {exc}") from None
    except TypeError as exc:  # a table where a value belongs, and the like
        raise SpecError(f"spec file {str(path)!r}: {exc}") from None


# --- plant variants ------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class Variant:
    """One plant set the loop is verified on.

    Attributes
    ----------
    label : str
        ``"nominal"`` or ``"mc<i>"`` (1-based).
    plants : tuple of Plant
        One per rig axis.
    """

    label: str
    plants: tuple[Plant, ...]

    def to_dict(self, axis_names: Sequence[str]) -> dict[str, Any]:
        """Plain dict: the label and per axis the varied parameters."""
        keys = ("gain_cps_per_v", "tau_s", "offset_v", "coulomb_v")
        return {
            "label": self.label,
            "plants": {
                n: {k: float(getattr(p, k)) for k in keys}
                for n, p in zip(axis_names, self.plants, strict=True)
            },
        }


def plant_variants(rig: Rig, mc: MonteCarlo, seed: int | None = None) -> tuple[Variant, ...]:
    """The nominal plants and ``mc.count`` random variants (deterministic in the seed).

    Each variant draws, for every axis in rig order, four uniforms in [−1, 1] (gain, tau,
    offset, Coulomb) and applies the spreads of ``mc`` to the axes it names.

    Raises
    ------
    SpecError
        If ``mc.axes`` names an axis the rig does not have.
    """
    names = rig.axis_names
    for a in mc.axes:
        if a not in names:
            raise SpecError(
                f"montecarlo.axes names {show_value(a)}, the rig has axes {list(names)}"
            )
    vary = [n in mc.axes if mc.axes else True for n in names]
    nominal = tuple(a.plant for a in rig.axes)
    out = [Variant(label="nominal", plants=nominal)]
    rng = np.random.default_rng(_seed_seqs(mc.seed if seed is None else seed)[0])
    u = rng.uniform(-1.0, 1.0, size=(mc.count, len(names), 4))
    for i in range(mc.count):
        plants = []
        for j, p in enumerate(nominal):
            if not vary[j]:
                plants.append(p)
                continue
            g, t, o, c = (float(x) for x in u[i, j])
            plants.append(
                replace(
                    p,
                    gain_cps_per_v=p.gain_cps_per_v * (1.0 + mc.gain_spread * g),
                    tau_s=p.tau_s * (1.0 + mc.tau_spread * t),
                    offset_v=p.offset_v + mc.offset_spread_v * o,
                    coulomb_v=p.coulomb_v * (1.0 + mc.coulomb_spread * c),
                )
            )
        out.append(Variant(label=f"mc{i + 1}", plants=tuple(plants)))
    return tuple(out)


def _seed_seqs(seed: int) -> list[np.random.SeedSequence]:
    """Independent seed sequences: [0] the variants, [1] the noise streams."""
    return np.random.SeedSequence(int(seed)).spawn(2)


# --- results -------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class Row:
    """One limit of one scenario on one axis, judged over every variant.

    Attributes
    ----------
    scenario : str
    quantity : str
        What is measured (``overshoot_pct``, ``max_sync_error_counts``, …, ``fault_runs``).
    axis : str
    unit : str
    limit : float
        Upper bound [unit].
    worst : float
        Largest value over the variants [unit] (``inf``: never settled).
    variant : str
        Label of the variant giving ``worst``.
    """

    scenario: str
    quantity: str
    axis: str
    unit: str
    limit: float
    worst: float
    variant: str

    @property
    def passed(self) -> bool:
        """``worst <= limit`` (a NaN fails)."""
        return bool(self.worst <= self.limit)

    @property
    def margin(self) -> float:
        """``limit − worst`` [unit]; negative when violated."""
        return self.limit - self.worst

    @property
    def relative_margin(self) -> float | None:
        """``margin / limit`` [1]; None for a zero limit."""
        return self.margin / self.limit if self.limit > 0 else None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (non-finite numbers as None)."""
        rel = self.relative_margin
        return {
            "axis": self.axis,
            "limit": float(self.limit),
            "margin": json_float(self.margin),
            "passed": self.passed,
            "quantity": self.quantity,
            "relative_margin": None if rel is None else json_float(rel),
            "scenario": self.scenario,
            "unit": self.unit,
            "variant": self.variant,
            "worst": json_float(self.worst),
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class Check:
    """A verification check that is not a scenario limit.

    Attributes
    ----------
    name : str
        ``counter_unwrap``, ``counter_input_frequency``, ``timer_period`` or ``overflow``.
    passed : bool
    value : float
        The checked quantity [unit].
    limit : float or None
        Its bound [unit]; None if only reported.
    unit : str
    detail : str
        One line for people.
    facts : mapping
        The numbers behind it.
    """

    name: str
    passed: bool
    value: float
    limit: float | None
    unit: str
    detail: str
    facts: Mapping[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return {
            "detail": self.detail,
            "facts": dict(self.facts),
            "limit": None if self.limit is None else json_float(self.limit),
            "name": self.name,
            "passed": self.passed,
            "unit": self.unit,
            "value": json_float(self.value),
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class Verification:
    """What :func:`verify` found.

    Attributes
    ----------
    spec : Spec
    rig_name : str
    axis_names : tuple of str
    seed : int
        The seed used (variants and noise).
    variants : tuple of Variant
        The nominal plants first.
    rows : tuple of Row
        Every limit of every scenario (empty if the runs were skipped, see ``checks``).
    checks : tuple of Check
    """

    spec: Spec
    rig_name: str
    axis_names: tuple[str, ...]
    seed: int
    variants: tuple[Variant, ...]
    rows: tuple[Row, ...]
    checks: tuple[Check, ...]

    @property
    def passed(self) -> bool:
        """Every limit and every check holds (and the runs were made)."""
        return (
            bool(self.rows)
            and all(r.passed for r in self.rows)
            and all(c.passed for c in self.checks)
        )

    @property
    def failures(self) -> list[str]:
        """One line per violated limit or failed check."""
        out = [
            f"{r.scenario}: {r.quantity} of {r.axis} = {_fmt(r.worst)} {r.unit} > limit "
            f"{_fmt(r.limit)} {r.unit} (variant {r.variant})"
            for r in self.rows
            if not r.passed
        ]
        out += [f"check {c.name}: {c.detail}" for c in self.checks if not c.passed]
        if not self.rows:
            out.append("closed-loop runs skipped (see the overflow check)")
        return out

    def row(self, scenario: str, quantity: str, axis: str) -> Row:
        """The row of one scenario, quantity and axis."""
        for r in self.rows:
            if (r.scenario, r.quantity, r.axis) == (scenario, quantity, axis):
                return r
        raise KeyError(f"no row {scenario}/{quantity}/{axis}")

    def check(self, name: str) -> Check:
        """The check called ``name``."""
        for c in self.checks:
            if c.name == name:
                return c
        raise KeyError(f"no check {show_value(name)}")

    def to_dict(self) -> dict[str, Any]:
        """Plain dict, JSON-ready (``json.dumps(..., sort_keys=True)``)."""
        return {
            "checks": [c.to_dict() for c in self.checks],
            "failures": self.failures,
            "passed": self.passed,
            "rig": self.rig_name,
            "rows": [r.to_dict() for r in self.rows],
            "seed": self.seed,
            "spec": self.spec.to_dict(),
            "variants": [v.to_dict(self.axis_names) for v in self.variants],
        }


# --- checks --------------------------------------------------------------------------------


def max_safe_gain_q() -> int:
    """Largest gain magnitude ``|q|`` whose product with a clamped error fits int64.

    Errors are clamped to ``±(2^31 − 1)`` before any product (SPEC §6), so ``|q · e| <= |q| ·
    (2^31 − 1)``; that is at most ``2^63 − 1`` for ``|q| <= 2^32 + 2``.

    Examples
    --------
    >>> max_safe_gain_q() == 2**32 + 2
    True
    """
    return int(INT64_MAX) // int(E_MAX)


def _gain_terms(c: AxisController) -> list[tuple[str, int, int]]:
    """(name, largest |q| the runtime multiplies by a clamped value, f) of every gain."""
    terms = [("lock_gain", abs(c.lock_gain.q), c.lock_gain.f)]
    t = c.task
    if t is None:
        return terms
    if isinstance(t, FuzzyPIDConstants):
        for name, base, (tq, f_t) in zip(TABLE_NAMES, t.bases, t.tables, strict=True):
            shift = base.f - int(f_t)
            if shift < 0:
                terms.append((f"{name} table (f_t {f_t} > f {base.f})", 0, -1))
                continue
            sched = [int(base.q) + int(x) * (1 << shift) for x in np.asarray(tq).reshape(-1)]
            q_max = max(abs(int(base.q)), *(abs(s) for s in sched))
            label = {"kp": "kp", "ki": "ki_t", "kd": "kd_t", "k1": "k1_t"}[name]
            terms.append((f"scheduled {label}", q_max, base.f))
        terms.append(("ke", abs(t.ke.q), t.ke.f))
        terms.append(("kec", abs(t.kec.q), t.kec.f))
    else:
        terms.append(("kp", abs(t.kp.q), t.kp.f))
        terms.append(("ki_t", abs(t.ki_t.q), t.ki_t.f))
    return terms


def check_overflow(tuning: Tuning, rig: Rig) -> Check:
    """Prove, on the tuning's own constants, that no runtime sum or product can overflow.

    The bound (SPEC §6):

    - errors, error changes and reference changes are clamped to ``|e| <= 2^31 − 1`` before
      any product, so a product ``q · e`` fits int64 if ``|q| <= 2^32 + 2``
      (:func:`max_safe_gain_q`); for the fuzzy-PID law ``q`` is the scheduled gain
      ``Kx0 + ΔKx`` (the table entry aligned exactly by ``2^(f − f_t)``), checked over every
      table cell;
    - every gain has ``0 <= f <= F_U`` (products align to the output's ``F_U`` fraction bits by
      a multiplication by ``2^(F_U − f)``, saturating, never a shift of a negative value), and
      every table ``f_t <= f``;
    - the integrator is clamped to the D/A span, ``|I| <= 2^(dac_bits − 1) · 2^F_U``; every
      other sum is a saturating add, so ``|u_q| <= 2^63 − 1`` and the code
      ``shift_round(u_q, F_U) + zero`` fits easily;
    - positions are int64 counts: at the fastest axis speed limit they overflow only after the
      time in ``facts["position_overflow_years"]``.

    Returns
    -------
    Check
        ``value`` is ``log2`` of the largest product bound [bits], ``limit`` 63.
    """
    limit = max_safe_gain_q()
    per_axis: dict[str, Any] = {}
    bad: list[str] = []
    worst_bound = 1
    for name, c in zip(tuning.axis_names, tuning.controllers, strict=True):
        entries = {}
        for term, q_max, f in _gain_terms(c):
            bound = q_max * int(E_MAX)
            worst_bound = max(worst_bound, bound)
            ok_f = 0 <= f <= F_U
            ok_q = q_max <= limit
            entries[term] = {"f": f, "product_bound": bound, "q_max": q_max, "ok": ok_f and ok_q}
            if not ok_f:
                bad.append(f"{name} {term}: f = {f} outside 0..{F_U} (needs a right shift)")
            elif not ok_q:
                bad.append(
                    f"{name} {term}: |q| up to {q_max} > {limit}, |q·e| up to 2^"
                    f"{math.log2(bound):.2f} > 2^63 − 1"
                )
        per_axis[name] = entries
    i_bound = (1 << (rig.dac.bits - 1)) << F_U
    v_max = max(a.speed_limit_rpm for a in rig.axes) / 60.0 * rig.counts_per_rev
    years = float(INT64_MAX) / v_max / (365.25 * 86400.0)
    log2_worst = math.log2(worst_bound)
    if bad:
        detail = "; ".join(bad)
    else:
        detail = (
            f"largest |gain·e| <= 2^{log2_worst:.2f} < 2^63 (|e| <= 2^31 − 1, gains <= "
            f"{limit}); integrator <= 2^{math.log2(i_bound):.0f}; other sums saturate"
        )
    return Check(
        name="overflow",
        passed=not bad,
        value=log2_worst,
        limit=63.0,
        unit="bits",
        detail=detail,
        facts={
            "axes": per_axis,
            "error_clamp": int(E_MAX),
            "integrator_bound": i_bound,
            "max_safe_gain_q": limit,
            "position_overflow_years": years,
        },
    )


def check_timer(rig: Rig, max_period_error_ppm: float | None = None) -> Check:
    """The timer's achieved period against the requested one [ppm] (judged only with a limit)."""
    t = rig.timer
    err = t.period_error_ppm
    ok = max_period_error_ppm is None or abs(err) <= max_period_error_ppm
    return Check(
        name="timer_period",
        passed=bool(ok),
        value=err,
        limit=max_period_error_ppm,
        unit="ppm",
        detail=(
            f"divisor {t.divisor}: {t.achieved_period_s * 1e3:.6f} ms for {t.period_s * 1e3:g} "
            f"ms requested ({err:+.1f} ppm"
            + (")" if max_period_error_ppm is None else f", limit ±{max_period_error_ppm:g})")
        ),
        facts={
            "achieved_period_s": t.achieved_period_s,
            "divisor": t.divisor,
            "requested_period_s": t.period_s,
        },
    )


@dataclass(slots=True)
class _Fastest:
    """Largest motion per tick and speed seen in the runs, and where."""

    counts_per_tick: float = 0.0
    speed_cps: float = 0.0
    where_tick: str = "no run"
    where_speed: str = "no run"


def check_speed(
    rig: Rig,
    max_counts_per_tick: float,
    max_speed_cps: float,
    *,
    where_tick: str = "",
    where_speed: str = "",
) -> tuple[Check, Check]:
    """The fastest simulated motion against the counter's two speed limits.

    Parameters
    ----------
    rig : Rig
    max_counts_per_tick : float
        Largest |motion| between two ticks in any run [counts/tick].
    max_speed_cps : float
        Largest |speed| in any run [counts/s].
    where_tick, where_speed : str
        Which run each came from (for the detail lines).

    Returns
    -------
    (Check, Check)
        ``counter_unwrap``: motion per tick against ``2^(bits − 8)`` (the high-byte rule);
        ``counter_input_frequency``: speed [r/min] against the card's input-frequency limit.
    """
    c, T, cpr = rig.counter, rig.period_s, rig.counts_per_rev
    lim_tick = hw_counter.max_counts_per_tick(c.bits)
    lim_unwrap_rpm = hw_counter.unwrap_speed_limit_rpm(c.bits, cpr, T)
    lim_input_rpm = hw_counter.input_speed_limit_rpm(c.max_input_hz, rig.encoder.pulses_per_rev)
    rpm_tick = max_counts_per_tick / T / cpr * 60.0
    rpm = max_speed_cps / cpr * 60.0
    unwrap = Check(
        name="counter_unwrap",
        passed=bool(max_counts_per_tick <= lim_tick),
        value=float(max_counts_per_tick),
        limit=float(lim_tick),
        unit="counts/tick",
        detail=(
            f"fastest motion {max_counts_per_tick:.1f} counts/tick ({rpm_tick:.0f} r/min)"
            f"{f' ({where_tick})' if where_tick else ''}; "
            f"the high-byte rule holds up to {lim_tick} counts/tick ({lim_unwrap_rpm:.0f} r/min)"
        ),
        facts={"limit_rpm": lim_unwrap_rpm, "value_rpm": rpm_tick},
    )
    freq = Check(
        name="counter_input_frequency",
        passed=bool(rpm <= lim_input_rpm),
        value=rpm,
        limit=lim_input_rpm,
        unit="r/min",
        detail=(
            f"fastest speed {rpm:.0f} r/min ({max_speed_cps * T:.1f} counts/tick)"
            f"{f' ({where_speed})' if where_speed else ''}; the card "
            f"counts up to {c.max_input_hz:g} Hz = {lim_input_rpm:.0f} r/min with "
            f"{rig.encoder.pulses_per_rev:g} pulses/rev"
        ),
        facts={
            "limit_counts_per_tick": lim_input_rpm / 60.0 * cpr * T,
            "value_counts_per_tick": max_speed_cps * T,
        },
    )
    return unwrap, freq


# --- running the scenarios -----------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class _MoveWindows:
    start: int  # last tick before the master's reference moves
    target: float  # the reference's final value [counts]
    steady: tuple[int, int]  # [lo, hi) ticks of the steady-lag window


def _inputs(rig: Rig, sc: ScenarioSpec) -> Inputs:
    assert sc.seconds is not None  # resolved by ScenarioSpec
    if sc.kind == "sync":
        return sync_move(
            rig,
            seconds=sc.seconds,
            speed_fraction=sc.speed_fraction,
            accel_s=sc.accel_s,
            load_step_v=sc.load_step_v,
        ).inputs
    if sc.kind == "track":
        return build_scenario(rig, "track", axis=_master(rig)[1], seconds=sc.seconds).inputs
    n = math.floor(sc.seconds / rig.period_s + 0.5)
    if n < 3:
        raise SpecError(f"scenario.{sc.name}.seconds gives only {n} ticks")
    return Inputs.hold(n, len(rig.axes))


def _master(rig: Rig) -> tuple[int, str]:
    for i, a in enumerate(rig.axes):
        if a.role == "master":
            return i, a.name
    raise SpecError(f"rig {show_value(rig.name)} has no master axis")


def _move_windows(rig: Rig, sc: ScenarioSpec, inputs: Inputs) -> _MoveWindows:
    i_m, _ = _master(rig)
    ref = inputs.ref_counts[:, i_m]
    moving = np.flatnonzero(ref != ref[0])
    if moving.size == 0:
        raise SpecError(f"scenario {show_value(sc.name)}: the master's reference does not move")
    start = max(int(moving[0]) - 1, 0)
    direction = 1 if ref[-1] >= ref[0] else -1
    dr = direction * np.diff(ref)
    cruise = np.flatnonzero(dr >= dr.max() - 2)  # within 2 counts/tick of the top speed
    c0, c1 = int(cruise[0]) + 1, int(cruise[-1]) + 1
    hi = c1
    for j, a in enumerate(rig.axes):
        if a.role == "slave":
            changed = np.flatnonzero(inputs.load_v[:, j] != inputs.load_v[0, j])
            if changed.size:
                hi = min(hi, int(changed[0]))
    lo = (c0 + hi) // 2
    if hi - lo < 3:
        raise SpecError(
            f"scenario {show_value(sc.name)} has no constant-speed part before the load step "
            f"to measure "
            "the steady lag; lengthen seconds or shorten accel_s"
        )
    return _MoveWindows(start=start, target=float(ref[-1]), steady=(lo, hi))


def _step_values(
    t: np.ndarray, y: np.ndarray, y_init: float, target: float, band_pct: float
) -> tuple[float, float]:
    from servotune.metrics import step_info

    info = step_info(t, y, y_init=y_init, y_final=target, settling_threshold=band_pct / 100.0)
    settle = info.settling_time_s
    return info.overshoot_pct, (math.inf if math.isnan(settle) else settle)


def _worst(values: np.ndarray, labels: Sequence[str]) -> tuple[float, str]:
    """Largest value (NaN counts as the largest) and the label of its variant."""
    v = np.where(np.isnan(values), np.inf, values)
    i = int(np.argmax(v))
    return float(v[i]), labels[i]


def _run(
    loop: Loop, variants: Sequence[Variant], seeds: Sequence[int], inputs: Inputs
) -> dict[str, np.ndarray]:
    """Traces of every variant, run in chunks of the engine's batch."""
    parts: list[dict[str, np.ndarray]] = []
    for k in range(0, len(variants), _CHUNK):
        vs = variants[k : k + _CHUNK]
        batch = prepare_batch(
            loop, plants=[v.plants for v in vs], seeds=list(seeds[k : k + _CHUNK])
        )
        res = run_batch(batch, inputs, metrics_only=False)
        assert res.traces is not None
        parts.append(res.traces)
    keys = ("counter", "pos_counts", "err_counts", "flags", "true_pos_counts", "speed_cps")
    return {key: np.concatenate([p[key] for p in parts]) for key in keys}


def _evaluate(
    rig: Rig,
    sc: ScenarioSpec,
    inputs: Inputs,
    tr: dict[str, np.ndarray],
    labels: Sequence[str],
) -> list[Row]:
    names = rig.axis_names
    n_v, n_t = tr["flags"].shape[:2]
    limits = sc.limits
    values: dict[tuple[str, str], np.ndarray] = {}
    pos = tr["true_pos_counts"]
    flags = tr["flags"]
    if sc.kind in ("sync", "track"):
        win = _move_windows(rig, sc, inputs)
        i_m, _ = _master(rig)
        t = (np.arange(n_t - win.start, dtype=np.int64)) * rig.period_s
        for a, name in enumerate(names):
            task = inputs.mode[:, a] == MODE_TASK
            if not task.any():
                continue
            over = np.empty(n_v)
            settle = np.empty(n_v)
            for b in range(n_v):
                y = pos[b, win.start :, a]
                over[b], settle[b] = _step_values(
                    t, y, float(y[0]), win.target, sc.settling_band_pct
                )
            values[("overshoot_pct", name)] = over
            values[("settling_time_s", name)] = settle
            sat = (flags[:, :, a] & FLAG_SATURATED) != 0
            values[("saturation_pct", name)] = 100.0 * sat[:, task].mean(axis=1)
            if rig.axes[a].role == "slave":
                e = pos[:, :, i_m] - pos[:, :, a]
                et = e[:, task]
                values[("max_sync_error_counts", name)] = np.abs(et).max(axis=1)
                values[("rms_sync_error_counts", name)] = np.sqrt(np.mean(et * et, axis=1))
                lo, hi = win.steady
                values[("steady_lag_counts", name)] = np.abs(e[:, lo:hi]).mean(axis=1)
    else:
        k0 = math.ceil(sc.settle_s / rig.period_s)
        bits = rig.counter.bits
        for a, name in enumerate(names):
            # the plant's whole count in the runtime's frame (relative to its first read)
            first = (tr["counter"][:, 0, a] - rig.axes[a].counter_init) % (1 << bits)
            first = np.where(first >= 1 << (bits - 1), first - (1 << bits), first)
            y = np.floor(pos[:, :, a]).astype(np.int64) - first[:, None]
            target = tr["pos_counts"][:, :, a] + tr["err_counts"][:, :, a]
            values[("holding_band_counts", name)] = (
                np.abs(target[:, k0:] - y[:, k0:]).max(axis=1).astype(float)
            )
            sat = (flags[:, :, a] & FLAG_SATURATED) != 0
            values[("saturation_pct", name)] = 100.0 * sat.mean(axis=1)
    rows = []
    for key, lim in limits.items():
        quantity, unit = LIMITS[key]
        for name in names:
            if (quantity, name) in values:
                worst, label = _worst(values[(quantity, name)], labels)
                rows.append(Row(scenario=sc.name, quantity=quantity, axis=name, unit=unit,
                                limit=lim, worst=worst, variant=label))  # fmt: skip
    for a, name in enumerate(names):
        faulted = ((flags[:, :, a] & FAULT_MASK) != 0).any(axis=1)
        first = labels[int(np.argmax(faulted))] if faulted.any() else labels[0]
        rows.append(Row(scenario=sc.name, quantity=_FAULT_QUANTITY, axis=name, unit="runs",
                        limit=0.0, worst=float(faulted.sum()), variant=first))  # fmt: skip
    return rows


def verify(
    tuning: Tuning,
    rig: Rig,
    spec: Spec,
    *,
    seed: int | None = None,
    progress: Callable[[str], None] | None = None,
) -> Verification:
    """Verify a tuning against a spec on the bit-true closed loop.

    Every scenario runs for the nominal plants and every Monte Carlo variant
    (:func:`plant_variants`), each with its own noise stream, through the engine with the
    tuning's quantised constants (nothing is re-quantised). Then the checks: the fastest motion
    against the counter's limits (:func:`check_speed`), the timer period (:func:`check_timer`)
    and the overflow bound (:func:`check_overflow`; if it fails the runs are skipped, since the
    runtime arithmetic is not defined for such constants).

    Parameters
    ----------
    tuning : Tuning
    rig : Rig
        The rig to verify on (its axes and period must match the tuning's).
    spec : Spec
    seed : int, optional
        Seeds the variants and the noise; default ``spec.montecarlo.seed``. Same inputs and
        seed give the same result.
    progress : callable, optional
        Receives one line per step (the CLI prints them on stderr).

    Returns
    -------
    Verification

    Raises
    ------
    TuningError
        If the tuning does not belong to the rig (axes, period).
    SpecError
        If the spec names another rig, an axis the rig lacks, or a scenario cannot be built.
    """
    say = progress or (lambda _msg: None)
    if spec.rig is not None and spec.rig != rig.name:
        raise SpecError(
            f"spec {show_value(spec.name)} is written for rig {show_value(spec.rig)}, not "
            f"{show_value(rig.name)}"
        )
    loop = tuning.loop(rig)
    sync_limits = ("max_sync_error_counts", "max_rms_sync_error_counts", "max_steady_lag_counts")
    if not any(a.role == "slave" for a in rig.axes):
        for sc in spec.scenarios:
            for k in sc.limits:
                if k in sync_limits:
                    raise SpecError(
                        f"scenario.{sc.name}.{k} needs a slave axis; rig "
                        f"{show_value(rig.name)} has none"
                    )
    used_seed = spec.montecarlo.seed if seed is None else int(seed)
    variants = plant_variants(rig, spec.montecarlo, used_seed)
    labels = [v.label for v in variants]
    noise = [int(s) for s in _seed_seqs(used_seed)[1].generate_state(len(variants), np.uint64)]
    overflow = check_overflow(tuning, rig)
    checks: list[Check] = [overflow, check_timer(rig, spec.max_period_error_ppm)]
    rows: list[Row] = []
    if not overflow.passed:
        say("verify: constants break the overflow bound; closed-loop runs skipped")
        return Verification(spec=spec, rig_name=rig.name, axis_names=rig.axis_names,
                            seed=used_seed, variants=variants, rows=(),
                            checks=tuple(checks))  # fmt: skip
    fastest = _Fastest()
    for sc in spec.scenarios:
        say(f"verify: scenario {sc.name} ({sc.kind}, {sc.seconds:g} s), {len(variants)} plant sets")
        try:
            inputs = _inputs(rig, sc)
        except SpecError as exc:
            raise SpecError(f"scenario.{sc.name}: {exc}") from None
        if sc.kind != "lock":
            _move_windows(rig, sc, inputs)  # a bad scenario fails before the runs
        tr = _run(loop, variants, noise, inputs)
        rows += _evaluate(rig, sc, inputs, tr, labels)
        step = np.abs(np.diff(tr["true_pos_counts"], axis=1))
        if step.size and step.max() > fastest.counts_per_tick:
            b, _, a = np.unravel_index(int(np.argmax(step)), step.shape)
            fastest.counts_per_tick = float(step.max())
            fastest.where_tick = f"{sc.name}, {rig.axes[a].name}, {labels[b]}"
        spd = np.abs(tr["speed_cps"])
        if spd.max() > fastest.speed_cps:
            b, _, a = np.unravel_index(int(np.argmax(spd)), spd.shape)
            fastest.speed_cps = float(spd.max())
            fastest.where_speed = f"{sc.name}, {rig.axes[a].name}, {labels[b]}"
    checks[:0] = check_speed(
        rig,
        fastest.counts_per_tick,
        fastest.speed_cps,
        where_tick=fastest.where_tick,
        where_speed=fastest.where_speed,
    )
    result = Verification(spec=spec, rig_name=rig.name, axis_names=rig.axis_names,
                          seed=used_seed, variants=variants, rows=tuple(rows),
                          checks=tuple(checks))  # fmt: skip
    say(f"verify: {'PASSED' if result.passed else 'FAILED'}")
    return result


# --- presenting ----------------------------------------------------------------------------


def _fmt(x: float | None, digits: int = 4) -> str:
    if x is None:
        return "n/a"
    if math.isinf(x):
        return "never" if x > 0 else "-inf"
    if math.isnan(x):
        return "nan"
    if x == 0:
        return "0"
    if abs(x) >= 1e5 or abs(x) < 1e-3:
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits}g}"


def format_table(verification: Verification) -> str:
    """A pass/fail table with margins, then the checks and the verdict (for the terminal)."""
    v = verification
    head = ("scenario", "quantity", "axis", "limit", "worst", "margin", "margin %", "variant", "")
    lines = [head]
    for r in v.rows:
        rel = r.relative_margin
        lines.append((
            r.scenario,
            r.quantity,
            r.axis,
            f"{_fmt(r.limit)} {r.unit}",
            f"{_fmt(r.worst)} {r.unit}",
            _fmt(r.margin),
            "n/a" if rel is None or not math.isfinite(rel) else f"{100.0 * rel:.0f}",
            r.variant,
            "ok" if r.passed else "FAIL",
        ))  # fmt: skip
    widths = [max(len(row[i]) for row in lines) for i in range(len(head))]
    right = {3, 4, 5, 6}
    out = [
        f"verify: spec {show_value(v.spec.name)} on rig {show_value(v.rig_name)}, seed {v.seed}, "
        f"{len(v.variants)} plant sets (nominal + {len(v.variants) - 1} Monte Carlo)"
    ]
    for row in lines:
        cells = [c.rjust(w) if i in right else c.ljust(w)
                 for i, (c, w) in enumerate(zip(row, widths, strict=True))]  # fmt: skip
        out.append("  ".join(cells).rstrip())
    if not v.rows:
        out.append("(closed-loop runs skipped)")
    out.append("checks")
    for c in v.checks:
        out.append(f"  {'ok  ' if c.passed else 'FAIL'}  {c.name}: {c.detail}")
    n_fail = sum(not r.passed for r in v.rows) + sum(not c.passed for c in v.checks)
    out.append("PASSED" if v.passed else f"FAILED ({n_fail} of {len(v.rows) + len(v.checks)})")
    return "\n".join(out)
