"""The linkage spec: what a linkage plan must keep when it is verified.

:func:`~servotune.arch.linkage.verify_plan_files` runs a plan
(:mod:`~servotune.arch.linkage.plan`) under a spec's conditions and judges it against the
spec's limits (:mod:`~servotune.arch.linkage.verify`).

Linkage spec (TOML; every key optional unless marked, at least one limit)::

    [spec]
    name = "linkage-6axis"         # default: the file name without .spec.toml
    description = "..."
    config = "linkage-6axis"       # if given, the plan's config name must match
    [run]
    seed = 0                       # encoder-noise seed of every run
    seconds = 15.0                 # simulated time [s]; default the path plus settle_s
    [clock]
    tolerance_ppm = 20.0           # each CPU verified at clock_ppm and at ± this [ppm]
    max_phase_drift_ticks = 1.0    # |tick time − index·T| of any CPU tick, in ticks
    [bus]
    max_utilisation_pct = 50.0     # frame time / broadcast period [%]
    [queue]
    max_underrun_ticks = 0         # ticks whose command was not in the queue, per CPU
    max_overrun_blocks = 0         # blocks that did not fit the queue, per CPU
    min_level_setpoints = 1        # lowest queue level before a pop [setpoints]
    max_skipped_setpoints = 0      # commands discarded at syncs (a CPU a whole tick behind)
    [contour]
    max_contour_error_counts = 2000.0   # distance from the programmed path [counts]
    [margins]                      # each axis's PI loop (servotune.analysis.margins)
    min_phase_margin_deg = 45.0
    min_gain_margin_db = 6.0
    max_sensitivity = 2.0
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from servotune.analysis.margins import MarginLimits
from servotune.arch.linkage.bus import MAX_CLOCK_PPM
from servotune.errors import SpecError
from servotune.io.files import parse_toml_as
from servotune.provenance import SourceFile
from servotune.validate import (
    check_integer,
    check_keys,
    check_number,
    check_seed,
    check_strings,
    check_table,
)

__all__ = [
    "LinkageSpec",
    "linkage_spec_from_bytes",
    "linkage_spec_from_dict",
    "load_linkage_spec",
]

_SPEC_TABLES: Mapping[str, tuple[tuple[str, str], ...]] = {
    "spec": (("name", "name"), ("description", "description"), ("config", "config")),
    "run": (("seed", "seed"), ("seconds", "seconds")),
    "clock": (("tolerance_ppm", "clock_tolerance_ppm"),
              ("max_phase_drift_ticks", "max_phase_drift_ticks")),
    "bus": (("max_utilisation_pct", "max_utilisation_pct"),),
    "queue": (("max_underrun_ticks", "max_underrun_ticks"),
              ("max_overrun_blocks", "max_overrun_blocks"),
              ("min_level_setpoints", "min_level_setpoints"),
              ("max_skipped_setpoints", "max_skipped_setpoints")),
    "contour": (("max_contour_error_counts", "max_contour_error_counts"),),
}  # fmt: skip
"""Spec table → (key in the file, field of :class:`LinkageSpec`)."""

_SPEC_WHERE = {fld: f"{t}.{k}" for t, pairs in _SPEC_TABLES.items() for k, fld in pairs}
_COUNT_LIMITS = {
    "max_underrun_ticks": "ticks",
    "max_overrun_blocks": "blocks",
    "min_level_setpoints": "setpoints",
    "max_skipped_setpoints": "setpoints",
}
_NUMBER_LIMITS = {
    "max_phase_drift_ticks": ("ticks", 1e6),
    "max_utilisation_pct": ("%", 100.0),
    "max_contour_error_counts": ("counts", 1e12),
}


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkageSpec:
    """What a linkage plan must keep (module docstring: the file; units in the names).

    Parameters
    ----------
    name : str
    description : str
    config : str or None
        The config name the spec is written for (checked if given).
    seed : int
        Encoder-noise seed of every run, 0 … 2**64 − 1.
    seconds : float or None
        Simulated time [s]; None: the path's duration plus ``settle_s``.
    clock_tolerance_ppm : float
        Each CPU also verified at its ``clock_ppm`` ± this [ppm]
        (:func:`~servotune.arch.linkage.clock_cases`).
    max_phase_drift_ticks : float or None
        Largest ``|tick time − index·T| / T`` of any CPU tick [ticks].
    max_utilisation_pct : float or None
        Largest bus utilisation (frame time / broadcast period) [%].
    max_underrun_ticks, max_overrun_blocks, max_skipped_setpoints : int or None
        Largest underruns [ticks], overruns [blocks], commands skipped at syncs [setpoints],
        per CPU.
    min_level_setpoints : int or None
        Smallest queue level before a pop [setpoints] (1: never empty).
    max_contour_error_counts : float or None
        Largest distance from the programmed path [counts].
    margins : MarginLimits or None
        Limits of each axis's PI loop; None: not checked.
    """

    name: str
    description: str = ""
    config: str | None = None
    seed: int = 0
    seconds: float | None = None
    clock_tolerance_ppm: float = 0.0
    max_phase_drift_ticks: float | None = None
    max_utilisation_pct: float | None = None
    max_underrun_ticks: int | None = None
    max_overrun_blocks: int | None = None
    min_level_setpoints: int | None = None
    max_skipped_setpoints: int | None = None
    max_contour_error_counts: float | None = None
    margins: MarginLimits | None = None

    def __post_init__(self) -> None:
        e = SpecError
        check_strings(
            {"name": self.name, "description": self.description},
            "spec",
            ("name", "description"),
            error=e,
        )
        if self.config is not None:
            check_strings({"config": self.config}, "spec", ("config",), error=e)
        check_seed(self.seed, "run.seed", error=e)
        if self.seconds is not None:
            check_number("run.seconds", self.seconds, "s", strict=True, hi=1e5, error=e)
        check_number(
            "clock.tolerance_ppm", self.clock_tolerance_ppm, "ppm", hi=MAX_CLOCK_PPM, error=e
        )
        for k, unit in _COUNT_LIMITS.items():
            if getattr(self, k) is not None:
                check_integer(_SPEC_WHERE[k], getattr(self, k), unit, hi=2**40, error=e)
        for k, (unit, hi) in _NUMBER_LIMITS.items():
            if getattr(self, k) is not None:
                check_number(_SPEC_WHERE[k], getattr(self, k), unit, hi=hi, error=e)
        if not self.limits and self.margins is None:
            keys = ", ".join(_SPEC_WHERE[k] for k in (*_COUNT_LIMITS, *_NUMBER_LIMITS))
            raise SpecError(f"the spec sets no limit; give at least one of {keys} or [margins]")

    @property
    def limits(self) -> dict[str, float | int]:
        """The limits set: field → value (units in the names)."""
        out = {}
        for k in (*_NUMBER_LIMITS, *_COUNT_LIMITS):
            if (v := getattr(self, k)) is not None:
                out[k] = v
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "margins"}
        d["margins"] = None if self.margins is None else self.margins.to_dict()
        return d


def linkage_spec_from_dict(data: Mapping[str, Any], default_name: str = "spec") -> LinkageSpec:
    """Build and validate a :class:`LinkageSpec` from a parsed spec file.

    Raises
    ------
    SpecError
        Naming the first unknown key or invalid value (with its unit).
    """
    check_keys(data, "", (), (*_SPEC_TABLES, "margins"), error=SpecError)
    kwargs: dict[str, Any] = {}
    for t, pairs in _SPEC_TABLES.items():
        table = check_table(data, t, error=SpecError, required=False)
        check_keys(table, t, (), [k for k, _ in pairs], error=SpecError)
        kwargs.update({fld: table[k] for k, fld in pairs if k in table})
    kwargs.setdefault("name", default_name)
    margins_t = check_table(data, "margins", error=SpecError, required=False)
    if "margins" in data:
        check_keys(
            margins_t, "margins", (), [f.name for f in fields(MarginLimits)], error=SpecError
        )
        try:
            kwargs["margins"] = MarginLimits(**margins_t)
        except SpecError as exc:
            raise SpecError(f"margins.{exc}") from None
    return LinkageSpec(**kwargs)


def linkage_spec_from_bytes(raw: bytes, src: str | Path) -> LinkageSpec:
    """Parse and check a linkage spec from the file's bytes (one line naming ``src``).

    Raises
    ------
    SpecError
    """
    stem = Path(src).name.removesuffix(".toml").removesuffix(".spec")
    return parse_toml_as(
        raw,
        str(src),
        SpecError,
        "linkage spec",
        lambda d: linkage_spec_from_dict(d, default_name=stem),
    )


def load_linkage_spec(path: str | Path) -> LinkageSpec:
    """Read and check a linkage spec file (TOML).

    Raises
    ------
    SpecError
        The file is missing, not TOML, or a field is invalid.
    """
    return linkage_spec_from_bytes(SourceFile.read(path, SpecError, "linkage spec").raw, path)
