"""The frequency grid of :func:`~servotune.tune.pi.design.tune_pi`: the discrete plant model,
the design and verification grids, the batched grid margins and the start point on them."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from servotune.analysis.margins import controller_basis, grid_margins
from servotune.modal import discretize, discretize_lti
from servotune.plant import Plant
from servotune.tune.pi.spec import TOL_GM_DB, TOL_MS_REL, TOL_PM_DEG, TOL_WC_REL, Spec

if TYPE_CHECKING:  # python-control is imported where used (slow to import)
    import control

__all__ = ["DECADES_BELOW", "POINTS_PER_DECADE", "design_grid", "q_im"]

POINTS_PER_DECADE = 150
"""Design grid density: log-spaced frequencies per decade (see :func:`tune_pi`)."""
DECADES_BELOW = 3.0
"""The design grid starts this many decades below the slowest plant feature."""
_MAX_STABILITY_CHECKS = 64  # start-point candidates that pass the grid checks, at most
_MAX_LAG_PHASE_STEP = 0.2  # [rad]: grid step times the lag (the delay's phase per step)


class Ctx(NamedTuple):
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


def plant_model(
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
    """:func:`plant_model` for a plant already discrete at ``period_s`` (e.g. a closed inner
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


def design_grid(w_lo: float, nyq: float, lag_s: float, poles: np.ndarray) -> np.ndarray:
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


def check_grid(w: np.ndarray) -> np.ndarray:
    """Verification grid: the design grid's geometric midpoints, a decade of log grid below
    it, and the Nyquist frequency."""
    below = np.geomspace(w[0] / 10.0, w[0], POINTS_PER_DECADE + 1)[:-1]
    return np.concatenate([below, np.sqrt(w[:-1] * w[1:]), w[-1:]])


def ss_response(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: float, z: np.ndarray) -> np.ndarray:
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


def q_im(w: np.ndarray, period_s: float) -> np.ndarray:
    """Im of ``T·z/(z−1)`` at ``z = exp(jωT)``: ``−(T/2)·cot(ωT/2)`` (its real part is T/2)."""
    return -0.5 * period_s / np.tan(0.5 * w * period_s)


def spectral_radius(ctx: Ctx, kp: np.ndarray, ki: np.ndarray) -> np.ndarray:
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


def _grid_margins(ctx: Ctx, kp: np.ndarray, ki: np.ndarray) -> dict[str, np.ndarray]:
    """Grid estimates for a batch of (kp, ki): worst PM [rad], worst GM [ln], Ms, top crossover
    (:func:`servotune.analysis.margins.grid_margins` of the PI loops on the plant)."""
    gains = np.stack([kp, ki * ctx.period_s, np.zeros_like(kp)], axis=1)
    basis = controller_basis(ctx.w, ctx.period_s)
    m = grid_margins(ctx.w, gains, basis, ctx.g[None, :], ctx.ph[None, :])
    return {k: v[:, 0] for k, v in m.items()}


def _feasible(m: dict[str, np.ndarray], spec: Spec, slack: float) -> np.ndarray:
    ok = np.ones(m["ms"].shape, dtype=bool)
    if spec.pm_deg is not None:
        ok &= m["pm"] >= math.radians(spec.pm_deg) - slack * math.radians(TOL_PM_DEG)
    if spec.gm_db is not None:
        ok &= m["gm"] >= spec.gm_db / 20 * math.log(10) - slack * TOL_GM_DB / 20 * math.log(10)
    if spec.ms is not None:
        ok &= m["ms"] <= spec.ms * (1 + slack * TOL_MS_REL)
    if spec.wc_max is not None:
        ok &= m["wc_top"] <= spec.wc_max * (1 + slack * TOL_WC_REL)
    return ok


def start_point(ctx: Ctx, spec: Spec) -> tuple[float, float] | None:
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
            stable = batch[spectral_radius(ctx, kpc[batch], kic[batch]) < 1.0]
            if stable.size:
                return float(kpc[stable[0]]), float(kic[stable[0]])
        start += size
        size = min(2 * size, 2048)
    return None
