"""Lightly damped modes fitted to a measured frequency response (docs/frf.md); the model and
its sampled response are :mod:`servotune.modal`'s.

**Fit** (:func:`fit_modes`). Weighted nonlinear least squares in the frequency domain (R.
Pintelon, J. Schoukens, "System Identification: A Frequency Domain Approach", 2nd ed., Wiley
2012, ch. 9, estimation with a known noise model): each line's residual is ``(G_model −
G_measured) / σ``, ``σ`` the FRF's own standard deviation (floored at :data:`STD_FLOOR` of its
median), on the lines not flagged ``aliased``. Parameters ``ln K``, ``ln τ``, ``d / T`` and per
mode ``ln f``, ``ln ζ``, ``g``, within bounds (:data:`DAMPING_BOUNDS`, :data:`GAIN_BOUNDS`,
``f`` from half the lowest line to Nyquist). Starts: the rigid plant given, or a robust grid
fit; modes are added one at a time, each started at one of the most prominent peaks of the
residual ratio ``|measured / model|``, its damping from the peak's half-power width (and twice
and half that), its gain from the most prominent valley within a factor 3 (``g = (f_peak /
f_valley)² − 1``) or else the peak's height (``g ≈ 2 ζ |ratio|``); the start whose first steps
end lowest is refined.

**Intervals** (95 %): ``cov θ = (JᵀJ)^{-1} · max(1, χ²_ν)`` from the Jacobian at the solution,
``χ²_ν`` the reduced chi-square (a fit worse than the noise widens them), Student's ``t`` for
``2 N − p`` degrees of freedom; a positive parameter's interval is ``exp(ln x ± t σ)``.

**Order** (``n_modes="auto"``): the fit is made on every other line (the even-numbered ones)
and its weighted error ``mean |G_model − G_measured|² / σ²`` evaluated on the others (about 1
for a model that explains all but the noise). Modes are added one at a time, up to
``max_modes``; a mode is kept only when it lowers that held-out error by at least
:data:`HELD_OUT_MARGIN` (20 %), every mode's gain interval excludes 0, *and* every mode is a
resonance the lines measure (:func:`_resonant`): its frequency between the lowest and the highest
line fitted, its damping below the fit's bound, and its own part of the response at its
frequency, ``|g| / (2 ζ)`` of the rest, at least :data:`MIN_PEAK`. The first that fails stops
the search. The chosen order is then refitted on all lines.

Why the last condition: the held-out lines interleave with the fitted ones, so a smooth misfit of
the model *class* is predicted on them as well as on the fitted lines, and any extra flexibility
that lowers it passes the first two tests. A two-mass axis with viscous friction to ground on the
motor is such a case: the modal model ties the anti-resonance's damping to the resonance's
(``ζ_a = ζ / √(1 + g)``), while the friction damps only the resonance (the anti-resonance, the
load swinging on a still motor, keeps the shaft's damping alone), so the one-mode fit leaves tens
of standard deviations at the anti-resonance of a well-averaged response. A second "mode" then
lowers that misfit: a critically damped one below the lowest line reshaping the rigid part, or a
heavily damped one of a few % beside the real one (tests/identify/test_modes_two_mass.py). Such a
term is no resonance: it is refused, and the misfit stays visible in the reduced chi-square.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import optimize, signal, stats

from servotune.analysis.frf import Frf
from servotune.errors import SpecError
from servotune.modal import (
    OUTPUTS,
    Mode,
    check_number,
    modal_response,
    sampled_response,
    with_intervals,
)

__all__ = [
    "DAMPING_BOUNDS",
    "GAIN_BOUNDS",
    "HELD_OUT_MARGIN",
    "MIN_PEAK",
    "STD_FLOOR",
    "ModeFit",
    "fit_modes",
    "lines_needed",
]

HELD_OUT_MARGIN = 0.2
"""A mode is added when it lowers the held-out error by at least this fraction."""

MIN_PEAK = 0.25
"""The least ``|g| / (2 ζ)`` of a mode ``auto`` keeps: its own part of the response at its
frequency relative to the rest (``1 + g s² / (s² + 2 ζ ω s + ω²)`` is ``1 + j g / (2 ζ)`` there).
A quarter is a 14° phase swing; the modes the fit is shown to recover (gain 0.1–1, damping
0.01–0.1) have at least 0.5; the spurious terms of a misfit model class (module docstring)
found within the lines had at most 0.1."""

STD_FLOOR = 1e-3
"""Weights are ``1 / max(std, STD_FLOOR · median std)`` (a noiseless line weighs no more)."""

DAMPING_BOUNDS = (1e-4, 0.99)
"""The fit's range of a mode's damping ratio [-]."""

GAIN_BOUNDS = (-0.99, 100.0)
"""The fit's range of a mode's gain ``g`` [-] (the load-to-motor inertia ratio of two masses)."""

MAX_DELAY_TICKS = 20.0
"""The fit's largest delay beyond the compute time [ticks]."""

_N_RIGID = 3  # ln K, ln tau, d / T
_PEAKS = 2  # residual peaks tried as a new mode's start
_LOG_LINES = 80  # lines the rigid start is fitted on
_SCREEN_NFEV = 12  # evaluations a start gets before the best one is refined


@dataclass(frozen=True, slots=True, kw_only=True)
class ModeFit:
    """What :func:`fit_modes` returns.

    Attributes
    ----------
    modes : tuple of Mode
        The fitted modes with their 95 % intervals, by frequency.
    gain_cps_per_v, tau_s, delay_s : float
        The rigid part: ``K`` [counts/s per V], ``τ`` [s] and the plant's delay [s] (the total
        delay less ``compute_s``).
    gain_cps_per_v_95, tau_s_95, delay_s_95 : (float, float)
        Their 95 % intervals.
    compute_s, period_s : float
        The compute time assumed [s] and the tick period [s].
    output : str
        The FRF's output (``"velocity"`` or ``"position"``).
    order_rule : str
        ``"auto"`` (held-out error) or ``"given"``.
    held_out : dict of int to float
        The held-out error per number of modes tried (``"auto"`` only; 1 is the noise level).
    chi_square : float
        ``Σ |G_model − G_measured|² / (σ² / 2)`` over the lines fitted.
    dof : int
        Its degrees of freedom, ``2 N − p``.
    lines : int
        Lines fitted (those not flagged aliased).
    """

    modes: tuple[Mode, ...]
    gain_cps_per_v: float
    tau_s: float
    delay_s: float
    gain_cps_per_v_95: tuple[float, float]
    tau_s_95: tuple[float, float]
    delay_s_95: tuple[float, float]
    compute_s: float
    period_s: float
    output: str
    order_rule: str
    held_out: dict[int, float] = field(default_factory=dict)
    chi_square: float
    dof: int
    lines: int

    @property
    def reduced_chi_square(self) -> float:
        """``chi_square / dof`` (about 1 when the model explains all but the noise)."""
        return self.chi_square / self.dof if self.dof > 0 else math.inf

    def response(self, freq_hz: np.ndarray, output: str | None = None) -> np.ndarray:
        """The fitted model's response at ``freq_hz`` (default the FRF's output)."""
        return modal_response(
            freq_hz,
            gain_cps_per_v=self.gain_cps_per_v,
            tau_s=self.tau_s,
            delay_s=self.delay_s,
            period_s=self.period_s,
            modes=self.modes,
            output=self.output if output is None else output,
            compute_s=self.compute_s,
        )

    def summary(self) -> str:
        """Lines for a terminal: the rigid part, then each mode with its 95 % intervals."""
        lo, hi = self.gain_cps_per_v_95
        out = [
            f"model: gain {self.gain_cps_per_v:.5g} counts/s/V ({lo:.5g} … {hi:.5g}), tau "
            f"{self.tau_s * 1e3:.4g} ms, delay {self.delay_s * 1e3:.3g} ms; {len(self.modes)} "
            f"mode{'s' if len(self.modes) != 1 else ''} ({self.order_rule}), reduced "
            f"chi-square {self.reduced_chi_square:.2f}"
        ]
        for m in self.modes:
            f95 = m.freq_hz_95 or (math.nan, math.nan)
            z95 = m.damping_95 or (math.nan, math.nan)
            out.append(
                f"  mode {m.freq_hz:.4g} Hz ({f95[0]:.4g} … {f95[1]:.4g}), damping "
                f"{m.damping:.3g} ({z95[0]:.3g} … {z95[1]:.3g}), gain {m.gain:.3g}, "
                f"anti-resonance {m.antiresonance_hz:.4g} Hz"
            )
        return "\n".join(out)

    def to_dict(self) -> dict[str, Any]:
        """Plain data, units in the keys."""
        return {
            "output": self.output,
            "period_s": self.period_s,
            "compute_s": self.compute_s,
            "rigid": with_intervals(self, ("gain_cps_per_v", "tau_s", "delay_s")),
            "modes": [m.to_dict() for m in self.modes],
            "order_rule": self.order_rule,
            "held_out": [{"modes": n, "error": e} for n, e in sorted(self.held_out.items())],
            "chi_square": self.chi_square,
            "dof": self.dof,
            "reduced_chi_square": self.reduced_chi_square,
            "lines": self.lines,
        }


@dataclass(frozen=True, slots=True)
class _Data:
    """The lines to fit: frequencies [Hz], response, weights ``1 / σ``, and the setting."""

    freq: np.ndarray
    resp: np.ndarray
    weight: np.ndarray
    output: str
    period_s: float
    compute_s: float
    lower: np.ndarray  # the parameters' bounds for the largest order
    upper: np.ndarray


@dataclass(frozen=True, slots=True)
class _Solution:
    theta: np.ndarray
    jac: np.ndarray
    cost: float  # Σ r² (the chi-square on the lines fitted)
    n: int  # modes


def _unpack(theta: np.ndarray, n: int, period_s: float) -> tuple[float, float, float, np.ndarray]:
    k, tau, d = math.exp(theta[0]), math.exp(theta[1]), theta[2] * period_s
    rows = theta[_N_RIGID : _N_RIGID + 3 * n].reshape(n, 3).copy()
    rows[:, :2] = np.exp(rows[:, :2])
    return k, tau, d, rows


def _model(data: _Data, theta: np.ndarray, n: int, idx: np.ndarray) -> np.ndarray:
    k, tau, d, rows = _unpack(theta, n, data.period_s)
    return sampled_response(data.freq[idx], k, tau, d, data.period_s, rows, data.output)


def _residual(theta: np.ndarray, data: _Data, n: int, idx: np.ndarray) -> np.ndarray:
    e = (_model(data, theta, n, idx) - data.resp[idx]) * (data.weight[idx] * math.sqrt(2.0))
    return np.concatenate([e.real, e.imag])


def _solve(
    data: _Data,
    idx: np.ndarray,
    theta0: np.ndarray,
    n: int,
    *,
    loss: str = "linear",
    max_nfev: int | None = None,
) -> _Solution:
    """Least squares from ``theta0`` (clipped into the bounds) on the lines ``idx``; the
    solution's cost is the chi-square whatever the loss."""
    p = _N_RIGID + 3 * n
    lo, hi = data.lower[:p], data.upper[:p]
    span = hi - lo
    x0 = np.clip(theta0[:p], lo + 1e-9 * span, hi - 1e-9 * span)
    res = optimize.least_squares(
        _residual,
        x0,
        bounds=(lo, hi),
        args=(data, n, idx),
        method="trf",
        x_scale="jac",
        xtol=1e-10,
        ftol=1e-10,
        loss=loss,
        f_scale=3.0,
        max_nfev=50 * p if max_nfev is None else max_nfev,
    )
    cost = float(np.sum(res.fun**2))
    return _Solution(res.x, res.jac, cost, n)


def _held_out(data: _Data, sol: _Solution, idx: np.ndarray) -> float:
    e = (_model(data, sol.theta, sol.n, idx) - data.resp[idx]) * data.weight[idx]
    return float(np.mean(np.abs(e) ** 2))


def _rigid_start(data: _Data, idx: np.ndarray) -> np.ndarray:
    """``(ln K, ln τ, d / T)`` of the rigid part, fitted robustly.

    On :data:`_LOG_LINES` lines spaced logarithmically (so the low lines, where ``K`` and ``τ``
    show apart, count as much as the many high ones): a grid of ``τ`` and ``d`` on the
    continuous-time approximation (the hold's ``(1 − e^{−jωT}) / (jωT)``, no aliasing), ``K``
    the median magnitude ratio, scored by the median squared weighted residual (a resonance's
    lines are a minority the median ignores); then a few steps of least squares on the exact
    model with a soft-l1 loss (a start, not a fit: the rigid part is refitted with the modes).
    """
    t = data.period_s
    f_all = data.freq[idx]
    near = np.searchsorted(f_all, np.geomspace(f_all[0], f_all[-1], _LOG_LINES))
    idx = idx[np.unique(np.clip(near, 0, f_all.size - 1))]  # as many lines in every octave
    f, g, w = data.freq[idx], data.resp[idx], data.weight[idx]
    s = 2j * math.pi * f
    hold = -np.expm1(-s * t) / (s * t)
    if data.output == "velocity":
        hold = hold * -np.expm1(-s * t) / t
    taus = np.geomspace(0.5 * t, 2000.0 * t, 40)[:, None, None]
    delays = data.compute_s + t * np.arange(0.0, 4.01, 0.5)[None, :, None]
    m = hold * np.exp(-s * delays) / (s * (taus * s + 1.0))  # K = 1
    k = np.median(np.abs(g) / np.abs(m), axis=2)
    score = np.median(np.abs(k[:, :, None] * m - g) ** 2 * w**2, axis=2)
    i, j = np.unravel_index(int(np.argmin(score)), score.shape)
    if not (k[i, j] > 0 and math.isfinite(k[i, j])):
        raise SpecError("the FRF's response is zero on most lines: no plant to fit")
    theta = np.array([math.log(k[i, j]), math.log(taus[i, 0, 0]), delays[0, j, 0] / t])
    return _solve(data, idx, theta, 0, loss="soft_l1", max_nfev=_SCREEN_NFEV).theta


def _valley_gain(f: np.ndarray, lvl: np.ndarray, k: int) -> float | None:
    """``(f_peak / f_valley)² − 1`` for the most prominent valley within a factor 3 of the peak
    ``k`` of the log ratio ``lvl``, or None."""
    valleys, props = signal.find_peaks(-lvl, prominence=0.0)
    near = (f[valleys] > f[k] / 3.0) & (f[valleys] < 3.0 * f[k]) & (valleys != k)
    if not np.any(near):
        return None
    v = valleys[near][np.argmax(props["prominences"][near])]
    return (f[k] / f[v]) ** 2 - 1.0


def _half_power_damping(f: np.ndarray, lvl: np.ndarray, k: int) -> float:
    """``ζ ≈ Δf / (2 f)`` from the half-power width of the peak ``k`` of the log ratio ``lvl``
    (interpolated between lines; one side's twice where the other leaves the band)."""
    drop = lvl[k] - 0.5 * math.log(2.0)
    halves = []
    for step in (-1, 1):
        j = k
        while 0 <= j + step < f.size and lvl[j + step] > drop:
            j += step
        if 0 <= j + step < f.size:
            a, b = lvl[j], lvl[j + step]
            frac = (a - drop) / (a - b) if a != b else 0.5
            halves.append(abs(f[j] + frac * (f[j + step] - f[j]) - f[k]))
    if not halves:
        return 0.05
    width = 2.0 * float(np.mean(halves))
    return float(np.clip(width / (2.0 * f[k]), 0.003, 0.3))


def _mode_starts(data: _Data, idx: np.ndarray, base: np.ndarray, n: int) -> list[np.ndarray]:
    """Starts for ``n + 1`` modes: ``base`` (``n`` modes fitted) plus a mode at each of the
    :data:`_PEAKS` most prominent peaks of ``|measured / model|`` (module docstring)."""
    f = data.freq[idx]
    lvl = np.log(np.abs(data.resp[idx] / _model(data, base, n, idx)))
    padded = np.concatenate([[lvl.min() - 1.0], lvl, [lvl.min() - 1.0]])  # the ends can peak
    peaks, props = signal.find_peaks(padded, prominence=0.0)
    peaks = peaks - 1
    existing = np.exp(base[_N_RIGID : _N_RIGID + 3 * n : 3])
    starts = []
    for k in peaks[np.argsort(-props["prominences"])]:
        if len(starts) >= 3 * _PEAKS:
            break
        if np.any(np.abs(np.log(f[k] / existing)) < 1e-3):
            continue
        zeta = _half_power_damping(f, lvl, k)
        g = _valley_gain(f, lvl, k)
        if g is None:
            g = 2.0 * zeta * math.exp(lvl[k])
        g = float(np.clip(g, GAIN_BOUNDS[0] + 0.04, 0.5 * GAIN_BOUNDS[1]))
        for z in (zeta, 2.0 * zeta, 0.5 * zeta):
            starts.append(np.concatenate([base, [math.log(f[k]), math.log(z), g]]))
    return starts


def _add_mode(data: _Data, idx: np.ndarray, base: np.ndarray, n: int) -> _Solution | None:
    """The fit with ``n + 1`` modes: each start of :func:`_mode_starts` gets
    :data:`_SCREEN_NFEV` evaluations, the one that ends lowest is refined (None: no start)."""
    best = None
    for theta0 in _mode_starts(data, idx, base, n):
        sol = _solve(data, idx, theta0, n + 1, max_nfev=_SCREEN_NFEV)
        if best is None or sol.cost < best.cost:
            best = sol
    return None if best is None else _solve(data, idx, best.theta, n + 1)


def _covariance(sol: _Solution) -> tuple[np.ndarray, float]:
    """``cov θ`` (scaled by the reduced chi-square when above 1) and the t quantile."""
    p = sol.theta.size
    dof = max(sol.jac.shape[0] - p, 1)
    scale = max(1.0, sol.cost / dof)
    cov = np.linalg.pinv(sol.jac.T @ sol.jac) * scale
    return cov, float(stats.t.ppf(0.975, dof))


def _gains_significant(sol: _Solution) -> bool:
    cov, t = _covariance(sol)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    gi = np.arange(_N_RIGID + 2, sol.theta.size, 3)
    return bool(np.all(np.abs(sol.theta[gi]) > t * sd[gi]))


def _resonant(data: _Data, sol: _Solution, idx: np.ndarray) -> bool:
    """Every mode of ``sol`` is a resonance the lines ``idx`` measure (module docstring): its
    frequency within theirs, its damping below the fit's bound, ``|g| / (2 ζ)`` at least
    :data:`MIN_PEAK`."""
    _, _, _, rows = _unpack(sol.theta, sol.n, data.period_s)
    f, zeta, g = rows[:, 0], rows[:, 1], rows[:, 2]
    inside = (f >= data.freq[idx].min()) & (f <= data.freq[idx].max())
    free = zeta < DAMPING_BOUNDS[1] * (1.0 - 1e-6)
    return bool(np.all(inside & free & (np.abs(g) >= MIN_PEAK * 2.0 * zeta)))


def _select_order(
    data: _Data, theta_rigid: np.ndarray, max_modes: int
) -> tuple[_Solution, dict[int, float]]:
    """Fit on the even-numbered lines, score on the odd-numbered ones, add modes while each
    lowers the held-out error by :data:`HELD_OUT_MARGIN` with every gain significant and every
    mode a resonance (:func:`_resonant`)."""
    lines = np.arange(data.freq.size)
    train, test = lines[0::2], lines[1::2]
    most = min(max_modes, (train.size - _N_RIGID) // 3)
    sol = _solve(data, train, theta_rigid, 0)
    held = {0: _held_out(data, sol, test)}
    while sol.n < most:
        base = sol.theta if sol.n > 0 else theta_rigid  # the first mode from the robust start
        bigger = _add_mode(data, train, base, sol.n)
        if bigger is None:
            break
        held[bigger.n] = _held_out(data, bigger, test)
        better = held[bigger.n] <= (1.0 - HELD_OUT_MARGIN) * held[sol.n]
        if not (better and _gains_significant(bigger) and _resonant(data, bigger, train)):
            break
        sol = bigger
    return sol, held


def _result(
    data: _Data, sol: _Solution, *, rule: str, held: dict[int, float], lines: int
) -> ModeFit:
    cov, t = _covariance(sol)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    th, p_s = sol.theta, data.period_s

    def expo(i: int) -> tuple[float, float]:
        return math.exp(th[i] - t * sd[i]), math.exp(th[i] + t * sd[i])

    def lin(i: int, scale: float = 1.0, shift: float = 0.0) -> tuple[float, float]:
        lo, hi = (float(th[i] + sign * t * sd[i]) * scale - shift for sign in (-1.0, 1.0))
        return lo, hi

    modes = [
        Mode(
            freq_hz=math.exp(th[j]),
            damping=math.exp(th[j + 1]),
            gain=float(th[j + 2]),
            freq_hz_95=expo(j),
            damping_95=expo(j + 1),
            gain_95=lin(j + 2),
        )
        for j in range(_N_RIGID, th.size, 3)
    ]
    return ModeFit(
        modes=tuple(sorted(modes, key=lambda m: m.freq_hz)),
        gain_cps_per_v=math.exp(th[0]),
        tau_s=math.exp(th[1]),
        delay_s=max(th[2] * p_s - data.compute_s, 0.0),
        gain_cps_per_v_95=expo(0),
        tau_s_95=expo(1),
        delay_s_95=lin(2, p_s, data.compute_s),
        compute_s=data.compute_s,
        period_s=p_s,
        output=data.output,
        order_rule=rule,
        held_out=held,
        chi_square=sol.cost,
        dof=2 * lines - th.size,
        lines=lines,
    )


def _prepare(frf: Frf, compute_s: float, max_modes: int) -> _Data:
    """Checks the FRF and gathers the lines not flagged aliased, with their weights."""
    check_number("compute_s", compute_s, 0.0)
    if frf.output not in OUTPUTS:
        raise SpecError(f"the FRF's output must be one of {', '.join(OUTPUTS)}, got {frf.output!r}")
    check_number("the FRF's period_s", frf.period_s, 0.0, strict=True)
    t = float(frf.period_s)
    nyq = 0.5 / t
    f = np.asarray(frf.freq_hz, dtype=float)
    if f.size and not np.all(np.isfinite(f) & (f > 0) & (f < nyq)):
        raise SpecError(f"the FRF's lines must lie within (0, {nyq:g}) Hz, the Nyquist frequency")
    keep = np.flatnonzero(~np.asarray(frf.aliased, dtype=bool))
    keep = keep[np.argsort(f[keep], kind="stable")]  # ascending, as the starts need
    resp = np.asarray(frf.response, dtype=complex)[keep]
    std = np.asarray(frf.std, dtype=float)[keep]
    if not (np.all(np.isfinite(resp)) and np.all(np.isfinite(std)) and np.all(std >= 0)):
        raise SpecError("the FRF's response and std must be finite (std >= 0) on its lines")
    floor = STD_FLOOR * float(np.median(std)) if std.size else 0.0
    if floor <= 0:  # a noiseless response: relative weights
        floor = STD_FLOOR * float(np.median(np.abs(resp))) if resp.size else 1.0
    f = f[keep]
    f_lo = 0.5 * float(f.min()) if f.size else 1.0
    f_hi = 0.999 * nyq
    d_lo = compute_s / t
    lower = [-60.0, math.log(1e-3 * t), d_lo]
    upper = [60.0, math.log(1e6 * t), d_lo + MAX_DELAY_TICKS]
    for _ in range(max_modes):
        lower += [math.log(f_lo), math.log(DAMPING_BOUNDS[0]), GAIN_BOUNDS[0]]
        upper += [math.log(f_hi), math.log(DAMPING_BOUNDS[1]), GAIN_BOUNDS[1]]
    weight = 1.0 / np.maximum(std, floor)
    return _Data(f, resp, weight, frf.output, t, float(compute_s), np.array(lower), np.array(upper))


def fit_modes(
    frf: Frf,
    *,
    n_modes: int | str = "auto",
    rigid: Any | None = None,
    compute_s: float = 0.0,
    max_modes: int = 3,
) -> ModeFit:
    """Fit the rigid plant and its lightly damped modes to a measured response (module
    docstring).

    Parameters
    ----------
    frf : Frf
        The measured response (:func:`servotune.analysis.frf.frf`); lines flagged ``aliased``
        are left out.
    n_modes : int or "auto"
        How many modes; ``"auto"`` chooses 0 … ``max_modes`` by the held-out error.
    rigid : Plant-like, optional
        Start for the rigid part (``gain_cps_per_v`` [counts/s per V], ``tau_s`` [s],
        ``delay_s`` [s]: a :class:`servotune.plant.Plant`); default a robust grid fit.
    compute_s : float
        The rig's compute time [s]: the D/A is written this long after the sample; the total
        delay is the plant's delay plus it (the fit keeps the plant's delay >= 0).
    max_modes : int
        The most modes ``"auto"`` tries, >= 0.

    Returns
    -------
    ModeFit

    Raises
    ------
    SpecError
        A bad option; a line at or above the Nyquist frequency; fewer lines than parameters
        (for ``"auto"``: fewer than twice the rigid part's, the fit using half of them).
    """
    auto = n_modes == "auto"
    if not auto and not (isinstance(n_modes, int) and not isinstance(n_modes, bool)):
        raise SpecError(f"n_modes must be a whole number >= 0 or 'auto', got {n_modes!r}")
    if not (isinstance(max_modes, int) and not isinstance(max_modes, bool) and max_modes >= 0):
        raise SpecError(f"max_modes must be a whole number >= 0, got {max_modes!r}")
    n_fit = max_modes if auto else int(n_modes)
    if n_fit < 0:
        raise SpecError(f"n_modes must be a whole number >= 0 or 'auto', got {n_modes!r}")
    data = _prepare(frf, compute_s, n_fit)
    lines = data.freq.size
    need = lines_needed(n_modes)
    if lines < need:
        what = "the rigid part, fitted on half of them" if auto else f"{n_fit} modes"
        raise SpecError(
            f"the FRF has {lines} lines not flagged aliased: too few for {what} (at least "
            f"{need} needed); measure more lines (a longer excitation period)"
        )
    all_lines = np.arange(lines)
    theta_rigid = _start(data, all_lines, rigid)
    if auto:
        sol, held = _select_order(data, theta_rigid, n_fit)
        sol = _solve(data, all_lines, sol.theta, sol.n)
        return _result(data, sol, rule="auto", held=held, lines=lines)
    sol = _Solution(theta_rigid, np.zeros((0, _N_RIGID)), math.inf, 0)  # the start
    while sol.n < n_fit:
        bigger = _add_mode(data, all_lines, sol.theta, sol.n)
        if bigger is None:
            raise SpecError(f"no residual peak to start mode {sol.n + 1} of {n_fit} from")
        sol = bigger
    if n_fit == 0:
        sol = _solve(data, all_lines, theta_rigid, 0)
    return _result(data, sol, rule="given", held={}, lines=lines)


def lines_needed(n_modes: int | str) -> int:
    """Lines not flagged aliased :func:`fit_modes` needs for ``n_modes`` (a number, or
    ``"auto"``: twice the rigid part's parameters, the order being chosen on half of them)."""
    return 2 * _N_RIGID if n_modes == "auto" else _N_RIGID + 3 * int(n_modes)


def _start(data: _Data, idx: np.ndarray, rigid: Any | None) -> np.ndarray:
    """``(ln K, ln τ, d / T)`` from ``rigid``, or by :func:`_rigid_start`."""
    if rigid is None:
        return _rigid_start(data, idx)
    try:
        k, tau, delay = (float(getattr(rigid, a)) for a in ("gain_cps_per_v", "tau_s", "delay_s"))
    except (AttributeError, TypeError, ValueError) as e:
        raise SpecError(
            f"rigid must have gain_cps_per_v, tau_s and delay_s (a Plant), got {rigid!r}"
        ) from e
    if not (k > 0 and tau > 0 and delay >= 0 and math.isfinite(k + tau + delay)):
        raise SpecError(f"rigid needs gain_cps_per_v > 0, tau_s > 0, delay_s >= 0, got {rigid!r}")
    return np.array([math.log(k), math.log(tau), (delay + data.compute_s) / data.period_s])
