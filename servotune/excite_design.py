"""The amplitude of an excitation (:func:`servotune.excite.design_excitation`): the motion the
rig's nominal plant predicts for held D/A codes, and the largest amplitude whose motion stays
within 90 % of the axis speed limit and of its travel.

The prediction is the exact response of the linear axis model (docs/formats.md#axis-model) to
the held codes, with the analog drift ``offset_v`` acting from the start and Coulomb friction
left out (it only slows the axis).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import signal

from servotune.errors import SpecError
from servotune.rig import Axis, Rig
from servotune.validate import show_value

__all__ = [
    "MARGIN",
    "AxisLimits",
    "FittedAmplitude",
    "Motion",
    "fit_amplitude",
    "predict_motion",
]

MARGIN = 0.10
"""Fraction of the speed limit and of the travel kept free by design [-]."""


@dataclass(frozen=True, slots=True)
class Motion:
    """The motion the nominal plant predicts for held codes (:func:`predict_motion`)."""

    speed_cps: np.ndarray  # at every input change (and the start) [counts/s]
    pos_counts: np.ndarray  # same instants, plus the coast-down point after the end [counts]


def predict_motion(rig: Rig, ax: Axis, codes: np.ndarray, offset_v: float) -> Motion:
    """Exact response of the linear axis model to held codes, drift from t = 0, no friction.

    The code of tick ``j`` reaches the motor at ``d + j·T`` (``d = compute_s + delay_s``) and is
    held for ``T``; before ``d`` the motor sees 0 V. On every interval the net input is constant,
    so the speed moves monotonically: its extremes are at the input changes, where it is
    sampled here. Position extremes between samples (where the speed crosses zero) exceed the
    samples by well under a count per tick at these speeds.
    """
    pl = ax.plant
    period, tau, gain = rig.period_s, pl.tau_s, pl.gain_cps_per_v
    d = rig.timer.compute_s + pl.delay_s
    # state when the first code arrives: drift alone for d seconds
    e_d = math.expm1(-d / tau)
    v0 = gain * offset_v * -e_d
    p0 = gain * offset_v * (d + tau * e_d)
    a = math.exp(-period / tau)
    one_minus_a = -math.expm1(-period / tau)
    w = codes.astype(float) * rig.dac.lsb_v + offset_v  # net input per interval [V]
    b_v = gain * one_minus_a
    zi = signal.lfiltic([b_v], [1.0, -a], y=[v0])
    v_next, _ = signal.lfilter([b_v], [1.0, -a], w, zi=zi)
    v = np.concatenate(([0.0, v0], v_next))  # t = 0, d, d + T, ...
    c1 = tau * one_minus_a
    c2 = gain * (period - tau * one_minus_a)
    p_next = p0 + np.cumsum(c1 * v[1:-1] + c2 * w)
    coast = p_next[-1] + tau * v[-1]  # where the axis stops if the command returns to 0 V
    p = np.concatenate(([0.0, p0], p_next, [coast]))
    return Motion(speed_cps=v, pos_counts=p)


def _limit_amplitude(
    unit: Motion, drift: Motion, bound_lo: float, bound_hi: float, pos: bool
) -> float:
    """Largest amplitude A with bound_lo <= A·unit + drift <= bound_hi at every sample."""
    x1 = unit.pos_counts if pos else unit.speed_cps
    x0 = drift.pos_counts if pos else drift.speed_cps
    with np.errstate(divide="ignore", invalid="ignore"):
        up = np.where(x1 > 0, (bound_hi - x0) / x1, np.inf)
        dn = np.where(x1 < 0, (bound_lo - x0) / x1, np.inf)
    return float(min(np.min(up), np.min(dn)))


@dataclass(frozen=True, slots=True)
class AxisLimits:
    """What an excitation's predicted motion must keep within: 90 % of the axis speed limit
    and of its travel (a rotary axis, ``travel_counts = None``, has no travel limit)."""

    speed_cps: float  # largest |speed| [counts/s]
    pos_lo: float  # lowest position [counts] (-inf without travel)
    pos_hi: float  # highest position [counts] (inf without travel)
    travel: tuple[float, float] | None  # the axis travel [counts]

    @classmethod
    def of(cls, rig: Rig, ax: Axis) -> AxisLimits:
        v_lim = ax.speed_limit_rpm / 60.0 * rig.counts_per_rev
        v_ok = (1.0 - MARGIN) * v_lim
        travel = ax.travel_counts
        p_lo, p_hi = -math.inf, math.inf
        if travel is not None:
            p_lo, p_hi = (1.0 - MARGIN) * travel[0], (1.0 - MARGIN) * travel[1]
        return cls(speed_cps=v_ok, pos_lo=p_lo, pos_hi=p_hi, travel=travel)


@dataclass(frozen=True, slots=True)
class FittedAmplitude:
    """The amplitude :func:`fit_amplitude` found, what set it, its codes and their motion
    (drift included)."""

    amplitude_codes: int
    limited_by: str
    codes: np.ndarray
    motion: Motion


@dataclass(frozen=True, slots=True)
class _Request:
    """What the error messages name: the axis, the kind and the duration asked for."""

    axis: str
    kind: str
    seconds: float


def fit_amplitude(
    rig: Rig,
    ax: Axis,
    make: Callable[[int], np.ndarray],
    unit: np.ndarray,
    amp: int,
    limited_by: str,
    *,
    axis: str,
    kind: str,
    seconds: float,
) -> FittedAmplitude:
    """The largest amplitude up to ``amp`` codes whose codes (``make(amplitude)``; ``unit`` the
    unit-amplitude pattern) keep the predicted motion, drift included, within
    :class:`AxisLimits`, and that still reverses the axis against drift and friction.
    ``limited_by`` says what set ``amp``; ``axis``, ``kind`` and ``seconds`` are for the errors.

    Raises
    ------
    SpecError
        Drift alone leaving 90 % of the travel, no amplitude of at least one code fits the
        limits, or the amplitude cannot reverse the axis.
    """
    req = _Request(axis=axis, kind=kind, seconds=seconds)
    lim = AxisLimits.of(rig, ax)
    offset = ax.plant.offset_v
    drift = _drift(rig, ax, unit.size, lim, req)
    unit_m = predict_motion(rig, ax, unit, 0.0)
    bounds = {"speed": _limit_amplitude(unit_m, drift, -lim.speed_cps, lim.speed_cps, pos=False)}
    if lim.travel is not None:
        bounds["travel"] = _limit_amplitude(unit_m, drift, lim.pos_lo, lim.pos_hi, pos=True)
    binding = min(bounds, key=bounds.__getitem__)
    if bounds[binding] < amp:
        amp, limited_by = math.floor(bounds[binding]), binding
    # the linear bound ignores rounding to whole codes: check the real codes, shrink if needed
    while True:
        if amp < 1:
            what = (
                f"speed limit {show_value(ax.speed_limit_rpm)} r/min"
                if limited_by == "speed"
                else f"travel {list(lim.travel) if lim.travel else None!r} counts"
            )
            raise SpecError(
                f"axis {show_value(axis)}: even 1 D/A code of {kind} for {show_value(seconds)} "
                f"s goes beyond 90 % "
                f"of the {what}; shorten the excitation"
            )
        codes = make(amp)
        m = predict_motion(rig, ax, codes, offset)
        ratios = {"speed": float(np.max(np.abs(m.speed_cps))) / lim.speed_cps}
        if lim.travel is not None:
            ratios["travel"] = max(m.pos_counts.max() / lim.pos_hi, m.pos_counts.min() / lim.pos_lo)
        worst = max(ratios, key=ratios.__getitem__)
        if ratios[worst] <= 1.0:
            break
        amp, limited_by = min(amp - 1, math.floor(amp / ratios[worst])), worst
    fitted = FittedAmplitude(amplitude_codes=amp, limited_by=limited_by, codes=codes, motion=m)
    _check_reversal(rig, ax, fitted, req)
    return fitted


def _drift(rig: Rig, ax: Axis, n: int, lim: AxisLimits, req: _Request) -> Motion:
    """The motion of the drift alone over ``n`` ticks of 0 codes.

    Raises
    ------
    SpecError
        The drift alone leaves 90 % of the travel.
    """
    offset = ax.plant.offset_v
    drift = predict_motion(rig, ax, np.zeros(n, dtype=np.int64), offset)
    p_drift = drift.pos_counts
    travel = lim.travel
    if travel is not None and (p_drift.min() < lim.pos_lo or p_drift.max() > lim.pos_hi):
        raise SpecError(
            f"axis {show_value(req.axis)}: the drift offset_v={show_value(offset)} V alone moves "
            f"the axis "
            f"{p_drift[np.argmax(np.abs(p_drift))]:.0f} counts in {show_value(req.seconds)} s, "
            f"beyond 90 % of "
            f"the travel {show_value(list(travel))} counts; shorten the excitation"
        )
    return drift


def _check_reversal(rig: Rig, ax: Axis, fitted: FittedAmplitude, req: _Request) -> None:
    """Check that the codes overcome drift and friction both ways and reverse the axis.

    Raises
    ------
    SpecError
        They do not.
    """
    codes, m, amp = fitted.codes, fitted.motion, fitted.amplitude_codes
    offset = ax.plant.offset_v
    lsb, coulomb = rig.dac.lsb_v, ax.plant.coulomb_v
    up_v, down_v = int(codes.max()) * lsb + offset, int(codes.min()) * lsb + offset
    if not (up_v > coulomb and down_v < -coulomb and m.speed_cps.max() > 0 > m.speed_cps.min()):
        requested = fitted.limited_by == "requested"
        which = "requested" if requested else "largest admissible"
        fix = "ask for a larger amplitude_codes" if requested else "shorten it"
        raise SpecError(
            f"axis {show_value(req.axis)}: the {which} {req.kind} amplitude, {amp} codes "
            f"({amp * lsb * 1e3:.2f} mV), cannot reverse the axis against the drift "
            f"({offset * 1e3:g} mV) and friction ({coulomb * 1e3:g} mV); {fix}"
        )
