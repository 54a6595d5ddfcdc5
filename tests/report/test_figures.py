"""Every figure the report embeds has its axes labelled with units, checked on the matplotlib
figure objects; the figures that were once unreadable say what they show."""

from __future__ import annotations

import doctest
import re
from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.colors import to_hex
from matplotlib.lines import Line2D

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
    a.set_ylabel("counts")  # a bare word is not a unit
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
    assert len(fig.axes) == 2 * len(link.cpus)  # a row per CPU: the whole run | a window
    wholes, windows = fig.axes[0::2], fig.axes[1::2]
    for whole, window in zip(wholes, windows, strict=True):
        # the whole run as the CPU's lowest/highest level per bin, not 3000 steps per line
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


def _twin_cpus() -> SimpleNamespace:
    """The stand-in linkage with three CPUs whose queues hold exactly the same levels."""
    link = _fake_linkage()
    c = link.cpus[0]
    twins = tuple(SimpleNamespace(**{**vars(c), "name": name}) for name in ("s1", "s2", "s3"))
    return SimpleNamespace(**{**vars(link), "cpus": twins})


def _data_lines(ax: Axes) -> list[Line2D]:
    """The lines that draw queue levels (not the horizontal and vertical markers)."""
    return [ln for ln in ax.get_lines() if len(ln.get_xdata()) > 2]


def test_every_cpu_keeps_a_visible_line_when_the_queues_coincide() -> None:
    link = _twin_cpus()
    colors = [to_hex(f"C{i}") for i in range(3)]
    fig = plot_queue_levels(link)
    rows = [fig.axes[2 * i : 2 * i + 2] for i in range(3)]
    for i, row in enumerate(rows):
        for ax in row:
            # the CPU's own panels: its levels, in its colour and no other CPU's, unshifted
            lines = _data_lines(ax)
            assert lines and {to_hex(ln.get_color()) for ln in lines} == {colors[i]}
            ys = np.concatenate([np.asarray(ln.get_ydata(), dtype=float) for ln in lines])
            assert (ys.min(), ys.max()) == (9, 13)  # the stand-in's levels 9..13
            assert f"s{i + 1}" in ax.get_ylabel()
            # every row on the same level scale: shared with the first row's
            assert ax.get_ylim() == rows[0][0].get_ylim()
    assert [row[1].get_xlim() for row in rows] == [rows[0][1].get_xlim()] * 3  # same window
    plt.close(fig)
    # on one axes: each CPU a line of its own style, the later ones above and narrower, so
    # that every one shows through the gaps of those above it; the legend names each
    fig, ax = plt.subplots()
    plot_queue_levels(link, ax=ax)
    lines = _data_lines(ax)
    assert [to_hex(ln.get_color()) for ln in lines] == colors
    assert len({(ln.get_linestyle(), str(ln._dash_pattern)) for ln in lines}) == 3
    assert [ln.get_zorder() for ln in lines] == sorted({ln.get_zorder() for ln in lines})
    widths = [ln.get_linewidth() for ln in lines]
    assert widths == sorted(widths, reverse=True) and len(set(widths)) == 3
    for ln in lines:  # the data itself, not moved to make room
        assert np.array_equal(ln.get_ydata(), link.cpus[0].queue_level)
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert [t.split(" ")[0] for t in legend] == ["s1", "s2", "s3"]
    plt.close(fig)


def test_doctests_of_the_report_modules() -> None:
    import servotune.report.summary

    for module in (servotune.plot, servotune.report.html, servotune.report.summary):
        result = doctest.testmod(module)
        assert result.failed == 0 and result.attempted > 0, module.__name__
