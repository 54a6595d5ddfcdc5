"""One log and axis of a fleet: its row, how it is fitted, and the rows as a table.

:func:`fit_fleet_log` fits one log (every axis of it, or one named axis) by
:func:`servotune.identify.fit_log` into one :class:`FleetRow` per axis. A log that cannot be
read or fitted is a row with its error message: it never stops a fleet's run.

**Machine and date**: the machine id is the log's ``# machine_id:`` metadata line
(docs/formats.md#metadata), else the file name's stem before its last ``_`` (``m017_2025-03-01.csv``
→ ``m017``; a stem without ``_`` is the id). The date is the ``# date:`` line, else the stem's part
after its last ``_`` if that is an ISO date. (Not ``-``: dates hold it.) A HAL capture has no
metadata: its file name gives both. Dates are compared as text, so they must be ISO 8601
(``2025-03-01``, optionally with a time).

**Latest fit**: a machine's fits of one axis count once in the fleet, by its latest fit
(:func:`latest_fits`).

The rows are sorted by (machine id, date, file, axis), every number is a fit's own, and no
wall-clock time is written: the same logs and options give the same table bytes
(:func:`read_fleet_table`; written by :func:`servotune.fleet.fit.write_fleet_table`).
"""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from servotune.budget import BudgetError
from servotune.digest import bytes_sha256
from servotune.errors import ServotuneError
from servotune.fleet.table import read_fleet_records
from servotune.identify import fit_log
from servotune.identify.model import ALL_PARAMS
from servotune.identify.result import FitResult
from servotune.io.hal import HalSettings, capture_format
from servotune.io.log_header import read_metadata
from servotune.logs import read_log
from servotune.rig import Rig

__all__ = [
    "FleetFitOptions",
    "FleetRow",
    "dated",
    "fit_fleet_log",
    "latest_fits",
    "machine_and_date",
    "read_fleet_table",
]

_ISO_DATE = re.compile(r"^\d{4}-\d{2}-\d{2}")
_MAX_MESSAGE = 600


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
        """The row as a record of the fleet table (:data:`servotune.fleet.table.COLUMNS`)."""
        rec: dict[str, Any] = {
            "machine_id": self.machine_id,
            "date": self.date,
            "file": self.file,
            "axis": self.axis,
            "sha256": self.sha256,
            "status": "error" if self.error else "ok",
            "error": self.error,
            "method": self.method,
            "structure": self.structure,
            "friction": self.friction,
            "adequate": self.adequate,
            "failed_tests": self.failed_tests,
            "velocity_fit_pct": self.velocity_fit_pct,
            "velocity_fit_cv_pct": self.velocity_fit_cv_pct,
            "position_fit_pct": self.position_fit_pct,
            "position_fit_cv_pct": self.position_fit_cv_pct,
        }
        for p in ALL_PARAMS:
            lo, hi = self.ci95.get(p, (None, None))
            rec[p], rec[f"{p}_lo"], rec[f"{p}_hi"] = self.params.get(p), lo, hi
        rec.update(
            n_samples=self.n_samples,
            period_s=self.period_s,
            outliers=",".join(self.outliers),
            drift=",".join(self.drift),
            warnings=self.warnings,
        )
        return rec

    @classmethod
    def from_record(cls, rec: Mapping[str, Any]) -> FleetRow:
        """A row from a fleet table's record (:meth:`to_record`'s inverse)."""
        params = {p: float(rec[p]) for p in ALL_PARAMS if rec.get(p) is not None}
        ci95 = {
            p: (float(rec[f"{p}_lo"]), float(rec[f"{p}_hi"]))
            for p in ALL_PARAMS
            if rec.get(f"{p}_lo") is not None and rec.get(f"{p}_hi") is not None
        }
        return cls(
            machine_id=rec["machine_id"],
            date=rec["date"],
            file=rec["file"],
            axis=rec["axis"],
            sha256=rec["sha256"],
            error=rec["error"],
            method=rec["method"],
            structure=rec["structure"],
            friction=rec["friction"],
            adequate=rec["adequate"],
            failed_tests=rec["failed_tests"],
            velocity_fit_pct=rec["velocity_fit_pct"],
            velocity_fit_cv_pct=rec["velocity_fit_cv_pct"],
            position_fit_pct=rec["position_fit_pct"],
            position_fit_cv_pct=rec["position_fit_cv_pct"],
            params=params,
            ci95=ci95,
            n_samples=rec["n_samples"],
            period_s=rec["period_s"],
            outliers=_split(rec["outliers"]),
            drift=_split(rec["drift"]),
            warnings=rec["warnings"],
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON (every field; intervals as lists, non-finite floats as None)."""
        return plain({f.name: getattr(self, f.name) for f in fields(self)})


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
    failed += [
        f"cross-correlation with {c['input']}"
        for c in r.cross_correlation
        if not c.get("uncorrelated", True)
    ]
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

    Raises
    ------
    BudgetError
        A log would need more memory than the budget (``--max-memory``): that refuses the
        whole run (no table is written), it is not the log's row.

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
        return (
            FleetRow(
                machine_id=machine,
                date=date,
                file=name,
                axis=opts.axis or "",
                error=f"cannot read {name!r}: {why}",
            ),
        )
    sha = bytes_sha256(raw)
    meta: dict[str, str] = {}
    if opts.hal is None or capture_format(path) == "csv":  # a CSV's own machine_id and date
        try:
            meta = read_metadata(path)
        except (ServotuneError, OSError):
            meta = {}  # the fit below names the problem
    machine, date = machine_and_date(path, meta)
    base = FleetRow(machine_id=machine, date=date, file=name, axis=opts.axis or "", sha256=sha)
    try:
        axes = _axes(path, opts)
    except BudgetError:  # the memory budget refuses the whole run, not one log's row
        raise
    except Exception as exc:  # a log that cannot be read is a row, never the end of the run
        return (replace(base, error=_error(exc, name, src)),)
    rows = []
    for ax in axes:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                result, _, _ = fit_log(path, axis=ax, **opts.fit_kwargs())
            except BudgetError:
                raise
            except Exception as exc:  # any failure of one fit is its row's error
                rows.append(replace(base, axis=ax or "", error=_error(exc, name, src)))
                continue
        said = " | ".join(
            dict.fromkeys(
                _one_line(f"{w.category.__name__}: {w.message}", name, src) for w in caught
            )
        )
        rows.append(_fit_row(replace(base, axis=ax or ""), result, _one_line(said, name, src)))
    return tuple(sorted(rows, key=lambda r: r.axis))


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


def dated(row: FleetRow) -> bool:
    """The row has an ISO 8601 date (``2025-03-01``…), so it is compared for drift."""
    return bool(_ISO_DATE.match(row.date))


def latest_fits(
    rows: Iterable[FleetRow], *, adequate_only: bool = False
) -> dict[tuple[str, str], FleetRow]:
    """The latest fit of each machine and axis: the row with the latest ISO 8601 date (an
    undated row counts as earlier than any dated one; ties: the last file name), failed rows
    left out.

    Parameters
    ----------
    rows : iterable of FleetRow
    adequate_only : bool
        Leave out the fits whose residual tests did not all pass (``adequate`` not True)
        before choosing.

    Returns
    -------
    dict
        ``(axis, machine_id)`` → that row, in sorted key order.

    Examples
    --------
    >>> a = FleetRow(machine_id="m1", date="2025-01-01", file="a.csv", axis="x")
    >>> b = FleetRow(machine_id="m1", date="2025-06-01", file="b.csv", axis="x")
    >>> latest_fits([b, a])[("x", "m1")].file
    'b.csv'
    """
    fitted = [r for r in rows if r.ok and (r.adequate is True or not adequate_only)]
    latest: dict[tuple[str, str], FleetRow] = {}
    for r in sorted(fitted, key=lambda r: (r.date if dated(r) else "", r.file)):
        latest[(r.axis, r.machine_id)] = r
    return dict(sorted(latest.items()))


def read_fleet_table(path: str | Path) -> tuple[FleetRow, ...]:
    """The rows of a fleet table (either form).

    Raises
    ------
    FleetTableError
        If the file cannot be read or is not a fleet table of this schema.
    """
    return tuple(FleetRow.from_record(rec) for rec in read_fleet_records(path))


def plain(x: Any) -> Any:
    """JSON-safe: tuples as lists, non-finite floats as None."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, Mapping):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [plain(v) for v in x]
    return x
