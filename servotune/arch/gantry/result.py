"""The result of gantry runs: one run's trace, the comparison of the topologies, its table."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from servotune._version import __version__
from servotune.analysis.margins import LoopMargins
from servotune.arch.gantry.config import GantryConfig
from servotune.arch.gantry.design import LoadPrediction
from servotune.io.files import json_float, json_safe
from servotune.laws.sync import SYNC_WARN
from servotune.verify.result import clopper_pearson

__all__ = [
    "GantryMetrics",
    "GantryMonteCarlo",
    "GantryTrace",
    "GantryVariant",
    "SyncComparison",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryMetrics:
    """The sync error of one gantry run (:meth:`GantryTrace.metrics`): one row of the
    comparison (:class:`SyncComparison`).

    Attributes
    ----------
    topology, case : str
        The run's topology (:data:`~servotune.arch.gantry.TOPOLOGIES`) and case
        (:data:`~servotune.arch.gantry.CASES`).
    max_sync_error_counts : float
        Largest measured ``|y_master − y_slave|`` over the run [counts].
    rms_sync_error_counts : float
        RMS of the measured sync error over the run [counts].
    warning_cycles : int
        Cycles the monitor was at the warning level [cycles].
    tripped : bool
        True if the monitor tripped.
    trip_time_s : float or None
        When it tripped, from the run's start [s]; None if it did not.
    """

    topology: str
    case: str
    max_sync_error_counts: float
    rms_sync_error_counts: float
    warning_cycles: int
    tripped: bool
    trip_time_s: float | None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict keyed by field name (a row of ``sync.json``'s ``results``)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryTrace:
    """One gantry run. Arrays have one row per cycle; axis columns are (master, slave).

    Attributes
    ----------
    topology, case : str
        The topology it ran (:data:`~servotune.arch.gantry.TOPOLOGIES`) and its case's label.
    cycle_s : float
    command : ndarray of int64 — the CNC's command [counts]
    ref : ndarray of int64 (n, 2) — each drive's position command [counts]
    y : ndarray of int64 (n, 2) — measured positions [counts]
    counter : ndarray of int64 (n, 2) — the counter registers the drives latched
    position : ndarray (n, 2) — true positions at the sample instants [counts]
    code, flags : ndarray of int64 (n, 2) — D/A codes and ``FLAG_*`` bits
    sync_error : ndarray of int64 — measured ``y_master − y_slave`` [counts]
    sync_op, sync_input, sync_comp, sync_level : ndarray of int64
        Per cycle: the compensator call (0 none, 1 enter, 2 step), the sync error it saw, its
        compensation [counts], the monitor level (0 ok, 1 warn, 2 trip).
    resets : ndarray of bool — the operator's resets (:func:`~servotune.arch.gantry.run.
        run_gantry`)
    trip_cycle : int
        Cycle the monitor first tripped, -1 if it did not.
    stop_bound_cycles : int
    """

    topology: str
    case: str
    cycle_s: float
    command: np.ndarray
    ref: np.ndarray
    y: np.ndarray
    counter: np.ndarray
    position: np.ndarray
    code: np.ndarray
    flags: np.ndarray
    sync_error: np.ndarray
    sync_op: np.ndarray
    sync_input: np.ndarray
    sync_comp: np.ndarray
    sync_level: np.ndarray
    resets: np.ndarray
    trip_cycle: int
    stop_bound_cycles: int

    @property
    def time_s(self) -> np.ndarray:
        """Sample instants [s]."""
        return np.arange(self.command.size, dtype=np.int64) * self.cycle_s

    def metrics(self) -> GantryMetrics:
        """Max and RMS |sync error| [counts], warning cycles, trip (:class:`GantryMetrics`)."""
        e = self.sync_error.astype(float)
        return GantryMetrics(
            topology=self.topology,
            case=self.case,
            max_sync_error_counts=float(np.max(np.abs(e))),
            rms_sync_error_counts=float(np.sqrt(np.mean(e * e))),
            warning_cycles=int(np.count_nonzero(self.sync_level == SYNC_WARN)),
            tripped=self.trip_cycle >= 0,
            trip_time_s=self.trip_cycle * self.cycle_s if self.trip_cycle >= 0 else None,
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryVariant:
    """One drawn plant pair and what it did.

    Attributes
    ----------
    index : int
    factors : dict of str to float
        ``master_gain``, ``master_tau``, ``slave_gain``, ``slave_tau``: the factors on the
        config's plants [1].
    max_sync_error_counts : float
        Largest |sync error| over the cases [counts].
    tripped : bool
        The monitor tripped in some case.
    """

    index: int
    factors: dict[str, float]
    max_sync_error_counts: float
    tripped: bool

    @property
    def label(self) -> str:
        return f"mc{self.index}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "factors": dict(self.factors),
            "max_sync_error_counts": json_float(self.max_sync_error_counts),
            "tripped": self.tripped,
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class GantryMonteCarlo:
    """Result of :func:`gantry_montecarlo`.

    Attributes
    ----------
    seed : int
        The study's seed (each variant's factors and noise are keyed by it and its index).
    variants : tuple of GantryVariant
    """

    seed: int
    variants: tuple[GantryVariant, ...]

    @property
    def pass_fraction(self) -> tuple[int, int, float, float, float]:
        """``(passed, count, fraction, low, high)``: pairs that never trip and the exact 95 %
        interval of the probability that a drawn pair does not."""
        n = len(self.variants)
        k = sum(not v.tripped for v in self.variants)
        return k, n, k / n, *clopper_pearson(k, n)

    @property
    def worst(self) -> GantryVariant:
        """The variant with the largest sync error (a trip first)."""
        return max(self.variants, key=lambda v: (v.tripped, v.max_sync_error_counts))

    @property
    def passed(self) -> bool:
        return all(not v.tripped for v in self.variants)

    def to_dict(self) -> dict[str, Any]:
        k, n, frac, lo, hi = self.pass_fraction
        return {
            "seed": self.seed,
            "count": n,
            "passed": k,
            "fraction": frac,
            "interval95": [lo, hi],
            "worst": self.worst.to_dict(),
            "tripped": [v.to_dict() for v in self.variants if v.tripped],
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class SyncComparison:
    """Max/RMS sync error per topology and case (:func:`compare_topologies`).

    Attributes
    ----------
    config : GantryConfig
        The gantry compared (gains resolved).
    rows : tuple of GantryMetrics
        One per case and topology, cases in :data:`CASES` order, topologies in
        :data:`TOPOLOGIES` order.
    traces : tuple of GantryTrace
        The runs, in the order of ``rows``.
    predicted : LoadPrediction or None
        What the linear loop gains predict for the ``load`` case; None with a coupled beam
        (the linear models leave the beam out).
    failed : tuple of str
        Why the checks failed (a trip of the deployed topology, a loop breaking a margin limit
        on some plant), empty if they passed.
    margins : tuple of LoopMargins
        Every loop on every plant case (:func:`~servotune.arch.gantry.margins.gantry_margins`).
    montecarlo : GantryMonteCarlo or None
        The deployed topology over drawn plant pairs (:func:`~servotune.arch.gantry.run.
        gantry_montecarlo`), where it was run.
    shaper : tuple of str
        The move's shaper: what it is designed for and what it adds to the move
        (:func:`~servotune.arch.gantry.shaping.gantry_shaper`); empty without one.
    """

    config: GantryConfig
    rows: tuple[GantryMetrics, ...]
    traces: tuple[GantryTrace, ...]
    predicted: LoadPrediction | None
    failed: tuple[str, ...]
    margins: tuple[LoopMargins, ...] = ()
    montecarlo: GantryMonteCarlo | None = None
    shaper: tuple[str, ...] = ()

    def worst_margins(self) -> dict[str, LoopMargins]:
        """Per loop (``master``, ``slave``, ``sync``), its case with the least phase margin."""
        out: dict[str, LoopMargins] = {}
        for m in self.margins:
            if m.axis not in out or m.phase_margin_deg < out[m.axis].phase_margin_deg:
                out[m.axis] = m
        return out

    @property
    def passed(self) -> bool:
        """True if the deployed topology tripped in no case."""
        return not self.failed

    def row(self, topology: str, case: str) -> GantryMetrics:
        """The metrics of one topology in one case.

        Raises
        ------
        KeyError
            If the comparison has no such run.
        """
        for r in self.rows:
            if r.topology == topology and r.case == case:
                return r
        raise KeyError(f"no run of the topology {topology!r} in the case {case!r}")

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (``schema`` ``servotune.sync/2``: ``/1`` and the margins)."""
        c = self.config
        lim = c.margins
        return json_safe(
            {
                "schema": "servotune.sync/2",
                "margins": {
                    "limits": lim.limits.to_dict()
                    | {
                        "extra_cycles": lim.extra_cycles,
                        "gain_spread": lim.gain_spread,
                        "tau_spread": lim.tau_spread,
                    },
                    "worst": {k: m.to_dict() for k, m in self.worst_margins().items()},
                },
                "name": c.name,
                "topology": c.topology,
                "cycle_s": c.bus.cycle_s,
                "latency_cycles": c.bus.latency_cycles,
                "stop_bound_cycles": c.stop_bound_cycles,
                "drives": {"master": c.master.gains.to_dict(), "slave": c.slave.gains.to_dict()},
                "sync": c.sync.gains.to_dict()
                | {"warn_counts": c.sync.warn_counts, "trip_counts": c.sync.trip_counts},
                "sync_constants": c.sync_constants.to_dict(),
                "results": [r.to_dict() for r in self.rows],
                "montecarlo": None if self.montecarlo is None else self.montecarlo.to_dict(),
                "predicted_load": {} if self.predicted is None else self.predicted.to_dict(),
                "passed": self.passed,
                "failed": list(self.failed),
                "version": __version__,
            }
        )
