"""The HTML report: one self-contained page (plots embedded as PNG data URIs, the numbers as a
JSON block), readable at 1280 px.

Sections, each with its numbers and units: a summary (verdict, failed checks, the tightest
margin, the Monte-Carlo pass fraction and what to do next, :mod:`.summary`); the verification
table and checks; the identification (fitted parameters with their 95 % intervals and fit %,
the fit plots with the validation split marked); the tuned gains; Bode plots of each task loop
with its margins (python-control, the discrete loop as the engine runs it) and why the axes'
phase margins differ; the margins of every loop the runtime can run (a table and heat maps
over the query-table cells); the responses in the bit-true loop against the spec's envelope;
the query-table heat maps; and — when the output directory holds them (``make demo`` writes
them first) — Figure 4 with its table and stated winner, the gantry and the linkage. The only
other module that imports matplotlib is :mod:`servotune.plot`.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import control
import matplotlib.pyplot as plt
import numpy as np

from servotune._version import __version__
from servotune.identify.model import ALL_PARAMS, UNITS
from servotune.io.files import atomic_write_text
from servotune.laws.axis import MODE_TASK
from servotune.laws.fuzzy_pid import TABLE_NAMES, FuzzyPIDConstants
from servotune.plant import discretize
from servotune.plot import (
    QUERY_TABLE_LABELS,
    MoveEnvelope,
    plot_bode,
    plot_comparison,
    plot_fit,
    plot_pareto,
    plot_query_tables,
    plot_queue_levels,
    plot_radial_deviation,
    plot_sync_errors,
    plot_tracking,
)
from servotune.report.summary import ReportSummary, margin_comment, search_notes, summarise
from servotune.rig import Rig, load_rig
from servotune.scenarios import _sync_move_for, build_scenario, step_inputs, sync_move
from servotune.sim.engine import simulate
from servotune.tune.workflow import tuning_summary
from servotune.tuning import Tuning, read_tuning
from servotune.validate import show_number
from servotune.verify.margins import DEFAULT_LIMITS, MarginLimits, Margins, tuning_margins

__all__ = ["EMBEDDED_FIGURES", "loop_response", "write_report"]

EMBEDDED_FIGURES: Mapping[str, Any] = {
    "fit_*.png": plot_fit,
    "figure4.png": plot_comparison,
    "pareto.png": plot_pareto,
    "sync_*.png": plot_sync_errors,
    "linkage_queues.png": plot_queue_levels,
    "linkage_circle.png": plot_radial_deviation,
}
"""The figures the report embeds from its output directory (written there first by the demo
or the CLI), by file pattern, with the function that draws them."""


def loop_response(rig: Rig, tuning: Tuning, axis: str, omega_rad_s: np.ndarray) -> Any:
    """Frequency response of one axis's task loop at the table centre (E = EC = 0).

    ``L(z) = C(z) · lsb_v · P(z)``, ``C(z) = Kp + Ki·T·z/(z−1) (+ Kd/T·(1 − z⁻¹))`` from the
    tuning's quantised constants, ``P`` the axis model discretised with ZOH and the lag
    ``compute_s + delay_s`` (:func:`servotune.plant.discretize`).

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


# --- HTML pieces -----------------------------------------------------------------------------


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, metadata={"Software": None})
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _file_uri(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _esc(x: Any) -> str:
    return html.escape(str(x))


def _figure(uri: str, alt: str, caption: str = "") -> str:
    cap = f"<figcaption>{caption}</figcaption>" if caption else ""
    return f'<figure><img alt="{_esc(alt)}" src="{uri}">{cap}</figure>'


def _table(head: Sequence[str], rows: Sequence[Sequence[Any]], bad: Sequence[bool] = ()) -> str:
    """A table of text cells; ``bad`` rows are highlighted."""
    out = ["<table><tr>" + "".join(f"<th>{_esc(h)}</th>" for h in head) + "</tr>"]
    for i, r in enumerate(rows):
        cls = ' class="fail"' if (i < len(bad) and bad[i]) else ""
        cells = "".join(f"<td>{_esc(c)}</td>" for c in r)
        out.append(f"<tr{cls}>{cells}</tr>")
    return "\n".join(out) + "</table>"


def _fmt(x: Any, unit: str = "") -> str:
    if isinstance(x, float | int) and not isinstance(x, bool):
        text = show_number(float(x))
        return f"{text} {unit}" if unit and math.isfinite(float(x)) else text
    return "—" if x is None else str(x)


def _p(text: str) -> str:
    return f"<p>{_esc(text)}</p>"


# --- sections --------------------------------------------------------------------------------


def _code(text: str) -> str:
    """``text`` escaped, with its `backticked` commands set as code."""
    parts = _esc(text).split("`")
    return "".join(f"<code>{x}</code>" if i % 2 else x for i, x in enumerate(parts))


def _summary_section(s: ReportSummary) -> str:
    cls = {"PASSED": "pass", "FAILED": "fail"}.get(s.verdict, "none")
    items = []
    if s.verified:
        items.append(f"{s.failed} of {s.total} limits and checks failed.")
        if s.tightest is not None:
            label = "Most broken limit" if s.tightest.relative_margin < 0 else "Tightest margin"
            items.append(f"{label}: {_esc(s.tightest.describe())}.")
        if s.montecarlo is not None:
            items.append(_esc(s.montecarlo_text()) + ".")
        for f in s.failures[:5]:
            items.append("Failed: " + _esc(f))
        if len(s.failures) > 5:
            items.append(f"… and {len(s.failures) - 5} more (see the verification below).")
    else:
        items.append("This report was written without a verification.")
    lis = "".join(f"<li>{x}</li>" for x in items)
    return (
        f'<section id="summary" class="summary {cls}"><h2>Summary: {_esc(s.verdict)}</h2>'
        f'<ul>{lis}</ul><p class="next"><strong>What to do next:</strong> '
        f"{_code(s.next_step)}</p></section>"
    )


def _verification_section(v: Any, s: ReportSummary) -> str:
    rows, bad = [], []
    for r in v.rows:
        rel = r.relative_margin
        rel_text = "n/a" if rel is None or not math.isfinite(rel) else f"{100.0 * rel:.0f} %"
        rows.append(
            [
                r.scenario,
                r.axis,
                r.quantity,
                _fmt(r.limit, r.unit),
                _fmt(r.worst, r.unit),
                _fmt(r.margin, r.unit),
                rel_text,
                r.variant,
                "pass" if r.passed else "FAIL",
            ]
        )
        bad.append(not r.passed)
    checks = [[c.name, "pass" if c.passed else "FAIL", c.detail] for c in v.checks]
    verdict = "PASSED" if v.passed else "FAILED"
    mc = s.montecarlo_text()
    return (
        f'<section id="verification"><h2>Verification: {verdict}</h2>'
        + _p(
            f"Spec {v.spec.name!r} on rig {v.rig_name!r}, seed {v.seed}: every scenario on the "
            f"nominal plants and {v.plant_sets - 1} Monte-Carlo plant sets; a limit holds "
            "if its worst value over all of them does. Margin: limit − worst (and as % of the "
            "limit)."
        )
        + (_p(mc + ".") if mc else "")
        + _table(
            [
                "scenario",
                "axis",
                "quantity",
                "limit",
                "worst",
                "margin",
                "margin %",
                "worst variant",
                "",
            ],
            rows,
            bad,
        )
        + "<h3>Checks</h3>"
        + _table(["check", "", "detail"], checks, [row[1] == "FAIL" for row in checks])
        + "</section>"
    )


_FIT_CAPTION = (
    "Measured against simulated position and speed, and the position residual. The dotted "
    "line marks the split of the split-half validation: each half is simulated by the model "
    "fitted on the other half, starting from its own first measured position with a speed "
    "taken from its first samples. The second half's simulation therefore restarts at the "
    "split without the motion in flight (the commands inside the loop delay, the "
    "acceleration), so the residual steps there — by the amount written on the figure — and "
    "then stays flat: a position simulation integrates the restart's speed error and never "
    "forgets it. A flat residual on both sides is what a good model looks like; the speed "
    "panel shows no step."
)


def _identification_section(rig: Rig, out: Path, fits: Mapping[str, Any] | None) -> str:
    files = sorted(out.glob("fit_*.png"))
    fitted = [a for a in rig.axes if a.plant_fit is not None]
    if not files and not fitted and not fits:
        return ""
    parts = ['<section id="identification"><h2>Identification</h2>']
    for a in rig.axes:
        fit = a.plant_fit
        result = (fits or {}).get(a.name)
        rows = []
        for p in ALL_PARAMS:
            value = getattr(a.plant, p)
            if value is None:
                continue
            ci = fit.ci95.get(p) if fit is not None else None
            if ci is not None:
                shown, interval = _with_interval(float(value), float(ci[0]), float(ci[1]))
                how = "fitted"
            elif fit is not None:
                shown, interval = show_number(float(value)), "—"
                how = "fitted" if p in fit.structure else "left out (0)"
            else:
                shown, interval, how = show_number(float(value)), "—", "as in the rig file"
            rows.append([p, shown, UNITS[p], interval, how])
        head = f"<h3>{_esc(a.name)} ({_esc(a.role)})</h3>"
        if fit is not None:
            note = (
                f"Method {fit.method}, friction {fit.friction}; residual tests: "
                + ("adequate" if fit.adequate else f"NOT adequate ({fit.reason})")
                + f". Intervals: {fit.interval}."
            )
        else:
            note = (
                "The rig file holds no fit record for this axis: its plant is as written "
                "(no intervals)."
            )
        pct = getattr(result, "fit_pct", None)
        if pct is None and isinstance(result, Mapping):
            pct = result.get("fit_pct")
        if pct:
            v, y = pct.get("velocity", {}), pct.get("position", {})
            note += (
                f" Fit (MATLAB compare, 100 % is perfect): speed {_pct(v.get('estimation'))} "
                f"on the whole log, {_pct(v.get('validation'))} cross-validated; position "
                f"{_pct(y.get('estimation'))} / {_pct(y.get('validation'))}."
            )
        else:
            note += " Fit %: not given to the report (see `servotune fit`'s output)."
        parts.append(
            head + _p(note) + _table(["parameter", "value", "unit", "95 % interval", ""], rows)
        )
    for f in files:
        parts.append(_figure(_file_uri(f), f.name, _esc(_FIT_CAPTION)))
    parts.append("</section>")
    return "".join(parts)


def _with_interval(value: float, lo: float, hi: float) -> tuple[str, str]:
    """A value and its interval with enough significant digits to tell the ends apart.

    >>> _with_interval(12287.89, 12287.59, 12288.19)
    ('12287.89', '12287.59 … 12288.19')
    """
    width = abs(hi - lo)
    scale = max(abs(value), abs(lo), abs(hi))
    digits = 4
    if width > 0 and scale > 0:
        digits = min(12, max(4, math.ceil(math.log10(scale / width)) + 2))
    return f"{value:.{digits}g}", f"{lo:.{digits}g} … {hi:.{digits}g}"


def _pct(x: Any) -> str:
    return "n/a" if x is None else f"{float(x):.1f} %"


def _gains_section(tuning: Tuning) -> str:
    summary = tuning_summary(tuning)
    rows = []
    for name, ax in summary["axes"].items():
        g = ax["gains"]
        rng = ", ".join(
            f"{label} {_fmt(g[k + '_range'][0])}–{_fmt(g[k + '_range'][1])}"
            for k, label in (("kp", "Kp"), ("ki", "Ki·T"), ("kd", "Kd/T"))
            if k + "_range" in g
        )
        rows.append(
            [
                name,
                ax["law"],
                _fmt(ax["lock_gain"]),
                _fmt(g.get("kp")),
                _fmt(g.get("ki_t")),
                _fmt(g.get("kd_t")),
                _fmt(g.get("k1_t")),
                rng or "—",
            ]
        )
    s = summary.get("slave") or {}
    notes = []
    if s.get("objective") is not None:
        notes.append(
            f"Slave objective (mean ITAE of the sync error over the tuning run's plant "
            f"variants): {s['objective']:.4g} counts·s²."
        )
    notes += [f"{n[0].upper()}{n[1:]}." for n in search_notes(s)]
    return (
        '<section id="gains"><h2>Tuned gains (as the runtime holds them)</h2>'
        + _table(
            [
                "axis",
                "law",
                "lock gain [codes/count]",
                "Kp [codes/count]",
                "Ki·T [codes/count per tick]",
                "Kd/T [codes/count of change]",
                "K1/T [codes/count of change]",
                "range over the query table",
            ],
            rows,
        )
        + "".join(_p(n) for n in notes)
        + "</section>"
    )


def _bode_section(rig: Rig, tuning: Tuning, margins: Margins, limits: MarginLimits) -> str:
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
        rows.append([name, where, _fmt(float(wgc)), _fmt(float(pm)), _fmt(gm_db), _fmt(float(wpc))])
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
        + _figure(_png(plot_bode(responses)), "Bode plots", _esc(caption))
        + _table(
            ["axis", "loop", "crossover [rad/s]", "PM [deg]", "GM [dB]", "phase crossover [rad/s]"],
            rows,
        )
        + (f'<p class="comment">{_esc(comment)}</p>' if comment else "")
        + "</section>"
    )


def _loop_row(m: Any, what: str, limits: MarginLimits) -> tuple[list[str], bool]:
    broken = limits.broken(m)
    return (
        [
            m.axis,
            what,
            _fmt(m.phase_margin_deg),
            _fmt(m.gain_margin_db),
            _fmt(m.max_sensitivity),
            _fmt(m.max_complementary_sensitivity),
            _fmt(m.delay_margin_ticks),
            _fmt(m.crossover_rad_s),
            _fmt(m.bandwidth_rad_s),
            "ok" if not broken else "FAIL: " + "; ".join(broken),
        ],
        bool(broken),
    )


def _margins_section(tuning: Tuning, m: Margins, limits: MarginLimits, verification: Any) -> str:
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
        _p(
            "Each axis runs a lock loop at rest and a task loop while moving; a scheduled "
            "(fuzzy-PID) axis runs one task loop per query-table cell, its gains frozen there. "
            "The feedforward acts on the reference only: it changes no margin. Ms is the peak "
            "of |1/(1 + L)| (how much the loop amplifies a disturbance at its worst frequency; "
            "Ms ≤ 2 alone guarantees GM ≥ 6 dB and PM ≥ 29°), the delay margin the extra loop "
            "delay that brings the phase margin to zero."
        ),
        _table(head, rows, bad),
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
                    _fmt(f.get("phase_margin_deg")),
                    _fmt(f.get("gain_margin_db")),
                    _fmt(f.get("max_sensitivity")),
                    "pass" if c.passed else "FAIL",
                ]
            )
            pbad.append(not c.passed)
        if prows:
            parts.append("<h3>Over the plant set (the verification's margins checks)</h3>")
            parts.append(
                _p(
                    "The worst loop of each kind over the identified intervals, the "
                    "spec's Monte-Carlo spreads, one tick more latency and the timer's "
                    "error (the plant case is named)."
                )
            )
            parts.append(
                _table(
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
            parts.append(_figure(_png(fig), f"{name} margins per cell", _esc(cap)))
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
        return _sync_move_for(rig, sc).inputs
    master = next((a.name for a in rig.axes if a.role == "master"), rig.axes[0].name)
    return build_scenario(rig, "track", axis=master, seconds=sc.seconds).inputs


def _response_section(rig: Rig, tuning: Tuning, seed: int, verification: Any) -> str:
    loop = tuning.loop(rig)
    step = simulate(loop, step_inputs(rig, step_counts=rig.counts_per_rev, seconds=2.0), seed=seed)
    parts = [
        '<section id="responses"><h2>Step and tracking responses (bit-true loop)</h2>',
        _figure(
            _png(plot_tracking(step, "master step of one revolution, slave following")),
            "step",
            _esc(
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
            _figure(
                _png(plot_tracking(track, "start, constant speed, load step on the slave, stop")),
                "tracking",
                _esc(
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
            drawn.append("the settling band the position must be in from the settling deadline "
                         "on (green)")  # fmt: skip
        if env.max_sync_error_counts is not None and env.slaves:
            drawn.append("in the middle panel the sync error master − slave (black) against its "
                         "limit (red dashed)")  # fmt: skip
        cap = (
            f"Scenario {sc.name!r} on the nominal plants, seed {seed}. Drawn from the spec: "
            + (", ".join(drawn) if drawn else "no limit on this run")
            + f". The verification judges the worst over every plant set: {worst or 'n/a'}."
        )
        parts.append(_figure(_png(fig), f"scenario {sc.name}", _esc(cap)))
    parts.append("</section>")
    return "".join(parts)


def _tables_section(tuning: Tuning) -> str:
    parts = []
    for name, c in zip(tuning.axis_names, tuning.controllers, strict=True):
        if isinstance(c.task, FuzzyPIDConstants):
            tabs = {QUERY_TABLE_LABELS[t]: c.task.scheduled(t) for t in TABLE_NAMES}
            fig = plot_query_tables(tabs, c.task.n, f"{name}: scheduled gains Kx0 + ΔKx per cell")
            const = [t.split(" [")[0] for t, a in tabs.items() if np.ptp(a) == 0]
            cap = (
                f"The gains the {name}'s runtime looks up at each fuzzy level of the error E "
                "(rows) and its change EC (columns), quantised as exported."
            )
            if const:
                cap += (
                    f" Constant table{'s' if len(const) > 1 else ''} "
                    f"({', '.join(const)}): the same value in every cell, written on the "
                    "tile (the gain is not scheduled)."
                )
            parts.append(_figure(_png(fig), f"{name} query tables", _esc(cap)))
    if not parts:
        return ""
    return (
        '<section id="tables"><h2>Query tables (as the runtime holds them)</h2>'
        + "".join(parts)
        + "</section>"
    )


_FIGURE4_COLUMNS = (
    ("itae", "ITAE (the tuning objective) [counts·s²]", 1.0, "{:.4g}"),
    ("max_sync_counts", "max sync error [counts]", 1.0, "{:.0f}"),
    ("rms_sync_counts", "RMS sync error [counts]", 1.0, "{:.1f}"),
    ("rise_s", "rise time [ms]", 1e3, "{:.0f}"),
    ("settling_s", "settling time [ms]", 1e3, "{:.0f}"),
    ("heldout_max_sync_counts", "held out: worst max sync error [counts]", 1.0, "{:.0f}"),
    ("heldout_rms_sync_counts", "held out: worst RMS sync error [counts]", 1.0, "{:.1f}"),
    ("heldout_pass_pct", "held out: plant sets keeping every limit [%]", 1.0, "{:.1f}"),
    ("worst_ms", "worst Ms over the plant set [1]", 1.0, "{:.2f}"),
)
_HIGHER_IS_BETTER = frozenset({"heldout_pass_pct"})
_STRUCTURES = {
    "pid": "PID",
    "pid_ff": "PID + feedforward",
    "composite": "composite (fuzzy-PID + feedforward)",
}


def _finite(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _figure4_text(data: Mapping[str, Any]) -> str:
    """The Figure-4 winner (the statement's verdict lines), its table with units (the best of
    each column in bold; ranges over the seeds in brackets), the constraints each structure's
    optimum sits on, and the whole statement."""
    statement = list(data.get("statement", []))
    verdicts = [s for s in statement if s.startswith("The composite law")]
    table, spread = data.get("table", {}), data.get("spread", {})
    parts = []
    objective = {s: row["itae"] for s, row in table.items() if _finite(row.get("itae"))}
    if objective or verdicts:
        head = ""
        if objective:
            top = min(objective.values())
            best = [_STRUCTURES.get(s, s) for s, v in objective.items() if v == top]
            head = (
                f"<strong>Winner on the tuning objective: {_esc(' and '.join(best))}</strong> "
                f"(ITAE of the sync error {top:.4g} counts·s²). "
            )
        parts.append(f'<div class="winner">{head}' + " ".join(_esc(s) for s in verdicts) + "</div>")
    if table:
        known = {k for k, *_ in _FIGURE4_COLUMNS}
        cols = [c for c in _FIGURE4_COLUMNS if any(k == c[0] for r in table.values() for k in r)]
        extra = sorted({k for r in table.values() for k in r} - known)
        cols += [(k, k, 1.0, "{:.4g}") for k in extra]
        best = {}
        for key, *_ in cols:
            vals = {s: row[key] for s, row in table.items() if _finite(row.get(key))}
            if len(vals) > 1:
                pick = max if key in _HIGHER_IS_BETTER else min
                top = pick(vals.values())
                best[key] = {s for s, v in vals.items() if v == top}
        rows = []
        for s, row in table.items():
            cells = [f"<th>{_esc(_STRUCTURES.get(s, s))}</th>"]
            for key, _label, scale, fmt in cols:
                v, r = row.get(key), spread.get(s, {}).get(key)
                text = "n/a" if not _finite(v) else fmt.format(v * scale)
                if r and _finite(r[0]) and _finite(r[1]) and r[0] != r[1]:
                    text += f" ({fmt.format(r[0] * scale)}–{fmt.format(r[1] * scale)})"
                if s in best.get(key, ()):
                    text = f"<strong>{text}</strong>"
                cells.append(f"<td>{text}</td>")
            active = data.get("active_constraints", {}).get(s, {})
            sits = ", ".join(active.get("binding", []) + active.get("at_bounds", [])) or "none"
            cells.append(f"<td>{_esc(sits)}</td>")
            rows.append("<tr>" + "".join(cells) + "</tr>")
        head = "".join(f"<th>{_esc(label)}</th>" for _k, label, *_ in cols)
        seeds = ", ".join(str(x) for x in data.get("seeds", []))
        parts.append(
            _p(
                f"Seeds {seeds}; held-out scenarios: "
                f"{', '.join(data.get('heldout_scenarios', []))}. Best of each column "
                "in bold; with several seeds the values are means, ranges in brackets."
            )
            + f"<table><tr><th>structure</th>{head}<th>active constraints</th></tr>"
            f"{''.join(rows)}</table>"
        )
    parts += [_p(s) for s in statement]
    return "".join(parts)


_FIGURE4_CAPTIONS = {
    "figure4.png": "The slave's speed and its sync error under each structure, each tuned by the "
    "same optimiser, budget and margin limits, on the same move.",
    "pareto.png": "Tracking against robustness: each structure's optima under a sweep of Ms "
    "ceilings (its front joined).",
}


def _figure4_figures(out: Path) -> list[Path]:
    files = sorted(out.glob("figure4.png"))
    if files and (out / "pareto.png").is_file():
        files.append(out / "pareto.png")
    return files


def _gantry_text(doc: Mapping[str, Any]) -> str:
    rows, bad = [], []
    for r in doc.get("results", []):
        trip = r.get("trip_time_s")
        rows.append(
            [
                r.get("topology"),
                r.get("case"),
                _fmt(r.get("max_sync_error_counts")),
                _fmt(r.get("rms_sync_error_counts")),
                r.get("warning_cycles"),
                "no" if trip is None else f"at {_fmt(trip)} s",
            ]
        )
        bad.append(trip is not None)
    return _p(
        f"Gantry {doc.get('name', '')!r}: deployed topology "
        f"{doc.get('topology', '')}, bus cycle {_fmt(doc.get('cycle_s'), 's')}, "
        f"latency {doc.get('latency_cycles')} cycle(s); "
        + (
            "PASSED."
            if doc.get("passed")
            else "FAILED: " + "; ".join(map(str, doc.get("failed", [])))
        )
    ) + _table(
        [
            "topology",
            "case",
            "max sync error [counts]",
            "RMS sync error [counts]",
            "warning cycles [1]",
            "tripped",
        ],
        rows,
        bad,
    )


def _gantry_caption(f: Path) -> str:
    return (
        f"Sync error over time, one line per topology ({f.stem.split('_', 1)[-1]} case); "
        "a dotted line marks a trip."
    )


def _linkage_text(doc: Mapping[str, Any]) -> str:
    bus = doc.get("bus", {})
    parts = [
        _p(
            f"Linkage {doc.get('name', '')!r}: bus frame {bus.get('frame_bytes')} bytes every "
            f"{_fmt(1e3 * bus.get('broadcast_period_s', math.nan), 'ms')} (utilisation "
            f"{_fmt(100 * bus.get('utilisation', math.nan), '%')}); contour error max "
            f"{_fmt(doc.get('contour_max_counts'), 'counts')}, RMS "
            f"{_fmt(doc.get('contour_rms_counts'), 'counts')}; "
            + ("PASSED." if doc.get("passed") else "FAILED.")
        )
    ]
    rows, bad = [], []
    for c in doc.get("cpus", []):
        rows.append(
            [
                c.get("name"),
                f"{c.get('clock_ppm', 0.0):+g} ppm",
                ", ".join(c.get("axes", [])),
                f"{c.get('min_level')}–{c.get('max_level')} of {c.get('queue_depth')}",
                c.get("underruns"),
                c.get("overruns"),
            ]
        )
        bad.append(bool(c.get("underruns") or c.get("overruns")))
    parts.append(
        _table(
            [
                "cpu",
                "clock error",
                "axes",
                "queue level [setpoints]",
                "underruns [1]",
                "overruns [1]",
            ],
            rows,
            bad,
        )
    )
    arcs = [
        [
            a.get("move"),
            "/".join(a.get("plane", [])),
            f"{a.get('radius_counts', math.nan):g}",
            _fmt(a.get("circularity_counts")),
            _fmt(a.get("circularity_whole_counts")),
        ]
        for a in doc.get("arcs", [])
    ]
    if arcs:
        parts.append(
            _table(
                [
                    "move",
                    "plane",
                    "radius [counts]",
                    "circularity at constant feed [counts]",
                    "with the ramps [counts]",
                ],
                arcs,
            )
        )
    return "".join(parts)


_LINKAGE_CAPTIONS = {
    "linkage_queues.png": "Each slave CPU's queue level before every pop. Top: over the "
    "whole run, the lowest and highest level in each time bin (the level is a sawtooth at "
    "the broadcast period, too fast to draw tick by tick over seconds); bottom: a window "
    "of a few broadcast periods with every pop.",
    "linkage_circle.png": "Circular test (ballbar plot): the radial deviation against the "
    "angle, magnified about the programmed circle.",
}


@dataclass(frozen=True, slots=True, kw_only=True)
class _DemoSection:
    """A section on what the demo wrote into the output folder (none of its figures: none)."""

    title: str
    figures: Callable[[Path], list[Path]]  # its figures in the folder
    data: str  # the data file, if the demo wrote it
    text: Callable[[Any], str]  # what the data says
    caption: Callable[[Path], str]  # a figure's caption


_DEMO_SECTIONS = {
    "figure4": _DemoSection(
        title="Figure 4: PID, PID + feedforward and the composite law",
        figures=_figure4_figures,
        data="figure4.json",
        text=_figure4_text,
        caption=lambda f: _FIGURE4_CAPTIONS[f.name],
    ),
    "gantry": _DemoSection(
        title="Gantry with a listening slave",
        figures=lambda out: sorted(out.glob("sync_*.png")),
        data="sync.json",
        text=_gantry_text,
        caption=_gantry_caption,
    ),
    "linkage": _DemoSection(
        title="Multi-CPU linkage",
        figures=lambda out: sorted(out.glob("linkage_*.png")),
        data="linkage.json",
        text=_linkage_text,
        caption=lambda f: _LINKAGE_CAPTIONS.get(f.name, ""),
    ),
}


def _demo_section(out: Path, sid: str) -> str:
    sec = _DEMO_SECTIONS[sid]
    figures = sec.figures(out)
    if not figures:
        return ""
    parts = [f'<section id="{sid}"><h2>{sec.title}</h2>']
    if (out / sec.data).is_file():
        parts.append(sec.text(json.loads((out / sec.data).read_text(encoding="utf-8"))))
    parts += [_figure(_file_uri(f), f.name, _esc(sec.caption(f))) for f in figures]
    parts.append("</section>")
    return "".join(parts)


# --- the page --------------------------------------------------------------------------------

_STYLE = (
    "body{font-family:sans-serif;max-width:1100px;margin:0 auto;padding:0 16px;"
    "line-height:1.4;color:#222}"
    "img{max-width:100%;height:auto;display:block}"
    "figure{margin:1em 0}figcaption{font-size:.9em;color:#444}"
    "table{border-collapse:collapse;margin:.8em 0;font-size:.88em;max-width:100%}"
    "td,th{border:1px solid #ccc;padding:2px 6px;vertical-align:top;overflow-wrap:break-word}"
    "th{background:#f4f4f4}tr.fail{background:#fdd}"
    ".summary{border:2px solid #888;border-radius:6px;padding:.2em 1em;background:#f6f6f6}"
    ".summary.pass{border-color:#2a2;background:#efe}"
    ".summary.fail{border-color:#c22;background:#fee}"
    ".winner{border-left:4px solid #36c;padding:.3em .8em;background:#eef3ff}"
    ".comment{border-left:4px solid #999;padding:.3em .8em;background:#f7f7f7}"
    "code{background:#f3f3f3;overflow-wrap:anywhere}nav{font-size:.9em}"
)


def _jsonable(x: Any) -> Any:
    """``x`` as strict JSON: non-finite floats as None, numpy scalars and tuples converted."""
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple | np.ndarray):
        return [_jsonable(v) for v in x]
    return x


def _data_block(data: Mapping[str, Any]) -> str:
    text = json.dumps(_jsonable(data), sort_keys=True, ensure_ascii=False, allow_nan=False)
    text = text.replace("<", "\\u003c")  # no "</script>" inside the block
    return f'<script type="application/json" id="servotune-data">{text}</script>'


def _nav(body: str) -> str:
    links = []
    for sid, title in (
        ("summary", "Summary"),
        ("verification", "Verification"),
        ("identification", "Identification"),
        ("gains", "Gains"),
        ("loops", "Loops"),
        ("margins", "Margins"),
        ("responses", "Responses"),
        ("tables", "Query tables"),
        ("figure4", "Figure 4"),
        ("gantry", "Gantry"),
        ("linkage", "Linkage"),
    ):
        if f'id="{sid}"' in body:
            links.append(f'<a href="#{sid}">{title}</a>')
    return "<nav>" + " · ".join(links) + "</nav>"


def write_report(
    out_dir: str | Path,
    *,
    tuning_path: str | Path,
    rig_path: str | Path,
    verification: Any = None,
    seed: int = 0,
    fits: Mapping[str, Any] | None = None,
    spec_path: str | Path | None = None,
) -> Path:
    """Write ``report.html`` into ``out_dir`` (atomically) and return its path.

    Parameters
    ----------
    out_dir : str or Path
        Where to write; figures and data the demo wrote there first (``fit_*.png``,
        ``figure4.png``/``.json``, ``pareto.png``, ``sync_*.png``/``sync.json``,
        ``linkage_*.png``/``linkage.json``) are embedded (:data:`EMBEDDED_FIGURES`).
    tuning_path, rig_path : str or Path
        The tuning and the rig it is reported on (the rig's fit record gives the intervals).
    verification : Verification, optional
        Its verdict heads the page; its spec's move scenarios are drawn with their limits.
    seed : int
        Noise seed of the responses drawn.
    fits : mapping, optional
        Per axis, its identification (:class:`~servotune.identify.FitResult`, or its
        ``to_dict()``): the fit % is shown from it.
    spec_path : str or Path, optional
        The spec file verified against (named in the next step's commands).

    Returns
    -------
    Path
        Same inputs give the same bytes.
    """
    out = Path(out_dir)
    tuning = read_tuning(tuning_path)
    rig = load_rig(rig_path)
    tuning.check_rig(rig)
    prov = tuning.provenance
    limits = verification.spec.margins if verification is not None else DEFAULT_LIMITS
    margins = tuning_margins(tuning, rig, limits=limits)
    summary = summarise(
        verification,
        tuning_path=str(tuning_path),
        rig_path=str(rig_path),
        spec_path=None if spec_path is None else str(spec_path),
    )
    sections = [
        _summary_section(summary),
        _verification_section(verification, summary) if verification is not None else "",
        _identification_section(rig, out, fits),
        _gains_section(tuning),
        _bode_section(rig, tuning, margins, limits),
        _margins_section(tuning, margins, limits, verification),
        _response_section(rig, tuning, seed, verification),
        _tables_section(tuning),
        *(_demo_section(out, sid) for sid in _DEMO_SECTIONS),
    ]
    body = "\n".join(s for s in sections if s)
    head = (
        f"<h1>servotune report: {_esc(rig.name)}</h1>"
        f"<p>Tool {_esc(__version__)}; tuning {_esc(Path(tuning_path).name)} (seed "
        f"{_esc(prov.get('seed'))}, rule base {_esc(prov.get('rule_base'))}) on rig file "
        f"{_esc(Path(rig_path).name)}; tick period {rig.period_s * 1e3:.6g} ms (divisor "
        f"{tuning.timer_divisor}).</p>"
    )
    data = {
        "schema": "servotune.report/1",
        "version": __version__,
        "rig": rig.name,
        "summary": summary.to_dict(),
        "gains": tuning_summary(tuning),
        "margins": margins.to_dict(),
        "verification": None if verification is None else verification.to_dict(),
    }
    page = (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>servotune report: {_esc(rig.name)}</title><style>{_STYLE}</style></head><body>\n"
        + head
        + _nav(body)
        + "\n"
        + body
        + "\n"
        + _data_block(data)
        + "\n</body></html>\n"
    )
    path = out / "report.html"
    atomic_write_text(path, page)
    return path
