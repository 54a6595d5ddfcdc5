"""One real report, built once for the report tests (the page, its figures, the browser).

The output directory is filled first with what the demo writes there (the fit plots, Figure 4
and its JSON, the Pareto plot, the gantry and linkage plots and JSON), each drawn by the same
plot function the demo uses, from small stand-in data; then :func:`write_report` runs on the
example rig (with a fit record written into a copy of it) and the session's default tuning,
with a real verification (4 Monte-Carlo variants, to stay quick). Every figure saved on the
way is checked for axis labels with units before it is written.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from matplotlib.figure import Figure

import servotune as st
from report.figures_check import axis_unit_problems
from servotune.report import write_report
from servotune.report.text import figure4_statement
from servotune.rig import PlantFit, write_plant
from servotune.scenarios import step_inputs
from servotune.sim.engine import simulate
from servotune.tuning import write_tuning
from servotune.verify.run import verify
from servotune.verify.spec import load_spec

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE_RIG = ROOT / "plants" / "pc-dual-servo.toml"
EXAMPLE_SPEC = ROOT / "plants" / "pc-dual-servo.spec.toml"


@dataclass(frozen=True)
class ReportBuild:
    """The report written for the tests and what was checked on the way."""

    path: Path
    out: Path
    figures: tuple[tuple[str, tuple[str, ...]], ...]  # (where saved, unit problems)
    verification: Any


# --- the demo's products, drawn by the demo's plot functions from stand-in data ---------------


def _fake_linkage() -> Any:
    """What :func:`plot_queue_levels` and :func:`plot_radial_deviation` read of a
    :class:`~servotune.arch.linkage.LinkageResult`: two CPUs whose queues saw-tooth at a
    10 ms broadcast over 6 s (a saw-tooth that once plotted as a solid band), one arc."""
    period = 0.002
    n = 3000
    t = np.arange(n, dtype=np.int64) * period
    cpus = []
    for name, ppm, phase in (("s1", 80.0, 0), ("s2", -60.0, 2)):
        level = 13 - ((np.arange(n) + phase) % 5)
        cpus.append(
            SimpleNamespace(
                name=name,
                clock_ppm=ppm,
                queue_depth=20,
                tick_time_s=t,
                queue_level=level,
                underruns=0,
                overruns=0,
                first_underrun_s=None,
                first_overrun_s=None,
                min_level=int(level.min()),
                max_level=int(level.max()),
            )
        )
    ang = np.linspace(0.0, 2 * np.pi, 400)
    arc = SimpleNamespace(
        angle_rad=ang,
        radial_dev_counts=100 + 60 * np.sin(3 * ang),
        cruise=(ang > 0.3) & (ang < 6.0),
        move=2,
        plane=("x", "y"),
        radius_counts=40000.0,
        circularity_counts=120.0,
    )
    return SimpleNamespace(
        cpus=tuple(cpus),
        resync_interval_s=2.5,
        time_s=t,
        period_s=period,
        bus=SimpleNamespace(broadcast_period_s=0.01),
        arcs=(arc,),
    )


def _write_products(out: Path, tuning: st.Tuning, rig: st.Rig) -> None:
    from servotune.plot import (
        plot_comparison,
        plot_fit,
        plot_pareto,
        plot_queue_levels,
        plot_radial_deviation,
        plot_sync_errors,
        save_figure,
    )

    rng = np.random.default_rng(0)
    n, split = 2000, 1000
    pos = np.cumsum(rng.normal(0.0, 20.0, n)).round()
    sim = pos + rng.normal(0.0, 0.5, n) + np.where(np.arange(n) >= split, 2.0, 0.0)
    for name in rig.axis_names:
        save_figure(
            plot_fit(pos, sim, rig.period_s, split, f"fit of {name}"), out / f"fit_{name}.png"
        )
    trace = simulate(tuning.loop(rig), step_inputs(rig, step_counts=4096, seconds=0.6), seed=0)
    slave = [a.role for a in rig.axes].index("slave")
    save_figure(
        plot_comparison({"pid": trace, "pid_ff": trace, "composite": trace}, slave),
        out / "figure4.png",
    )
    points = [
        SimpleNamespace(
            structure=s,
            feasible=True,
            worst_ms=ms,
            itae=500.0 / ms,
            max_sync_counts=900.0 / ms,
            front_itae=True,
            front_max=True,
        )
        for s in ("pid", "composite")
        for ms in (1.3, 1.6, 2.0)
    ]
    save_figure(plot_pareto(points), out / "pareto.png")
    ts = np.arange(500, dtype=np.int64) * 0.001
    gantry = [
        SimpleNamespace(
            case=case,
            topology=topo,
            time_s=ts,
            cycle_s=0.001,
            sync_error=k * np.sin(8 * ts),
            trip_cycle=-1,
        )
        for case in ("load", "mismatch")
        for k, topo in ((30.0, "parallel"), (10.0, "listening"))
    ]
    for case in ("load", "mismatch"):
        save_figure(plot_sync_errors(gantry, case), out / f"sync_{case}.png")
    link = _fake_linkage()
    save_figure(plot_queue_levels(link), out / "linkage_queues.png")
    save_figure(plot_radial_deviation(link), out / "linkage_circle.png")
    table = {
        "pid": {"itae": 720.4, "max_sync_counts": 1349.0, "rise_s": 0.104},
        "pid_ff": {"itae": 642.7, "max_sync_counts": 897.0, "rise_s": 0.100},
        "composite": {"itae": 378.9, "max_sync_counts": 522.0, "rise_s": 0.096},
    }
    fig4 = {
        "schema": "servotune.figure4/2",
        "seeds": [0],
        "table": table,
        "spread": {},
        "heldout_scenarios": ["track", "lock", "heldout"],
        "active_constraints": {"pid": {"binding": ["max_overshoot_pct"], "at_bounds": []}},
        "statement": figure4_statement(table).splitlines(),
    }
    (out / "figure4.json").write_text(json.dumps(fig4, sort_keys=True), encoding="utf-8")
    sync = {
        "name": "gantry",
        "topology": "listening",
        "cycle_s": 0.001,
        "latency_cycles": 1,
        "passed": True,
        "failed": [],
        "results": [
            {
                "topology": "parallel",
                "case": "load",
                "max_sync_error_counts": 190.0,
                "rms_sync_error_counts": 57.0,
                "warning_cycles": 0,
                "trip_time_s": None,
            }
        ],
    }
    (out / "sync.json").write_text(json.dumps(sync, sort_keys=True), encoding="utf-8")
    linkage = {
        "name": "six-axis",
        "passed": True,
        "contour_max_counts": 180.0,
        "contour_rms_counts": 60.0,
        "bus": {"frame_bytes": 128, "broadcast_period_s": 0.01, "utilisation": 0.28},
        "cpus": [
            {
                "name": c.name,
                "clock_ppm": c.clock_ppm,
                "axes": ["x"],
                "min_level": c.min_level,
                "max_level": c.max_level,
                "queue_depth": c.queue_depth,
                "underruns": 0,
                "overruns": 0,
            }
            for c in link.cpus
        ],
        "arcs": [
            {
                "move": 2,
                "plane": ["x", "y"],
                "radius_counts": 40000.0,
                "circularity_counts": 120.0,
                "circularity_whole_counts": 130.0,
            }
        ],
    }
    (out / "linkage.json").write_text(json.dumps(linkage, sort_keys=True), encoding="utf-8")


def _fitted_rig(out: Path, rig: st.Rig) -> Path:
    """A copy of the example rig with a fit record (intervals ±1 %) on every axis."""
    path = out / "fitted-rig.toml"
    for a in rig.axes:
        ci = {
            k: (0.99 * getattr(a.plant, k), 1.01 * getattr(a.plant, k))
            for k in ("gain_cps_per_v", "tau_s")
        }
        fit = PlantFit(
            method="iv",
            structure=("gain_cps_per_v", "tau_s"),
            friction="sym",
            adequate=True,
            interval="stand-in ±1 %",
            ci95=ci,
        )
        write_plant(path, a.name, a.plant, template=EXAMPLE_RIG, fit=fit)
    return path


FIT_PCT = {"velocity": {"estimation": 99.04, "validation": 98.99},
           "position": {"estimation": 99.86, "validation": 95.07}}  # fmt: skip


@pytest.fixture(scope="session")
def report_build(
    tmp_path_factory: pytest.TempPathFactory, default_tuning: st.Tuning
) -> Iterator[ReportBuild]:
    out = tmp_path_factory.mktemp("report")
    rig = st.load_rig(EXAMPLE_RIG)
    saved: list[tuple[str, tuple[str, ...]]] = []
    original = Figure.savefig

    def checked_savefig(self: Figure, fname: Any, *args: Any, **kwargs: Any) -> Any:
        where = Path(fname).name if isinstance(fname, str | Path) else "embedded by the report"
        title = self.get_suptitle() or next((a.get_title() for a in self.axes), "")
        saved.append((f"{where}: {title}", tuple(axis_unit_problems(self))))
        return original(self, fname, *args, **kwargs)

    spec = load_spec(EXAMPLE_SPEC)
    spec = dataclasses.replace(
        spec, montecarlo=dataclasses.replace(spec.montecarlo, count=4), margin_samples=0
    )
    tuning_path = out / "tuning.json"
    write_tuning(default_tuning, tuning_path)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Figure, "savefig", checked_savefig)
        _write_products(out, default_tuning, rig)
        rig_path = _fitted_rig(out, rig)
        v = verify(default_tuning, rig, spec)
        fits = {name: {"fit_pct": FIT_PCT} for name in rig.axis_names}
        path = write_report(
            out,
            tuning_path=tuning_path,
            rig_path=rig_path,
            verification=v,
            fits=fits,
            spec_path=EXAMPLE_SPEC,
        )
    assert math.isfinite(v.pass_fraction[2])
    yield ReportBuild(path=path, out=out, figures=tuple(saved), verification=v)
