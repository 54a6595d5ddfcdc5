"""The end-to-end job on a rig (what ``make demo`` runs).

Today: the virtual rig and the closed loop (the lock module holding both axes against their
drift, a PI move of the master with the slave following, wrapping the 24-bit counter),
identification of both axes from simulated logs, tuning from the fitted models, and the
Figure-4 comparison, verification against the spec, export (JSON and C) and the HTML report,
with plots and a summary written into the output directory.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from servotune._version import __version__
from servotune.arch.gantry import CASES, compare_topologies
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.synthesis import resolve_gains
from servotune.arch.linkage import load_linkage, run_linkage
from servotune.arch.linkage import resolve_gains as resolve_linkage_gains
from servotune.compare import compare_structures, pareto_front, pareto_specs
from servotune.export import c as c_export
from servotune.export import json as json_export
from servotune.identify import fit_log, simulate_fit, validation_split
from servotune.io.files import atomic_write_text, staged_directory
from servotune.io.log import write_log
from servotune.laws.lock import lock_holding_band
from servotune.metrics import tracking_metrics
from servotune.plot import (
    plot_comparison,
    plot_fit,
    plot_lock_hold,
    plot_pareto,
    plot_queue_levels,
    plot_radial_deviation,
    plot_sync_errors,
    plot_tracking,
    save_figure,
)
from servotune.report import write_report
from servotune.report.text import figure4_statement
from servotune.rig import Rig, describe_rig, load_rig, write_plant
from servotune.scenarios import Inputs, Scenario, build_scenario, check_run_memory
from servotune.sim.engine import Loop, Trace, simulate
from servotune.tune.pi import pi_loop_shaping
from servotune.tune.slave import tune_spec_from
from servotune.tune.workflow import tune_rig
from servotune.tuning import write_tuning
from servotune.validate import check_seed
from servotune.verify import load_for_export, verify_files
from servotune.verify.spec import Spec, load_spec

__all__ = [
    "PRESETS",
    "DemoPreset",
    "comparison_statement",
    "comparison_table_text",
    "default_pi_gains",
    "fit_log",
    "lock_hold",
    "run_comparison",
    "run_demo",
    "run_scenario",
    "trace_log_columns",
]


def default_pi_gains(rig: Rig) -> list:
    """Loop-shaping PI gains (:func:`~servotune.tune.pi.pi_loop_shaping`) for every axis."""
    return [
        pi_loop_shaping(
            a.plant, period_s=rig.period_s, lsb_v=rig.dac.lsb_v, compute_s=rig.timer.compute_s
        )
        for a in rig.axes
    ]


def run_scenario(rig: Rig, scenario: Scenario, *, seed: int = 0, noise: bool = True) -> Trace:
    """Simulate a named scenario on the rig (PI gains by loop shaping where a task law runs)."""
    loop = Loop.from_rig(rig, default_pi_gains(rig) if scenario.needs_task_law else None)
    plants = None
    if not noise:
        plants = [replace(a.plant, noise_counts=0.0) for a in rig.axes]
    return simulate(loop, scenario.inputs, seed=seed, plants=plants)


def trace_log_columns(trace: Trace, excitation: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Log columns (docs/formats.md#columns) of a trace: per axis dac_code, counter, ref_counts,
    mode.

    With ``excitation`` (the run's ``Inputs.dac_add_codes``, shape (ticks, axes) [D/A codes])
    each axis also gets ``exc_code``, the excitation its law added
    (docs/decisions.md#5-excitation-is-logged), from which
    ``servotune fit`` builds its instruments.
    """
    cols: dict[str, np.ndarray] = {}
    for i, name in enumerate(trace.axis_names):
        cols[f"{name}.dac_code"] = trace.code[:, i].astype(np.int64)
        cols[f"{name}.counter"] = trace.counter[:, i]
        cols[f"{name}.ref_counts"] = trace.ref_counts[:, i]
        if excitation is not None:
            cols[f"{name}.exc_code"] = np.asarray(excitation[:, i], dtype=np.int64)
        cols[f"{name}.mode"] = trace.mode[:, i]
    return cols


def log_metadata(rig: Rig, **extra: object) -> dict[str, object]:
    """Metadata lines of a log written from a rig (docs/formats.md#metadata)."""
    lo, hi = rig.dac.range_v
    meta: dict[str, object] = {
        "rig": rig.name,
        "period_s": repr(rig.period_s),
        "counter_bits": rig.counter.bits,
        "dac_bits": rig.dac.bits,
        "dac_range_v": f"{lo:g},{hi:g}",
        "compute_s": repr(rig.timer.compute_s),
    }
    meta.update(extra)
    meta["servotune_version"] = __version__
    return meta


@dataclass(frozen=True, slots=True, kw_only=True)
class LockHoldResult:
    """The lock module holding every axis against its drift.

    Attributes
    ----------
    trace : Trace
    settle_s : float
        Start transient excluded from the judgement [s].
    observed : dict
        Per axis (min, max) of ``target − position`` on the noiseless position after settling.
    predicted : dict
        Per axis the band of :func:`~servotune.laws.lock.lock_holding_band`.
    """

    trace: Trace
    settle_s: float
    observed: dict[str, tuple[int, int]]
    predicted: dict[str, tuple[int, int]]


def lock_hold(
    rig: Rig,
    *,
    seconds: float = 60.0,
    settle_s: float = 2.0,
    seed: int = 0,
    plants: list | None = None,
) -> LockHoldResult:
    """Run the lock module alone on every axis and compare the hold with the prediction."""
    check_run_memory(rig, seconds / rig.period_s, f"a lock hold of {seconds:g} s")
    n = math.floor(seconds / rig.period_s + 0.5)
    loop = Loop.from_rig(rig)
    trace = simulate(loop, Inputs.hold(n, len(rig.axes)), seed=seed, plants=plants)
    k0 = math.ceil(settle_s / rig.period_s)
    observed, predicted = {}, {}
    facts = describe_rig(rig)
    use = plants or [a.plant for a in rig.axes]
    for i, a in enumerate(rig.axes):
        e = -np.floor(trace.true_pos_counts[k0:, i]).astype(np.int64)
        observed[a.name] = (int(e.min()), int(e.max()))
        if plants is None:
            predicted[a.name] = tuple(facts["axes"][a.name]["lock_band_counts"])
        else:
            predicted[a.name] = lock_holding_band(
                a.lock_gain_codes_per_count, use[i].offset_v, rig.dac.lsb_v, use[i].coulomb_v
            )
    return LockHoldResult(trace=trace, settle_s=settle_s, observed=observed, predicted=predicted)


def run_architectures(plants_dir: str | Path, out_dir: str | Path, *, seed: int = 0) -> dict:
    """Run the synchronisation architectures whose example configs sit in ``plants_dir``.

    ``gantry.toml`` (the fieldbus gantry): every topology in both cases → ``sync.json``,
    ``sync_load.png``, ``sync_mismatch.png``; ``linkage-6axis.toml`` (the multi-CPU linkage) →
    ``linkage.json``, ``linkage_queues.png``, ``linkage_circle.png``. Returns a summary per
    architecture (whether it passed its checks, and its headline figures).
    """

    plants, out = Path(plants_dir), Path(out_dir)
    summary: dict[str, Any] = {}
    gantry_path = plants / "gantry.toml"
    if gantry_path.is_file():
        cmp = compare_topologies(resolve_gains(load_gantry(gantry_path)), seed=seed)
        doc = cmp.to_dict()
        atomic_write_text(out / "sync.json", json.dumps(doc, indent=2, sort_keys=True) + "\n")
        for case in CASES:
            save_figure(plot_sync_errors(cmp.traces, case), out / f"sync_{case}.png")
        summary["gantry"] = {
            "passed": cmp.passed,
            "results": doc["results"],
            "predicted_load": doc["predicted_load"],
        }
    linkage_path = plants / "linkage-6axis.toml"
    if linkage_path.is_file():
        res = run_linkage(resolve_linkage_gains(load_linkage(linkage_path)), seed=seed)
        doc = res.to_dict()
        atomic_write_text(out / "linkage.json", json.dumps(doc, indent=2, sort_keys=True) + "\n")
        save_figure(plot_queue_levels(res), out / "linkage_queues.png")
        save_figure(plot_radial_deviation(res), out / "linkage_circle.png")
        summary["linkage"] = {
            "passed": res.passed,
            "bus": doc["bus"],
            "contour_max_counts": doc["contour_max_counts"],
            "worst_underrun_margin": doc["worst_underrun_margin"],
            "arcs": doc["arcs"],
        }
    return summary


def _tracking_move(rig: Rig, out: Path, seed: int) -> dict[str, Any]:
    """A PI move of the master with the slave following: writes ``track.png`` and
    ``track_log.csv``; returns each axis's counter wraps, faults and tracking metrics."""
    master = next(a.name for a in rig.axes if a.role == "master")
    scen = build_scenario(rig, "track", axis=master, seconds=6.0)
    trace = run_scenario(rig, scen, seed=seed)
    save_figure(plot_tracking(trace, "PI move of the master, slave following"), out / "track.png")
    write_log(
        out / "track_log.csv",
        period_s=rig.period_s,
        columns=trace_log_columns(trace),
        metadata=log_metadata(rig, scenario="track", axis=master, seed=seed),
    )
    task = trace.mode == 1
    track = {}
    for i, name in enumerate(trace.axis_names):
        e = trace.err_counts[task[:, i], i]
        m = tracking_metrics(e, period_s=rig.period_s) if e.size >= 3 else None
        raw = trace.counter[:, i]
        track[name] = {
            "counter_wraps": int(np.sum(np.abs(np.diff(raw)) > (1 << (rig.counter.bits - 1)))),
            "faults": int(np.any(trace.flags[:, i] & 3)),
            "tracking": None if m is None else m.to_dict(),
        }
    return track


def _identify_axes(
    rig: Rig, rig_path: str | Path, out: Path, seed: int
) -> tuple[dict[str, Any], dict[str, Any], Path]:
    """Identify every axis from a simulated closed-loop log (:func:`_identify_axis`): the
    summary of each fit, the fits, and ``fitted-rig.toml`` (the rig with the fitted plants)."""
    identification = {}
    fits = {}
    fitted_rig = out / "fitted-rig.toml"
    for name in rig.axis_names:
        fits[name], identification[name] = _identify_axis(
            rig, rig_path, name, out, fitted_rig, seed
        )
    return identification, fits, fitted_rig


def _identify_axis(
    rig: Rig, rig_path: str | Path, name: str, out: Path, fitted_rig: Path, seed: int
) -> tuple[Any, dict[str, Any]]:
    """Fit axis ``name`` from a closed-loop multi-level PRBS log: writes
    ``ident_log_<axis>.csv``, ``fit_<axis>.png`` and the fitted plant into ``fitted_rig``;
    returns the fit and its summary (errors against the rig's plant)."""
    scen_id = build_scenario(rig, "prbs", axis=name, seconds=40.0, closed_loop=True)
    id_trace = run_scenario(rig, scen_id, seed=seed)
    log_path = out / f"ident_log_{name}.csv"
    write_log(
        log_path,
        period_s=rig.period_s,
        columns=trace_log_columns(id_trace, scen_id.inputs.dac_add_codes),
        metadata=log_metadata(rig, scenario="prbs", axis=name, closed_loop="true", seed=seed),
    )
    result, log, _ = fit_log(log_path, axis=name, rig=rig)
    ax = log.axis(name)
    sim = simulate_fit(result, ax.cmd_v, ax.pos_counts)
    save_figure(
        plot_fit(ax.pos_counts, sim, log.period_s, validation_split(sim.size), f"fit of {name}"),
        out / f"fit_{name}.png",
    )
    write_plant(
        fitted_rig,
        name,
        result.plant,
        template=rig_path,
        provenance=f"fitted by servotune {__version__} from {log_path.name}",
        fit=result.plant_fit,
    )
    truth = rig.axis(name).plant
    return result, {
        "fit_pct": result.fit_pct,
        "params": result.params,
        "relative_error": {
            "gain_cps_per_v": result.params["gain_cps_per_v"] / truth.gain_cps_per_v - 1,
            "tau_s": result.params["tau_s"] / truth.tau_s - 1,
        },
        "structure": list(result.structure),
    }


def _verify_and_export(tuning_path: Path, spec_path: Path, out: Path) -> tuple[Any, list[str]]:
    """Verify the tuning against the spec and, if it passes, export exactly the verified bytes
    (``fuzzy.json`` and ``c/``); returns the verification and what was exported."""
    verification, _, _ = verify_files(tuning_path, spec_path)
    exported = []
    if verification.passed:
        v = load_for_export(tuning_path, spec_path=spec_path)
        json_export.to_file(v.tuning, out / "fuzzy.json", rig=v.rig, verification=v.record)
        c_export.to_file(v.tuning, out / "c", rig=v.rig, verification=v.record)
        exported = ["fuzzy.json", "c/"]
    return verification, exported


def run_demo(
    rig_path: str | Path,
    out_dir: str | Path,
    *,
    seed: int = 0,
    preset: str = "quick",
    progress: Any = None,
) -> dict[str, Any]:
    """Run the demo job and write its products into ``out_dir``.

    ``preset`` (:data:`PRESETS`): ``quick`` tunes with a small budget and runs Figure 4 with one
    seed; ``full`` uses the default budget, Figure 4 over three seeds and the trade-off sweep.
    ``progress`` receives a line per step.

    Writes ``demo_summary.json``, ``lock_hold.png``, ``track.png``, ``track_log.csv``; for
    the identification step ``ident_log_<axis>.csv`` (a closed-loop multi-level PRBS per axis),
    ``fit_<axis>.png`` and ``fitted-rig.toml`` (the rig with the fitted plants); for tuning
    ``tuning.json`` (tuned on the fitted rig) and the Figure-4 comparison ``figure4.png``,
    ``figure4.json``; the verification on the example rig against ``<rig>.spec.toml``
    (``tuning.json.verify.json``), and if it passes the exports ``fuzzy.json`` and ``c/``;
    ``report.html``.

    Returns
    -------
    dict
        The summary.
    """

    out = Path(out_dir)
    if not out.is_dir():
        raise FileNotFoundError(f"output directory {str(out)!r} does not exist")
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {', '.join(PRESETS)}, got {preset!r}")
    check_seed(seed)
    say = progress or (lambda _msg: None)
    rig = load_rig(rig_path)
    facts = describe_rig(rig)
    say("demo: lock hold and a tracking move on the virtual rig")
    hold = lock_hold(rig, seconds=60.0, seed=seed)
    save_figure(
        plot_lock_hold(hold.trace, hold.predicted, hold.settle_s, "Position lock, 60 s"),
        out / "lock_hold.png",
    )
    track = _tracking_move(rig, out, seed)
    say("demo: identify both axes from closed-loop logs")
    identification, fits, fitted_rig = _identify_axes(rig, rig_path, out, seed)
    # tune from the identified models (what a user has), then Figure 4 on the example rig

    chosen = PRESETS[preset]
    spec_path = Path(rig_path).with_suffix(".spec.toml")
    spec = load_spec(spec_path)
    say(f"demo: tune on the fitted rig ({chosen.generations} generations of {chosen.population})")
    budget = {"generations": chosen.generations, "population": chosen.population}
    tuning = tune_rig(fitted_rig, seed=seed, spec=tune_spec_from(spec, **budget))
    tuning_path = out / "tuning.json"
    write_tuning(tuning, tuning_path)
    say(
        f"demo: Figure 4 ({len(chosen.seeds)} seed(s), held-out scenarios)"
        + (", trade-off sweep" if chosen.pareto_ms else "")
    )
    cmp = run_comparison(rig, spec, out, preset=chosen, seed=seed)
    # verify on the rig the tuning was made for (the fitted models: what a user has; the spec's
    # Monte-Carlo spreads cover the model error), then export exactly the verified bytes

    say("demo: gantry and linkage")
    architectures = run_architectures(Path(rig_path).parent, out, seed=seed)
    say("demo: verify, export, report")
    verification, exported = _verify_and_export(tuning_path, spec_path, out)
    write_report(
        out,
        tuning_path=tuning_path,
        rig_path=fitted_rig,
        verification=verification,
        seed=seed,
        fits=fits,
        spec_path=spec_path,
    )
    summary = {
        "architectures": architectures,
        "comparison": cmp.to_dict()["table"],
        "figure4_statement": comparison_statement(cmp),
        "exported": exported,
        "verification": {"passed": verification.passed, "failures": verification.failures},
        "identification": identification,
        "tuning": {
            "master_pi": tuning.design["master"]["pi"],
            "slave_itae": tuning.design["slave"]["tuning"]["objective"],
            "slave_start_itae": tuning.design["slave"]["tuning"]["start_objective"],
        },
        "lock_hold": {
            name: {
                "observed_counts": list(hold.observed[name]),
                "predicted_counts": list(hold.predicted[name]),
            }
            for name in hold.observed
        },
        "rig": facts,
        "preset": preset,
        "schema": "servotune.demo/2",
        "seed": seed,
        "track": track,
        "version": __version__,
    }
    atomic_write_text(
        out / "demo_summary.json", json.dumps(summary, indent=2, sort_keys=True) + "\n"
    )
    return summary


_COMPARISON_COLUMNS = (
    ("max_sync_counts", "max sync [counts]", "{:.0f}"),
    ("rms_sync_counts", "RMS sync [counts]", "{:.1f}"),
    ("rise_s", "rise [ms]", "{:.0f}"),
    ("settling_s", "settling [ms]", "{:.0f}"),
    ("itae", "ITAE [counts·s²]", "{:.4g}"),
    ("heldout_max_sync_counts", "held-out max sync [counts]", "{:.0f}"),
    ("heldout_pass_pct", "held-out pass [%]", "{:.0f}"),
    ("worst_ms", "worst Ms", "{:.2f}"),
)


def comparison_table_text(table: dict[str, dict[str, float]]) -> str:
    """The Figure-4 table as aligned text (rise and settling in ms)."""
    head = ["structure"] + [c[1] for c in _COMPARISON_COLUMNS]
    rows = [head]
    for name, row in table.items():
        cells = [name]
        for key, _, fmt in _COMPARISON_COLUMNS:
            v = row.get(key)
            if v is None or not math.isfinite(v):
                cells.append("n/a")
                continue
            cells.append(fmt.format(v * (1000.0 if key in ("rise_s", "settling_s") else 1.0)))
        rows.append(cells)
    widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
    return "\n".join("  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in rows)


@dataclass(frozen=True, slots=True, kw_only=True)
class DemoPreset:
    """How much of the study the demo runs (see the README: ``make demo`` is ``quick``,
    ``servotune demo --full`` the whole study).

    Attributes
    ----------
    generations, population : int
        The slave tuner's budget (the tuning written and every Figure-4 structure alike).
    seeds : tuple of int
        Figure-4 seeds (the spread over seeds is reported where there are several).
    heldout_count : int
        Monte-Carlo plant draws of each held-out verification in Figure 4.
    pareto_ms : tuple of float
        Peak-sensitivity ceilings of the trade-off sweep (empty: no sweep).
    """

    generations: int
    population: int
    seeds: tuple[int, ...]
    heldout_count: int
    pareto_ms: tuple[float, ...] = ()


PRESETS = {
    "quick": DemoPreset(generations=12, population=16, seeds=(0,), heldout_count=8),
    "full": DemoPreset(generations=40, population=32, seeds=(0, 1, 2), heldout_count=64,
                       pareto_ms=(1.3, 1.5, 1.7, 2.0)),
}  # fmt: skip
"""The demo's presets."""


def comparison_statement(cmp: Any) -> list[str]:
    """The lines of :func:`~servotune.report.text.figure4_statement` for a comparison (with its
    ranges where it ran more than one seed)."""
    return figure4_statement(cmp.table, cmp.spread if len(cmp.seeds) > 1 else None).splitlines()


def run_comparison(
    rig: Rig,
    spec: Spec,
    out_dir: str | Path,
    *,
    preset: DemoPreset = PRESETS["quick"],
    seed: int = 0,
    progress: Any = None,
) -> Any:
    """Figure 4 on ``rig`` (:func:`servotune.compare.compare_structures`, the preset's
    seeds offset by ``seed``) and, if the preset sweeps, the trade-off
    (:func:`~servotune.compare.pareto_front`): writes ``figure4.png``, ``figure4.json``
    (the comparison, the statement, the Pareto points) and ``pareto.png``.

    Returns
    -------
    Comparison
    """

    out = Path(out_dir)
    tune = tune_spec_from(spec, generations=preset.generations, population=preset.population)
    pareto_specs(tune, preset.pareto_ms)  # a ceiling the tuner refuses fails before the work
    cmp = compare_structures(
        rig,
        spec,
        tune=tune,
        seeds=[seed + s for s in preset.seeds],
        heldout_count=preset.heldout_count,
        progress=progress,
    )
    data = {"schema": "servotune.figure4/2", "seed": seed, "version": __version__}
    data.update(cmp.to_dict())
    data["statement"] = comparison_statement(cmp)
    points = (
        pareto_front(rig, tune, preset.pareto_ms, seed=seed, progress=progress)
        if (preset.pareto_ms)
        else []
    )
    data["pareto"] = [p.to_dict() for p in points]
    slave = [a.role for a in rig.axes].index("slave")
    with staged_directory(out) as stage:  # the three files as a whole, or none
        save_figure(plot_comparison(dict(cmp.traces), slave), stage / "figure4.png")
        if points:
            save_figure(plot_pareto(points), stage / "pareto.png")
        atomic_write_text(stage / "figure4.json", json.dumps(data, indent=2, sort_keys=True) + "\n")
    return cmp
