"""The result of a linkage run (per CPU, per axis, per arc) and its text summary."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from servotune.arch.linkage.checks import BusFigures, Check
from servotune.arch.linkage.config import SCHEMA
from servotune.arch.linkage.path import Interpolation
from servotune.io.files import json_float

__all__ = [
    "EVENT_COLUMNS",
    "EVENT_KINDS",
    "ArcResult",
    "AxisResult",
    "AxisTrace",
    "CpuResult",
    "LinkageResult",
]

EVENT_KINDS = ("sync", "tick", "block")
"""The kinds of a CPU's queue events (:attr:`CpuResult.events`), by their code 0, 1, 2."""

EVENT_COLUMNS = ("kind", "arg", "level_before", "level_after", "count", "late", "next")
"""The columns of :attr:`CpuResult.events`, one row per event of the CPU's queue, in order:

- ``kind``: 0 sync (a clock-sync broadcast; the first, at motion start, is master tick 0),
  1 tick (the CPU pops and executes one command), 2 block (a block frame has arrived; the
  prefill blocks come first, before motion);
- ``arg``: sync: the master's tick index ``k_r``; tick: the command index executed; block:
  the block index ``b`` (commands ``b·B … b·B + B − 1``);
- ``level_before``, ``level_after``: queue level around the event [setpoints per axis];
- ``count``: sync: commands discarded (the CPU was behind); tick: 1 on an underrun (the
  command was not in the queue: each axis holds its previous one); block: setpoints lost to
  a full queue (an overrun if > 0);
- ``late``: block: setpoints whose tick had passed (ignored); sync: the CPU's next index
  before the sync (``arg − late`` > 0: behind, < 0: ahead);
- ``next``: the index of the CPU's next tick after the event.

(The kernel's ``_EV_*`` codes and ``_E_*`` columns, in this order.)
"""


def _plain(
    obj: Any, arrays: bool = False, skip: tuple[str, ...] = (), **extra: Any
) -> dict[str, Any]:
    """A result's fields as a plain dict: the others (tuples as lists) and ``extra`` sorted by
    name, then, with ``arrays``, its arrays as lists in field order; none of ``skip``."""
    values = {f.name: getattr(obj, f.name) for f in fields(obj) if f.name not in skip}
    per_tick = {k: v for k, v in values.items() if isinstance(v, np.ndarray)}
    d = {k: list(v) if isinstance(v, tuple) else v for k, v in values.items() if k not in per_tick}
    d = dict(sorted({**d, **extra}.items()))
    if arrays:
        d.update((k, v.tolist()) for k, v in per_tick.items())
    return d


@dataclass(frozen=True, slots=True, kw_only=True)
class CpuResult:
    """What happened on one slave CPU.

    Attributes
    ----------
    name : str
        The CPU's name in the config.
    axes : tuple of str
    clock_ppm : float
        Its clock's error [ppm].
    queue_depth : int
        Capacity [setpoints per axis].
    tick_time_s : ndarray
        Master time of each of its ticks [s].
    tick_index : ndarray of int64
        The command index each tick executed (strictly increasing: none runs twice).
    queue_level : ndarray of int64
        Queue level just before each tick's pop [setpoints].
    underruns : int
        Ticks whose command was not in the queue.
    first_underrun_s : float or None
        Time of the first [s].
    overruns : int
        Blocks that did not fit completely.
    first_overrun_s : float or None
        Time of the first [s].
    min_level : int
        Worst underrun margin: lowest queue level before a pop [setpoints].
    max_level : int
        Highest queue level after an arrival [setpoints].
    skipped : int
        Commands consumed unexecuted at a sync (the slave was behind by whole ticks).
    resyncs : int
        Sync broadcasts during motion (after the start sync).
    events : ndarray of int64, shape (events, 7) or None
        With ``run_linkage(..., trace=True)``: the queue's events in order, one row each,
        columns :data:`EVENT_COLUMNS` (what the slave's receive queue and clock-sync logic see
        and do: the exported C replays them). Not in :meth:`to_dict`.
    """

    name: str
    axes: tuple[str, ...]
    clock_ppm: float
    queue_depth: int
    tick_time_s: np.ndarray = field(repr=False)
    tick_index: np.ndarray = field(repr=False)
    queue_level: np.ndarray = field(repr=False)
    underruns: int
    first_underrun_s: float | None
    overruns: int
    first_overrun_s: float | None
    min_level: int
    max_level: int
    skipped: int
    resyncs: int
    events: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self, arrays: bool = False) -> dict[str, Any]:
        """Plain dict; the per-tick arrays only with ``arrays=True`` (the events never)."""
        return _plain(self, arrays, skip=("events",), ticks=int(self.tick_time_s.size))


@dataclass(frozen=True, slots=True, kw_only=True)
class AxisResult:
    """Tracking of one axis.

    Attributes
    ----------
    name, cpu : str
        The axis, and the slave CPU that drives it.
    kp : float
        [codes/count]
    ki : float
        [codes/(count·s)]
    tuned : bool
        True if the gains were tuned (not given: the caller's
        :func:`~servotune.arch.linkage.synthesis.resolve_gains` tuned them).
    max_abs_err_counts, rms_err_counts : float
        Of ``command − actual`` over every master tick [counts].
    saturated_ticks : int
        Ticks whose D/A output hit a rail.
    fault : str or None
        ``"following_error"`` or ``"counter"`` if a fault latched.
    first_fault_s : float or None
        When [s].
    """

    name: str
    cpu: str
    kp: float
    ki: float
    tuned: bool
    max_abs_err_counts: float
    rms_err_counts: float
    saturated_ticks: int
    fault: str | None
    first_fault_s: float | None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return _plain(self)


@dataclass(frozen=True, slots=True, kw_only=True)
class AxisTrace:
    """The ticks of one axis on its slave CPU (``run_linkage(..., trace=True)``).

    Row ``i`` is the CPU's ``i``-th tick, at ``CpuResult.tick_time_s[i]`` (master time),
    executing command ``CpuResult.tick_index[i]``.

    Attributes
    ----------
    name, cpu : str
        The axis and the CPU that drives it.
    ref_counts : ndarray of int64
        Reference the law followed: the popped command, the previous one on an underrun
        [counts].
    code : ndarray of int64
        D/A code written.
    pos_counts : ndarray of int64
        The runtime's unwrapped position, relative to its first read [counts].
    true_pos_counts : ndarray
        Plant position at the tick, no noise, not quantised [counts].
    speed_cps : ndarray
        Plant speed at the tick [counts/s].
    """

    name: str
    cpu: str
    ref_counts: np.ndarray = field(repr=False)
    code: np.ndarray = field(repr=False)
    pos_counts: np.ndarray = field(repr=False)
    true_pos_counts: np.ndarray = field(repr=False)
    speed_cps: np.ndarray = field(repr=False)

    @property
    def n_ticks(self) -> int:
        """Number of ticks recorded."""
        return int(self.code.size)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict, the arrays as lists (every key sorted)."""
        return dict(sorted(_plain(self, arrays=True).items()))


@dataclass(frozen=True, slots=True, kw_only=True)
class ArcResult:
    """The circular test of one arc (ISO 230-4 reading).

    As a ballbar test is read at a constant feed after a run-in, the extremes and the
    circularity are taken over the arc's cruise (constant-feed) ticks; the arrays cover the
    whole move, ramps included, and ``circularity_whole_counts`` reads them all.

    Attributes
    ----------
    move : int
    plane : tuple of str
    centre : tuple of float
        [counts]
    radius_counts : float
        Programmed radius [counts].
    angle_rad : ndarray
        Angle of the actual point about the centre, per tick of the move [rad].
    radial_dev_counts : ndarray
        Actual radius − programmed radius, per tick of the move [counts].
    cruise : ndarray of bool
        Per tick of the move: at the constant feed.
    max_dev_counts, min_dev_counts : float
        Extremes of the radial deviation at the constant feed [counts].
    circularity_counts : float
        ``max − min`` at the constant feed [counts].
    circularity_whole_counts : float
        ``max − min`` over the whole move, ramps included [counts].
    """

    move: int
    plane: tuple[str, str]
    centre: tuple[float, float]
    radius_counts: float
    angle_rad: np.ndarray = field(repr=False)
    radial_dev_counts: np.ndarray = field(repr=False)
    cruise: np.ndarray = field(repr=False)
    max_dev_counts: float
    min_dev_counts: float
    circularity_counts: float
    circularity_whole_counts: float

    def to_dict(self, arrays: bool = False) -> dict[str, Any]:
        """Plain dict; the per-tick arrays only with ``arrays=True``."""
        return _plain(self, arrays)


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkageResult:
    """Result of :func:`run_linkage`.

    Attributes
    ----------
    name : str
        The name of the configuration that ran.
    seed : int
    period_s : float
        Nominal period [s].
    bus : BusFigures
        :func:`bus_figures` (utilisation, frame and broadcast period [s], lead [s], ...).
    resync_interval_s : float
        Interval used [s] (0: start sync only), after rounding to whole ticks.
    recommended_resync_interval_s : float or None
        :func:`recommended_resync_interval_s` [s] (None if no interval works).
    cpus : tuple of CpuResult
    axes : tuple of AxisResult
    arcs : tuple of ArcResult
    contour_max_counts, contour_rms_counts : float
        Contour error over every master tick [counts].
    checks : tuple of Check
        Before and during motion.
    interpolation : Interpolation
    time_s : ndarray
        Master ticks ``k · period_s`` [s].
    command_counts : ndarray of int64, shape (ticks, axes)
        Commands [counts] (the path, then its end held).
    path_counts : ndarray, shape (ticks, axes)
        Programmed positions [counts].
    actual_counts : ndarray, shape (ticks, axes)
        Plant positions at the master ticks [counts].
    contour_counts : ndarray
        Contour error per master tick [counts].
    traces : tuple of AxisTrace or None
        Every axis's ticks on its CPU, in column order; only with ``run_linkage(...,
        trace=True)`` (off by default: 40 bytes per tick and axis). Not in :meth:`to_dict`.
    """

    name: str
    seed: int
    period_s: float
    bus: BusFigures
    resync_interval_s: float
    recommended_resync_interval_s: float | None
    cpus: tuple[CpuResult, ...]
    axes: tuple[AxisResult, ...]
    arcs: tuple[ArcResult, ...]
    contour_max_counts: float
    contour_rms_counts: float
    checks: tuple[Check, ...]
    interpolation: Interpolation = field(repr=False)
    time_s: np.ndarray = field(repr=False)
    command_counts: np.ndarray = field(repr=False)
    path_counts: np.ndarray = field(repr=False)
    actual_counts: np.ndarray = field(repr=False)
    contour_counts: np.ndarray = field(repr=False)
    traces: tuple[AxisTrace, ...] | None = field(default=None, repr=False)

    @property
    def passed(self) -> bool:
        """True if every check passed."""
        return all(c.passed for c in self.checks)

    @property
    def failed_checks(self) -> tuple[Check, ...]:
        """The checks that failed."""
        return tuple(c for c in self.checks if not c.passed)

    @property
    def axis_names(self) -> tuple[str, ...]:
        """Axis names in column order."""
        return tuple(a.name for a in self.axes)

    @property
    def worst_underrun_margin(self) -> int:
        """Lowest queue level before a pop over every slave [setpoints]."""
        return min(c.min_level for c in self.cpus)

    @property
    def tracking_error_counts(self) -> np.ndarray:
        """``command − actual`` per master tick and axis [counts]."""
        return self.command_counts - self.actual_counts

    def to_dict(self, arrays: bool = False) -> dict[str, Any]:
        """Plain JSON-able dict with ``"schema": "servotune.linkage/1"``.

        Parameters
        ----------
        arrays : bool
            Also the per-tick arrays (queue levels, radial deviations); off by default.
        """
        return {
            "arcs": [a.to_dict(arrays) for a in self.arcs],
            "axes": [a.to_dict() for a in self.axes],
            "bus": {
                k: v if isinstance(v, int) else json_float(float(v))
                for k, v in self.bus.to_dict().items()
            },
            "checks": [c.to_dict() for c in self.checks],
            "contour_max_counts": self.contour_max_counts,
            "contour_rms_counts": self.contour_rms_counts,
            "cpus": [c.to_dict(arrays) for c in self.cpus],
            "duration_s": self.interpolation.duration_s,
            "name": self.name,
            "passed": self.passed,
            "period_s": self.period_s,
            "recommended_resync_interval_s": self.recommended_resync_interval_s,
            "resync_interval_s": self.resync_interval_s,
            "schema": SCHEMA,
            "seconds": int(self.time_s.size) * self.period_s,
            "seed": self.seed,
            "worst_underrun_margin": self.worst_underrun_margin,
        }


def optional_time(x: float) -> float | None:
    return None if x < 0.0 else float(x)
