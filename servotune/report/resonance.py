"""The report's resonance section: the rig's lightly damped modes and, when a measured frequency
response is given, that response against the rig's model (docs/frf.md#in-the-report).

Shown only when some axis of the rig has modes or an FRF is given: a report of a rigid rig
without an FRF keeps its bytes. Per axis:

- a table of its modes (the rig file's ``[[axis.<name>.plant.modes]]``, docs/formats.md#modes):
  frequency [Hz], damping [-], gain [-], their 95 % intervals where the file has them (a fit's,
  ``servotune fit --modes``), and the anti-resonance ``f / √(1 + g)`` [Hz];
- with an FRF (a ``servotune frf`` JSON file, schema ``servotune.frf/1``, or an
  :class:`~servotune.analysis.frf.Frf`): its magnitude and phase with their 95 % bounds and the
  coherence, beside the rig's model at the same lines — the exact sampled response of the
  rig's plant with its modes, the compute time and the delay
  (:func:`servotune.modal.modal_response`) — and the lines where the model lies outside the
  measured 95 % circle marked;
- one sentence of what is measured, from the numbers (:func:`resonance_statement`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune.analysis.frf import Frf, FrfSource, read_frf
from servotune.errors import SpecError
from servotune.modal import modal_response
from servotune.plot import plot_frf
from servotune.report.page import escape_html, figure_html, paragraph_html, png_uri, table_html
from servotune.report.sections import with_interval
from servotune.resonance import Mode
from servotune.rig import Rig
from servotune.validate import show_number

__all__ = [
    "FrfSource",
    "ResonanceCheck",
    "check_model",
    "format_hz",
    "modes_phrase",
    "read_frf",
    "resonance_figure",
    "resonance_section",
    "resonance_statement",
    "rig_model_response",
]

"""A measured frequency response: an :class:`Frf`, the path of a ``servotune frf`` JSON file, or
that file's content as a mapping."""

PERIOD_RTOL = 1e-3
"""How far the FRF's tick period may differ from the rig's (relative) for the rig's model to be
compared with it."""

_MODEL_LABEL = "rig's model (plant and modes, sampled)"


def rig_model_response(
    rig: Rig, axis: str, freq_hz: np.ndarray, output: str = "velocity"
) -> np.ndarray:
    """The rig's model of ``axis`` at ``freq_hz`` [Hz]: the exact sampled response of its plant
    (the mean of the two directions' gains, ``τ``, the delay and the modes) with the rig's tick
    period and compute time (:func:`servotune.modal.modal_response`), as ``servotune frf``
    measures it (``output`` ``"velocity"`` or ``"position"``)."""
    plant = rig.axis(axis).plant
    return modal_response(
        freq_hz,
        gain_cps_per_v=plant.mean_gain_cps_per_v,
        tau_s=plant.tau_s,
        delay_s=plant.delay_s,
        period_s=rig.period_s,
        modes=plant.modes,
        output=output,
        compute_s=rig.timer.compute_s,
    )


@dataclass(frozen=True, slots=True)
class ResonanceCheck:
    """A measured response against the rig's model of one axis (:func:`check_model`).

    Attributes
    ----------
    frf : Frf
        The measured response.
    model : ndarray of complex
        The rig's model at the FRF's lines.
    inside : ndarray of bool
        Per line, whether the model lies inside the measured 95 % circle.
    """

    frf: Frf
    model: np.ndarray
    inside: np.ndarray

    @property
    def distance(self) -> np.ndarray:
        """Per line, ``|model − measured|`` in units of the 95 % radius (inside: <= 1)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.abs(self.model - self.frf.response) / self.frf.radius95

    @property
    def lines(self) -> int:
        return int(self.inside.size)

    @property
    def lines_inside(self) -> int:
        return int(np.sum(self.inside))

    def to_dict(self) -> dict[str, Any]:
        return {
            "output": self.frf.output,
            "lines": self.lines,
            "lines_inside_95": self.lines_inside,
            "lines_aliased": int(np.sum(self.frf.aliased)),
            "outside_hz": [float(f) for f in self.frf.freq_hz[~self.inside]],
            "periods": self.frf.periods,
        }


def check_model(rig: Rig, axis: str, source: FrfSource) -> ResonanceCheck:
    """The FRF of ``source`` against the rig's model of ``axis`` (:func:`rig_model_response`):
    inside where ``|model − measured| <= radius95`` (:meth:`Frf.contains`).

    Raises
    ------
    SpecError
        No such axis, an unreadable FRF, or one measured at another tick period.
    """
    if axis not in rig.axis_names:
        raise SpecError(f"FRF given for axis {axis!r}; rig {rig.name!r} has {list(rig.axis_names)}")
    frf = read_frf(source)
    if abs(frf.period_s - rig.period_s) > PERIOD_RTOL * rig.period_s:
        raise SpecError(
            f"the FRF of axis {axis!r} was measured at a tick period of {frf.period_s!r} s; rig "
            f"{rig.name!r} runs at {rig.period_s!r} s: its model cannot be compared with it"
        )
    model = rig_model_response(rig, axis, frf.freq_hz, frf.output)
    return ResonanceCheck(frf=frf, model=model, inside=np.asarray(frf.contains(model), dtype=bool))


def format_hz(f: float) -> str:
    """A frequency with at least one decimal and three significant digits.

    >>> format_hz(35.0), format_hz(2.345), format_hz(120.5)
    ('35.0', '2.35', '120.5')
    """
    decimals = max(1, 2 - math.floor(math.log10(abs(f)))) if f else 1
    return f"{f:.{decimals}f}"


def modes_phrase(modes: Sequence[Mode]) -> str:
    """``"1 mode at 35.0 Hz (damping 0.040)"``, ``"2 modes at … and …"``, ``"no mode"``.

    >>> modes_phrase([Mode(freq_hz=35.0, damping=0.04, gain=0.5)])
    '1 mode at 35.0 Hz (damping 0.040)'
    """
    if not modes:
        return "no mode"
    each = [f"{format_hz(m.freq_hz)} Hz (damping {m.damping:.3f})" for m in modes]
    listed = each[0] if len(each) == 1 else ", ".join(each[:-1]) + " and " + each[-1]
    return f"{len(modes)} mode{'s' if len(modes) != 1 else ''} at {listed}"


def resonance_statement(
    axis: str, modes: Sequence[Mode], check: ResonanceCheck | None = None
) -> str:
    """One sentence on one axis: its modes, and with a measured response on how many of its
    lines the rig's model lies inside the measured 95 % bounds.

    >>> resonance_statement("slave", ())
    'slave: no mode in the rig file; no frequency response measured.'
    """
    said = f"{axis}: {modes_phrase(modes)} in the rig file"
    if check is None:
        return said + "; no frequency response measured."
    frf = check.frf
    said += (
        f"; the rig's model is within the measured 95 % bounds on {check.lines_inside} of "
        f"{check.lines} lines ({frf.output} response, {format_hz(float(frf.freq_hz[0]))}–"
        f"{format_hz(float(frf.freq_hz[-1]))} Hz, {frf.periods} periods averaged"
    )
    if check.lines_inside < check.lines:
        k = int(np.argmax(check.distance))
        far, at = float(check.distance[k]), format_hz(float(frf.freq_hz[k]))
        said += (
            f"; farthest outside at {at} Hz, {show_number(far, 3)} times its 95 % radius away"
            if math.isfinite(far)
            else f"; outside at {at} Hz, where the bounds have no width (no noise)"
        )
    return said + ")."


def resonance_figure(rig: Rig, axis: str, source: FrfSource | ResonanceCheck) -> Any:
    """The report's figure of one axis (a matplotlib figure): the measured magnitude and phase
    with their 95 % bounds and the coherence (:func:`servotune.plot.plot_frf`), the rig's model
    beside them (:func:`rig_model_response`), the lines where the model lies outside the
    bounds marked with crosses."""
    check = source if isinstance(source, ResonanceCheck) else check_model(rig, axis, source)
    frf = check.frf
    title = f"{axis}: measured {frf.output} response and the rig's model"
    fig = plot_frf(frf, title, check.model, model_label=_MODEL_LABEL)
    out = ~check.inside
    if np.any(out):
        ax = fig.axes[0]
        ax.semilogx(
            frf.freq_hz[out],
            20.0 * np.log10(np.abs(check.model[out])),
            "x",
            ms=5,
            color="C3",
            label=f"model outside the 95 % bounds ({int(np.sum(out))} lines)",
        )
        ax.legend(loc="best", fontsize=8)
    return fig


def _table_rows(rig: Rig) -> list[list[str]]:
    rows = []
    for a in rig.axes:
        for m in a.plant.modes:
            row = [a.name]
            for name in ("freq_hz", "damping", "gain"):
                value, ci = float(getattr(m, name)), getattr(m, f"{name}_95")
                if ci is None:
                    row += [show_number(value), "—"]
                else:
                    row += list(with_interval(value, float(ci[0]), float(ci[1])))
            rows.append([*row, show_number(m.antiresonance_hz)])
    return rows


_TABLE_HEAD = (
    "axis",
    "frequency [Hz]",
    "95 % interval",
    "damping [-]",
    "95 % interval",
    "gain [-]",
    "95 % interval",
    "anti-resonance [Hz]",
)

_TABLE_NOTE = (
    "Each mode multiplies the rigid plant by 1 + gain · s² / (s² + 2 · damping · ω · s + ω²), "
    "ω = 2π · frequency (docs/frf.md#modes); with one mode, gain is the load's inertia over the "
    "motor's and the anti-resonance frequency / √(1 + gain). Intervals: the rig file's (a fit's, "
    "servotune fit --modes); — where it has none."
)

_FIGURE_CAPTION = (
    "Measured: the ratio of the averaged spectra over the excitation's periods, its 95 % bounds "
    "the circle about each line (magnitude and phase shown as that circle's), and the coherence "
    "with the excitation. The model: the rig file's plant with its modes, sampled exactly with "
    "the tick period, the compute time and the delay; crosses mark the lines where it lies "
    "outside the measured 95 % circle (a right model lies inside on about 95 % of the lines)."
)


def resonance_section(
    rig: Rig, frf: Mapping[str, FrfSource] | None = None
) -> tuple[str, dict[str, Any] | None]:
    """The section's HTML and its numbers for the page's data block; ``("", None)`` when no
    axis has modes and no FRF is given (the page keeps its bytes).

    Parameters
    ----------
    rig : Rig
        The rig reported on: its modes, and its model for the FRFs.
    frf : mapping of str to FrfSource, optional
        Per axis, its measured frequency response (:func:`check_model`).
    """
    given = dict(frf or {})
    if not given and not any(a.plant.modes for a in rig.axes):
        return "", None
    unknown = sorted(set(given) - set(rig.axis_names))
    if unknown:
        raise SpecError(
            f"FRF given for axes {unknown}; rig {rig.name!r} has {list(rig.axis_names)}"
        )
    checks = {a.name: check_model(rig, a.name, given[a.name]) for a in rig.axes if a.name in given}
    data: dict[str, Any] = {}
    said = []
    for a in rig.axes:
        check = checks.get(a.name)
        sentence = resonance_statement(a.name, a.plant.modes, check)
        said.append(paragraph_html(sentence))
        data[a.name] = {
            "modes": [m.to_dict() for m in a.plant.modes],
            "frf": None if check is None else check.to_dict(),
            "statement": sentence,
        }
    parts = ['<section id="resonance"><h2>Resonance</h2>', *said]
    rows = _table_rows(rig)
    if rows:
        parts.append(table_html(_TABLE_HEAD, rows) + paragraph_html(_TABLE_NOTE))
    for name, check in checks.items():
        fig = resonance_figure(rig, name, check)
        alt = f"{name}: measured frequency response and the rig's model"
        parts.append(figure_html(png_uri(fig), alt, escape_html(_FIGURE_CAPTION)))
    parts.append("</section>")
    return "".join(parts), data
