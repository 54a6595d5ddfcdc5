"""What a fleet's fits say together: the spread of each parameter, the machines that stand out
against the fleet and the ones that drifted since their previous fit.

:func:`summarise_fleet` computes, per axis name:

**The fleet's spread** of each parameter over the latest fit of each machine
(:func:`~servotune.fleet.rows.latest_fits`: the latest ``date``; a machine's earlier fits would
count it twice): the median, the median absolute deviation ``MAD = median |x − median|``, the
robust standard deviation ``spread = MAD / 0.6745`` (= 1.4826 · MAD, consistent with the
standard deviation for normal data) and the 5 % and 95 % quantiles (``numpy.quantile``'s
default linear interpolation).

**Outliers against the fleet**: the modified z-score ``z = 0.6745 · (x − median) / MAD`` of
each machine's latest value; ``|z| > 3.5`` is an outlier (B. Iglewicz and D. C. Hoaglin, *How
to Detect and Handle Outliers*, ASQC Quality Press, 1993, §2.2: the score and its 3.5 cut-off).
Where more than half the machines share one value (``MAD = 0``: e.g. a term most fits left
out), the mean absolute deviation scaled by √(π/2) = 1.2533 (again consistent with the standard
deviation for normal data) stands in for ``MAD / 0.6745``; if that is 0 too, the parameter has
no spread and nothing is flagged on it.

**Drift against the machine's previous fit**: the latest fit of a machine and axis is compared
with its previous one: the fit of the same machine id and axis with the latest earlier date,
in this run or in a ``baseline`` table (an earlier ``--fleet`` output, ``--baseline``;
docs/decisions.md#12-fleet-drift). A parameter drifted when **both**

1. its 95 % intervals in the two fits do not overlap (the change is not estimation noise; a
   term a fit left out counts as fixed at 0, its interval ``[0, 0]``), **and**
2. the change is larger than ``k`` times the fleet's spread of that parameter,
   ``|x_now − x_before| > k · spread`` with ``k =`` :data:`DRIFT_K` ``= 2`` (the change is
   large against how much machines differ anyway: a change of two fleet standard deviations
   moves a median machine to the edge of the fleet).

The first condition alone would flag changes too small to matter on a long, quiet log; the
second alone would flag a noisy fit. A log without an ISO 8601 date is counted in the spread,
but not compared for drift (the summary says how many).

Flags need a fleet: with fewer than :data:`MIN_MACHINES` machines of an axis, no spread is
computed and nothing is flagged on that axis.

**Outliers by chance.** The 3.5 cut-off is calibrated for large samples: there a parameter that
spreads normally over the fleet puts a value beyond it with probability 2·(1 − Φ(3.5)) =
4.65e-4. A small fleet's median and MAD are themselves uncertain, so the same rule flags far
more often: 5.3 % of the values at 5 machines, 1.6 % at 10, 0.37 % at 30, 0.09 % at 150
(:func:`chance_outlier_rate`). The summary states how many outliers a fleet of its size would
show by chance alone (every parameter spread normally, no machine out of line) beside the
count it found, so three outliers among 24 machines' 144 values read as what they are.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from functools import lru_cache
from typing import Any

import numpy as np

from servotune.fleet.rows import FleetRow, dated, latest_fits, plain
from servotune.identify.model import ALL_PARAMS, UNITS

__all__ = [
    "DRIFT_K",
    "MAD_TO_SD",
    "MIN_MACHINES",
    "OUTLIER_Z",
    "Drift",
    "FleetSummary",
    "Outlier",
    "ParameterSpread",
    "chance_outlier_rate",
    "robust_spread",
    "robust_z",
    "summarise_fleet",
]

OUTLIER_Z = 3.5
"""Modified z-score beyond which a value is an outlier (Iglewicz & Hoaglin 1993) [-]."""

MAD_TO_SD = 0.6745
"""``Φ⁻¹(0.75)``: ``MAD / 0.6745`` estimates the standard deviation of normal data [-]."""

_MEANAD_TO_SD = math.sqrt(math.pi / 2)  # 1.2533: mean |x − median| → standard deviation

DRIFT_K = 2.0
"""A drift is larger than this many fleet spreads (:func:`robust_spread`) [-]."""

MIN_MACHINES = 5
"""Machines of an axis needed before its spread is computed and anything is flagged."""


def robust_spread(values: Sequence[float] | np.ndarray) -> tuple[float, float, float]:
    """Median, MAD and robust standard deviation of ``values`` (module docstring).

    Returns
    -------
    median : float
    mad : float
        ``median |x − median|``.
    spread : float
        ``MAD / 0.6745``; if MAD is 0, ``1.2533 · mean |x − median|``; 0 if that is 0 too.

    Examples
    --------
    >>> robust_spread([1.0, 2.0, 3.0, 4.0, 100.0])
    (3.0, 1.0, 1.4825796886582654)
    """
    x = np.asarray(values, dtype=float)
    med = float(np.median(x))
    dev = np.abs(x - med)
    mad = float(np.median(dev))
    spread = mad / MAD_TO_SD if mad > 0 else _MEANAD_TO_SD * float(np.mean(dev))
    return med, mad, spread


def robust_z(values: Sequence[float] | np.ndarray) -> np.ndarray:
    """Modified z-scores ``0.6745 · (x − median) / MAD`` (Iglewicz & Hoaglin 1993), with
    :func:`robust_spread`'s fallback when MAD is 0; NaN where there is no spread. A 2-D array:
    each row on its own.

    >>> robust_z([1.0, 2.0, 3.0, 4.0, 100.0]).round(2).tolist()
    [-1.35, -0.67, 0.0, 0.67, 65.43]
    """
    x = np.asarray(values, dtype=float)
    med = np.median(x, axis=-1, keepdims=True)
    dev = np.abs(x - med)
    mad = np.median(dev, axis=-1, keepdims=True)
    mean_dev = np.mean(dev, axis=-1, keepdims=True)
    spread = np.where(mad > 0, mad / MAD_TO_SD, _MEANAD_TO_SD * mean_dev)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(spread > 0, (x - med) / spread, np.nan)


CHANCE_VALUES = 2_000_000
"""Normal values :func:`chance_outlier_rate` draws per fleet size (about ±3 % at 300 machines,
where about 1,200 of them pass the cut-off)."""


@lru_cache(maxsize=256)
def chance_outlier_rate(n_machines: int, outlier_z: float = OUTLIER_Z) -> float:
    """The share of values that ``|robust z| > outlier_z`` flags in a fleet of ``n_machines``
    whose parameter spreads normally (no machine out of line): the outlier rule's false-flag
    rate at that fleet size.

    Estimated by simulation: :data:`CHANCE_VALUES` standard normal values in fleets of
    ``n_machines``, seeded by ``n_machines`` (the same figure on every run and machine). It
    tends to ``2·(1 − Φ(outlier_z))`` for large fleets (4.65e-4 at 3.5) and is much larger
    for small ones.

    Parameters
    ----------
    n_machines : int
        Machines with the parameter, >= 3.
    outlier_z : float
        The cut-off [-].

    Returns
    -------
    float
        The share [1].
    """
    if n_machines < 3:
        raise ValueError(f"n_machines must be >= 3, got {n_machines}")
    rng = np.random.default_rng([0x0F1EE7, n_machines])
    fleets = max(1, CHANCE_VALUES // n_machines)
    z = robust_z(rng.standard_normal((fleets, n_machines)))
    return float(np.mean(np.abs(z) > outlier_z))


@dataclass(frozen=True, slots=True, kw_only=True)
class ParameterSpread:
    """One parameter's spread over a fleet's machines (latest fit each).

    Attributes
    ----------
    axis, parameter, unit : str
    n_machines : int
    median, mad, spread : float
        :func:`robust_spread` [the parameter's unit].
    q05, q95 : float
        5 % and 95 % quantiles [the parameter's unit].
    """

    axis: str
    parameter: str
    unit: str
    n_machines: int
    median: float
    mad: float
    spread: float
    q05: float
    q95: float

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON."""
        return plain({f.name: getattr(self, f.name) for f in fields(self)})


@dataclass(frozen=True, slots=True, kw_only=True)
class Outlier:
    """A machine's latest value of a parameter far from the fleet's.

    Attributes
    ----------
    machine_id, axis, parameter, unit, file, date : str
    value : float
        The machine's value [unit].
    z : float
        Its modified z-score [-].
    median, spread : float
        The fleet's [unit].
    """

    machine_id: str
    axis: str
    parameter: str
    unit: str
    file: str
    date: str
    value: float
    z: float
    median: float
    spread: float

    def sentence(self) -> str:
        """The outlier in words."""
        return (
            f"{_who(self.machine_id, self.axis)}: {self.parameter} {_num(self.value)} "
            f"{self.unit} ({self.date or 'undated'}, {self.file}), robust z {self.z:+.1f} "
            f"(fleet median {_num(self.median)}, spread {_num(self.spread)} {self.unit})"
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON."""
        return plain({f.name: getattr(self, f.name) for f in fields(self)})


@dataclass(frozen=True, slots=True, kw_only=True)
class Drift:
    """A parameter of a machine that changed since its previous fit by more than the fleet's
    spread allows (module docstring).

    Attributes
    ----------
    machine_id, axis, parameter, unit : str
    before_file, before_date, after_file, after_date : str
        The previous and the latest fit.
    before_source : str
        ``"run"`` (this run's logs) or ``"baseline"`` (the ``baseline`` table).
    before, after : float
        The values [unit].
    before_ci95, after_ci95 : tuple of float
        Their 95 % intervals [unit].
    change : float
        ``after − before`` [unit].
    change_pct : float or None
        ``change / |before|`` [%] (None if ``before`` is 0).
    spread : float
        The fleet's spread of the parameter [unit].
    k : float
        ``|change| / spread`` [-] (above :data:`DRIFT_K`).
    """

    machine_id: str
    axis: str
    parameter: str
    unit: str
    before_file: str
    before_date: str
    before_source: str
    after_file: str
    after_date: str
    before: float
    after: float
    before_ci95: tuple[float, float]
    after_ci95: tuple[float, float]
    change: float
    change_pct: float | None
    spread: float
    k: float

    def sentence(self) -> str:
        """The drift in words."""
        verb = "rose" if self.change > 0 else "fell"
        pct = "" if self.change_pct is None else f" {abs(self.change_pct):.1f} %"
        was = " (baseline table)" if self.before_source == "baseline" else ""
        lo0, hi0 = self.before_ci95
        lo1, hi1 = self.after_ci95
        return (
            f"{_who(self.machine_id, self.axis)}: {self.parameter} {verb}{pct}, "
            f"{_num(self.before)} → {_num(self.after)} {self.unit} ({self.before_date}{was} → "
            f"{self.after_date}), {self.k:.1f}× the fleet's spread {_num(self.spread)} "
            f"{self.unit}; 95 % intervals {lo0:.6g} … {hi0:.6g} and {lo1:.6g} … {hi1:.6g} "
            "apart"
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON."""
        return plain({f.name: getattr(self, f.name) for f in fields(self)})


def _who(machine: str, axis: str) -> str:
    return f"machine {machine}" + (f" axis {axis}" if axis else "")


def _num(x: float) -> str:
    return f"{x:.4g}"


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetSummary:
    """What a fleet's fits say together (:func:`summarise_fleet`).

    Attributes
    ----------
    n_logs : int
        Distinct files in the run.
    n_rows, n_failed : int
        Rows (log × axis) and rows with an error.
    n_machines : int
        Distinct machine ids with at least one fit.
    n_inadequate : int
        Fitted rows whose residual tests did not all pass.
    n_undated : int
        Fitted rows without an ISO 8601 date (not compared for drift).
    n_baseline : int
        Rows of the baseline table (0 without one).
    spreads : tuple of ParameterSpread
        Per axis and parameter.
    outliers : tuple of Outlier
    drifts : tuple of Drift
    small_axes : tuple of str
        Axes with fewer than :data:`MIN_MACHINES` machines (nothing flagged on them).
    failures : tuple of tuple of str
        ``(file, axis, error)`` of each failed row.
    outlier_z, drift_k : float
        The thresholds used [-].
    chance_outliers : float
        Outliers a fleet of the same size would show by chance alone, every parameter spread
        normally: the sum over the parameters judged of machines × :func:`chance_outlier_rate`.
    judged_values : int
        Values judged for outliers (machines × parameters, every axis).
    """

    n_logs: int
    n_rows: int
    n_failed: int
    n_machines: int
    n_inadequate: int
    n_undated: int
    n_baseline: int
    spreads: tuple[ParameterSpread, ...]
    outliers: tuple[Outlier, ...]
    drifts: tuple[Drift, ...]
    small_axes: tuple[str, ...]
    failures: tuple[tuple[str, str, str], ...]
    outlier_z: float = OUTLIER_Z
    drift_k: float = DRIFT_K
    chance_outliers: float = 0.0
    judged_values: int = 0

    @property
    def drifted(self) -> dict[str, tuple[str, ...]]:
        """Machine id → the parameters that drifted (any axis), sorted."""
        out: dict[str, set[str]] = {}
        for d in self.drifts:
            out.setdefault(d.machine_id, set()).add(d.parameter)
        return {m: tuple(sorted(p)) for m, p in sorted(out.items())}

    @property
    def outlying(self) -> dict[str, tuple[str, ...]]:
        """Machine id → the parameters that are outliers against the fleet, sorted."""
        out: dict[str, set[str]] = {}
        for o in self.outliers:
            out.setdefault(o.machine_id, set()).add(o.parameter)
        return {m: tuple(sorted(p)) for m, p in sorted(out.items())}

    def text(self) -> str:
        """The summary in words (what ``servotune fit --fleet`` prints on stderr)."""
        lines = [
            f"fleet: {self.n_logs} logs, {self.n_rows} fits (log × axis) of {self.n_machines} "
            f"machines: {self.n_rows - self.n_failed} fitted ({self.n_inadequate} with a failed "
            f"residual test), {self.n_failed} failed"
            + (f"; baseline table: {self.n_baseline} rows" if self.n_baseline else "")
        ]
        for axis in sorted({s.axis for s in self.spreads}):
            rows = [s for s in self.spreads if s.axis == axis]
            lines.append(
                f"spread over {rows[0].n_machines} machines (latest fit each)"
                + (f", axis {axis}" if axis else "")
                + ": median, robust spread "
                "(MAD/0.6745), 5 % … 95 %"
            )
            lines += [
                f"  {s.parameter:18s} {_num(s.median):>11s} {_num(s.spread):>11s}   "
                f"{_num(s.q05)} … {_num(s.q95)} {s.unit}"
                for s in rows
            ]
        for axis in self.small_axes:
            lines.append(
                f"axis {axis or '(unprefixed)'}: fewer than {MIN_MACHINES} machines, "
                "no spread, nothing flagged"
            )
        lines.append(
            f"outliers against the fleet (|robust z| > {self.outlier_z:g}): "
            + (str(len(self.outliers)) if self.outliers else "none")
            + (
                f" of {self.judged_values} values; a fleet of this size would show "
                f"about {self.chance_outliers:.2g} by chance alone (every parameter "
                "spread normally)"
                if self.judged_values
                else ""
            )
        )
        lines += ["  " + o.sentence() for o in self.outliers]
        n_drift = len(self.drifted)
        lines.append(
            f"drift since each machine's previous fit (intervals apart and change > "
            f"{self.drift_k:g}× the fleet's spread): "
            + (f"{n_drift} machine{'s' if n_drift != 1 else ''}" if n_drift else "none")
        )
        lines += ["  " + d.sentence() for d in self.drifts]
        if self.n_undated:
            lines.append(
                f"{self.n_undated} fits without an ISO 8601 date (# date: YYYY-MM-DD): "
                "not compared for drift"
            )
        if self.failures:
            lines.append(f"failed ({len(self.failures)}; the table's error column):")
            lines += [f"  {f}{' axis ' + a if a else ''}: {e}" for f, a, e in self.failures[:10]]
            if len(self.failures) > 10:
                lines.append(f"  … and {len(self.failures) - 10} more")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON (every field; the nested results through their ``to_dict``)."""
        d: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("spreads", "outliers", "drifts"):
                v = [x.to_dict() for x in v]
            d[f.name] = v
        d["drifted"] = self.drifted
        d["outlying"] = self.outlying
        return plain(d)


@dataclass(frozen=True, slots=True)
class _FleetSpread:
    """The spread part of a summary: each parameter's spread, the outliers, the axes of too
    few machines, the spread by (axis, parameter) (drift is judged against it), the values
    judged and the outliers expected among them by chance."""

    spreads: list[ParameterSpread]
    outliers: list[Outlier]
    small_axes: list[str]
    spread_of: dict[tuple[str, str], float]
    judged_values: int
    chance_outliers: float


def _fleet_spread(latest: dict[tuple[str, str], FleetRow], outlier_z: float) -> _FleetSpread:
    """The fleet's spread of each parameter over each machine's latest fit, and the outliers
    against it (module docstring)."""
    spreads: list[ParameterSpread] = []
    outliers: list[Outlier] = []
    small: list[str] = []
    spread_of: dict[tuple[str, str], float] = {}
    judged, chance = 0, 0.0
    for axis in sorted({a for a, _ in latest}):
        machines = sorted((m, r) for (a, m), r in latest.items() if a == axis)
        if len(machines) < MIN_MACHINES:
            small.append(axis)
            continue
        for p in ALL_PARAMS:
            have = [(m, r) for m, r in machines if p in r.params]
            if len(have) < MIN_MACHINES:
                continue
            x = np.array([r.params[p] for _, r in have])
            med, mad, spread = robust_spread(x)
            q05, q95 = (float(q) for q in np.quantile(x, [0.05, 0.95]))
            spreads.append(
                ParameterSpread(
                    axis=axis,
                    parameter=p,
                    unit=UNITS[p],
                    n_machines=len(have),
                    median=med,
                    mad=mad,
                    spread=spread,
                    q05=q05,
                    q95=q95,
                )
            )
            spread_of[(axis, p)] = spread
            if spread <= 0:
                continue
            judged += len(have)
            chance += len(have) * chance_outlier_rate(len(have), outlier_z)
            outliers += _outliers(axis, p, have, x, med, spread, outlier_z)
    return _FleetSpread(
        spreads=spreads,
        outliers=outliers,
        small_axes=small,
        spread_of=spread_of,
        judged_values=judged,
        chance_outliers=chance,
    )


def _outliers(
    axis: str,
    p: str,
    have: list[tuple[str, FleetRow]],
    x: np.ndarray,
    med: float,
    spread: float,
    outlier_z: float,
) -> list[Outlier]:
    """The machines (``have``: machine id and latest fit; ``x`` their values of ``p``) whose
    robust z-score against the fleet's median and spread is beyond ``outlier_z``."""
    out = []
    for (m, r), z in zip(have, (x - med) / spread, strict=True):
        if abs(z) > outlier_z:
            out.append(
                Outlier(
                    machine_id=m,
                    axis=axis,
                    parameter=p,
                    unit=UNITS[p],
                    file=r.file,
                    date=r.date,
                    value=r.params[p],
                    z=float(z),
                    median=med,
                    spread=spread,
                )
            )
    return out


def _drifts(
    rows: Sequence[FleetRow],
    fitted: list[FleetRow],
    baseline: Sequence[FleetRow],
    latest: dict[tuple[str, str], FleetRow],
    fleet: _FleetSpread,
    drift_k: float,
) -> list[Drift]:
    """Each machine's drift since its previous fit, in this run or the baseline (a baseline
    row of a file also in ``rows`` is skipped), on the axes with a fleet spread."""
    in_run = {r.sha256 for r in rows if r.sha256}
    earlier = [(r, "run") for r in fitted] + [
        (r, "baseline") for r in baseline if r.ok and r.sha256 not in in_run
    ]
    drifts = []
    for (axis, machine), now in sorted(latest.items()):
        if axis in fleet.small_axes or not dated(now):
            continue
        before_all = [
            (r, src)
            for r, src in earlier
            if r.axis == axis and r.machine_id == machine and dated(r) and r.date < now.date
        ]
        if not before_all:
            continue
        prev, src = max(before_all, key=lambda t: (t[0].date, t[1] == "run", t[0].file))
        for p in ALL_PARAMS:
            spread = fleet.spread_of.get((axis, p), 0.0)
            drift = _drift(machine, axis, p, prev, src, now, spread, drift_k)
            if drift is not None:
                drifts.append(drift)
    return drifts


def _drift(
    machine: str,
    axis: str,
    p: str,
    prev: FleetRow,
    src: str,
    now: FleetRow,
    spread: float,
    drift_k: float,
) -> Drift | None:
    """The drift of ``p`` from ``prev`` (from ``src``: ``run`` or ``baseline``) to ``now``:
    their 95 % intervals apart and the change beyond ``drift_k`` fleet spreads; else None."""
    i0, i1 = prev.interval(p), now.interval(p)
    if spread <= 0 or i0 is None or i1 is None:
        return None
    change = now.params[p] - prev.params[p]
    apart = i0[1] < i1[0] or i1[1] < i0[0]
    if not (apart and abs(change) > drift_k * spread):
        return None
    b = prev.params[p]
    return Drift(
        machine_id=machine,
        axis=axis,
        parameter=p,
        unit=UNITS[p],
        before_file=prev.file,
        before_date=prev.date,
        before_source=src,
        after_file=now.file,
        after_date=now.date,
        before=b,
        after=now.params[p],
        before_ci95=i0,
        after_ci95=i1,
        change=change,
        change_pct=None if b == 0 else 100.0 * change / abs(b),
        spread=spread,
        k=abs(change) / spread,
    )


def summarise_fleet(
    rows: Sequence[FleetRow],
    *,
    baseline: Sequence[FleetRow] = (),
    outlier_z: float = OUTLIER_Z,
    drift_k: float = DRIFT_K,
) -> FleetSummary:
    """The fleet's spread, its outliers and its drifted machines (module docstring).

    Parameters
    ----------
    rows : sequence of FleetRow
        This run's rows.
    baseline : sequence of FleetRow
        An earlier fleet table's rows (:func:`read_fleet_table`): previous fits for drift only
        (a baseline row of a file also in ``rows``, same SHA-256, is the same fit: skipped).
    outlier_z : float
        Modified z-score beyond which a value is an outlier [-].
    drift_k : float
        Fleet spreads a drift must exceed [-].

    Returns
    -------
    FleetSummary
    """
    fitted = [r for r in rows if r.ok]
    latest = latest_fits(fitted)
    fleet = _fleet_spread(latest, outlier_z)
    drifts = _drifts(rows, fitted, baseline, latest, fleet, drift_k)
    return FleetSummary(
        n_logs=len({r.file for r in rows}),
        n_rows=len(rows),
        n_failed=len(rows) - len(fitted),
        n_machines=len({r.machine_id for r in fitted}),
        n_inadequate=sum(1 for r in fitted if r.adequate is False),
        n_undated=sum(1 for r in fitted if not dated(r)),
        n_baseline=len(baseline),
        spreads=tuple(fleet.spreads),
        outliers=tuple(fleet.outliers),
        drifts=tuple(drifts),
        small_axes=tuple(fleet.small_axes),
        failures=tuple((r.file, r.axis, r.error) for r in rows if not r.ok),
        outlier_z=outlier_z,
        drift_k=drift_k,
        chance_outliers=fleet.chance_outliers,
        judged_values=fleet.judged_values,
    )
