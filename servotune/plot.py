"""Figures (the only module besides report.py that imports matplotlib)."""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from servotune.io.files import atomic_write_bytes
from servotune.sim.engine import Trace

if TYPE_CHECKING:
    from servotune.arch.linkage import LinkageResult
    from servotune.fleet import FleetResult

__all__ = [
    "QUERY_TABLE_LABELS",
    "MoveEnvelope",
    "finish_figure",
    "plot_bode",
    "plot_comparison",
    "plot_fit",
    "plot_fleet",
    "plot_frf",
    "plot_lock_hold",
    "plot_pareto",
    "plot_query_tables",
    "plot_queue_levels",
    "plot_radial_deviation",
    "plot_sync_errors",
    "plot_tracking",
    "residual_step",
    "save_figure",
]

_PNG_META = {"Software": None}


def save_figure(fig: plt.Figure, path: str | Path) -> None:
    """Save a figure as PNG without a software stamp (same input → same bytes), then close it."""
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=110, metadata=_PNG_META)
    finally:
        plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def finish_figure(fig: plt.Figure, axs: Sequence[plt.Axes], title: str) -> plt.Figure:
    """Grid and legend on every panel, ``title`` (if any) on the first, then lay it out."""
    for a in axs:
        a.grid(True, alpha=0.3)
        a.legend(loc="best", fontsize=8)
    if title:
        axs[0].set_title(title)
    fig.tight_layout()
    return fig


@dataclass(frozen=True, slots=True, kw_only=True)
class MoveEnvelope:
    """A verification scenario's limits on a move, drawn over its response (:func:`plot_tracking`).

    Attributes
    ----------
    start_s : float
        When the master's reference starts to move [s] (the step's time zero).
    initial_counts, target_counts : float
        Position before the move and the reference's final value [counts].
    settling_band_pct : float
        Settling band, % of the move.
    master : int
        The master's axis column.
    slaves : tuple of int
        The slaves' axis columns.
    max_overshoot_pct : float or None
        Largest run past the target, % of the move.
    max_settling_time_s : float or None
        Time from ``start_s`` to settle into the band for good [s].
    max_sync_error_counts : float or None
        Largest ``|master − slave|`` [counts].
    """

    start_s: float
    initial_counts: float
    target_counts: float
    settling_band_pct: float
    master: int = 0
    slaves: tuple[int, ...] = ()
    max_overshoot_pct: float | None = None
    max_settling_time_s: float | None = None
    max_sync_error_counts: float | None = None


def _draw_envelope(axs: Sequence[plt.Axes], trace: Trace, env: MoveEnvelope) -> None:
    t_end = float(trace.time_s[-1])
    move = env.target_counts - env.initial_counts
    sign = 1.0 if move >= 0 else -1.0
    if env.max_overshoot_pct is not None:
        y = env.target_counts + sign * abs(move) * env.max_overshoot_pct / 100.0
        label = f"overshoot limit ({env.max_overshoot_pct:g} % of the move)"
        axs[0].hlines(y, env.start_s, t_end, colors="C3", linestyles="--", lw=1.0, label=label)
    if env.max_settling_time_s is not None:
        band = abs(move) * env.settling_band_pct / 100.0
        t0 = env.start_s + env.max_settling_time_s
        if t0 < t_end:
            axs[0].fill_between(
                [t0, t_end],
                env.target_counts - band,
                env.target_counts + band,
                color="C2",
                alpha=0.35,
                lw=0,
                label=f"settled by {env.max_settling_time_s:g} s into ±{env.settling_band_pct:g} %",
            )
    if env.max_sync_error_counts is not None and env.slaves:
        for j in env.slaves:
            e = trace.true_pos_counts[:, env.master] - trace.true_pos_counts[:, j]
            axs[1].plot(
                trace.time_s,
                e,
                color="k",
                lw=0.8,
                label=f"sync error {trace.axis_names[env.master]} − {trace.axis_names[j]}",
            )
        lim = env.max_sync_error_counts
        axs[1].axhline(lim, color="C3", ls="--", lw=1.0, label=f"sync-error limit ±{lim:g} counts")
        axs[1].axhline(-lim, color="C3", ls="--", lw=1.0)


def plot_tracking(
    trace: Trace, title: str = "", *, envelope: MoveEnvelope | None = None
) -> plt.Figure:
    """Positions, errors, D/A codes and modes of a trace (one column per axis); with
    ``envelope``, the spec's limits on the move drawn over it (the overshoot ceiling, the
    settling band, the sync-error bound and the sync error itself)."""
    t = trace.time_s
    fig, axs = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for i, name in enumerate(trace.axis_names):
        axs[0].plot(t, trace.pos_counts[:, i], label=f"{name} position")
        axs[1].plot(t, trace.err_counts[:, i], label=f"{name} error (r − y)")
        axs[2].step(t, trace.code[:, i], where="post", label=f"{name} D/A code")
    if trace.ref_counts.shape[1] and np.any(trace.ref_counts):
        axs[0].plot(t, trace.ref_counts[:, 0], "k--", lw=0.8, label="reference")
    if envelope is not None:
        _draw_envelope(axs, trace, envelope)
    axs[0].set_ylabel("position [counts]")
    axs[1].set_ylabel("error [counts]")
    axs[2].set_ylabel("D/A output [codes]")
    axs[2].set_xlabel("time [s]")
    return finish_figure(fig, axs, title)


def plot_lock_hold(
    trace: Trace, bands: dict[str, tuple[int, int]], settle_s: float, title: str = ""
) -> plt.Figure:
    """Lock-module hold: noiseless position error vs the predicted band, per axis."""
    t = trace.time_s
    fig, axs = plt.subplots(
        len(trace.axis_names),
        1,
        figsize=(9, 2.8 * len(trace.axis_names)),
        sharex=True,
        squeeze=False,
    )
    for i, name in enumerate(trace.axis_names):
        ax = axs[i, 0]
        e = -np.floor(trace.true_pos_counts[:, i])
        ax.step(t, e, where="post", lw=0.8, label=f"{name}: target − position (noiseless)")
        lo, hi = bands[name]
        ax.axhspan(lo - 0.5, hi + 0.5, color="C2", alpha=0.2, label=f"predicted band [{lo}, {hi}]")
        ax.axhline(4, color="C3", ls=":", lw=0.8)
        ax.axhline(-4, color="C3", ls=":", lw=0.8, label="±1 pulse (±4 counts)")
        ax.axvline(settle_s, color="k", ls="--", lw=0.6)
        ax.set_ylabel("target − position [counts]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axs[-1, 0].set_xlabel("time [s]")
    if title:
        axs[0, 0].set_title(title)
    fig.tight_layout()
    return fig


def residual_step(residual_counts: np.ndarray, split_index: int) -> float:
    """How far the position residual steps at the split of a split-half validation [counts]:
    the median over the second half's first samples (after its restart transient) less the
    median over the first half's last ones; NaN without a split inside the log.

    >>> residual_step(np.r_[np.zeros(100), np.full(100, 2.0)], 100)
    2.0
    """
    r = np.asarray(residual_counts, dtype=float)
    n = r.size
    if not 0 < split_index < n:
        return float("nan")
    k = max(1, min(50, split_index, (n - split_index) // 4))
    after = r[split_index + k : split_index + 2 * k]
    if after.size == 0:
        after = r[split_index:]
    return float(np.median(after) - np.median(r[split_index - k : split_index]))


def plot_fit(
    pos_counts: np.ndarray,
    sim_pos_counts: np.ndarray,
    period_s: float,
    split_index: int,
    title: str = "",
) -> plt.Figure:
    """Measured vs simulated position and velocity, and the residuals, of an identification.

    The split of the split-half validation is marked on every panel: each half is simulated by
    the model fitted on the other half, from its own first measured position and a speed taken
    from its first samples (:func:`servotune.identify.simulate_fit`). The second half's
    simulation restarts there without the motion in flight (the commands inside the loop
    delay, the acceleration), so the position residual steps at the split and then stays
    (position integrates the speed error of the restart); the step is written on the figure
    (:func:`residual_step`).

    Parameters
    ----------
    pos_counts, sim_pos_counts : ndarray
        Measured and simulated position [counts] (the simulation restarts at the split).
    period_s : float
        Sample period [s].
    split_index : int
        First sample of the second half (0: no split to mark).
    """
    time_s = np.arange(len(pos_counts), dtype=np.int64) * period_s
    fig, axs = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    v_m = np.diff(pos_counts) / period_s
    v_s = np.diff(sim_pos_counts) / period_s
    t_v = time_s[:-1]
    residual = np.asarray(pos_counts, dtype=float) - np.asarray(sim_pos_counts, dtype=float)
    axs[0].plot(time_s, pos_counts, lw=0.8, label="measured")
    axs[0].plot(time_s, sim_pos_counts, lw=0.8, ls="--", label="simulated")
    axs[0].set_ylabel("position [counts]")
    axs[1].plot(t_v, v_m, lw=0.5, label="measured (Δcounts/T)")
    axs[1].plot(t_v, v_s, lw=0.8, label="simulated")
    axs[1].set_ylabel("speed [counts/s]")
    axs[2].plot(time_s, residual, lw=0.6, label="position residual (measured − simulated)")
    axs[2].margins(y=0.25)
    axs[2].set_ylabel("residual [counts]")
    axs[2].set_xlabel("time [s]")
    split = 0 < split_index < len(pos_counts)
    if split:
        t_split = float(time_s[split_index])
        for i, a in enumerate(axs):
            a.axvline(
                t_split,
                color="k",
                ls=":",
                lw=1.0,
                label="split: each half simulated by the other half's model" if i == 0 else None,
            )
        for x, text in ((0.25, "first half"), (0.75, "second half")):
            axs[0].text(
                x, 1.01, text, transform=axs[0].transAxes, ha="center", va="bottom", fontsize=8
            )
        step = residual_step(residual, split_index)
        axs[2].text(
            0.01,
            0.96,
            f"at the split the simulation restarts from the measured "
            f"position (the motion in flight is lost):\nthe residual steps by "
            f"{step:+.1f} counts there and then stays",
            transform=axs[2].transAxes,
            va="top",
            fontsize=7.5,
            bbox={"facecolor": "white", "alpha": 0.8, "lw": 0},
        )
    for a, where in zip(axs, ("upper right", "upper right", "lower right"), strict=True):
        a.grid(True, alpha=0.3)
        a.legend(loc=where, fontsize=8)
    fig.suptitle(title or "identification: measured against simulated")
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
    return finish_figure(
        fig, axs, title or "slave tracking: PID, PID + feedforward, composite (Figure 4)"
    )


def plot_pareto(points: Sequence[Any], title: str = "") -> plt.Figure:
    """The tracking/robustness trade-off: ITAE and max sync error against the worst Ms, one
    colour per structure, its front joined (:func:`servotune.compare.pareto_front`)."""
    fig, axs = plt.subplots(1, 2, figsize=(10, 4.2))
    labels = {"pid": "PID", "pid_ff": "PID + feedforward", "composite": "fuzzy-PID + feedforward"}
    for structure in dict.fromkeys(p.structure for p in points):
        mine = [p for p in points if p.structure == structure and p.feasible]
        for ax, key, front in (
            (axs[0], "itae", "front_itae"),
            (axs[1], "max_sync_counts", "front_max"),
        ):
            line = ax.plot(
                [p.worst_ms for p in mine], [getattr(p, key) for p in mine], "o", ms=4, alpha=0.5
            )[0]
            on = sorted((p for p in mine if getattr(p, front)), key=lambda p: p.worst_ms)
            ax.plot(
                [p.worst_ms for p in on],
                [getattr(p, key) for p in on],
                "-o",
                ms=5,
                color=line.get_color(),
                label=labels.get(structure, structure),
            )
    axs[0].set_ylabel("ITAE of the sync error [counts·s²]")
    axs[1].set_ylabel("max |sync error| [counts]")
    for ax in axs:
        ax.set_xlabel("worst peak sensitivity Ms over the plant set [1]")
    return finish_figure(fig, axs, title or "tracking against robustness (each structure's front)")


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


QUERY_TABLE_LABELS: Mapping[str, str] = {
    "kp": "Kp [codes/count]",
    "ki": "Ki·T [codes/count per tick]",
    "kd": "Kd/T [codes/count of change]",
    "k1": "K1/T [codes/count of change]",
}
"""Labels with units of a fuzzy-PID law's scheduled gains (``FuzzyPIDConstants.scheduled``), by
table name (:data:`servotune.laws.fuzzy_pid.TABLE_NAMES`), for :func:`plot_query_tables`."""


def plot_query_tables(tables: dict[str, np.ndarray], n: int, title: str = "") -> plt.Figure:
    """Heat maps of query tables (row E, column EC, levels −n…n).

    Each panel is titled with its name (give it with its unit, e.g. from
    :data:`QUERY_TABLE_LABELS`) and the range of its values; its colour bar carries the name.
    A table whose cells are all equal (a constant table, such as a feedforward gain that is not
    scheduled) is drawn as one flat tile with its value written on it, not as a colour scale of
    nothing. NaN cells stay blank.
    """
    names = list(tables)
    fig, axs = plt.subplots(1, len(names), figsize=(3.4 * len(names), 3.6), squeeze=False)
    ext = (-n - 0.5, n + 0.5, n + 0.5, -n - 0.5)
    for ax, name in zip(axs[0], names, strict=True):
        label = name
        a = np.asarray(tables[name], dtype=float)
        finite = a[np.isfinite(a)]
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (np.nan, np.nan)
        if finite.size and lo == hi:
            ax.imshow(
                np.where(np.isfinite(a), 0.0, np.nan), extent=ext, cmap="Greys", vmin=-1, vmax=4
            )
            ax.text(
                0.5,
                0.5,
                f"constant\n{lo:.4g}",
                transform=ax.transAxes,
                ha="center",
                va="center",
                fontsize=12,
                fontweight="bold",
            )
            ax.set_title(f"{label}\nevery cell {lo:.4g}", fontsize=8)
        else:
            im = ax.imshow(a, extent=ext, cmap="coolwarm")
            ax.set_title(f"{label}\n{lo:.4g} … {hi:.4g}", fontsize=8)
            bar = fig.colorbar(im, ax=ax, fraction=0.046)
            bar.set_label(label, fontsize=8)
        ax.set_xlabel("EC: error-change level [1]", fontsize=8)
        ax.set_ylabel("E: error level [1]", fontsize=8)
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


def plot_frf(
    frf: Any, title: str = "", model: Any = None, model_label: str = "model"
) -> plt.Figure:
    """A measured frequency response (:class:`servotune.analysis.frf.Frf`): magnitude with its
    95 % bounds, phase with its bounds, and the coherence with the excitation; the lines flagged
    as possibly aliased marked. ``model``: a complex response at the same lines, drawn beside
    it (a fitted model), labelled ``model_label``."""
    fig, axs = plt.subplots(3, 1, figsize=(8, 8), sharex=True, height_ratios=(3, 2, 1))
    f = frf.freq_hz
    lo_db, hi_db = frf.magnitude_bounds_db()
    lo_ph, hi_ph = frf.phase_bounds_deg()
    axs[0].semilogx(f, frf.magnitude_db, ".-", ms=3, lw=0.8, label="measured")
    floor = np.maximum(lo_db, frf.magnitude_db - 40)
    axs[0].fill_between(f, floor, hi_db, alpha=0.25, label="95 % bounds")
    axs[1].semilogx(f, frf.phase_deg, ".-", ms=3, lw=0.8, label="measured")
    axs[1].fill_between(f, lo_ph, hi_ph, alpha=0.25, label="95 % bounds")
    if model is not None:
        m = np.asarray(model)
        axs[0].semilogx(f, 20 * np.log10(np.abs(m)), lw=1.2, label=model_label)
        ph = np.degrees(np.unwrap(np.angle(m)))
        ph += 360.0 * np.round((frf.phase_deg[0] - ph[0]) / 360.0)
        axs[1].semilogx(f, ph, lw=1.2, label=model_label)
    if np.any(frf.aliased):
        for a in axs[:2]:
            start = float(f[frf.aliased][0])
            a.axvspan(start, float(f[-1]), color="0.85", alpha=0.5, label="possibly aliased")
    axs[2].semilogx(f, frf.coherence, ".", ms=3, label="coherence")
    axs[2].set_ylim(0, 1.05)
    unit = "counts/s per V" if frf.output == "velocity" else "counts per V"
    axs[0].set_ylabel(f"|G| [dB re 1 {unit}]")
    axs[1].set_ylabel("phase [deg]")
    axs[2].set_ylabel("coherence [-]")
    axs[2].set_xlabel("frequency [Hz]")
    return finish_figure(fig, axs, title)


def _queue_markers(ax: plt.Axes, result: LinkageResult, only: int | None = None) -> None:
    """Depth (dotted), first underrun / overrun (dashed / dash-dot) of every CPU (or of the
    ``only``-th), each in its colour, and the resyncs (grey)."""
    for i, c in enumerate(result.cpus):
        if only is not None and i != only:
            continue
        color = f"C{i}"
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


def _queue_label(c: Any) -> str:
    return (
        f"{c.name} ({c.clock_ppm:+g} ppm): level {c.min_level}–{c.max_level} of "
        f"{c.queue_depth}, {c.underruns} underruns, {c.overruns} overruns"
    )


def _queue_window(result: LinkageResult) -> tuple[float, float]:
    """A window a few broadcast periods wide [s]: around the first underrun or overrun, else
    at the start of the run (the sawtooth of arrivals and pops is read there)."""
    width = max(6.0 * result.bus.broadcast_period_s, 40.0 * result.period_s)
    firsts = [
        t for c in result.cpus for t in (c.first_underrun_s, c.first_overrun_s) if t is not None
    ]
    t0 = max(0.0, min(firsts) - width / 2) if firsts else 0.0
    return t0, t0 + width


_OVERLAP_DASHES = ((), (6, 3), (2, 2), (8, 2, 2, 2), (1, 3), (4, 1, 1, 1, 1, 1))
"""Dash patterns [points] of the lines that may lie on top of each other (the first solid)."""


def _overlap_style(i: int, n: int) -> dict[str, Any]:
    """Line style of the ``i``-th of ``n`` lines that may lie on top of each other (the same
    data on several CPUs): each in its colour, the first solid and widest, every later one
    narrower, drawn above and dashed in its own pattern, so that each stays visible through
    the gaps of the ones drawn after it. No line is moved off its data."""
    dashes = _OVERLAP_DASHES[i % len(_OVERLAP_DASHES)]
    style: dict[str, Any] = {"color": f"C{i}", "lw": 1.0 + 1.6 * (n - 1 - i), "zorder": 2 + i}
    if dashes:
        style["dashes"] = dashes
    return style


def plot_queue_levels(result: LinkageResult, ax: plt.Axes | None = None) -> plt.Figure:
    """Queue level of every slave CPU before each pop over master time (multi-CPU linkage).

    The level is a sawtooth at the broadcast period (a block arrives, each tick pops one), far
    too fast to read over a whole run. Without ``ax`` the figure has one row of panels per CPU,
    every panel on the same level scale (CPUs whose queues move alike would hide each other on
    one panel): on the left, over the whole run, the CPU's lowest and highest level per time
    bin (a band, its edges drawn); on the right, a window of a few broadcast periods (around
    the first underrun or overrun, else at the start; the same window for every CPU) with
    every pop. With ``ax``, every CPU's pops are drawn on it (zoom with ``set_xlim``), each in
    its colour and its own dash pattern, the first widest, so that identical levels stay
    readable. Each CPU's queue depth is dotted, its first underrun / overrun a dashed /
    dash-dot vertical line; the resync instants are grey.
    """
    sync = (
        f"resync every {result.resync_interval_s:g} s"
        if result.resync_interval_s
        else "start sync only"
    )
    n = len(result.cpus)
    if ax is not None:
        fig = ax.figure
        for i, c in enumerate(result.cpus):
            ax.step(
                c.tick_time_s,
                c.queue_level,
                where="post",
                alpha=0.9,
                label=_queue_label(c),
                **_overlap_style(i, n),
            )
        _queue_markers(ax, result)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("queue level [setpoints]")
        ax.set_title(f"slave queues, {sync} (dotted: depth)")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
        fig.tight_layout()
        return fig
    rows = max(n, 1)
    fig, axs = plt.subplots(
        rows,
        2,
        figsize=(12, 1.4 + 2.5 * rows),
        squeeze=False,
        sharex="col",
        sharey=True,
        width_ratios=(1.6, 1.0),
    )
    bins = 400
    t0, t1 = _queue_window(result)
    for i, c in enumerate(result.cpus):
        color = f"C{i}"
        whole, zoom = axs[i]
        t = np.asarray(c.tick_time_s, dtype=float)
        lvl = np.asarray(c.queue_level, dtype=float)
        if t.size:
            edges = np.linspace(t[0], t[-1], bins + 1)
            k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, bins - 1)
            lo = np.full(bins, np.inf)
            hi = np.full(bins, -np.inf)
            np.minimum.at(lo, k, lvl)
            np.maximum.at(hi, k, lvl)
            used = np.isfinite(lo)
            mid = 0.5 * (edges[:-1] + edges[1:])[used]
            whole.fill_between(
                mid, lo[used], hi[used], color=color, alpha=0.2, lw=0, label=_queue_label(c)
            )
            whole.plot(mid, lo[used], color=color, lw=1.2)
            whole.plot(mid, hi[used], color=color, lw=1.2, ls="--")
            sel = (t >= t0) & (t <= t1)
            zoom.step(t[sel], lvl[sel], where="post", color=color, lw=1.2, label=c.name)
        for a in (whole, zoom):
            _queue_markers(a, result, only=i)
            a.set_ylabel(f"{c.name} queue [setpoints]")
            a.grid(True, alpha=0.3)
            a.legend(loc="best", fontsize=8)
    bottom_whole, bottom_zoom = axs[-1]
    bottom_whole.set_xlabel("time [s]")
    bottom_zoom.set_xlabel("time [s]")
    bottom_zoom.set_xlim(t0, t1)
    top_whole, top_zoom = axs[0]
    top_whole.set_title(
        f"whole run: lowest (solid) and highest (dashed) level per "
        f"{(result.time_s.size * result.period_s) / bins * 1e3:.0f} ms",
        fontsize=10,
    )
    top_zoom.set_title(
        f"{(t1 - t0) * 1e3:.0f} ms from {t0:.3f} s: a block every "
        f"{result.bus.broadcast_period_s * 1e3:g} ms, a pop every tick",
        fontsize=10,
    )
    fig.suptitle(
        f"slave queues, one row per CPU on the same scales, {sync}; dotted: depth", fontsize=11
    )
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
    ax.set_xlabel("angle on the circle [deg]", fontsize=8)
    ax.set_ylabel("radial deviation [counts]", fontsize=8, labelpad=28)
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
        ax.plot(
            a.angle_rad,
            dev,
            color=color,
            lw=1.2,
            label=f"move {a.move} ({'/'.join(a.plane)}, R {a.radius_counts:g}): "
            f"circularity {a.circularity_counts:.1f} counts",
        )
    ax.set_ylim(lo - 0.15 * span, hi + 0.15 * span)
    ax.set_rorigin(lo - 1.0 * span)
    ax.set_rlabel_position(90)
    ax.tick_params(axis="y", labelsize=7)
    ax.set_title("circular test: radial deviation [counts] (magnified)", fontsize=10)
    ax.legend(loc="lower center", bbox_to_anchor=(0.5, -0.28), fontsize=8)
    fig.tight_layout()
    return fig


def plot_fleet(result: FleetResult, *, columns: int = 2) -> plt.Figure:
    """Histograms of each fitted parameter over a fleet (latest fit of each machine), with the
    fleet's median, the band within which a value is no outlier (``|robust z| ≤ 3.5``), the
    outliers (red) and the machines that drifted (orange: an arrow from the previous fit's value
    to the latest) marked and named (:mod:`servotune.fleet`).

    One panel per axis and parameter with a spread (:attr:`FleetSummary.spreads`); every x axis
    is labelled with the parameter's unit.
    """
    s = result.summary
    panels = list(s.spreads)
    n = max(1, len(panels))
    rows = -(-n // columns)
    fig, axs = plt.subplots(rows, columns, figsize=(5.2 * columns, 3.2 * rows), squeeze=False)
    flat = list(axs.ravel())
    latest: dict[tuple[str, str, str], float] = {}
    for r in sorted((r for r in result.rows if r.ok), key=lambda r: (r.date, r.file)):
        for p, v in r.params.items():
            latest[(r.axis, r.machine_id, p)] = v
    for a, sp in zip(flat, panels, strict=False):
        x = np.array([v for (ax, _, p), v in latest.items() if ax == sp.axis and p == sp.parameter])
        a.hist(
            x,
            bins=min(40, max(8, int(np.sqrt(x.size)) * 2)),
            color="0.7",
            edgecolor="0.45",
            lw=0.5,
            label=f"{x.size} machines (latest fit)",
        )
        a.axvline(sp.median, color="k", lw=1.0, label="median")
        if sp.spread > 0:
            half = s.outlier_z * sp.spread
            a.axvspan(
                sp.median - half,
                sp.median + half,
                color="tab:blue",
                alpha=0.08,
                label=f"|robust z| ≤ {s.outlier_z:g}",
            )
        top = a.get_ylim()[1]
        outs = [o for o in s.outliers if o.axis == sp.axis and o.parameter == sp.parameter]
        for i, o in enumerate(outs):
            a.plot(
                [o.value],
                [0.92 * top],
                "v",
                color="tab:red",
                ms=7,
                label=f"outlier (|z| > {s.outlier_z:g})" if i == 0 else None,
            )
            a.annotate(
                o.machine_id,
                (o.value, 0.92 * top),
                xytext=(0, 5),
                ha="center",
                textcoords="offset points",
                fontsize=7,
                color="tab:red",
            )
        drifts = [d for d in s.drifts if d.axis == sp.axis and d.parameter == sp.parameter]
        for i, d in enumerate(drifts):
            y = (0.55 + 0.08 * (i % 4)) * top
            arrow = {"arrowstyle": "->", "color": "tab:orange", "lw": 1.4}
            a.annotate("", xy=(d.after, y), xytext=(d.before, y), arrowprops=arrow)
            a.plot(
                [d.after],
                [y],
                "o",
                color="tab:orange",
                ms=5,
                label="drifted: previous → latest fit" if i == 0 else None,
            )
            a.annotate(
                d.machine_id,
                (d.after, y),
                xytext=(0, 4),
                textcoords="offset points",
                ha="center",
                fontsize=7,
                color="tab:orange",
            )
        a.xaxis.set_major_locator(plt.MaxNLocator(6))
        a.set_xlabel(f"{sp.parameter} [{sp.unit}]")
        a.set_ylabel("machines [1]")
        a.set_title(f"{sp.parameter}" + (f" (axis {sp.axis})" if sp.axis else ""), fontsize=9)
        a.grid(True, alpha=0.3)
        a.legend(loc="best", fontsize=7)
    for a in flat[len(panels) :]:
        fig.delaxes(a)
    if not panels:
        fig.text(0.5, 0.5, "too few machines per axis: no spread", ha="center", va="center")
    fig.suptitle(
        f"fleet: {s.n_machines} machines, {len(s.outliers)} outliers, "
        f"{len(s.drifted)} drifted machines"
    )
    fig.tight_layout()
    return fig
