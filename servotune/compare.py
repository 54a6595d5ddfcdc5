"""The paper's Figure 4, done fairly, and the tracking/robustness trade-off.

:func:`compare_structures`: conventional PID, PID + the feedforward differential, and the
composite fuzzy-PID + feedforward are each tuned by the same optimiser
(:func:`~servotune.tune.slave.tune_slave`) with the same budget, search bounds, objective and
robustness limits (every loop over the plant set, :mod:`servotune.analysis.margins`), once per
seed. Each result is then measured

- on the tuning run (the nominal rig: max and RMS sync error, the start transient's rise and
  settling of the slave's speed, the objective), and
- on what the tuner never saw: :func:`~servotune.verify.verify` of the quantised tuning against
  the verification spec's *other* scenarios (other move lengths, speeds, loads) over its own
  Monte-Carlo plant draws (other plants than the tuner's corners), margins by python-control.

The table holds each metric's mean over the seeds, ``spread`` its range; whether a law wins is
read from those numbers by :func:`servotune.report.text.figure4_statement`.

:func:`pareto_front`: each structure tuned under a sweep of peak-sensitivity ceilings; tracking
(ITAE and max sync error on the tuning run) against robustness (the worst Ms over the plant set),
and which points no other point of the same structure beats on both (:func:`pareto_mask`).

A study of tunings and their verification, it sits above both :mod:`servotune.tune` and
:mod:`servotune.verify`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from servotune.errors import SpecError
from servotune.io.files import json_float
from servotune.laws.axis import AxisController
from servotune.metrics import step_info
from servotune.rig import Rig
from servotune.scenarios import sync_move_for
from servotune.sim.engine import Loop, Trace, simulate
from servotune.tune.slave import (
    STRUCTURES,
    SlaveTuneSpec,
    SlaveTuning,
    master_slave,
    tune_slave,
    tune_spec_from,
    tuning_run,
)
from servotune.tune.workflow import robust_start, rule_tables
from servotune.tuning import Tuning
from servotune.verify.run import verify
from servotune.verify.spec import Spec

__all__ = [
    "Comparison",
    "ParetoPoint",
    "StructureRun",
    "compare_structures",
    "pareto_front",
    "pareto_mask",
    "pareto_specs",
]

METRICS = (
    "itae",
    "max_sync_counts",
    "rms_sync_counts",
    "rise_s",
    "settling_s",
    "heldout_max_sync_counts",
    "heldout_rms_sync_counts",
    "heldout_pass_pct",
    "worst_ms",
)
"""Columns of :attr:`Comparison.table` (lower is better, except ``heldout_pass_pct``)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class StructureRun:
    """One structure tuned with one seed, and what it measured.

    Attributes
    ----------
    structure : str
    seed : int
    tuning : SlaveTuning
    metrics : dict of str to float
        :data:`METRICS`: on the tuning run (nominal rig) ``itae`` (the objective, mean over the
        tuner's variants) [counts·s²], ``max_sync_counts``, ``rms_sync_counts`` [counts],
        ``rise_s``, ``settling_s`` [s]; held out (the spec's other scenarios over its
        Monte-Carlo draws) ``heldout_max_sync_counts``, ``heldout_rms_sync_counts`` (worst)
        [counts], ``heldout_pass_pct`` (share of plant sets keeping every limit) [%];
        ``worst_ms``, the largest peak sensitivity of any loop over the plant set
        (python-control) [1].
    """

    structure: str
    seed: int
    tuning: SlaveTuning = field(repr=False)
    metrics: Mapping[str, float]


@dataclass(frozen=True, slots=True, kw_only=True)
class Comparison:
    """The Figure-4 comparison over one or more seeds.

    Attributes
    ----------
    seeds : tuple of int
    runs : tuple of StructureRun
        Every structure with every seed.
    traces : dict of str to Trace
        Per structure, the first seed's tuning run on the nominal rig (noise included).
    heldout : tuple of str
        Names of the held-out scenarios.
    budget : dict
        The optimiser's budget and the limits every structure was tuned under.
    """

    seeds: tuple[int, ...]
    runs: tuple[StructureRun, ...]
    traces: Mapping[str, Trace] = field(repr=False)
    heldout: tuple[str, ...]
    budget: Mapping[str, Any]

    @property
    def structures(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(r.structure for r in self.runs))

    @property
    def tunings(self) -> dict[str, SlaveTuning]:
        """Per structure, the first seed's tuning."""
        return {s: self._of(s)[0].tuning for s in self.structures}

    def _of(self, structure: str) -> list[StructureRun]:
        return [r for r in self.runs if r.structure == structure]

    @property
    def table(self) -> dict[str, dict[str, float]]:
        """Per structure, each metric's mean over the seeds."""
        return {
            s: {k: float(np.mean([r.metrics[k] for r in self._of(s)])) for k in METRICS}
            for s in self.structures
        }

    @property
    def spread(self) -> dict[str, dict[str, tuple[float, float]]]:
        """Per structure, each metric's range (min, max) over the seeds."""
        out: dict[str, dict[str, tuple[float, float]]] = {}
        for s in self.structures:
            vals = {k: [r.metrics[k] for r in self._of(s)] for k in METRICS}
            out[s] = {k: (float(np.min(v)), float(np.max(v))) for k, v in vals.items()}
        return out

    def active_constraints(self) -> dict[str, dict[str, list[str]]]:
        """Per structure: the constraints its optima sit on and the search bounds they reached
        (every seed's, without repeats)."""
        return {
            s: {
                "binding": sorted({b for r in self._of(s) for b in r.tuning.binding}),
                "at_bounds": sorted({b for r in self._of(s) for b in r.tuning.at_bounds}),
            }
            for s in self.structures
        }

    def to_dict(self) -> dict[str, Any]:
        """Plain dict: the means, ranges, every run, the active constraints, the budget."""
        return {
            "active_constraints": self.active_constraints(),
            "budget": dict(self.budget),
            "heldout_scenarios": list(self.heldout),
            "runs": [
                {
                    "metrics": {k: json_float(v) for k, v in r.metrics.items()},
                    "seed": r.seed,
                    "structure": r.structure,
                    "tuning": r.tuning.to_dict(),
                }
                for r in self.runs
            ],
            "seeds": list(self.seeds),
            "spread": {
                s: {k: [json_float(lo), json_float(hi)] for k, (lo, hi) in row.items()}
                for s, row in self.spread.items()
            },
            "table": {
                s: {k: json_float(v) for k, v in row.items()} for s, row in self.table.items()
            },
        }


def _tuning_run_row(trace: Trace, i_s: int, start: int, load_tick: int) -> dict[str, float]:
    task = trace.mode[:, i_s] == 1
    e = trace.err_counts[task, i_s].astype(float)
    # start transient: from the master's start to just before the load step
    t = trace.time_s[start:load_tick] - trace.time_s[start]
    v = trace.speed_cps[start:load_tick, i_s]
    info = step_info(t, v, y_init=0.0, y_final=float(np.mean(v[-10:])))
    return {
        "max_sync_counts": float(np.max(np.abs(e))),
        "rms_sync_counts": float(np.sqrt(np.mean(e * e))),
        "rise_s": info.rise_time_s,
        "settling_s": info.settling_time_s,
    }


def _heldout_row(tuning: Tuning, rig: Rig, spec: Spec, seed: int) -> dict[str, float]:
    v = verify(tuning, rig, spec, seed=seed)

    def worst(quantity: str) -> float:
        vals = [r.worst for r in v.rows if r.quantity == quantity]
        return float(max(vals)) if vals else float("nan")

    passed = v.variant_passed or (v.passed,)  # every plant set: the nominal and the draws
    ms = [c.value for c in v.checks if c.name.startswith("margins:")]
    return {
        "heldout_max_sync_counts": worst("max_sync_error_counts"),
        "heldout_rms_sync_counts": worst("rms_sync_error_counts"),
        "heldout_pass_pct": 100.0 * sum(passed) / len(passed),
        "worst_ms": float(max(ms)) if ms else float("nan"),
    }


def _as_tuning(rig: Rig, master_gains: Any, slave: SlaveTuning) -> Tuning:
    """The structure's law as the runtime runs it (quantised, in memory)."""
    i_m, i_s = master_slave(rig)
    gains: list[object | None] = [None] * len(rig.axes)
    gains[i_m], gains[i_s] = master_gains, slave.gains
    ctls: tuple[AxisController, ...] = Loop.from_rig(rig, gains).controllers
    return Tuning.for_rig(rig, ctls, rig_sha256="")


def compare_structures(
    rig: Rig,
    spec: Spec,
    *,
    tune: SlaveTuneSpec | None = None,
    seeds: Sequence[int] = (0,),
    heldout_count: int = 16,
    structures: Sequence[str] = STRUCTURES,
    rule_base: str = "default",
    progress: Callable[[str], None] | None = None,
) -> Comparison:
    """Tune each structure with the same optimiser, budget, bounds and limits, once per seed;
    measure it on the tuning run and on the spec's held-out scenarios.

    Parameters
    ----------
    rig : Rig
    spec : Spec
        The verification spec: its limits and plant spreads are the tuner's
        (:func:`~servotune.tune.slave.tune_spec_from`), its tuning run is the scenario the
        tuner sees, and every other scenario is held out.
    tune : SlaveTuneSpec, optional
        Tuner budget and constraints (default: from ``spec``).
    seeds : sequence of int
        Optimiser and noise seeds (the spread over seeds is reported).
    heldout_count : int
        Monte-Carlo plant draws per held-out verification.
    structures : sequence of str
        Any of :data:`~servotune.tune.slave.STRUCTURES`.

    Returns
    -------
    Comparison
    """
    say = progress or (lambda _msg: None)
    tune = tune or tune_spec_from(spec)
    _, i_s = master_slave(rig)
    start = robust_start(rig, tune)
    rig = start.rig
    tables = rule_tables(rule_base)
    scen = sync_move_for(rig, tune)
    mode = scen.inputs.mode[:, i_s]
    t0 = int(np.argmax(mode == 1))
    load_tick = int(np.argmax(scen.inputs.load_v[:, i_s] != 0.0)) or mode.size
    run = tuning_run(spec)
    held = tuple(s for s in spec.scenarios if run is None or s.name != run.name)
    held_spec = dataclasses.replace(
        spec,
        scenarios=held or spec.scenarios,
        montecarlo=dataclasses.replace(spec.montecarlo, count=heldout_count),
    )
    runs, traces = [], {}
    for seed in seeds:
        for structure in structures:
            say(f"compare: {structure}, seed {seed}")
            res = tune_slave(
                rig,
                start.master_pi.gains,
                structure=structure,
                tables=tables if structure == "composite" else None,
                start=start.slave_pi.gains,
                spec=tune,
                seed=seed,
                progress=progress,
            )
            tuning = _as_tuning(rig, start.master_pi.gains, res)
            tr = simulate(tuning.loop(rig), scen.inputs, seed=seed)
            if structure not in traces:
                traces[structure] = tr
            metrics = {
                **_tuning_run_row(tr, i_s, t0, load_tick),
                "itae": res.objective,
                **_heldout_row(tuning, rig, held_spec, seed),
            }
            runs.append(StructureRun(structure=structure, seed=seed, tuning=res, metrics=metrics))
    budget = {
        "generations": tune.generations,
        "population": tune.population,
        "limits": tune.limits.to_dict(),
        "heldout_count": heldout_count,
    }
    return Comparison(
        seeds=tuple(seeds),
        runs=tuple(runs),
        traces=traces,
        heldout=tuple(s.name for s in held),
        budget=budget,
    )


# --- the trade-off ---------------------------------------------------------------------------


def pareto_mask(*objectives: Sequence[float]) -> np.ndarray:
    """Which points no other point beats: not worse in every objective and better in one
    (every objective minimised; NaN or inf never on the front).

    >>> pareto_mask([1.0, 2.0, 3.0], [3.0, 1.0, 3.5]).tolist()
    [True, True, False]
    """
    x = np.column_stack([np.asarray(o, dtype=float) for o in objectives])
    ok = np.all(np.isfinite(x), axis=1)
    front = ok.copy()
    for i in np.flatnonzero(ok):
        other = x[ok]
        beaten = np.all(other <= x[i], axis=1) & np.any(other < x[i], axis=1)
        front[i] = not beaten.any()
    return front


@dataclass(frozen=True, slots=True, kw_only=True)
class ParetoPoint:
    """One tuning of the trade-off sweep.

    Attributes
    ----------
    structure : str
    ms_limit : float
        The peak-sensitivity ceiling it was tuned under [1].
    feasible : bool
    worst_ms : float
        Largest peak sensitivity of the slave's loops over the plant set (the tuner's screen) [1].
    itae : float
        Objective (mean ITAE of the sync error over the tuner's variants) [counts·s²].
    max_sync_counts : float
        Largest |sync error| over the tuner's variants [counts].
    front_itae, front_max : bool
        No point of the same structure has both a lower (or equal) Ms and a lower ITAE /
        max sync error.
    """

    structure: str
    ms_limit: float
    feasible: bool
    worst_ms: float
    itae: float
    max_sync_counts: float
    front_itae: bool = False
    front_max: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {
            k: json_float(v) if isinstance(v, float) else v
            for k, v in dataclasses.asdict(self).items()
        }


def pareto_specs(tune: SlaveTuneSpec, ms_limits: Sequence[float]) -> list[SlaveTuneSpec]:
    """``tune`` under each peak-sensitivity ceiling of a sweep; a ceiling the tuner refuses
    raises its :class:`~servotune.errors.SpecError` (``pareto: max_sensitivity must be …``),
    so a caller can check a sweep before the work that precedes it."""
    out = []
    for ms in ms_limits:
        try:
            out.append(dataclasses.replace(tune, max_sensitivity=float(ms)))
        except SpecError as exc:
            raise SpecError(f"pareto: {exc}") from None
    return out


def pareto_front(
    rig: Rig,
    tune: SlaveTuneSpec,
    ms_limits: Sequence[float],
    *,
    structures: Sequence[str] = STRUCTURES,
    seed: int = 0,
    rule_base: str = "default",
    progress: Callable[[str], None] | None = None,
) -> tuple[ParetoPoint, ...]:
    """Each structure tuned under each peak-sensitivity ceiling in ``ms_limits`` (the other
    limits and the budget from ``tune``); the points and their fronts.

    The fixed loops (lock gains, the master's PI) are designed once under ``tune``'s limits so
    that only the slave's law moves along the sweep.
    """
    say = progress or (lambda _msg: None)
    specs = pareto_specs(tune, ms_limits)
    start = robust_start(rig, tune)
    tables = rule_tables(rule_base)
    points: list[ParetoPoint] = []
    for structure in structures:
        mine = []
        for ms, spec in zip(ms_limits, specs, strict=True):
            say(f"pareto: {structure}, Ms <= {ms:g}")
            res = tune_slave(
                start.rig,
                start.master_pi.gains,
                structure=structure,
                tables=tables if structure == "composite" else None,
                start=start.slave_pi.gains,
                spec=spec,
                seed=seed,
            )
            w = res.worst
            nan = float("nan")
            mine.append(
                ParetoPoint(
                    structure=structure,
                    ms_limit=float(ms),
                    feasible=res.feasible,
                    worst_ms=w["max_sensitivity"],
                    itae=res.objective if res.feasible else nan,
                    max_sync_counts=w["max_sync_counts"] if res.feasible else nan,
                )
            )
        ms_v = [p.worst_ms for p in mine]
        f_itae = pareto_mask(ms_v, [p.itae for p in mine])
        f_max = pareto_mask(ms_v, [p.max_sync_counts for p in mine])
        points += [
            dataclasses.replace(p, front_itae=bool(a), front_max=bool(b))
            for p, a, b in zip(mine, f_itae, f_max, strict=True)
        ]
    return tuple(points)
