"""Simulation results: one trajectory (:class:`Trace`) and a batch's (:class:`BatchResult`).

A batch's metrics and traces are named objects (:class:`BatchMetrics`, :class:`BatchTraces`):
one field per quantity, each an array over candidates (and ticks) and axes.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from servotune.errors import SimulationError
from servotune.sim.tick import METRIC_NAMES

__all__ = ["BatchMetrics", "BatchResult", "BatchTraces", "Trace"]


@dataclass(frozen=True, slots=True, kw_only=True)
class Trace:
    """One simulated trajectory, arrays of shape (ticks, axes).

    Attributes
    ----------
    period_s : float
        Tick period [s].
    axis_names : tuple of str
    code : ndarray of int32
        D/A code written each tick (0 in ideal mode).
    volts : ndarray
        D/A output [V] (the ideal law's unquantised output in ideal mode).
    counter : ndarray of int64
        Raw counter register read each tick (0 in ideal mode).
    pos_counts : ndarray of int64
        Runtime's extended position (relative to its first read) [counts].
    err_counts : ndarray of int64
        The law's error ``r − y`` [counts].
    ref_counts : ndarray of int64
        Task reference relative to the start [counts].
    mode : ndarray of int8
        Mode the runtime ran (``MODE_*``).
    flags : ndarray of int16
        ``FLAG_*`` bits.
    true_pos_counts : ndarray
        Plant position at the tick start, no noise, not quantised [counts].
    speed_cps : ndarray
        Plant speed at the tick start [counts/s].
    """

    period_s: float
    axis_names: tuple[str, ...]
    code: np.ndarray
    volts: np.ndarray
    counter: np.ndarray
    pos_counts: np.ndarray
    err_counts: np.ndarray
    ref_counts: np.ndarray
    mode: np.ndarray
    flags: np.ndarray
    true_pos_counts: np.ndarray
    speed_cps: np.ndarray

    @property
    def n_ticks(self) -> int:
        """Number of ticks."""
        return int(self.code.shape[0])

    @property
    def time_s(self) -> np.ndarray:
        """Tick start times ``k · period_s`` [s]."""
        return np.arange(self.n_ticks, dtype=np.int64) * self.period_s

    def axis(self, name: str) -> int:
        """Column index of an axis."""
        try:
            return self.axis_names.index(name)
        except ValueError:
            raise SimulationError(f"no axis {name!r}; axes: {list(self.axis_names)}") from None


@dataclass(frozen=True, slots=True, kw_only=True)
class BatchMetrics:
    """Per-candidate, per-axis metrics of a batch, each of shape (candidates, axes).

    Counted over the task ticks from ``metric_from_tick`` (:func:`~servotune.sim.engine.run_batch`).

    Attributes
    ----------
    max_abs_err_counts : ndarray
        Largest ``|e|`` [counts].
    rms_err_counts : ndarray
        RMS of ``e`` [counts].
    itae_counts_s2 : ndarray
        ∫ t·|e| dt from ``metric_from_tick`` [counts·s²].
    saturated_ticks : ndarray
        Ticks with a saturated D/A code (all ticks).
    first_fault_tick : ndarray
        First tick with a latched fault, -1 if none.
    final_err_counts : ndarray
        ``e`` at the last tick [counts].
    task_ticks : ndarray
        Ticks counted.
    max_err_counts, min_err_counts : ndarray
        Signed extremes of ``e = r − y`` [counts] (overshoot shows as a negative minimum).
    """

    max_abs_err_counts: np.ndarray
    rms_err_counts: np.ndarray
    itae_counts_s2: np.ndarray
    saturated_ticks: np.ndarray
    first_fault_tick: np.ndarray
    final_err_counts: np.ndarray
    task_ticks: np.ndarray
    max_err_counts: np.ndarray
    min_err_counts: np.ndarray

    @classmethod
    def from_array(cls, metrics: np.ndarray) -> BatchMetrics:
        """From the kernel's array of shape (candidates, axes, metrics), ``METRIC_NAMES`` order."""
        return cls(**{name: metrics[:, :, j] for j, name in enumerate(METRIC_NAMES)})

    @property
    def array(self) -> np.ndarray:
        """Every metric stacked: shape (candidates, axes, metrics), ``METRIC_NAMES`` order."""
        return np.stack([getattr(self, name) for name in METRIC_NAMES], axis=-1)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of nested lists (JSON)."""
        return {f.name: getattr(self, f.name).tolist() for f in fields(self)}


@dataclass(frozen=True, slots=True, kw_only=True)
class BatchTraces:
    """Per-tick records of every candidate, each of shape (candidates, ticks, axes).

    The fields are those of :class:`Trace` (same meaning, units and dtypes), for every
    candidate.
    """

    code: np.ndarray
    volts: np.ndarray
    counter: np.ndarray
    pos_counts: np.ndarray
    err_counts: np.ndarray
    mode: np.ndarray
    flags: np.ndarray
    true_pos_counts: np.ndarray
    speed_cps: np.ndarray

    @property
    def n_candidates(self) -> int:
        """Number of candidates."""
        return int(self.code.shape[0])

    @classmethod
    def concatenate(cls, parts: list[BatchTraces]) -> BatchTraces:
        """The candidates of several batches (same ticks and axes), in order."""
        return cls(
            **{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)}
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class BatchResult:
    """What :func:`~servotune.sim.engine.run_batch` returns.

    Attributes
    ----------
    metrics : BatchMetrics
        Every candidate's figures, each axis's.
    traces : BatchTraces or None
        With ``metrics_only=False``.
    """

    metrics: BatchMetrics
    traces: BatchTraces | None = None

    def metric(self, name: str) -> np.ndarray:
        """One metric by name, shape (candidates, axes)."""
        if name not in METRIC_NAMES:
            raise SimulationError(f"no metric {name!r}; metrics: {', '.join(METRIC_NAMES)}")
        return getattr(self.metrics, name)
