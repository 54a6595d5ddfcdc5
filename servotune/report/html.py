"""The HTML report: one self-contained page (plots embedded as PNG data URIs, the numbers as a
JSON block), readable at 1280 px.

Sections, each with its numbers and units: a summary (verdict, failed checks, the tightest
margin, the Monte-Carlo pass fraction and what to do next, :mod:`.summary`); the verification
table and checks; the identification (fitted parameters with their 95 % intervals and fit %,
the fit plots with the validation split marked); the resonance (the rig's modes and a measured
frequency response against the rig's model, when there are either); the tuned gains; Bode plots
of each task loop with its margins (python-control, the discrete loop as the engine runs it)
and why the axes' phase margins differ; the margins of every loop the runtime can run (a table
and heat maps over the query-table cells); the responses in the bit-true loop against the
spec's envelope; the query-table heat maps; and — when the output directory holds them
(``make demo`` writes them first) — Figure 4 with its table and stated winner, the gantry and
the linkage.

The page is put together here (:func:`write_report`) from :mod:`.page` (escaping, tables,
embedded PNGs, the style sheet and the data block), :mod:`.sections` (summary, verification,
identification, gains, query tables), :mod:`.resonance` (modes, FRF), :mod:`.filters` (output
filters: margins with and without, Bode, a shaped move), :mod:`.loops` (Bode,
margins, responses) and :mod:`.demo_sections` (Figure 4, gantry, linkage); the names other
modules import from here are re-exported. Outside this package the only module that imports
matplotlib is :mod:`servotune.plot` (here, :mod:`.page` saves the figures as PNG).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from servotune._version import __version__
from servotune.analysis.margins import DEFAULT_LIMITS, tuning_margins
from servotune.io.files import atomic_write_text
from servotune.plot import (
    plot_comparison,
    plot_fit,
    plot_pareto,
    plot_queue_levels,
    plot_radial_deviation,
    plot_sync_errors,
)
from servotune.report.demo_sections import DEMO_SECTIONS, demo_section
from servotune.report.filters import filters_section
from servotune.report.loops import bode_section, loop_response, margins_section, response_section
from servotune.report.page import (
    escape_html,
    page_html,
)
from servotune.report.resonance import FrfSource, resonance_section
from servotune.report.sections import (
    gains_section,
    identification_section,
    summary_section,
    tables_section,
    verification_section,
    with_interval,
)
from servotune.report.summary import summarise
from servotune.rig import load_rig
from servotune.tune.workflow import tuning_summary
from servotune.tuning import read_tuning

__all__ = ["EMBEDDED_FIGURES", "loop_response", "write_report"]

__test__ = {"with_interval": with_interval}  # doctest.testmod(this module) runs its examples

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


def _nav(body: str) -> str:
    links = []
    for sid, title in (
        ("summary", "Summary"),
        ("verification", "Verification"),
        ("identification", "Identification"),
        ("resonance", "Resonance"),
        ("filters", "Output filters"),
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
    frf: Mapping[str, FrfSource] | None = None,
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
        ``to_dict()``): the fit % is shown from it; without it, from the rig's fit record
        when that records the fit % (``servotune fit -o`` does).
    spec_path : str or Path, optional
        The spec file verified against (named in the next step's commands).
    frf : mapping, optional
        Per axis, its measured frequency response: the path of a ``servotune frf`` JSON file
        or an :class:`~servotune.analysis.frf.Frf`, drawn against the rig's model in the
        resonance section (:mod:`.resonance`; shown when some axis has modes or an FRF is
        given, docs/frf.md#in-the-report).

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
    resonance, resonance_data = resonance_section(rig, frf)
    filters, filters_data = filters_section(tuning, rig, margins.loops, frf)
    sections = [
        summary_section(summary),
        verification_section(verification, summary) if verification is not None else "",
        identification_section(rig, out, fits),
        resonance,
        filters,
        gains_section(tuning),
        bode_section(rig, tuning, margins, limits),
        margins_section(tuning, margins, limits, verification),
        response_section(rig, tuning, seed, verification),
        tables_section(tuning),
        *(demo_section(out, sid) for sid in DEMO_SECTIONS),
    ]
    body = "\n".join(s for s in sections if s)
    head = (
        f"<h1>servotune report: {escape_html(rig.name)}</h1>"
        f"<p>Tool {escape_html(__version__)}; tuning {escape_html(Path(tuning_path).name)} (seed "
        f"{escape_html(prov.get('seed'))}, rule base {escape_html(prov.get('rule_base'))}) on rig "
        f"file "
        f"{escape_html(Path(rig_path).name)}; tick period {rig.period_s * 1e3:.6g} ms (divisor "
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
    if resonance_data is not None:  # without modes and FRFs the page keeps its bytes
        data["resonance"] = resonance_data
    if filters_data is not None:  # without filters too
        data["filters"] = filters_data
    page = page_html(f"servotune report: {rig.name}", head + _nav(body) + "\n" + body, data)
    path = out / "report.html"
    atomic_write_text(path, page)
    return path
