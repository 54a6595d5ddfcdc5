"""Fleet fits: the logs of many machines identified at once, their spread, the machines that
stand out against the fleet and the ones that drifted since their previous fit (issue 22).

``servotune fit logs/*.csv --fleet out.parquet`` runs :func:`fit_fleet`: every log (every axis
of it, or one named axis) is fitted by :func:`servotune.identify.fit_log` as one task of an
:class:`~servotune.executor.Executor` (in-process, or a Dask cluster), one
:class:`FleetRow` per log and axis. A log that cannot be read or fitted is a row with its error
message: it never stops the run. :func:`summarise_fleet` then computes, per axis name:

**The fleet's spread** of each parameter over the latest fit of each machine (the latest
``date``; a machine's earlier fits would count it twice): the median, the median absolute
deviation ``MAD = median |x − median|``, the robust standard deviation ``spread = MAD / 0.6745``
(= 1.4826 · MAD, consistent with the standard deviation for normal data) and the 5 % and 95 %
quantiles (``numpy.quantile``'s default linear interpolation).

**Outliers against the fleet**: the modified z-score ``z = 0.6745 · (x − median) / MAD`` of
each machine's latest value; ``|z| > 3.5`` is an outlier (B. Iglewicz and D. C. Hoaglin, *How
to Detect and Handle Outliers*, ASQC Quality Press, 1993, §2.2: the score and its 3.5 cut-off).
Where more than half the machines share one value (``MAD = 0``: e.g. a term most fits left
out), the mean absolute deviation scaled by √(π/2) = 1.2533 (again consistent with the standard
deviation for normal data) stands in for ``MAD / 0.6745``; if that is 0 too, the parameter has
no spread and nothing is flagged on it.

**Drift against the machine's previous fit**: the latest fit of a machine and axis is compared
with its previous one: the fit of the same machine id and axis with the latest earlier date,
in this run or in a ``baseline`` table (an earlier ``--fleet`` output, ``--baseline``; DECISIONS
12). A parameter drifted when **both**

1. its 95 % intervals in the two fits do not overlap (the change is not estimation noise; a
   term a fit left out counts as fixed at 0, its interval ``[0, 0]``), **and**
2. the change is larger than ``k`` times the fleet's spread of that parameter,
   ``|x_now − x_before| > k · spread`` with ``k =`` :data:`DRIFT_K` ``= 2`` (the change is
   large against how much machines differ anyway: a change of two fleet standard deviations
   moves a median machine to the edge of the fleet).

The first condition alone would flag changes too small to matter on a long, quiet log; the
second alone would flag a noisy fit. Dates are compared as text, so they must be ISO 8601
(``2025-03-01``, optionally with a time); a log without such a date is fitted and counted in
the spread, but not compared for drift (the summary says how many).

Flags need a fleet: with fewer than :data:`MIN_MACHINES` machines of an axis, no spread is
computed and nothing is flagged on that axis.

**Machine and date**: the machine id is the log's ``# machine_id:`` metadata line (DECISIONS
1), else the file name's stem before its last ``_`` (``m017_2025-03-01.csv`` → ``m017``; a stem
without ``_`` is the id). The date is the ``# date:`` line, else the stem's part after its last
``_`` if that is an ISO date. (Not ``-``: dates hold it.) A HAL capture has no metadata: its
file name gives both.

The rows are sorted by (machine id, date, file, axis), every number is a fit's own, and no
wall-clock time is written: the same logs and options give the same table bytes, on any
executor (each fit is a pure function of its file).
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from servotune._version import __version__
from servotune.digest import bytes_sha256
from servotune.errors import ServotuneError
from servotune.executor import Executor, InProcessExecutor
from servotune.identify import fit_log
from servotune.identify.model import ALL_PARAMS, UNITS
from servotune.identify.result import FitResult
from servotune.io.fleet_table import (
    FLEET_SCHEMA,
    fleet_table_bytes,
    read_fleet_records,
    table_format,
    write_fleet_records,
)
from servotune.io.hal import HalSettings
from servotune.logs import read_log, read_metadata
from servotune.rig import Rig

if TYPE_CHECKING:
    import matplotlib.figure

__all__ = [
    "DRIFT_K",
    "FLEET_CLUSTER_MIN_LOGS",
    "FLEET_SCHEMA",
    "MAD_TO_SD",
    "MIN_MACHINES",
    "OUTLIER_Z",
    "Drift",
    "FleetFitOptions",
    "FleetResult",
    "FleetRow",
    "FleetSummary",
    "Outlier",
    "ParameterSpread",
    "fit_fleet",
    "fit_fleet_log",
    "machine_and_date",
    "read_fleet_table",
    "robust_spread",
    "robust_z",
    "summarise_fleet",
    "write_fleet_table",
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

FLEET_CLUSTER_MIN_LOGS = 200
"""Logs from which ``servotune fit --fleet`` starts an embedded Dask ``LocalCluster`` on this
machine's cores (``--workers``/``--scheduler`` choose otherwise). A fit of an 8 s log (2,000
ticks) takes about 0.1 s of one core; starting a 2-worker cluster and loading the compiled
kernels in each worker costs about 3–5 s, and 2 workers fit about 1.6 times as many logs per
second as one process, so the cluster pays back from about 150 such logs on 2 cores
(``docs/scale.md``, "Fleet fits")."""

_ISO_DATE = re.compile(r"^\d{4}-\d{2}-\d{2}")
_MAX_MESSAGE = 600


# --- rows ------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetFitOptions:
    """How each log of a fleet is fitted: :func:`servotune.identify.fit_log`'s options, the
    same for every log.

    Attributes
    ----------
    axis : str or None
        The axis to fit in every log; None: every axis of each log.
    rig : Rig or None
        Fallbacks for settings a log does not state (D/A, counter, period, compute time).
    structure, method, friction, invert_encoder, strict, hal
        As :func:`~servotune.identify.fit_log`'s.
    counter_bits, dac_bits : int or None
    dac_range_v : tuple of float or None
        D/A range [V].
    period_s, compute_s : float or None
        Sample period and compute time [s].
    """

    axis: str | None = None
    rig: Rig | None = None
    structure: str | None = None
    counter_bits: int | None = None
    dac_bits: int | None = None
    dac_range_v: tuple[float, float] | None = None
    period_s: float | None = None
    compute_s: float | None = None
    method: str = "auto"
    friction: str = "auto"
    invert_encoder: bool = False
    strict: bool = False
    hal: HalSettings | None = None

    def fit_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :func:`~servotune.identify.fit_log` (all but ``axis``)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "axis"}


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetRow:
    """One log and axis of a fleet: where it comes from and what its fit found.

    Every number is a fitted result (:class:`~servotune.identify.FitResult`).

    Attributes
    ----------
    machine_id, date : str
        From the log's metadata or its file name (module docstring); ``date`` may be ``""``.
    file : str
        The log's file name (without its directory).
    axis : str
        The axis fitted (``""``: the log's one unprefixed axis).
    sha256 : str
        SHA-256 of the log's bytes (hex); ``""`` if it could not be read.
    error : str
        Why the log could not be read or fitted (one line); ``""`` for a fit.
    method, structure, friction : str
        The fit's method (``iv``/``oe``), estimated parameters joined by ``+``, friction form.
    adequate : bool or None
        Every residual test passed (None: no fit).
    failed_tests : str
        The residual tests that failed, ``"; "``-joined (``whiteness``,
        ``cross-correlation with exc_code`` …).
    velocity_fit_pct, position_fit_pct : float or None
        Fit % (MATLAB ``compare``) of the whole-log model on the whole log [%].
    velocity_fit_cv_pct, position_fit_cv_pct : float or None
        The same, split-half cross-validated [%] (None if a half could not be fitted).
    params : dict
        Every parameter of :data:`~servotune.identify.model.ALL_PARAMS` present in the fit
        (0 for a term left out; the ``*_neg`` ones only for the asymmetric friction form)
        [units in the names].
    ci95 : dict
        95 % interval of each *estimated* parameter (a term left out has none).
    n_samples : int or None
    period_s : float or None
        Sample period of the log [s].
    outliers, drift : tuple of str
        Parameters flagged on this row by :func:`summarise_fleet` (outlier against the fleet;
        drifted since the machine's previous fit).
    warnings : str
        The warnings the fit raised, ``" | "``-joined (one line).
    """

    machine_id: str
    date: str
    file: str
    axis: str
    sha256: str = ""
    error: str = ""
    method: str = ""
    structure: str = ""
    friction: str = ""
    adequate: bool | None = None
    failed_tests: str = ""
    velocity_fit_pct: float | None = None
    velocity_fit_cv_pct: float | None = None
    position_fit_pct: float | None = None
    position_fit_cv_pct: float | None = None
    params: dict[str, float] = field(default_factory=dict)
    ci95: dict[str, tuple[float, float]] = field(default_factory=dict)
    n_samples: int | None = None
    period_s: float | None = None
    outliers: tuple[str, ...] = ()
    drift: tuple[str, ...] = ()
    warnings: str = ""

    @property
    def ok(self) -> bool:
        """The log was fitted (no error)."""
        return not self.error

    @property
    def key(self) -> tuple[str, str, str, str]:
        """The table's sort key: (machine id, date, file, axis)."""
        return (self.machine_id, self.date, self.file, self.axis)

    def interval(self, p: str) -> tuple[float, float] | None:
        """The 95 % interval of parameter ``p``; ``(0, 0)`` for a term the fit left out
        (fixed at 0), None if the fit has no such parameter."""
        if p in self.ci95:
            return self.ci95[p]
        if p in self.params:
            v = self.params[p]
            return (v, v)
        return None

    def to_record(self) -> dict[str, Any]:
        """The row as a record of the fleet table (:data:`servotune.io.fleet_table.COLUMNS`)."""
        rec: dict[str, Any] = {
            "machine_id": self.machine_id, "date": self.date, "file": self.file,
            "axis": self.axis, "sha256": self.sha256, "status": "error" if self.error else "ok",
            "error": self.error, "method": self.method, "structure": self.structure,
            "friction": self.friction, "adequate": self.adequate,
            "failed_tests": self.failed_tests, "velocity_fit_pct": self.velocity_fit_pct,
            "velocity_fit_cv_pct": self.velocity_fit_cv_pct,
            "position_fit_pct": self.position_fit_pct,
            "position_fit_cv_pct": self.position_fit_cv_pct,
        }  # fmt: skip
        for p in ALL_PARAMS:
            lo, hi = self.ci95.get(p, (None, None))
            rec[p], rec[f"{p}_lo"], rec[f"{p}_hi"] = self.params.get(p), lo, hi
        rec.update(n_samples=self.n_samples, period_s=self.period_s,
                   outliers=",".join(self.outliers), drift=",".join(self.drift),
                   warnings=self.warnings)  # fmt: skip
        return rec

    @classmethod
    def from_record(cls, rec: Mapping[str, Any]) -> FleetRow:
        """A row from a fleet table's record (:meth:`to_record`'s inverse)."""
        params = {p: float(rec[p]) for p in ALL_PARAMS if rec.get(p) is not None}
        ci95 = {p: (float(rec[f"{p}_lo"]), float(rec[f"{p}_hi"])) for p in ALL_PARAMS
                if rec.get(f"{p}_lo") is not None and rec.get(f"{p}_hi") is not None}  # fmt: skip
        return cls(
            machine_id=rec["machine_id"], date=rec["date"], file=rec["file"], axis=rec["axis"],
            sha256=rec["sha256"], error=rec["error"], method=rec["method"],
            structure=rec["structure"], friction=rec["friction"], adequate=rec["adequate"],
            failed_tests=rec["failed_tests"], velocity_fit_pct=rec["velocity_fit_pct"],
            velocity_fit_cv_pct=rec["velocity_fit_cv_pct"],
            position_fit_pct=rec["position_fit_pct"],
            position_fit_cv_pct=rec["position_fit_cv_pct"], params=params, ci95=ci95,
            n_samples=rec["n_samples"], period_s=rec["period_s"],
            outliers=_split(rec["outliers"]), drift=_split(rec["drift"]),
            warnings=rec["warnings"],
        )  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON (every field; intervals as lists, non-finite floats as None)."""
        return _plain({f.name: getattr(self, f.name) for f in fields(self)})


def _split(text: str) -> tuple[str, ...]:
    return tuple(t for t in text.split(",") if t)


def _one_line(text: object, name: str, path: str) -> str:
    """A message as one line of at most 600 characters, naming the file by ``name``."""
    line = " ".join(str(text).replace(path, name).split())
    return line if len(line) <= _MAX_MESSAGE else line[: _MAX_MESSAGE - 1] + "…"


def machine_and_date(path: str | Path, metadata: Mapping[str, str]) -> tuple[str, str]:
    """The machine id and date of a log (module docstring: metadata, else the file name).

    >>> machine_and_date("logs/m017_2025-03-01.csv", {})
    ('m017', '2025-03-01')
    >>> machine_and_date("gantry-7.csv", {"machine_id": "G7", "date": "2024-11-30"})
    ('G7', '2024-11-30')
    """
    stem = Path(path).stem
    head, sep, tail = stem.rpartition("_")
    machine = metadata.get("machine_id", "").strip() or (head if sep and head else stem)
    date = metadata.get("date", "").strip()
    if not date and sep and head and _ISO_DATE.match(tail):
        date = tail
    return machine, date


def _failed_tests(r: FitResult) -> str:
    failed = [] if r.whiteness.get("white", True) else ["whiteness"]
    failed += [f"cross-correlation with {c['input']}" for c in r.cross_correlation
               if not c.get("uncorrelated", True)]  # fmt: skip
    return "; ".join(failed)


def _pct(x: Any) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def _fit_row(base: FleetRow, r: FitResult, caught: str) -> FleetRow:
    f = r.fit_pct
    return replace(
        base,
        method=r.method,
        structure="+".join(r.structure),
        friction=r.friction,
        adequate=bool(r.adequate),
        failed_tests=_failed_tests(r),
        velocity_fit_pct=_pct(f["velocity"]["estimation"]),
        velocity_fit_cv_pct=_pct(f["velocity"]["validation"]),
        position_fit_pct=_pct(f["position"]["estimation"]),
        position_fit_cv_pct=_pct(f["position"]["validation"]),
        params={p: float(r.params[p]) for p in ALL_PARAMS if p in r.params},
        ci95={p: (float(lo), float(hi)) for p, (lo, hi) in r.ci95.items()},
        n_samples=int(r.n_samples),
        period_s=float(r.period_s),
        warnings=caught,
    )


def fit_fleet_log(path: str | Path, options: FleetFitOptions | None = None) -> tuple[FleetRow, ...]:
    """Fit one log of a fleet: one row per axis (``options.axis``, or every axis of the log).

    A log that cannot be read, or an axis that cannot be fitted, gives a row with its error
    (:attr:`FleetRow.error`, one line naming the file by its name) instead of raising; the
    warnings a fit raises are kept in its row, not shown. (A task of :func:`fit_fleet`: a
    module-level function, so a Dask worker can run it.)

    Returns
    -------
    tuple of FleetRow
        Sorted by axis.
    """
    opts = FleetFitOptions() if options is None else options
    src, name = str(path), Path(path).name
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        machine, date = machine_and_date(path, {})
        why = exc.strerror or str(exc)
        return (FleetRow(machine_id=machine, date=date, file=name, axis=opts.axis or "",
                         error=f"cannot read {name!r}: {why}"),)  # fmt: skip
    sha = bytes_sha256(raw)
    meta: dict[str, str] = {}
    if opts.hal is None:
        try:
            meta = read_metadata(path)
        except (ServotuneError, OSError):
            meta = {}  # the fit below names the problem
    machine, date = machine_and_date(path, meta)
    base = FleetRow(machine_id=machine, date=date, file=name, axis=opts.axis or "", sha256=sha)
    try:
        axes = _axes(path, opts)
    except Exception as exc:  # a log that cannot be read is a row, never the end of the run
        return (replace(base, error=_error(exc, name, src)),)
    rows = []
    for ax in axes:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                result, _, _ = fit_log(path, axis=ax, **opts.fit_kwargs())
            except Exception as exc:  # any failure of one fit is its row's error
                rows.append(replace(base, axis=ax or "", error=_error(exc, name, src)))
                continue
        said = " | ".join(dict.fromkeys(_one_line(f"{w.category.__name__}: {w.message}", name,
                                                  src) for w in caught))  # fmt: skip
        rows.append(_fit_row(replace(base, axis=ax or ""), result, _one_line(said, name, src)))
    return tuple(sorted(rows, key=lambda r: r.axis))


def _fit_task(path: str, shared: FleetFitOptions) -> tuple[FleetRow, ...]:
    """:func:`fit_fleet_log` as an executor task (a Dask executor passes ``shared`` by name)."""
    return fit_fleet_log(path, shared)


def _axes(path: str | Path, opts: FleetFitOptions) -> list[str | None]:
    """The axes to fit in a log: the named one, else every axis the log has (a HAL capture,
    or a log without axis prefixes: its one axis, None)."""
    if opts.axis is not None:
        return [opts.axis]
    if opts.hal is not None:
        return [None]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the fit reports the log's warnings in its row
        settings = ("counter_bits", "dac_bits", "dac_range_v", "period_s", "compute_s")
        kw = {k: v for k, v in opts.fit_kwargs().items() if k in settings}
        log = read_log(path, **kw)
    names = list(log.axes)
    return [None] if names == [""] else names


def _error(exc: BaseException, name: str, src: str) -> str:
    text = str(exc) if isinstance(exc, ServotuneError) else f"{type(exc).__name__}: {exc}"
    if isinstance(exc, OSError) and not isinstance(exc, ServotuneError) and exc.strerror:
        text = f"cannot read {name!r}: {exc.strerror}"
    return _one_line(text or type(exc).__name__, name, src)


# --- the fleet's statistics ------------------------------------------------------------------


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
    :func:`robust_spread`'s fallback when MAD is 0; NaN where there is no spread.

    >>> robust_z([1.0, 2.0, 3.0, 4.0, 100.0]).round(2).tolist()
    [-1.35, -0.67, 0.0, 0.67, 65.43]
    """
    x = np.asarray(values, dtype=float)
    med, _, spread = robust_spread(x)
    if spread <= 0:
        return np.full(x.shape, np.nan)
    return (x - med) / spread


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
        return _plain({f.name: getattr(self, f.name) for f in fields(self)})


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
        return _plain({f.name: getattr(self, f.name) for f in fields(self)})


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
        return _plain({f.name: getattr(self, f.name) for f in fields(self)})


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
            lines.append(f"spread over {rows[0].n_machines} machines (latest fit each)"
                         + (f", axis {axis}" if axis else "") + ": median, robust spread "
                         "(MAD/0.6745), 5 % … 95 %")  # fmt: skip
            lines += [f"  {s.parameter:18s} {_num(s.median):>11s} {_num(s.spread):>11s}   "
                      f"{_num(s.q05)} … {_num(s.q95)} {s.unit}" for s in rows]  # fmt: skip
        for axis in self.small_axes:
            lines.append(f"axis {axis or '(unprefixed)'}: fewer than {MIN_MACHINES} machines, "
                         "no spread, nothing flagged")  # fmt: skip
        lines.append(f"outliers against the fleet (|robust z| > {self.outlier_z:g}): "
                     + (str(len(self.outliers)) if self.outliers else "none"))  # fmt: skip
        lines += ["  " + o.sentence() for o in self.outliers]
        n_drift = len(self.drifted)
        lines.append(
            f"drift since each machine's previous fit (intervals apart and change > "
            f"{self.drift_k:g}× the fleet's spread): "
            + (f"{n_drift} machine{'s' if n_drift != 1 else ''}" if n_drift else "none")
        )
        lines += ["  " + d.sentence() for d in self.drifts]
        if self.n_undated:
            lines.append(f"{self.n_undated} fits without an ISO 8601 date (# date: YYYY-MM-DD): "
                         "not compared for drift")  # fmt: skip
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
        return _plain(d)


def _dated(row: FleetRow) -> bool:
    return bool(_ISO_DATE.match(row.date))


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
    latest: dict[tuple[str, str], FleetRow] = {}
    for r in sorted(fitted, key=lambda r: (r.date if _dated(r) else "", r.file)):
        latest[(r.axis, r.machine_id)] = r
    spreads, outliers, drifts, small = [], [], [], []
    spread_of: dict[tuple[str, str], float] = {}
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
            spreads.append(ParameterSpread(axis=axis, parameter=p, unit=UNITS[p],
                                           n_machines=len(have), median=med, mad=mad,
                                           spread=spread, q05=q05, q95=q95))  # fmt: skip
            spread_of[(axis, p)] = spread
            if spread <= 0:
                continue
            for (m, r), z in zip(have, (x - med) / spread, strict=True):
                if abs(z) > outlier_z:
                    outliers.append(Outlier(machine_id=m, axis=axis, parameter=p, unit=UNITS[p],
                                            file=r.file, date=r.date, value=r.params[p],
                                            z=float(z), median=med, spread=spread))  # fmt: skip
    in_run = {r.sha256 for r in rows if r.sha256}
    earlier = [(r, "run") for r in fitted] + [
        (r, "baseline") for r in baseline if r.ok and r.sha256 not in in_run
    ]
    for (axis, machine), now in sorted(latest.items()):
        if axis in small or not _dated(now):
            continue
        before_all = [(r, src) for r, src in earlier if r.axis == axis and
                      r.machine_id == machine and _dated(r) and r.date < now.date]  # fmt: skip
        if not before_all:
            continue
        prev, src = max(before_all, key=lambda t: (t[0].date, t[1] == "run", t[0].file))
        for p in ALL_PARAMS:
            spread = spread_of.get((axis, p), 0.0)
            i0, i1 = prev.interval(p), now.interval(p)
            if spread <= 0 or i0 is None or i1 is None:
                continue
            change = now.params[p] - prev.params[p]
            apart = i0[1] < i1[0] or i1[1] < i0[0]
            if apart and abs(change) > drift_k * spread:
                b = prev.params[p]
                drifts.append(Drift(
                    machine_id=machine, axis=axis, parameter=p, unit=UNITS[p],
                    before_file=prev.file, before_date=prev.date, before_source=src,
                    after_file=now.file, after_date=now.date, before=b, after=now.params[p],
                    before_ci95=i0, after_ci95=i1, change=change,
                    change_pct=None if b == 0 else 100.0 * change / abs(b), spread=spread,
                    k=abs(change) / spread,
                ))  # fmt: skip
    return FleetSummary(
        n_logs=len({r.file for r in rows}),
        n_rows=len(rows),
        n_failed=len(rows) - len(fitted),
        n_machines=len({r.machine_id for r in fitted}),
        n_inadequate=sum(1 for r in fitted if r.adequate is False),
        n_undated=sum(1 for r in fitted if not _dated(r)),
        n_baseline=len(baseline),
        spreads=tuple(spreads),
        outliers=tuple(outliers),
        drifts=tuple(drifts),
        small_axes=tuple(small),
        failures=tuple((r.file, r.axis, r.error) for r in rows if not r.ok),
        outlier_z=outlier_z,
        drift_k=drift_k,
    )


# --- the run ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class FleetResult:
    """A fleet fit: its rows and what they say together.

    Attributes
    ----------
    rows : tuple of FleetRow
        One per log and axis, sorted by (machine id, date, file, axis), with the flags of
        :attr:`summary` set.
    summary : FleetSummary
    executor : str
        Where the fits ran (provenance: not written into the table).
    """

    rows: tuple[FleetRow, ...]
    summary: FleetSummary
    executor: str = "in-process"

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON: the summary and the rows, with the schema and version."""
        return {
            "schema": FLEET_SCHEMA,
            "version": __version__,
            "summary": self.summary.to_dict(),
            "rows": [r.to_dict() for r in self.rows],
        }

    def records(self) -> list[dict[str, Any]]:
        """The fleet table's records, in row order."""
        return [r.to_record() for r in self.rows]

    def table_bytes(self, fmt: str) -> bytes:
        """The fleet table as the bytes of a ``"parquet"`` or ``"csv"`` file."""
        return fleet_table_bytes(self.records(), fmt)

    def plot(self) -> matplotlib.figure.Figure:
        """Histograms of every parameter over the fleet (:func:`servotune.plot.plot_fleet`)."""
        from servotune.plot import plot_fleet  # matplotlib only when a figure is drawn

        return plot_fleet(self)


def fit_fleet(
    paths: Iterable[str | Path],
    *,
    axis: str | None = None,
    options: FleetFitOptions | None = None,
    executor: Executor | None = None,
    baseline: Sequence[FleetRow] | str | Path | None = None,
    progress: Callable[[str], None] | None = None,
    outlier_z: float = OUTLIER_Z,
    drift_k: float = DRIFT_K,
) -> FleetResult:
    """Fit every log of a fleet and summarise it (module docstring).

    Parameters
    ----------
    paths : iterable of str or Path
        The logs (duplicates are fitted once).
    axis : str, optional
        The axis to fit in every log (overrides ``options.axis``); default: every axis.
    options : FleetFitOptions, optional
        How each log is fitted.
    executor : Executor, optional
        Where the fits run (:func:`servotune.executor.open_executor`); default in-process.
    baseline : sequence of FleetRow, or a fleet table's path, optional
        Earlier fits, for drift (``--baseline``).
    progress : callable, optional
        Called with progress lines (``"fit fleet: 12/300 logs"``).
    outlier_z, drift_k : float
        :func:`summarise_fleet`'s thresholds.

    Returns
    -------
    FleetResult

    Raises
    ------
    FleetTableError
        If ``baseline`` is a file that is not a fleet table.
    """
    opts = FleetFitOptions() if options is None else options
    if axis is not None:
        opts = replace(opts, axis=axis)
    base = read_fleet_table(baseline) if isinstance(baseline, str | Path) else tuple(baseline or ())
    items = list(dict.fromkeys(str(p) for p in paths))
    ex = InProcessExecutor() if executor is None else executor
    say = progress or (lambda _m: None)
    say(f"fit fleet: {len(items)} logs on {ex.name}")
    parts = ex.map(_fit_task, items, shared=opts,
                   done=lambda k: say(f"fit fleet: {k}/{len(items)} logs"))  # fmt: skip
    rows = sorted((r for part in parts for r in part), key=lambda r: r.key)
    summary = summarise_fleet(rows, baseline=base, outlier_z=outlier_z, drift_k=drift_k)
    return FleetResult(rows=tuple(_flag(rows, summary)), summary=summary, executor=ex.name)


def _flag(rows: Sequence[FleetRow], s: FleetSummary) -> list[FleetRow]:
    """``rows`` with the parameters each is flagged for (outlier, drift) set."""
    out_of: dict[tuple[str, str, str], list[str]] = {}
    for o in s.outliers:
        out_of.setdefault((o.file, o.axis, o.machine_id), []).append(o.parameter)
    drift_of: dict[tuple[str, str, str], list[str]] = {}
    for d in s.drifts:
        drift_of.setdefault((d.after_file, d.axis, d.machine_id), []).append(d.parameter)
    return [replace(r, outliers=tuple(out_of.get((r.file, r.axis, r.machine_id), ())),
                    drift=tuple(drift_of.get((r.file, r.axis, r.machine_id), ())))
            for r in rows]  # fmt: skip


def write_fleet_table(result: FleetResult | Sequence[FleetRow], path: str | Path) -> None:
    """Write the fleet table atomically, Parquet or CSV by the file's suffix
    (:mod:`servotune.io.fleet_table`).

    Raises
    ------
    FleetTableError
        If the suffix is neither ``.parquet`` nor ``.csv``.
    OSError
        If the file cannot be written (nothing is left behind).
    """
    rows = result.rows if isinstance(result, FleetResult) else result
    table_format(path)
    write_fleet_records([r.to_record() for r in rows], path)


def read_fleet_table(path: str | Path) -> tuple[FleetRow, ...]:
    """The rows of a fleet table (either form).

    Raises
    ------
    FleetTableError
        If the file cannot be read or is not a fleet table of this schema.
    """
    return tuple(FleetRow.from_record(rec) for rec in read_fleet_records(path))


def _plain(x: Any) -> Any:
    """JSON-safe: tuples as lists, non-finite floats as None."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, Mapping):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    return x
