"""The report's sections on the result: the summary, the verification, the identification, the
tuned gains and their query tables (:func:`servotune.report.html.write_report` puts them on
the page)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from servotune.identify.model import ALL_PARAMS, UNITS
from servotune.laws.fuzzy_pid import TABLE_NAMES, FuzzyPIDConstants
from servotune.plot import QUERY_TABLE_LABELS, plot_query_tables
from servotune.report.page import (
    code_html,
    escape_html,
    figure_html,
    file_uri,
    fmt_value,
    paragraph_html,
    png_uri,
    table_html,
)
from servotune.report.summary import ReportSummary, search_notes
from servotune.rig import FIT_PCT_KEYS, PlantFit, Rig
from servotune.tune.workflow import tuning_summary
from servotune.tuning import Tuning
from servotune.validate import show_number

__all__ = [
    "gains_section",
    "identification_section",
    "summary_section",
    "tables_section",
    "verification_section",
    "with_interval",
]


def summary_section(s: ReportSummary) -> str:
    cls = {"PASSED": "pass", "FAILED": "fail"}.get(s.verdict, "none")
    items = []
    if s.verified:
        items.append(f"{s.failed} of {s.total} limits and checks failed.")
        if s.tightest is not None:
            label = "Most broken limit" if s.tightest.relative_margin < 0 else "Tightest margin"
            items.append(f"{label}: {escape_html(s.tightest.describe())}.")
        if s.montecarlo is not None:
            items.append(escape_html(s.montecarlo_text()) + ".")
        for f in s.failures[:5]:
            items.append("Failed: " + escape_html(f))
        if len(s.failures) > 5:
            items.append(f"… and {len(s.failures) - 5} more (see the verification below).")
    else:
        items.append("This report was written without a verification.")
    lis = "".join(f"<li>{x}</li>" for x in items)
    return (
        f'<section id="summary" class="summary {cls}"><h2>Summary: {escape_html(s.verdict)}</h2>'
        f'<ul>{lis}</ul><p class="next"><strong>What to do next:</strong> '
        f"{code_html(s.next_step)}</p></section>"
    )


def verification_section(v: Any, s: ReportSummary) -> str:
    rows, bad = [], []
    for r in v.rows:
        rel = r.relative_margin
        rel_text = "n/a" if rel is None or not math.isfinite(rel) else f"{100.0 * rel:.0f} %"
        rows.append(
            [
                r.scenario,
                r.axis,
                r.quantity,
                fmt_value(r.limit, r.unit),
                fmt_value(r.worst, r.unit),
                fmt_value(r.margin, r.unit),
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
        + paragraph_html(
            f"Spec {v.spec.name!r} on rig {v.rig_name!r}, seed {v.seed}: every scenario on the "
            f"nominal plants and {v.plant_sets - 1} Monte-Carlo plant sets; a limit holds "
            "if its worst value over all of them does. Margin: limit − worst (and as % of the "
            "limit)."
        )
        + (paragraph_html(mc + ".") if mc else "")
        + table_html(
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
        + table_html(["check", "", "detail"], checks, [row[1] == "FAIL" for row in checks])
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


def identification_section(rig: Rig, out: Path, fits: Mapping[str, Any] | None) -> str:
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
                shown, interval = with_interval(float(value), float(ci[0]), float(ci[1]))
                how = "fitted"
            elif fit is not None:
                shown, interval = show_number(float(value)), "—"
                how = "fitted" if p in fit.structure else "left out (0)"
            else:
                shown, interval, how = show_number(float(value)), "—", "as in the rig file"
            rows.append([p, shown, UNITS[p], interval, how])
        head = f"<h3>{escape_html(a.name)} ({escape_html(a.role)})</h3>"
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
        where = ""
        if not pct and fit is not None:
            pct = _recorded_fit_pct(fit)
            where = " as recorded in the rig file"
        if pct:
            v, y = pct.get("velocity", {}), pct.get("position", {})
            note += (
                f" Fit (MATLAB compare, 100 % is perfect){where}: speed "
                f"{_pct(v.get('estimation'))} on the whole log, {_pct(v.get('validation'))} "
                f"cross-validated; position {_pct(y.get('estimation'))} / "
                f"{_pct(y.get('validation'))}."
            )
        elif fit is not None:
            note += (
                " Fit %: not recorded in the rig file's fit record (`servotune fit -o` "
                "records it; fit the log again to have it here)."
            )
        else:
            note += " Fit %: none (not fitted)."
        parts.append(
            head
            + paragraph_html(note)
            + table_html(["parameter", "value", "unit", "95 % interval", ""], rows)
        )
    for f in files:
        parts.append(figure_html(file_uri(f), f.name, escape_html(_FIT_CAPTION)))
    parts.append("</section>")
    return "".join(parts)


def _recorded_fit_pct(fit: PlantFit) -> dict[str, dict[str, float | None]] | None:
    """The fit figures a rig's fit record holds, shaped like a fit's ``fit_pct`` (None: none)."""
    if all(getattr(fit, k) is None for k in FIT_PCT_KEYS):
        return None
    return {
        q: {
            "estimation": getattr(fit, f"{q}_fit_pct"),
            "validation": getattr(fit, f"{q}_fit_cv_pct"),
        }
        for q in ("velocity", "position")
    }


def with_interval(value: float, lo: float, hi: float) -> tuple[str, str]:
    """A value and its interval with enough significant digits to tell the ends apart.

    >>> with_interval(12287.89, 12287.59, 12288.19)
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


def gains_section(tuning: Tuning) -> str:
    summary = tuning_summary(tuning)
    rows = []
    for name, ax in summary["axes"].items():
        g = ax["gains"]
        rng = ", ".join(
            f"{label} {fmt_value(g[k + '_range'][0])}–{fmt_value(g[k + '_range'][1])}"
            for k, label in (("kp", "Kp"), ("ki", "Ki·T"), ("kd", "Kd/T"))
            if k + "_range" in g
        )
        rows.append(
            [
                name,
                ax["law"],
                fmt_value(ax["lock_gain"]),
                fmt_value(g.get("kp")),
                fmt_value(g.get("ki_t")),
                fmt_value(g.get("kd_t")),
                fmt_value(g.get("k1_t")),
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
        + table_html(
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
        + "".join(paragraph_html(n) for n in notes)
        + "</section>"
    )


def tables_section(tuning: Tuning) -> str:
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
            parts.append(figure_html(png_uri(fig), f"{name} query tables", escape_html(cap)))
    if not parts:
        return ""
    return (
        '<section id="tables"><h2>Query tables (as the runtime holds them)</h2>'
        + "".join(parts)
        + "</section>"
    )
