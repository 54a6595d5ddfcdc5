"""The report's filters section: what each axis's output filters do to its loops
(docs/tuning.md#filters).

Shown only when some axis of the tuning has filters: a report without any keeps its bytes. Per
filtered axis:

- one sentence from the numbers (:func:`filters_statement`): the sections, their attenuation at
  the plant's modes, and the task loop's margins on the rig's model with and without them;
- a table of every loop's margins with and without the filters on the nominal model
  (:func:`servotune.analysis.filter_effect.filter_effects`) and, with a measured response, on
  it and its 95 % bounds (:func:`servotune.analysis.frf_margins.frf_loops`);
- a figure: the task loop's Bode diagram with and without the filters on the rig's model, and on
  the measured response where one is given;
- a figure: a move of the axis on the rig's model in the engine, unshaped and shaped for the
  closed loop's modes (ZVD), with the residual vibration of each
  (:func:`servotune.verify.scenario_values.residual_vibration`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import matplotlib.pyplot as plt
import numpy as np

from servotune.analysis.filter_effect import FilterEffect, filter_effects
from servotune.analysis.frf import FrfSource, read_frf
from servotune.analysis.frf_margins import frf_loops, position_response
from servotune.analysis.margins import controller_response, gain_sets
from servotune.analysis.plant_cases import PlantCase, plant_response
from servotune.analysis.shaping import axis_shaper, task_gains
from servotune.laws.axis import MODE_TASK
from servotune.laws.filters import chain_response
from servotune.laws.shaping import shape_reference
from servotune.plot import finish_figure
from servotune.report.page import figure_html, paragraph_html, png_uri, table_html
from servotune.rig import Rig
from servotune.scenarios import Inputs, trapezoid_ref
from servotune.sim.engine import Loop, simulate
from servotune.tuning import Tuning
from servotune.verify.scenario_values import residual_vibration

__all__ = ["filters_section", "filters_statement", "shaped_move"]

_HEAD = ["loop", "on", "PM [deg] with", "without", "GM [dB] with", "without", "Ms with", "without"]


def filters_statement(fx: FilterEffect, task_with: Any, task_without: Any) -> str:
    """One sentence of what the filters of one axis do, from the numbers."""
    modes = "; ".join(f"{g:+.1f} dB at the mode {f:g} Hz" for f, g, _ in fx.at_modes)
    return (
        f"{fx.axis}: {len(fx.sections)} output filter section(s), {modes or 'no plant mode'}. "
        f"The task loop on the rig's model keeps PM {task_with.phase_margin_deg:.1f}°, "
        f"GM {task_with.gain_margin_db:.1f} dB, Ms {task_with.max_sensitivity:.2f} with them; "
        f"without them PM {task_without.phase_margin_deg:.1f}°, GM "
        f"{task_without.gain_margin_db:.1f} dB, Ms {task_without.max_sensitivity:.2f}."
    )


def shaped_move(
    rig: Rig, tuning: Tuning, axis: str, distance: float = 3000.0
) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, float]], str]:
    """The axis alone (its tuning's law and filters, the rig's model without noise, friction
    or drift) moving ``distance`` counts, unshaped and shaped (ZVD for its closed loop's modes):
    ``(time, {label: (position − target, residual vibration [counts])}, the shaper's line)``."""
    i = rig.axis_names.index(axis)
    a = rig.axes[i]
    plant = dataclasses.replace(a.plant, noise_counts=0.0, coulomb_v=0.0, offset_v=0.0)
    one = dataclasses.replace(rig, axes=(dataclasses.replace(a, plant=plant, role="master"),))
    ctl = tuning.controllers[i]
    loop = Loop(rig=one, controllers=(ctl,))
    gains = task_gains(tuning, rig, axis)
    sh, _, why = axis_shaper(one, axis, gains, "zvd", ctl.filters)
    v = rig.axes[i].speed_limit_rpm / 60.0 * rig.counts_per_rev * 0.3
    n = int(1.5 / rig.period_s)
    ref = trapezoid_ref(n, rig.period_s, distance, v, v / 0.05, start_tick=25)
    out = {}
    for label, r in (("unshaped", ref), ("shaped (ZVD)", shape_reference(ref, sh))):
        inputs = Inputs.hold(n, 1).replace_axis(0, mode=MODE_TASK, ref_counts=r)
        tr = simulate(loop, inputs, seed=0)
        y = tr.true_pos_counts[:, 0]
        stop = int(np.flatnonzero(np.diff(r))[-1]) + 1
        out[label] = (y - r[-1], float(residual_vibration(y[None, :], one, 0, stop)[0]))
    return tr.time_s, out, "; ".join(why)


def _rows(fx: FilterEffect, nominal: Sequence[Any], measured: Sequence[Any]) -> list[list[str]]:
    rows = []
    for m in fx.without:
        w = next(x for x in nominal if x.loop == m.loop and x.cell == m.cell)
        rows.append(
            [
                m.loop,
                "model",
                f"{w.phase_margin_deg:.1f}",
                f"{m.phase_margin_deg:.1f}",
                f"{w.gain_margin_db:.1f}",
                f"{m.gain_margin_db:.1f}",
                f"{w.max_sensitivity:.2f}",
                f"{m.max_sensitivity:.2f}",
            ]
        )
    for loop in ("lock", "task"):
        for ticks in sorted({x.extra_ticks for x in measured}):
            pair = [
                max(
                    (
                        x
                        for x in measured
                        if x.loop == loop and x.extra_ticks == ticks and x.filtered == f
                    ),
                    key=lambda x: x.max_sensitivity,
                    default=None,
                )
                for f in (True, False)
            ]
            if pair[0] is None or pair[1] is None:
                continue
            w, wo = pair
            rows.append(
                [
                    loop,
                    f"measured +{ticks} tick",
                    f"{w.phase_margin_deg:.1f}",
                    f"{wo.phase_margin_deg:.1f}",
                    f"{w.gain_margin_db:.1f}",
                    f"{wo.gain_margin_db:.1f}",
                    f"{w.max_sensitivity:.2f}",
                    f"{wo.max_sensitivity:.2f}",
                ]
            )
    return rows


def filters_section(
    tuning: Tuning,
    rig: Rig,
    nominal: Sequence[Any],
    frf: Mapping[str, FrfSource] | None = None,
) -> tuple[str, dict[str, Any] | None]:
    """The section's HTML and its numbers; ``("", None)`` when no axis has filters.

    ``nominal``: the tuning's nominal loops with their filters (``tuning_margins``' loops on
    the nominal plants), the "with" columns."""
    effects = filter_effects(tuning, rig)
    if not effects:
        return "", None
    parts = ['<section id="filters"><h2>Output filters</h2>']
    data: dict[str, Any] = {}
    for fx in effects:
        i = rig.axis_names.index(fx.axis)
        ctl = tuning.controllers[i]
        mine = [m for m in nominal if m.axis == fx.axis and m.plant == "nominal"]
        task_w = next(m for m in mine if m.loop == "task" and m.cell in (None, (0, 0)))
        task_wo = next(m for m in fx.without if m.loop == "task")
        sentence = filters_statement(fx, task_w, task_wo)
        measured = []
        response = None
        if frf and fx.axis in frf:
            response = read_frf(frf[fx.axis])
            for f in (True, False):
                measured += frf_loops(response, ctl, lsb_v=rig.dac.lsb_v, axis=fx.axis, filters=f)
        parts.append(paragraph_html(sentence))
        parts.append(table_html(_HEAD, _rows(fx, mine, measured)))
        fig = _bode(rig, i, ctl, response)
        parts.append(
            figure_html(png_uri(fig), f"{fx.axis}: the task loop with and without its filters")
        )
        t, moves, why = shaped_move(rig, tuning, fx.axis)
        fig = _plot_move(
            t, {k: v[0] for k, v in moves.items()}, f"{fx.axis}: a move's end, unshaped and shaped"
        )
        said = "; ".join(f"{k}: residual vibration {v[1]:.2f} counts" for k, v in moves.items())
        parts.append(figure_html(png_uri(fig), f"{fx.axis}: shaped and unshaped move", said))
        data[fx.axis] = fx.to_dict() | {
            "statement": sentence,
            "measured": [m.to_dict() for m in measured],
            "residual_vibration_counts": {k: v[1] for k, v in moves.items()},
            "shaper": why,
        }
    parts.append("</section>")
    return "".join(parts), data


def _bode(rig: Rig, i: int, ctl: Any, response: Any) -> Any:
    plant = rig.axes[i].plant
    loop_gains = next(
        g for loop, cell, g in gain_sets(ctl) if loop == "task" and cell in (None, (0, 0))
    )
    f = np.geomspace(0.5, 0.45 / rig.period_s, 400)
    w = 2 * np.pi * f
    c = controller_response(
        np.array([loop_gains.kp, loop_gains.ki_t, loop_gains.kd_t]), w, rig.period_s
    ).ravel()
    case = PlantCase(
        label="nominal", plants=tuple(a.plant for a in rig.axes), period_s=rig.period_s
    )
    p = plant_response(plant, rig, case, w)
    filt = chain_response(ctl.filters, w, rig.period_s)
    curves = {"model, with filters": c * filt * p, "model, without": c * p}
    if response is not None:
        wm, g, _ = position_response(response)
        cm = controller_response(
            np.array([loop_gains.kp, loop_gains.ki_t, loop_gains.kd_t]), wm, rig.period_s
        ).ravel()
        fm = chain_response(ctl.filters, wm, rig.period_s)
        curves_m = {
            "measured, with filters": (wm / (2 * np.pi), cm * fm * g * rig.dac.lsb_v),
            "measured, without": (wm / (2 * np.pi), cm * g * rig.dac.lsb_v),
        }
    else:
        curves_m = {}
    return _plot_loop(f, curves, curves_m, "the task loop with and without its filters")


def _plot_loop(
    f_hz: np.ndarray,
    curves: dict[str, np.ndarray],
    measured: dict[str, tuple[np.ndarray, np.ndarray]],
    title: str = "",
) -> Any:
    """A loop's Bode diagram, several versions: ``curves`` (responses on ``f_hz``, lines) and
    ``measured`` (``(f, response)`` each, markers): magnitude [dB] and unwrapped phase [deg],
    the 0 dB and −180° lines drawn."""
    fig, axs = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for label, r in curves.items():
        axs[0].semilogx(f_hz, 20 * np.log10(np.abs(r)), lw=1.2, label=label)
        axs[1].semilogx(f_hz, np.degrees(np.unwrap(np.angle(r))), lw=1.2, label=label)
    for label, (f, r) in measured.items():
        axs[0].semilogx(f, 20 * np.log10(np.abs(r)), ".", ms=4, label=label)
        axs[1].semilogx(f, np.degrees(np.unwrap(np.angle(r))), ".", ms=4, label=label)
    axs[0].axhline(0.0, color="k", lw=0.8)
    axs[1].axhline(-180.0, color="k", lw=0.8)
    axs[0].set_ylabel("|L| [dB]")
    axs[1].set_ylabel("phase [deg]")
    axs[1].set_xlabel("frequency [Hz]")
    return finish_figure(fig, axs, title)


def _plot_move(t: np.ndarray, moves: dict[str, np.ndarray], title: str = "") -> Any:
    """The end of a move, several versions: position − target [counts] against time [s]."""
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for label, y in moves.items():
        ax.plot(t, y, lw=1.0, label=label)
    span = max(float(np.max(np.abs(y[len(y) // 2 :]))) for y in moves.values())
    ax.set_ylim(-1.5 * span - 1, 1.5 * span + 1)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position − target [counts]")
    return finish_figure(fig, [ax], title)
