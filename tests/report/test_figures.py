"""Every figure the report embeds has its axes labelled with units, checked on the matplotlib
figure objects (issue 20, point 4); the figures the issue found unreadable say what they show."""

from __future__ import annotations

import doctest
import re

import matplotlib.pyplot as plt
import numpy as np

import servotune.plot
import servotune.report.html
from report.conftest import ReportBuild, _fake_linkage
from report.figures_check import axis_unit_problems
from servotune.plot import plot_fit, plot_query_tables, plot_queue_levels, residual_step


def test_every_embedded_figure_has_units_on_its_axes(report_build: ReportBuild) -> None:
    # each figure saved while the report was built (the demo's products first, then the ones
    # the report draws itself), checked before it was written
    bad = {where: problems for where, problems in report_build.figures if problems}
    assert not bad, bad
    # and they are every image of the page: one saved figure per <img>
    page = report_build.path.read_text(encoding="utf-8")
    assert len(re.findall(r"<img ", page)) == len(report_build.figures)
    # every figure kind the report takes from its output directory was among them
    for pattern in servotune.report.html.EMBEDDED_FIGURES:
        assert list(report_build.out.glob(pattern)), pattern


def test_the_check_finds_a_label_without_a_unit() -> None:
    fig, (a, b) = plt.subplots(2, 1, sharex=True)
    a.set_ylabel("counts")  # issue 20: a bare word is not a unit
    b.set_ylabel("code [codes]")
    b.set_xlabel("time [s]")
    problems = axis_unit_problems(fig)
    plt.close(fig)
    assert len(problems) == 1 and "'counts'" in problems[0]


def test_a_constant_table_shows_its_value_not_a_grey_square() -> None:
    n = 3
    k1 = np.full((2 * n + 1, 2 * n + 1), 3.843)
    kp = np.add.outer(np.arange(-n, n + 1), np.arange(-n, n + 1)) * 0.01 + 0.5
    labels = servotune.plot.QUERY_TABLE_LABELS
    fig = plot_query_tables({labels["kp"]: kp, labels["k1"]: k1}, n, "tables")
    texts = [t.get_text() for t in fig.axes[1].texts]  # the k1 panel (the colour bar is last)
    assert any("3.843" in t for t in texts), texts
    # the scheduled table keeps its colour bar (labelled), the constant one needs none
    assert sum(getattr(a, "_colorbar", None) is not None for a in fig.axes) == 1
    assert not axis_unit_problems(fig)
    plt.close(fig)


def test_the_fit_plot_marks_the_split_and_states_the_residual_step() -> None:
    n, split, period = 400, 200, 0.004
    pos = np.cumsum(np.sin(np.arange(n) / 9.0) * 30.0)
    sim = pos + np.where(np.arange(n) >= split, -2.0, 0.0)  # residual steps by +2 counts
    assert residual_step(pos - sim, split) == 2.0
    fig = plot_fit(pos, sim, period, split, "fit")
    for ax in fig.axes:  # the split drawn on every panel, at its time
        xs = [ln.get_xdata()[0] for ln in ax.get_lines() if ln.get_linestyle() == ":"]
        assert xs and abs(xs[0] - split * period) < 1e-12
    said = " ".join(t.get_text() for t in fig.axes[2].texts)
    assert "+2.0 counts" in said and "restarts" in said
    plt.close(fig)
    # no split inside the log (a plot of one half): nothing to mark
    fig = plot_fit(pos, pos, period, 0)
    assert not fig.axes[2].texts
    plt.close(fig)


def test_the_queue_plot_reads_as_a_band_and_a_window() -> None:
    link = _fake_linkage()
    fig = plot_queue_levels(link)
    whole, window = fig.axes
    # the whole run as each CPU's lowest/highest level per bin, not 3000 steps per line
    assert max(len(ln.get_xdata()) for ln in whole.get_lines()) <= 400
    lo, hi = window.get_xlim()
    assert 0 < hi - lo <= 0.1 * float(link.time_s[-1])  # a few broadcast periods
    assert not axis_unit_problems(fig)
    plt.close(fig)
    # on a given axes (the notebooks zoom it with set_xlim): every pop drawn
    fig, ax = plt.subplots()
    plot_queue_levels(link, ax=ax)
    assert max(len(ln.get_xdata()) for ln in ax.get_lines()) >= link.time_s.size
    plt.close(fig)


def test_doctests_of_the_report_modules() -> None:
    import servotune.report.summary

    for module in (servotune.plot, servotune.report.html, servotune.report.summary):
        result = doctest.testmod(module)
        assert result.failed == 0 and result.attempted > 0, module.__name__
