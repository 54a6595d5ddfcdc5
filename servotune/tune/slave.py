"""Slave-axis tuning: composite fuzzy-PID + feedforward by optimisation over batched runs.

The slave follows the master (its reference is the master's position read in the same tick).
Its law's parameters are tuned by differential evolution
(:func:`scipy.optimize.differential_evolution`, vectorised: one generation is one batch of the
engine) on the :func:`~servotune.scenarios.sync_move` run (master start, constant speed, stop;
a load step on the slave) over plant variants of the slave (gain ±20 %, tau ±30 %: the nominal
and the four corners). Every candidate runs in the runtime's integer arithmetic, so what is
tuned is what runs.

Objective: the mean over variants of the ITAE of the sync error (master − slave) [counts·s²].
Constraints, on every variant: no fault (following-error trip), D/A saturation at most
``max_saturation_pct`` of the task ticks, overshoot of the sync error (its largest swing past
zero, the slave ahead of the master, as a share of its largest lag) at most
``max_overshoot_pct``; and robustness, on every loop the law can switch to (every query-table
cell's frozen gains) over the variants, each also with one extra tick of latency:
phase margin, gain margin and peak sensitivity within ``min_phase_margin_deg``,
``min_gain_margin_db``, ``max_sensitivity`` (screened on a frequency grid,
:func:`servotune.analysis.margins.grid_margins`; the tuning's verdict is python-control's, see
:func:`servotune.analysis.margins.tuning_margins`). A candidate that breaks a constraint ranks
behind every one that keeps them, by how much it breaks them.

Three structures share the optimiser and its budget (the paper's Figure 4 comparison):
``pid`` (conventional PID: zero tables, no feedforward), ``pid_ff`` (PID + the feedforward
differential) and ``composite`` (fuzzy-PID + feedforward: the query tables scaled by tuned output
scales, the level scalings ``Ke``, ``Kec`` tuned too).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from scipy.optimize import differential_evolution
from scipy.stats import qmc

from servotune.analysis.margins import DEFAULT_LIMITS, MarginLimits
from servotune.analysis.plant_cases import PlantCase, plant_cases
from servotune.budget import check_memory, format_count
from servotune.errors import SpecError
from servotune.io.files import json_float
from servotune.laws.axis import AxisController
from servotune.laws.fuzzy_pid import TABLE_NAMES, FuzzyPIDConstants, FuzzyPIDGains
from servotune.laws.pi import PIGains
from servotune.plant import Plant
from servotune.rig import Rig
from servotune.scenarios import Scenario, sync_move_for
from servotune.sim.engine import Loop, prepare_batch, run_batch
from servotune.tune.robust import MarginScreen, design_limits
from servotune.validate import check_integer, check_number

__all__ = [
    "STRUCTURES",
    "SlaveTuneSpec",
    "SlaveTuning",
    "corner_plants",
    "ideal_feedforward",
    "tune_slave",
    "tune_spec_from",
    "tuning_run",
]

STRUCTURES = ("pid", "pid_ff", "composite")
"""Slave law structures the tuner can tune."""

_BIG = 1.0e12  # objective of a candidate that breaks a constraint, before its violation


@dataclass(frozen=True, slots=True, kw_only=True)
class SlaveTuneSpec:
    """What the slave tuner optimises and under which constraints.

    Parameters
    ----------
    max_saturation_pct : float
        Largest share of task ticks with the D/A on a rail, on any variant [%].
    max_overshoot_pct : float
        Largest lead of the slave over the master (sync error opposite to the motion) as a share
        of the largest lag, on any variant [%]. Default 100: the slave may lead by as much as
        it lags (a gantry's skew is the same either way; the spec bounds |sync error|). A
        tighter bound costs tracking once the margins are held (a lower integral gain).
    gain_spread : float
        Relative spread of the slave's gain in the variants (0.2: ±20 %).
    tau_spread : float
        Relative spread of the slave's time constant (0.3: ±30 %).
    seconds : float
        Length of the tuning run [s].
    speed_fraction : float
        Master cruise speed as a fraction of its speed limit.
    accel_s : float
        Master acceleration time [s].
    load_step_v : float
        Load step on the slave [V] (negative: opposing the motion, as a cutting force).
    population : int
        Candidates per generation.
    generations : int
        Generations of differential evolution after the initial population (the budget).
    min_phase_margin_deg, min_gain_margin_db, max_sensitivity : float
        Robustness limits of every loop (every cell of the slave's law, the master's PI, the
        lock loops) over the plant set [deg], [dB], [1] (defaults:
        :data:`servotune.analysis.margins.DEFAULT_LIMITS`).
    extra_ticks : int
        Latency the loops must also take [ticks], 0..10.
    period_error_ppm : float
        The timer's period error the loops must also take [ppm].
    margin_samples : int
        Plant sets drawn inside the plant set's box that the finished tuning's margins are
        also confirmed on (the tuner's screen takes the corners).
    """

    max_saturation_pct: float = 2.0
    max_overshoot_pct: float = 100.0
    gain_spread: float = 0.2
    tau_spread: float = 0.3
    seconds: float = 2.4
    speed_fraction: float = 0.5
    accel_s: float = 0.1
    load_step_v: float = -0.3
    population: int = 32
    generations: int = 40
    min_phase_margin_deg: float = DEFAULT_LIMITS.min_phase_margin_deg
    min_gain_margin_db: float = DEFAULT_LIMITS.min_gain_margin_db
    max_sensitivity: float = DEFAULT_LIMITS.max_sensitivity
    extra_ticks: int = 1
    period_error_ppm: float = 100.0
    margin_samples: int = 32

    def __post_init__(self) -> None:
        e = SpecError
        check_number("max_saturation_pct", self.max_saturation_pct, "%", hi=100.0, error=e)
        check_number("max_overshoot_pct", self.max_overshoot_pct, "%", error=e)
        check_number("gain_spread", self.gain_spread, "1", hi=0.9, error=e)
        check_number("tau_spread", self.tau_spread, "1", hi=0.9, error=e)
        check_number("seconds", self.seconds, "s", strict=True, error=e)
        check_integer("population", self.population, "candidates", lo=5, error=e)
        check_integer("generations", self.generations, "generations", error=e)
        check_integer("extra_ticks", self.extra_ticks, "ticks", hi=10, error=e)
        check_integer("margin_samples", self.margin_samples, "plant sets", hi=10_000, error=e)
        check_number("period_error_ppm", self.period_error_ppm, "ppm", hi=1e4, error=e)
        self.limits  # noqa: B018 (validates the three limits)

    def plant_cases(
        self, rig: Rig, *, seed: int = 0, sampled: bool = False
    ) -> tuple[PlantCase, ...]:
        """The plant set the margin limits hold over
        (:func:`~servotune.analysis.plant_cases.plant_cases` of these spreads, latency and timer
        error; with ``sampled``, also ``margin_samples`` plant sets drawn inside it from
        ``seed``)."""
        return plant_cases(
            rig,
            gain_spread=self.gain_spread,
            tau_spread=self.tau_spread,
            extra_ticks=self.extra_ticks,
            period_error_ppm=self.period_error_ppm,
            samples=self.margin_samples if sampled else 0,
            seed=seed,
        )

    @property
    def limits(self) -> MarginLimits:
        """The robustness limits as a :class:`~servotune.analysis.margins.MarginLimits`."""
        return MarginLimits.of(self)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return dataclasses.asdict(self)


def tuning_run(spec: Any) -> Any:
    """The scenario of a verification spec the slave is tuned on: the one named ``sync``, else
    the first sync scenario, else None (the tuner's default run). Every other scenario of the
    spec is held out from tuning."""
    syncs = [s for s in spec.scenarios if s.kind == "sync"]
    return next((s for s in syncs if s.name == "sync"), syncs[0] if syncs else None)


def tune_spec_from(spec: Any = None, *, rig: Rig | None = None, **overrides: Any) -> SlaveTuneSpec:
    """The slave tuner's spec that designs for what a verification spec checks.

    From ``spec`` (a :class:`servotune.verify.spec.Spec`; None: the defaults): the margin
    limits and their extra latency (``[margins]``), the timer's period error (``[timer]
    max_period_error_ppm``), the plant spreads (``[montecarlo]`` gain and tau spreads), and the
    tuning run from the scenario named ``sync`` (else the first sync scenario): its length,
    speed, acceleration, load step and saturation limit. The spec's other scenarios are not
    tuned on: they stay held out. ``overrides`` (the budget, or a limit given on the command
    line) win.

    Raises
    ------
    SpecError
        An override that is not a field of :class:`SlaveTuneSpec`, an invalid value, or a spec
        written for another rig than ``rig`` (where both name one).
    """
    if spec is not None and rig is not None and spec.rig is not None and spec.rig != rig.name:
        raise SpecError(f"spec {spec.name!r} is written for rig {spec.rig!r}, not {rig.name!r}")
    unknown = set(overrides) - {f.name for f in dataclasses.fields(SlaveTuneSpec)}
    if unknown:
        raise SpecError(f"unknown tuning option(s): {', '.join(sorted(unknown))}")
    if spec is None:
        return SlaveTuneSpec(**overrides)
    kw: dict[str, Any] = {
        "min_phase_margin_deg": spec.margins.min_phase_margin_deg,
        "min_gain_margin_db": spec.margins.min_gain_margin_db,
        "max_sensitivity": spec.margins.max_sensitivity,
        "extra_ticks": spec.margin_extra_ticks,
        "margin_samples": spec.margin_samples,
        "gain_spread": spec.montecarlo.gain_spread,
        "tau_spread": spec.montecarlo.tau_spread,
    }
    if spec.max_period_error_ppm is not None:
        kw["period_error_ppm"] = spec.max_period_error_ppm
    run = tuning_run(spec)
    if run is not None:
        kw.update(
            speed_fraction=run.speed_fraction, accel_s=run.accel_s, load_step_v=run.load_step_v
        )
        if run.seconds is not None:
            kw["seconds"] = run.seconds
        if run.max_saturation_pct is not None:
            kw["max_saturation_pct"] = run.max_saturation_pct
    kw.update(overrides)
    return SlaveTuneSpec(**kw)


@dataclass(frozen=True, slots=True, kw_only=True)
class SlaveTuning:
    """Result of :func:`tune_slave` (fitted quantities).

    Attributes
    ----------
    structure : str
    gains : FuzzyPIDGains
        The tuned law in design units (quantise with the rig's period to run it).
    objective : float
        Mean ITAE of the sync error over the variants [counts·s²] (``inf`` if infeasible).
    start_objective : float
        The same for the start point (whether or not it keeps the constraints).
    start_feasible : bool
        The start point keeps the constraints.
    feasible : bool
        All constraints hold on every variant.
    evaluations : int
        Candidate evaluations (each over every variant).
    history : tuple of float
        Best objective after the initial population and each generation.
    worst : dict
        Worst case over the variants of the tuning run: ``saturation_pct``, ``overshoot_pct``,
        ``fault`` (1 if any variant trips), the margins over the plant set
        (``phase_margin_deg``, ``gain_margin_db``, ``max_sensitivity``: the grid screen's) and
        the sync error over the task ticks (``max_sync_counts``, ``rms_sync_counts``).
    at_bounds : tuple of str
        Search parameters whose optimum lies at a bound of the search space (within 0.5 % of
        its range): there the bound, not the problem, decided.
    binding : tuple of str
        Constraints the optimum sits on (within 2 % of the limit, or 0.5° of phase margin).
    """

    structure: str
    gains: FuzzyPIDGains
    objective: float
    start_objective: float
    start_feasible: bool
    feasible: bool
    evaluations: int
    history: tuple[float, ...] = field(repr=False)
    worst: Mapping[str, float] = field(default_factory=dict)
    at_bounds: tuple[str, ...] = ()
    binding: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (``inf`` as None)."""
        return {
            "at_bounds": list(self.at_bounds),
            "binding": list(self.binding),
            "evaluations": self.evaluations,
            "feasible": self.feasible,
            "gains": self.gains.to_dict(),
            "history": [json_float(h) for h in self.history],
            "objective": json_float(self.objective),
            "start_feasible": self.start_feasible,
            "start_objective": json_float(self.start_objective),
            "structure": self.structure,
            "worst": {k: float(v) for k, v in sorted(self.worst.items())},
        }


def master_slave(rig: Rig) -> tuple[int, int]:
    """Indices of the rig's master and slave axes.

    Raises
    ------
    SpecError
        The rig has no master or no slave axis.
    """
    roles = [a.role for a in rig.axes]
    if "master" not in roles or "slave" not in roles:
        raise SpecError(f"rig {rig.name!r} needs a master and a slave axis, has roles {roles}")
    return roles.index("master"), roles.index("slave")


def ideal_feedforward(plant: Plant, lsb_v: float) -> float:
    """Ideal velocity feedforward ``K1 = 1 / (gain_cps_per_v · lsb_v)`` [codes per count/s]."""
    return 1.0 / (plant.gain_cps_per_v * lsb_v)


def corner_plants(plant: Plant, gain_spread: float, tau_spread: float) -> tuple[Plant, ...]:
    """The nominal plant and the four corners of gain ``±gain_spread``, tau ``±tau_spread``."""
    out = [plant]
    for g in (1 - gain_spread, 1 + gain_spread):
        for t in (1 - tau_spread, 1 + tau_spread):
            out.append(
                dataclasses.replace(
                    plant, gain_cps_per_v=plant.gain_cps_per_v * g, tau_s=plant.tau_s * t
                )
            )
    return tuple(out)


# --- parameter vector -----------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Space:
    names: tuple[str, ...]
    lo: np.ndarray
    hi: np.ndarray
    start: np.ndarray


def _space(structure: str, start: PIGains, n: int) -> _Space:
    kp, ki = max(start.kp, 1e-6), max(start.ki, 1e-6)
    # name: (lower, upper, start); log10 for gains and scalings, linear for fractions
    p: dict[str, tuple[float, float, float]] = {
        # Kp0 up to 25x the start PI's: at 5x, PID + feedforward's optimum reached the bound
        # on some seeds of the full Figure-4 study (the margins, not the bound, must decide)
        "log_kp0": (math.log10(kp / 5), math.log10(kp * 25), math.log10(kp)),
        "log_ki0": (math.log10(ki / 20), math.log10(ki * 20), math.log10(ki)),
        "log_kd0": (math.log10(kp * 1e-5), math.log10(kp * 1.0), math.log10(kp * 1e-4)),
    }
    if structure in ("pid_ff", "composite"):
        p["k1_ratio"] = (0.0, 1.3, 1.0)
    if structure == "composite":
        p["log_ke"] = (math.log10(n / 2000), math.log10(n / 5), math.log10(n / 200))
        # Kec down to n/5000: an optimum that wants the EC index to barely move reached n/200
        p["log_kec"] = (math.log10(n / 5000), math.log10(float(n)), math.log10(n / 20))
        for t in ("kp", "ki", "kd"):
            p["scale_" + t] = (0.0, 0.95, 0.3)
    names = tuple(p)
    arr = np.array([p[k] for k in names])
    return _Space(names=names, lo=arr[:, 0], hi=arr[:, 1], start=arr[:, 2])


def _gains_from(
    x: np.ndarray, space: _Space, k1_ideal: float, tables: Mapping[str, np.ndarray], n: int
) -> FuzzyPIDGains:
    v = dict(zip(space.names, (float(t) for t in x), strict=True))
    kp0, ki0, kd0 = 10 ** v["log_kp0"], 10 ** v["log_ki0"], 10 ** v["log_kd0"]
    k10 = v.get("k1_ratio", 0.0) * k1_ideal
    if "log_ke" not in v:
        return FuzzyPIDGains(kp0=kp0, ki0=ki0, kd0=kd0, k10=k10, ke=1.0, kec=1.0, n=n)
    # output scales as fractions of the base gain keep Kx0 + min ΔKx >= 0 (tables in [−1, 1])
    base = {"kp": kp0, "ki": ki0, "kd": kd0}
    d = {"d" + t: v["scale_" + t] * base[t] * np.asarray(tables[t]) for t in ("kp", "ki", "kd")}
    d["dk1"] = k10 * np.asarray(tables["k1"])
    return FuzzyPIDGains(
        kp0=kp0, ki0=ki0, kd0=kd0, k10=k10, ke=10 ** v["log_ke"], kec=10 ** v["log_kec"], n=n, **d
    )


# --- evaluation -----------------------------------------------------------------------------


def _screen(rig: Rig, slave: int, spec: SlaveTuneSpec) -> MarginScreen:
    """The margin screen over the plant set verification judges robustness on
    (:func:`~servotune.analysis.plant_cases.plant_cases`), its late cases only: one tick more delay
    lowers the phase at every frequency, so a loop that keeps its margins late keeps them on
    time (verification checks both)."""
    cases = spec.plant_cases(rig)
    late = max(c.extra_lag_s for c in cases)
    return MarginScreen(rig, slave, [c for c in cases if c.extra_lag_s == late])


def _worst_margins(screen: MarginScreen, task: FuzzyPIDConstants) -> tuple[float, float, float]:
    """Worst phase margin [deg], gain margin [dB] and Ms over every cell and plant case."""
    cells = np.stack([task.scheduled(name).ravel() for name in ("kp", "ki", "kd")], axis=1)
    pm, gm, ms = screen(np.unique(cells, axis=0))
    return float(pm.min()), float(gm.min()), float(ms.max())


@dataclass(frozen=True, slots=True, kw_only=True)
class _Problem:
    loop: Loop
    scenario: Scenario
    slave: int
    variants: tuple[tuple[Plant, ...], ...]
    seeds: tuple[int, ...]
    master_ctl: AxisController
    spec: SlaveTuneSpec
    screen: MarginScreen


@dataclass(frozen=True, slots=True)
class _Worst:
    """Each candidate's worst case over the plant variants (arrays, one entry per candidate)."""

    saturation_pct: np.ndarray
    overshoot_pct: np.ndarray
    fault: np.ndarray  # 1.0 where a variant tripped
    phase_margin_deg: np.ndarray
    gain_margin_db: np.ndarray
    max_sensitivity: np.ndarray
    max_sync_counts: np.ndarray
    rms_sync_counts: np.ndarray

    def row(self, i: int) -> dict[str, float]:
        """Candidate ``i``'s figures, by name."""
        return {f.name: float(getattr(self, f.name)[i]) for f in fields(self)}


def _evaluate(prob: _Problem, gains: Sequence[FuzzyPIDGains]) -> tuple[np.ndarray, _Worst]:
    """Objective and worst-case quantities (saturation %, overshoot, fault, PM [deg], GM [dB],
    Ms, max and RMS |sync error| [counts]) per candidate."""
    rig = prob.loop.rig
    n_v = len(prob.variants)
    ctls = []
    robust = []
    for g in gains:
        slave_ctl = AxisController.from_gains(
            lock_gain_codes_per_count=rig.axes[prob.slave].lock_gain_codes_per_count,
            task_gains=g,
            period_s=rig.period_s,
            following_error_limit_counts=rig.axes[prob.slave].following_error_limit_counts,
        )
        robust.append(_worst_margins(prob.screen, slave_ctl.task))  # type: ignore[arg-type]
        row = [prob.master_ctl] * len(rig.axes)
        row[prob.slave] = slave_ctl
        ctls.extend([tuple(row)] * n_v)
    plants = list(prob.variants) * len(gains)
    seeds = list(prob.seeds) * len(gains)
    batch = prepare_batch(prob.loop, plants=plants, controllers=ctls, seeds=seeds)
    res = run_batch(batch, prob.scenario.inputs, metrics_only=True)
    s = prob.slave
    itae = res.metric("itae_counts_s2")[:, s].reshape(len(gains), n_v)
    sat = res.metric("saturated_ticks")[:, s] / np.maximum(res.metric("task_ticks")[:, s], 1.0)
    lead = np.maximum(-res.metric("min_err_counts")[:, s], 0.0)
    over = 100.0 * lead / np.maximum(res.metric("max_err_counts")[:, s], 1.0)
    fault = (res.metric("first_fault_tick") >= 0).any(axis=1)
    per_variant = (len(gains), n_v)
    pm, gm, ms = np.array(robust).T
    worst = _Worst(
        saturation_pct=100.0 * sat.reshape(per_variant).max(axis=1),
        overshoot_pct=over.reshape(per_variant).max(axis=1),
        fault=fault.reshape(per_variant).any(axis=1).astype(float),
        phase_margin_deg=pm,
        gain_margin_db=gm,
        max_sensitivity=ms,
        max_sync_counts=res.metric("max_abs_err_counts")[:, s].reshape(per_variant).max(axis=1),
        rms_sync_counts=res.metric("rms_err_counts")[:, s].reshape(per_variant).max(axis=1),
    )
    return itae.mean(axis=1), worst


def _penalised(prob: _Problem, itae: np.ndarray, worst: _Worst) -> np.ndarray:
    spec = prob.spec
    aim = design_limits(spec.limits)
    viol = (
        np.maximum(worst.saturation_pct - spec.max_saturation_pct, 0.0)
        / max(spec.max_saturation_pct, 1.0)
        + np.maximum(worst.overshoot_pct - spec.max_overshoot_pct, 0.0)
        / max(spec.max_overshoot_pct, 1.0)
        + worst.fault * 10.0
        + np.maximum(aim.min_phase_margin_deg - worst.phase_margin_deg, 0.0) / 10.0
        + np.maximum(aim.min_gain_margin_db - worst.gain_margin_db, 0.0) / 2.0
        + np.maximum(worst.max_sensitivity - aim.max_sensitivity, 0.0) / 0.2
    )
    return np.where(viol > 0, _BIG * (1.0 + viol), itae)


_BYTES_PER_RUN = 16_000
"""Memory of one run (candidate × plant variant) of a generation's batch [bytes]: its
controller, plant rows, constants and results. Measured on the example rig: a
population of 3,000 over the 5 corner plants raised the peak by 75 kB per candidate."""


def _table_size(structure: str, tables: Mapping[str, np.ndarray] | None) -> int:
    """The query tables' ``n`` (tables of shape (2n+1, 2n+1)) for ``composite``, else 1.

    Raises
    ------
    SpecError
        ``composite`` without valid tables.
    """
    if structure != "composite":
        return 1
    if tables is None:
        raise SpecError("the composite structure needs query tables")
    n = (np.asarray(tables["kp"]).shape[0] - 1) // 2
    for t in TABLE_NAMES:
        a = np.asarray(tables[t])
        if a.shape != (2 * n + 1, 2 * n + 1) or np.max(np.abs(a)) > 1.0 + 1e-12:
            raise SpecError(f"query table {t} must be (2n+1, 2n+1) with values in [-1, 1]")
    return n


def _problem(
    rig: Rig,
    axes: tuple[int, int],
    master_gains: PIGains,
    start: PIGains,
    spec: SlaveTuneSpec,
    seed: int,
) -> _Problem:
    """The tuning run, its plant variants of the slave and their noise seeds, checked against
    the memory one generation's batch takes (``axes``: the master's and the slave's index)."""
    i_m, i_s = axes
    loop = Loop.from_rig(rig, [master_gains if i == i_m else start for i in range(len(rig.axes))])
    scenario = sync_move_for(rig, spec)
    variants = tuple(
        tuple(v if j == i_s else rig.axes[j].plant for j in range(len(rig.axes)))
        for v in corner_plants(rig.axes[i_s].plant, spec.gain_spread, spec.tau_spread)
    )
    runs = spec.population * len(variants)  # one generation, evaluated as one batch
    check_memory(
        runs * _BYTES_PER_RUN,
        f"tuning with a population of {spec.population:,}",
        f"{format_count(runs)} runs a generation × {_BYTES_PER_RUN // 1000} kB",
    )
    seeds = tuple(
        int(s) for s in np.random.SeedSequence(seed).generate_state(len(variants), np.uint64)
    )
    return _Problem(
        loop=loop,
        scenario=scenario,
        slave=i_s,
        variants=variants,
        seeds=seeds,
        master_ctl=loop.controllers[i_m],
        spec=spec,
        screen=_screen(rig, i_s, spec),
    )


def _initial_population(space: _Space, population: int, seed: int) -> np.ndarray:
    """The first generation: a Latin hypercube over the search space from ``seed``, its first
    member the start point."""
    unit = (space.start - space.lo) / (space.hi - space.lo)
    rng = np.random.default_rng(seed)
    sampler = qmc.LatinHypercube(d=len(space.names), rng=rng)
    init_u = sampler.random(population)
    init_u[0] = unit  # the start is a member of the first population
    return space.lo + init_u * (space.hi - space.lo)


def _optimise(
    objective: Callable[[np.ndarray], np.ndarray],
    space: _Space,
    init: np.ndarray,
    spec: SlaveTuneSpec,
    seed: int,
    callback: Callable[[Any], None],
) -> tuple[np.ndarray, int]:
    """The best candidate and the evaluations it took: differential evolution from ``init``
    for ``spec.generations`` generations (none: the best of ``init``)."""
    if spec.generations > 0:
        res = differential_evolution(
            objective,
            list(zip(space.lo, space.hi, strict=True)),
            maxiter=spec.generations,
            init=init,
            rng=np.random.default_rng(seed + 1),
            polish=False,
            tol=0.0,
            atol=0.0,
            updating="deferred",
            vectorized=True,
            callback=callback,
        )
        return res.x, int(res.nfev)
    vals = objective(init.T)
    return init[int(np.argmin(vals))], spec.population


def _at_bounds(space: _Space, x_best: np.ndarray) -> tuple[str, ...]:
    """The search parameters within 0.5 % of their range of a bound, in words."""
    edge = 0.005 * (space.hi - space.lo)
    return tuple(
        f"{name} at its {'lower' if x <= lo + e else 'upper'} bound"
        for name, x, lo, hi, e in zip(space.names, x_best, space.lo, space.hi, edge, strict=True)
        if x <= lo + e or x >= hi - e
    )


def _binding(spec: SlaveTuneSpec, w0: Mapping[str, float]) -> tuple[str, ...]:
    """The constraints a candidate's worst case ``w0`` sits on (see :class:`SlaveTuning`)."""
    return tuple(
        name
        for name, near in (
            ("max_saturation_pct", w0["saturation_pct"] >= 0.98 * spec.max_saturation_pct > 0),
            ("max_overshoot_pct", w0["overshoot_pct"] >= 0.98 * spec.max_overshoot_pct),
            ("min_phase_margin_deg", w0["phase_margin_deg"] <= spec.min_phase_margin_deg + 1.0),
            ("min_gain_margin_db", w0["gain_margin_db"] <= spec.min_gain_margin_db + 0.3),
            ("max_sensitivity", w0["max_sensitivity"] >= 0.98 * spec.max_sensitivity),
        )
        if near
    )


def tune_slave(
    rig: Rig,
    master_gains: PIGains,
    *,
    structure: str = "composite",
    tables: Mapping[str, np.ndarray] | None = None,
    start: PIGains,
    spec: SlaveTuneSpec | None = None,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> SlaveTuning:
    """Tune the slave's law by differential evolution over batched closed-loop runs.

    Parameters
    ----------
    rig : Rig
        Needs one master and one slave axis.
    master_gains : PIGains
        The master's PI (fixed during the slave's tuning).
    structure : {"pid", "pid_ff", "composite"}
        Law structure (see the module docstring).
    tables : mapping of str to ndarray, optional
        Normalised query tables ``kp``, ``ki``, ``kd``, ``k1`` (values in [−1, 1], shape
        (2n+1, 2n+1)) for ``composite``; they set ``n``.
    start : PIGains
        Start point's base ``Kp0``, ``Ki0`` (e.g. from :func:`~servotune.tune.pi.tune_pi`); the
        start has ``K1`` the ideal feedforward (``pid_ff``, ``composite``), output scales 0.3.
    spec : SlaveTuneSpec, optional
        Constraints, run and budget; defaults as documented there.
    seed : int
        Seeds the optimiser and the variants' noise: same seed, same result.
    progress : callable, optional
        Called with one line per generation (the CLI prints it on stderr).

    Returns
    -------
    SlaveTuning

    Raises
    ------
    SpecError
        Unknown structure, missing tables, or a rig without master and slave.
    """
    spec = spec or SlaveTuneSpec()
    if structure not in STRUCTURES:
        raise SpecError(f"structure must be one of {', '.join(STRUCTURES)}, got {structure!r}")
    axes = master_slave(rig)
    n = _table_size(structure, tables)
    prob = _problem(rig, axes, master_gains, start, spec, seed)
    space = _space(structure, start, n)
    k1_ideal = ideal_feedforward(rig.axes[prob.slave].plant, rig.dac.lsb_v)
    tab = tables or {}

    def to_gains(x: np.ndarray) -> FuzzyPIDGains:
        return _gains_from(x, space, k1_ideal, tab, n)

    def objective(xs: np.ndarray) -> np.ndarray:
        # vectorised: xs has shape (parameters, candidates)
        cols = np.atleast_2d(xs.T) if xs.ndim == 2 else xs[None, :]
        itae, worst = _evaluate(prob, [to_gains(x) for x in cols])
        return _penalised(prob, itae, worst)

    itae0, worst0 = _evaluate(prob, [to_gains(space.start)])
    start_feasible = bool(_penalised(prob, itae0, worst0)[0] < _BIG)
    init = _initial_population(space, spec.population, seed)
    history: list[float] = []

    def callback(intermediate_result: Any) -> None:
        history.append(float(intermediate_result.fun))
        if progress is not None:
            best = intermediate_result.fun
            shown = f"{best:.4g}" if best < _BIG else "infeasible"
            progress(
                f"tune {structure}: generation {len(history)}/{spec.generations}, best {shown}"
            )

    x_best, evaluations = _optimise(objective, space, init, spec, seed, callback)
    gains = to_gains(x_best)
    itae, worst = _evaluate(prob, [gains])
    val = float(_penalised(prob, itae, worst)[0])
    feasible = val < _BIG
    w0 = worst.row(0)
    return SlaveTuning(
        structure=structure,
        gains=gains,
        objective=val if feasible else math.inf,
        start_objective=float(itae0[0]),
        start_feasible=start_feasible,
        feasible=feasible,
        evaluations=evaluations + 1,
        history=tuple(history),
        at_bounds=_at_bounds(space, x_best),
        binding=_binding(spec, w0),
        worst=w0,
    )
