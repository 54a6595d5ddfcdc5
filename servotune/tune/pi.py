"""PI design for a position axis.

:func:`pi_loop_shaping` is a closed-form loop-shaping rule used where no tuning exists yet (the
virtual rig's ``track`` scenario, first guesses for optimisers): it places the crossover where the
phase margin target is met given the axis lag, with the PI zero a fixed fraction below it.

:func:`tune_pi` is the synthesis: the largest integral gain under the robustness constraints the
user gives (phase margin, gain margin, peak sensitivity, crossover bound), on the exact discrete
loop, solved as a constrained NLP with casadi/ipopt; every number it reports is re-checked with
python-control. :func:`tune_pi_axis` does the same for one axis of a rig.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from servotune.errors import InfeasibleError, SpecError
from servotune.hw import dac as hw_dac
from servotune.io.files import json_float
from servotune.laws.pi import PIGains
from servotune.plant import Plant, discretize, discretize_lti, lag_split

if TYPE_CHECKING:  # python-control and casadi are imported where used (slow to import)
    import control

    from servotune.rig import Rig

__all__ = ["DEFAULT_TARGETS", "PITuning", "pi_loop_shaping", "tune_pi", "tune_pi_axis"]

DEFAULT_TARGETS: Mapping[str, float] = {
    "phase_margin_deg": 50.0,
    "gain_margin_db": 8.0,
    "max_sensitivity": 1.6,
}
"""Default robustness targets of a position-loop PI design (the master, the slave's start
point, the gantry drives, the linkage axes)."""


def pi_loop_shaping(
    plant: Plant,
    *,
    period_s: float,
    lsb_v: float,
    compute_s: float = 0.0,
    phase_margin_deg: float = 55.0,
    zero_ratio: float = 0.2,
) -> PIGains:
    """PI gains for ``gain / (s (tau s + 1))`` by loop shaping at a target phase margin.

    The loop ``L = (Kp + Ki/s) · LSB · plant`` includes the lag ``compute_s + delay_s`` and the
    ZOH's half period. The crossover ``wc`` solves
    ``180° − 90° − atan(wc·tau) − wc·lag − atan(zero_ratio) = phase_margin_deg``; ``Ki/Kp`` is
    ``zero_ratio · wc``; ``Kp`` makes ``|L(j wc)| = 1``.

    Parameters
    ----------
    plant : Plant
        Axis model.
    period_s : float
        Tick period [s].
    lsb_v : float
        D/A step [V] (gains are in codes).
    compute_s : float
        Tick start → D/A write [s].
    phase_margin_deg : float
        Target phase margin [deg], in (0, 85).
    zero_ratio : float
        PI zero as a fraction of the crossover, in (0, 1).

    Returns
    -------
    PIGains
        ``kp`` [codes/count], ``ki`` [codes/(count·s)].

    Raises
    ------
    ValueError
        If the targets are out of range.

    Examples
    --------
    >>> g = pi_loop_shaping(Plant(gain_cps_per_v=12288, tau_s=0.025), period_s=0.004,
    ...                     lsb_v=20 / 4096)
    >>> round(g.kp, 3) > 0 and g.ki > 0
    True
    """
    if not 0 < phase_margin_deg < 85:
        raise ValueError(f"phase_margin_deg must be in (0, 85) [deg], got {phase_margin_deg!r}")
    if not 0 < zero_ratio < 1:
        raise ValueError(f"zero_ratio must be in (0, 1), got {zero_ratio!r}")
    lag = compute_s + plant.delay_s + period_s / 2
    tau = plant.tau_s
    pm = math.radians(phase_margin_deg)

    def margin(wc: float) -> float:
        return math.pi / 2 - math.atan(wc * tau) - wc * lag - math.atan(zero_ratio) - pm

    hi = math.pi / (2 * lag)
    wc = brentq(margin, 1e-9, hi)
    ki_over_kp = zero_ratio * wc
    plant_mag = plant.gain_cps_per_v * lsb_v / (wc * math.hypot(1.0, wc * tau))
    pi_mag = math.hypot(1.0, ki_over_kp / wc)
    kp = 1.0 / (plant_mag * pi_mag)
    return PIGains(kp=kp, ki=kp * ki_over_kp)


# --- tune_pi: largest Ki under robustness constraints ----------------------------------------

POINTS_PER_DECADE = 150
"""Design grid density: log-spaced frequencies per decade (see :func:`tune_pi`)."""
DECADES_BELOW = 3.0
"""The design grid starts this many decades below the slowest plant feature."""
_TOL_PM_DEG, _TOL_GM_DB, _TOL_MS_REL, _TOL_WC_REL = 0.5, 0.1, 0.01, 0.01
_REFINE_ROUNDS = 8  # NLP solves at most
_MAX_BUILDS = 3  # NLP rebuilds for a changed crossing structure at most
_GUARD_GAIN = 0.95  # |L| at a guard against a new gain crossover, at most
_PEAK_STENCIL = np.array([0.995, 0.998, 1.0, 1.002, 1.005])  # added around a missed Ms peak
_MAX_STABILITY_CHECKS = 64  # start-point candidates that pass the grid checks, at most
_MAX_LAG_PHASE_STEP = 0.2  # [rad]: grid step times the lag (the delay's phase per step)


@dataclass(frozen=True, slots=True, kw_only=True)
class PITuning:
    """A PI design from :func:`tune_pi` and its margins as python-control computes them.

    The margins are computed results for the exact discrete loop
    ``L(z) = (Kp + Ki·T·z/(z−1)) · lsb_v · P(z)`` (``P`` with ZOH and the input lag).

    Parameters
    ----------
    kp : float
        Proportional gain [codes/count] (for a transfer-function plant: input units per output
        unit, divided by ``lsb_v``).
    ki : float
        Integral gain [codes/(count·s)].
    period_s : float
        Sample period the design is for [s].
    compute_s : float
        Tick start → output write [s] (part of the loop's lag).
    lsb_v : float
        Output step [V per code] (1.0 for a plain transfer function).
    crossover_rad_s : float
        Gain crossover frequency (where ``|L| = 1``; the one python-control reports with the
        phase margin) [rad/s]; NaN if ``|L|`` never crosses 1.
    phase_margin_deg : float
        Phase margin [deg]; ``inf`` if there is no gain crossover.
    gain_margin_db : float
        Gain margin [dB] (python-control's choice among the phase crossovers: the one closest
        to 0 dB); ``inf`` if the phase never crosses −180°.
    phase_crossover_rad_s : float
        Frequency of that phase crossover [rad/s]; NaN if none.
    max_sensitivity : float
        Peak of ``|1/(1 + L)|`` over ``(0, π/T]`` [-].
    sensitivity_peak_rad_s : float
        Where that peak is [rad/s].
    spectral_radius : float
        Largest closed-loop pole magnitude [-], < 1 (the loop is stable).
    target_phase_margin_deg, target_gain_margin_db, target_max_sensitivity : float or None
        The lower bounds (margins) and upper bound (sensitivity) asked; None if not asked.
    target_crossover_rad_s : float or None
        Upper bound asked on the gain crossover [rad/s].
    binding : tuple of str
        Targets met with (almost) no slack, by name (``"phase_margin_deg"``, ...): the ones
        that limit Ki.
    solver_status : str
        Ipopt's return status of the final solve (``"Solve_Succeeded"``, ...), or
        ``"start point"`` if the grid search's design was kept.
    solver_iterations : int
        Ipopt iterations over all solves (refinements included).
    """

    kp: float
    ki: float
    period_s: float
    compute_s: float
    lsb_v: float
    crossover_rad_s: float
    phase_margin_deg: float
    gain_margin_db: float
    phase_crossover_rad_s: float
    max_sensitivity: float
    sensitivity_peak_rad_s: float
    spectral_radius: float
    target_phase_margin_deg: float | None = None
    target_gain_margin_db: float | None = None
    target_max_sensitivity: float | None = None
    target_crossover_rad_s: float | None = None
    binding: tuple[str, ...] = ()
    solver_status: str = ""
    solver_iterations: int = 0

    def __post_init__(self) -> None:
        for name, unit in (("kp", "codes/count"), ("ki", "codes/(count·s)")):
            v = getattr(self, name)
            if not _is_real(v) or not math.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be a finite number >= 0 [{unit}], got {v!r}")
        for name, unit in (("period_s", "s"), ("lsb_v", "V")):
            v = getattr(self, name)
            if not _is_real(v) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a finite number > 0 [{unit}], got {v!r}")
        if not _is_real(self.compute_s) or not self.compute_s >= 0:
            raise ValueError(f"compute_s must be >= 0 [s], got {self.compute_s!r}")
        if not _is_real(self.spectral_radius) or not 0 <= self.spectral_radius < 1:
            raise ValueError(
                f"spectral_radius must be in [0, 1) (a stable loop), got {self.spectral_radius!r}"
            )
        object.__setattr__(self, "binding", tuple(self.binding))

    @property
    def gains(self) -> PIGains:
        """The gains as :class:`~servotune.laws.pi.PIGains` (what the runtime and engine use)."""
        return PIGains(kp=self.kp, ki=self.ki)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (sorted keys); non-finite numbers (``inf``, NaN) become None.

        ``gain_margin_db: None`` thus means "no phase crossover" (infinite gain margin), a
        ``target_*: None`` that the target was not asked.
        """
        out: dict[str, Any] = {}
        for name in sorted(self.__slots__):  # type: ignore[attr-defined]
            v = getattr(self, name)
            if isinstance(v, float):
                v = json_float(v)
            elif isinstance(v, tuple):
                v = list(v)
            out[name] = v
        return out


def _is_real(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


class _Spec(NamedTuple):
    pm_deg: float | None
    gm_db: float | None
    ms: float | None
    wc_max: float | None

    def describe(self) -> str:
        parts = []
        if self.pm_deg is not None:
            parts.append(f"phase_margin_deg >= {self.pm_deg:g}")
        if self.gm_db is not None:
            parts.append(f"gain_margin_db >= {self.gm_db:g}")
        if self.ms is not None:
            parts.append(f"max_sensitivity <= {self.ms:g}")
        if self.wc_max is not None:
            parts.append(f"crossover_rad_s <= {self.wc_max:g}")
        return ", ".join(parts)


class _Ctx(NamedTuple):
    """The discrete plant (``lsb_v`` included): its state-space matrices (with the held past
    inputs, for the closed-loop poles), its response at any frequency and on the design grid."""

    period_s: float
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: float
    resp: Callable[[np.ndarray], np.ndarray]  # plant response at ω [rad/s] (lsb_v included)
    w: np.ndarray  # design grid [rad/s]
    g: np.ndarray  # plant response on it (lsb_v included)
    ph: np.ndarray  # unwrapped phase of g [rad]
    q_im: np.ndarray  # Im of T·z/(z−1) on the grid; Re is T/2


def _check_spec(
    period_s: float,
    compute_s: float,
    lsb_v: float,
    pm: float | None,
    gm: float | None,
    ms: float | None,
    wc: float | None,
) -> _Spec:
    def real(name: str, v: object, unit: str) -> float:
        if not _is_real(v) or not math.isfinite(v):  # type: ignore[arg-type]
            raise ValueError(f"{name} must be a finite number [{unit}], got {v!r}")
        return float(v)  # type: ignore[arg-type]

    if real("period_s", period_s, "s") <= 0:
        raise ValueError(f"period_s must be > 0 [s], got {period_s!r}")
    if real("compute_s", compute_s, "s") < 0:
        raise ValueError(f"compute_s must be >= 0 [s], got {compute_s!r}")
    if real("lsb_v", lsb_v, "V") <= 0:
        raise ValueError(f"lsb_v must be > 0 [V], got {lsb_v!r}")
    if pm is None and gm is None and ms is None:
        raise SpecError(
            "give at least one of phase_margin_deg, gain_margin_db, max_sensitivity "
            "(crossover_rad_s alone does not make the loop robust)"
        )
    if pm is not None and not 0 < real("phase_margin_deg", pm, "deg") < 90:
        raise SpecError(f"phase_margin_deg must be in (0, 90) [deg], got {pm!r}")
    if gm is not None and not real("gain_margin_db", gm, "dB") > 0:
        raise SpecError(f"gain_margin_db must be > 0 [dB], got {gm!r}")
    if ms is not None and not real("max_sensitivity", ms, "-") > 1:
        raise SpecError(f"max_sensitivity must be > 1 (no loop has a smaller peak), got {ms!r}")
    if wc is not None:
        nyq = math.pi / period_s
        if not 0 < real("crossover_rad_s", wc, "rad/s") < nyq:
            raise SpecError(
                f"crossover_rad_s must be in (0, π/period_s = {nyq:.6g}) [rad/s], got {wc!r}"
            )
    return _Spec(
        None if pm is None else float(pm),
        None if gm is None else float(gm),
        None if ms is None else float(ms),
        None if wc is None else float(wc),
    )


def _plant_model(
    plant: Plant | control.TransferFunction, period_s: float, compute_s: float
) -> tuple[Callable[[float], control.StateSpace], float, float]:
    """The exact ZOH discretiser of the plant (a function of the lag), the total lag [s] and
    the plant's slowest feature [rad/s] (``1/tau_s``, or the smallest nonzero pole/zero)."""
    import control

    if isinstance(plant, Plant):
        lag = compute_s + plant.delay_s
        return (lambda lag_s: discretize(plant, period_s, lag_s)), lag, 1.0 / plant.tau_s
    if isinstance(plant, control.TransferFunction | control.StateSpace):
        if not (plant.ninputs == 1 and plant.noutputs == 1):
            raise ValueError("plant must be SISO")
        if plant.isdtime(strict=True):
            return _discrete_plant_model(plant, period_s, compute_s)
        if not plant.isctime(strict=True):
            raise ValueError(
                f"plant must be continuous-time (dt=0) or discrete at period_s; got dt={plant.dt!r}"
            )
        roots = np.concatenate([np.atleast_1d(plant.poles()), np.atleast_1d(plant.zeros())])
        mags = np.abs(roots[np.isfinite(roots)])
        mags = mags[mags > 1e-12]
        feature = float(mags.min()) if mags.size else math.inf
        return (lambda lag_s: discretize_lti(plant, period_s, lag_s)), compute_s, feature
    raise ValueError(
        "plant must be a servotune Plant or a continuous control.TransferFunction, "
        f"got {type(plant).__name__}"
    )


def _discrete_plant_model(
    plant: control.TransferFunction | control.StateSpace, period_s: float, compute_s: float
) -> tuple[Callable[[float], control.StateSpace], float, float]:
    """:func:`_plant_model` for a plant already discrete at ``period_s`` (e.g. a closed inner
    loop): the lag must be whole periods and acts as ``z^-m``."""
    import control

    if not math.isclose(float(plant.dt), period_s, rel_tol=1e-9):
        raise ValueError(
            f"a discrete plant must have dt = period_s = {period_s!r}, got {plant.dt!r}"
        )
    ss = control.ss(plant)

    def delayed(lag_s: float) -> control.StateSpace:
        m = round(lag_s / period_s)
        if abs(lag_s - m * period_s) > 1e-9 * period_s:
            raise ValueError(
                f"compute_s must be whole periods for a discrete plant, got {compute_s!r} s "
                f"at period_s={period_s!r} s"
            )
        if m == 0:
            return ss
        return control.ss(control.series(ss, control.tf([1.0], [1.0] + [0.0] * m, period_s)))

    poles = np.concatenate([np.atleast_1d(ss.poles()), np.atleast_1d(ss.zeros())])
    poles = poles[np.isfinite(poles) & (np.abs(poles) > 1e-12)]
    s_c = np.abs(np.log(poles.astype(complex))) / period_s
    s_c = s_c[s_c > 1e-9]
    feature = float(s_c.min()) if s_c.size else math.inf
    return delayed, compute_s, feature


def _grid(w_lo: float, nyq: float, lag_s: float, poles: np.ndarray) -> np.ndarray:
    """Design grid: log-spaced, refined by a linear grid where a lag turns the phase fast
    (steps of at most 0.2 rad of lag phase) and around lightly damped plant poles."""
    n = max(50, math.ceil(math.log10(nyq / w_lo) * POINTS_PER_DECADE) + 1)
    parts = [np.geomspace(w_lo, nyq, n)]
    step = _MAX_LAG_PHASE_STEP / lag_s  # [rad/s]
    if nyq / step > 1:
        parts.append(np.arange(1, math.floor(nyq / step) + 1) * step)
    z = poles[(np.abs(poles) > 1e-9) & (np.abs(poles - 1.0) > 1e-9)]
    s_c = np.log(z.astype(complex)) / (math.pi / nyq)
    for s_i in s_c[s_c.imag > 0]:
        wn = abs(s_i)
        zeta = -s_i.real / wn
        if 0 < zeta < 0.2:  # ±8 half-power bandwidths in steps of 1/8 of one
            parts.append(wn * (1.0 + zeta * np.linspace(-8.0, 8.0, 129)))
    w = np.unique(np.concatenate(parts))
    w = w[(w >= w_lo) & (w < nyq * (1 - 1e-12))]
    return np.append(w, nyq)


def _check_grid(w: np.ndarray) -> np.ndarray:
    """Verification grid: the design grid's geometric midpoints, a decade of log grid below
    it, and the Nyquist frequency."""
    below = np.geomspace(w[0] / 10.0, w[0], POINTS_PER_DECADE + 1)[:-1]
    return np.concatenate([below, np.sqrt(w[:-1] * w[1:]), w[-1:]])


def _ss_response(
    a: np.ndarray, b: np.ndarray, c: np.ndarray, d: float, z: np.ndarray
) -> np.ndarray:
    """``C (zI − A)⁻¹ B + D`` at each ``z``, batched (in chunks, to bound the memory)."""
    n = a.shape[0]
    if n == 0:
        return np.full(z.shape, d, dtype=complex)
    out = np.empty(z.shape, dtype=complex)
    chunk = max(1, 2**22 // (n * n))
    eye = np.eye(n)
    for i in range(0, z.size, chunk):
        zc = z[i : i + chunk]
        m = zc[:, None, None] * eye[None] - a[None]
        x = np.linalg.solve(m, np.broadcast_to(b.astype(complex), (zc.size, n, 1)))
        out[i : i + chunk] = (c[None] @ x)[:, 0, 0] + d
    return out


def _q_im(w: np.ndarray, period_s: float) -> np.ndarray:
    """Im of ``T·z/(z−1)`` at ``z = exp(jωT)``: ``−(T/2)·cot(ωT/2)`` (its real part is T/2)."""
    return -0.5 * period_s / np.tan(0.5 * w * period_s)


def _unwrapped_phase(g: np.ndarray) -> np.ndarray:
    """Phase from the lowest frequency on, its first value taken in (−3π/2, π/2]."""
    ph = np.angle(g)
    if ph[0] > 0.5 * math.pi:
        ph[0] -= 2 * math.pi
    return np.unwrap(ph)


def _spectral_radius(ctx: _Ctx, kp: np.ndarray, ki: np.ndarray) -> np.ndarray:
    """Largest closed-loop pole magnitude for each (kp, ki), batched."""
    t = ctx.period_s
    a, b, c, d = ctx.a, ctx.b[:, 0], ctx.c[0], ctx.d
    n = a.shape[0]
    g = kp + ki * t
    s = 1.0 / (1.0 + g * d)
    m = np.zeros((kp.size, n + 1, n + 1))
    m[:, :n, :n] = a[None] - (b[None, :, None] * (s * g)[:, None, None]) * c[None, None, :]
    m[:, :n, n] = b[None, :] * s[:, None]
    # e = -(1 - d s g) C x - d s I ;  I' = I + ki T e
    kit = ki * t
    m[:, n, :n] = -(kit * (1.0 - d * s * g))[:, None] * c[None, :]
    m[:, n, n] = 1.0 - kit * d * s
    return np.max(np.abs(np.linalg.eigvals(m)), axis=1)


def _grid_margins(ctx: _Ctx, kp: np.ndarray, ki: np.ndarray) -> dict[str, np.ndarray]:
    """Grid estimates for a batch of (kp, ki): worst PM [rad], worst GM [ln], Ms, top crossover.

    Crossings are located by linear interpolation between grid points.
    """
    t = ctx.period_s
    cr = (kp + ki * 0.5 * t)[:, None]
    ci = ki[:, None] * ctx.q_im[None, :]
    loop = (cr + 1j * ci) * ctx.g[None, :]
    lnl = np.log(np.abs(loop) + 1e-300)
    phl = ctx.ph[None, :] + np.arctan2(ci, cr)
    ms = 1.0 / np.min(np.abs(1.0 + loop), axis=1)
    # gain crossovers: sign changes of ln|L|
    s0, s1 = lnl[:, :-1], lnl[:, 1:]
    cross = (s0 >= 0) != (s1 >= 0)
    f = np.where(cross, s0 / np.where(cross, s0 - s1, 1.0), 0.0)
    ph_c = phl[:, :-1] + f * (phl[:, 1:] - phl[:, :-1])
    pm = np.where(cross, np.mod(ph_c, 2 * math.pi) - math.pi, np.inf).min(axis=1, initial=np.inf)
    lw = np.log(ctx.w)
    w_c = np.exp(lw[:-1][None, :] + f * (lw[1:] - lw[:-1])[None, :])
    wc_top = np.where(cross, w_c, 0.0).max(axis=1, initial=0.0)
    # phase crossovers: the phase passes an odd multiple of π
    k = np.floor((phl + math.pi) / (2 * math.pi))
    pc = k[:, :-1] != k[:, 1:]
    lvl = np.maximum(k[:, :-1], k[:, 1:]) * 2 * math.pi - math.pi
    dph = phl[:, 1:] - phl[:, :-1]
    fp = np.where(pc, (lvl - phl[:, :-1]) / np.where(pc, dph, 1.0), 0.0)
    ln_c = lnl[:, :-1] + fp * (lnl[:, 1:] - lnl[:, :-1])
    gm = np.where(pc, -ln_c, np.inf).min(axis=1, initial=np.inf)
    return {"pm": pm, "gm": gm, "ms": ms, "wc_top": wc_top}


def _feasible(m: dict[str, np.ndarray], spec: _Spec, slack: float) -> np.ndarray:
    ok = np.ones(m["ms"].shape, dtype=bool)
    if spec.pm_deg is not None:
        ok &= m["pm"] >= math.radians(spec.pm_deg) - slack * math.radians(_TOL_PM_DEG)
    if spec.gm_db is not None:
        ok &= m["gm"] >= spec.gm_db / 20 * math.log(10) - slack * _TOL_GM_DB / 20 * math.log(10)
    if spec.ms is not None:
        ok &= m["ms"] <= spec.ms * (1 + slack * _TOL_MS_REL)
    if spec.wc_max is not None:
        ok &= m["wc_top"] <= spec.wc_max * (1 + slack * _TOL_WC_REL)
    return ok


def _start_point(ctx: _Ctx, spec: _Spec) -> tuple[float, float] | None:
    """Best grid design: points of the phase-margin loci with the largest Ki that pass.

    On the locus of level φ every (kp, ki) puts ``L = −exp(jφ)`` at one grid frequency (on
    the first branch: the unwrapped loop phase there is ``−180° + φ``). The loci for φ from
    the lowest level the targets allow (the phase-margin target, and ``2·asin(1/(2·Ms))``,
    which every loop with that peak sensitivity has) to 87.5° in steps of 2.5°, and on to 175°
    in steps of 5° (small gains on a plant without integrator), cover the designs. Candidates
    are checked, the largest Ki first, against the targets on every other grid point (with
    the reporting tolerances as slack) and for stability (the first 64 that pass the grid
    checks at most: past those, the plant is taken as not stabilisable by the PI under the
    targets).
    """
    t = ctx.period_s
    lo = 2.5
    if spec.pm_deg is not None:
        lo = max(lo, spec.pm_deg)
    if spec.ms is not None:
        lo = max(lo, math.degrees(2 * math.asin(0.5 / spec.ms)) - 0.5)
    # above 90° too: small gains on a plant without integrator give margins up to 180°
    levels = np.unique(
        np.concatenate(
            [[lo], np.arange(2.5 * math.ceil(lo / 2.5), 90.0, 2.5), np.arange(90.0, 176.0, 5.0)]
        )
    )
    sel = np.arange(0, ctx.w.size - 1, 2)  # every other grid point, Nyquist excluded
    q = ctx.q_im[None, sel]
    c = -np.exp(1j * np.radians(levels))[:, None] / ctx.g[None, sel]  # the PI at that point
    ki = c.imag / q
    kp = c.real - 0.5 * t * ki
    # the first branch only: the loop's unwrapped phase there is −180° + φ, not 360° lower
    phase = ctx.ph[None, sel] + np.arctan2(ki * q, kp + 0.5 * t * ki)
    first = np.abs(phase + math.pi - np.radians(levels)[:, None]) < 1e-6
    keep = ((kp >= 0) & (ki > 0) & np.isfinite(kp) & np.isfinite(ki) & first).ravel()
    kp, ki = kp.ravel()[keep], ki.ravel()[keep]
    order = np.argsort(-ki)
    kp, ki = kp[order], ki[order]
    sub = np.append(np.arange(0, ctx.w.size - 1, 2), ctx.w.size - 1)
    coarse = ctx._replace(w=ctx.w[sub], g=ctx.g[sub], ph=ctx.ph[sub], q_im=ctx.q_im[sub])
    start, size, budget = 0, 128, _MAX_STABILITY_CHECKS
    while start < kp.size and budget > 0:  # the largest Ki first: the first that passes wins
        kpc, kic = kp[start : start + size], ki[start : start + size]
        idx = np.flatnonzero(_feasible(_grid_margins(coarse, kpc, kic), spec, slack=1.0))
        for j in range(0, min(idx.size, budget), 16):
            batch = idx[j : min(j + 16, budget)]
            budget -= batch.size
            stable = batch[_spectral_radius(ctx, kpc[batch], kic[batch]) < 1.0]
            if stable.size:
                return float(kpc[stable[0]]), float(kic[stable[0]])
        start += size
        size = min(2 * size, 2048)
    return None


class _Crossing(NamedTuple):
    """A crossing of the start loop: ln ω, its bracket [lo, hi] and its phase branch/level."""

    x: float
    lo: float
    hi: float
    level: float  # gain crossover: the branch offset b (PM = ph − b − π); phase: the level


_MAX_CROSSINGS = 6


def _crossings(ctx: _Ctx, kp: float, ki: float) -> tuple[list[_Crossing], list[_Crossing]]:
    """Gain crossovers and phase crossings (odd multiples of π) of the loop on the grid.

    Each is located by linear interpolation in ln ω and bracketed by the midpoints to its
    neighbours of the same kind (the grid ends outside).
    """
    t = ctx.period_s
    cr, ci = kp + 0.5 * ki * t, ki * ctx.q_im
    lnl = np.log(np.abs((cr + 1j * ci) * ctx.g) + 1e-300)
    phl = ctx.ph + np.arctan2(ci, cr)
    lw = np.log(ctx.w)

    def bracket(xs: list[float], levels: list[float]) -> list[_Crossing]:
        out = []
        for i, (x, lvl) in enumerate(zip(xs, levels, strict=True)):
            lo = lw[0] if i == 0 else 0.5 * (xs[i - 1] + x)
            hi = lw[-1] if i == len(xs) - 1 else 0.5 * (x + xs[i + 1])
            out.append(_Crossing(float(x), float(lo), float(hi), float(lvl)))
        return out[:_MAX_CROSSINGS]

    i = np.flatnonzero((lnl[:-1] >= 0) != (lnl[1:] >= 0))
    f = lnl[i] / (lnl[i] - lnl[i + 1])
    xs = list(lw[i] + f * (lw[i + 1] - lw[i]))
    ph_c = phl[i] + f * (phl[i + 1] - phl[i])
    gains = bracket(xs, list(2 * math.pi * np.floor(ph_c / (2 * math.pi))))
    k = np.floor((phl + math.pi) / (2 * math.pi))
    i = np.flatnonzero(k[:-1] != k[1:])
    lvl = np.maximum(k[i], k[i + 1]) * 2 * math.pi - math.pi
    f = (lvl - phl[i]) / (phl[i + 1] - phl[i])
    phases = bracket(list(lw[i] + f * (lw[i + 1] - lw[i])), list(lvl))
    return gains, phases


def _modelled(
    ctx: _Ctx, spec: _Spec, kp: float, ki: float
) -> tuple[list[_Crossing], list[_Crossing]]:
    """The crossings the NLP models: every gain crossover if a phase margin is asked; the
    phase crossings if a gain margin is asked, except those with a margin 20 dB beyond the
    target (the re-check watches them) and a touch at the Nyquist frequency (where ``L`` is
    real; a constraint of its own)."""
    xcs, x180s = _crossings(ctx, kp, ki)
    if spec.pm_deg is None:
        xcs = []
    if spec.gm_db is None:
        return xcs, []
    t = ctx.period_s
    x_last = math.log(ctx.w[-2])
    keep = []
    for c in x180s:
        om = np.array([math.exp(c.x)])
        loop = (kp + ki * (0.5 * t + 1j * _q_im(om, t)[0])) * ctx.resp(om)[0]
        gm_db = -20 * math.log10(abs(loop))
        if c.x < x_last and gm_db < spec.gm_db + 20.0:
            keep.append(c)
    return xcs, keep


class _NlpResult(NamedTuple):
    kp: float
    ki: float
    x: np.ndarray  # the solution vector (scaled gains, crossing frequencies)
    status: str
    iterations: int
    success: bool
    on_bracket: bool  # a crossing ended on an inner bracket bound: rebuild from here


_N_EXTRA_MS, _N_EXTRA_WC = 24, 16  # parameter slots for frequencies added by the refinement


class _Nlp:
    """The NLP for the crossing structure of one loop (built again when that changes).

    Variables: ``kp/kp0``, ``ki/ki0`` (scaled by the gains it is built from) and the ln ω of
    every gain crossover (if a phase margin is asked) and phase crossing (if a gain margin is
    asked) of that loop, each kept inside its bracket. Objective: ``−ki/ki0``. The targets and
    the frequencies added by the refinement are parameters, so one build serves every round.
    """

    def __init__(self, ctx: _Ctx, spec: _Spec, gains: tuple[float, float]) -> None:
        import casadi as ca

        t = ctx.period_s
        self.ctx, self.kp0, self.ki0 = ctx, gains[0], gains[1]
        xcs, x180s = _modelled(ctx, spec, *gains)
        self.structure = (len(xcs), tuple(c.level for c in x180s))
        lw = np.log(ctx.w)
        nv = 2 + len(xcs) + len(x180s)
        v = ca.SX.sym("v", nv)
        # parameters: PM target [rad], ln GM target, Ms², then (Re G, Im G, Im q) per slot
        p_t = ca.SX.sym("p_t", 3)
        p_ms = ca.SX.sym("p_ms", 3, _N_EXTRA_MS)
        p_wc = ca.SX.sym("p_wc", 3, _N_EXTRA_WC)
        p_gd = ca.SX.sym("p_gd", 3, _N_EXTRA_WC)
        kp, ki = self.kp0 * v[0], self.ki0 * v[1]
        cr = kp + 0.5 * t * ki
        g: list[Any] = []
        lbg: list[float] = []
        ubg: list[float] = []

        def loop(gr: Any, gi: Any, qim: Any) -> tuple[Any, Any]:
            ci = ki * qim
            return cr * gr - ci * gi, cr * gi + ci * gr

        def add(expr: Any, lo: float, hi: float) -> None:
            g.append(expr)
            lbg.extend([lo] * expr.numel())
            ubg.extend([hi] * expr.numel())

        if spec.ms is not None:
            # in log form: |1 + L| spans decades over the grid
            lr, li = loop(ca.DM(ctx.g.real), ca.DM(ctx.g.imag), ca.DM(ctx.q_im))
            add(ca.log(p_t[2]) + ca.log((1 + lr) ** 2 + li**2), 0.0, math.inf)
            lr, li = loop(p_ms[0, :].T, p_ms[1, :].T, p_ms[2, :].T)
            add(p_t[2] * ((1 + lr) ** 2 + li**2) - 1, 0.0, math.inf)
        top = lw[-1]
        if spec.wc_max is not None:
            top = min(top, math.log(spec.wc_max))
            above = ctx.w > spec.wc_max
            if above.any():
                gw, qw = ctx.g[above], ctx.q_im[above]
                lr, li = loop(ca.DM(gw.real), ca.DM(gw.imag), ca.DM(qw))
                add(1 - (lr**2 + li**2), 0.0, math.inf)
        if spec.gm_db is not None and ctx.g[-1].real < 0:
            # at the Nyquist frequency L is real: a gain margin there, L(π/T) >= −1/GM
            add(1 + (cr * ctx.g[-1].real) * ca.exp(p_t[1]), 0.0, math.inf)
        # |L| <= 1 at added frequencies (the crossover bound), |L| <= 0.95 at guards against
        # new crossovers
        lr, li = loop(p_wc[0, :].T, p_wc[1, :].T, p_wc[2, :].T)
        add(1 - (lr**2 + li**2), 0.0, math.inf)
        lr, li = loop(p_gd[0, :].T, p_gd[1, :].T, p_gd[2, :].T)
        add(_GUARD_GAIN**2 - (lr**2 + li**2), 0.0, math.inf)
        if xcs or x180s:
            f_ln = ca.interpolant("ln_g", "bspline", [lw], np.log(np.abs(ctx.g) + 1e-300))
            f_ph = ca.interpolant("ph_g", "bspline", [lw], ctx.ph)

            def at(x: Any) -> tuple[Any, Any]:
                ci = -ki * 0.5 * t / ca.tan(0.5 * t * ca.exp(x))
                return f_ln(x) + 0.5 * ca.log(cr**2 + ci**2), f_ph(x) + ca.atan2(ci, cr)

        self.lbx, self.ubx = [0.0, 1e-9], [math.inf, math.inf]
        self.x0 = [1.0, 1.0]
        self.inner: list[tuple[int, float, float]] = []  # variable, inner bracket bounds
        k = 2
        for c in xcs:  # PM = (phase − branch) − π, python-control's convention
            ln_c, ph_c = at(v[k])
            add(ln_c, 0.0, 0.0)
            add(ph_c - c.level - math.pi - p_t[0], 0.0, math.inf)
            add(ph_c - c.level - 2 * math.pi, -math.inf, 0.0)  # PM < 180°: no wrap
            self._bound(k, c, hi_cap=top)
            k += 1
        for c in x180s:
            ln_p, ph_p = at(v[k])
            add(ph_p - c.level, 0.0, 0.0)
            add(-ln_p - p_t[1], 0.0, math.inf)
            self._bound(k, c)
            k += 1
        self.lbg, self.ubg = lbg, ubg
        params = ca.vertcat(p_t, ca.vec(p_ms), ca.vec(p_wc), ca.vec(p_gd))
        nlp = {"x": v, "p": params, "f": -v[1], "g": ca.vertcat(*g) if g else ca.SX(0, 1)}
        opts = {
            "print_time": False,
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "ipopt.tol": 1e-10,
            "ipopt.constr_viol_tol": 1e-10,
            "ipopt.max_iter": 100,
        }
        self.solver = ca.nlpsol("tune_pi", "ipopt", nlp, opts)

    @staticmethod
    def structure_of(ctx: _Ctx, spec: _Spec, kp: float, ki: float) -> tuple[int, tuple]:
        """What the NLP models of a loop: the number of gain crossovers, the phase levels."""
        xcs, x180s = _modelled(ctx, spec, kp, ki)
        return len(xcs), tuple(c.level for c in x180s)

    def _bound(self, k: int, c: _Crossing, hi_cap: float = math.inf) -> None:
        lw = np.log(self.ctx.w)
        hi = min(c.hi, hi_cap)
        lo = min(c.lo, hi - 1e-9)
        self.lbx.append(lo)
        self.ubx.append(hi)
        self.x0.append(min(max(c.x, lo), hi))
        self.inner.append((k, lo if lo > lw[0] else -math.inf, hi if c.hi < lw[-1] else math.inf))

    def _slots(self, w: np.ndarray, n: int) -> np.ndarray:
        """Parameter values for ``n`` slots: the last ``n`` frequencies of ``w``."""
        out = np.zeros((3, n))  # an empty slot has G = 0: a constraint that always holds
        w = np.asarray(w, dtype=float)[-n:]
        if w.size:
            ctx = self.ctx
            gw = ctx.resp(w)
            out[:, : w.size] = [gw.real, gw.imag, _q_im(w, ctx.period_s)]
        return out

    def solve(
        self,
        x0: np.ndarray | None,
        *,
        pm_deg: float,
        gm_db: float,
        ms: float,
        ms_w: np.ndarray,
        wc_w: np.ndarray,
        guard_w: np.ndarray,
    ) -> _NlpResult:
        """Solve from ``x0`` (a previous solution; None: the build point)."""
        p = np.concatenate(
            [
                [math.radians(pm_deg), gm_db / 20 * math.log(10), ms**2],
                self._slots(ms_w, _N_EXTRA_MS).ravel(order="F"),
                self._slots(wc_w, _N_EXTRA_WC).ravel(order="F"),
                self._slots(guard_w, _N_EXTRA_WC).ravel(order="F"),
            ]
        )
        x_start = self.x0 if x0 is None else x0
        sol = self.solver(x0=x_start, p=p, lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg)
        stats = self.solver.stats()
        xs = np.asarray(sol["x"]).ravel()
        status = str(stats.get("return_status", "unknown"))
        ok = bool(stats.get("success", False)) or status == "Solved_To_Acceptable_Level"
        on_bracket = any(
            abs(xs[k] - lo) < 1e-6 or abs(xs[k] - hi) < 1e-6 for k, lo, hi in self.inner
        )
        return _NlpResult(
            kp=max(0.0, float(xs[0] * self.kp0)),
            ki=max(0.0, float(xs[1] * self.ki0)),
            x=xs,
            status=status,
            iterations=int(stats.get("iter_count", 0)),
            success=ok,
            on_bracket=on_bracket,
        )


class _Check(NamedTuple):
    pm_deg: float
    wgc: float
    wc_top: float
    gm_db: float
    wpc: float
    ms: float
    w_ms: float
    ms_peaks: np.ndarray
    rho: float
    wgcs: np.ndarray = np.empty(0)  # every gain crossover [rad/s]
    l_peaks: np.ndarray = np.empty(0)  # refined local maxima of |L| above 1 [rad/s]
    w: np.ndarray = np.empty(0)  # the grid used, refined extrema included [rad/s]


def _refine_grid(
    loop_at: Callable[[np.ndarray], np.ndarray], w: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``w`` plus the refined local extrema of ``|L|`` near 1 and of its phase near an odd
    multiple of 180°, so that no pair of crossings hides between two grid points; and the
    refined local maxima where ``|L| > 1``."""
    lw = loop_at(w)
    lnm = np.log(np.abs(lw) + 1e-300)
    ph = np.unwrap(np.angle(lw))
    near_pi = np.abs(np.remainder(ph, 2 * math.pi) - math.pi) < 0.3
    found, peaks = [], []
    for f, sel, sign, phase in (
        (lnm, lnm > math.log(0.8), 1.0, False),  # maxima of |L|
        (-lnm, lnm < math.log(1.25), -1.0, False),  # minima of |L|
        (ph, near_pi, 1.0, True),  # maxima and minima of the phase
        (-ph, near_pi, -1.0, True),
    ):
        idx = np.flatnonzero((f[1:-1] > f[:-2]) & (f[1:-1] >= f[2:]) & sel[1:-1])[:20] + 1
        for j in idx:

            def neg(x: float, ref: complex = lw[j], sign: float = sign, phase: bool = phase):
                v = loop_at(np.array([x]))[0]
                return -sign * (float(np.angle(v / ref)) if phase else math.log(abs(v) + 1e-300))

            r = minimize_scalar(neg, bounds=(w[j - 1], w[j + 1]), method="bounded")
            found.append(r.x)
            if sign > 0 and not phase and -r.fun > 0.0:
                peaks.append(r.x)
    return np.union1d(w, found), np.asarray(peaks)


def _select(pms: np.ndarray, wgcs: np.ndarray, gms: np.ndarray, wpcs: np.ndarray) -> tuple:
    """python-control's choice among crossings: the smallest ``|PM|``, the GM nearest 0 dB."""
    if pms.size:
        i = int(np.argmin(np.abs(pms)))
        pm, wgc, wc_top = float(pms[i]), float(wgcs[i]), float(np.max(wgcs))
    else:
        pm, wgc, wc_top = math.inf, math.nan, math.nan
    if gms.size and not np.all(np.isinf(gms)):
        with np.errstate(divide="ignore"):
            i = int(np.argmin(np.abs(np.log(gms))))
        gm_db = 20 * math.log10(gms[i]) if gms[i] > 0 else -math.inf
        wpc = float(wpcs[i])
    else:
        gm_db, wpc = math.inf, math.nan
    return pm, wgc, wc_top, gm_db, wpc


def _sensitivity_peak(
    loop_at: Callable[[np.ndarray], np.ndarray], w: np.ndarray, lw: np.ndarray
) -> tuple[float, float, np.ndarray]:
    """Peak of ``|1/(1 + L)|``: the grid's four largest local maxima, refined in between their
    neighbours on the exact loop. Returns the peak, its frequency and the refined maxima."""
    s_abs = 1.0 / np.abs(1.0 + lw)
    pad = np.concatenate([[-1.0], s_abs, [-1.0]])
    peaks = np.flatnonzero((s_abs >= pad[:-2]) & (s_abs >= pad[2:]))
    peaks = peaks[np.argsort(-s_abs[peaks])][:4]
    best_ms, best_w, found = -1.0, math.nan, []
    for i in peaks:
        lo, hi = w[max(i - 1, 0)], w[min(i + 1, w.size - 1)]

        def neg_s(x: float) -> float:
            return -1.0 / abs(1.0 + loop_at(np.array([x]))[0])

        r = minimize_scalar(neg_s, bounds=(lo, hi), method="bounded", options={"xatol": 1e-9 * hi})
        ms_i, w_i = (-r.fun, r.x) if -r.fun > s_abs[i] else (s_abs[i], w[i])
        found.append(w_i)
        if ms_i > best_ms:
            best_ms, best_w = ms_i, w_i
    return float(best_ms), float(best_w), np.asarray(found)


def _new_peaks(nlp: _Nlp, res: _NlpResult, chk: _Check) -> np.ndarray:
    """Where ``|L|`` peaks above 1 above the NLP's top modelled gain crossover, for a solution
    that has more gain crossovers than the NLP models (empty if none)."""
    n_pm = nlp.structure[0]
    if n_pm == 0 or chk.wgcs.size <= n_pm:
        return np.empty(0)
    top = math.exp(res.x[2 + n_pm - 1]) * 1.02
    return chk.l_peaks[chk.l_peaks > top]


def _sens(ctx: _Ctx, kp: float, ki: float, w: np.ndarray) -> np.ndarray:
    """``1/(1 + L)`` at ``w``."""
    t = ctx.period_s
    gw = ctx.resp(w)
    return 1.0 / (1.0 + (kp + ki * (0.5 * t + 1j * _q_im(w, t))) * gw)


def _fast_check(ctx: _Ctx, kp: float, ki: float, w: np.ndarray) -> _Check:
    """The re-check's numbers computed directly (used between the refinement rounds).

    Crossings are bracketed on ``w`` and solved on the exact loop with brentq, as
    python-control's FRD method does on its interpolant; stability from the closed-loop
    matrix's eigenvalues.
    """
    t = ctx.period_s

    def loop_at(om: np.ndarray) -> np.ndarray:
        gw = ctx.resp(om)
        return (kp + ki * (0.5 * t + 1j * _q_im(om, t))) * gw

    w, l_peaks = _refine_grid(loop_at, w)
    lw = loop_at(w)
    mod = np.abs(lw) - 1.0
    i = np.flatnonzero(np.diff(np.sign(mod)))
    wgcs = np.array(
        [brentq(lambda x: abs(loop_at(np.array([x]))[0]) - 1.0, w[j], w[j + 1]) for j in i]
    )
    pms = np.remainder(np.angle(loop_at(wgcs), deg=True), 360.0) - 180.0 if i.size else wgcs
    arg = np.angle(-lw)
    i = np.flatnonzero(np.diff(np.sign(arg)))
    i = i[lw[i].real <= 0]
    wpcs = np.array(
        [brentq(lambda x: float(np.angle(-loop_at(np.array([x]))[0])), w[j], w[j + 1]) for j in i]
    )
    with np.errstate(divide="ignore"):
        gms = 1.0 / np.abs(loop_at(wpcs)) if i.size else wpcs
    pm, wgc, wc_top, gm_db, wpc = _select(pms, wgcs, gms, wpcs)
    ms, w_ms, found = _sensitivity_peak(loop_at, w, lw)
    rho = float(_spectral_radius(ctx, np.array([kp]), np.array([ki]))[0])
    return _Check(pm, wgc, wc_top, float(gm_db), wpc, ms, w_ms, found, rho, wgcs, l_peaks, w)


def _python_control_check(
    p_scaled: control.StateSpace, kp: float, ki: float, w: np.ndarray
) -> _Check:
    """Margins, peak sensitivity and closed-loop poles of the discrete loop, by python-control.

    ``control.stability_margins`` runs on the loop's ``control.frequency_response`` over ``w``
    (python-control's interpolating FRD method: its polynomial method is ill-conditioned for
    short periods); its choice among several crossovers is python-control's (smallest
    ``|PM|``, gain margin closest to 0 dB). The sensitivity peak is the largest of
    ``|1/(1 + L)|`` on that response, refined between grid neighbours on the loop's
    state-space model; the poles are those of ``control.feedback(L, 1)``.
    """
    import control

    t = p_scaled.dt
    ctrl = control.ss([[1.0]], [[ki * t]], [[1.0]], [[kp + ki * t]], dt=t)
    loop = control.series(ctrl, p_scaled)
    w_top = math.pi / t
    while w_top * t > math.pi:  # the Nyquist frequency, rounded so python-control accepts it
        w_top = np.nextafter(w_top, 0.0)
    w = np.unique(np.minimum(w, w_top))
    lw = control.frequency_response(loop, w).complex.ravel()
    frd = control.FRD(lw, w, smooth=True, dt=t)
    gms, pms, _sms, wpcs, wgcs, _wss = control.stability_margins(frd, returnall=True)
    pm, wgc, wc_top, gm_db, wpc = _select(
        *(np.atleast_1d(np.asarray(v, dtype=float)) for v in (pms, wgcs, gms, wpcs))
    )
    a_l, b_l = np.asarray(loop.A, dtype=float), np.asarray(loop.B, dtype=float)
    c_l, d_l = np.asarray(loop.C, dtype=float), float(np.asarray(loop.D)[0, 0])

    def loop_at(om: np.ndarray) -> np.ndarray:
        return _ss_response(a_l, b_l, c_l, d_l, np.exp(1j * om * t))

    ms, w_ms, found = _sensitivity_peak(loop_at, w, lw)
    rho = float(np.max(np.abs(control.feedback(loop, 1).poles())))
    return _Check(pm, wgc, wc_top, float(gm_db), wpc, ms, w_ms, found, rho)


def _violations(chk: _Check, spec: _Spec) -> dict[str, float]:
    """How far each target is missed, in its unit (deg, dB, relative, relative); > 0: missed."""
    out = {}
    if not chk.rho < 1.0:
        out["stability"] = chk.rho - 1.0
    if spec.pm_deg is not None:
        out["phase_margin_deg"] = spec.pm_deg - chk.pm_deg if not math.isnan(chk.pm_deg) else 90.0
    if spec.gm_db is not None:
        out["gain_margin_db"] = spec.gm_db - chk.gm_db if not math.isnan(chk.gm_db) else 90.0
    if spec.ms is not None:
        out["max_sensitivity"] = chk.ms / spec.ms - 1.0
    if spec.wc_max is not None:
        out["crossover_rad_s"] = (
            (chk.wc_top / spec.wc_max - 1.0) if math.isfinite(chk.wc_top) else 0.0
        )
    return out


def _acceptable(viol: dict[str, float], strict: bool = False) -> bool:
    """Targets met within the reporting tolerances, or (``strict``) the refinement's."""
    if "stability" in viol:
        return False
    tol = {
        "phase_margin_deg": 0.0 if strict else _TOL_PM_DEG,
        "gain_margin_db": 0.0 if strict else _TOL_GM_DB,
        "max_sensitivity": 0.0 if strict else _TOL_MS_REL,
        "crossover_rad_s": 0.0 if strict else _TOL_WC_REL,
    }
    return all(viol[k] <= tol[k] for k in viol)


def tune_pi(
    plant: Plant | control.TransferFunction,
    *,
    period_s: float,
    phase_margin_deg: float | None = None,
    gain_margin_db: float | None = None,
    max_sensitivity: float | None = None,
    crossover_rad_s: float | None = None,
    compute_s: float = 0.0,
    lsb_v: float | None = None,
) -> PITuning:
    """PI gains with the largest integral gain Ki that meet the robustness targets.

    The controller is the runtime's (:mod:`servotune.laws.pi`), ``C(z) = Kp + Ki·T·z/(z−1)``,
    and the loop ``L(z) = C(z) · lsb_v · P(z)`` is exact in discrete time: ``P`` is the plant
    discretised with a zero-order hold at ``period_s`` and its input lagged by ``compute_s``
    (plus ``delay_s`` for a :class:`~servotune.plant.Plant`): :func:`~servotune.plant.discretize`
    or :func:`~servotune.plant.discretize_lti`.

    Formulation (a constrained NLP solved by casadi/ipopt): maximise Ki over ``Kp >= 0``,
    ``Ki > 0`` and, as extra variables, the frequency ``ωc`` of every gain crossover (if a
    phase margin is asked) and ``ωp`` of every phase crossover (if a gain margin is asked),
    subject to

    - phase margin, at each ``ωc``: ``|L(ωc)| = 1`` and ``arg L(ωc) + 180° >= phase_margin_deg``
      (the phase taken on its branch, as python-control's margin);
    - gain margin, at each ``ωp``: ``arg L(ωp) = −180°`` (or −540°, ...) and
      ``−20·log10|L(ωp)| >= gain_margin_db``;
    - sensitivity: ``|1 + L(ω)| >= 1/max_sensitivity`` at every design-grid frequency;
    - crossover bound: ``|L(ω)| <= 1`` at ``crossover_rad_s`` and every grid frequency above it
      (and ``ωc <= crossover_rad_s``).

    ``L`` is linear in (Kp, Ki): the plant's response is computed once with numpy on the
    design grid and enters as constants; at the crossover variables it enters through cubic
    splines of its log-magnitude and unwrapped phase on that grid. The design grid is
    log-spaced, :data:`POINTS_PER_DECADE` per decade, from :data:`DECADES_BELOW` decades below
    the slowest plant pole/zero (``1/tau_s`` for a Plant) to the Nyquist frequency ``π/T``
    included, plus a linear grid fine enough that the lag turns the phase by at most 0.2 rad
    per step, plus 129 points around each lightly damped pole (ζ < 0.2). Each crossover
    variable is kept between its neighbours'; the start point is the best design on the
    phase-margin loci (for each grid ω, the (Kp, Ki) that put ``L`` at the margin there),
    checked against all targets on the grid and for stability.

    Re-check and refinement: every NLP solution is checked on a verification grid (the design
    grid's midpoints, plus the refined extrema of ``|L|`` near 1 and of its phase near −180°,
    so that no pair of crossings hides between points) with crossings solved on the exact
    loop. A target missed between grid points is refined by an exchange step (the missed
    sensitivity peak's frequencies added as constraints, or the target tightened by the miss)
    and the NLP solved again; if the solution has a gain crossover above those modelled and
    misses a target, ``|L| <= 0.95`` is imposed at that peak of ``|L|`` (a design with a new
    crossover there is not searched); if crossovers otherwise appear or vanish, the NLP is
    rebuilt around the new loop. The start point stays a candidate. The final design is
    re-checked
    with python-control, and every reported number is python-control's: margins from
    ``control.stability_margins`` on the loop's ``control.frequency_response`` (its FRD
    method; its polynomial method is ill-conditioned for short periods), the sensitivity peak
    over that response (refined between neighbours), stability from the poles of
    ``control.feedback(L, 1)``. Targets are then met exactly up to the NLP's tolerances
    (about 1e-6° and 1e-7 relative) or, after eight solves, within 0.5° / 0.1 dB / 1 % / 1 %
    (reported as found); a larger miss, or an unstable loop, raises
    :class:`~servotune.errors.SpecError`.

    A phase margin below 90° is always reachable with small enough gains on a stable plant,
    a plant with an integrator included (Ki then becomes small: ``phase_margin_deg=89`` on the
    example rig gives Ki ≈ 2e-5 codes/(count·s)); a spec is impossible when no PI with
    ``Kp, Ki >= 0`` stabilises the plant while meeting it.

    Parameters
    ----------
    plant : Plant or control.TransferFunction
        Axis model (volts → counts, lag ``delay_s`` included), any continuous SISO system, or
        a SISO system already discrete at ``period_s`` (e.g. a closed inner loop; then
        ``compute_s`` must be whole periods and acts as ``z^-m``).
    period_s : float
        Sample period [s]: for a rig, the achieved timer period.
    phase_margin_deg : float, optional
        Lower bound on the phase margin [deg], in (0, 90).
    gain_margin_db : float, optional
        Lower bound on the gain margin [dB], > 0.
    max_sensitivity : float, optional
        Upper bound on ``max |1/(1 + L)|`` [-], > 1.
    crossover_rad_s : float, optional
        Upper bound on the gain crossover frequency [rad/s], below ``π/period_s``.
    compute_s : float
        Sample instant → output write [s], >= 0 (the loop's computation lag).
    lsb_v : float, optional
        Output units per controller unit. Default: the 12-bit ±10 V D/A step 20/4096 V for a
        :class:`~servotune.plant.Plant` (gains in D/A codes), 1.0 for a transfer function.

    Returns
    -------
    PITuning
        Gains [codes/count], [codes/(count·s)] and the loop's margins.

    Raises
    ------
    SpecError
        If no target (phase, gain margin or sensitivity) is given, a target is out of range,
        or no stabilising PI with ``Kp >= 0, Ki > 0`` meets the targets.
    ValueError
        If ``period_s``, ``compute_s``, ``lsb_v`` or ``plant`` are invalid.

    Examples
    --------
    >>> import control
    >>> r = tune_pi(control.tf([1], [1, 3, 3, 1]), period_s=0.001, phase_margin_deg=60)
    >>> round(r.phase_margin_deg, 1), round(r.ki, 2)
    (60.0, 0.45)
    """
    if lsb_v is None:
        lsb_v = hw_dac.lsb_v() if isinstance(plant, Plant) else 1.0
    spec = _check_spec(
        period_s,
        compute_s,
        lsb_v,
        phase_margin_deg,
        gain_margin_db,
        max_sensitivity,
        crossover_rad_s,
    )
    discretiser, lag, feature = _plant_model(plant, period_s, compute_s)
    p_scaled = lsb_v * discretiser(lag)
    a = np.asarray(p_scaled.A, dtype=float)
    b = np.asarray(p_scaled.B, dtype=float)
    c = np.asarray(p_scaled.C, dtype=float)
    d = float(np.asarray(p_scaled.D, dtype=float)[0, 0])
    # responses: the whole ticks of lag are a pure shift z^-m, the rest a small model
    m_ticks, lam = lag_split(lag, period_s)
    p_frac = lsb_v * discretiser(lam)
    mats = [np.asarray(x, dtype=float) for x in (p_frac.A, p_frac.B, p_frac.C)]
    d_frac = float(np.asarray(p_frac.D, dtype=float)[0, 0])

    def resp(om: np.ndarray) -> np.ndarray:
        z = np.exp(1j * np.asarray(om, dtype=float) * period_s)
        return _ss_response(*mats, d_frac, z) * z ** (-m_ticks)

    nyq = math.pi / period_s
    w_lo = min(feature, nyq, spec.wc_max or math.inf) * 10.0**-DECADES_BELOW
    w = _grid(w_lo, nyq, lag + period_s, np.linalg.eigvals(mats[0]))
    g = resp(w)
    if not np.all(np.isfinite(g)):
        raise SpecError("the discrete plant has a pole on the unit circle away from z = 1")
    ctx = _Ctx(period_s, a, b, c, d, resp, w, g, _unwrapped_phase(g), _q_im(w, period_s))
    w_check = _check_grid(w)
    where = f"on this plant at period_s={period_s:g} s, compute_s={compute_s:g} s"

    start = _start_point(ctx, spec)
    if start is None:
        raise InfeasibleError(
            f"no stabilising PI with kp >= 0, ki > 0 meets {spec.describe()} {where}"
        )
    # the NLP aims a hair inside the targets, so that the re-check finds them met
    pm_t = spec.pm_deg + 1e-6 if spec.pm_deg is not None else 0.0
    gm_t = spec.gm_db + 1e-6 if spec.gm_db is not None else 0.0
    ms_t = spec.ms * (1 - 1e-7) if spec.ms is not None else 2.0
    ms_w, guard_w = np.empty(0), np.empty(0)
    wc_w = np.array([spec.wc_max * (1 - 1e-7)]) if spec.wc_max is not None else np.empty(0)
    iterations, builds = 0, 0
    designs: list[tuple[float, float, str, bool]] = []  # acceptable: kp, ki, status, strictly
    nlp = _Nlp(ctx, spec, start)
    x0: np.ndarray | None = None
    for _ in range(_REFINE_ROUNDS):
        res = nlp.solve(x0, pm_deg=pm_t, gm_db=gm_t, ms=ms_t, ms_w=ms_w, wc_w=wc_w, guard_w=guard_w)
        iterations += res.iterations
        if not (res.success and res.ki > 0):
            break
        chk = _fast_check(ctx, res.kp, res.ki, w_check)
        viol = _violations(chk, spec)
        strict = _acceptable(viol, strict=True)
        if _acceptable(viol):
            designs.append((res.kp, res.ki, res.status, strict))
        guards = np.empty(0) if strict else _new_peaks(nlp, res, chk)
        if guards.size:
            # the NLP went to a loop with new crossovers above the ones it models, and that
            # loop misses a target: keep |L| <= 1 there, and solve again as before
            guard_w = np.append(guard_w, np.outer(guards, _PEAK_STENCIL))
            continue
        structure = _Nlp.structure_of(ctx, spec, res.kp, res.ki)
        if res.on_bracket or structure != nlp.structure:
            if builds >= _MAX_BUILDS:
                break
            nlp, x0, builds = _Nlp(ctx, spec, (res.kp, res.ki)), None, builds + 1
            continue  # a crossing appeared, vanished or left its bracket: model it again
        if strict:
            break
        # exchange: add the frequencies where a target was missed between grid points
        x0 = res.x
        if viol.get("max_sensitivity", 0.0) > 0:
            hot = chk.ms_peaks[np.abs(_sens(ctx, res.kp, res.ki, chk.ms_peaks)) > ms_t]
            if ms_w.size:  # peaks were added already, yet the peak moved: tighten as well
                ms_t /= 1.0 + viol["max_sensitivity"] + 1e-7
            ms_w = np.append(ms_w, np.outer(hot, _PEAK_STENCIL))
        if viol.get("crossover_rad_s", 0.0) > 0:
            wc_w = np.append(wc_w, chk.wc_top)
        if viol.get("phase_margin_deg", 0.0) > 0:
            pm_t = min(89.99, pm_t + viol["phase_margin_deg"] + 1e-6)
        if viol.get("gain_margin_db", 0.0) > 0:
            gm_t += viol["gain_margin_db"] + 1e-6
    viol = _violations(_fast_check(ctx, *start, w_check), spec)
    designs.append((*start, "start point", _acceptable(viol, strict=True)))
    # the re-check by python-control decides: designs that meet the targets, the largest Ki
    # first, then those within the tolerances, the last refined first
    tried = sorted((d for d in designs if d[3]), key=lambda d: -d[1])
    tried += [d for d in designs[::-1] if not d[3]]
    for design in tried:
        w_design = _fast_check(ctx, design[0], design[1], w_check).w
        chk = _python_control_check(p_scaled, design[0], design[1], w_design)
        viol = _violations(chk, spec)
        if _acceptable(viol):
            break
    else:
        worst = max(viol, key=lambda k: viol[k])
        raise SpecError(
            f"cannot meet {spec.describe()} {where} with a PI (kp >= 0, ki > 0): "
            f"the best design found misses {worst}"
        )
    kp, ki, status, _ = design
    viol = _violations(chk, spec)
    binding_tol = {
        "phase_margin_deg": -0.05,
        "gain_margin_db": -0.05,
        "max_sensitivity": -2e-3,
        "crossover_rad_s": -2e-3,
    }
    binding = tuple(k for k, v in viol.items() if k in binding_tol and v >= binding_tol[k])
    return PITuning(
        kp=kp,
        ki=ki,
        period_s=float(period_s),
        compute_s=float(compute_s),
        lsb_v=float(lsb_v),
        crossover_rad_s=chk.wgc,
        phase_margin_deg=chk.pm_deg,
        gain_margin_db=chk.gm_db,
        phase_crossover_rad_s=chk.wpc,
        max_sensitivity=chk.ms,
        sensitivity_peak_rad_s=chk.w_ms,
        spectral_radius=chk.rho,
        target_phase_margin_deg=spec.pm_deg,
        target_gain_margin_db=spec.gm_db,
        target_max_sensitivity=spec.ms,
        target_crossover_rad_s=spec.wc_max,
        binding=binding,
        solver_status=status,
        solver_iterations=iterations,
    )


def tune_pi_axis(rig: Rig, axis_name: str, **targets: float | None) -> PITuning:
    """:func:`tune_pi` for one axis of a rig, at the rig's achieved period and compute lag.

    ``period_s`` is ``rig.period_s`` (the achieved timer period), ``compute_s`` is
    ``rig.timer.compute_s`` and ``lsb_v`` is ``rig.dac.lsb_v``, so the gains are in D/A codes
    per count as the runtime uses them.

    Parameters
    ----------
    rig : Rig
    axis_name : str
        Name of the axis (``rig.axis_names``).
    **targets : float
        ``phase_margin_deg``, ``gain_margin_db``, ``max_sensitivity``, ``crossover_rad_s``.

    Returns
    -------
    PITuning

    Raises
    ------
    RigError
        If the rig has no such axis.
    SpecError
        As :func:`tune_pi`, or if a target is not one of the four names.
    """
    allowed = {"phase_margin_deg", "gain_margin_db", "max_sensitivity", "crossover_rad_s"}
    unknown = sorted(set(targets) - allowed)
    if unknown:
        raise SpecError(
            f"tune_pi_axis takes only the targets {', '.join(sorted(allowed))}; got "
            f"{', '.join(unknown)} (period_s, compute_s and lsb_v come from the rig)"
        )
    axis = rig.axis(axis_name)
    return tune_pi(
        axis.plant,
        period_s=rig.period_s,
        compute_s=rig.timer.compute_s,
        lsb_v=rig.dac.lsb_v,
        **targets,  # type: ignore[arg-type]
    )
