"""The spec file: the limits a tuning must keep per scenario and the plant spread they must
hold over (:func:`load_spec`); :func:`~servotune.verify.run.verify` checks a tuning against it.

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

    [margins]                     # every loop the runtime can run (analysis.margins); defaults:
    min_phase_margin_deg = 45.0   # [deg]
    min_gain_margin_db = 6.0      # [dB]
    max_sensitivity = 2.0         # peak sensitivity Ms [1] (Åström & Hägglund: 1.2–2.0)
    extra_ticks = 1               # latency the loops must also take [ticks] (0: none)
    samples = 32                  # plant sets drawn inside the box besides its corners
    min_filter_attenuation_db = 10.0  # optional: each mode attenuated at least this much by its
                                  # axis's output filters over its frequency range [dB]

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
- ``max_residual_vibration_counts`` [counts]: for an axis whose plant has modes, the largest
  band-passed position at its modes after the reference stops
  (:func:`servotune.verify.scenario_values.residual_vibration`); an axis without modes has none.

``lock`` (every axis held by the position-lock module): ``seconds`` (10.0), ``settle_s`` [s]
(2.0). Limits: ``max_holding_band_counts`` [counts], max |lock target − position| after
``settle_s``; ``max_saturation_pct`` (over all ticks).

Positions are the plant's (noise-free, ``floor`` to whole counts for the lock band) in the
runtime's frame; every scenario also requires that no run latches a fault.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from servotune.analysis.margins import DEFAULT_LIMITS, MarginLimits
from servotune.errors import SpecError
from servotune.io.files import parse_toml, read_bytes
from servotune.validate import (
    check_integer,
    check_keys,
    check_number,
    check_strings,
    check_table,
    show_value,
)

__all__ = [
    "KINDS",
    "LIMITS",
    "MonteCarlo",
    "ScenarioSpec",
    "Spec",
    "load_spec",
    "spec_from_bytes",
    "spec_from_dict",
]

LIMITS: Mapping[str, tuple[str, str]] = {
    "max_overshoot_pct": ("overshoot_pct", "%"),
    "max_settling_time_s": ("settling_time_s", "s"),
    "max_sync_error_counts": ("max_sync_error_counts", "counts"),
    "max_rms_sync_error_counts": ("rms_sync_error_counts", "counts"),
    "max_steady_lag_counts": ("steady_lag_counts", "counts"),
    "max_saturation_pct": ("saturation_pct", "%"),
    "max_holding_band_counts": ("holding_band_counts", "counts"),
    "max_residual_vibration_counts": ("residual_vibration_counts", "counts"),
}
"""Spec limit key → (quantity it bounds, unit)."""

_MOVE_LIMITS = (
    "max_overshoot_pct",
    "max_settling_time_s",
    "max_sync_error_counts",
    "max_rms_sync_error_counts",
    "max_steady_lag_counts",
    "max_saturation_pct",
    "max_residual_vibration_counts",
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
_MAX_VARIANTS = 100_000_000  # 1e8 plant sets: an hour on a cluster (docs/scale.md)


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
    max_residual_vibration_counts : float or None
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
    max_residual_vibration_counts: float | None = None

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
        return {
            f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v
            for f in fields(self)
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class Spec:
    """A verification spec (see the module docstring for the file).

    Parameters
    ----------
    name : str
        The spec's name, quoted by reports and verification records.
    scenarios : tuple of ScenarioSpec
        At least one, unique names.
    montecarlo : MonteCarlo
    description : str
    rig : str or None
        Rig name the spec is written for (checked by :func:`verify` if given).
    max_period_error_ppm : float or None
        Limit on the timer's |period error| [ppm]; None: reported, not judged.
    margins : MarginLimits
        Limits of every loop's margins over the plant set (default PM >= 45°, GM >= 6 dB,
        Ms <= 2.0).
    margin_extra_ticks : int
        Extra latency the loops must also keep those margins with [ticks], 0..10.
    margin_samples : int
        Plant sets drawn inside the plant set's box besides its corners (seeded by the
        Monte-Carlo seed), 0..10,000.
    min_filter_attenuation_db : float or None
        ``[margins] min_filter_attenuation_db``: every mode of every axis must be attenuated by
        at least this much by the axis's output filters, over the mode's frequency range
        (:func:`servotune.verify.checks.check_filter_attenuation`) [dB], > 0; None: not judged.
    """

    name: str
    scenarios: tuple[ScenarioSpec, ...]
    montecarlo: MonteCarlo = field(default_factory=MonteCarlo)
    description: str = ""
    rig: str | None = None
    max_period_error_ppm: float | None = None
    margins: MarginLimits = DEFAULT_LIMITS
    margin_extra_ticks: int = 1
    margin_samples: int = 32
    min_filter_attenuation_db: float | None = None

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
        check_integer(
            "margins.extra_ticks", self.margin_extra_ticks, "ticks", hi=10, error=SpecError
        )
        check_integer(
            "margins.samples", self.margin_samples, "plant sets", hi=10_000, error=SpecError
        )
        if self.min_filter_attenuation_db is not None:
            check_number(
                "margins.min_filter_attenuation_db",
                self.min_filter_attenuation_db,
                "dB",
                strict=True,
                hi=200.0,
                error=SpecError,
            )

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
            "margins": {
                **self.margins.to_dict(),
                "extra_ticks": self.margin_extra_ticks,
                "samples": self.margin_samples,
            }
            | (
                {"min_filter_attenuation_db": self.min_filter_attenuation_db}
                if self.min_filter_attenuation_db is not None
                else {}
            ),
            "max_period_error_ppm": self.max_period_error_ppm,
            "montecarlo": self.montecarlo.to_dict(),
            "name": self.name,
            "rig": self.rig,
            "scenarios": [s.to_dict() for s in self.scenarios],
        }


def _table(data: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    return check_table(data, key, error=SpecError, required=False)


def _only(table: Mapping[str, Any], path: str, allowed: Sequence[str]) -> None:
    check_keys(dict(table), path, (), tuple(allowed), error=SpecError)


def spec_from_dict(data: Mapping[str, Any], default_name: str = "spec") -> Spec:
    """Build and validate a :class:`Spec` from the parsed contents of a spec file.

    Raises
    ------
    SpecError
        Naming the first unknown key or invalid value (with its unit).
    """
    _only(data, "", ("spec", "timer", "montecarlo", "margins", "scenario"))
    meta = _table(data, "spec")
    _only(meta, "spec", ("name", "description", "rig"))
    check_strings(meta, "spec", ("name", "description", "rig"), error=SpecError)
    timer = _table(data, "timer")
    _only(timer, "timer", ("max_period_error_ppm",))
    mc_t = dict(_table(data, "montecarlo"))
    _only(mc_t, "montecarlo", [f.name for f in fields(MonteCarlo)])
    if "axes" in mc_t:
        if not isinstance(mc_t["axes"], list):
            raise SpecError(f"montecarlo.axes must be a list of axis names, got {mc_t['axes']!r}")
        mc_t["axes"] = tuple(mc_t["axes"])
    montecarlo = MonteCarlo(**mc_t)
    margins_t = dict(_table(data, "margins"))
    limit_keys = [f.name for f in fields(MarginLimits)]
    _only(
        margins_t, "margins", [*limit_keys, "extra_ticks", "samples", "min_filter_attenuation_db"]
    )
    try:
        margin_limits = MarginLimits(**{k: v for k, v in margins_t.items() if k in limit_keys})
    except SpecError as exc:
        raise SpecError(f"margins.{exc}") from None
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
        margins=margin_limits,
        margin_extra_ticks=margins_t.get("extra_ticks", 1),
        margin_samples=margins_t.get("samples", 32),
        min_filter_attenuation_db=margins_t.get("min_filter_attenuation_db"),
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
