"""Figures (the only module besides report.py that imports matplotlib)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from servotune.sim.engine import Trace

if TYPE_CHECKING:
    from servotune.arch.linkage import LinkageResult

__all__ = [
    "plot_bode",
    "plot_comparison",
    "plot_fit",
    "plot_lock_hold",
    "plot_pareto",
    "plot_query_tables",
    "plot_queue_levels",
    "plot_radial_deviation",
    "plot_sync_errors",
    "plot_tracking",
    "save_figure",
]

_PNG_META = {"Software": None}


def save_figure(fig: plt.Figure, path: str | Path) -> None:
    """Save a figure as PNG without a software stamp (same input → same bytes), then close it."""
    p = Path(path)
    tmp = p.with_name(f".{p.name}.tmp.png")
    fig.savefig(tmp, dpi=110, metadata=_PNG_META)
    plt.close(fig)
    tmp.replace(p)


def _finish(fig: plt.Figure, axs: Sequence[plt.Axes], title: str) -> plt.Figure:
    """Grid and legend on every panel, ``title`` (if any) on the first, then lay it out."""
    for a in axs:
        a.grid(True, alpha=0.3)
        a.legend(loc="best", fontsize=8)
    if title:
        axs[0].set_title(title)
    fig.tight_layout()
    return fig


def plot_tracking(trace: Trace, title: str = "") -> plt.Figure:
    """Positions, errors, D/A codes and modes of a trace (one column per axis)."""
    t = trace.time_s
    fig, axs = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for i, name in enumerate(trace.axis_names):
        axs[0].plot(t, trace.pos_counts[:, i], label=f"{name} position")
        axs[1].plot(t, trace.err_counts[:, i], label=f"{name} error (r − y)")
        axs[2].step(t, trace.code[:, i], where="post", label=f"{name} D/A code")
    if trace.ref_counts.shape[1] and np.any(trace.ref_counts):
        axs[0].plot(t, trace.ref_counts[:, 0], "k--", lw=0.8, label="reference")
    axs[0].set_ylabel("counts")
    axs[1].set_ylabel("counts")
    axs[2].set_ylabel("code")
    axs[2].set_xlabel("time [s]")
    return _finish(fig, axs, title)


def plot_lock_hold(
    trace: Trace, bands: dict[str, tuple[int, int]], settle_s: float, title: str = ""
) -> plt.Figure:
    """Lock-module hold: noiseless position error vs the predicted band, per axis."""
    t = trace.time_s
    fig, axs = plt.subplots(len(trace.axis_names), 1, figsize=(9, 2.8 * len(trace.axis_names)),
                            sharex=True, squeeze=False)  # fmt: skip
    for i, name in enumerate(trace.axis_names):
        ax = axs[i, 0]
        e = -np.floor(trace.true_pos_counts[:, i])
        ax.step(t, e, where="post", lw=0.8, label=f"{name}: target − position (noiseless)")
        lo, hi = bands[name]
        ax.axhspan(lo - 0.5, hi + 0.5, color="C2", alpha=0.2, label=f"predicted band [{lo}, {hi}]")
        ax.axhline(4, color="C3", ls=":", lw=0.8)
        ax.axhline(-4, color="C3", ls=":", lw=0.8, label="±1 pulse (±4 counts)")
        ax.axvline(settle_s, color="k", ls="--", lw=0.6)
        ax.set_ylabel("counts")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axs[-1, 0].set_xlabel("time [s]")
    if title:
        axs[0, 0].set_title(title)
    fig.tight_layout()
    return fig


def plot_fit(
    pos_counts: np.ndarray,
    sim_pos_counts: np.ndarray,
    period_s: float,
    split_index: int,
    title: str = "",
) -> plt.Figure:
    """Measured vs simulated position and velocity, and the residuals, of an identification.

    Parameters
    ----------
    pos_counts, sim_pos_counts : ndarray
        Measured and simulated position [counts] (the simulation restarts at the split).
    period_s : float
        Sample period [s].
    split_index : int
        First sample of the validation part.
    """
    time_s = np.arange(len(pos_counts), dtype=np.int64) * period_s
    fig, axs = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    v_m = np.diff(pos_counts) / period_s
    v_s = np.diff(sim_pos_counts) / period_s
    t_v = time_s[:-1]
    axs[0].plot(time_s, pos_counts, lw=0.8, label="measured")
    axs[0].plot(time_s, sim_pos_counts, lw=0.8, ls="--", label="simulated")
    axs[0].set_ylabel("position [counts]")
    axs[1].plot(t_v, v_m, lw=0.5, label="measured (Δcounts/T)")
    axs[1].plot(t_v, v_s, lw=0.8, label="simulated")
    axs[1].set_ylabel("speed [counts/s]")
    axs[2].plot(time_s, pos_counts - sim_pos_counts, lw=0.6, label="position residual")
    axs[2].set_ylabel("residual [counts]")
    axs[2].set_xlabel("time [s]")
    for a in axs:
        a.axvline(time_s[split_index], color="k", ls=":", lw=0.8)
        a.grid(True, alpha=0.3)
        a.legend(loc="upper right", fontsize=8)
    axs[0].set_title(title or "identification: estimation | validation")
    fig.tight_layout()
    return fig


def plot_comparison(traces: dict[str, Trace], slave: int, title: str = "") -> plt.Figure:
    """Figure 4: the slave's speed and sync error under each tuned structure.

    Parameters
    ----------
    traces : dict of str to Trace
        Per structure (``pid``, ``pid_ff``, ``composite``), the same scenario.
    slave : int
        The slave's axis column.
    """
    fig, axs = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
    labels = {"pid": "PID", "pid_ff": "PID + feedforward", "composite": "fuzzy-PID + feedforward"}
    master_drawn = False
    for name, tr in traces.items():
        t = tr.time_s
        master = 1 - slave if len(tr.axis_names) == 2 else 0
        if not master_drawn:
            axs[0].plot(t, tr.speed_cps[:, master], "k--", lw=0.8, label="master")
            master_drawn = True
        axs[0].plot(t, tr.speed_cps[:, slave], lw=0.9, label=labels.get(name, name))
        axs[1].plot(t, tr.err_counts[:, slave], lw=0.9, label=labels.get(name, name))
    axs[0].set_ylabel("slave speed [counts/s]")
    axs[1].set_ylabel("sync error [counts]")
    axs[1].set_xlabel("time [s]")
    return _finish(
        fig, axs, title or "slave tracking: PID, PID + feedforward, composite (Figure 4)"
    )


def plot_pareto(points: Sequence[Any], title: str = "") -> plt.Figure:
    """The tracking/robustness trade-off: ITAE and max sync error against the worst Ms, one
    colour per structure, its front joined (:func:`servotune.tune.compare.pareto_front`)."""
    fig, axs = plt.subplots(1, 2, figsize=(10, 4.2))
    labels = {"pid": "PID", "pid_ff": "PID + feedforward", "composite": "fuzzy-PID + feedforward"}
    for structure in dict.fromkeys(p.structure for p in points):
        mine = [p for p in points if p.structure == structure and p.feasible]
        for ax, key, front in ((axs[0], "itae", "front_itae"), (axs[1], "max_sync_counts",
                                                                 "front_max")):  # fmt: skip
            line = ax.plot([p.worst_ms for p in mine], [getattr(p, key) for p in mine], "o",
                           ms=4, alpha=0.5)[0]  # fmt: skip
            on = sorted((p for p in mine if getattr(p, front)), key=lambda p: p.worst_ms)
            ax.plot([p.worst_ms for p in on], [getattr(p, key) for p in on], "-o", ms=5,
                    color=line.get_color(), label=labels.get(structure, structure))  # fmt: skip
    axs[0].set_ylabel("ITAE of the sync error [counts·s²]")
    axs[1].set_ylabel("max |sync error| [counts]")
    for ax in axs:
        ax.set_xlabel("worst peak sensitivity Ms over the plant set")
    return _finish(fig, axs, title or "tracking against robustness (each structure's front)")


def plot_sync_errors(traces: Sequence[object], case: str, title: str = "") -> plt.Figure:
    """Sync error over time, one line per topology, for one case of a gantry comparison
    (:func:`servotune.arch.gantry.compare_topologies`' traces)."""
    fig, ax = plt.subplots(figsize=(8, 4))
    for tr in traces:
        if tr.case != case:  # type: ignore[attr-defined]
            continue
        ax.plot(tr.time_s, tr.sync_error, lw=1, label=tr.topology)  # type: ignore[attr-defined]
        if tr.trip_cycle >= 0:  # type: ignore[attr-defined]
            ax.axvline(tr.trip_cycle * tr.cycle_s, color="k", ls=":", lw=0.8)  # type: ignore[attr-defined]
    ax.set_xlabel("time [s]")
    ax.set_ylabel("sync error y_master − y_slave [counts]")
    ax.set_title(title or f"gantry sync error, {case} case")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    fig.tight_layout()
    return fig


def plot_query_tables(tables: dict[str, np.ndarray], n: int, title: str = "") -> plt.Figure:
    """Heat maps of query tables (row E, column EC, levels −n…n)."""
    names = list(tables)
    fig, axs = plt.subplots(1, len(names), figsize=(3.2 * len(names), 3.2), squeeze=False)
    ext = (-n - 0.5, n + 0.5, n + 0.5, -n - 0.5)
    for ax, name in zip(axs[0], names, strict=True):
        im = ax.imshow(np.asarray(tables[name], dtype=float), extent=ext, cmap="coolwarm")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("EC level")
        ax.set_ylabel("E level")
        fig.colorbar(im, ax=ax, fraction=0.046)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def plot_bode(responses: dict[str, tuple[np.ndarray, np.ndarray]], title: str = "") -> plt.Figure:
    """Open-loop Bode plots: per name ``(omega [rad/s], L(e^{jωT}) complex)``."""
    fig, axs = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for name, (w, resp) in responses.items():
        axs[0].semilogx(w, 20 * np.log10(np.abs(resp)), label=name)
        axs[1].semilogx(w, np.degrees(np.unwrap(np.angle(resp))), label=name)
    axs[0].axhline(0.0, color="k", lw=0.6)
    axs[1].axhline(-180.0, color="k", lw=0.6)
    axs[0].set_ylabel("|L| [dB]")
    axs[1].set_ylabel("phase [deg]")
    axs[1].set_xlabel("frequency [rad/s]")
    for a in axs:
        a.grid(True, which="both", alpha=0.3)
        a.legend(loc="best", fontsize=8)
    axs[0].set_title(title or "open loop L = C · LSB · P (discrete, as the engine runs it)")
    fig.tight_layout()
    return fig


def plot_queue_levels(result: LinkageResult, ax: plt.Axes | None = None) -> plt.Figure:
    """Queue level of every slave CPU before each pop over master time (seed 002 linkage).

    Each slave's level (setpoints per axis) is drawn with its queue depth (dotted) and its
    first underrun / overrun (dashed / dash-dot vertical line); the resync instants are grey.
    """
    if ax is None:
        fig, ax = plt.subplots(figsize=(9, 3.8))
    else:
        fig = ax.figure
    for i, c in enumerate(result.cpus):
        color = f"C{i}"
        ax.step(c.tick_time_s, c.queue_level, where="post", lw=0.8, color=color, alpha=0.8,
                label=f"{c.name} ({c.clock_ppm:+g} ppm): {c.underruns} underruns, "
                      f"{c.overruns} overruns")  # fmt: skip
        ax.axhline(c.queue_depth, color=color, ls=":", lw=0.8)
        if c.first_underrun_s is not None:
            ax.axvline(c.first_underrun_s, color=color, ls="--", lw=0.8)
        if c.first_overrun_s is not None:
            ax.axvline(c.first_overrun_s, color=color, ls="-.", lw=0.8)
    if result.resync_interval_s > 0:
        end = result.time_s.size * result.period_s
        n = int(end / result.resync_interval_s + 1e-9)
        for r in range(1, n + 1):
            ax.axvline(r * result.resync_interval_s, color="0.6", lw=0.5)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("queue level [setpoints]")
    sync = (f"resync every {result.resync_interval_s:g} s" if result.resync_interval_s
            else "start sync only")  # fmt: skip
    ax.set_title(f"slave queues, {sync} (dotted: depth)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    return fig


def plot_radial_deviation(result: LinkageResult, ax: plt.Axes | None = None) -> plt.Figure:
    """Circular test as a ballbar plot: radial deviation against angle, magnified.

    Polar plot of every arc of a linkage run: the programmed circle is the thin black circle
    (zero deviation) and the actual radius − programmed radius [counts] is drawn about it on a
    magnified radial scale (the centre of the plot is not the circle's centre). The constant-
    feed part (where the circularity is read, ISO 230-4) is solid, the ramps are faint.
    ``ax`` must be a polar axes if given.
    """
    if ax is None:
        fig, ax = plt.subplots(figsize=(6, 6), subplot_kw={"projection": "polar"})
    else:
        fig = ax.figure
    if not result.arcs:
        ax.set_title("no arc in the path")
        return fig
    lo = min(0.0, *(float(a.radial_dev_counts.min()) for a in result.arcs))
    hi = max(0.0, *(float(a.radial_dev_counts.max()) for a in result.arcs))
    span = max(hi - lo, 1.0)
    theta = np.linspace(0.0, 2.0 * np.pi, 361)
    ax.plot(theta, np.zeros_like(theta), color="k", lw=0.8, label="programmed circle")
    for i, a in enumerate(result.arcs):
        color = f"C{i}"
        ax.plot(a.angle_rad, a.radial_dev_counts, color=color, lw=0.5, alpha=0.35)
        dev = np.where(a.cruise, a.radial_dev_counts, np.nan)
        ax.plot(a.angle_rad, dev, color=color, lw=1.2,
                label=f"move {a.move} ({'/'.join(a.plane)}, R {a.radius_counts:g}): "
                      f"circularity {a.circularity_counts:.1f} counts")  # fmt: skip
    ax.set_ylim(lo - 0.15 * span, hi + 0.15 * span)
    ax.set_rorigin(lo - 1.0 * span)
    ax.set_rlabel_position(90)
    ax.tick_params(axis="y", labelsize=7)
    ax.set_title("circular test: radial deviation [counts] (magnified)", fontsize=10)
    ax.legend(loc="lower center", bbox_to_anchor=(0.5, -0.2), fontsize=8)
    fig.tight_layout()
    return fig
