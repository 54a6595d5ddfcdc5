"""Gains that keep their margins over the plant set: the master's PI and each axis's lock gain.

What is not known about a loop (:func:`servotune.analysis.plant_cases.plant_cases`: the corners of
the identified intervals and of the spreads, each one tick late, at the period ± the timer's
error) is where the margin limits must hold, not only the nominal plant. The two fixed-gain
loops are designed for it here; the slave's scheduled law keeps the same limits as constraints
of its own tuner (:mod:`servotune.tune.slave`).

Designs aim a little inside the limits (:data:`DESIGN_TOLERANCE`) so that the verdict,
python-control on the quantised constants (:func:`~servotune.analysis.margins.tuning_margins`),
is not decided by a rounding.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from servotune.analysis.margins import (
    MarginLimits,
    controller_basis,
    grid_margins,
    mode_points,
    unwrapped_phase,
)
from servotune.analysis.plant_cases import PlantCase, plant_response
from servotune.errors import InfeasibleError, SpecError
from servotune.laws.filters import chain_response
from servotune.rig import Rig
from servotune.tune.pi import PITuning, tune_pi

__all__ = [
    "DESIGN_TOLERANCE",
    "MarginScreen",
    "design_limits",
    "modes_note",
    "robust_lock_gain",
    "robust_pi",
]

DESIGN_TOLERANCE = MarginLimits(min_phase_margin_deg=0.5, min_gain_margin_db=0.2,
                                max_sensitivity=1.03)  # fmt: skip
"""How far inside the limits a design aims: PM + 0.5°, GM + 0.2 dB, Ms − 0.03 (the grid
screen and the quantisation move the figures by far less)."""
SCREEN_POINTS = 400
"""Frequencies of a margin screen (log-spaced up to the Nyquist frequency)."""
SLOWER_STEP = 0.8
"""Factor on the crossover bound per try when no design keeps the limits (:func:`robust_pi`)."""
SLOWER_TRIES = 12
"""Tries of :data:`SLOWER_STEP` (down to 0.8^12 ≈ 7 % of the crossover)."""
SLOWER_BISECTIONS = 3
"""Bisection steps between the last failing and the first passing bound."""


def design_limits(limits: MarginLimits) -> MarginLimits:
    """``limits`` tightened by :data:`DESIGN_TOLERANCE` (an Ms limit close to 1 by at most
    half its distance to 1, so the aim stays a valid limit)."""
    tol = DESIGN_TOLERANCE
    ms = limits.max_sensitivity
    return MarginLimits(
        min_phase_margin_deg=limits.min_phase_margin_deg + tol.min_phase_margin_deg,
        min_gain_margin_db=limits.min_gain_margin_db + tol.min_gain_margin_db,
        max_sensitivity=max(ms - (tol.max_sensitivity - 1.0), 1.0 + 0.5 * (ms - 1.0)),
    )


class MarginScreen:
    """Worst margins of gain sets on one axis over a plant set, fast (a grid screen).

    The plant responses of the cases are computed once (python-control); each call multiplies
    them (and the axis's output filters, :meth:`~servotune.rig.Rig.runtime_filters`) with the
    controllers' responses and finds every crossing on the grid
    (:func:`~servotune.analysis.margins.grid_margins`).

    Parameters
    ----------
    rig : Rig
    axis : int
        Index of the axis in the rig.
    cases : sequence of PlantCase
    """

    def __init__(self, rig: Rig, axis: int, cases: Sequence[PlantCase]) -> None:
        self._grids = []
        filters = rig.runtime_filters(axis)
        for case in cases:
            plant = case.plants[axis]
            top = math.pi / case.period_s
            while top * case.period_s >= math.pi:
                top = float(np.nextafter(top, 0.0))
            w = np.logspace(math.log10(1e-3 / plant.tau_s), math.log10(top), SCREEN_POINTS)
            w[-1] = top  # logspace's end rounds either way
            if plant.modes:
                w = np.unique(np.concatenate([w, mode_points(plant, top)]))
            g = plant_response(plant, rig, case, w) * chain_response(filters, w, case.period_s)
            g = g[None, :]
            self._grids.append((w, controller_basis(w, case.period_s), g, unwrapped_phase(g)))

    def __call__(self, gains: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Worst phase margin [deg], gain margin [dB] and Ms over the cases of each gain row
        ``(Kp, Ki·T, Kd/T)`` [codes/count]."""
        g = np.atleast_2d(np.asarray(gains, dtype=float))
        pm = np.full(g.shape[0], np.inf)
        gm = np.full(g.shape[0], np.inf)
        ms = np.zeros(g.shape[0])
        for w, basis, pr, ph in self._grids:
            m = grid_margins(w, g, basis, pr, ph)
            pm = np.minimum(pm, np.degrees(m["pm"][:, 0]))
            gm = np.minimum(gm, 20.0 / math.log(10.0) * m["gm"][:, 0])
            ms = np.maximum(ms, m["ms"][:, 0])
        return pm, gm, ms


def _meets(limits: MarginLimits, pm: np.ndarray, gm: np.ndarray, ms: np.ndarray) -> np.ndarray:
    return (
        (pm >= limits.min_phase_margin_deg)
        & (gm >= limits.min_gain_margin_db)
        & (ms <= limits.max_sensitivity)
    )


def _binding(limits: MarginLimits, pm: float, gm: float, ms: float) -> str:
    shortfall = {
        f"PM {pm:.1f}° < {limits.min_phase_margin_deg:g}°": (limits.min_phase_margin_deg - pm)
        / limits.min_phase_margin_deg,
        f"GM {gm:.1f} dB < {limits.min_gain_margin_db:g} dB": (limits.min_gain_margin_db - gm)
        / max(limits.min_gain_margin_db, 1.0),
        f"Ms {ms:.2f} > {limits.max_sensitivity:g}": (ms - limits.max_sensitivity)
        / limits.max_sensitivity,
    }
    return max(shortfall, key=lambda k: shortfall[k])


def modes_note(rig: Rig, axis: int) -> str:
    """`` with the mode at 15 Hz (damping 0.03) and its notch (15 Hz, …)`` for an axis whose plant
    has modes (and filters), else ``""``: what an infeasible loop's message names."""
    a = rig.axes[axis]
    if not a.plant.modes:
        return ""
    modes = ", ".join(f"{m.freq_hz:g} Hz (damping {m.damping:g})" for m in a.plant.modes)
    what = "modes" if len(a.plant.modes) > 1 else "mode"
    filters = " and ".join(f.describe() for f in a.filters)
    return f" with the {what} at {modes}" + (f" behind its {filters}" if filters else "")


def robust_pi(
    rig: Rig,
    axis_name: str,
    cases: Sequence[PlantCase],
    limits: MarginLimits,
    screen_cases: Sequence[PlantCase] | None = None,
) -> PITuning:
    """The PI of one axis with the largest integral gain that keeps ``limits`` on every case.

    :func:`~servotune.tune.pi.tune_pi` designs at each case whose latency is the largest (the
    others lag less, so lose less phase at every frequency), aiming at the tightened limits
    (:func:`design_limits`); each design is screened over every case (``screen_cases``, default
    ``cases``: a wider set, e.g. with sampled plants, costs a grid per case, not a design) and
    the feasible one with the largest Ki is kept. If none is feasible (a lightly damped mode
    that moves over the cases), the slowest design's crossover is bounded lower until the
    screen passes (:data:`SLOWER_STEP`): the fastest plain PI found that keeps the limits.

    Raises
    ------
    InfeasibleError
        No design keeps the limits on every case (the message names the binding limit).
    """
    a = rig.axis_names.index(axis_name)
    aim = design_limits(limits)
    screen = MarginScreen(rig, a, cases if screen_cases is None else screen_cases)
    lag = max(c.extra_lag_s for c in cases)
    best: PITuning | None = None
    closest: tuple[float, str] = (math.inf, "")
    slowest: tuple[PITuning, PlantCase] | None = None
    for case in cases:
        if case.extra_lag_s != lag or case.period_s != rig.period_s:
            continue
        design = _design_at(rig, a, case, aim)
        ok, why = _screened(screen, limits, design, rig.period_s)
        if ok:
            if best is None or design.gains.ki > best.gains.ki:
                best = design
        else:
            closest = min(closest, why)
            if slowest is None or design.crossover_rad_s < slowest[0].crossover_rad_s:
                slowest = (design, case)
    if best is None and slowest is not None:
        best = _slower(rig, a, slowest, aim, screen, limits)
    if best is None:
        raise InfeasibleError(
            f"no PI for axis {axis_name!r}{modes_note(rig, a)} keeps the margin limits on every "
            f"plant case: {closest[1] or 'no case to design at'}"
        )
    return best


def _design_at(
    rig: Rig, a: int, case: PlantCase, aim: MarginLimits, crossover_rad_s: float | None = None
) -> PITuning:
    p = case.plants[a]
    return tune_pi(
        dataclasses.replace(p, delay_s=p.delay_s + case.extra_lag_s),
        period_s=rig.period_s,
        compute_s=rig.timer.compute_s,
        lsb_v=rig.dac.lsb_v,
        phase_margin_deg=aim.min_phase_margin_deg,
        gain_margin_db=aim.min_gain_margin_db,
        max_sensitivity=aim.max_sensitivity,
        crossover_rad_s=crossover_rad_s,
        filters=rig.runtime_filters(a),
    )


def _screened(
    screen: MarginScreen, limits: MarginLimits, design: PITuning, period_s: float
) -> tuple[bool, tuple[float, str]]:
    g = design.gains
    pm, gm, ms = (float(x[0]) for x in screen(np.array([[g.kp, g.ki * period_s, 0.0]])))
    if _meets(limits, np.array(pm), np.array(gm), np.array(ms)):
        return True, (math.inf, "")
    return False, (-min(pm, 90.0), _binding(limits, pm, gm, ms))


def _slower(
    rig: Rig,
    a: int,
    slowest: tuple[PITuning, PlantCase],
    aim: MarginLimits,
    screen: MarginScreen,
    limits: MarginLimits,
) -> PITuning | None:
    """When no design at a case keeps the limits on every case (a lightly damped mode that
    moves): the design at the case whose crossover was the lowest, its crossover bounded at
    :data:`SLOWER_STEP` powers of itself until the screen passes, then refined by bisection
    (:data:`SLOWER_BISECTIONS` steps). None if even ``SLOWER_STEP ** SLOWER_TRIES`` fails."""
    design, case = slowest
    wc0 = design.crossover_rad_s
    hi = 1.0
    for k in range(1, SLOWER_TRIES + 1):
        lo = SLOWER_STEP**k
        try:
            trial = _design_at(rig, a, case, aim, wc0 * lo)
        except SpecError:
            continue
        if _screened(screen, limits, trial, rig.period_s)[0]:
            break
        hi = lo
    else:
        return None
    for _ in range(SLOWER_BISECTIONS):
        mid = math.sqrt(lo * hi)
        try:
            cand = _design_at(rig, a, case, aim, wc0 * mid)
        except SpecError:
            hi = mid
            continue
        if _screened(screen, limits, cand, rig.period_s)[0]:
            lo, trial = mid, cand
        else:
            hi = mid
    return trial


def robust_lock_gain(
    rig: Rig, axis_name: str, cases: Sequence[PlantCase], limits: MarginLimits
) -> float:
    """The rig's lock gain [codes/count], lowered if needed to the largest that keeps the
    tightened limits (:func:`design_limits`) on every case (bisection on the screen).

    Raises
    ------
    InfeasibleError
        Not even a hundredth of the rig's gain keeps them.
    """
    a = rig.axis_names.index(axis_name)
    k0 = rig.axes[a].lock_gain_codes_per_count
    aim = design_limits(limits)
    screen = MarginScreen(rig, a, cases)

    def ok(k: float) -> bool:
        return bool(_meets(aim, *screen(np.array([[k, 0.0, 0.0]])))[0])

    if ok(k0):
        return k0
    lo, hi = k0 * 0.01, k0
    if not ok(lo):
        pm, gm, ms = (float(x[0]) for x in screen(np.array([[lo, 0.0, 0.0]])))
        raise InfeasibleError(
            f"no lock gain for axis {axis_name!r}{modes_note(rig, a)} keeps the margin limits "
            f"on every plant case: {_binding(aim, pm, gm, ms)} (the limit with the design's "
            "tolerance)"
        )
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
        if hi / lo < 1.001:
            break
    return lo
