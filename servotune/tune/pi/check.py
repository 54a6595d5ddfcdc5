"""The re-checks of :func:`~servotune.tune.pi.design.tune_pi`'s designs: the fast direct check
between refinement rounds, the final python-control check, and the targets' violations."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from servotune.tune.pi.grid import Ctx, q_im, spectral_radius, ss_response
from servotune.tune.pi.nlp import Nlp, NlpResult
from servotune.tune.pi.spec import TOL_GM_DB, TOL_MS_REL, TOL_PM_DEG, TOL_WC_REL, Spec

if TYPE_CHECKING:  # python-control is imported where used (slow to import)
    import control

__all__ = ["acceptable", "violations"]


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


def new_peaks(nlp: Nlp, res: NlpResult, chk: _Check) -> np.ndarray:
    """Where ``|L|`` peaks above 1 above the NLP's top modelled gain crossover, for a solution
    that has more gain crossovers than the NLP models (empty if none)."""
    n_pm = nlp.structure[0]
    if n_pm == 0 or chk.wgcs.size <= n_pm:
        return np.empty(0)
    top = math.exp(res.x[2 + n_pm - 1]) * 1.02
    return chk.l_peaks[chk.l_peaks > top]


def sens(ctx: Ctx, kp: float, ki: float, w: np.ndarray) -> np.ndarray:
    """``1/(1 + L)`` at ``w``."""
    t = ctx.period_s
    gw = ctx.resp(w)
    return 1.0 / (1.0 + (kp + ki * (0.5 * t + 1j * q_im(w, t))) * gw)


def fast_check(ctx: Ctx, kp: float, ki: float, w: np.ndarray) -> _Check:
    """The re-check's numbers computed directly (used between the refinement rounds).

    Crossings are bracketed on ``w`` and solved on the exact loop with brentq, as
    python-control's FRD method does on its interpolant; stability from the closed-loop
    matrix's eigenvalues.
    """
    t = ctx.period_s

    def loop_at(om: np.ndarray) -> np.ndarray:
        gw = ctx.resp(om)
        return (kp + ki * (0.5 * t + 1j * q_im(om, t))) * gw

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
    rho = float(spectral_radius(ctx, np.array([kp]), np.array([ki]))[0])
    return _Check(pm, wgc, wc_top, float(gm_db), wpc, ms, w_ms, found, rho, wgcs, l_peaks, w)


def python_control_check(
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
        return ss_response(a_l, b_l, c_l, d_l, np.exp(1j * om * t))

    ms, w_ms, found = _sensitivity_peak(loop_at, w, lw)
    rho = float(np.max(np.abs(control.feedback(loop, 1).poles())))
    return _Check(pm, wgc, wc_top, float(gm_db), wpc, ms, w_ms, found, rho)


def violations(chk: _Check, spec: Spec) -> dict[str, float]:
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


def acceptable(viol: dict[str, float], strict: bool = False) -> bool:
    """Targets met within the reporting tolerances, or (``strict``) the refinement's."""
    if "stability" in viol:
        return False
    tol = {
        "phase_margin_deg": 0.0 if strict else TOL_PM_DEG,
        "gain_margin_db": 0.0 if strict else TOL_GM_DB,
        "max_sensitivity": 0.0 if strict else TOL_MS_REL,
        "crossover_rad_s": 0.0 if strict else TOL_WC_REL,
    }
    return all(viol[k] <= tol[k] for k in viol)
