"""Input shapers for an axis as its loop runs it: the closed loop's vibration modes, and the
shaper designed for them (docs/runtime.md#input-shaping).

A shaper on the reference cancels the vibration at the poles it is designed for. A mode of the
plant sits inside the position loop (the encoder measures it), so the loop moves its pole: the
reference excites the **closed loop's** pole near the mode, not the plant's. With a slow loop
the two are close; with a stiff one they are not (at the same tick, Kp = 1 code/count moves a
35 Hz mode of damping 0.04 by several per cent). :func:`closed_loop_modes` finds those poles on
the loop model the margins use (:func:`servotune.analysis.margins.loop_model`: the discretised
plant with its modes, the lag, the D/A gain and the law's PI), and :func:`axis_shaper` designs
the shaper for them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from servotune.analysis.margins import GainSet, loop_model
from servotune.errors import SpecError
from servotune.laws.filters import SectionQ
from servotune.laws.pi import PIGains
from servotune.laws.shaping import Shaper, choose_shaper, shape_reference, shaper_for_modes
from servotune.plant import Plant
from servotune.resonance import Mode
from servotune.rig import Rig
from servotune.scenarios import Scenario
from servotune.tuning import Tuning

__all__ = [
    "axis_shaper",
    "closed_loop_modes",
    "format_shaper",
    "shape_scenario",
    "task_filters",
    "task_gains",
]


def closed_loop_modes(
    plant: Plant,
    gains: PIGains,
    *,
    period_s: float,
    lag_s: float,
    lsb_volts: float,
    filters: Sequence[SectionQ] = (),
) -> list[Mode]:
    """The closed loop's pole pair nearest each of the plant's modes, as modes (frequency and
    damping of ``s = ln(z) / T``; the plant mode's gain and intervals, the intervals scaled by
    the frequency's shift). The loop includes the axis's output ``filters``: a notch on the mode
    moves (and damps) the pole the reference excites.

    Raises
    ------
    SpecError
        A closed-loop pole near a mode that is not damped (the loop rings or is unstable there).
    """
    import control

    loop = loop_model(
        plant,
        GainSet(gains.kp, gains.ki * period_s),
        period_s=period_s,
        lag_s=lag_s,
        lsb_volts=lsb_volts,
        filters=filters,
    )
    z = np.asarray(control.feedback(loop, 1).poles(), dtype=complex)
    if np.any(np.abs(z) >= 1.0):
        raise SpecError(
            f"the closed loop with Kp {gains.kp:g}, Ki {gains.ki:g} is unstable (a pole at "
            f"|z| = {np.abs(z).max():.4g}): no shaper helps; tune the loop first"
        )
    s = np.log(z[np.abs(z) > 0]) / period_s
    s = s[s.imag > 0]
    out = []
    for m in plant.modes:
        w = 2 * math.pi * m.freq_hz
        s_m = complex(-m.damping * w, w * math.sqrt(1 - m.damping**2))
        p = s[int(np.argmin(np.abs(s - s_m)))]
        f, zeta = abs(p) / (2 * math.pi), -p.real / abs(p)
        if not 0 < zeta < 1:
            raise SpecError(
                f"shaper: the closed loop's pole near the {m.freq_hz:g} Hz mode has damping "
                f"{zeta:.3g}: the loop is unstable or rings there; tune it first"
            )
        scale = f / m.freq_hz
        f95 = None if m.freq_hz_95 is None else (m.freq_hz_95[0] * scale, m.freq_hz_95[1] * scale)
        out.append(Mode(freq_hz=f, damping=zeta, gain=m.gain, freq_hz_95=f95))
    return out


def axis_shaper(
    rig: Rig,
    axis: str,
    gains: PIGains,
    kind: str = "auto",
    filters: Sequence[SectionQ] | None = None,
) -> tuple[Shaper, list[Mode], list[str]]:
    """An input shaper for ``axis`` running the PI ``gains`` (task mode) behind its output
    ``filters`` (None: the rig's, :meth:`~servotune.rig.Rig.runtime_filters`), designed for its
    closed loop's modes (:func:`closed_loop_modes`) at the rig's achieved tick:
    :func:`~servotune.laws.shaping.choose_shaper` for ``"auto"``, else ``kind`` for every mode.

    Returns
    -------
    (Shaper, list of Mode, list of str)
        The shaper, the closed-loop modes it is designed for, one line per mode.

    Raises
    ------
    SpecError
        An axis without modes, a loop that rings at a mode, a mode no shaper can be designed for.
    """
    ax = rig.axis(axis)
    if not ax.plant.modes:
        raise SpecError(
            f"axis {axis!r} has no modes to shape for; give its plant "
            "[[axis.X.plant.modes]] (docs/formats.md#modes) or fit them (servotune fit --modes)"
        )
    if filters is None:
        filters = rig.runtime_filters(rig.axis_names.index(axis))
    modes = closed_loop_modes(
        ax.plant,
        gains,
        period_s=rig.period_s,
        lag_s=rig.timer.compute_s + ax.plant.delay_s,
        lsb_volts=rig.dac.lsb_v,
        filters=filters,
    )
    if kind == "auto":
        sh, why = choose_shaper(modes, rig.period_s)
    else:
        sh = shaper_for_modes(kind, [(m.freq_hz, m.damping) for m in modes], rig.period_s)
        why = [f"{m.freq_hz:.4g} Hz: {kind}, as asked" for m in modes]
    why = [
        f"plant mode {pm.freq_hz:.4g} Hz (damping {pm.damping:.3g}) is {m.freq_hz:.4g} Hz "
        f"(damping {m.damping:.3g}) in the closed loop; {w}"
        for pm, m, w in zip(ax.plant.modes, modes, why, strict=True)
    ]
    return sh, modes, why


def shape_scenario(
    rig: Rig,
    scenario: Scenario,
    gains: PIGains,
    kind: str = "auto",
    filters: Sequence[SectionQ] | None = None,
) -> tuple[Scenario, list[str]]:
    """The scenario with its axis's task reference shaped (:func:`axis_shaper`,
    :func:`~servotune.laws.shaping.shape_reference`); the shaped move ends ``n_taps − 1``
    ticks later, within the scenario's length."""
    sh, _, why = axis_shaper(rig, scenario.axis, gains, kind, filters)
    i = rig.axis_names.index(scenario.axis)
    ref = shape_reference(scenario.inputs.ref_counts[:, i], sh)
    inputs = scenario.inputs.replace_axis(i, ref_counts=ref)
    shaped = Scenario(
        name=f"{scenario.name}+{sh.kind}",
        axis=scenario.axis,
        inputs=inputs,
        needs_task_law=scenario.needs_task_law,
    )
    return shaped, why


def task_gains(tuning: Tuning, rig: Rig, axis: str) -> PIGains:
    """The PI gains ``axis`` runs in task mode under ``tuning`` [codes/count, codes/(count·s)]:
    the PI's constants as quantised, or a fuzzy-PID's base gains (the centre of its tables).

    Raises
    ------
    SpecError
        A tuning of another rig, an axis it does not have, or one without a task law.
    """
    if tuning.rig_name != rig.name:
        raise SpecError(
            f"the tuning is for rig {tuning.rig_name!r}, not {rig.name!r}: shape with its own rig"
        )
    if axis not in tuning.axis_names:
        raise SpecError(f"the tuning has no axis {axis!r} ({', '.join(tuning.axis_names)})")
    task = tuning.controllers[tuning.axis_names.index(axis)].task
    if task is None:
        raise SpecError(f"axis {axis!r} has no task law in the tuning: it only locks")
    return PIGains(kp=task.kp.value, ki=task.ki_t.value / tuning.period_s)


def task_filters(tuning: Tuning, axis: str) -> tuple[SectionQ, ...]:
    """The output filters ``axis`` runs under ``tuning`` (its controller's, quantised)."""
    return tuning.controllers[tuning.axis_names.index(axis)].filters


def format_shaper(axis: str, shaper: Shaper, why: list[str]) -> str:
    """A shaper as ``servotune shaper`` prints it: length and added time, why each mode got
    its kind, the Q15 amplitudes, the residual vibration at each mode and within ±15 % of it."""
    lines = [
        f"{axis}: {shaper.kind} shaper, {shaper.n_taps} taps on the {shaper.period_s:g} s "
        f"tick, moves {1000 * shaper.added_time_s:.1f} ms longer",
        *(f"  {w}" for w in why),
        "  Q15 amplitudes: " + " ".join(str(a) for a in shaper.amplitudes_q),
    ]
    for f, z in shaper.modes:
        lines.append(
            f"  residual vibration at {f:.4g} Hz: {100 * shaper.residual(f, z):.2f} %; "
            f"worst within ±15 %: {100 * shaper.worst_residual(f, z, 0.15):.2f} %"
        )
    return "\n".join(lines)
