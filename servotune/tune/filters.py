"""The output filters of an axis whose plant has lightly damped modes, chosen with its PI
(docs/tuning.md#filters): a notch on each mode, or a low-pass below them, or none, whichever
lets the robust PI (:func:`~servotune.tune.robust.robust_pi`) reach the highest bandwidth (of its
task loop on the nominal plant: :func:`nominal_figures`) while every loop keeps the margin limits
over the plant set (each mode's frequency over the wider of its 95 % interval and ±10 %:
:func:`~servotune.analysis.plant_cases.plant_cases`).

Candidates, for the modes ``f_i`` (their frequency range ``[lo_i, hi_i]``):

- **none**: the plain PI;
- **notch** (two widths): one notch per mode, centred at ``f_i``, depth :data:`NOTCH_DEPTH_DB`,
  its −3 dB width ``k·(hi_i − lo_i)`` for ``k`` in :data:`NOTCH_WIDTHS` (at least
  :data:`MIN_NOTCH_WIDTH` of ``f_i``): deep at the nominal mode and still attenuating at the
  ends of its range;
- **low-pass**: one second-order low-pass, corner :data:`LOWPASS_CORNER` times the lowest
  mode's low end, damping :data:`LOWPASS_DAMPING`: it attenuates every mode, at the price of
  phase at the crossover.

Each candidate's sections are realised as the runtime runs them (quantised at the rig's achieved
period, :func:`servotune.laws.filters.realize`) and enter every loop of the axis, the lock loop
included. The highest bandwidth wins; a filter must beat the plain PI by :data:`MIN_GAIN` to
be placed (a filter that buys nothing only adds delay and a failure point).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

from servotune.analysis.frf import Frf
from servotune.analysis.frf_margins import frf_loop
from servotune.analysis.margins import (
    GainSet,
    LoopFigures,
    MarginLimits,
    loop_margins,
    loop_model,
    margin_grid,
)
from servotune.analysis.plant_cases import PlantCase, mode_factors
from servotune.errors import InfeasibleError
from servotune.laws.filters import Section, lowpass2, notch
from servotune.rig import Rig
from servotune.tune.pi import PITuning
from servotune.tune.robust import robust_pi

__all__ = [
    "LOWPASS_CORNER",
    "LOWPASS_DAMPING",
    "MIN_GAIN",
    "MIN_NOTCH_WIDTH",
    "NOTCH_DEPTH_DB",
    "NOTCH_WIDTHS",
    "FilterChoice",
    "choose_filters",
    "filter_candidates",
    "nominal_figures",
]

NOTCH_DEPTH_DB = -20.0
"""Depth of a notch at its centre [dB]."""
NOTCH_WIDTHS = (1.5, 3.0)
"""Notch −3 dB widths tried, in units of the mode's frequency range ``hi − lo``."""
MIN_NOTCH_WIDTH = 0.2
"""Smallest notch width, relative to the mode's frequency."""
LOWPASS_CORNER = 0.5
"""Low-pass corner relative to the lowest mode's low end."""
LOWPASS_DAMPING = 0.5
"""Low-pass damping ratio."""
MIN_GAIN = 1.05
"""A filter is placed only if its PI's bandwidth is at least this factor above the plain
PI's."""


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class FilterChoice:
    """The filters chosen for one axis and why.

    Attributes
    ----------
    axis : str
    chosen : str
        ``"none"``, ``"notch"`` or ``"lowpass2"``.
    sections : tuple of Section
        The chosen sections (empty for ``"none"``).
    pi : PITuning
        The robust PI designed with them.
    why : str
        One line: the modes, each candidate's Ki and crossover, and the choice.
    candidates : tuple of dict
        Per candidate: ``name``, ``sections`` (design inputs), its robust PI's ``kp``, ``ki``
        and its nominal loop's figures (:func:`nominal_figures`: ``bandwidth_rad_s``,
        ``crossover_rad_s``, the margins), or ``infeasible`` (the binding limit).
    """

    axis: str
    chosen: str
    sections: tuple[Section, ...]
    pi: PITuning
    why: str
    candidates: tuple[dict[str, Any], ...]

    def to_dict(self) -> dict[str, Any]:
        """Plain data for the tuning's design record."""
        return {
            "axis": self.axis,
            "candidates": list(self.candidates),
            "chosen": self.chosen,
            "sections": [s.to_dict() for s in self.sections],
            "why": self.why,
        }


def filter_candidates(rig: Rig, axis_name: str) -> list[tuple[str, tuple[Section, ...]]]:
    """The candidates of the module docstring for one axis (``[("none", ())]`` without modes);
    a section the rig's period cannot carry (at or above Nyquist) is left out."""
    modes = rig.axis(axis_name).plant.modes
    out: list[tuple[str, tuple[Section, ...]]] = [("none", ())]
    if not modes:
        return out
    nyq = 0.5 / rig.period_s
    for k in NOTCH_WIDTHS:
        secs = []
        for m in modes:
            lo, hi = mode_factors(m)
            width = max(k * (hi - lo), MIN_NOTCH_WIDTH) * m.freq_hz
            secs.append(notch(m.freq_hz, width, NOTCH_DEPTH_DB))
        if all(s.warp_hz < nyq for s in secs):
            out.append((f"notch x{k:g}", tuple(secs[:4])))
    low = min(m.freq_hz * mode_factors(m)[0] for m in modes)
    out.append(("lowpass2", (lowpass2(LOWPASS_CORNER * low, LOWPASS_DAMPING),)))
    return out


def nominal_figures(rig: Rig, axis: int, pi: PITuning) -> LoopFigures:
    """The task loop of ``pi`` on the axis's nominal plant behind its filters
    (:meth:`~servotune.rig.Rig.runtime_filters`), by python-control: its bandwidth (``|T|`` at
    −3 dB), crossover and margins."""
    plant = rig.axes[axis].plant
    model = loop_model(
        plant,
        GainSet(pi.gains.kp, pi.gains.ki * rig.period_s),
        period_s=rig.period_s,
        lag_s=rig.timer.compute_s + plant.delay_s,
        lsb_volts=rig.dac.lsb_v,
        filters=rig.runtime_filters(axis),
    )
    return loop_margins(model, margin_grid(plant, rig.period_s))


def choose_filters(
    rig: Rig,
    axis_name: str,
    cases: Sequence[PlantCase],
    limits: MarginLimits,
    screen_cases: Sequence[PlantCase] | None = None,
    *,
    frf: Frf | None = None,
    extra_ticks: int = 1,
) -> FilterChoice:
    """Choose the output filters and the robust PI of one axis together (module docstring):
    each candidate's PI designed at ``cases`` and screened over ``screen_cases``
    (:func:`~servotune.tune.robust.robust_pi`). With a measured response ``frf`` of the axis
    (``servotune frf``), a candidate must also keep the limits on it and its 95 % bounds, with 0
    and ``extra_ticks`` more ticks of latency (:func:`~servotune.analysis.frf_margins.frf_loop`:
    the task loop and the lock loop at the rig's lock gain); the best one that does is chosen.

    Raises
    ------
    InfeasibleError
        No candidate, the plain PI included, keeps the limits on every case (or on the measured
        response): the message names the axis's modes and each candidate's binding margin.
    """
    a = rig.axis_names.index(axis_name)
    where = ", ".join(f"{m.freq_hz:g} Hz (damping {m.damping:g})" for m in rig.axes[a].plant.modes)
    tried: list[_Tried] = []
    for name, secs in filter_candidates(rig, axis_name):
        trial = _with_filters(rig, a, secs)
        try:
            pi = robust_pi(trial, axis_name, cases, limits, screen_cases)
        except InfeasibleError as exc:
            tried.append(_Tried(name, secs, None, None, str(exc).rsplit(": ", 1)[-1]))
            continue
        broken = "" if frf is None else _frf_broken(trial, a, pi, frf, limits, extra_ticks)
        tried.append(_Tried(name, secs, pi, nominal_figures(trial, a, pi), broken))
    feasible = [t for t in tried if t.pi is not None and not t.why]
    if not feasible:
        broken = "; ".join(f"{t.name}: {t.why}" for t in tried)
        raise InfeasibleError(
            f"no PI for axis {axis_name!r} keeps the margin limits with the mode at {where}, "
            f"with or without a filter ({broken})"
        )
    plain = tried[0] if tried[0] in feasible else None
    best = max(feasible, key=lambda t: t.bandwidth)
    if plain is not None and best.bandwidth < MIN_GAIN * plain.bandwidth:
        best = plain
    if best is plain:
        why = f"no filter: none beats the plain PI's bandwidth by {100 * (MIN_GAIN - 1):g} %"
    elif plain is None:
        why = f"{best.name}: the plain PI cannot keep the limits ({tried[0].why})"
    else:
        why = f"{best.name}: bandwidth {best.bandwidth / plain.bandwidth:.2f}x the plain PI's"
    summary = "; ".join(t.summary() for t in tried)
    return FilterChoice(
        axis=axis_name,
        chosen=best.name.split(" ")[0],
        sections=best.sections,
        pi=best.pi,  # type: ignore[arg-type]
        why=f"modes at {where}; {why} ({summary})",
        candidates=tuple(t.to_dict() for t in tried),
    )


@dataclasses.dataclass(frozen=True, slots=True)
class _Tried:
    """One candidate: its PI and nominal figures, or why it is out."""

    name: str
    sections: tuple[Section, ...]
    pi: PITuning | None
    figures: LoopFigures | None
    why: str  # empty: feasible

    @property
    def bandwidth(self) -> float:
        return math.nan if self.figures is None else self.figures.bandwidth_rad_s

    def summary(self) -> str:
        if self.pi is None:
            return f"{self.name}: infeasible ({self.why})"
        text = f"{self.name}: bandwidth {self.bandwidth:.3g} rad/s (Ki {self.pi.gains.ki:.4g})"
        return text + (f", but {self.why}" if self.why else "")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name, "sections": [s.to_dict() for s in self.sections]}
        if self.pi is not None and self.figures is not None:
            out |= {"kp": self.pi.gains.kp, "ki": self.pi.gains.ki} | self.figures.as_fields()
        if self.why:
            out["infeasible"] = self.why
        return out


def _with_filters(rig: Rig, a: int, secs: tuple[Section, ...]) -> Rig:
    axes = tuple(
        dataclasses.replace(x, filters=secs) if i == a else x for i, x in enumerate(rig.axes)
    )
    return dataclasses.replace(rig, axes=axes)


def _frf_broken(
    rig: Rig, a: int, pi: PITuning, frf: Frf, limits: MarginLimits, extra_ticks: int
) -> str:
    """What the candidate breaks on the measured response (empty: nothing)."""
    secs = rig.runtime_filters(a)
    t = rig.period_s
    ax = rig.axes[a]
    for loop, g in (
        ("task", GainSet(pi.gains.kp, pi.gains.ki * t)),
        ("lock", GainSet(ax.lock_gain_codes_per_count)),
    ):
        for m in sorted({0, extra_ticks}):
            res = frf_loop(frf, g, lsb_v=rig.dac.lsb_v, filters=secs, extra_ticks=m, loop=loop)
            if broken := res.broken(limits):
                tick = f" +{m} tick" if m else ""
                return f"on the measured response, {loop} loop{tick}: {'; '.join(broken)}"
    return ""
