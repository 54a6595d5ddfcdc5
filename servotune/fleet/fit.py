"""A fleet fit: every log of many machines fitted at once, then summarised.

``servotune fit logs/*.csv --fleet out.parquet`` runs :func:`fit_fleet`: every log (every axis
of it, or one named axis) is fitted by :func:`~servotune.fleet.rows.fit_fleet_log` as one task
of an :class:`~servotune.executor.Executor` (in-process, or a Dask cluster), one
:class:`~servotune.fleet.rows.FleetRow` per log and axis, then summarised by
:func:`~servotune.fleet.summary.summarise_fleet`; the rows get the summary's flags. Each fit is
a pure function of its file, so the table's bytes are the same on any executor.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from servotune._version import __version__
from servotune.executor import Executor, InProcessExecutor
from servotune.fleet.rows import FleetFitOptions, FleetRow, fit_fleet_log, read_fleet_table
from servotune.fleet.summary import DRIFT_K, OUTLIER_Z, FleetSummary, summarise_fleet
from servotune.fleet.table import (
    FLEET_SCHEMA,
    fleet_table_bytes,
    table_format,
    write_fleet_records,
)

__all__ = [
    "FLEET_CLUSTER_MIN_LOGS",
    "FleetResult",
    "fit_fleet",
    "write_fleet_table",
]

FLEET_CLUSTER_MIN_LOGS = 200
"""Logs from which ``servotune fit --fleet`` starts an embedded Dask ``LocalCluster`` on this
machine's cores (``--workers``/``--scheduler`` choose otherwise). A fit of an 8 s log (2,000
ticks) takes about 0.1 s of one core; starting a 2-worker cluster and loading the compiled
kernels in each worker costs about 3–5 s, and 2 workers fit about 1.6 times as many logs per
second as one process, so the cluster pays back from about 150 such logs on 2 cores
(``docs/scale.md``, "Fleet fits")."""


def _fit_task(path: str, shared: FleetFitOptions) -> tuple[FleetRow, ...]:
    """:func:`fit_fleet_log` as an executor task (a Dask executor passes ``shared`` by name)."""
    return fit_fleet_log(path, shared)


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
    BudgetError
        A log would need more memory than the budget (``--max-memory``): the run stops.
    """
    opts = FleetFitOptions() if options is None else options
    if axis is not None:
        opts = replace(opts, axis=axis)
    base = read_fleet_table(baseline) if isinstance(baseline, str | Path) else tuple(baseline or ())
    items = list(dict.fromkeys(str(p) for p in paths))
    ex = InProcessExecutor() if executor is None else executor
    say = progress or (lambda _m: None)
    say(f"fit fleet: {len(items)} logs on {ex.name}")
    parts = ex.map(
        _fit_task, items, shared=opts, done=lambda k: say(f"fit fleet: {k}/{len(items)} logs")
    )
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
    return [
        replace(
            r,
            outliers=tuple(out_of.get((r.file, r.axis, r.machine_id), ())),
            drift=tuple(drift_of.get((r.file, r.axis, r.machine_id), ())),
        )
        for r in rows
    ]


def write_fleet_table(result: FleetResult | Sequence[FleetRow], path: str | Path) -> None:
    """Write the fleet table atomically, Parquet or CSV by the file's suffix
    (:mod:`servotune.fleet.table`).

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
