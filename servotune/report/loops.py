"""The report's sections on the loops: Bode plots and margins of every loop the runtime can run
(frequency domain), and the step and tracking responses against the spec (time domain)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import control
import numpy as np

from servotune._control import scipy_paths
from servotune.analysis.margins import MarginLimits, Margins
from servotune.laws.axis import MODE_TASK
from servotune.laws.fuzzy_pid import FuzzyPIDConstants
from servotune.modal import discretize
from servotune.plot import MoveEnvelope, plot_bode, plot_query_tables, plot_tracking
from servotune.report.page import (
    escape_html,
    figure_html,
    fmt_value,
    paragraph_html,
    png_uri,
    table_html,
)
from servotune.report.summary import margin_comment
from servotune.rig import Rig
from servotune.scenarios import build_scenario, step_inputs, sync_move, sync_move_for
from servotune.sim.engine import simulate
from servotune.tuning import Tuning
from servotune.validate import show_number

__all__ = ["bode_section", "loop_response", "margins_section", "response_section"]


@scipy_paths
def loop_response(rig: Rig, tuning: Tuning, axis: str, omega_rad_s: np.ndarray) -> Any:
    """Frequency response of one axis's task loop at the table centre (E = EC = 0).

    ``L(z) = C(z) · lsb_v · P(z)``, ``C(z) = Kp + Ki·T·z/(z−1) (+ Kd/T·(1 − z⁻¹))`` from the
    tuning's quantised constants, ``P`` the axis model discretised with ZOH and the lag
    ``compute_s + delay_s`` (:func:`servotune.modal.discretize`).

    Returns
    -------
    control.FrequencyResponseData
    """

    c = tuning.controller(axis)
    if c.task is None:
        raise ValueError(f"axis {axis!r} has no task law")
    t = rig.period_s
    kp, kit = c.task.kp.value, c.task.ki_t.value
    kdt = 0.0
    if isinstance(c.task, FuzzyPIDConstants):
        n = c.task.n
        kp = float(c.task.scheduled("kp")[n, n])
        kit = float(c.task.scheduled("ki")[n, n])
        kdt = float(c.task.scheduled("kd")[n, n])
    # C(z) = [(Kp + Ki·T + Kd/T) z² − (Kp + 2·Kd/T) z + Kd/T] / (z² − z)
    ctrl = control.tf([kp + kit + kdt, -(kp + 2 * kdt), kdt], [1.0, -1.0, 0.0], dt=t)
    ax = rig.axis(axis)
    plant = discretize(ax.plant, t, rig.timer.compute_s + ax.plant.delay_s) * rig.dac.lsb_v
    return control.frequency_response(control.series(ctrl, plant), omega_rad_s)


@scipy_paths
def bode_section(rig: Rig, tuning: Tuning, margins: Margins, limits: MarginLimits) -> str:
    w = np.logspace(-1, math.log10(math.pi / rig.period_s) - 1e-3, 600)
    responses, rows, centre = {}, [], {}
    for name, c in zip(tuning.axis_names, tuning.controllers, strict=True):
        if c.task is None:
            continue
        fr = loop_response(rig, tuning, name, w)
        gm, pm, _sm, wpc, wgc, _ws = control.stability_margins(fr)
        responses[name] = (w, np.asarray(fr.complex).ravel())
        gm_db = 20 * math.log10(gm) if gm and math.isfinite(gm) else math.inf
        where = "table centre E = EC = 0" if isinstance(c.task, FuzzyPIDConstants) else "PI"
        rows.append(
            [
                name,
                where,
                fmt_value(float(wgc)),
                fmt_value(float(pm)),
                fmt_value(gm_db),
                fmt_value(float(wpc)),
            ]
        )
        centre[name] = float(pm)
    cells = {
        name: [m for m in margins.select(name, "task") if m.cell is not None]
        for name, c in zip(tuning.axis_names, tuning.controllers, strict=True)
        if isinstance(c.task, FuzzyPIDConstants)
    }
    comment = margin_comment(centre, cells, min_phase_margin_deg=limits.min_phase_margin_deg)
    caption = (
        "Open-loop gain and phase of each axis's task loop L = C · LSB · P on the nominal "
        "plant, discrete as the engine runs it (with the compute time and the drive's "
        "delay). The phase margin is read where |L| crosses 0 dB, the gain margin where "
        "the phase crosses −180°."
    )
    return (
        '<section id="loops"><h2>Loops (Bode, margins by python-control; slave at the table '
        "centre)</h2>"
        + figure_html(png_uri(plot_bode(responses)), "Bode plots", escape_html(caption))
        + table_html(
            ["axis", "loop", "crossover [rad/s]", "PM [deg]", "GM [dB]", "phase crossover [rad/s]"],
            rows,
        )
        + (f'<p class="comment">{escape_html(comment)}</p>' if comment else "")
        + "</section>"
    )


def _loop_row(m: Any, what: str, limits: MarginLimits) -> tuple[list[str], bool]:
    broken = limits.broken(m)
    return (
        [
            m.axis,
            what,
            fmt_value(m.phase_margin_deg),
            fmt_value(m.gain_margin_db),
            fmt_value(m.max_sensitivity),
            fmt_value(m.max_complementary_sensitivity),
            fmt_value(m.delay_margin_ticks),
            fmt_value(m.crossover_rad_s),
            fmt_value(m.bandwidth_rad_s),
            "ok" if not broken else "FAIL: " + "; ".join(broken),
        ],
        bool(broken),
    )


def margins_section(tuning: Tuning, m: Margins, limits: MarginLimits, verification: Any) -> str:
    """The margins of each loop on the nominal plants (a table; for a scheduled axis its centre
    cell and its worst cells), over the plant set where a verification judged them, and heat
    maps of each scheduled axis's phase margin and Ms over the query table."""
    rows, bad = [], []
    for name in tuning.axis_names:
        for kind in ("lock", "task"):
            loops = list(m.select(name, kind))
            if not loops:
                continue
            if loops[0].cell is None:
                row, b = _loop_row(loops[0], kind, limits)
                rows.append(row)
                bad.append(b)
                continue
            picks = [
                (next((x for x in loops if x.cell == (0, 0)), None), "centre cell"),
                (m.worst(name, kind), "worst cell by Ms"),
                (min(loops, key=lambda x: x.phase_margin_deg), "least-PM cell"),
            ]
            for x, what in picks:
                if x is not None:
                    cell = f"task, {what} E={x.cell[0]:+d} EC={x.cell[1]:+d}"
                    row, b = _loop_row(x, cell, limits)
                    rows.append(row)
                    bad.append(b)
    head = [
        "axis",
        "loop",
        "PM [deg]",
        "GM [dB]",
        "Ms [1]",
        "Mt [1]",
        "delay margin [ticks]",
        "crossover [rad/s]",
        "bandwidth [rad/s]",
        f"limits (PM ≥ "
        f"{limits.min_phase_margin_deg:g}°, GM ≥ {limits.min_gain_margin_db:g} dB, Ms ≤ "
        f"{limits.max_sensitivity:g})",
    ]
    parts = [
        '<section id="margins"><h2>Margins of every loop the runtime can run (nominal plants)</h2>',
        paragraph_html(
            "Each axis runs a lock loop at rest and a task loop while moving; a scheduled "
            "(fuzzy-PID) axis runs one task loop per query-table cell, its gains frozen there. "
            "The feedforward acts on the reference only: it changes no margin. Ms is the peak "
            "of |1/(1 + L)| (how much the loop amplifies a disturbance at its worst frequency; "
            "Ms ≤ 2 alone guarantees GM ≥ 6 dB and PM ≥ 29°), the delay margin the extra loop "
            "delay that brings the phase margin to zero."
        ),
        table_html(head, rows, bad),
    ]
    if verification is not None:
        prows, pbad = [], []
        for c in verification.checks:
            if not c.name.startswith("margins:"):
                continue
            f = c.facts
            prows.append(
                [
                    c.name,
                    _loop_name(f),
                    str(f.get("plant", "")),
                    fmt_value(f.get("phase_margin_deg")),
                    fmt_value(f.get("gain_margin_db")),
                    fmt_value(f.get("max_sensitivity")),
                    "pass" if c.passed else "FAIL",
                ]
            )
            pbad.append(not c.passed)
        if prows:
            parts.append("<h3>Over the plant set (the verification's margins checks)</h3>")
            parts.append(
                paragraph_html(
                    "The worst loop of each kind over the identified intervals, the "
                    "spec's Monte-Carlo spreads, one tick more latency and the timer's "
                    "error (the plant case is named)."
                )
            )
            parts.append(
                table_html(
                    ["check", "worst loop", "plant case", "PM [deg]", "GM [dB]", "Ms [1]", ""],
                    prows,
                    pbad,
                )
            )
    for name, c in zip(tuning.axis_names, tuning.controllers, strict=True):
        if isinstance(c.task, FuzzyPIDConstants):
            grids = {
                "phase margin PM [deg]": m.cell_grid(name, "phase_margin_deg"),
                "peak sensitivity Ms [1]": m.cell_grid(name, "max_sensitivity"),
            }
            fig = plot_query_tables(grids, c.task.n, f"{name}: margins per query-table cell")
            cap = (
                f"The {name}'s task loop at every query-table cell (row E, column EC), frozen "
                "gains, nominal plant: its phase margin and its peak sensitivity Ms."
            )
            parts.append(figure_html(png_uri(fig), f"{name} margins per cell", escape_html(cap)))
    parts.append("</section>")
    return "".join(parts)


def _loop_name(f: Mapping[str, Any]) -> str:
    cell = f.get("cell")
    where = "" if not cell else f" cell E={cell[0]:+d} EC={cell[1]:+d}"
    return f"{f.get('axis', '')} {f.get('loop', '')}{where}".strip()


def _envelope(rig: Rig, sc: Any, inputs: Any, trace: Any) -> MoveEnvelope:
    """The spec's limits of a move scenario, placed on its run (as the verification measures:
    the move starts the tick before the master's reference moves)."""
    master = next((i for i, a in enumerate(rig.axes) if a.role == "master"), 0)
    slaves = tuple(
        i
        for i, a in enumerate(rig.axes)
        if a.role == "slave" and np.any(inputs.mode[:, i] == MODE_TASK)
    )
    ref = inputs.ref_counts[:, master]
    moving = np.flatnonzero(ref != ref[0])
    start = max(int(moving[0]) - 1, 0) if moving.size else 0
    return MoveEnvelope(
        start_s=float(trace.time_s[start]),
        initial_counts=float(trace.true_pos_counts[start, master]),
        target_counts=float(ref[-1]),
        settling_band_pct=float(sc.settling_band_pct),
        max_overshoot_pct=sc.max_overshoot_pct,
        max_settling_time_s=sc.max_settling_time_s,
        max_sync_error_counts=sc.max_sync_error_counts,
        master=master,
        slaves=slaves,
    )


def _scenario_inputs(rig: Rig, sc: Any) -> Any:
    """The inputs of a move scenario of a spec (as :mod:`servotune.verify.run` builds them)."""
    if sc.kind == "sync":
        return sync_move_for(rig, sc).inputs
    master = next((a.name for a in rig.axes if a.role == "master"), rig.axes[0].name)
    return build_scenario(rig, "track", axis=master, seconds=sc.seconds).inputs


def response_section(rig: Rig, tuning: Tuning, seed: int, verification: Any) -> str:
    loop = tuning.loop(rig)
    step = simulate(loop, step_inputs(rig, step_counts=rig.counts_per_rev, seconds=2.0), seed=seed)
    parts = [
        '<section id="responses"><h2>Step and tracking responses (bit-true loop)</h2>',
        figure_html(
            png_uri(plot_tracking(step, "master step of one revolution, slave following")),
            "step",
            escape_html(
                f"A step of the master's reference by one revolution "
                f"({rig.counts_per_rev:g} counts) on the nominal plants, seed "
                f"{seed}; the spec sets no limit on a step."
            ),
        ),
    ]
    moves = (
        []
        if verification is None
        else [sc for sc in verification.spec.scenarios if sc.kind in ("sync", "track")]
    )
    if not moves:
        track = simulate(loop, sync_move(rig).inputs, seed=seed)
        parts.append(
            figure_html(
                png_uri(
                    plot_tracking(track, "start, constant speed, load step on the slave, stop")
                ),
                "tracking",
                escape_html(
                    "The slave-tuning move on the nominal plants (no spec given: no limits drawn)."
                ),
            )
        )
    for sc in moves:
        inputs = _scenario_inputs(rig, sc)
        trace = simulate(loop, inputs, seed=seed)
        env = _envelope(rig, sc, inputs, trace)
        fig = plot_tracking(trace, f"scenario {sc.name} ({sc.kind}) against the spec", envelope=env)
        rows = [r for r in verification.rows if r.scenario == sc.name]
        worst = "; ".join(
            f"{r.quantity} of {r.axis} {show_number(r.worst)} {r.unit} "
            f"(limit {show_number(r.limit)})"
            for r in rows
            if r.quantity != "fault_runs"
        )
        drawn = []
        if env.max_overshoot_pct is not None:
            drawn.append("the overshoot ceiling (red dashed)")
        if env.max_settling_time_s is not None:
            drawn.append(
                "the settling band the position must be in from the settling deadline on (green)"
            )
        if env.max_sync_error_counts is not None and env.slaves:
            drawn.append(
                "in the middle panel the sync error master − slave (black) against its "
                "limit (red dashed)"
            )
        cap = (
            f"Scenario {sc.name!r} on the nominal plants, seed {seed}. Drawn from the spec: "
            + (", ".join(drawn) if drawn else "no limit on this run")
            + f". The verification judges the worst over every plant set: {worst or 'n/a'}."
        )
        parts.append(figure_html(png_uri(fig), f"scenario {sc.name}", escape_html(cap)))
    parts.append("</section>")
    return "".join(parts)
