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
compute time and the drive's delay as an input lag (:func:`servotune.plant.discretize`; an
asymmetric plant enters with the mean of its two directions' gains), behind the D/A's gain
(one code is ``lsb_v`` volts). Friction, offset, the speed limit and the quantisation are left
out: the margins are those of the linear loop between them. Loop ``L(z) = C(z)·lsb·P(z)``
[counts per count].

Every figure is computed with python-control: the loop's frequency response
(``control.frequency_response``) on a grid up to the Nyquist frequency, its gain and phase
margins and their crossovers from ``control.stability_margins`` on that response (an FRD,
python-control's interpolating method), stability from the poles of ``control.feedback(L, 1)``.
The delay margin is the smallest ``PM_i/ω_i`` over the gain crossovers [s] (the extra
loop delay that brings the phase margin to zero); ``Ms = max|1/(1 + L)|``,
``Mt = max|L/(1 + L)|``; the bandwidth is the lowest frequency where ``|T|`` falls below
``1/√2`` (−3 dB).

The default limits (PM ≥ 45°, GM ≥ 6 dB, Ms ≤ 2.0) follow Åström & Hägglund, *Advanced PID
Control* (ISA, 2006), §4.2: Ms between 1.2 and 2.0 is the usual robust range, and Ms ≤ 2.0
alone guarantees GM ≥ 6 dB and PM ≥ 29°.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from servotune.errors import SpecError
from servotune.laws.fuzzy_pid import FuzzyPIDConstants
from servotune.laws.pi import PIConstants
from servotune.plant import Plant, discretize
from servotune.validate import check_number

if TYPE_CHECKING:  # python-control is imported where used (slow to import)
    import control

    from servotune.rig import Rig
    from servotune.tuning import Tuning

__all__ = [
    "DEFAULT_LIMITS",
    "GainSet",
    "LoopMargins",
    "MarginLimits",
    "Margins",
    "controller_tf",
    "gain_sets",
    "loop_margins",
    "loop_model",
    "tuning_margins",
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
        check_number("min_phase_margin_deg", self.min_phase_margin_deg, "deg", hi=90.0,
                     hi_strict=True, error=e)  # fmt: skip
        check_number("min_gain_margin_db", self.min_gain_margin_db, "dB", hi=60.0, error=e)
        check_number("max_sensitivity", self.max_sensitivity, "1", lo=1.0, strict=True, hi=100.0,
                     error=e)  # fmt: skip

    def broken(self, m: LoopMargins) -> tuple[str, ...]:
        """The limits ``m`` breaks, each as a phrase (empty: it meets them all)."""
        if not m.stable:
            return (f"unstable (closed-loop pole radius {m.spectral_radius:.4f})",)
        out = []
        if m.phase_margin_deg < self.min_phase_margin_deg:
            out.append(f"PM {m.phase_margin_deg:.1f}° < {self.min_phase_margin_deg:g}°")
        if m.gain_margin_db < self.min_gain_margin_db:
            out.append(f"GM {m.gain_margin_db:.1f} dB < {self.min_gain_margin_db:g} dB")
        if m.max_sensitivity > self.max_sensitivity:
            out.append(f"Ms {m.max_sensitivity:.2f} > {self.max_sensitivity:g}")
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


def loop_model(
    plant: Plant, g: GainSet, *, period_s: float, lag_s: float, lsb_volts: float
) -> control.StateSpace:
    """The loop ``L(z) = C(z)·lsb·P(z)`` [counts per count] (module docstring).

    Parameters
    ----------
    plant : Plant
    g : GainSet
    period_s : float
        Achieved tick period [s].
    lag_s : float
        Total lag from the tick start to the motor input [s] (compute time + drive delay).
    lsb_volts : float
        D/A gain [V/code].
    """
    import control

    p = discretize(plant, period_s, lag_s) * lsb_volts
    return control.ss(control.series(controller_tf(g, period_s), p))


def _grid(plant: Plant, period_s: float) -> np.ndarray:
    nyq = math.pi / period_s
    top = nyq
    while top * period_s >= math.pi:  # below Nyquist, so python-control accepts every point
        top = float(np.nextafter(top, 0.0))
    lo = min(1.0 / plant.tau_s, nyq) * 10.0**-GRID_DECADES_BELOW
    return np.logspace(math.log10(lo), math.log10(top), GRID_POINTS)


def loop_margins(loop: control.StateSpace, w: np.ndarray) -> dict[str, float | bool]:
    """Margins, peaks, bandwidth and stability of a discrete loop, by python-control.

    Parameters
    ----------
    loop : control.StateSpace
        Discrete open loop ``L`` (negative unity feedback).
    w : ndarray
        Frequency grid [rad/s], increasing, below the Nyquist frequency.

    Returns
    -------
    dict
        ``stable``, ``spectral_radius``, ``gain_margin_db`` (inf without a phase crossover),
        ``phase_margin_deg`` (inf without a gain crossover), ``delay_margin_s``,
        ``crossover_rad_s``, ``phase_crossover_rad_s`` (NaN where there is none),
        ``max_sensitivity``, ``max_complementary_sensitivity``, ``bandwidth_rad_s``.
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
    return {
        "stable": rho < 1.0,
        "spectral_radius": rho,
        "gain_margin_db": gm_db,
        "phase_margin_deg": pm,
        "delay_margin_s": dm,
        "crossover_rad_s": wc,
        "phase_crossover_rad_s": wpc,
        "max_sensitivity": float(np.max(np.abs(s))),
        "max_complementary_sensitivity": float(np.max(np.abs(t))),
        "bandwidth_rad_s": bw,
    }


@dataclass(frozen=True, slots=True, kw_only=True)
class LoopMargins:
    """The margins of one loop the runtime can run, on one plant.

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
        Closed-loop −3 dB bandwidth [rad/s].
    period_s : float
        The tick period of the loop [s].
    """

    axis: str
    loop: str
    cell: tuple[int, int] | None
    plant: str
    gains: GainSet
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
    """

    loops: tuple[LoopMargins, ...]
    limits: MarginLimits = field(default=DEFAULT_LIMITS)

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
        """Every loop meets every limit."""
        return not self.failures()

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
        }


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


def tuning_margins(
    tuning: Tuning,
    rig: Rig,
    *,
    limits: MarginLimits = DEFAULT_LIMITS,
    plants: Mapping[str, Sequence[Plant]] | None = None,
    extra_lag_s: Sequence[float] = (0.0,),
    periods_s: Sequence[float] | None = None,
) -> Margins:
    """The margins of every loop of ``tuning`` on ``rig`` (module docstring).

    Parameters
    ----------
    tuning : Tuning
    rig : Rig
        The rig the tuning was made for (its axes and period are checked).
    limits : MarginLimits
        The limits the verdict uses.
    plants : mapping of str to sequence of Plant, optional
        Label → one plant per rig axis (e.g. the corners of the identified intervals); default
        ``{"nominal": the rig's plants}``.
    extra_lag_s : sequence of float
        Extra input lags [s] each plant is also taken with (e.g. ``(0, T)``: one tick more).
    periods_s : sequence of float, optional
        Tick periods [s] to take (e.g. the period ± the timer's error); default the rig's.

    Returns
    -------
    Margins
        Gain sets shared by several cells are computed once.
    """
    tuning.check_rig(rig)
    lsb = rig.dac.lsb_v
    plant_sets = {"nominal": tuple(a.plant for a in rig.axes)} if plants is None else dict(plants)
    periods = (rig.period_s,) if periods_s is None else tuple(periods_s)
    cases = []
    for label, ps in plant_sets.items():
        for extra in extra_lag_s:
            for per in periods:
                tag = label
                if len(extra_lag_s) > 1 or extra:
                    tag += f"+{extra / rig.period_s:g}tick"
                if len(periods) > 1:
                    tag += f"@{(per / rig.period_s - 1) * 1e6:+.0f}ppm"
                cases.append((tag, ps, extra, per))
    out: list[LoopMargins] = []
    for a, (name, ctrl) in enumerate(zip(tuning.axis_names, tuning.controllers, strict=True)):
        sets = gain_sets(ctrl)
        for tag, ps, extra, per in cases:
            plant = ps[a]
            lag = rig.timer.compute_s + plant.delay_s + extra
            w = _grid(plant, per)
            memo: dict[GainSet, dict[str, float | bool]] = {}
            for loop, cell, g in sets:
                if g not in memo:
                    model = loop_model(plant, g, period_s=per, lag_s=lag, lsb_volts=lsb)
                    memo[g] = loop_margins(model, w)
                out.append(LoopMargins(axis=name, loop=loop, cell=cell, plant=tag, gains=g,
                                       period_s=per, **memo[g]))  # type: ignore[arg-type]  # fmt: skip
    return Margins(loops=tuple(out), limits=limits)


def with_limits(m: Margins, limits: MarginLimits) -> Margins:
    """The same margins judged by other limits."""
    return replace(m, limits=limits)
