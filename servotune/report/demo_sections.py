"""The report's sections on what the demo wrote into the output folder first: Figure 4 (its
table and stated winner), the gantry and the linkage, each with its figures and its data."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from servotune.report.page import (
    escape_html,
    figure_html,
    file_uri,
    fmt_value,
    paragraph_html,
    table_html,
)

__all__ = ["DEMO_SECTIONS", "demo_section"]


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
                "<strong>Winner on the tuning objective: "
                f"{escape_html(' and '.join(best))}</strong> "
                f"(ITAE of the sync error {top:.4g} counts·s²). "
            )
        parts.append(
            f'<div class="winner">{head}' + " ".join(escape_html(s) for s in verdicts) + "</div>"
        )
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
            cells = [f"<th>{escape_html(_STRUCTURES.get(s, s))}</th>"]
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
            cells.append(f"<td>{escape_html(sits)}</td>")
            rows.append("<tr>" + "".join(cells) + "</tr>")
        head = "".join(f"<th>{escape_html(label)}</th>" for _k, label, *_ in cols)
        seeds = ", ".join(str(x) for x in data.get("seeds", []))
        parts.append(
            paragraph_html(
                f"Seeds {seeds}; held-out scenarios: "
                f"{', '.join(data.get('heldout_scenarios', []))}. Best of each column "
                "in bold; with several seeds the values are means, ranges in brackets."
            )
            + f"<table><tr><th>structure</th>{head}<th>active constraints</th></tr>"
            f"{''.join(rows)}</table>"
        )
    parts += [paragraph_html(s) for s in statement]
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
                fmt_value(r.get("max_sync_error_counts")),
                fmt_value(r.get("rms_sync_error_counts")),
                r.get("warning_cycles"),
                "no" if trip is None else f"at {fmt_value(trip)} s",
            ]
        )
        bad.append(trip is not None)
    return paragraph_html(
        f"Gantry {doc.get('name', '')!r}: deployed topology "
        f"{doc.get('topology', '')}, bus cycle {fmt_value(doc.get('cycle_s'), 's')}, "
        f"latency {doc.get('latency_cycles')} cycle(s); "
        + (
            "PASSED."
            if doc.get("passed")
            else "FAILED: " + "; ".join(map(str, doc.get("failed", [])))
        )
    ) + table_html(
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
        paragraph_html(
            f"Linkage {doc.get('name', '')!r}: bus frame {bus.get('frame_bytes')} bytes every "
            f"{fmt_value(1e3 * bus.get('broadcast_period_s', math.nan), 'ms')} (utilisation "
            f"{fmt_value(100 * bus.get('utilisation', math.nan), '%')}); contour error max "
            f"{fmt_value(doc.get('contour_max_counts'), 'counts')}, RMS "
            f"{fmt_value(doc.get('contour_rms_counts'), 'counts')}; "
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
        table_html(
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
            fmt_value(a.get("circularity_counts")),
            fmt_value(a.get("circularity_whole_counts")),
        ]
        for a in doc.get("arcs", [])
    ]
    if arcs:
        parts.append(
            table_html(
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
    "linkage_queues.png": "Each slave CPU's queue level before every pop, one row per CPU "
    "on the same scales (CPUs whose queues move alike would hide each other on one panel). "
    "Left: over the whole run, the lowest and highest level in each time bin (the level is "
    "a sawtooth at the broadcast period, too fast to draw tick by tick over seconds); right: "
    "a window of a few broadcast periods with every pop.",
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


DEMO_SECTIONS = {
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


def demo_section(out: Path, sid: str) -> str:
    sec = DEMO_SECTIONS[sid]
    figures = sec.figures(out)
    if not figures:
        return ""
    parts = [f'<section id="{sid}"><h2>{sec.title}</h2>']
    if (out / sec.data).is_file():
        parts.append(sec.text(json.loads((out / sec.data).read_text(encoding="utf-8"))))
    parts += [figure_html(file_uri(f), f.name, escape_html(sec.caption(f))) for f in figures]
    parts.append("</section>")
    return "".join(parts)
