"""What an axis's output filters do to its loops (what ``servotune margins`` shows beside the
margins): each section's response at the plant's modes and at the loop's crossover, and the
nominal loops' margins with the filters taken out (docs/tuning.md#filters).

The sections are the quantised ones the runtime runs (``AxisController.filters``); their
response is that of their realised coefficients at the rig's achieved period
(:func:`servotune.laws.filters.chain_response`). The margins without them are computed as every
loop's are (:func:`servotune.analysis.margins.loop_model`, python-control), with no filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from servotune.analysis.margins import LoopMargins, gain_sets, loop_margins, loop_model, margin_grid
from servotune.laws.filters import SectionQ, chain_response

if TYPE_CHECKING:
    from servotune.rig import Rig
    from servotune.tuning import Tuning

__all__ = ["FilterEffect", "filter_effects"]


@dataclass(frozen=True, slots=True, kw_only=True)
class FilterEffect:
    """One axis's filters and what they do.

    Attributes
    ----------
    axis : str
    sections : tuple of SectionQ
        The quantised sections, in the order they run.
    at_modes : tuple of (float, float, float)
        Per plant mode: its frequency [Hz], the filters' gain there [dB] and phase [deg].
    at_crossover : tuple of (str, float, float, float)
        Per loop (``lock``, ``task``): its crossover with the filters [rad/s] and the filters'
        gain [dB] and phase [deg] there (the phase they cost the loop).
    without : tuple of LoopMargins
        The nominal lock and task loops (a scheduled law's centre cell) with no filter.
    """

    axis: str
    sections: tuple[SectionQ, ...]
    at_modes: tuple[tuple[float, float, float], ...]
    at_crossover: tuple[tuple[str, float, float, float], ...]
    without: tuple[LoopMargins, ...]

    def to_dict(self) -> dict[str, Any]:
        """Plain data (units in the keys)."""
        return {
            "axis": self.axis,
            "sections": [s.to_dict() for s in self.sections],
            "at_modes": [{"freq_hz": f, "gain_db": g, "phase_deg": p} for f, g, p in self.at_modes],
            "at_crossover": [
                {"loop": n, "crossover_rad_s": w, "gain_db": g, "phase_deg": p}
                for n, w, g, p in self.at_crossover
            ],
            "without_filters": [m.to_dict() for m in self.without],
        }


def _db_deg(sections: tuple[SectionQ, ...], w: float, period_s: float) -> tuple[float, float]:
    h = complex(chain_response(sections, np.array([w]), period_s)[0])
    return 20.0 * math.log10(max(abs(h), 1e-300)), math.degrees(math.atan2(h.imag, h.real))


def filter_effects(tuning: Tuning, rig: Rig) -> tuple[FilterEffect, ...]:
    """The :class:`FilterEffect` of every axis of ``tuning`` that has filters (none: empty)."""
    out = []
    period = rig.period_s
    for a, (name, ctl) in enumerate(zip(tuning.axis_names, tuning.controllers, strict=True)):
        if not ctl.filters:
            continue
        plant = rig.axes[a].plant
        lag = rig.timer.compute_s + plant.delay_s
        w = margin_grid(plant, period)
        at_modes = tuple(
            (m.freq_hz, *_db_deg(ctl.filters, 2 * math.pi * m.freq_hz, period)) for m in plant.modes
        )
        crossings, without = [], []
        for loop, cell, g in gain_sets(ctl):
            if cell not in (None, (0, 0)):
                continue
            fig = {}
            for secs in (ctl.filters, ()):
                model = loop_model(
                    plant, g, period_s=period, lag_s=lag, lsb_volts=rig.dac.lsb_v, filters=secs
                )
                fig[bool(secs)] = loop_margins(model, w)
            wc = fig[True].crossover_rad_s
            if math.isfinite(wc):
                crossings.append((loop, wc, *_db_deg(ctl.filters, wc, period)))
            without.append(
                LoopMargins(
                    axis=name,
                    loop=loop,
                    cell=cell,
                    plant="nominal",
                    gains=g,
                    period_s=period,
                    **fig[False].as_fields(),
                )  # type: ignore[arg-type]
            )
        out.append(
            FilterEffect(
                axis=name,
                sections=ctl.filters,
                at_modes=at_modes,
                at_crossover=tuple(crossings),
                without=tuple(without),
            )
        )
    return tuple(out)
