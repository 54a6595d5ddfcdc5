"""The single-rig closed-loop engine (docs/runtime.md#one-tick): one trajectory or a batch of
candidates.

Tick ``k`` starts at ``t_k = k · period_s`` (the achieved timer period). For every axis the
counter latches the encoder count (``floor`` of position plus noise), the runtime reads and
unwraps it (:func:`servotune.laws.axis.axis_read`); then every axis runs its control step
(:func:`servotune.laws.axis.axis_control`) in the runtime's integer arithmetic, giving the D/A
code written at ``t_k + compute_s``; the motor sees it ``delay_s`` later and moves with the exact
solution of the axis model between input changes (:func:`servotune.plant.advance`).

Candidates of a batch (plant variants, gain sets) run in parallel (numba ``prange``), each with
its own noise stream (splitmix64 seeded per candidate), so a candidate gives the same codes run
alone or in a batch. No fast-math: results are bit-reproducible. One-axis batches run for
metrics only (candidate sweeps of one axis) take a leaner kernel with the same laws and results.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from servotune._numba_cache import call_compiled
from servotune.budget import check_memory
from servotune.errors import SimulationError
from servotune.laws.axis import MODE_TASK, AxisController, task_law
from servotune.plant import NROW, Plant, plant_row
from servotune.rig import Rig
from servotune.scenarios import Inputs
from servotune.sim.kernel import G_KIT, G_KP, G_LOCK, I_LAG, LANES, NPI, batch_kernel
from servotune.sim.lean import CONSTS_CAPACITY, kernel_lean
from servotune.sim.result import BatchMetrics, BatchResult, BatchTraces, Trace
from servotune.sim.tick import METRIC_NAMES, N_METRICS
from servotune.validate import check_seed

__all__ = [
    "METRIC_NAMES",
    "Batch",
    "BatchMetrics",
    "BatchResult",
    "BatchTraces",
    "Loop",
    "Trace",
    "prepare_batch",
    "run_batch",
    "simulate",
]


@dataclass(frozen=True, slots=True, kw_only=True)
class Loop:
    """A rig with its controllers: what the engine closes the loop around.

    Parameters
    ----------
    rig : Rig
        Hardware and axes (plants in rig axis order).
    controllers : tuple of AxisController
        One per rig axis, in rig order.
    ref_source : tuple of int
        Per axis, ``-1`` if its task reference comes from the scenario, else the index of the
        axis whose position (read in the same tick) is its reference: a slave following its
        master (docs/runtime.md#modes-and-bumpless-switches). Default: external for the master, the
        master for slaves.
    """

    rig: Rig
    controllers: tuple[AxisController, ...]
    ref_source: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        n = len(self.rig.axes)
        if len(self.controllers) != n:
            raise SimulationError(
                f"need one controller per axis ({n}), got {len(self.controllers)}"
            )
        if not self.ref_source:
            master = next((i for i, a in enumerate(self.rig.axes) if a.role == "master"), -1)
            src = tuple(-1 if (a.role == "master" or master < 0) else master for a in self.rig.axes)
            object.__setattr__(self, "ref_source", src)
        if len(self.ref_source) != n:
            raise SimulationError(f"ref_source needs {n} entries, got {len(self.ref_source)}")
        for i, s in enumerate(self.ref_source):
            if s != -1 and not (0 <= s < n and s != i):
                raise SimulationError(f"ref_source[{i}] must be -1 or another axis index, got {s}")

    @classmethod
    def from_rig(cls, rig: Rig, task_gains: Sequence[object | None] | None = None) -> Loop:
        """Loop with each axis's lock gain and following-error limit from the rig.

        ``task_gains``: per axis a :class:`~servotune.laws.pi.PIGains`, a
        :class:`~servotune.laws.fuzzy_pid.FuzzyPIDGains`, or None (lock only).
        """
        gains = list(task_gains) if task_gains is not None else [None] * len(rig.axes)
        if len(gains) != len(rig.axes):
            raise SimulationError(f"need one task_gains entry per axis ({len(rig.axes)})")
        ctl = tuple(
            AxisController.from_gains(
                lock_gain_codes_per_count=a.lock_gain_codes_per_count,
                task_gains=g,
                period_s=rig.period_s,
                following_error_limit_counts=a.following_error_limit_counts,
                filters=rig.runtime_filters(i),
            )
            for i, (a, g) in enumerate(zip(rig.axes, gains, strict=True))
        )
        return cls(rig=rig, controllers=ctl)


@dataclass(frozen=True, slots=True, kw_only=True)
class Batch:
    """Discretised candidates ready to run (:func:`prepare_batch`)."""

    loop: Loop
    pf: np.ndarray
    pi: np.ndarray
    consts: np.ndarray
    gains_f: np.ndarray
    seeds: np.ndarray
    ring: int
    ref_source: np.ndarray = field(repr=False)

    @property
    def n_candidates(self) -> int:
        """Number of candidates."""
        return int(self.pf.shape[0])


# --- preparation ---------------------------------------------------------------------------


def _plant_rows(rig: Rig, plants: Sequence[Plant]) -> tuple[np.ndarray, np.ndarray]:
    pf = np.zeros((len(plants), NROW))
    pi = np.zeros((len(plants), NPI), dtype=np.int64)
    for i, (axis, pl) in enumerate(zip(rig.axes, plants, strict=True)):
        pf[i], m = plant_row(pl, rig.period_s, rig.timer.compute_s, rig.counts_per_rev)
        pi[i] = (m, axis.counter_init)
    return pf, pi


def _consts_rows(
    rig: Rig, controllers: Sequence[AxisController]
) -> tuple[list[np.ndarray], np.ndarray]:
    rows = [
        c.consts(counter_bits=rig.counter.bits, dac_bits=rig.dac.bits, dac_zero=rig.dac.zero_code)
        for c in controllers
    ]
    gains = np.zeros((len(controllers), 3))
    for i, c in enumerate(controllers):
        gains[i, G_LOCK] = c.lock_gain.value
        if c.task is not None:
            gains[i, G_KP] = c.task.kp.value
            gains[i, G_KIT] = c.task.ki_t.value
    return rows, gains


def prepare_batch(
    loop: Loop,
    *,
    plants: Sequence[Sequence[Plant]] | None = None,
    controllers: Sequence[Sequence[AxisController]] | None = None,
    seeds: Sequence[int] | int = 0,
    n_candidates: int | None = None,
) -> Batch:
    """Discretise candidates: plant variants and/or controller variants of one loop.

    Parameters
    ----------
    loop : Loop
        The nominal loop.
    plants : sequence of sequences of Plant, optional
        Per candidate, one plant per axis; default the rig's plants.
    controllers : sequence of sequences of AxisController, optional
        Per candidate, one controller per axis; default the loop's.
    seeds : int or sequence of int
        Per-candidate noise stream seeds, or one base seed from which they are derived
        (``numpy.random.SeedSequence(seed).generate_state``).
    n_candidates : int, optional
        Number of candidates when neither plants nor controllers vary.

    Returns
    -------
    Batch
    """
    rig = loop.rig
    sizes = {len(x) for x in (plants, controllers) if x is not None}
    if n_candidates is not None:
        sizes.add(n_candidates)
    if len(sizes) > 1:
        raise SimulationError(
            f"plants, controllers and n_candidates disagree on the count: {sizes}"
        )
    n = sizes.pop() if sizes else 1
    if n < 1:
        raise SimulationError("a batch needs at least one candidate")
    plant_sets = plants if plants is not None else [tuple(a.plant for a in rig.axes)] * n
    ctl_sets = controllers if controllers is not None else [loop.controllers] * n
    n_ax = len(rig.axes)
    pf = np.zeros((n, n_ax, NROW))
    pi = np.zeros((n, n_ax, NPI), dtype=np.int64)
    gains = np.zeros((n, n_ax, 3))
    # identical candidates (frozen, hashable dataclasses) are discretised once
    cache_p: dict[tuple[Plant, ...], tuple[np.ndarray, np.ndarray]] = {}
    cache_c: dict[tuple[AxisController, ...], tuple[list[np.ndarray], np.ndarray]] = {}
    rows_c: list[list[np.ndarray]] = []
    for b in range(n):
        ps, cs = tuple(plant_sets[b]), tuple(ctl_sets[b])
        if len(ps) != n_ax or len(cs) != n_ax:
            raise SimulationError(f"candidate {b}: need {n_ax} plants and controllers")
        key_c = cs
        if ps not in cache_p:
            cache_p[ps] = _plant_rows(rig, ps)
        if key_c not in cache_c:
            cache_c[key_c] = _consts_rows(rig, cs)
        pf[b], pi[b] = cache_p[ps]
        rows_c.append(cache_c[key_c][0])
        gains[b] = cache_c[key_c][1]
    # constants vectors differ in length (tables); pad to the longest
    width = max(len(r) for rows in rows_c for r in rows)
    consts = np.zeros((n, n_ax, width), dtype=np.int64)
    for b, rows in enumerate(rows_c):
        for i, r in enumerate(rows):
            consts[b, i, : len(r)] = r
    if np.ndim(seeds) == 0:  # one base seed
        base = check_seed(seeds, error=SimulationError)
        if n == 1:
            seed_arr = np.array([base], dtype=np.uint64)
        else:
            seed_arr = np.random.SeedSequence(base).generate_state(n, dtype=np.uint64)
    else:
        checked = [check_seed(s, error=SimulationError) for s in seeds]  # type: ignore[union-attr]
        seed_arr = np.asarray(checked, dtype=np.uint64)
        if seed_arr.shape != (n,):
            raise SimulationError(f"need {n} seeds, got {seed_arr.size}")
    ring = int(pi[:, :, I_LAG].max()) + 2
    return Batch(
        loop=loop,
        pf=pf,
        pi=pi,
        consts=consts,
        gains_f=gains,
        seeds=seed_arr,
        ring=ring,
        ref_source=np.asarray(loop.ref_source, dtype=np.int64),
    )


def _check_inputs(loop: Loop, inputs: Inputs) -> None:
    n_ax = len(loop.rig.axes)
    if inputs.n_axes != n_ax:
        raise SimulationError(f"inputs have {inputs.n_axes} axes, the rig has {n_ax}")
    for i, c in enumerate(loop.controllers):
        if c.task is None and np.any(inputs.mode[:, i] == MODE_TASK):
            raise SimulationError(
                f"axis {loop.rig.axes[i].name!r} has task ticks but no task law (give PI gains)"
            )


def input_arrays(inputs: Inputs) -> tuple[np.ndarray, ...]:
    """The per-tick inputs in kernel argument order: ref, mode, reset, u_add, load."""
    return (inputs.ref_counts, inputs.mode, inputs.reset, inputs.dac_add_codes, inputs.load_v)


def converter_args(rig: Rig) -> tuple[int, bool, float, float, float]:
    """Counter and D/A scalars in kernel argument order: bits, latched, skew, dac_lo, lsb."""
    return (
        int(rig.counter.bits),
        bool(rig.counter.latched),
        float(rig.counter.read_skew_s),
        float(rig.dac.range_v[0]),
        float(rig.dac.lsb_v),
    )


def run_batch(
    batch: Batch,
    inputs: Inputs,
    *,
    metrics_only: bool = True,
    ideal: bool = False,
    metric_from_tick: int = 0,
    threads: int | None = None,
) -> BatchResult:
    """Run every candidate of a batch through the same scenario inputs.

    Parameters
    ----------
    batch : Batch
        From :func:`prepare_batch`.
    inputs : Inputs
        Per-tick references, modes, resets, added commands and loads.
    metrics_only : bool
        Return only per-candidate metrics (for optimisers); else also full traces.
    ideal : bool
        Ideal floating-point laws, no encoder or D/A quantisation, no counter (design checks).
    metric_from_tick : int
        First tick counted in the metrics.
    threads : int, optional
        Number of threads (default: numba's default).

    Returns
    -------
    BatchResult

    Notes
    -----
    A one-axis batch run for metrics only, not ideal, with lags of at most one whole tick and
    law constants of at most ``CONSTS_CAPACITY`` words runs in a leaner kernel than the others
    (no traces, its state in registers); it calls the same law and plant functions in the same
    order, so the metrics are the same bit for bit.
    """
    loop = batch.loop
    _check_inputs(loop, inputs)
    for c in loop.controllers if ideal else ():
        if c.task is not None and not task_law(c.task).ideal:
            raise SimulationError(
                f"ideal mode runs lock and PI only, not the {task_law(c.task).name} law"
            )
    n, n_ax = batch.n_candidates, len(loop.rig.axes)
    nt = inputs.n_ticks
    rec = 0 if metrics_only else nt
    check_memory(  # before allocating the traces: 6 int64 and 3 float64 per tick and axis
        n * rec * n_ax * 72,
        f"simulating {n} candidate{'s' if n != 1 else ''} over {nt:,} ticks",
        f"{n} × {rec:,} ticks × {n_ax} axes × 72 bytes",
    )
    out_i = np.zeros((6, n, rec, n_ax), dtype=np.int64)
    out_f = np.zeros((3, n, rec, n_ax))
    metrics = np.zeros((n, n_ax, N_METRICS))
    rig = loop.rig
    old_threads = nb.get_num_threads()
    if threads is not None:
        nb.set_num_threads(max(1, min(int(threads), nb.config.NUMBA_NUM_THREADS)))
    # one-axis metrics-only runs (candidate sweeps) take the lean kernel: same results, about
    # twice as fast; it holds lags of at most one whole tick (ring = largest lag + 2)
    lean = (
        metrics_only
        and not ideal
        and n_ax == 1
        and batch.ring <= 3
        and batch.consts.shape[2] <= CONSTS_CAPACITY
    )
    try:
        if lean:
            _run_lean_batch(batch, inputs, metric_from_tick, metrics)
        else:
            call_compiled(
                batch_kernel,
                batch.pf,
                batch.pi,
                batch.consts,
                batch.gains_f,
                batch.seeds,
                batch.ref_source,
                *input_arrays(inputs),
                *converter_args(rig),
                bool(ideal),
                int(batch.ring),
                int(metric_from_tick),
                float(rig.period_s),
                out_i,
                out_f,
                metrics,
                LANES,
            )
    finally:
        nb.set_num_threads(old_threads)
    traces = None
    if not metrics_only:
        traces = BatchTraces(
            code=out_i[0].astype(np.int32),
            counter=out_i[1],
            pos_counts=out_i[2],
            err_counts=out_i[3],
            mode=out_i[4].astype(np.int8),
            flags=out_i[5].astype(np.int16),
            volts=out_f[0],
            true_pos_counts=out_f[1],
            speed_cps=out_f[2],
        )
    return BatchResult(metrics=BatchMetrics.from_array(metrics), traces=traces)


def simulate(
    loop: Loop,
    inputs: Inputs,
    *,
    seed: int = 0,
    ideal: bool = False,
    plants: Sequence[Plant] | None = None,
) -> Trace:
    """Simulate one trajectory.

    Parameters
    ----------
    loop : Loop
    inputs : Inputs
    seed : int
        Noise stream seed (the same as this candidate's seed in a batch gives the same codes).
    ideal : bool
        Ideal laws and converters (see :func:`run_batch`).
    plants : sequence of Plant, optional
        Plants to use instead of the rig's.

    Returns
    -------
    Trace
    """
    batch = prepare_batch(loop, plants=None if plants is None else [tuple(plants)], seeds=[seed])
    res = run_batch(batch, inputs, metrics_only=False, ideal=ideal, threads=1)
    t = res.traces
    assert t is not None
    return Trace(
        period_s=loop.rig.period_s,
        axis_names=loop.rig.axis_names,
        code=t.code[0],
        volts=t.volts[0],
        counter=t.counter[0],
        pos_counts=t.pos_counts[0],
        err_counts=t.err_counts[0],
        ref_counts=np.asarray(inputs.ref_counts),
        mode=t.mode[0],
        flags=t.flags[0],
        true_pos_counts=t.true_pos_counts[0],
        speed_cps=t.speed_cps[0],
    )


def _run_lean_batch(
    batch: Batch, inputs: Inputs, metric_from_tick: int, metrics: np.ndarray
) -> None:
    """Run a one-axis metrics-only batch in the lean kernel, one candidate per chunk.

    ``numba.set_parallel_chunksize`` is numba's documented per-thread setting; the caller's
    value is restored afterwards.
    """
    rig = batch.loop.rig
    previous = nb.set_parallel_chunksize(1)
    try:
        call_compiled(
            kernel_lean,
            batch.pf,
            batch.pi,
            batch.consts,
            batch.seeds,
            *(np.ascontiguousarray(x[:, 0]) for x in input_arrays(inputs)),
            *converter_args(rig),
            int(metric_from_tick),
            float(rig.period_s),
            metrics,
        )
    finally:
        nb.set_parallel_chunksize(previous)
