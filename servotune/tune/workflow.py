"""Tuning a rig end to end (what ``servotune tune`` runs).

:func:`tune_rig`: the lock gains and the master's PI designed to keep the margin limits over
the plant set (:mod:`servotune.tune.robust`), the slave's composite fuzzy-PID + feedforward by
:func:`~servotune.tune.slave.tune_slave` (the margins of every cell as constraints) starting
from a PI designed the same way for the slave, the rule base evaluated into query tables by
:mod:`servotune.fuzzy`; everything quantised into a :class:`~servotune.tuning.Tuning`, whose
margins python-control then confirms.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from servotune import fuzzy
from servotune._version import __version__
from servotune.analysis.frf import Frf
from servotune.analysis.frf_margins import frf_loops
from servotune.analysis.margins import tuning_margins
from servotune.analysis.shaping import axis_shaper
from servotune.errors import InfeasibleError, SpecError
from servotune.laws.fuzzy_pid import FuzzyPIDConstants
from servotune.rig import Rig, load_rig
from servotune.sim.engine import Loop
from servotune.tune.filters import choose_filters
from servotune.tune.robust import modes_note, robust_lock_gain, robust_pi
from servotune.tune.slave import (
    SlaveTuneSpec,
    master_slave,
    tune_slave,
)
from servotune.tuning import Tuning, file_sha256
from servotune.validate import check_seed

__all__ = [
    "rule_tables",
    "tune_rig",
    "tuning_summary",
]


def rule_tables(rule_base: str = "default", *, n: int = 6) -> dict[str, np.ndarray]:
    """Normalised query tables (values in [−1, 1]) of a rule base: ``default`` or ``classic``."""
    bases = {"classic": fuzzy.CLASSIC_RULES, "default": fuzzy.DEFAULT_RULES}
    if rule_base not in bases:
        raise SpecError(f"rule_base must be one of {', '.join(sorted(bases))}, got {rule_base!r}")
    qt = fuzzy.query_tables(bases[rule_base], n=n)
    return {t: np.asarray(getattr(qt, t)) for t in ("kp", "ki", "kd", "k1")}


@dataclass(frozen=True, slots=True, kw_only=True)
class _RobustStart:
    """The fixed-gain loops designed for the plant set, before the slave's law is tuned."""

    rig: Rig  # the rig with each axis's lock gain as designed
    master_pi: Any  # PITuning
    slave_pi: Any  # PITuning (the slave tuner's start point)
    lock_gains: tuple[float, ...]
    filters: dict[str, Any]  # axis name → FilterChoice, for the axes whose filters were chosen


def _has_modes(rig: Rig) -> bool:
    return any(a.plant.modes for a in rig.axes)


def robust_start(
    rig: Rig, spec: SlaveTuneSpec, *, seed: int = 0, frf: Mapping[str, Frf] | None = None
) -> _RobustStart:
    """Output filters, lock gains and PI designs that keep ``spec``'s margin limits over the
    plant set (:func:`~servotune.analysis.plant_cases.plant_cases` of the spec's spreads,
    latency and timer error, and each mode's frequency range).

    An axis whose plant has modes and whose rig gives it no filters gets them chosen with its
    PI (:func:`~servotune.tune.filters.choose_filters`); the returned rig carries them, so every
    loop designed or run from it (the lock gains, the slave's tuner, the engine) has them.

    Raises
    ------
    InfeasibleError
        A loop cannot keep the limits (the message names the axis and the binding limit; for an
        axis with modes, the modes too).
    """
    i_m, i_s = master_slave(rig)
    cases = spec.plant_cases(rig)
    # an axis with modes: its screens also take the sampled plant sets the final check takes (a
    # mode's frequency inside its range with the gain and tau elsewhere than at a corner)
    sampled = spec.plant_cases(rig, seed=seed, sampled=True) if _has_modes(rig) else cases
    screen = {a.name: sampled if a.plant.modes else cases for a in rig.axes}
    choices = {
        a.name: choose_filters(
            rig,
            a.name,
            cases,
            spec.limits,
            screen[a.name],
            frf=(frf or {}).get(a.name),
            extra_ticks=spec.extra_ticks,
        )
        for a in rig.axes
        if a.plant.modes and not a.filters
    }
    rig = dataclasses.replace(
        rig,
        axes=tuple(
            dataclasses.replace(a, filters=choices[a.name].sections) if a.name in choices else a
            for a in rig.axes
        ),
    )
    locks = tuple(robust_lock_gain(rig, a.name, screen[a.name], spec.limits) for a in rig.axes)
    robust = dataclasses.replace(
        rig,
        axes=tuple(
            dataclasses.replace(a, lock_gain_codes_per_count=k)
            for a, k in zip(rig.axes, locks, strict=True)
        ),
    )

    def pi(i: int) -> Any:
        name = rig.axes[i].name
        if name in choices:
            return choices[name].pi
        return robust_pi(robust, name, cases, spec.limits, screen[name])

    return _RobustStart(
        rig=robust,
        master_pi=pi(i_m),
        slave_pi=pi(i_s),
        lock_gains=locks,
        filters=choices,
    )


def tune_rig(
    rig_path: str | Path,
    *,
    seed: int = 0,
    spec: SlaveTuneSpec | None = None,
    rule_base: str = "default",
    progress: Callable[[str], None] | None = None,
    frf: Mapping[str, Frf] | None = None,
    shaper: str | None = None,
) -> Tuning:
    """Tune a rig: lock gains, master PI, slave composite law; the result as the runtime will
    run it, every loop of it keeping ``spec``'s margin limits over the plant set.

    ``shaper`` (``auto``, ``zv``, ``zvd``, ``ei``) also designs the input shaper of the
    master's task reference for its closed-loop modes with the tuned PI and filters
    (:func:`~servotune.analysis.shaping.axis_shaper`): its Q15 amplitudes become the
    controller's ``shaper`` (exported with the tables, docs/runtime.md#shapers-in-the-tables)
    and ``design.shapers`` records the design and why.

    ``frf`` maps axis names to their measured responses (``servotune frf``): an axis's filters
    are then chosen to keep the limits on it too (:func:`~servotune.tune.filters.
    choose_filters`), and every loop of the tuning is judged on it at the end
    (:func:`~servotune.analysis.frf_margins.frf_loops`, with the spec's extra latency); the
    worst loop per axis goes into ``design.frf_margins``.

    The lock gains (the rig's, lowered if needed) and the PIs are designed for the plant set
    (:mod:`servotune.tune.robust`); the slave's law is tuned with the margins of every cell as
    constraints (:func:`~servotune.tune.slave.tune_slave`). The result is then judged as
    verification judges it: python-control on the quantised constants over the plant set
    (:func:`~servotune.analysis.margins.tuning_margins`); its figures go into ``design``.

    Parameters
    ----------
    rig_path : str or Path
        Rig file (its SHA-256 goes into the provenance).
    seed : int
        Optimiser and noise seed: same rig, options and seed give the same tuning file bytes.
    spec : SlaveTuneSpec, optional
        Slave tuning run, constraints and budget.
    rule_base : {"default", "classic"}
        Rule base of the query tables.
    progress : callable, optional
        Receives one line per step (the CLI prints them on stderr).

    Returns
    -------
    Tuning

    Raises
    ------
    InfeasibleError
        No tuning keeps the constraints (the message names the loop and the binding limit);
        nothing is returned, so nothing is written.
    """
    check_seed(seed)
    rig = load_rig(rig_path)
    spec = spec or SlaveTuneSpec()
    say = progress or (lambda _msg: None)
    i_m, i_s = master_slave(rig)
    if shaper is not None and not rig.axes[i_m].plant.modes:
        raise SpecError(
            f"--shaper: the master {rig.axes[i_m].name!r} has no modes to shape for; give its "
            "plant [[axis.X.plant.modes]] (docs/formats.md#modes) or fit them (servotune fit "
            "--modes)"
        )
    say(f"tune: PI for {rig.axes[i_m].name} and the start point of {rig.axes[i_s].name}")
    frf = dict(frf or {})
    for name in frf:
        rig.axis(name)  # an unknown axis is one line, before any work
    start = robust_start(rig, spec, seed=seed, frf=frf)
    rig, master_pi, slave_pi = start.rig, start.master_pi, start.slave_pi
    for choice in start.filters.values():
        say(f"tune: filters for {choice.axis}: {choice.why}")
    tables = rule_tables(rule_base)
    slave = tune_slave(
        rig,
        master_pi.gains,
        structure="composite",
        tables=tables,
        start=slave_pi.gains,
        spec=spec,
        seed=seed,
        progress=progress,
    )
    if not slave.feasible:
        raise InfeasibleError(_slave_infeasible(slave, spec))
    gains: list[object | None] = [None] * len(rig.axes)
    gains[i_m], gains[i_s] = master_pi.gains, slave.gains
    ctls = Loop.from_rig(rig, gains).controllers
    kept = "keeps" if slave.start_feasible else "breaks"
    say(
        f"tune: sync-error ITAE {slave.start_objective:.4g} counts·s² at the start (which {kept} "
        f"the constraints), {slave.objective:.4g} tuned"
    )
    rig_sha256 = file_sha256(rig_path)
    tuning = Tuning.for_rig(
        rig,
        ctls,
        rig_sha256=rig_sha256,
        rig_path=rig_path,
        design={
            "master": {"axis": rig.axes[i_m].name, "pi": master_pi.to_dict()},
            "slave": {
                "axis": rig.axes[i_s].name,
                "start_pi": slave_pi.to_dict(),
                "tuning": slave.to_dict(),
            },
            "spec": spec.to_dict(),
            "lock_gains_codes_per_count": dict(zip(rig.axis_names, start.lock_gains, strict=True)),
        }
        | (
            {"filters": {k: c.to_dict() for k, c in start.filters.items()}} if start.filters else {}
        ),
        provenance={
            "rig_sha256": rig_sha256,
            "rule_base": rule_base,
            "seed": seed,
            "tool": "servotune",
            "tool_version": __version__,
        },
    )
    say("tune: margins of every loop over the plant set (python-control)")
    cases = spec.plant_cases(rig, seed=seed, sampled=True)
    margins = tuning_margins(tuning, rig, limits=spec.limits, cases=cases, every_loop=False)
    if not margins.passed:
        m, broken = margins.failures()[0]
        raise InfeasibleError(
            f"the tuned {m.name} breaks the margin limits on plant {m.plant}: "
            f"{'; '.join(broken)} (the grid screen passed it; tighten the limits or report "
            "this)"
        )
    summary = {a: margins.worst(a).to_dict() for a in rig.axis_names}
    design = {**tuning.design, "margins": summary}
    if frf:
        say("tune: margins of every loop on the measured responses (python-control)")
        design["frf_margins"] = _frf_verdict(tuning, rig, frf, spec)
    if shaper is not None:
        tuning, design["shapers"] = _with_shaper(tuning, rig, i_m, master_pi.gains, shaper, say)
    return dataclasses.replace(tuning, design=design)


def _with_shaper(
    tuning: Tuning, rig: Rig, axis: int, gains: Any, kind: str, say: Callable[[str], None]
) -> tuple[Tuning, dict[str, Any]]:
    """The tuning with the master's reference shaper (:func:`tune_rig`'s ``shaper``), and its
    ``design.shapers`` record."""
    name = rig.axis_names[axis]
    ctl = tuning.controllers[axis]
    sh, _, why = axis_shaper(rig, name, gains, kind, ctl.filters)
    for line in why:
        say(f"tune: shaper for {name}: {line}")
    say(
        f"tune: shaper for {name}: {sh.kind}, {sh.n_taps} taps, moves end "
        f"{1000 * sh.added_time_s:.1f} ms later"
    )
    ctls = list(tuning.controllers)
    ctls[axis] = dataclasses.replace(ctl, shaper=sh.amplitudes_q)
    return dataclasses.replace(tuning, controllers=tuple(ctls)), {
        name: {**sh.to_dict(), "why": why}
    }


def _frf_verdict(
    tuning: Tuning, rig: Rig, frf: Mapping[str, Frf], spec: SlaveTuneSpec
) -> dict[str, Any]:
    """The worst loop of each axis with a measured response, judged on it; a loop that breaks a
    limit there stops the tune."""
    out = {}
    for a, (name, ctl) in enumerate(zip(tuning.axis_names, tuning.controllers, strict=True)):
        if name not in frf:
            continue
        loops = frf_loops(
            frf[name], ctl, lsb_v=rig.dac.lsb_v, axis=name, extra_ticks=spec.extra_ticks
        )
        worst = max(loops, key=lambda x: x.max_sensitivity)
        bad = [(x, x.broken(spec.limits)) for x in loops if x.broken(spec.limits)]
        if bad:
            x, broken = bad[0]
            cell = "" if x.cell is None else f" cell E={x.cell[0]} EC={x.cell[1]}"
            raise InfeasibleError(
                f"the tuned {name} {x.loop}{cell} (+{x.extra_ticks} tick) breaks the margin "
                f"limits on the measured response{modes_note(rig, a)}: {'; '.join(broken)}"
            )
        out[name] = worst.to_dict()
    return out


def _slave_infeasible(slave: Any, spec: SlaveTuneSpec) -> str:
    """The one line of a slave tuning that met no constraint set: what the closest breaks."""
    w = slave.worst
    broken = [
        text
        for bad, text in (
            (w["fault"] > 0, "a fault (following-error trip) on some variant"),
            (
                w["saturation_pct"] > spec.max_saturation_pct,
                f"saturation {w['saturation_pct']:.1f} % > {spec.max_saturation_pct:g} %",
            ),
            (
                w["overshoot_pct"] > spec.max_overshoot_pct,
                f"overshoot {w['overshoot_pct']:.0f} % > {spec.max_overshoot_pct:g} %",
            ),
            (
                w["phase_margin_deg"] < spec.min_phase_margin_deg,
                f"PM {w['phase_margin_deg']:.1f}° < {spec.min_phase_margin_deg:g}°",
            ),
            (
                w["gain_margin_db"] < spec.min_gain_margin_db,
                f"GM {w['gain_margin_db']:.1f} dB < {spec.min_gain_margin_db:g} dB",
            ),
            (
                w["max_sensitivity"] > spec.max_sensitivity,
                f"Ms {w['max_sensitivity']:.2f} > {spec.max_sensitivity:g}",
            ),
        )
        if bad
    ]
    return (
        f"no slave tuning met the constraints within the budget ({spec.generations} "
        f"generations of {spec.population}); the closest breaks: "
        f"{'; '.join(broken) or 'a margin limit by the tolerance the design keeps'} "
        f"(worst cell PM {w['phase_margin_deg']:.1f}°, GM {w['gain_margin_db']:.1f} dB, "
        f"Ms {w['max_sensitivity']:.2f})"
    )


def tuning_summary(tuning: Tuning) -> dict[str, Any]:
    """What ``servotune tune`` reports: per axis its gains as they run (lock gain, the task law's
    base gains and, for a scheduled law, the range over its query table) and its worst loop's
    margins over the plant set (python-control, from ``tuning.design["margins"]``); the slave
    tuner's objective and constraint figures.

    Returns
    -------
    dict
        ``schema`` ``"servotune.tune-summary/1"``, ``axes`` (name → ``lock_gain``, ``law``,
        ``gains``, ``worst_loop``), ``slave`` (objective, worst case over the variants of the
        tuning run: sync error, saturation, overshoot, grid-screened margins; the constraints
        it sits on and the search bounds it reached), ``run`` (the tuning run's move and load).
    """
    margins = tuning.design.get("margins", {})
    axes: dict[str, Any] = {}
    for name, ctl in zip(tuning.axis_names, tuning.controllers, strict=True):
        task = ctl.task
        gains: dict[str, Any] = {}
        if task is not None:
            gains = {"kp": task.kp.value, "ki_t": task.ki_t.value}
        if isinstance(task, FuzzyPIDConstants):
            gains["kd_t"] = task.kd_t.value
            gains["k1_t"] = task.k1_t.value
            for key in ("kp", "ki", "kd"):
                s = task.scheduled(key)
                gains[f"{key}_range"] = [float(s.min()), float(s.max())]
        axes[name] = {
            "gains": gains,
            "law": ctl.to_dict()["law"],
            "lock_gain": ctl.lock_gain.value,
            "worst_loop": margins.get(name),
        }
    slave = tuning.design.get("slave", {}).get("tuning", {})
    spec = tuning.design.get("spec", {})
    return {
        "schema": "servotune.tune-summary/1",
        "axes": axes,
        "slave": {
            k: slave.get(k)
            for k in ("objective", "feasible", "worst", "structure", "binding", "at_bounds")
        },
        "run": {k: spec.get(k) for k in ("seconds", "speed_fraction", "accel_s", "load_step_v")},
    }
