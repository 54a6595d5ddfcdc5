"""Estimating on part of a log and predicting the rest (:mod:`servotune.identify.fitting`'s
steps 3, 4 and 6): the estimator of each method on given samples, the simulation of a fitted
model from a command, split-half cross-validation, and the held-out check that can overrule
BIC's choice of structure."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from servotune.identify import iv, model, oe, quality
from servotune.identify.noise import NoiseModel

__all__ = [
    "HELD_OUT_MARGIN_PCT",
    "cross_validate",
    "estimate",
    "fit_pcts",
    "held_out_check",
    "held_out_pct",
    "simulate_dy",
    "skip_samples",
    "validation_split",
]


def validation_split(n_samples: int) -> int:
    """First sample of the second half of a log of ``n_samples`` (split-half validation)."""
    return n_samples // 2


def skip_samples(x: np.ndarray, period_s: float, n: int) -> int:
    """Start samples left out (at most a tenth of the log).

    The model's initial transient (five time constants, at least 50 samples), and twice the
    projection's FIR length: before the FIR has seen the excitation's past, the projected
    command (and so the instruments) is wrong, and those samples weigh heavily.
    """
    start = max(50, math.ceil(5.0 * x[1] / period_s), 2 * iv.projection_lags(period_s))
    return int(min(start, max(1, n // 10)))


def estimate(
    method: str,
    u1: np.ndarray,
    dy: np.ndarray,
    sigs: list[np.ndarray],
    x0: np.ndarray,
    free: np.ndarray,
    *,
    period_s: float,
    compute_s: float,
    skip: int,
    projection: iv.Projection | None = None,
    noise0: NoiseModel | None = None,
    max_nfev: int = 60,
    max_outer: int = 4,
    refit_noise: bool = True,
) -> tuple[model.Estimate, dict[str, Any]]:
    if method.startswith("iv"):  # iv: refined, else basic; iv-refined, iv-basic: only that
        kw = {
            "period_s": period_s,
            "compute_s": compute_s,
            "skip": skip,
            "projection": projection,
            "noise0": noise0,
            "max_outer": max_outer,
            "refit_noise": refit_noise,
        }
        try:
            if method == "iv-basic":
                raise iv.NotConverged("basic IV asked for")
            r = iv.estimate_iv(u1, dy, sigs, x0, free, **kw)
        except iv.NotConverged:  # refined IV did not settle: basic IV (raises if it neither)
            if method == "iv-refined":
                raise
            r = iv.estimate_iv(u1, dy, sigs, x0, free, prefilter=False, **kw)
        info = {
            "converged": r.converged,
            "iterations": r.iterations,
            "lags": r.projection.lags,
            "r2": r.projection.r2,
            "prefilter": r.prefilter,
        }
        return r, info
    f = oe.estimate_oe(
        u1,
        dy,
        x0,
        free,
        period_s=period_s,
        compute_s=compute_s,
        skip=skip,
        max_nfev=max_nfev,
        noise0=noise0,
        refit_noise=refit_noise,
    )
    return f, {"nfev": f.nfev}


HELD_OUT_MARGIN_PCT = 2.0
"""How much better [percentage points of velocity fit] the largest structure must predict
held-out samples than BIC's choice to overrule it (:func:`held_out_check`)."""


def held_out_check(
    best: dict[str, Any],
    scored: list[dict[str, Any]],
    reason: str,
    variant: str,
    u: np.ndarray,
    dy: np.ndarray,
    sigs: list[np.ndarray],
    n_s: int,
    noise0: NoiseModel | None,
    x_start: np.ndarray,
    *,
    period_s: float,
    compute_s: float,
) -> tuple[dict[str, Any], str]:
    """BIC's choice, unless the largest structure predicts held-out samples clearly better.

    BIC judges a structure by the method's own residual; on a real drive whose friction the
    noise model half absorbs, it can keep a structure without friction that simulates the
    axis far worse (the EMPS drive: 72–80 % velocity fit on the other log against 93–94 %).
    (There refined IV found no solution for the structures with friction, which so could not
    win.) Both are estimated on each half of the selection's samples, by refined IV where it
    settles and basic IV where not, and simulated on the other half (:func:`held_out_pct`);
    the largest wins when it is better by more than :data:`HELD_OUT_MARGIN_PCT`. Each gets
    ``held_out_velocity_fit_pct`` in the selection.
    """
    full = max(scored, key=lambda e: int(e["_free"].sum()))
    if full is best:
        return best, reason
    variant = "iv" if variant.startswith("iv") else variant  # refined, else basic, for both
    for e in (best, full):
        e["held_out_velocity_fit_pct"] = held_out_pct(
            variant,
            u,
            dy,
            sigs,
            (e["_x"], np.where(e["_free"], x_start, 0.0)),
            e["_free"],
            n_s,
            noise0,
            period_s=period_s,
            compute_s=compute_s,
        )
    got, kept = full["held_out_velocity_fit_pct"], best["held_out_velocity_fit_pct"]
    if not got > kept + HELD_OUT_MARGIN_PCT:
        return best, reason
    return full, (
        f"{'+'.join(full['params'])}: it predicts held-out samples at {got:.1f} % velocity fit "
        f"against {kept:.1f} % for {'+'.join(best['params'])}, BIC's choice ({reason})"
    )


def held_out_pct(
    variant: str,
    u: np.ndarray,
    dy: np.ndarray,
    sigs: list[np.ndarray],
    starts: tuple[np.ndarray, ...],
    free: np.ndarray,
    n_s: int,
    noise0: NoiseModel | None,
    *,
    period_s: float,
    compute_s: float,
) -> float:
    """Two-fold held-out velocity fit % of a structure on the first ``n_s`` samples: the quick
    estimate of each half (from the first of ``starts`` it settles from), simulated on the other
    half from that half's own first speed; the mean of both ways (−inf where no start gives an
    estimate)."""
    h = n_s // 2
    pcts = []
    for (a, b), (c, d) in (((0, h), (h, n_s)), ((h, n_s), (0, h))):
        sg = [s[a:b] for s in sigs]
        proj = None
        if variant.startswith("iv"):
            proj = iv.project(u[a:b], sg, iv.projection_lags(period_s))
        for x0 in starts:
            try:
                est, _ = estimate(
                    variant,
                    u[a:b],
                    dy[a:b],
                    sg,
                    x0,
                    free,
                    period_s=period_s,
                    compute_s=compute_s,
                    skip=skip_samples(x0, period_s, b - a),
                    projection=proj,
                    noise0=noise0,
                    max_nfev=40,
                    max_outer=4,
                    refit_noise=noise0 is None,
                )
                dp = simulate_dy(u[c:d], dy[c:d], est.x, free, period_s, compute_s)
            except (iv.NotConverged, ValueError):
                continue
            pcts.append(quality.fit_pct(dy[c:d] / period_s, dp / period_s))
            break
        else:
            return -math.inf
    return float(np.mean(pcts))


def simulate_dy(
    u: np.ndarray,
    dy: np.ndarray,
    x: np.ndarray,
    free: np.ndarray,
    period_s: float,
    compute_s: float,
) -> np.ndarray:
    v0 = float(np.mean(dy[: max(1, min(5, dy.size))]) / period_s)
    return model.simulate_increments(
        np.asarray(u, dtype=float)[None, :],
        [x],
        free,
        [0],
        period_s=period_s,
        compute_s=compute_s,
        v0=v0,
    )[0]


def fit_pcts(y: np.ndarray, dy: np.ndarray, dp: np.ndarray, period_s: float) -> tuple[float, float]:
    pos = y[0] + np.concatenate([[0.0], np.cumsum(dp)])
    return (quality.fit_pct(dy / period_s, dp / period_s), quality.fit_pct(y.astype(float), pos))


def cross_validate(
    est: model.Estimate,
    u: np.ndarray,
    y: np.ndarray,
    free: np.ndarray,
    *,
    period_s: float,
    compute_s: float,
) -> tuple[list[np.ndarray], list[tuple[float, float]] | None]:
    """Split-half: each half's estimate, and its fit % (velocity, position) on the other half.

    Each half's estimate is the one-step estimate from the whole log's: one Gauss–Newton step
    of that half's own estimating equations (the terms ``est`` holds per sample, summed over
    that half only), ``θ_h = θ̂ + A_h⁻¹ Σ_{k∈h} s_k``. To first order it is the estimate the
    half alone gives — the other half enters only at second order, through the start — and it
    costs no simulation. The fit % is then the simulation of each half by the other half's
    model, from that half's own first position and speed.
    """
    n = y.size
    h = validation_split(n)
    first = (n - 1) - est.scores.shape[0]  # the increment index of the equations' first term
    split = min(max(h - first, 1), est.scores.shape[0] - 1)
    lo, hi = model.lower_bounds()[free], model.upper_bounds(period_s)[free]
    xs: list[np.ndarray] = []
    for sel in (slice(0, split), slice(split, None)):
        a_h = est.instruments[:, sel] @ est.sensitivities[:, sel].T
        try:
            step = np.linalg.solve(a_h, est.scores[sel].sum(axis=0))
        except np.linalg.LinAlgError:
            return [], None
        xh = est.x.copy()
        xh[free] = np.clip(est.x[free] + step, lo, hi)
        xs.append(xh)
    folds = []
    for i, (a, b) in enumerate(((0, h), (h, n))):
        ua, ya = u[a:b], y[a:b]
        dya = np.diff(ya).astype(float)
        try:
            dp = simulate_dy(ua[:-1], dya, xs[1 - i], free, period_s, compute_s)
        except ValueError:  # a one-step estimate outside what a plant can be
            return [], None
        folds.append(fit_pcts(ya, dya, dp, period_s))
    return xs, folds
