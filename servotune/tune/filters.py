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
  phase at the crossover;
- **notch with a lead** (:func:`lead_candidates`): where a notch is the best of those (it
  beats the plain PI), the notch with one more section, a phase lead (:func:`lead_section`, a
  general biquad) centred at :data:`LEAD_CENTRES` times that candidate's crossover, ratio
  :data:`LEAD_RATIOS`. Behind its notch the mode no longer limits the loop; the phase margin
  at the crossover does (the plant's lag, the tick's delay and one more tick). The lead buys
  phase there, at the price of more gain above the crossover: every loop's margins over the
  plant set judge it, and since the filters also run in lock mode, a lead is kept only if the
  robust lock gain it leaves
  (:func:`~servotune.tune.robust.robust_lock_gain`) is at least :data:`LEAD_LOCK_KEEP` of the
  notch's alone (the lock's stiffness against the drive's offset).

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
from servotune.laws.axis import MAX_FILTERS
from servotune.laws.filters import Section, biquad, lowpass2, notch
from servotune.rig import Rig
from servotune.tune.pi import PITuning
from servotune.tune.robust import robust_lock_gain, robust_pi

__all__ = [
    "LEAD_CENTRES",
    "LEAD_LOCK_KEEP",
    "LEAD_RATIOS",
    "LOWPASS_CORNER",
    "LOWPASS_DAMPING",
    "MIN_GAIN",
    "MIN_NOTCH_WIDTH",
    "NOTCH_DEPTH_DB",
    "NOTCH_WIDTHS",
    "FilterChoice",
    "choose_filters",
    "filter_candidates",
    "lead_candidates",
    "lead_section",
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
LEAD_CENTRES = (1.3, 1.7)
"""Lead centres tried, relative to the crossover of the candidate it is added to."""
LEAD_RATIOS = (1.1, 1.15)
"""Lead ratios tried (:func:`lead_section`'s ``ratio``: its gain rises by ``ratio²``)."""
LEAD_LOCK_KEEP = 0.8
"""The smallest share of the notch's robust lock gain a lead may leave."""


@dataclasses.dataclass(frozen=True, slots=True, kw_only=True)
class FilterChoice:
    """The filters chosen for one axis and why.

    Attributes
    ----------
    axis : str
    chosen : str
        ``"none"``, ``"notch"``, ``"notch+lead"`` or ``"lowpass2"``.
    name : str
        The chosen candidate's full name (``"notch x1.5+lead 1.25@20.1"``: the notch width in
        units of the mode's range, the lead's ratio and centre [rad/s]).
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
    name: str
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
            "name": self.name,
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


def lead_section(center_rad_s: float, ratio: float) -> Section:
    """A phase lead as one second-order section: two equal first-order leads, each with its
    zero at ``center/ratio^½`` and its pole at ``center·ratio^½``. Unit gain at DC, ``ratio²``
    at high frequency, the most phase, ``2·asin((ratio − 1)/(ratio + 1))``, at ``center``
    (pre-warped there): ``F(s) = (s/ω_z + 1)² / (s/ω_p + 1)²``.
    """
    wz = center_rad_s / math.sqrt(ratio)
    wp = center_rad_s * math.sqrt(ratio)
    k = (wp / wz) ** 2
    return biquad(
        [k, 2.0 * k * wz, k * wz**2], [1.0, 2.0 * wp, wp**2], warp_hz=center_rad_s / (2 * math.pi)
    )


def lead_candidates(
    name: str, sections: tuple[Section, ...], crossover_rad_s: float, nyquist_hz: float
) -> list[tuple[str, tuple[Section, ...]]]:
    """Candidate ``name`` (its ``sections``, its loop crossing over at ``crossover_rad_s``)
    with a lead (:func:`lead_section`) at each of :data:`LEAD_CENTRES` times the crossover and
    each of :data:`LEAD_RATIOS`; none where the chain is full or the crossover unknown, and a
    lead whose pole is at or above half of ``nyquist_hz`` is left out."""
    if len(sections) >= MAX_FILTERS or not math.isfinite(crossover_rad_s):
        return []
    out = []
    for r in LEAD_CENTRES:
        wc = r * crossover_rad_s
        for ratio in LEAD_RATIOS:
            if wc * math.sqrt(ratio) / (2 * math.pi) < 0.5 * nyquist_hz:
                label = f"{name}+lead {ratio:g}@{wc:.3g}"
                out.append((label, (*sections, lead_section(wc, ratio))))
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

    def attempt(name: str, kind: str, secs: tuple[Section, ...]) -> _Tried:
        trial = _with_filters(rig, a, secs)
        try:
            pi = robust_pi(trial, axis_name, cases, limits, screen_cases)
        except InfeasibleError as exc:
            return _Tried(name, kind, secs, None, None, str(exc).rsplit(": ", 1)[-1])
        broken = "" if frf is None else _frf_broken(trial, a, pi, frf, limits, extra_ticks)
        return _Tried(name, kind, secs, pi, nominal_figures(trial, a, pi), broken)

    tried = [attempt(n, n.split(" ")[0], s) for n, s in filter_candidates(rig, axis_name)]
    base = _best(tried)
    if base is not None and base.kind == "notch":  # the notch with a lead (module docstring)
        crossover = base.figures.crossover_rad_s  # type: ignore[union-attr]
        screen = cases if screen_cases is None else screen_cases
        lock = robust_lock_gain(_with_filters(rig, a, base.sections), axis_name, screen, limits)
        for n, s in lead_candidates(base.name, base.sections, crossover, 0.5 / rig.period_s):
            t = attempt(n, "notch+lead", s)
            if t.feasible:
                try:
                    k = robust_lock_gain(_with_filters(rig, a, s), axis_name, screen, limits)
                except InfeasibleError:
                    k = 0.0
                if k < LEAD_LOCK_KEEP * lock:
                    why = f"lock gain {k:.3g} < {LEAD_LOCK_KEEP:g} of the notch's {lock:.3g}"
                    t = dataclasses.replace(t, why=why)
            tried.append(t)
    best = _best(tried)
    if best is None:
        broken = "; ".join(f"{t.name}: {t.why}" for t in tried)
        raise InfeasibleError(
            f"no PI for axis {axis_name!r} keeps the margin limits with the mode at {where}, "
            f"with or without a filter ({broken})"
        )
    plain = tried[0] if tried[0].feasible else None
    if best is plain:
        why = f"no filter: none beats the plain PI's bandwidth by {100 * (MIN_GAIN - 1):g} %"
    elif plain is None:
        why = f"{best.name}: the plain PI cannot keep the limits ({tried[0].why})"
    else:
        why = f"{best.name}: bandwidth {best.bandwidth / plain.bandwidth:.2f}x the plain PI's"
    summary = "; ".join(t.summary() for t in tried)
    return FilterChoice(
        axis=axis_name,
        chosen=best.kind,
        name=best.name,
        sections=best.sections,
        pi=best.pi,  # type: ignore[arg-type]
        why=f"modes at {where}; {why} ({summary})",
        candidates=tuple(t.to_dict() for t in tried),
    )


@dataclasses.dataclass(frozen=True, slots=True)
class _Tried:
    """One candidate: its PI and nominal figures, or why it is out."""

    name: str
    kind: str  # FilterChoice.chosen
    sections: tuple[Section, ...]
    pi: PITuning | None
    figures: LoopFigures | None
    why: str  # empty: feasible

    @property
    def feasible(self) -> bool:
        return self.pi is not None and not self.why

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


def _best(tried: Sequence[_Tried]) -> _Tried | None:
    """The feasible candidate with the highest bandwidth, the plain PI (``tried[0]``) unless
    it is beaten by :data:`MIN_GAIN`; None if none is feasible."""
    feasible = [t for t in tried if t.feasible]
    if not feasible:
        return None
    best = max(feasible, key=lambda t: t.bandwidth)
    plain = tried[0] if tried[0].feasible else None
    if plain is not None and best.bandwidth < MIN_GAIN * plain.bandwidth:
        return plain
    return best


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
