"""Refined instrumental variables with instruments from the external signals (``--method iv``).

Why an instrumental-variable method. In closed loop the command ``u`` carries the controller's
reaction to the load disturbance, so the residual of any fit that regresses the motion on the
logged command (least squares, :mod:`servotune.identify.oe`) is correlated with its regressors
and the estimate is biased — by several per cent on the example rig with a coloured load, and no
amount of data removes it. A prediction-error method with a noise model is consistent in closed
loop only if the noise model is exactly right, and here the disturbance enters *before* the
friction nonlinearity, so no additive output-noise model is. An IV estimator needs neither: it
only needs instruments that are correlated with the model's sensitivities and independent of the
disturbance, and the log has them — the excitation the law adds (``exc_code``) and the reference
where it moves (task mode), which no disturbance reaches.

The estimator (a two-stage, "tailor-made" instrument construction, Gilson & Van den Hof,
Automatica 41, 2005; refined with the noise model's prefilter, Young, Automatica 12, 1976):

1. **Projection.** The command is projected on the external signals: ``û`` is the
   least-squares FIR prediction of ``u`` from the current and :func:`projection_lags` past
   samples of the excitation and of the reference increments (a constant too), solved through
   their correlations (Wiener–Hopf, FFT), so ``û`` is a function of the external signals only.
2. **Instruments.** ``Z = ∂ŷ(û; θ)/∂θ``: the sensitivities of the model simulated from ``û``
   — noise-free by construction, and close to the sensitivities ``J = ∂ŷ(u; θ)/∂θ`` of the model
   driven by the logged command.
3. **Estimating equations.** ``Σ_k (F z_k)·(F ε_k(θ)) = 0`` with ``ε(θ) = Δy − ŷ(u; θ)`` the
   output error of the model simulated from the *logged* command (so friction, saturation and
   the D/A act on the command the drive really saw) and ``F = A/C`` the whitening prefilter of
   the residual's ARMA noise model (:mod:`servotune.identify.noise`). Solved by Gauss–Newton
   with ``(ZᵀJ)`` as the Jacobian (gain and tau move by at most half per step), instruments and
   prefilter refreshed until a step's own sensitivities solve it. The sequences are filtered
   from the log's start and used only after the projection, the simulation and the filter have
   settled (a filter started from rest gives its first outputs a weight that can dwarf
   thousands of samples).
4. **Basic IV** (``prefilter=False``): where the refined iteration does not settle — on a real
   drive whose fast dynamics the model lacks, the prefilter's emphasis on the fast part can
   leave the equations without a nearby solution — the same equations unfiltered (``F = 1``)
   are solved instead: as consistent, less efficient. :func:`servotune.identify.fit_arrays`
   tries refined, then basic, then falls back to least squares with a warning.

Assumes: the excitation (and the reference, where used) is independent of the load disturbance
and of the measurement noise; the model structure (the axis model with the chosen terms) holds; the
disturbance acts additively on the drive input (then its effect on the increments is linear away
from speed reversals). Biased when: the logged excitation is not the one the drive received (a
clipped D/A hides it in ``u`` but not in ``exc_code``: harmless; an excitation computed from the
measured position: not an instrument), the structure misses a term, or the disturbance's effect
through Coulomb friction at speed reversals is large next to the excitation (second order in
``coulomb_v / excitation amplitude``). Weak instruments (an excitation that explains little of
the command) make it noisy, not biased; :func:`servotune.identify.fit_arrays` falls back to
least squares with a warning below :data:`MIN_R2`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from servotune.errors import IdentificationError
from servotune.identify import model
from servotune.identify.noise import (
    NoiseModel,
    convolve,
    correlation_length,
    correlation_of_spectra,
    fit_noise_model,
    spectrum,
)

__all__ = [
    "MIN_R2",
    "IVFit",
    "NotConverged",
    "Projection",
    "estimate_iv",
    "external_signals",
    "project",
    "projection_lags",
]

MIN_R2 = 0.05
"""Smallest share of the command's variance the external signals must explain for ``iv``."""
_RIDGE = 1e-8
_MAX_OUTER = 4
_MAX_CHORD = 8
_TOL = 1e-8
_TOL_SETTLED = 1e-4
_MAX_REL_STEP = 0.5


def projection_lags(period_s: float) -> int:
    """FIR length of the projection [samples]: 0.25 s of the log, within 32 … 256."""
    return int(min(256, max(32, round(0.25 / period_s))))


@dataclass(frozen=True, slots=True, kw_only=True)
class Projection:
    """The command projected on the external signals.

    Attributes
    ----------
    u_hat : ndarray
        The projection [V], a function of the external signals only.
    r2 : float
        Share of the command's variance it explains.
    lags : int
        FIR length [samples].
    """

    u_hat: np.ndarray
    r2: float
    lags: int


def project(u: np.ndarray, signals: list[np.ndarray], lags: int) -> Projection:
    """Least-squares FIR projection of ``u`` on ``signals`` (lags 0 … ``lags`` − 1, a constant).

    The normal equations are built from the (FFT) correlations of the signals — a block-Toeplitz
    system of size ``len(signals)·lags`` — with a tiny ridge against collinear lags (a reference
    that ramps for a long time has nearly equal lagged increments).
    """
    u = np.asarray(u, dtype=float)
    um = float(np.mean(u))
    uc = u - um
    s = [np.asarray(x, dtype=float) - float(np.mean(x)) for x in signals]
    m = len(s)
    size = m * lags
    gram = np.empty((size, size))
    rhs = np.empty(size)
    idx = np.arange(lags)
    diff = idx[:, None] - idx[None, :]
    # every correlation here has the same length: each sequence is transformed once
    nf = correlation_length(u.size, lags - 1)
    spec = [spectrum(x, nf) for x in s]
    spec_u = spectrum(uc, nf)
    for a in range(m):
        rhs[a * lags : (a + 1) * lags] = correlation_of_spectra(spec[a], spec_u, nf, lags - 1)
        for b in range(a, m):
            r_ab = correlation_of_spectra(spec[a], spec[b], nf, lags - 1)  # Σ s_a,k s_b,k+j
            r_ba = r_ab if b == a else correlation_of_spectra(spec[b], spec[a], nf, lags - 1)
            # Σ_k s_a,k−i s_b,k−j is R_ab(i − j) for i >= j and R_ba(j − i) for i < j
            full = np.where(diff >= 0, r_ab[np.abs(diff)], r_ba[np.abs(diff)])
            gram[a * lags : (a + 1) * lags, b * lags : (b + 1) * lags] = full
            gram[b * lags : (b + 1) * lags, a * lags : (a + 1) * lags] = full.T
    ridge = _RIDGE * max(float(np.trace(gram)) / size, 1e-300)
    h = np.linalg.solve(gram + ridge * np.eye(size), rhs)
    u_hat = np.full(u.size, um)
    for a in range(m):
        u_hat += convolve(s[a], h[a * lags : (a + 1) * lags], {nf: spec[a]})
    den = float(np.dot(uc, uc))
    miss = u - u_hat
    r2 = 1.0 - float(np.dot(miss, miss)) / den if den > 0 else 0.0
    return Projection(u_hat=u_hat, r2=r2, lags=lags)


@dataclass(frozen=True, slots=True, kw_only=True)
class IVFit(model.Estimate):
    """What the IV estimator found (:class:`~servotune.identify.model.Estimate`), and how.

    ``a_mat`` is ``Σ (F z)(F j)ᵀ`` and the scores ``(F z_k)·(F ε_k)``, ``F`` the prefilter
    (the noise model's inverse, or 1 for basic IV); ``whitened`` the residual filtered from the
    log's start by the noise model and used after the skipped start and the filter's settling.

    Attributes
    ----------
    projection : Projection
    iterations : int
    converged : bool
    prefilter : bool
        Whether the equations were prefiltered by the noise model (refined IV).
    """

    projection: Projection
    iterations: int
    converged: bool
    prefilter: bool = True


class NotConverged(IdentificationError):
    """The IV iteration found no solution (it wandered or kept hitting its step limit)."""


def estimate_iv(
    u: np.ndarray,
    dy: np.ndarray,
    signals: list[np.ndarray],
    x0: np.ndarray,
    free: np.ndarray,
    *,
    period_s: float,
    compute_s: float,
    skip: int,
    projection: Projection | None = None,
    noise0: NoiseModel | None = None,
    max_outer: int = _MAX_OUTER,
    refit_noise: bool = True,
    prefilter: bool = True,
) -> IVFit:
    """IV estimate of the free parameters (module docstring: method, assumptions).

    Parameters
    ----------
    u : ndarray, shape (n,)
        Logged command [V] (row k written at ``t_k + compute_s``).
    dy : ndarray, shape (n,)
        Logged position increment over tick k [counts] (``y[k+1] − y[k]``).
    signals : list of ndarray, shape (n,)
        External signals (excitation [V], reference increments in task mode [counts]).
    x0 : ndarray
        Start (:data:`~servotune.identify.model.ALL_PARAMS` order).
    free : ndarray of bool
        Structure.
    period_s, compute_s : float
        Tick and known compute time [s].
    skip : int
        Samples at the start left out (the simulation's initial transient).
    projection : Projection, optional
        A projection already made for these data.
    noise0 : NoiseModel, optional
        A noise model of a similar residual (its order is kept, the coefficients refitted).
    max_outer : int
        Most refreshes of the sensitivities, instruments and prefilter.
    refit_noise : bool
        Refit the noise model at each refresh; False keeps ``noise0`` (given) throughout, so
        that fits of several structures are whitened alike (structure selection).
    prefilter : bool
        Refined IV: the estimating equations prefiltered by the noise model's inverse (default).
        False: basic IV, no prefilter — as consistent, less efficient, and steadier where the
        model misses dynamics that the prefilter's emphasis on the fast part would magnify (a
        real drive's); the intervals then rest on the block bootstrap alone.

    Returns
    -------
    IVFit

    Raises
    ------
    NotConverged
        If the iteration does not settle.
    """
    proj = projection or project(u, signals, projection_lags(period_s))
    inputs = (np.asarray(u, dtype=float), proj.u_hat)  # the logged command, its projection
    v0 = float(np.mean(dy[: max(1, min(5, dy.size))]) / period_s)
    x = model.clip_to_bounds(x0, free, period_s)
    lo, hi = model.lower_bounds()[free], model.upper_bounds(period_s)[free]
    converged = False
    iterations = 0
    noise = noise0
    pf = NoiseModel.identity()
    cut = skip
    jf = zf = np.zeros((int(free.sum()), 0))
    a_mat = zf @ jf.T
    moved = np.full(int(free.sum()), np.inf)
    rel = np.inf

    def simulate(x: np.ndarray) -> np.ndarray:
        return model.simulate_increments(
            inputs, [x], free, [0], period_s=period_s, compute_s=compute_s, v0=v0
        )[0]

    for outer in range(max_outer):
        del jf, zf  # the last refresh's, released before the next one is made (memory)
        (base, jac), (base_hat, zs) = model.sensitivities(
            inputs, x, free, (0, 1), period_s=period_s, compute_s=compute_s, v0=v0
        )
        if prefilter:
            # the noise model is refitted twice at most (at the start, then near the solution):
            # refitted at every refresh it moves the weakly determined directions (offset,
            # Coulomb level) each time, and the iteration creeps instead of settling
            if noise is None or (refit_noise and outer < 2):
                noise = fit_noise_model(dy[skip:] - base[skip:], start=noise)
            pf = noise
        cut = skip + pf.settle_samples  # filtered from the start, used after both transients
        eps = dy - base
        # whitened in place, in the simulations' rows: no new arrays (memory)
        jf = pf.whiten(jac, out=jac)[:, cut:]
        zf = pf.whiten(zs, out=zs)[:, cut:]
        a_mat = zf @ jf.T
        del base, jac, base_hat, zs
        scale = model.typical_scale(x, period_s)[free]
        active = np.ones(scale.size, dtype=bool)
        for chord in range(_MAX_CHORD):
            if chord:
                eps = dy - simulate(x)
            g = zf @ pf.whiten(eps, out=eps)[cut:]  # eps is not needed after: in place
            step = _step(a_mat, g, scale, active)
            # a parameter on a bound that the step pushes further out stays there (active set)
            pinned = ((x[free] <= lo) & (step < 0)) | ((x[free] >= hi) & (step > 0))
            if np.any(pinned & active):
                active &= ~pinned
                step = _step(a_mat, g, scale, active)
            # gain and tau change by at most half per step: a longer step is no Newton step
            rel = float(np.max(np.abs(step[:2]) / np.maximum(np.abs(x[free][:2]), 1e-300)))
            if rel > _MAX_REL_STEP:
                step *= _MAX_REL_STEP / rel
            iterations += 1
            x_new = x.copy()
            x_new[free] = np.clip(x[free] + step, lo, hi)
            moved = np.abs(x_new[free] - x[free])
            x = x_new
            if rel <= _MAX_REL_STEP and bool(np.all(moved <= _TOL * scale)):
                # solved. The sensitivities, instruments and prefilter were made at this outer
                # step's start, near the solution: instruments and a prefilter made at a
                # nearby point are as valid (any fixed ones give a consistent estimate) and
                # lose only a sliver of efficiency, so they are not refreshed again.
                converged = True
                break
        if converged:
            break
    if not converged and bool(np.all(moved <= _TOL_SETTLED * scale)) and rel <= _MAX_REL_STEP:
        converged = True  # still creeping, by far less than any statistical error
    if not converged:
        raise NotConverged(
            f"{'refined' if prefilter else 'basic'} instrumental variables did not settle in "
            f"{iterations} iterations"
        )
    sim = simulate(x)
    eps = dy - sim
    weighed = pf.whiten(eps)[cut:]  # the residual as the equations weigh it
    if prefilter:
        assert noise is not None
        whitened = weighed
    else:  # the diagnostics still test the innovations of a noise model of the residual
        noise = fit_noise_model(eps[skip:], start=noise0)
        whitened = noise.whiten(eps)[skip + noise.settle_samples :]
    # a_mat: the last refresh's zf @ jf.T (the instruments and sensitivities kept)
    return IVFit(
        x=x,
        a_mat=a_mat,
        scores=(zf * weighed).T,
        residual=eps[cut:],
        whitened=whitened,
        noise=noise,
        instruments=zf,
        sensitivities=jf,
        simulated=sim,
        projection=proj,
        iterations=iterations,
        converged=converged,
        prefilter=prefilter,
    )


def _step(a: np.ndarray, g: np.ndarray, scale: np.ndarray, active: np.ndarray) -> np.ndarray:
    """Gauss–Newton step of the active parameters (the others 0), in scaled variables."""
    step = np.zeros(scale.size)
    idx = np.flatnonzero(active)
    if idx.size == 0:
        return step
    a_s = a[np.ix_(idx, idx)] * scale[idx][None, :]
    try:
        d = np.linalg.solve(a_s, g[idx])
    except np.linalg.LinAlgError:
        d = np.linalg.lstsq(a_s, g[idx], rcond=None)[0]
    step[idx] = d * scale[idx]
    return step


def external_signals(
    exc_v: np.ndarray | None,
    ref_counts: np.ndarray | None,
    task: np.ndarray | None,
) -> tuple[list[np.ndarray], list[str]]:
    """The external signals a log offers, and their names.

    The excitation [V] when it varies; the reference's increments [counts] on the rows where
    the task law follows it (all rows if the log has no mode column), when they vary. A lock
    target (latched from the measured position) is not external and is never used.
    """
    sigs: list[np.ndarray] = []
    labels: list[str] = []
    if exc_v is not None and np.ptp(exc_v) > 0:
        sigs.append(np.asarray(exc_v, dtype=float))
        labels.append("exc_code")
    if ref_counts is not None:
        dr = np.diff(np.asarray(ref_counts, dtype=float), prepend=float(ref_counts[0]))
        if task is not None:
            dr = np.where(task, dr, 0.0)
        if np.ptp(dr) > 0 and math.isfinite(float(np.max(np.abs(dr)))):
            sigs.append(dr)
            labels.append("ref_counts")
    return sigs, labels
