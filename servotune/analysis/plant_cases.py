"""The plant sets robustness is judged over (:func:`plant_cases`): every axis's gain and time
constant at the corners of the wider of its identified 95 % interval and a spread, with a tick
more latency and the timer's period error, and plant sets drawn inside that box; and one
axis's plant response in a case (:func:`plant_response`), what the loop margins
(:mod:`servotune.analysis.margins`) and the tuners take the loops on."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from servotune.modal import discretize
from servotune.plant import Plant
from servotune.resonance import Mode

if TYPE_CHECKING:
    from servotune.rig import Rig

__all__ = [
    "MODE_FREQ_SPREAD",
    "PlantCase",
    "damping_range",
    "mode_factors",
    "modes_at",
    "plant_cases",
    "plant_response",
    "spread_factors",
]

MODE_FREQ_SPREAD = 0.1
"""Each mode's frequency is judged over the wider of its 95 % interval and this relative spread
(±10 %): a resonance moves with the load, the belt's tension and the temperature."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PlantCase:
    """One plant set the loops are taken on.

    Attributes
    ----------
    label : str
        ``"nominal"``, ``"gain+20%,tau-30%"``, with ``"+1tick"`` (one tick more latency) and
        ``"@+100ppm"`` (the timer's period error) where they apply.
    plants : tuple of Plant
        One per rig axis.
    extra_lag_s : float
        Latency added to every axis's loop [s].
    period_s : float
        Tick period [s].
    """

    label: str
    plants: tuple[Plant, ...]
    extra_lag_s: float = 0.0
    period_s: float


def spread_factors(plant: Plant, fit: Any, key: str, spread: float) -> tuple[float, float]:
    """Low and high factor on ``key``: the wider of the identification's 95 % interval (the
    axis's plant fit record, where the rig has one) and ``± spread``.

    >>> spread_factors(Plant(gain_cps_per_v=100.0, tau_s=0.02), None, "tau_s", 0.3)
    (0.7, 1.3)
    """
    v = float(getattr(plant, key))
    lo, hi = 1.0 - spread, 1.0 + spread
    ci = getattr(fit, "ci95", {}) if fit is not None else {}
    if key in ci and v > 0:
        lo, hi = min(lo, ci[key][0] / v), max(hi, ci[key][1] / v)
    return max(lo, 1e-3), hi


def mode_factors(mode: Mode, spread: float = MODE_FREQ_SPREAD) -> tuple[float, float]:
    """Low and high factor on a mode's frequency: the wider of its 95 % interval and
    ``± spread``.

    >>> mode_factors(Mode(freq_hz=50.0, damping=0.05, gain=0.5, freq_hz_95=(44.0, 52.0)))
    (0.88, 1.1)
    """
    lo, hi = 1.0 - spread, 1.0 + spread
    if mode.freq_hz_95 is not None:
        lo = min(lo, mode.freq_hz_95[0] / mode.freq_hz)
        hi = max(hi, mode.freq_hz_95[1] / mode.freq_hz)
    return max(lo, 1e-3), hi


def modes_at(
    plant: Plant, factors: Sequence[float], dampings: Sequence[float] | None = None
) -> Plant:
    """``plant`` with its mode ``i``'s frequency times ``factors[i]`` (and its damping
    ``dampings[i]`` where given)."""
    modes = tuple(
        replace(
            m,
            freq_hz=m.freq_hz * k,
            damping=m.damping if dampings is None else dampings[i],
        )
        for i, (m, k) in enumerate(zip(plant.modes, factors, strict=True))
    )
    return replace(plant, modes=modes)


def damping_range(mode: Mode) -> tuple[float, float]:
    """The mode's damping interval (its 95 % interval kept inside (0, 1)), or its value."""
    if mode.damping_95 is None:
        return mode.damping, mode.damping
    lo, hi = mode.damping_95
    return min(max(lo, 1e-4), mode.damping), max(min(hi, 0.99), mode.damping)


def _mode_corners(rig: Rig) -> list[tuple[str, tuple[Plant, ...]]]:
    """Every axis's modes at the low and at the high end of their frequency range
    (:func:`mode_factors`), each at the low end of its damping interval where it has one."""
    out = []
    for end, label in ((0, "modes-"), (1, "modes+")):
        plants = []
        for a in rig.axes:
            ks = [mode_factors(m)[end] for m in a.plant.modes]
            zs = [damping_range(m)[0] for m in a.plant.modes]
            plants.append(modes_at(a.plant, ks, zs))
        out.append((label, tuple(plants)))
    return out


def plant_cases(
    rig: Rig,
    *,
    measured: Sequence[tuple[str, tuple[Plant, ...]]] = (),
    gain_spread: float = 0.0,
    tau_spread: float = 0.0,
    extra_ticks: int = 1,
    period_error_ppm: float = 0.0,
    samples: int = 0,
    seed: int = 0,
) -> tuple[PlantCase, ...]:
    """The plant set robustness is judged over: what is not known about the loop.

    Every axis's gain and time constant at the corners of the wider of its identified 95 %
    interval (``[axis.<name>.plant.fit]``) and ``± spread``; each corner and the nominal plants
    as they are and with ``extra_ticks`` ticks more latency; each at the nominal period and at
    ``± period_error_ppm``. Then ``samples`` plant sets drawn inside that box (every axis's
    gain and tau, the latency in [0, ``extra_ticks``] ticks and the period error, uniformly and
    independently; labelled ``sample<i>``): a loop's margins need not be worst at a corner.
    ``measured`` plant sets (e.g. a fleet's machines) are cases as the corners are (each
    also late and at the period's ends). A rig whose plants have modes adds two corners: every
    mode at the low and at the high end of its frequency range (the wider of its 95 % interval
    and ±:data:`MODE_FREQ_SPREAD`), each at the low end of its damping interval; its samples
    also draw each mode's frequency (and damping, inside its interval) from a stream of their
    own, so the draws of a rig without modes are as before. Friction, offset and noise do not
    enter a linear loop's margins.

    Parameters
    ----------
    rig : Rig
    gain_spread, tau_spread : float
        Relative spreads [1] (e.g. a spec's Monte-Carlo spreads).
    extra_ticks : int
        Extra latency [ticks] (0: none).
    period_error_ppm : float
        Timer period error [ppm] (0: the nominal period only).
    samples : int
        Plant sets drawn inside the box (0: corners only).
    seed : int
        Seeds the draw: the same arguments give the same cases.
    measured : sequence of (str, tuple of Plant)
        Labelled plant sets (one plant per rig axis) judged beside the corners.

    Returns
    -------
    tuple of PlantCase
        The nominal case first.
    """
    corners: list[tuple[str, tuple[Plant, ...]]] = [("nominal", tuple(a.plant for a in rig.axes))]
    if gain_spread > 0 or tau_spread > 0 or any(a.plant_fit is not None for a in rig.axes):
        for sg in (-1, 1):
            for st_ in (-1, 1):
                plants = []
                for a in rig.axes:
                    g = spread_factors(a.plant, a.plant_fit, "gain_cps_per_v", gain_spread)
                    tt = spread_factors(a.plant, a.plant_fit, "tau_s", tau_spread)
                    fg, ft = g[sg > 0], tt[st_ > 0]
                    changes: dict[str, Any] = {
                        "gain_cps_per_v": a.plant.gain_cps_per_v * fg,
                        "tau_s": a.plant.tau_s * ft,
                    }
                    if a.plant.gain_neg_cps_per_v is not None:
                        changes["gain_neg_cps_per_v"] = a.plant.gain_neg_cps_per_v * fg
                    plants.append(replace(a.plant, **changes))
                label = f"gain{'-+'[sg > 0]},tau{'-+'[st_ > 0]}"
                corners.append((label, tuple(plants)))
    if any(a.plant.modes for a in rig.axes):
        corners += _mode_corners(rig)
    corners += [(label, tuple(plants)) for label, plants in measured]
    lags = [(0.0, "")] + (
        [(extra_ticks * rig.period_s, f"+{extra_ticks}tick")] if extra_ticks > 0 else []
    )
    periods = [(rig.period_s, "")]
    if period_error_ppm > 0:
        for s in (-1, 1):
            periods.append(
                (rig.period_s * (1 + s * period_error_ppm * 1e-6), f"@{s * period_error_ppm:+g}ppm")
            )
    cases = [
        PlantCase(
            label=(label + lt + pt) if (lt or pt) else label,
            plants=plants,
            extra_lag_s=lag,
            period_s=per,
        )
        for label, plants in corners
        for lag, lt in lags
        for per, pt in periods
    ]
    rng = np.random.default_rng([seed, 0x6D617267])  # a stream of its own ("marg")
    mode_rng = np.random.default_rng([seed, 0x6D6F6465])  # the modes' own ("mode")
    for i in range(samples):
        plants = []
        for a in rig.axes:
            g = rng.uniform(*spread_factors(a.plant, a.plant_fit, "gain_cps_per_v", gain_spread))
            tt = rng.uniform(*spread_factors(a.plant, a.plant_fit, "tau_s", tau_spread))
            changes = {"gain_cps_per_v": a.plant.gain_cps_per_v * g, "tau_s": a.plant.tau_s * tt}
            if a.plant.gain_neg_cps_per_v is not None:
                changes["gain_neg_cps_per_v"] = a.plant.gain_neg_cps_per_v * g
            plants.append(replace(a.plant, **changes))
        if any(a.plant.modes for a in rig.axes):
            plants = [_drawn_modes(p, mode_rng) for p in plants]
        lag = rng.uniform(0.0, extra_ticks * rig.period_s)
        per = rig.period_s * (1.0 + rng.uniform(-1.0, 1.0) * period_error_ppm * 1e-6)
        cases.append(
            PlantCase(label=f"sample{i}", plants=tuple(plants), extra_lag_s=lag, period_s=per)
        )
    return tuple(cases)


def _drawn_modes(plant: Plant, rng: np.random.Generator) -> Plant:
    """``plant`` with each mode's frequency drawn in its range (:func:`mode_factors`) and its
    damping in its 95 % interval (kept where it has none)."""
    ks = [rng.uniform(*mode_factors(m)) for m in plant.modes]
    zs = [rng.uniform(*damping_range(m)) for m in plant.modes]
    return modes_at(plant, ks, zs)


def plant_response(plant: Plant, rig: Rig, case: PlantCase, w: np.ndarray) -> np.ndarray:
    """``lsb·P(e^{jωT})`` of one axis's plant in a case, by python-control, on ``w``: a transfer
    function (the whole grid at once), its coefficients by ``scipy.signal.ss2tf`` (the path
    ``control.ss2tf`` takes without slycot: the same bits, in about a quarter of the time)."""
    import control
    from scipy.signal import ss2tf

    d = discretize(plant, case.period_s, rig.timer.compute_s + plant.delay_s + case.extra_lag_s)
    num, den = ss2tf(d.A, d.B, d.C * rig.dac.lsb_v, d.D * rig.dac.lsb_v)
    return control.frequency_response(control.tf(num[0], den, d.dt), w).complex.ravel()
