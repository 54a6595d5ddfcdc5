"""Loop margins on a measured frequency response (``--frf AXIS=FILE``,
docs/tuning.md#on-the-measured-response): the loop rebuilt from the non-parametric response of
``servotune frf`` instead of the rig's model, with the response's 95 % bounds.

The response ``Ĝ`` is the sampled one from the D/A voltage to the counter (counts per V; a
velocity response, counts/s per V, is turned into position by ``T / (1 − e^{−jωT})``, the
backward difference undone). Each loop of an axis is ``L = C(z)·F(z)·lsb·Ĝ·z^{−m}``: the
controller's frozen gains (:func:`~servotune.analysis.margins.gain_sets`), the axis's output
filters (their realised coefficients), the D/A's gain and ``m`` extra ticks of latency (the
plant set's). The figures come from python-control on a ``FrequencyResponseData`` of ``L``
(``control.stability_margins``, its interpolating method; ``Ms = max |1/(1 + L)|`` over the
lines), once on ``Ĝ`` and once on each of four responses at the corners of its 95 % circle
(``|Ĝ| ± r``, ``arg Ĝ ± asin(r/|Ĝ|)``, each line's radius ``r``); the worst of all is what the
limits judge. Only the measured band is seen: a crossover outside it is reported, not found.
Stability is the model's to show (a measured response cannot count encirclements outside its
band); the margins here check that the model's loop keeps its robustness on the machine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from servotune.analysis.frf import Frf
from servotune.analysis.margins import GainSet, MarginLimits, controller_response, gain_sets
from servotune.laws.filters import SectionQ, chain_response

if TYPE_CHECKING:
    from servotune.laws.axis import AxisController

__all__ = ["FrfLoop", "frf_loop", "frf_loops", "position_response"]


@dataclass(frozen=True, slots=True, kw_only=True)
class FrfLoop:
    """One loop's margins on a measured response.

    Attributes
    ----------
    axis, loop : str
    cell : (int, int) or None
    extra_ticks : int
    phase_margin_deg, gain_margin_db, max_sensitivity : float
        The worst over the response and its four 95 % corners.
    nominal_phase_margin_deg, nominal_gain_margin_db, nominal_max_sensitivity : float
        On ``Ĝ`` itself.
    crossover_rad_s : float
        The gain crossover on ``Ĝ`` (NaN if ``|L|`` does not cross 1 inside the band).
    band_hz : (float, float)
        The measured lines' range.
    filtered : bool
        The axis's filters are in the loop.
    """

    axis: str
    loop: str
    cell: tuple[int, int] | None
    extra_ticks: int
    phase_margin_deg: float
    gain_margin_db: float
    max_sensitivity: float
    nominal_phase_margin_deg: float
    nominal_gain_margin_db: float
    nominal_max_sensitivity: float
    crossover_rad_s: float
    band_hz: tuple[float, float]
    filtered: bool

    def broken(self, limits: MarginLimits) -> tuple[str, ...]:
        """The limits it breaks, each as ``"PM 41.2° < 45°"``."""
        return limits.broken_values(
            self.phase_margin_deg, self.gain_margin_db, self.max_sensitivity
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain data."""
        return {
            "axis": self.axis,
            "loop": self.loop,
            "cell": None if self.cell is None else list(self.cell),
            "extra_ticks": self.extra_ticks,
            "phase_margin_deg": self.phase_margin_deg,
            "gain_margin_db": self.gain_margin_db,
            "max_sensitivity": self.max_sensitivity,
            "nominal_phase_margin_deg": self.nominal_phase_margin_deg,
            "nominal_gain_margin_db": self.nominal_gain_margin_db,
            "nominal_max_sensitivity": self.nominal_max_sensitivity,
            "crossover_rad_s": self.crossover_rad_s,
            "band_hz": list(self.band_hz),
            "filtered": self.filtered,
        }


def position_response(frf: Frf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(ω [rad/s], Ĝ [counts per V], r95)`` of the measured lines (aliased lines left out),
    a velocity response turned into position (module docstring)."""
    keep = ~np.asarray(frf.aliased, dtype=bool)
    w = 2.0 * math.pi * np.asarray(frf.freq_hz, dtype=float)[keep]
    g = np.asarray(frf.response, dtype=complex)[keep]
    r = np.asarray(frf.radius95, dtype=float)[keep]
    if frf.output == "velocity":
        k = frf.period_s / (1.0 - np.exp(-1j * w * frf.period_s))
        g, r = g * k, r * np.abs(k)
    return w, g, r


def _figures(w: np.ndarray, resp: np.ndarray) -> tuple[float, float, float, float]:
    import control

    gm, pm, _, _, wcg, _ = control.stability_margins(control.frd(resp, w))
    ms = float(np.max(1.0 / np.abs(1.0 + resp)))
    gm_db = math.inf if gm is None or not np.isfinite(gm) else 20.0 * math.log10(gm)
    pm_deg = math.inf if pm is None or not np.isfinite(pm) else float(pm)
    return pm_deg, gm_db, ms, float(wcg) if np.isfinite(wcg) else math.nan


def frf_loop(
    frf: Frf,
    gains: GainSet,
    *,
    lsb_v: float,
    filters: tuple[SectionQ, ...] = (),
    extra_ticks: int = 0,
    axis: str = "",
    loop: str = "task",
    cell: tuple[int, int] | None = None,
) -> FrfLoop:
    """One loop's figures on ``frf`` (module docstring)."""
    w, g, r = position_response(frf)
    t = frf.period_s
    outer = controller_response(
        np.array([gains.kp, gains.ki_t, gains.kd_t]), w, t
    ).ravel() * chain_response(filters, w, t)
    outer = outer * lsb_v * np.exp(-1j * w * t * extra_ticks)
    nominal = _figures(w, outer * g)
    worst = list(nominal[:3])
    rel = np.minimum(r / np.maximum(np.abs(g), 1e-300), 0.999)
    dphi = np.arcsin(rel)
    for s_mag in (-1.0, 1.0):
        for s_ph in (-1.0, 1.0):
            corner = g * (1.0 + s_mag * rel) * np.exp(1j * s_ph * dphi)
            pm, gm, ms, _ = _figures(w, outer * corner)
            worst = [min(worst[0], pm), min(worst[1], gm), max(worst[2], ms)]
    return FrfLoop(
        axis=axis,
        loop=loop,
        cell=cell,
        extra_ticks=extra_ticks,
        phase_margin_deg=worst[0],
        gain_margin_db=worst[1],
        max_sensitivity=worst[2],
        nominal_phase_margin_deg=nominal[0],
        nominal_gain_margin_db=nominal[1],
        nominal_max_sensitivity=nominal[2],
        crossover_rad_s=nominal[3],
        band_hz=(float(w[0] / (2 * math.pi)), float(w[-1] / (2 * math.pi))),
        filtered=bool(filters),
    )


def frf_loops(
    frf: Frf,
    controller: AxisController,
    *,
    lsb_v: float,
    axis: str = "",
    extra_ticks: int = 1,
    filters: bool = True,
) -> tuple[FrfLoop, ...]:
    """Every loop of an axis controller on ``frf``, with 0 and ``extra_ticks`` extra ticks of
    latency (a scheduled law: every cell), the axis's filters in (``filters``) or taken out."""
    secs = controller.filters if filters else ()
    out = []
    seen: dict[tuple[GainSet, int], FrfLoop] = {}
    for loop, cell, g in gain_sets(controller):
        for m in sorted({0, extra_ticks}):
            if (g, m) not in seen:
                seen[(g, m)] = frf_loop(
                    frf, g, lsb_v=lsb_v, filters=secs, extra_ticks=m, axis=axis, loop=loop
                )
            res = seen[(g, m)]
            out.append(FrfLoop(**{**_fields(res), "loop": loop, "cell": cell}))
    return tuple(out)


def _fields(x: FrfLoop) -> dict[str, Any]:
    return {k: getattr(x, k) for k in FrfLoop.__dataclass_fields__}
