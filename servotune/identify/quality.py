"""How good the identified model is: fit %, residual tests and intervals that allow correlation.

- **Fit %** (MATLAB ``compare``): ``100·(1 − ‖y − ŷ‖/‖y − mean(y)‖)`` of a simulation.
A test fails when it is significant *and* material (a correlation of at least
:data:`MATERIAL_CORRELATION`). Significant means below :data:`TEST_LEVEL`, the family-wise level
:data:`SIGNIFICANCE` shared by the :data:`RESIDUAL_TESTS` tests a fit runs (Bonferroni): the
verdict ``adequate`` is one decision on the whole family, so it is the family's false-alarm rate
that must be :data:`SIGNIFICANCE` — three tests each at 1 % flag about 3 % of correctly modelled
logs.

- **Whiteness**: Ljung–Box on the noise model's innovations (the residual whitened by its ARMA
  model, :mod:`servotune.identify.noise`): if they are not white, the noise model (and so the
  intervals it shapes) does not describe the residual. The ``p + q`` ARMA coefficients were
  fitted to this residual, which constrains its first autocorrelations: the statistic is χ² with
  ``lags − p − q`` degrees of freedom (Box & Pierce, JASA 65, 1970; Ljung & Box, Biometrika 65,
  1978).
- **Input–residual cross-correlation**: the innovations against the input prewhitened by its
  own autoregression, lags 0 … M — the external signal for ``iv`` (in closed loop the residual
  legitimately correlates with the command, through the controller), the command for ``oe``.
  Statistic ``n·Σρ²``, χ² with M + 1 degrees of freedom (Ljung, *System Identification*, 2nd
  ed., 1999, §16.6). A correlation left there is dynamics the model misses.
- **Intervals**: a moving-block bootstrap of the estimating equations (Künsch, Ann. Stat. 17,
  1989): the estimate is linearised, ``θ̂ − θ = A⁻¹ Σ s_k`` with ``s_k`` the equations' terms,
  and the sum is resampled in blocks of consecutive samples, so correlation within a block is
  kept; the block length is chosen from the data (Politis & White, Econometric Reviews 23,
  2004, with the correction of Patton, Politis & White 2009). The interval is the basic
  bootstrap interval of :data:`BOOTSTRAP_REPLICATES` replicates, drawn from a counter-based
  generator with a fixed key (same log, same interval). Blocks are at least ``n^(1/3)`` long
  (the rate that keeps the variance estimate consistent under any short-range correlation),
  and longer where the data ask for it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.special import gammaincc

from servotune.identify.model import Estimate
from servotune.identify.noise import (
    REGRESSION_SAMPLES,
    autocorrelation,
    crosscorrelation,
    fit_noise_model,
    levinson,
    lfilter,
    long_enough,
)

__all__ = [
    "BOOTSTRAP_REPLICATES",
    "RESIDUAL_TESTS",
    "SIGNIFICANCE",
    "TEST_LEVEL",
    "block_bootstrap",
    "bootstrap_intervals",
    "cross_correlation_test",
    "fit_pct",
    "ljung_box",
    "residual_tests",
]

BOOTSTRAP_REPLICATES = 999
"""Replicates of the moving-block bootstrap."""
MAX_BLOCKS = 1000
"""Most blocks in one replicate (the block length grows with longer logs beyond that)."""
BOOTSTRAP_KEY = (17, 0)
"""Key of the bootstrap's Philox generator (docs/decisions.md#11-random-numbers: counter-based,
fixed)."""
SIGNIFICANCE = 0.01
"""Family-wise level of the residual tests: the probability that a correctly modelled log is
called not adequate (by any of its tests)."""
RESIDUAL_TESTS = 3
"""Tests in the family: whiteness and the cross-correlation with each input tested — the command
for ``oe``, the external signals for ``iv``, of which a log has two at most (``exc_code`` and the
reference). Fewer tests make the Bonferroni level only more conservative."""
TEST_LEVEL = SIGNIFICANCE / RESIDUAL_TESTS
"""A residual test fails below this p-value (and only with a material correlation): Bonferroni's
inequality, P(any of m tests fails) ≤ Σ P(test fails) = m·(α/m) = α, whatever their dependence
(Holm, Scand. J. Statist. 6, 1979). The tests are decided one by one (each result stands on
its own in a fit's record), so the per-test Bonferroni level rather than Holm's step-down."""
MATERIAL_CORRELATION = 0.02
"""A residual test fails only if some correlation reaches this size too: with a million
samples a correlation of 0.005 is significant — the whitening of quantisation noise leaves
that much — but it is no missing dynamics and changes no interval."""
TEST_LAGS = 20
"""Lags of the whiteness and cross-correlation tests."""
PREWHITEN_ORDER = 20
"""Order of the autoregression that prewhitens an input for the cross-correlation test."""


def fit_pct(meas: np.ndarray, sim: np.ndarray) -> float:
    """MATLAB ``compare`` fit [%]: ``100·(1 − ‖meas − sim‖ / ‖meas − mean(meas)‖)``."""
    den = np.linalg.norm(meas - np.mean(meas))
    if den == 0:
        return float("nan")
    return float(100.0 * (1.0 - np.linalg.norm(meas - sim) / den))


def _chi2_sf(q: float, dof: int) -> float:
    return float(gammaincc(dof / 2.0, q / 2.0))


def ljung_box(w: np.ndarray, lags: int = TEST_LAGS, fitted: int = 0) -> dict[str, Any]:
    """Ljung–Box whiteness test of ``w`` (``fitted``: ARMA parameters estimated from it).

    The p-value is that of χ² with ``lags − fitted`` degrees of freedom: the innovations of an
    ARMA(p, q) model fitted to the series satisfy ``p + q`` normal equations, so ``p + q`` of
    the statistic's degrees of freedom are spent (Box & Pierce, JASA 65, 1970; Ljung & Box,
    Biometrika 65, 1978). Without the correction the test would be conservative (the
    statistic's mean is ``lags − p − q``, not ``lags``). The correction holds only for the
    innovations of a model *fitted to this residual* with its order right: a noise model whose
    order was chosen on another residual leaves them coloured, and the test then says so.

    Returns ``lags``, ``statistic``, ``p_value``, ``lag1_autocorrelation``,
    ``max_abs_autocorrelation`` and ``white`` (p ≥ :data:`TEST_LEVEL`, or no autocorrelation
    reaching :data:`MATERIAL_CORRELATION`).
    """
    w = np.asarray(w, dtype=float) - np.mean(w)
    n = w.size
    r = autocorrelation(w, lags) if n > lags + 1 else np.zeros(lags + 1)
    if r[0] <= 0 or n <= lags + 1:
        return {
            "lag1_autocorrelation": float("nan"),
            "lags": lags,
            "p_value": float("nan"),
            "max_abs_autocorrelation": float("nan"),
            "statistic": float("nan"),
            "white": False,
        }
    rho = r[1:] / r[0]
    q = float(n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, lags + 1))))
    p = _chi2_sf(q, max(1, lags - fitted))
    big = float(np.max(np.abs(rho)))
    return {
        "lag1_autocorrelation": float(rho[0]),
        "lags": lags,
        "p_value": p,
        "max_abs_autocorrelation": big,
        "statistic": q,
        "white": bool(p >= TEST_LEVEL or big < MATERIAL_CORRELATION),
    }


def cross_correlation_test(
    w: np.ndarray, x: np.ndarray, lags: int = TEST_LAGS, name: str = "input"
) -> dict[str, Any]:
    """Cross-correlation of the innovations ``w`` with the past of an input ``x``.

    The two sequences are aligned at their ends (``x`` may be longer).

    The input is prewhitened by its own autoregression first (so the correlations of two white
    sequences have variance ``1/n`` each); ``ρ_j = corr(x_k, w_{k+j})`` for ``j = 0 … lags``;
    statistic ``n·Σρ²`` ~ χ²(lags + 1) when the model misses nothing ``x`` drives (Ljung,
    *System Identification*, 2nd ed., 1999, §16.6; asymptotically, the parameters estimated
    from the same data only make it smaller, so the test errs on the safe side).

    Returns ``input``, ``lags``, ``statistic``, ``p_value``, ``max_abs_correlation`` and
    ``uncorrelated`` (p ≥ :data:`TEST_LEVEL`, or no correlation reaching
    :data:`MATERIAL_CORRELATION`).
    """
    w = np.asarray(w, dtype=float) - np.mean(w)
    x = np.asarray(x, dtype=float)[-w.size :]
    x = x - np.mean(x)
    n = w.size
    out: dict[str, Any] = {"input": name, "lags": lags}
    if n <= lags + 1 or not np.any(x) or not np.any(w):
        out.update(
            max_abs_correlation=float("nan"),
            p_value=float("nan"),
            statistic=float("nan"),
            uncorrelated=False,
        )
        return out
    # prewhitened by a long autoregression (Levinson–Durbin): a well-conditioned fit, the same
    # bytes on every run (an ARMA fit to a piecewise-constant excitation is ill-conditioned)
    order = min(PREWHITEN_ORDER, max(1, x.size // 50))
    poly, _ = levinson(autocorrelation(x, order) / x.size, order)
    xw = lfilter(poly, np.ones(1), x)
    xw = xw - np.mean(xw)
    rho = crosscorrelation(xw, w, lags) / math.sqrt(float(np.dot(xw, xw)) * float(np.dot(w, w)))
    q = float(n * np.sum(rho**2))
    p = _chi2_sf(q, lags + 1)
    big = float(np.max(np.abs(rho)))
    out.update(
        max_abs_correlation=big,
        p_value=p,
        statistic=q,
        uncorrelated=bool(p >= TEST_LEVEL or big < MATERIAL_CORRELATION),
    )
    return out


def _flat_top(t: np.ndarray) -> np.ndarray:
    a = np.abs(t)
    return np.where(a <= 0.5, 1.0, np.where(a <= 1.0, 2.0 * (1.0 - a), 0.0))


BLOCK_LENGTH_SAMPLES = 100_000
"""Samples (the first ones) the block length is worked out on; it scales as ``n^(1/3)``."""


def block_length(x: np.ndarray) -> int:
    """Politis–White automatic block length of the moving-block bootstrap for series ``x``.

    Worked out on the first :data:`BLOCK_LENGTH_SAMPLES` samples and scaled to the whole
    series by ``(n / n_used)^(1/3)``, the rate of the optimal block length.
    """
    full = np.asarray(x).size
    if full > BLOCK_LENGTH_SAMPLES:
        b = block_length(np.asarray(x)[:BLOCK_LENGTH_SAMPLES])
        return math.ceil(b * (full / BLOCK_LENGTH_SAMPLES) ** (1 / 3))
    x = np.asarray(x, dtype=float) - np.mean(x)
    n = x.size
    max_lag = min(n - 1, max(10, math.ceil(math.sqrt(n)) + 5, 1000))
    r = autocorrelation(x, max_lag) / n
    if r[0] <= 0:
        return 1
    rho = r[1:] / r[0]
    kn = max(5, math.ceil(math.sqrt(math.log10(n))))
    c = 2.0 * math.sqrt(math.log10(n) / n)
    small = np.abs(rho) < c
    m_hat = max_lag
    for m in range(0, max_lag - kn + 1):
        if small[m : m + kn].all():
            m_hat = m  # the first lag after which kn correlations in a row are negligible
            break
    big_m = min(2 * max(m_hat, 1), max_lag)
    k = np.arange(-big_m, big_m + 1)
    lam = _flat_top(k / big_m)
    rk = r[np.abs(k)]
    g_hat = float(np.sum(lam * np.abs(k) * rk))
    d_hat = 4.0 / 3.0 * float(np.sum(lam * rk)) ** 2
    if d_hat <= 0 or g_hat == 0:
        return max(1, math.ceil(n ** (1 / 3)))
    b = (2.0 * g_hat**2 / d_hat) ** (1 / 3) * n ** (1 / 3)
    return int(max(1, math.ceil(b)))


def block_bootstrap(
    a_mat: np.ndarray, scores: np.ndarray, replicates: int = BOOTSTRAP_REPLICATES
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Moving-block bootstrap of the linearised estimate ``θ̂ − θ = A⁻¹ Σ s_k``.

    Parameters
    ----------
    a_mat : ndarray, shape (p, p)
        Jacobian of the estimating equations.
    scores : ndarray, shape (n, p)
        Their terms at the estimate.
    replicates : int

    Returns
    -------
    std : ndarray, shape (p,)
        Bootstrap standard deviation [parameter units].
    lo_dev, hi_dev : ndarray, shape (p,)
        The 2.5 % and 97.5 % quantiles of the bootstrap deviation ``θ* − θ̂``; the basic 95 %
        interval is ``[θ̂ − hi_dev, θ̂ − lo_dev]``.
    block : int
        Block length used [samples].
    """
    n, p = scores.shape
    try:
        a_inv = np.linalg.inv(a_mat)
    except np.linalg.LinAlgError:
        a_inv = np.linalg.pinv(a_mat)
    infl = scores @ a_inv.T  # each sample's influence on the estimate
    block = max([block_length(infl[:, i]) for i in range(p)] + [math.ceil(n ** (1 / 3))])
    block = int(min(max(block, math.ceil(n / MAX_BLOCKS)), max(1, n // 4)))
    k = max(1, math.ceil(n / block))
    csum = np.vstack([np.zeros(p), np.cumsum(infl, axis=0)])
    sums = csum[block:] - csum[:-block]  # every moving block's sum, shape (n - block + 1, p)
    centre = k * sums.mean(axis=0)
    key = np.array(BOOTSTRAP_KEY, dtype=np.uint64)
    rng = np.random.Generator(np.random.Philox(key=key))
    dev = np.empty((replicates, p))
    chunk = max(1, 500_000 // k)
    for start in range(0, replicates, chunk):
        m = min(chunk, replicates - start)
        idx = rng.integers(0, sums.shape[0], size=(m, k))
        dev[start : start + m] = sums[idx].sum(axis=1) - centre
    dev *= math.sqrt(n / (k * block))  # a replicate of k blocks stands for n samples
    std = dev.std(axis=0, ddof=1)
    lo_dev, hi_dev = np.quantile(dev, [0.025, 0.975], axis=0)
    return std, lo_dev, hi_dev, block


def bootstrap_intervals(
    a_mat: np.ndarray,
    scores: np.ndarray,
    params: dict[str, float],
    names: tuple[str, ...] | list[str],
    lower_bounds: np.ndarray,
) -> tuple[dict[str, float], dict[str, tuple[float, float]], int]:
    """Standard deviations and basic 95 % intervals from the moving-block bootstrap, and the
    block length; an interval of a non-negative parameter stops at its bound."""
    std_v, lo_dev, hi_dev, block = block_bootstrap(a_mat, scores)
    lo_b = lower_bounds
    std = {p: float(s) for p, s in zip(names, std_v, strict=True)}
    ci95 = {
        p: (
            max(params[p] - float(hd), float(lb)) if lb >= 0 else params[p] - float(hd),
            params[p] - float(ld),
        )
        for p, ld, hd, lb in zip(names, lo_dev, hi_dev, lo_b, strict=True)
    }
    return std, ci95, block


def residual_tests(
    est: Estimate,
    method: str,
    u1: np.ndarray,
    sigs: list[np.ndarray],
    labels: list[str],
    skip: int,
) -> tuple[dict[str, Any], list[dict[str, Any]], list[str]]:
    """The residual tests of a fit: Ljung-Box whiteness of the innovations, their
    cross-correlation with the instruments (``iv``) or the command (``oe``), and the reasons
    for a failed test (empty when the model is adequate)."""
    # the residual tests judge the final residual, so its noise model is fitted afresh (order
    # by BIC): the estimator's own model was chosen at its start and kept, and when that order
    # is too small the innovations are coloured by it, not by the plant model (a false alarm
    # in about 5 % of correctly modelled logs)
    if long_enough(min(est.residual.size, REGRESSION_SAMPLES)):
        nm = fit_noise_model(est.residual)
        innov, fitted = nm.whiten(est.residual)[nm.settle_samples :], sum(nm.order)
    else:  # too short to fit afresh: the estimator's own model
        innov, fitted = est.whitened, sum(est.noise.order)
    white = ljung_box(innov, fitted=fitted)
    if method == "iv":
        cross = [
            cross_correlation_test(innov, s, name=lab) for s, lab in zip(sigs, labels, strict=True)
        ]
    else:
        cross = [cross_correlation_test(innov, u1, name="command")]
    reasons = []
    if not white["white"]:
        reasons.append(
            f"the innovations are not white (Ljung-Box p = {white['p_value']:.2g}, largest "
            f"|autocorrelation| {white['max_abs_autocorrelation']:.3f}): the noise model misses "
            "structure of the residual, so the intervals may be too narrow"
        )
    for c in cross:
        if not c["uncorrelated"]:
            reasons.append(
                f"the residual is correlated with the {c['input']} (p = {c['p_value']:.2g}, "
                f"largest |corr| {c['max_abs_correlation']:.3f}): the model misses dynamics "
                "that input drives"
            )
    return white, cross, reasons
