"""Verification: does a tuning meet its spec on the bit-true closed loop?

:func:`verify` runs the tuning's controllers, exactly as the runtime
runs them (the engine: :func:`~servotune.sim.engine.prepare_batch`,
:func:`~servotune.sim.engine.run_batch`), on every scenario for the nominal plants and every
Monte Carlo variant, and reports per limit the worst value, the variant it came from and the
margin. It also checks what no scenario can show by a number alone: the fastest simulated
motion against the counter's speed limits, the timer's period error, and that no runtime sum
can overflow with the tuning's constants.

The spec file is described in :mod:`servotune.verify.spec`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Literal

import numpy as np

from servotune.analysis.margins import tuning_margins
from servotune.analysis.plant_cases import plant_cases
from servotune.errors import SpecError
from servotune.executor import Executor, InProcessExecutor, chunk_bounds, guided_chunk_bounds
from servotune.kernels import warm_up
from servotune.laws.axis import MODE_TASK
from servotune.laws.shaping import shape_reference
from servotune.rig import Rig
from servotune.scenarios import Inputs
from servotune.sim.engine import (
    Loop,
    converter_args,
    input_arrays,
    prepare_batch,
    run_batch,
)
from servotune.sim.lean import CONSTS_CAPACITY
from servotune.sim.lean_sync import FIGURE_NAMES, SyncWindows, run_sync_figures
from servotune.tuning import Tuning
from servotune.validate import check_seed, show_value
from servotune.verify.checks import (
    FAULT_QUANTITY,
    Fastest,
    check_filter_attenuation,
    check_overflow,
    check_speed,
    check_timer,
)
from servotune.verify.montecarlo import PlantDistribution, SpecSpread, summarise, worst_draws
from servotune.verify.plant_sets import ChunkPlants, nominal_parameters
from servotune.verify.result import Check, Row, Verification
from servotune.verify.scenario_values import evaluate, hold_from, move_windows, scenario_inputs
from servotune.verify.spec import LIMITS, ScenarioSpec, Spec
from servotune.verify.variants import Variant, seed_seqs

__all__ = [
    "LISTED_VARIANTS",
    "verify",
]

LISTED_VARIANTS = 10_000
"""Monte-Carlo plant sets that a :class:`Verification` (and its record) lists one by one; a
bigger run lists the nominal plants and the plant sets its rows and its worst list name (the
others are redrawn from the seed by their label: :func:`~servotune.verify.plant_variants`)."""

_TRACE_BYTES = 64 * 2**20  # traces one engine batch holds at once (bounds a chunk's memory)
_CHUNK_RANGE = (256, 16384)  # plant sets per task: the last (smallest) and the first (largest)
_CHUNK_WORK = 16384 * 1200  # plant·ticks a task holds at most (the example rig's sync scenario:
# 0.6 s on one core here); a spec's longer scenarios get fewer plant sets per task, so a task
# keeps its worker's event loop (Dask's heartbeats, its 3 s unresponsiveness warning) waiting
# no longer than that, and a worker lost mid-task loses no more


# --- running the scenarios -----------------------------------------------------------------


# --- a chunk of plant sets through every scenario (one task of the executor) -----------------


@dataclass(frozen=True, slots=True, kw_only=True)
class _Shared:
    """What every chunk of a verification needs (sent to each worker once)."""

    rig: Rig
    loop: Loop
    runs: tuple[tuple[ScenarioSpec, Inputs], ...]
    distribution: PlantDistribution
    seed: int
    threads: int | None
    kernel: Literal["auto", "general"] = "auto"


@dataclass(frozen=True, slots=True, kw_only=True)
class _Chunk:
    """Plant sets ``start … stop − 1`` (0 the nominal plants, ``i`` the draw ``mc<i>``) and
    their noise stream seeds."""

    start: int
    stop: int
    noise: np.ndarray


@dataclass(frozen=True, slots=True, kw_only=True)
class _ChunkResult:
    """A chunk's findings: per limit (``figures`` order) the worst value and where (fault rows:
    how many latched and the first), per plant set whether it passed, its least relative margin,
    the limit giving it and that value, the drawn values, and per scenario the fastest motion."""

    figures: tuple[tuple[str, str, str, str, float], ...]
    worst: np.ndarray
    where: np.ndarray
    passed: np.ndarray
    margin: np.ndarray
    which: np.ndarray
    value: np.ndarray
    drawn: np.ndarray
    fastest: tuple[tuple[float, int, int, float, int, int], ...]


def _relative(v: np.ndarray, limit: float) -> np.ndarray:
    """``(limit − v) / limit`` [1]; a zero limit gives 0 if kept, ``-inf`` if not; NaN → -inf."""
    if limit > 0:
        r = (limit - v) / limit
    else:
        r = np.where(v <= limit, 0.0, -np.inf)
    return np.where(np.isnan(r), -np.inf, r)


def _chunk_plants(chunk: _Chunk, shared: _Shared) -> tuple[ChunkPlants, np.ndarray]:
    """The chunk's plant sets and drawn values: parameter rows where the distribution offers
    them (``draw_parameters``: no :class:`Plant` built per plant set), else the plants."""
    rig = shared.rig
    first_draw = max(chunk.start, 1) - 1
    draw_parameters = getattr(shared.distribution, "draw_parameters", None)
    if draw_parameters is None:
        plant_sets, drawn = shared.distribution.draw(shared.seed, first_draw, chunk.stop - 1)
        if chunk.start == 0:
            plant_sets = [tuple(a.plant for a in rig.axes), *plant_sets]
        return ChunkPlants(rig=rig, plant_sets=plant_sets), drawn
    params, drawn = draw_parameters(shared.seed, first_draw, chunk.stop - 1)
    if chunk.start == 0:
        params = np.concatenate([nominal_parameters(rig)[None], params])
    return ChunkPlants(rig=rig, params=params), drawn


def _lean_sync_ok(shared: _Shared, sc: ScenarioSpec, pi: np.ndarray) -> bool:
    """Whether a scenario runs in the lean two-axis kernel: a move (``sync``, ``track``) or a
    hold (``lock``) of a master and one slave following it, lags of at most one whole tick,
    constants that fit."""
    loop, rig = shared.loop, shared.rig
    if sc.kind not in ("sync", "track", "lock") or len(rig.axes) != 2:
        return False
    roles = [a.role for a in rig.axes]
    if sorted(roles) != ["master", "slave"]:
        return False
    i_m = roles.index("master")
    src = tuple(loop.ref_source)
    if src[i_m] != -1 or src[1 - i_m] != i_m:
        return False
    if any(a.plant.modes for a in rig.axes):  # the lean two-axis kernel runs rigid plants
        return False
    consts = _loop_consts(shared)
    return 2 * consts.shape[1] <= CONSTS_CAPACITY and bool((pi[:, :, 0] <= 1).all())


def _loop_consts(shared: _Shared) -> np.ndarray:
    """The loop's constants per axis, shape (axes, width), padded as a batch pads them."""
    rig = shared.rig
    rows = [
        c.consts(counter_bits=rig.counter.bits, dac_bits=rig.dac.bits, dac_zero=rig.dac.zero_code)
        for c in shared.loop.controllers
    ]
    out = np.zeros((len(rows), max(len(r) for r in rows)), dtype=np.int64)
    for i, r in enumerate(rows):
        out[i, : len(r)] = r
    return out


_LeanValues = tuple[dict[tuple[str, str], np.ndarray], dict[str, np.ndarray], np.ndarray]


def _run_lean_sync(
    shared: _Shared,
    sc: ScenarioSpec,
    inputs: Inputs,
    pf: np.ndarray,
    pi: np.ndarray,
    seeds: np.ndarray,
) -> _LeanValues | None:
    """:func:`_evaluate`'s values and faults of a move or a hold for every plant set, from the
    lean two-axis kernel (the same bits, no traces), and per plant set its fastest motion
    (:data:`servotune.sim.lean_sync.N_FAST`). None if a plant set's move is no step response
    :func:`~servotune.metrics.step_info` accepts (a position not finite, a zero step), where
    :func:`_evaluate` raises, or a hold's position is not finite or out of int64's range: the
    caller then runs the traced path (which raises that error, or casts as it casts)."""
    rig = shared.rig
    names = rig.axis_names
    n_t = inputs.n_ticks
    if sc.kind == "lock":  # every tick counts for the saturation share; no step, no sync
        windows = SyncWindows(
            counted=np.ones((n_t, 2), dtype=bool),
            step_from=0,
            target=0.0,
            threshold=0.0,
            has_step=np.zeros(2, dtype=bool),
            steady=(0, 0),
            hold_from=hold_from(rig, sc, inputs),
        )
    else:
        win = move_windows(rig, sc, inputs)
        task = inputs.mode == MODE_TASK
        windows = SyncWindows(
            counted=task,
            step_from=win.start,
            target=win.target,
            threshold=sc.settling_band_pct / 100.0,
            has_step=task.any(axis=0),
            steady=win.steady,
            hold_from=n_t,
        )
    has_step = windows.has_step
    figs, fast = run_sync_figures(
        pf,
        pi,
        _loop_consts(shared),
        seeds,
        np.asarray(shared.loop.ref_source, dtype=np.int64),
        input_arrays(inputs),
        converter_args(rig),
        windows,
        float(rig.period_s),
        shared.threads,
    )
    col = {nm: j for j, nm in enumerate(FIGURE_NAMES)}
    if np.isnan(figs[:, has_step, col["overshoot_pct"]]).any():
        return None
    faults = {name: figs[:, a, col["fault"]] != 0.0 for a, name in enumerate(names)}
    values: dict[tuple[str, str], np.ndarray] = {}
    if sc.kind == "lock":
        if np.isnan(figs[:, :, col["holding_band_counts"]]).any():
            return None
        for a, name in enumerate(names):
            for q in ("holding_band_counts", "saturation_pct"):
                values[(q, name)] = figs[:, a, col[q]]
        return values, faults, fast
    for a, name in enumerate(names):
        if not has_step[a]:
            continue
        for q in ("overshoot_pct", "settling_time_s", "saturation_pct"):
            values[(q, name)] = figs[:, a, col[q]]
        if rig.axes[a].role == "slave":
            for q in ("max_sync_error_counts", "rms_sync_error_counts", "steady_lag_counts"):
                values[(q, name)] = figs[:, a, col[q]]
    return values, faults, fast


def _judge(
    sc: ScenarioSpec,
    names: Sequence[str],
    values: dict[tuple[str, str], np.ndarray],
    faults: dict[str, np.ndarray],
    start: int,
    figures: list[tuple[str, str, str, str, float]],
    worst: list[float],
    where: list[int],
    passed: np.ndarray,
    margin: np.ndarray,
    which: np.ndarray,
    value: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A scenario's values and faults of a chunk against its limits: appends each limit's row
    (``figures``, the worst value, where) and returns the plant sets' updated pass flags, least
    relative margins, the limit giving each and its value."""
    for key, lim in sc.limits.items():
        quantity, unit = LIMITS[key]
        for name in names:
            if (quantity, name) not in values:
                continue
            v = values[(quantity, name)]
            w = np.where(np.isnan(v), np.inf, v)  # NaN counts as the largest
            i = int(np.argmax(w))
            figures.append((sc.name, quantity, name, unit, float(lim)))
            worst.append(float(w[i]))
            where.append(start + i)
            passed &= v <= lim
            rel = _relative(v, float(lim))
            better = rel < margin
            margin = np.where(better, rel, margin)
            which = np.where(better, len(figures) - 1, which)
            value = np.where(better, v, value)
    for name in names:
        faulted = faults[name]
        figures.append((sc.name, FAULT_QUANTITY, name, "runs", 0.0))
        worst.append(float(faulted.sum()))
        where.append(start + int(np.argmax(faulted)) if faulted.any() else -1)
        passed &= ~faulted
        better = faulted & (margin > -np.inf)
        margin = np.where(better, -np.inf, margin)
        which = np.where(better, len(figures) - 1, which)
        value = np.where(better, 1.0, value)
    return passed, margin, which, value


_Fastest = tuple[float, int, int, float, int, int]
"""A scenario's fastest motion in a chunk: the largest step per tick [counts], its plant set
and axis, the largest speed [counts/s], its plant set and axis (plant set -1: none)."""


def _lean_fastest(fast: np.ndarray, start: int) -> _Fastest:
    """The fastest motion from the lean kernel's per-plant-set figures (``N_FAST`` columns)."""
    step_best = (0.0, -1, -1)
    speed_best = (0.0, -1, -1)
    if fast.shape[0]:
        b = int(np.argmax(fast[:, 0]))
        if fast[b, 0] > 0.0:
            step_best = (float(fast[b, 0]), start + b, int(fast[b, 2]))
        b = int(np.argmax(fast[:, 3]))
        if fast[b, 3] > 0.0:
            speed_best = (float(fast[b, 3]), start + b, int(fast[b, 5]))
    return (*step_best, *speed_best)


def _run_traced(
    chunk: _Chunk, shared: _Shared, sc: ScenarioSpec, inputs: Inputs, plant_sets: list
) -> tuple[dict[tuple[str, str], np.ndarray], dict[str, np.ndarray], _Fastest]:
    """A scenario for the chunk's plant sets in the general kernel, traced (batches bounded by
    ``_TRACE_BYTES``): the figures, the faults and the fastest motion."""
    rig, n = shared.rig, chunk.stop - chunk.start
    per_batch = max(1, _TRACE_BYTES // (inputs.n_ticks * len(rig.axes) * 72))
    parts = []
    step_best = (0.0, -1, -1)
    speed_best = (0.0, -1, -1)
    for k in range(0, n, per_batch):
        hi = min(n, k + per_batch)
        batch = prepare_batch(
            shared.loop, plants=plant_sets[k:hi], seeds=[int(x) for x in chunk.noise[k:hi]]
        )
        res = run_batch(batch, inputs, metrics_only=False, threads=shared.threads)
        assert res.traces is not None
        tr = res.traces
        traces = {
            "counter": tr.counter,
            "pos_counts": tr.pos_counts,
            "err_counts": tr.err_counts,
            "flags": tr.flags,
            "true_pos_counts": tr.true_pos_counts,
        }
        parts.append(evaluate(rig, sc, inputs, traces))
        # the first largest motion per tick and speed in (plant set, tick, axis) order
        step = np.abs(np.diff(tr.true_pos_counts, axis=1))
        if step.size and step.max() > step_best[0]:
            b, _, a = np.unravel_index(int(np.argmax(step)), step.shape)
            step_best = (float(step.max()), chunk.start + k + int(b), int(a))
        spd = np.abs(tr.speed_cps)
        if spd.max() > speed_best[0]:
            b, _, a = np.unravel_index(int(np.argmax(spd)), spd.shape)
            speed_best = (float(spd.max()), chunk.start + k + int(b), int(a))
    values = {key: np.concatenate([v[key] for v, _ in parts]) for key in parts[0][0]}
    faults = {nm: np.concatenate([f[nm] for _, f in parts]) for nm in parts[0][1]}
    return values, faults, (*step_best, *speed_best)


def _run_chunk(chunk: _Chunk, shared: _Shared) -> _ChunkResult:
    """Every scenario for the plant sets of ``chunk`` (the executor's task)."""
    names = shared.rig.axis_names
    chunk_plants, drawn = _chunk_plants(chunk, shared)
    n = chunk.stop - chunk.start
    figures: list[tuple[str, str, str, str, float]] = []
    worst: list[float] = []
    where: list[int] = []
    passed = np.ones(n, dtype=bool)
    margin = np.full(n, np.inf)
    which = np.zeros(n, dtype=np.int64)
    value = np.full(n, np.nan)
    fastest = []
    # the lean two-axis kernel runs rigid plants: a resonant rig's rows are not built for it
    lean_ok = shared.kernel == "auto" and not any(a.plant.modes for a in shared.rig.axes)
    for sc, inputs in shared.runs:
        lean = None
        if lean_ok and _lean_sync_ok(shared, sc, chunk_plants.rows()[1]):
            pf, pi = chunk_plants.rows()
            seeds = np.asarray(chunk.noise, dtype=np.uint64)
            lean = _run_lean_sync(shared, sc, inputs, pf, pi, seeds)
        if lean is not None:
            values, faults, fast = lean
            fastest.append(_lean_fastest(fast, chunk.start))
        else:
            values, faults, fast_t = _run_traced(chunk, shared, sc, inputs, chunk_plants.plants())
            fastest.append(fast_t)
        passed, margin, which, value = _judge(
            sc,
            names,
            values,
            faults,
            chunk.start,
            figures,
            worst,
            where,
            passed,
            margin,
            which,
            value,
        )
    return _ChunkResult(
        figures=tuple(figures),
        worst=np.asarray(worst),
        where=np.asarray(where, dtype=np.int64),
        passed=passed,
        margin=margin,
        which=which,
        value=value,
        drawn=drawn,
        fastest=tuple(fastest),
    )


def _label(index: int) -> str:
    """The label of plant set ``index`` (0 the nominal plants)."""
    return "nominal" if index == 0 else f"mc{index}"


def _reduce_rows(parts: Sequence[_ChunkResult]) -> tuple[list[Row], set[int]]:
    """Each limit's worst value over every chunk, in chunk order (the first worst wins), and
    the Monte-Carlo plant sets (1-based draw index) the rows name."""
    rows = []
    named = set()
    for j, (scenario, quantity, axis, unit, limit) in enumerate(parts[0].figures):
        if quantity == FAULT_QUANTITY:
            count = sum(float(p.worst[j]) for p in parts)
            firsts = [int(p.where[j]) for p in parts if p.where[j] >= 0]
            worst, at = count, (firsts[0] if firsts else 0)
        else:
            worst, at = parts[0].worst[j], int(parts[0].where[j])
            for p in parts[1:]:
                if p.worst[j] > worst:
                    worst, at = p.worst[j], int(p.where[j])
        rows.append(
            Row(
                scenario=scenario,
                quantity=quantity,
                axis=axis,
                unit=unit,
                limit=limit,
                worst=float(worst),
                variant=_label(at),
            )
        )
        if at > 0:
            named.add(at)
    return rows, named


def _reduce_fastest(
    rig: Rig, runs: Sequence[tuple[ScenarioSpec, Inputs]], parts: Sequence[_ChunkResult]
) -> Fastest:
    """The largest motion per tick and speed over every scenario and chunk, and where: the
    first in (scenario, plant set, tick, axis) order."""
    fastest = Fastest()
    for s, (sc, _) in enumerate(runs):
        for p in parts:
            step, b_t, a_t, speed, b_s, a_s = p.fastest[s]
            if step > fastest.counts_per_tick:
                fastest.counts_per_tick = step
                fastest.where_tick = f"{sc.name}, {rig.axes[a_t].name}, {_label(b_t)}"
            if speed > fastest.speed_cps:
                fastest.speed_cps = speed
                fastest.where_speed = f"{sc.name}, {rig.axes[a_s].name}, {_label(b_s)}"
    return fastest


def _listed_variants(
    rig: Rig, distribution: PlantDistribution, seed: int, count: int, named: set[int]
) -> tuple[Variant, ...]:
    """The nominal plants and every draw (up to :data:`LISTED_VARIANTS`), else the draws in
    ``named`` (indices ≥ 1), redrawn by index."""
    nominal = Variant(label="nominal", plants=tuple(a.plant for a in rig.axes))
    if count <= LISTED_VARIANTS:
        plants, _ = distribution.draw(seed, 0, count)
        return (nominal, *(Variant(label=_label(i + 1), plants=p) for i, p in enumerate(plants)))
    out = [nominal]
    for i in sorted(x for x in named if x >= 1):
        (p,), _ = distribution.draw(seed, i - 1, i)
        out.append(Variant(label=_label(i), plants=p))
    return tuple(out)


def check_margins(
    tuning: Tuning, rig: Rig, spec: Spec, distribution: PlantDistribution | None = None
) -> list[Check]:
    """One check per axis and loop kind (``margins:<axis>:<lock|task>``): every loop of that
    kind (every query-table cell of a scheduled law) keeps the spec's margin limits on the
    nominal plants and over the plant set (:func:`~servotune.analysis.plant_cases.plant_cases`: the
    corners of the identified intervals and of the spec's Monte-Carlo gain and tau spreads,
    and the Monte-Carlo ``distribution``'s own plant sets (a fleet's machines), each also
    ``margins.extra_ticks`` ticks late, at the period ± the timer's error limit; and
    ``margins.samples`` plant sets drawn inside that box).

    The check's value is the worst Ms [1]; its detail names the worst loop (the cell), the
    plant case and the limits it breaks. Every loop on every case is screened on a grid; the
    worst ones (by Ms, phase and gain margin) are judged by python-control.
    """
    mc = spec.montecarlo
    measured = () if distribution is None else distribution.margin_plant_sets
    cases = plant_cases(
        rig,
        gain_spread=mc.gain_spread,
        tau_spread=mc.tau_spread,
        extra_ticks=spec.margin_extra_ticks,
        period_error_ppm=spec.max_period_error_ppm or 0.0,
        samples=spec.margin_samples,
        seed=mc.seed,
        measured=measured,
    )
    m = tuning_margins(tuning, rig, limits=spec.margins, cases=cases, every_loop=False)
    lim = spec.margins
    out = []
    for name in tuning.axis_names:
        for kind in ("lock", "task"):
            loops = list(m.select(name, kind))
            if not loops:
                continue
            bad = [(x, lim.broken(x)) for x in loops if lim.broken(x)]
            worst, broken = bad[0] if bad else (m.worst(name, kind), ())
            if bad:
                worst, broken = min(bad, key=lambda xb: (xb[0].stable, -xb[0].max_sensitivity))
            figures = (
                f"PM {worst.phase_margin_deg:.1f}°, GM {worst.gain_margin_db:.1f} dB, "
                f"Ms {worst.max_sensitivity:.2f}"
            )
            if broken:
                detail = (
                    f"{worst.name} on plant {worst.plant}: {'; '.join(broken)} "
                    f"({len(bad)} of {len(loops)} loop cases break a limit)"
                )
            else:
                detail = f"worst {worst.name} on plant {worst.plant}: {figures}"
            out.append(
                Check(
                    name=f"margins:{name}:{kind}",
                    passed=not broken,
                    value=worst.max_sensitivity,
                    limit=lim.max_sensitivity,
                    unit="1",
                    detail=detail,
                    facts=worst.to_dict(),
                )
            )
    return out


def _check_sync_limits(rig: Rig, spec: Spec) -> None:
    """A spec's sync limits need a slave axis: SpecError naming the first if the rig has none."""
    sync_limits = ("max_sync_error_counts", "max_rms_sync_error_counts", "max_steady_lag_counts")
    if not any(a.role == "slave" for a in rig.axes):
        for sc in spec.scenarios:
            for k in sc.limits:
                if k in sync_limits:
                    raise SpecError(
                        f"scenario.{sc.name}.{k} needs a slave axis; rig "
                        f"{show_value(rig.name)} has none"
                    )


def _scenario_runs(
    rig: Rig, spec: Spec, tuning: Tuning, say: Callable[[str], None]
) -> list[tuple[ScenarioSpec, Inputs]]:
    """Each scenario with its inputs; a scenario that cannot be built or measured fails here,
    before any run. A master whose controller has a reference shaper gets its moves shaped
    as the runtime shapes them (docs/runtime.md#shapers-in-the-tables), which ``say`` tells."""
    for a, ctl in enumerate(tuning.controllers):
        if ctl.shaper and rig.axes[a].role == "master":
            added = (len(ctl.shaper) - 1) * rig.period_s
            say(
                f"verify: {rig.axis_names[a]}'s moves shaped by its {len(ctl.shaper)}-tap "
                f"reference shaper (+{1000 * added:.1f} ms)"
            )
    runs = []
    for sc in spec.scenarios:
        try:
            inputs = scenario_inputs(rig, sc)
        except SpecError as exc:
            raise SpecError(f"scenario.{sc.name}: {exc}") from None
        for a, ctl in enumerate(tuning.controllers):
            if ctl.shaper and rig.axes[a].role == "master" and sc.kind != "lock":
                shaped = shape_reference(inputs.ref_counts[:, a], ctl.shaper)
                inputs = inputs.replace_axis(a, ref_counts=shaped)
        if sc.kind == "lock":
            hold_from(rig, sc, inputs)
        else:
            move_windows(rig, sc, inputs)
        runs.append((sc, inputs))
    return runs


def _chunks(
    rig: Rig,
    runs: Sequence[tuple[ScenarioSpec, Inputs]],
    n_sets: int,
    ex: Executor,
    chunk_size: int | None,
    seed: int,
) -> list[_Chunk]:
    """The executor's tasks: ``n_sets`` plant sets in chunks (guided by the work per plant set
    unless ``chunk_size`` is given), each with its plant sets' noise seeds."""
    if chunk_size is None:
        smallest, largest = _CHUNK_RANGE
        per_set = len(rig.axes) * sum(inputs.n_ticks for _, inputs in runs)  # plant·ticks
        largest = max(smallest, min(largest, _CHUNK_WORK // max(per_set, 1)))
        bounds = guided_chunk_bounds(n_sets, ex.workers, smallest=smallest, largest=largest)
    else:
        bounds = chunk_bounds(n_sets, chunk_size)
    noise = seed_seqs(seed)[1].generate_state(n_sets, np.uint64)
    return [_Chunk(start=a, stop=b, noise=noise[a:b]) for a, b in bounds]


def verify(
    tuning: Tuning,
    rig: Rig,
    spec: Spec,
    *,
    seed: int | None = None,
    progress: Callable[[str], None] | None = None,
    executor: Executor | None = None,
    distribution: PlantDistribution | None = None,
    chunk_size: int | None = None,
    kernel: Literal["auto", "general"] = "auto",
) -> Verification:
    """Verify a tuning against a spec on the bit-true closed loop.

    Every scenario runs for the nominal plants and every Monte Carlo plant set (``count`` draws
    from ``distribution``, by default the spec's spread: :func:`plant_variants`), each with its
    own noise stream, through the engine with the tuning's quantised constants (nothing is
    re-quantised). The plant sets run in chunks, each chunk through every scenario as one task
    of ``executor`` (in-process, or a Dask cluster: :mod:`servotune.executor`); the chunks'
    findings are reduced in chunk order, and every draw and noise stream is keyed by the seed
    and the plant set's index, so the result is the same whatever the chunk size and the
    executor. Then the checks: the fastest motion against the counter's limits
    (:func:`check_speed`), the timer period (:func:`check_timer`) and the overflow bound
    (:func:`check_overflow`; if it fails the runs are skipped, since the runtime arithmetic is
    not defined for such constants), and the margins of every loop the runtime can run over
    the plant set (:func:`check_margins`). The Monte-Carlo plant sets are summarised
    (:attr:`Verification.montecarlo`: the pass fraction with its exact interval, the plant sets
    with the least margin and the sensitivity table, :mod:`servotune.verify.montecarlo`).

    Parameters
    ----------
    tuning : Tuning
    rig : Rig
        The rig to verify on (its axes and period must match the tuning's).
    spec : Spec
        Its ``montecarlo.count`` is the number of draws.
    seed : int, optional
        Seeds the variants and the noise; default ``spec.montecarlo.seed``. Same inputs and
        seed give the same result.
    progress : callable, optional
        Receives one line per step (the CLI prints them on stderr).
    executor : Executor, optional
        Where the chunks run (default in-process;
        :func:`servotune.executor.open_executor` chooses by size).
    distribution : PlantDistribution, optional
        Where the plant sets come from (default :class:`~servotune.verify.montecarlo.SpecSpread`
        of the spec's ``[montecarlo]`` table).
    chunk_size : int, optional
        Plant sets per task (default: chunks shrinking from large to small, each a quarter
        of an even share of what is left per worker, from 256 up to 16384 or fewer, at most
        about 2e7 plant·ticks a task: :func:`~servotune.executor.guided_chunk_bounds`);
        changes the run's granularity, never its result.
    kernel : {"auto", "general"}
        Which compiled kernel runs the scenarios: ``"auto"`` runs a master and one slave
        following it in the lean two-axis kernel (no traces; each scenario it cannot take,
        and every other rig, in the general one), ``"general"`` runs every scenario in the
        general, traced kernel. Both give the same result, bit for bit; ``"general"`` is
        slower and exists to check that.

    Returns
    -------
    Verification

    Raises
    ------
    TuningError
        If the tuning does not belong to the rig (axes, period).
    SpecError
        If the spec names another rig, an axis the rig lacks, or a scenario cannot be built.
    ValueError
        If ``kernel`` is neither ``"auto"`` nor ``"general"``.
    """
    if kernel not in ("auto", "general"):
        raise ValueError(f"kernel must be 'auto' or 'general', got {kernel!r}")
    say = progress or (lambda _msg: None)
    if spec.rig is not None and spec.rig != rig.name:
        raise SpecError(
            f"spec {show_value(spec.name)} is written for rig {show_value(spec.rig)}, not "
            f"{show_value(rig.name)}"
        )
    loop = tuning.loop(rig)
    _check_sync_limits(rig, spec)
    used_seed = spec.montecarlo.seed if seed is None else check_seed(seed)
    dist = SpecSpread(rig=rig, montecarlo=spec.montecarlo) if distribution is None else distribution
    dist.draw(used_seed, 0, 0)  # a distribution that cannot draw for this rig fails first
    count = spec.montecarlo.count
    overflow = check_overflow(tuning, rig)
    checks: list[Check] = [overflow, check_timer(rig, spec.max_period_error_ppm)]
    if not overflow.passed:
        say("verify: constants break the overflow bound; closed-loop runs skipped")
        return Verification(
            spec=spec,
            rig_name=rig.name,
            axis_names=rig.axis_names,
            seed=used_seed,
            rows=(),
            checks=tuple(checks),
            variants=_listed_variants(rig, dist, used_seed, count, set()),
        )
    runs = _scenario_runs(rig, spec, tuning, say)
    ex = InProcessExecutor() if executor is None else executor
    n_sets = count + 1
    chunks = _chunks(rig, runs, n_sets, ex, chunk_size, used_seed)
    shared = _Shared(
        rig=rig,
        loop=loop,
        runs=tuple(runs),
        distribution=dist,
        seed=used_seed,
        threads=ex.threads_per_task,
        kernel=kernel,
    )
    for sc, _ in runs:
        say(f"verify: scenario {sc.name} ({sc.kind}, {sc.seconds:g} s), {n_sets:,} plant sets")
    say(
        f"verify: the nominal plants and {count:,} plant sets from the {dist.name} in "
        f"{len(chunks)} chunks on {ex.name}"
    )

    def done(k: int) -> None:
        say(f"verify montecarlo: {k}/{len(chunks)} chunks")

    # the kernels compile first, if the cache lacks them, with their progress lines: here once,
    # not in every worker of a cluster, and not beside the margins thread (compiled beside it,
    # the two-axis kernel took 152 s on 2 cores, against about 50 s alone); a two-axis master
    # and slave runs in the lean two-axis kernel (unless kernel="general"), anything else in
    # the general one
    two_axis = kernel == "auto" and sorted(a.role for a in rig.axes) == ["master", "slave"]
    two_axis = two_axis and not any(a.plant.modes for a in rig.axes)  # lean two-axis: rigid
    warm_up(("margins", "verification" if two_axis else "simulation"), progress=progress)
    # the loop margins depend on neither the runs nor their plant sets: a thread computes them
    # while the chunks run (the caller only waits on the executor then)
    with ThreadPoolExecutor(max_workers=1) as pool:
        margins = pool.submit(check_margins, tuning, rig, spec, dist)
        parts = ex.map(_run_chunk, chunks, shared=shared, done=done)
        rows, named = _reduce_rows(parts)
        fastest = _reduce_fastest(rig, runs, parts)
        checks[:0] = check_speed(
            rig,
            fastest.counts_per_tick,
            fastest.speed_cps,
            where_tick=fastest.where_tick,
            where_speed=fastest.where_speed,
        )
        say("verify: margins of every loop over the plant set")
        checks += margins.result()
        checks += check_filter_attenuation(tuning, rig, spec)
    passed = np.concatenate([p.passed for p in parts])
    summary = None
    if count:
        cat = {
            f: np.concatenate([getattr(p, f) for p in parts])[1:]
            for f in ("margin", "which", "value")
        }
        summary = summarise(
            distribution=dist,
            values=np.concatenate([p.drawn for p in parts]),
            passed=passed[1:],
            margin=cat["margin"],
            figures=parts[0].figures,
            which=cat["which"],
            figure_values=cat["value"],
        )
        named |= {int(i) + 1 for i in worst_draws(cat["margin"])}
    result = Verification(
        spec=spec,
        rig_name=rig.name,
        axis_names=rig.axis_names,
        seed=used_seed,
        variants=_listed_variants(rig, dist, used_seed, count, named),
        rows=tuple(rows),
        checks=tuple(checks),
        variant_passed=tuple(passed.tolist()),
        montecarlo=summary,
    )
    say(f"verify: {'PASSED' if result.passed else 'FAILED'}")
    return result
