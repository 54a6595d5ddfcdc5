"""Stability margins of every loop the runtime can run, on the discrete loop as the engine runs it.

Each axis runs one of a few linear loops around its plant, switched by mode and, for the
composite law, by the fuzzy levels of the error and its change:

- the **lock** loop: ``u = KL·e`` (the position-lock module);
- the **task** loop of a PI axis: ``C(z) = Kp + Ki·T·z/(z − 1)`` (the runtime's integrator adds
  ``Ki·T·e(k)`` before the output is formed);
- the **task** loop of a fuzzy-PID axis at **every query-table cell** ``(E, EC)``:
  ``C(z) = Kp(E,EC) + Ki·T(E,EC)·z/(z − 1) + Kd/T(E,EC)·(1 − z⁻¹)``, the scheduled gains frozen
  (a frozen-gain linearisation: each cell is one loop the runtime can sit in). The feedforward
  differential ``K1·Δr/T`` acts on the reference only: it is outside the loop and changes no
  margin.

The gains are the quantised constants of the tuning (``q·2⁻ᶠ``), i.e. what runs. The plant is
the axis model discretised exactly with a zero-order hold at the achieved period, with the
compute time and the drive's delay as an input lag (:func:`servotune.modal.discretize`; an
asymmetric plant enters with the mean of its two directions' gains), behind the D/A's gain
(one code is ``lsb_v`` volts). Friction, offset, the speed limit and the quantisation are left
out: the margins are those of the linear loop between them. Loop ``L(z) = C(z)·lsb·P(z)``
[counts per count].

Every figure is computed with python-control: the loop's frequency response
(``control.frequency_response``) on a grid up to the Nyquist frequency, its gain and phase
margins and their crossovers from ``control.stability_margins`` on that response (an FRD,
python-control's interpolating method), stability from the poles of ``control.feedback(L, 1)``,
all on python-control's scipy paths (:func:`servotune._control.scipy_paths`: the same bits with
slycot installed). The delay margin is the smallest ``PM_i/ω_i`` over the gain crossovers [s]
(the extra loop delay that brings the phase margin to zero); ``Ms = max|1/(1 + L)|``,
``Mt = max|L/(1 + L)|``; the bandwidth is the lowest frequency where ``|T|`` falls below −3 dB.

The default limits (PM ≥ 45°, GM ≥ 6 dB, Ms ≤ 2.0) follow Åström & Hägglund, *Advanced PID
Control* (ISA, 2006), §4.2: Ms between 1.2 and 2.0 is the usual robust range, and Ms ≤ 2.0
alone guarantees GM ≥ 6 dB and PM ≥ 29°.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from servotune._control import scipy_paths
from servotune._numba_cache import jit
from servotune.analysis.plant_cases import PlantCase, plant_response
from servotune.errors import SpecError
from servotune.laws.filters import SectionQ, chain_response
from servotune.laws.fuzzy_pid import FuzzyPIDConstants
from servotune.laws.pi import PIConstants
from servotune.modal import discretize
from servotune.plant import Plant
from servotune.validate import check_number

if TYPE_CHECKING:  # python-control is imported where used (slow to import)
    import control

    from servotune.rig import Rig
    from servotune.tuning import Tuning

__all__ = [
    "DEFAULT_LIMITS",
    "GainSet",
    "LoopFigures",
    "LoopMargins",
    "MarginLimits",
    "Margins",
    "controller_basis",
    "controller_response",
    "controller_tf",
    "filters_tf",
    "gain_sets",
    "grid_margins",
    "loop_margins",
    "loop_model",
    "margin_grid",
    "mode_points",
    "tuning_margins",
    "unwrapped_phase",
]

GRID_POINTS = 800
"""Frequencies of the response grid (log-spaced up to the Nyquist frequency)."""
GRID_DECADES_BELOW = 3.0
"""The grid starts this many decades below the plant's corner ``1/tau_s``."""


@dataclass(frozen=True, slots=True, kw_only=True)
class MarginLimits:
    """Robustness limits every loop must meet.

    Parameters
    ----------
    min_phase_margin_deg : float
        Smallest phase margin [deg], in [0, 90).
    min_gain_margin_db : float
        Smallest gain margin [dB], >= 0.
    max_sensitivity : float
        Largest peak sensitivity Ms [1], > 1.
    """

    min_phase_margin_deg: float = 45.0
    min_gain_margin_db: float = 6.0
    max_sensitivity: float = 2.0

    def __post_init__(self) -> None:
        e = SpecError
        check_number(
            "min_phase_margin_deg",
            self.min_phase_margin_deg,
            "deg",
            hi=90.0,
            hi_strict=True,
            error=e,
        )
        check_number("min_gain_margin_db", self.min_gain_margin_db, "dB", hi=60.0, error=e)
        check_number(
            "max_sensitivity", self.max_sensitivity, "1", lo=1.0, strict=True, hi=100.0, error=e
        )

    @classmethod
    def of(cls, owner: Any) -> MarginLimits:
        """The limits held by ``owner`` (a tuning spec, a gantry's ``[margins]``) in attributes
        named as this class's fields."""
        return cls(**{f.name: getattr(owner, f.name) for f in fields(cls)})

    def broken(self, m: LoopMargins) -> tuple[str, ...]:
        """The limits ``m`` breaks, each as a phrase (empty: it meets them all)."""
        return self.broken_figures(m)

    def broken_figures(self, figures: LoopFigures) -> tuple[str, ...]:
        """:meth:`broken` for the figures of :func:`loop_margins`."""
        if not figures.stable:
            return (f"unstable (closed-loop pole radius {figures.spectral_radius:.4f})",)
        return self.broken_values(
            figures.phase_margin_deg, figures.gain_margin_db, figures.max_sensitivity
        )

    def broken_values(self, pm_deg: float, gm_db: float, ms: float) -> tuple[str, ...]:
        """The limits a phase margin [deg], gain margin [dB] and Ms break, each as a phrase."""
        out = []
        if pm_deg < self.min_phase_margin_deg:
            out.append(f"PM {pm_deg:.1f}° < {self.min_phase_margin_deg:g}°")
        if gm_db < self.min_gain_margin_db:
            out.append(f"GM {gm_db:.1f} dB < {self.min_gain_margin_db:g} dB")
        if ms > self.max_sensitivity:
            out.append(f"Ms {ms:.2f} > {self.max_sensitivity:g}")
        return tuple(out)

    def to_dict(self) -> dict[str, float]:
        """Plain dict."""
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


DEFAULT_LIMITS = MarginLimits()
"""PM ≥ 45°, GM ≥ 6 dB, Ms ≤ 2.0 (module docstring)."""


@dataclass(frozen=True, slots=True)
class GainSet:
    """The frozen gains of one loop [codes/count]: ``Kp``, ``Ki·T`` (per tick), ``Kd/T``."""

    kp: float
    ki_t: float = 0.0
    kd_t: float = 0.0


def controller_tf(g: GainSet, period_s: float) -> control.TransferFunction:
    """``C(z) = Kp + Ki·T·z/(z − 1) + Kd/T·(1 − z⁻¹)`` [codes/count], ``dt = period_s``.

    Examples
    --------
    >>> c = controller_tf(GainSet(2.0, 0.5), 0.004)
    >>> complex(c(10.0)).real  # 2 + 0.5·10/9
    2.5555555555555554
    """
    import control

    c = control.tf([g.kp], [1.0], period_s)
    if g.ki_t:
        c = c + control.tf([g.ki_t, 0.0], [1.0, -1.0], period_s)
    if g.kd_t:
        c = c + control.tf([g.kd_t, -g.kd_t], [1.0, 0.0], period_s)
    return c


def filters_tf(sections: Sequence[SectionQ], period_s: float) -> control.TransferFunction | None:
    """``F(z)``: the product of the quantised sections as they run (their realised
    coefficients, whatever the period), ``dt = period_s``; None without sections."""
    import control

    out = None
    for sec in sections:
        b, a = sec.ba()
        f = control.tf(b, a, period_s)
        out = f if out is None else out * f
    return out


@scipy_paths
def loop_model(
    plant: Plant,
    g: GainSet,
    *,
    period_s: float,
    lag_s: float,
    lsb_volts: float,
    filters: Sequence[SectionQ] = (),
) -> control.StateSpace:
    """The loop ``L(z) = C(z)·F(z)·lsb·P(z)`` [counts per count] (module docstring).

    Parameters
    ----------
    plant : Plant
    g : GainSet
    period_s, lag_s : float
        Achieved tick period [s]; total lag from the tick start to the motor input [s].
    lsb_volts : float
        D/A gain [V/code].
    filters : sequence of SectionQ
        The axis's output filters (``AxisController.filters``), in every loop of the axis.
    """
    import control

    p = discretize(plant, period_s, lag_s) * lsb_volts
    f = filters_tf(filters, period_s)
    if f is not None:
        p = control.series(control.ss(f), p)
    return control.ss(control.series(controller_tf(g, period_s), p))


def unwrapped_phase(g: np.ndarray) -> np.ndarray:
    """Phase of a response along its last axis, from the lowest frequency on, its first value
    taken in (−3π/2, π/2] [rad]."""
    ph = np.angle(g)
    first = ph[..., 0]
    ph[..., 0] = np.where(first > 0.5 * math.pi, first - 2 * math.pi, first)
    return np.unwrap(ph, axis=-1)


@jit
def _grid_kernel(
    lw: np.ndarray,
    gains: np.ndarray,
    integ: np.ndarray,
    diff: np.ndarray,
    g: np.ndarray,
    g_phase: np.ndarray,
    out: np.ndarray,
) -> None:
    """:func:`grid_margins` for every (gain row, plant) pair into ``out[u, p, 0:4]``."""
    two_pi = 2.0 * math.pi
    m = lw.size
    c = np.empty(m, dtype=np.complex128)
    c_phase = np.empty(m)
    for u in range(gains.shape[0]):
        for i in range(m):
            c[i] = gains[u, 0] + gains[u, 1] * integ[i] + gains[u, 2] * diff[i]
            c_phase[i] = math.atan2(c[i].imag, c[i].real)
        for p in range(g.shape[0]):
            pm, gm, s2_min, wc_top = math.inf, math.inf, math.inf, 0.0
            a0 = ph0 = k0 = 0.0
            for i in range(m):
                loop = c[i] * g[p, i]
                a1 = loop.real * loop.real + loop.imag * loop.imag  # |L|²
                ph1 = g_phase[p, i] + c_phase[i]
                k1 = math.floor((ph1 + math.pi) / two_pi)
                s2 = (1.0 + loop.real) ** 2 + loop.imag * loop.imag  # |1 + L|²
                if s2 < s2_min:
                    s2_min = s2
                if i > 0:
                    if (a0 >= 1.0) != (a1 >= 1.0):  # a gain crossover
                        ln0, ln1 = 0.5 * math.log(a0), 0.5 * math.log(a1)
                        f = ln0 / (ln0 - ln1)
                        v = (ph0 + f * (ph1 - ph0)) % two_pi - math.pi
                        pm = min(pm, v)
                        wc_top = max(wc_top, math.exp(lw[i - 1] + f * (lw[i] - lw[i - 1])))
                    if k0 != k1:  # a phase crossover (an odd multiple of π)
                        lvl = max(k0, k1) * two_pi - math.pi
                        fp = (lvl - ph0) / (ph1 - ph0)
                        ln0 = 0.5 * math.log(a0 + 1e-300)
                        ln1 = 0.5 * math.log(a1 + 1e-300)
                        gm = min(gm, -(ln0 + fp * (ln1 - ln0)))
                a0, ph0, k0 = a1, ph1, k1
            out[u, p, 0] = pm
            out[u, p, 1] = gm
            out[u, p, 2] = 1.0 / math.sqrt(s2_min)
            out[u, p, 3] = wc_top


def controller_basis(w: np.ndarray, period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``z/(z − 1)`` and ``1 − 1/z`` at ``z = e^{jωT}`` on ``w``: ``C = Kp + Ki·T·(first) +
    Kd/T·(second)`` (:func:`controller_response`)."""
    z = np.exp(1j * np.asarray(w, dtype=float) * period_s)
    return z / (z - 1.0), 1.0 - 1.0 / z


def grid_margins(
    w: np.ndarray,
    gains: np.ndarray,
    basis: tuple[np.ndarray, np.ndarray],
    g: np.ndarray,
    g_phase: np.ndarray,
) -> dict[str, np.ndarray]:
    """Margins of every loop ``L = C·G`` of a batch of controllers and plants from their
    responses on a grid (compiled; the screen behind the tuners).

    Every gain and phase crossover is located by linear interpolation (``ln|L|`` against
    ``ln ω``, and the phase) between grid points; the verdict is :func:`loop_margins`
    (python-control), which the tests hold this against.

    Parameters
    ----------
    w : ndarray, shape (m,)
        Frequency grid [rad/s], increasing.
    gains : ndarray, shape (u, 3)
        Rows ``(Kp, Ki·T, Kd/T)`` [codes/count], each >= 0 (so ``Re C > 0``: the controller's
        phase is continuous without unwrapping).
    basis : tuple of ndarray
        :func:`controller_basis` of ``w`` at the loop's period.
    g : ndarray of complex, shape (p, m)
        Plant responses (D/A gain included).
    g_phase : ndarray, shape (p, m)
        Their unwrapped phases [rad] (:func:`unwrapped_phase`).

    Returns
    -------
    dict of str to ndarray, shape (u, p)
        ``pm`` worst phase margin [rad] (inf without a gain crossover), ``gm`` worst gain margin
        [ln, i.e. nepers] (inf without a phase crossover), ``ms`` peak sensitivity [1] on the
        grid, ``wc_top`` highest gain crossover [rad/s] (0 without one).
    """
    gr = np.ascontiguousarray(np.atleast_2d(gains), dtype=float)
    g2 = np.ascontiguousarray(np.atleast_2d(g), dtype=complex)
    out = np.empty((gr.shape[0], g2.shape[0], 4))
    _grid_kernel(
        np.log(np.asarray(w, dtype=float)),
        gr,
        np.ascontiguousarray(basis[0], dtype=complex),
        np.ascontiguousarray(basis[1], dtype=complex),
        g2,
        np.ascontiguousarray(np.atleast_2d(g_phase), dtype=float),
        out,
    )
    return {"pm": out[..., 0], "gm": out[..., 1], "ms": out[..., 2], "wc_top": out[..., 3]}


def mode_points(plant: Plant, top: float) -> np.ndarray:
    """Frequencies around each of the plant's modes [rad/s], below ``top``: ±8 half-power
    bandwidths of its resonance and of its anti-resonance in steps of 1/8 of one, so that a
    lightly damped peak or dip is not missed between the points of a log grid."""
    parts = [np.empty(0)]
    for m in plant.modes:
        for f in (m.freq_hz, m.antiresonance_hz):
            w = 2.0 * math.pi * f
            parts.append(w * (1.0 + m.damping * np.linspace(-8.0, 8.0, 129)))
    w = np.concatenate(parts)
    return w[(w > 0) & (w < top)]


def margin_grid(plant: Plant, period_s: float) -> np.ndarray:
    """The frequency grid a loop's margins are measured on: :data:`GRID_POINTS` log-spaced,
    from :data:`GRID_DECADES_BELOW` decades below the plant's corner (or Nyquist) to Nyquist,
    and the points around the plant's modes (:func:`mode_points`)."""
    nyq = math.pi / period_s
    top = nyq * (1.0 - 1e-9)  # below Nyquist however it is rounded: python-control takes it
    lo = min(1.0 / plant.tau_s, nyq) * 10.0**-GRID_DECADES_BELOW
    w = np.logspace(math.log10(lo), math.log10(top), GRID_POINTS)
    if plant.modes:
        w = np.unique(np.concatenate([w, mode_points(plant, top)]))
    return w


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopFigures:
    """What :func:`loop_margins` measures on one discrete loop (a :class:`LoopMargins` adds
    where the loop sits).

    Attributes
    ----------
    stable : bool
        All closed-loop poles inside the unit circle.
    spectral_radius : float
        Largest closed-loop pole magnitude [1].
    gain_margin_db, phase_margin_deg : float
        [dB], [deg]; inf where the loop has no phase (gain) crossover.
    delay_margin_s : float
        Extra loop delay the loop tolerates [s].
    crossover_rad_s, phase_crossover_rad_s : float
        Gain and phase crossover [rad/s] (NaN where none).
    max_sensitivity, max_complementary_sensitivity : float
        Ms and Mt [1].
    bandwidth_rad_s : float
        Closed-loop −3 dB bandwidth [rad/s] (NaN where ``|T|`` stays above −3 dB).
    """

    stable: bool
    spectral_radius: float
    gain_margin_db: float
    phase_margin_deg: float
    delay_margin_s: float
    crossover_rad_s: float
    phase_crossover_rad_s: float
    max_sensitivity: float
    max_complementary_sensitivity: float
    bandwidth_rad_s: float

    def as_fields(self) -> dict[str, float | bool]:
        """The figures by name, to build a :class:`LoopMargins` from
        (``LoopMargins(axis=…, **figures.as_fields())``)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@scipy_paths
def loop_margins(loop: control.StateSpace, w: np.ndarray) -> LoopFigures:
    """Margins, peaks, bandwidth and stability of a discrete loop, by python-control.

    Parameters
    ----------
    loop : control.StateSpace
        Discrete open loop ``L`` (negative unity feedback).
    w : ndarray
        Frequency grid [rad/s], increasing, below the Nyquist frequency.

    Returns
    -------
    LoopFigures
    """
    import control

    dt = loop.dt
    lw = control.frequency_response(loop, w).complex.ravel()
    frd = control.FRD(lw, w, smooth=True, dt=dt)
    gms, pms, _sms, wpcs, wgcs, _wms = (
        np.atleast_1d(np.asarray(v, dtype=float))
        for v in control.stability_margins(frd, returnall=True)
    )
    ok_p = np.isfinite(pms) & np.isfinite(wgcs) & (wgcs > 0)
    pms, wgcs = pms[ok_p], wgcs[ok_p]
    ok_g = np.isfinite(gms) & (gms > 0)
    gms, wpcs = gms[ok_g], wpcs[ok_g]
    if pms.size:
        i = int(np.argmin(pms))
        pm, wc = float(pms[i]), float(wgcs[i])
        dm = float(np.min(np.where(pms > 0, np.radians(pms) / wgcs, 0.0)))
    else:
        pm, wc, dm = math.inf, math.nan, math.inf
    if gms.size:
        j = int(np.argmin(np.abs(np.log(gms))))  # the crossing closest to 0 dB
        gm_db, wpc = float(20.0 * np.log10(gms[j])), float(wpcs[j])
    else:
        gm_db, wpc = math.inf, math.nan
    s = 1.0 / (1.0 + lw)
    t = lw * s
    below = np.nonzero(np.abs(t) < 1.0 / math.sqrt(2.0))[0]
    bw = float(w[below[0]]) if below.size else math.nan
    rho = float(np.max(np.abs(control.feedback(loop, 1).poles())))
    return LoopFigures(
        stable=rho < 1.0,
        spectral_radius=rho,
        gain_margin_db=gm_db,
        phase_margin_deg=pm,
        delay_margin_s=dm,
        crossover_rad_s=wc,
        phase_crossover_rad_s=wpc,
        max_sensitivity=float(np.max(np.abs(s))),
        max_complementary_sensitivity=float(np.max(np.abs(t))),
        bandwidth_rad_s=bw,
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopMargins(LoopFigures):
    """The margins of one loop the runtime can run, on one plant: what :func:`loop_margins`
    measured (the :class:`LoopFigures`) and where the loop sits.

    Attributes
    ----------
    axis : str
    loop : str
        ``"lock"`` or ``"task"``.
    cell : tuple of int or None
        ``(E, EC)`` fuzzy levels of a scheduled law's cell; None for a fixed-gain loop.
    plant : str
        ``"nominal"`` or the plant variant's label.
    gains : GainSet
        The frozen gains [codes/count].
    period_s : float
        The tick period of the loop [s].
    """

    axis: str
    loop: str
    cell: tuple[int, int] | None
    plant: str
    gains: GainSet
    period_s: float

    @property
    def name(self) -> str:
        """``"slave task cell E=+3 EC=-1"``, ``"master lock"``."""
        where = "" if self.cell is None else f" cell E={self.cell[0]:+d} EC={self.cell[1]:+d}"
        return f"{self.axis} {self.loop}{where}"

    @property
    def delay_margin_ticks(self) -> float:
        """:attr:`delay_margin_s` in ticks."""
        return self.delay_margin_s / self.period_s

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (non-finite numbers as None)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, GainSet):
                v = {"kp": v.kp, "ki_t": v.ki_t, "kd_t": v.kd_t}
            elif isinstance(v, tuple):
                v = list(v)
            elif isinstance(v, float) and not math.isfinite(v):
                v = None
            out[f.name] = v
        out["delay_margin_ticks"] = (
            self.delay_margin_ticks if math.isfinite(self.delay_margin_ticks) else None
        )
        return out


def _severity(m: LoopMargins) -> tuple[int, float]:
    """Sort key: unstable loops first (largest pole radius), then by Ms."""
    return (0, -m.spectral_radius) if not m.stable else (1, -m.max_sensitivity)


@dataclass(frozen=True, slots=True, kw_only=True)
class Margins:
    """The margins of every loop of a tuning (:func:`tuning_margins`).

    Attributes
    ----------
    loops : tuple of LoopMargins
        Rig axis order; per axis the lock loop, then the task loop (each cell, row ``E`` then
        column ``EC``); per loop every plant.
    limits : MarginLimits
    filters : tuple of FilterEffect
        What each filtered axis's filters do (:func:`servotune.analysis.filter_effect.
        filter_effects`), where the caller added it (``servotune margins``).
    measured : tuple of FrfLoop
        The loops on measured responses (:func:`servotune.analysis.frf_margins.frf_loops`),
        where the caller added them (``servotune margins --frf``); judged by the limits too.
    """

    loops: tuple[LoopMargins, ...]
    limits: MarginLimits = field(default=DEFAULT_LIMITS)
    filters: tuple[Any, ...] = ()
    measured: tuple[Any, ...] = ()

    def select(self, axis: str | None = None, loop: str | None = None) -> Iterator[LoopMargins]:
        """The loops of ``axis`` (and kind ``loop``), all if None."""
        return (
            m
            for m in self.loops
            if (axis is None or m.axis == axis) and (loop is None or m.loop == loop)
        )

    def worst(self, axis: str | None = None, loop: str | None = None) -> LoopMargins:
        """The least robust loop: an unstable one (largest pole radius) or the largest Ms."""
        return min(self.select(axis, loop), key=_severity)

    def failures(self) -> tuple[tuple[LoopMargins, tuple[str, ...]], ...]:
        """Every loop that breaks a limit, with the limits it breaks, the worst first."""
        bad = [(m, b) for m in self.loops if (b := self.limits.broken(m))]
        return tuple(sorted(bad, key=lambda mb: _severity(mb[0])))

    @property
    def passed(self) -> bool:
        """Every loop meets every limit (the measured ones with the filters in too)."""
        return not self.failures() and not any(
            m.broken(self.limits) for m in self.measured if m.filtered
        )

    def cell_grid(self, axis: str, attr: str, plant: str = "nominal") -> np.ndarray:
        """``attr`` of a scheduled axis's task loop on ``plant`` over the table, shape
        ``(2n+1, 2n+1)``, row ``E``, column ``EC`` (for heat maps)."""
        cells = [m for m in self.select(axis, "task") if m.cell is not None and m.plant == plant]
        if not cells:
            raise ValueError(f"axis {axis!r} has no scheduled task loop")
        n = max(abs(m.cell[0]) for m in cells)  # type: ignore[index]
        out = np.full((2 * n + 1, 2 * n + 1), np.nan)
        for m in cells:
            out[m.cell[0] + n, m.cell[1] + n] = getattr(m, attr)  # type: ignore[index]
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain dict: the limits, the verdict, the worst loop per axis and every loop."""
        axes = list(dict.fromkeys(m.axis for m in self.loops))
        return {
            "limits": self.limits.to_dict(),
            "passed": self.passed,
            "feedforward_note": "the feedforward acts on the reference only and changes no margin",
            "worst": {a: self.worst(a).name for a in axes},
            "failures": [
                {"loop": m.name, "plant": m.plant, "broken": list(b)} for m, b in self.failures()
            ],
            "loops": [m.to_dict() for m in self.loops],
        } | (
            ({"filters": [f.to_dict() for f in self.filters]} if self.filters else {})
            | ({"measured": [m.to_dict() for m in self.measured]} if self.measured else {})
        )


def gain_sets(
    controller: Any,
) -> list[tuple[str, tuple[int, int] | None, GainSet]]:
    """Every loop an axis controller can run: ``(loop, cell, gains)`` (module docstring).

    Parameters
    ----------
    controller : AxisController
        The quantised constants (what runs).
    """
    out: list[tuple[str, tuple[int, int] | None, GainSet]] = [
        ("lock", None, GainSet(controller.lock_gain.value))
    ]
    t = controller.task
    if isinstance(t, PIConstants):
        out.append(("task", None, GainSet(t.kp.value, t.ki_t.value)))
    elif isinstance(t, FuzzyPIDConstants):
        kp, ki, kd = (t.scheduled(name) for name in ("kp", "ki", "kd"))
        n = t.n
        for i in range(2 * n + 1):
            for j in range(2 * n + 1):
                g = GainSet(float(kp[i, j]), float(ki[i, j]), float(kd[i, j]))
                out.append(("task", (i - n, j - n), g))
    return out


def controller_response(gains: np.ndarray, w: np.ndarray, period_s: float) -> np.ndarray:
    """``C(e^{jωT})`` of each row ``(Kp, Ki·T, Kd/T)`` of ``gains`` on ``w``, shape (rows, m)."""
    integ, diff = controller_basis(w, period_s)
    g = np.atleast_2d(gains)
    return g[:, :1] + g[:, 1:2] * integ[None, :] + g[:, 2:3] * diff[None, :]


def _margins_of(
    axis: str,
    loop: str,
    cell: tuple[int, int] | None,
    g: GainSet,
    plant: Plant,
    rig: Rig,
    case: PlantCase,
    filters: Sequence[SectionQ] = (),
) -> LoopMargins:
    lag = rig.timer.compute_s + plant.delay_s + case.extra_lag_s
    model = loop_model(
        plant, g, period_s=case.period_s, lag_s=lag, lsb_volts=rig.dac.lsb_v, filters=filters
    )
    figures = loop_margins(model, margin_grid(plant, case.period_s))
    return LoopMargins(
        axis=axis,
        loop=loop,
        cell=cell,
        plant=case.label,
        gains=g,
        period_s=case.period_s,
        **figures.as_fields(),
    )  # type: ignore[arg-type]


def tuning_margins(
    tuning: Tuning,
    rig: Rig,
    *,
    limits: MarginLimits = DEFAULT_LIMITS,
    cases: Sequence[PlantCase] | None = None,
    every_loop: bool = True,
) -> Margins:
    """The margins of every loop of ``tuning`` on ``rig`` (module docstring).

    On the nominal plants every loop is computed with python-control. Over a plant set
    (``cases``, e.g. :func:`plant_cases`) every loop on every other case is screened on a grid
    (:func:`grid_margins`); for each axis and loop kind the cases and cells with the worst Ms,
    the worst phase margin and the worst gain margin are then computed with python-control,
    and those are the figures reported. So each reported number is python-control's, and the
    worst case is found among all of them.

    Parameters
    ----------
    tuning : Tuning
    rig : Rig
        The rig the tuning was made for (its axes and period are checked).
    limits : MarginLimits
        The limits the verdict uses.
    cases : sequence of PlantCase, optional
        The plant set; default the nominal plants only.
    every_loop : bool
        Compute every nominal loop with python-control (for tables and heat maps). False: the
        nominal plants are screened like the other cases and only the worst loops found are
        computed with python-control (what a verdict needs; verification uses it).

    Returns
    -------
    Margins
        The nominal loops (rig axis order; per axis the lock loop, then the task loop, each cell
        row ``E`` then column ``EC``), then the worst cases found over the plant set.
    """
    tuning.check_rig(rig)
    nominal = PlantCase(
        label="nominal", plants=tuple(a.plant for a in rig.axes), period_s=rig.period_s
    )
    others = [c for c in (cases or ()) if c.label != "nominal" or not every_loop]
    if not every_loop and not any(c.label == "nominal" for c in others):
        others.insert(0, nominal)
    out: list[LoopMargins] = []
    worst: list[LoopMargins] = []
    for a, (name, ctrl) in enumerate(zip(tuning.axis_names, tuning.controllers, strict=True)):
        sets = gain_sets(ctrl)
        memo: dict[GainSet, LoopMargins] = {}
        for loop, cell, g in sets if every_loop else ():
            if g not in memo:
                memo[g] = _margins_of(
                    name, loop, cell, g, nominal.plants[a], rig, nominal, ctrl.filters
                )
            out.append(replace(memo[g], loop=loop, cell=cell))
        if not others:
            continue
        for kind in ("lock", "task"):
            kind_sets = [(cell, g) for loop, cell, g in sets if loop == kind]
            if not kind_sets:
                continue
            uniq = list(dict.fromkeys(g for _, g in kind_sets))
            gains = np.array([(g.kp, g.ki_t, g.kd_t) for g in uniq])
            found: dict[tuple[int, int], None] = {}
            scores = []
            for ci, case in enumerate(others):
                plant = case.plants[a]
                w = margin_grid(plant, case.period_s)
                gr = plant_response(plant, rig, case, w)[None, :]
                gr = gr * chain_response(ctrl.filters, w, case.period_s)[None, :]
                m = grid_margins(
                    w, gains, controller_basis(w, case.period_s), gr, unwrapped_phase(gr)
                )
                scores.append((ci, m["ms"][:, 0], m["pm"][:, 0], m["gm"][:, 0]))
            for pick in (lambda s: -s[1], lambda s: s[2], lambda s: s[3]):  # Ms, PM, GM
                best = min((float(pick(s)[u]), s[0], u) for s in scores for u in range(len(uniq)))
                found[(best[1], best[2])] = None
            for ci, u in found:
                cell = next(cell for cell, g in kind_sets if g == uniq[u])
                worst.append(
                    _margins_of(
                        name,
                        kind,
                        cell,
                        uniq[u],
                        others[ci].plants[a],
                        rig,
                        others[ci],
                        ctrl.filters,
                    )
                )
    return Margins(loops=tuple(out + worst), limits=limits)


def with_limits(m: Margins, limits: MarginLimits) -> Margins:
    """The same margins judged by other limits."""
    return replace(m, limits=limits)
