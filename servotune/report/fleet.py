"""The fleet report page (``servotune fit LOGS --fleet out.parquet --fleet-report fleet.html``):
one self-contained HTML page with the fleet's summary in words, the histograms of every
parameter with the outliers and the drifted machines marked (:func:`servotune.plot.plot_fleet`),
the spread table, the flagged and the failed logs, and the summary as a JSON block.

Built from the same pieces as the tuning report (:mod:`servotune.report.html`: page style,
tables, embedded PNG, the JSON data block).
"""

from __future__ import annotations

from pathlib import Path

from servotune._version import __version__
from servotune.fleet import FLEET_SCHEMA, FleetResult
from servotune.io.files import atomic_write_text
from servotune.plot import plot_fleet
from servotune.report.page import (
    PAGE_STYLE,
    data_block,
    escape_html,
    figure_html,
    fmt_value,
    paragraph_html,
    png_uri,
    table_html,
)

__all__ = ["fleet_report_html", "write_fleet_report"]


def fleet_report_html(result: FleetResult, *, title: str = "fleet") -> str:
    """The report page's HTML (same result → same text, apart from matplotlib's PNG bytes)."""
    s = result.summary
    summary = (
        '<section id="summary"><h2>Summary</h2><pre>' + escape_html(s.text()) + "</pre></section>"
    )
    intro = paragraph_html(f"Tool {__version__}; {s.n_logs} logs, {s.n_machines} machines.")
    parts = [f"<h1>servotune fleet report: {escape_html(title)}</h1>", intro, summary]
    uri = png_uri(plot_fleet(result))
    parts.append(
        '<section id="distributions"><h2>Distributions</h2>'
        + figure_html(
            uri,
            "histograms of the fleet's parameters",
            "Latest fit of each machine. Blue band: no outlier (|robust z| within the "
            "limit); red: outliers against the fleet; orange arrows: drift from a "
            "machine's previous fit to its latest (intervals apart, change above "
            f"{result.summary.drift_k:g}× the fleet's spread).",
        )
        + "</section>"
    )
    head = ["axis", "parameter", "unit", "machines", "median", "spread (MAD/0.6745)", "5 %", "95 %"]
    rows = [
        [
            sp.axis,
            sp.parameter,
            sp.unit,
            sp.n_machines,
            fmt_value(sp.median),
            fmt_value(sp.spread),
            fmt_value(sp.q05),
            fmt_value(sp.q95),
        ]
        for sp in s.spreads
    ]
    parts.append('<section id="spread"><h2>Spread</h2>' + table_html(head, rows) + "</section>")
    flagged = [r for r in result.rows if r.outliers or r.drift]
    head = ["machine", "date", "file", "axis", "outlier in", "drifted in"]
    rows = [
        [r.machine_id, r.date, r.file, r.axis, ", ".join(r.outliers), ", ".join(r.drift)]
        for r in flagged
    ]
    parts.append(
        '<section id="flagged"><h2>Flagged machines</h2>'
        + (table_html(head, rows, [True] * len(rows)) if rows else paragraph_html("None."))
        + "</section>"
    )
    if s.failures:
        rows = [list(f) for f in s.failures]
        parts.append(
            '<section id="failed"><h2>Failed logs</h2>'
            + table_html(["file", "axis", "error"], rows, [True] * len(rows))
            + "</section>"
        )
    data = {"schema": FLEET_SCHEMA, "version": __version__, "summary": s.to_dict()}
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>servotune fleet report: {escape_html(title)}</title>"
        f"<style>{PAGE_STYLE}</style></head>"
        "<body>\n" + "\n".join(parts) + "\n" + data_block(data) + "\n</body></html>\n"
    )


def write_fleet_report(result: FleetResult, path: str | Path, *, title: str = "fleet") -> Path:
    """Write the fleet report page to ``path`` atomically and return the path."""
    atomic_write_text(path, fleet_report_html(result, title=title))
    return Path(path)
