"""The closed-loop tick engine (SPEC §4): one trajectory or a batch of candidates.

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

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numba as nb
import numpy as np
from numba import types
from numba.extending import intrinsic

try:  # numba internals, used only by the lean kernel's intrinsics (see _try_lean)
    from numba.core import cgutils
    from numba.np.arrayobj import make_array, populate_array
except ImportError:  # pragma: no cover - such a numba runs every batch in the general kernel
    cgutils = make_array = populate_array = None

from servotune.budget import check_memory
from servotune.errors import SimulationError
from servotune.laws.axis import (
    FLAG_SATURATED,
    LAW_FUZZY_PID,
    MODE_LOCK,
    MODE_TASK,
    N_STATE,
    S_MODE,
    AxisController,
    axis_control,
    axis_read,
)
from servotune.laws.pi import pi_ideal_step
from servotune.plant import NROW, R_NOISE, R_OFFSET, Plant, advance_tick, plant_row
from servotune.rig import Rig
from servotune.scenarios import Inputs

__all__ = [
    "METRIC_NAMES",
    "Batch",
    "BatchResult",
    "Loop",
    "Trace",
    "prepare_batch",
    "run_batch",
    "simulate",
]

# plant rows (float64, per candidate and axis): servotune.plant.plant_row; integer parameters:
# whole ticks of lag, counter register at start
_I_LAG, _I_INIT = 0, 1
_NPI = 2
# ideal-law gains (float64): lock, kp, ki*T
_G_LOCK, _G_KP, _G_KIT = 0, 1, 2

METRIC_NAMES = (
    "max_abs_err_counts",
    "rms_err_counts",
    "itae_counts_s2",
    "saturated_ticks",
    "first_fault_tick",
    "final_err_counts",
    "task_ticks",
    "max_err_counts",
    "min_err_counts",
)
"""Per-candidate, per-axis metrics (over task ticks from ``metric_from_tick``; the signed
extremes ``max_err_counts``/``min_err_counts`` of ``e = r − y`` show overshoot)."""
_NM = len(METRIC_NAMES)


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
        master (SPEC §6). Default: external for the master, the master for slaves.
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
            )
            for a, g in zip(rig.axes, gains, strict=True)
        )
        return cls(rig=rig, controllers=ctl)


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


@dataclass(frozen=True, slots=True, kw_only=True)
class BatchResult:
    """Per-candidate results.

    Attributes
    ----------
    metrics : ndarray, shape (candidates, axes, len(METRIC_NAMES))
    traces : dict of ndarray or None
        With ``metrics_only=False``: arrays of shape (candidates, ticks, axes) as in Trace.
    """

    metrics: np.ndarray
    traces: dict[str, np.ndarray] | None = None

    def metric(self, name: str) -> np.ndarray:
        """One metric, shape (candidates, axes)."""
        return self.metrics[:, :, METRIC_NAMES.index(name)]


# --- preparation ---------------------------------------------------------------------------


def _plant_rows(rig: Rig, plants: Sequence[Plant]) -> tuple[np.ndarray, np.ndarray]:
    pf = np.zeros((len(plants), NROW))
    pi = np.zeros((len(plants), _NPI), dtype=np.int64)
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
        gains[i, _G_LOCK] = c.lock_gain.value
        if c.task is not None:
            gains[i, _G_KP] = c.task.kp.value
            gains[i, _G_KIT] = c.task.ki_t.value
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
    pi = np.zeros((n, n_ax, _NPI), dtype=np.int64)
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
    if isinstance(seeds, int | np.integer):
        seed_arr = (
            np.array([int(seeds)], dtype=np.uint64)
            if n == 1
            else np.random.SeedSequence(int(seeds)).generate_state(n, dtype=np.uint64)
        )
    else:
        seed_arr = np.asarray([int(s) for s in seeds], dtype=np.uint64)
        if seed_arr.shape != (n,):
            raise SimulationError(f"need {n} seeds, got {seed_arr.size}")
    ring = int(pi[:, :, _I_LAG].max()) + 2
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


def _input_arrays(inputs: Inputs) -> tuple[np.ndarray, ...]:
    """The per-tick inputs in kernel argument order: ref, mode, reset, u_add, load."""
    return (inputs.ref_counts, inputs.mode, inputs.reset, inputs.dac_add_codes, inputs.load_v)


def _converter_args(rig: Rig) -> tuple[int, bool, float, float, float]:
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
    A one-axis batch run for metrics only, not ideal, with lags of at most one whole tick runs
    in a leaner kernel than the others (no traces, its state in registers); it calls the same
    law and plant functions in the same order, so the metrics are the same bit for bit.
    """
    loop = batch.loop
    _check_inputs(loop, inputs)
    if ideal and any(c.law == LAW_FUZZY_PID for c in loop.controllers):
        raise SimulationError("ideal mode runs lock and PI only, not the fuzzy-PID law")
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
    metrics = np.zeros((n, n_ax, _NM))
    rig = loop.rig
    old_threads = nb.get_num_threads()
    if threads is not None:
        nb.set_num_threads(max(1, min(int(threads), nb.config.NUMBA_NUM_THREADS)))
    # one-axis metrics-only runs (candidate sweeps) take the lean kernel: same results, about
    # twice as fast; it holds lags of at most one whole tick (ring = largest lag + 2)
    lean = metrics_only and not ideal and n_ax == 1 and batch.ring <= 3
    try:
        if not (lean and _try_lean(batch, inputs, metric_from_tick, metrics)):
            _kernel(
                batch.pf,
                batch.pi,
                batch.consts,
                batch.gains_f,
                batch.seeds,
                batch.ref_source,
                *_input_arrays(inputs),
                *_converter_args(rig),
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
        traces = {
            "code": out_i[0].astype(np.int32),
            "counter": out_i[1],
            "pos_counts": out_i[2],
            "err_counts": out_i[3],
            "mode": out_i[4].astype(np.int8),
            "flags": out_i[5].astype(np.int16),
            "volts": out_f[0],
            "true_pos_counts": out_f[1],
            "speed_cps": out_f[2],
        }
    return BatchResult(metrics=metrics, traces=traces)


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
    batch = prepare_batch(
        loop, plants=None if plants is None else [tuple(plants)], seeds=[int(seed)]
    )
    res = run_batch(batch, inputs, metrics_only=False, ideal=ideal, threads=1)
    t = res.traces
    assert t is not None
    return Trace(
        period_s=loop.rig.period_s,
        axis_names=loop.rig.axis_names,
        code=t["code"][0],
        volts=t["volts"][0],
        counter=t["counter"][0],
        pos_counts=t["pos_counts"][0],
        err_counts=t["err_counts"][0],
        ref_counts=np.asarray(inputs.ref_counts),
        mode=t["mode"][0],
        flags=t["flags"][0],
        true_pos_counts=t["true_pos_counts"][0],
        speed_cps=t["speed_cps"][0],
    )


# --- the kernel ----------------------------------------------------------------------------

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


@nb.njit(cache=True)
def _splitmix(state: np.uint64) -> tuple[np.uint64, np.uint64]:
    state = state + _GOLDEN
    z = state
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return state, z ^ (z >> np.uint64(31))


@nb.njit(cache=True)
def _normal(state: np.uint64) -> tuple[np.uint64, float]:
    state, z1 = _splitmix(state)
    state, z2 = _splitmix(state)
    u1 = (float(z1 >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)
    u2 = float(z2 >> np.uint64(11)) * (1.0 / 9007199254740992.0)
    return state, math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@nb.njit(cache=True, inline="always")
def _sample(p, v, nz, init, mask, latched, nbytes, skew):
    """The counter register read at the tick start: position ``p`` [counts] plus noise ``nz``.

    Latched: one read of the whole register. Not latched: byte ``j`` is read ``j · skew`` later,
    while the count moves at the speed ``v`` [counts/s].
    """
    if latched:
        return (init + np.int64(math.floor(p + nz))) & mask
    raw = np.int64(0)
    for j in range(nbytes):
        cj = np.int64(math.floor(p + v * (j * skew) + nz))
        rj = (init + cj) & mask
        raw |= rj & (np.int64(0xFF) << (8 * j))
    return raw


@nb.njit(cache=True, inline="always")
def _accumulate(mt, ln, k, e, flags, cur_mode, m_from, period):
    """Add tick ``k`` to the metrics row ``mt[ln]`` (``METRIC_NAMES`` order; rms as a sum)."""
    if flags & 3 and mt[ln, 4] < 0.0:
        mt[ln, 4] = k
    if flags & FLAG_SATURATED:
        mt[ln, 3] += 1.0
    if k >= m_from and cur_mode == MODE_TASK:
        ae = abs(float(e))
        if ae > mt[ln, 0]:
            mt[ln, 0] = ae
        mt[ln, 1] += ae * ae
        mt[ln, 2] += (k - m_from) * period * ae * period
        mt[ln, 6] += 1.0
        if e > mt[ln, 7]:
            mt[ln, 7] = e
        if e < mt[ln, 8]:
            mt[ln, 8] = e
    mt[ln, 5] = e


@nb.njit(cache=True, inline="always")
def _finish(mt, ln, metrics, b, a):
    """Turn the sums of ``mt[ln]`` into the metrics of candidate ``b``, axis ``a``."""
    cnt = mt[ln, 6]
    mt[ln, 1] = math.sqrt(mt[ln, 1] / cnt) if cnt > 0 else 0.0
    for j in range(_NM):
        metrics[b, a, j] = mt[ln, j]


LANES = 2
"""Candidates interleaved per thread: independent lanes let the CPU overlap their tick chains."""


@nb.njit(cache=True)
def _run_group(
    b0, n_group, pf, pi, consts, gains, seeds, src, ref, mode, reset, u_add, load,
    bits, latched, skew, dac_lo, lsb, ideal, ring, m_from, period, out_i, out_f, metrics,
):  # fmt: skip
    # lane ln = g * n_ax + a runs axis a of candidate b0 + g; lanes never interact across
    # candidates and each candidate draws its own noise stream, so grouping changes no result
    n_ax = pf.shape[1]
    n_l = n_group * n_ax
    nt = ref.shape[0]
    rec = out_i.shape[2] > 0
    mask = (np.int64(1) << bits) - 1
    nbytes = bits // 8
    st = np.zeros((n_l, N_STATE), dtype=np.int64)
    hist = np.zeros((n_l, ring))
    pos = np.zeros(n_l)
    spd = np.zeros(n_l)
    y = np.zeros(n_l, dtype=np.int64)
    yf = np.zeros(n_l)
    integ_f = np.zeros(n_l)
    target_f = np.zeros(n_l)
    mode_f = np.zeros(n_l, dtype=np.int64)
    rng = seeds[b0 : b0 + n_group].copy()
    pfb = pf[b0 : b0 + n_group].copy().reshape(n_l, pf.shape[2])
    pib = pi[b0 : b0 + n_group].copy().reshape(n_l, pi.shape[2])
    cb = consts[b0 : b0 + n_group].copy().reshape(n_l, consts.shape[2])
    gb = gains[b0 : b0 + n_group].copy().reshape(n_l, gains.shape[2])
    mt = np.zeros((n_l, metrics.shape[2]))
    lane_ax = np.empty(n_l, dtype=np.int64)
    lane_g = np.empty(n_l, dtype=np.int64)
    for ln in range(n_l):
        lane_g[ln] = ln // n_ax
        lane_ax[ln] = ln - lane_g[ln] * n_ax
        mt[ln, 4] = -1.0
    slot = ring - 1
    for k in range(nt):
        slot += 1
        if slot == ring:
            slot = 0
        # 1-2. sample and unwrap, every axis
        for ln in range(n_l):
            a = lane_ax[ln]
            p = pos[ln]
            nz = 0.0
            if pfb[ln, R_NOISE] > 0.0:
                g_l = lane_g[ln]
                rng[g_l], g = _normal(rng[g_l])
                nz = g * pfb[ln, R_NOISE]
            if ideal:
                yf[ln] = p + nz
                continue
            raw = _sample(p, spd[ln], nz, pib[ln, _I_INIT], mask, latched, nbytes, skew)
            y[ln] = axis_read(st, cb, ln, raw, reset[k, a])
            if rec:
                out_i[1, b0 + lane_g[ln], k, a] = raw
        # 3-4. control law and D/A, every axis
        for ln in range(n_l):
            a = lane_ax[ln]
            s = src[a]
            base = ln - a
            if ideal:
                r = float(ref[k, a]) if s < 0 else yf[base + s]
                md = mode[k, a]
                if md == MODE_LOCK:
                    if mode_f[ln] != MODE_LOCK or k == 0:
                        target_f[ln] = yf[ln]
                    e_f = target_f[ln] - yf[ln]
                    u = gb[ln, _G_LOCK] * e_f
                elif md == MODE_TASK:
                    e_f = r - yf[ln]
                    u, integ_f[ln] = pi_ideal_step(gb[ln, _G_KP], gb[ln, _G_KIT], integ_f[ln], e_f)
                else:
                    e_f = 0.0
                    u = float(u_add[k, a])
                mode_f[ln] = md
                volts = u * lsb
                code = 0
                flags = 0
                e = np.int64(math.floor(e_f + 0.5))
                cur_mode = md
            else:
                r = ref[k, a] if s < 0 else y[base + s]
                code, flags, e = axis_control(st, cb, ln, r, mode[k, a], reset[k, a], u_add[k, a])
                volts = dac_lo + code * lsb
                cur_mode = st[ln, S_MODE]
            hist[ln, slot] = volts
            if rec:
                b = b0 + lane_g[ln]
                out_i[0, b, k, a] = code
                out_i[2, b, k, a] = y[ln]
                out_i[3, b, k, a] = e
                out_i[4, b, k, a] = cur_mode
                out_i[5, b, k, a] = flags
                out_f[0, b, k, a] = volts
                out_f[1, b, k, a] = pos[ln]
                out_f[2, b, k, a] = spd[ln]
            _accumulate(mt, ln, k, e, flags, cur_mode, m_from, period)
        # 5-6. hold the writes and move the plants to the next tick
        for ln in range(n_l):
            a = lane_ax[ln]
            m = pib[ln, _I_LAG]
            w_off = pfb[ln, R_OFFSET] + load[k, a]
            j_new = slot - m
            if j_new < 0:
                j_new += ring
            v_new = hist[ln, j_new] if k >= m else 0.0
            j_old = j_new - 1
            if j_old < 0:
                j_old += ring
            v_old = hist[ln, j_old] if k >= m + 1 else 0.0
            w_new = v_new + w_off
            w_old = v_old + w_off
            pos[ln], spd[ln] = advance_tick(pos[ln], spd[ln], w_old, w_new, pfb[ln])
    for ln in range(n_l):
        _finish(mt, ln, metrics, b0 + lane_g[ln], lane_ax[ln])


@nb.njit(cache=True, parallel=True)
def _kernel(
    pf, pi, consts, gains, seeds, src, ref, mode, reset, u_add, load,
    bits, latched, skew, dac_lo, lsb, ideal, ring, m_from, period, out_i, out_f, metrics, lanes,
):  # fmt: skip
    n = pf.shape[0]
    n_groups = (n + lanes - 1) // lanes
    for gi in nb.prange(n_groups):
        b0 = gi * lanes
        _run_group(
            b0, min(lanes, n - b0), pf, pi, consts, gains, seeds, src, ref, mode, reset, u_add,
            load, bits, latched, skew, dac_lo, lsb, ideal, ring, m_from, period, out_i, out_f,
            metrics,
        )  # fmt: skip


# --- the lean kernel: one axis, metrics only, integer runtime ------------------------------
#
# Sweeps of many candidates of a one-axis loop for metrics only run here rather than in
# _run_group. It calls the same law and plant functions (axis_read, axis_control,
# advance_tick) and the same counter and metric helpers, with the same float operations in the
# same order, so its metrics equal _run_group's bit for bit (tests/test_engine.py checks it);
# only the plumbing differs, each choice for speed (about 2x over _run_group here):
# - one candidate per loop, its law state and metric sums in small function-local ("stack")
#   arrays indexed by constants, which LLVM promotes to registers; _run_group's heap arrays are
#   stored and reloaded every tick, as LLVM cannot prove they do not alias the other arrays.
#   Interleaving two candidates per loop, as _run_group does, gained nothing here (measured):
#   this loop is bound by instruction throughput, not by the latency of one candidate's tick
#   chain, and two candidates' state overflows the registers (paired timings: 4-8 % slower).
#   Neither did a volts table or packing the per-tick inputs (within +-3 %). What did help a
#   little: 1-D input columns with an unsigned tick index (+4 %), and the common tick (task
#   mode, no reset, no excitation) called with those inputs as constants (+5 %);
# - compiled without reference counting (numba's ``_nrt=False``): passing arrays to the inlined
#   law functions otherwise leaves NRT_incref/NRT_decref calls in the tick loop, and every such
#   call spills the floating-point registers (about 25 % of the time);
# - no trace, ideal-law or slave-reference branches, and no ring buffer: a lag of 0 or 1 whole
#   ticks needs only the last two writes, kept in scalars;
# - threads take candidates one at a time from a shared counter (_kernel_lean), so a thread
#   slowed by other work on its core does not hold up the batch.


@intrinsic
def _stack_zeros(typingctx, shape, dtype):
    """A zeroed C-contiguous array in the calling function's stack frame (jitted code only).

    Parameters
    ----------
    shape : tuple of int
        Dimensions, compile-time constants (literals or module constants).
    dtype : numba dtype
        Element type, e.g. ``np.int64``.

    Returns
    -------
    ndarray
        A view of stack memory without an NRT meminfo, so usable under ``_nrt=False``. It lives
        as long as the frame of the function that calls ``_stack_zeros``: call it only from a
        function that is never IR-inlined (``inline="always"``) into another, and never return
        the array or store it where it outlives that call.
    """
    if not (
        isinstance(shape, types.BaseTuple)
        and all(isinstance(d, types.IntegerLiteral) for d in shape)
        and isinstance(dtype, types.DTypeSpec)
    ):
        return None
    dims = [d.literal_value for d in shape]
    arrty = types.Array(dtype.dtype, len(dims), "C")

    def codegen(context, builder, sig, args):
        ll_ty = context.get_value_type(dtype.dtype)
        itemsize = context.get_abi_sizeof(ll_ty)
        strides = []
        size = 1
        for d in reversed(dims):
            strides.insert(0, size * itemsize)
            size *= d
        intp = context.get_value_type(types.intp)
        data = cgutils.alloca_once(builder, ll_ty, size=size)
        cgutils.memset(builder, data, intp(size * itemsize), 0)
        ary = make_array(arrty)(context, builder)
        populate_array(
            ary,
            data=data,
            shape=[intp(d) for d in dims],
            strides=[intp(st) for st in strides],
            itemsize=intp(itemsize),
            meminfo=None,
        )
        return ary._getvalue()

    return arrty(shape, dtype), codegen


@nb.njit(cache=True, _nrt=False)
def _run_lean(
    b, pf, pi, consts, seeds, ref, mode, reset, u_add, load,
    bits, latched, skew, dac_lo, lsb, m_from, period, metrics,
):  # fmt: skip
    """Run candidate ``b`` of a one-axis batch and write its metrics (arguments as _kernel).

    Needs whole ticks of lag 0 or 1 (``Batch.ring <= 3``); integer runtime, no traces. The
    per-tick inputs ``ref`` … ``load`` are the axis's 1-D columns (contiguous: plain indexing).
    """
    nt = ref.shape[0]
    mask = (np.int64(1) << bits) - 1
    nbytes = bits // 8
    st = _stack_zeros((1, N_STATE), np.int64)
    mt = _stack_zeros((1, _NM), np.float64)
    mt[0, 4] = -1.0
    cb = consts[b]  # (1, width): axis row 0 for the law functions
    row = pf[b, 0]
    noise = row[R_NOISE]
    offset = row[R_OFFSET]
    init = pi[b, 0, _I_INIT]
    lag = pi[b, 0, _I_LAG]
    rng = seeds[b]
    pos = 0.0
    spd = 0.0
    v1 = 0.0  # volts written one tick ago
    v2 = 0.0  # and two ticks ago
    for k in range(nt):
        i = np.uint64(k)  # an unsigned index: no negative-index wraparound code per access
        nz = 0.0
        if noise > 0.0:
            rng, g = _normal(rng)
            nz = g * noise
        raw = _sample(pos, spd, nz, init, mask, latched, nbytes, skew)
        rs = reset[i]
        md = mode[i]
        ua = u_add[i]
        if not rs and md == MODE_TASK and ua == 0:
            # the common tick, with these inputs as constants: the same calls with the same
            # values, which LLVM folds (no reset, lock or excitation paths); ~5 % faster
            axis_read(st, cb, 0, raw, False)
            code, flags, e = axis_control(st, cb, 0, ref[i], MODE_TASK, False, 0)
        else:
            axis_read(st, cb, 0, raw, rs)
            code, flags, e = axis_control(st, cb, 0, ref[i], md, rs, ua)
        volts = dac_lo + code * lsb
        _accumulate(mt, 0, k, e, flags, st[0, S_MODE], m_from, period)
        # the writes of ticks k - lag (from λ on) and k - lag - 1 (before λ); 0 V before tick 0
        if lag == 0:
            v_new = volts
            v_old = v1
        else:
            v_new = v1
            v_old = v2
        v2 = v1
        v1 = volts
        w_off = offset + load[i]
        pos, spd = advance_tick(pos, spd, v_old + w_off, v_new + w_off, row)
    _finish(mt, 0, metrics, b, 0)


@intrinsic
def _take_next(typingctx, counter):
    """Atomically increment ``counter[0]`` (int64) and return its previous value."""
    if not (
        isinstance(counter, types.Array) and counter.dtype == types.int64 and counter.ndim == 1
    ):
        return None

    def codegen(context, builder, sig, args):
        ary = make_array(sig.args[0])(context, builder, args[0])
        zero = context.get_constant(types.intp, 0)
        ptr = cgutils.get_item_pointer(context, builder, sig.args[0], ary, [zero])
        one = context.get_constant(types.int64, 1)
        return builder.atomic_rmw("add", ptr, one, "monotonic")

    return types.int64(counter), codegen


@nb.njit(cache=True, parallel=True)
def _kernel_lean(
    pf, pi, consts, seeds, ref, mode, reset, u_add, load,
    bits, latched, skew, dac_lo, lsb, m_from, period, metrics, workers,
):  # fmt: skip
    """Every candidate of a one-axis batch through :func:`_run_lean`, in parallel.

    Each of ``workers`` (the number of threads) takes the next candidate from a shared counter
    until none is left (dynamic scheduling): prange alone splits the candidates evenly in
    advance, so on a shared machine the run waits for the thread whose core is busiest. Each
    candidate writes only its own metrics row, so which thread runs it changes no result.
    ``workers`` is an argument because ``nb.get_num_threads()`` in jitted code would keep this
    function out of numba's cache.
    """
    n = pf.shape[0]
    counter = np.zeros(1, dtype=np.int64)
    for _ in nb.prange(min(workers, n)):
        b = _take_next(counter)
        while b < n:
            _run_lean(
                b, pf, pi, consts, seeds, ref, mode, reset, u_add, load,
                bits, latched, skew, dac_lo, lsb, m_from, period, metrics,
            )  # fmt: skip
            b = _take_next(counter)


_lean_works: bool | None = None
"""Whether the lean kernel compiled with this numba (None: not tried yet)."""
_LEAN_BUILD_ERRORS = (nb.core.errors.NumbaError, KeyError, AttributeError, TypeError)
"""What a numba without the internals the lean kernel uses raises when compiling it
(``_nrt`` is a private option, ``_stack_zeros`` builds an array by hand)."""


def _try_lean(batch: Batch, inputs: Inputs, metric_from_tick: int, metrics: np.ndarray) -> bool:
    """Run a one-axis metrics-only batch in the lean kernel; False if it cannot compile here.

    The lean kernel relies on numba internals; should a numba release drop them, the first
    call warns once and every batch runs in the general kernel instead (same results,
    slower). ``tests/test_engine.py`` fails on such a numba, so the fallback is not silent in CI.
    """
    global _lean_works
    if _lean_works is False:
        return False
    rig = batch.loop.rig
    args = (
        batch.pf,
        batch.pi,
        batch.consts,
        batch.seeds,
        *(np.ascontiguousarray(x[:, 0]) for x in _input_arrays(inputs)),
        *_converter_args(rig),
        int(metric_from_tick),
        float(rig.period_s),
        metrics,
        nb.get_num_threads(),
    )
    try:
        _kernel_lean(*args)
    except _LEAN_BUILD_ERRORS as exc:
        if _lean_works:  # it compiled before: a real error, not a missing internal
            raise
        _lean_works = False
        warnings.warn(
            f"servotune: the lean one-axis kernel does not compile with numba "
            f"{nb.__version__} ({type(exc).__name__}); batches run in the general kernel",
            RuntimeWarning,
            stacklevel=3,
        )
        return False
    _lean_works = True
    return True
