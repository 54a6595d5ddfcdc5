"""The noise model: an ARMA description of the residual, and the filter that whitens it.

What is left of a log after the deterministic model — the load disturbance driven through the
plant, the encoder's quantisation (white in position, so a unit-root MA in the increments), a
drive's unmodelled detail — is coloured. The identifier describes it by an ARMA model
``A(q)·e_k = C(q)·w_k`` with ``w`` white, fitted by the Hannan–Rissanen method (a long
autoregression by Levinson–Durbin estimates the innovations, then one least-squares regression on
the past residuals and past innovations gives ``A`` and ``C``; Hannan & Rissanen, Biometrika 69,
1982), the orders chosen by BIC. Its inverse ``A/C`` is the prefilter of the refined
instrumental-variable estimator (the "refined" of refined IV: Young, Automatica 12, 1976) and
whitens the residual that the diagnostics test.

Also the correlation helpers (FFT) the estimators share.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import fft as sp_fft
from scipy.optimize import least_squares

from servotune._numba_cache import call_compiled, jit

__all__ = [
    "NoiseModel",
    "autocorrelation",
    "convolve",
    "crosscorrelation",
    "fit_noise_model",
    "levinson",
    "lfilter",
]

MAX_ARMA_ORDER = 3
"""Largest ARMA order tried (both A and C)."""
LONG_AR_ORDER = 40
"""Order of the long autoregression that estimates the innovations (Hannan–Rissanen step 1);
a residual of fewer than 25 times as many samples gets a shorter one."""
REGRESSION_SAMPLES = 20_000
"""Residual samples the noise model is fitted on at most (the first ones)."""
MAX_ROOT = 0.99
"""Largest root magnitude of ``C`` (the whitening filter ``1/C`` stays stable and settles
within :attr:`NoiseModel.settle_samples`, at most about 900 samples)."""
_BEGIN = 300  # innovations before this are left out of the fit (the filter's start-up)


@jit
def _lfilter_rows(b: np.ndarray, a: np.ndarray, x: np.ndarray, y: np.ndarray) -> None:
    """Direct-form filter ``a(q)·y = b(q)·x`` along each row, from rest (``a[0] = 1``)."""
    nb, na = b.size, a.size
    for r in range(x.shape[0]):
        for k in range(x.shape[1]):
            acc = 0.0
            for i in range(min(nb, k + 1)):
                acc += b[i] * x[r, k - i]
            for i in range(1, min(na, k + 1)):
                acc -= a[i] * y[r, k - i]
            y[r, k] = acc


def lfilter(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``b(q)/a(q)`` applied along the last axis from rest (the short ARMA filters here).

    ``a`` is monic. The same as ``scipy.signal.lfilter(b, a, x, axis=-1)``, compiled, so that
    ``servotune fit`` need not import :mod:`scipy.signal` (half a second).
    """
    x = np.asarray(x, dtype=float)
    rows = np.ascontiguousarray(x.reshape(-1, x.shape[-1]) if x.ndim != 1 else x[None, :])
    y = np.empty_like(rows)
    call_compiled(_lfilter_rows, np.asarray(b, dtype=float), np.asarray(a, dtype=float), rows, y)
    return y.reshape(x.shape)


def convolve(x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The first ``len(x)`` samples of the full convolution ``x * h`` (FFT)."""
    n = x.size + h.size - 1
    nf = sp_fft.next_fast_len(n, real=True)
    out = sp_fft.irfft(sp_fft.rfft(x, nf, workers=-1) * sp_fft.rfft(h, nf, workers=-1), nf,
                       workers=-1)  # fmt: skip
    return out[: x.size]


def crosscorrelation(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """``R[j] = Σ_k a_k · b_{k+j}`` for ``j = 0 … max_lag`` (sums over the overlap; FFT)."""
    n = a.size
    nf = sp_fft.next_fast_len(n + max_lag + 1, real=True)  # no wrap-around up to max_lag
    fa = sp_fft.rfft(a, nf, workers=-1)
    fb = sp_fft.rfft(b, nf, workers=-1)
    return sp_fft.irfft(np.conj(fa) * fb, nf, workers=-1)[: max_lag + 1].copy()


def autocorrelation(a: np.ndarray, max_lag: int) -> np.ndarray:
    """``R[j] = Σ_k a_k · a_{k+j}`` for ``j = 0 … max_lag`` (FFT)."""
    return crosscorrelation(a, a, max_lag)


def levinson(r: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Levinson–Durbin recursion on autocovariances ``r[0..order]``.

    Returns
    -------
    poly : ndarray, shape (order + 1,)
        ``1, a_1 … a_order`` of the order-``order`` whitening polynomial.
    var : ndarray, shape (order + 1,)
        Innovation variance of every order 0 … ``order`` (relative to ``r[0]``'s scale).
    """
    a = np.zeros(order + 1)
    a[0] = 1.0
    var = np.empty(order + 1)
    e = float(r[0])
    var[0] = e
    for p in range(1, order + 1):
        if e <= 0:
            var[p:] = max(e, 0.0)
            break
        k = -float(np.dot(a[:p], r[p:0:-1])) / e
        a[: p + 1] = a[: p + 1] + k * a[p::-1][: p + 1] * (np.arange(p + 1) > 0)
        a[p] = k
        e *= 1.0 - k * k
        var[p] = e
    return a, var


def _stable(c: np.ndarray) -> np.ndarray:
    """``c`` with its roots pulled inside the circle of :data:`MAX_ROOT` (same spectrum shape)."""
    if c.size <= 1:
        return c
    roots = np.roots(c)
    mag = np.abs(roots)
    if np.all(mag < MAX_ROOT):
        return c
    outside = mag > 1.0
    roots[outside] = 1.0 / np.conj(roots[outside])
    mag = np.abs(roots)
    big = mag > MAX_ROOT
    roots[big] = roots[big] / mag[big] * MAX_ROOT
    return np.real(np.poly(roots))


@dataclass(frozen=True, slots=True, kw_only=True)
class NoiseModel:
    """An ARMA noise model ``A(q) e = C(q) w`` (w white, variance ``variance``).

    Attributes
    ----------
    ar, ma : ndarray
        ``A`` and ``C``, leading 1.
    variance : float
        Innovation variance [residual units²].
    bic : float
        The order selection's criterion.
    """

    ar: np.ndarray
    ma: np.ndarray
    variance: float
    bic: float

    @classmethod
    def identity(cls) -> NoiseModel:
        """``A = C = 1``: white noise, no filtering."""
        return cls(ar=np.ones(1), ma=np.ones(1), variance=float("nan"), bic=0.0)

    @property
    def settle_samples(self) -> int:
        """Samples after which the whitening filter's start-up transient has decayed to 1e-4.

        Filtered sequences are used only after it: started from rest, the filter's first
        outputs carry the jump from rest to the data, which can outweigh thousands of samples.
        """
        if self.ma.size <= 1:
            return self.ar.size
        r = min(max(float(np.max(np.abs(np.roots(self.ma)))), 0.5), MAX_ROOT)
        return math.ceil(math.log(1e-4) / math.log(r)) + self.ar.size

    @property
    def order(self) -> tuple[int, int]:
        """``(len(A) − 1, len(C) − 1)``."""
        return self.ar.size - 1, self.ma.size - 1

    def whiten(self, x: np.ndarray) -> np.ndarray:
        """``A(q)/C(q)`` applied along the last axis, started in steady state at the mean.

        The mean of ``x`` passes with the filter's static gain ``A(1)/C(1)`` from the first
        sample on, the deviations from it are filtered from rest: started from rest with the
        mean included, a slowly decaying start-up transient would dominate the output wherever
        ``A(1)/C(1)`` is small (a noise model with a root near 1), and started in steady state
        at the first sample it would where that gain is large.
        """
        x = np.asarray(x, dtype=float)
        gain = float(np.sum(self.ar) / np.sum(self.ma))
        if self.ar.size == 1 and self.ma.size == 1:
            return x * gain
        m = np.mean(x, axis=-1, keepdims=True)
        return lfilter(self.ar, self.ma, x - m) + m * gain

    def to_dict(self) -> dict[str, object]:
        """Plain dict for JSON."""
        return {"ar": [float(v) for v in self.ar], "ma": [float(v) for v in self.ma],
                "innovation_variance": self.variance}  # fmt: skip


ORDERS = ((1, 1), (2, 2), (2, 3), (3, 3))
"""ARMA orders ``(len(A) − 1, len(C) − 1)`` tried; the smallest BIC wins."""


def _hannan_rissanen(e: np.ndarray, innov: np.ndarray, p: int, q: int, start: int) -> np.ndarray:
    """``a_1 … a_p, c_1 … c_q`` by one regression on past residuals and past innovations."""
    n = e.size
    cols = [-e[start - i : n - i] for i in range(1, p + 1)]
    cols += [innov[start - i : n - i] for i in range(1, q + 1)]
    theta, *_ = np.linalg.lstsq(np.column_stack(cols), e[start:], rcond=None)
    return np.concatenate([theta[:p], _stable(np.concatenate([[1.0], theta[p:]]))[1:]])


def _inside(poly: np.ndarray, radius: float) -> bool:
    """True if every root of the monic ``poly`` lies within ``radius`` (Schur–Cohn step-down)."""
    a = poly * radius ** -np.arange(poly.size, dtype=float)
    for p in range(a.size - 1, 0, -1):
        k = a[p]
        if not abs(k) < 1.0:
            return False
        a = (a[:p] - k * a[p:0:-1]) / (1.0 - k * k)
    return True


def _innovations(e: np.ndarray, theta: np.ndarray, p: int, start: int) -> np.ndarray:
    a = np.concatenate([[1.0], theta[:p]])
    c = np.concatenate([[1.0], theta[p:]])
    if not (_inside(c, MAX_ROOT) and _inside(a, 1.0)):
        return np.full(e.size - start, 1e6 * (1.0 + float(np.sum(np.abs(theta)))))
    return lfilter(a, c, e)[start:]


def fit_noise_model(
    e: np.ndarray, max_order: int = MAX_ARMA_ORDER, *, start: NoiseModel | None = None
) -> NoiseModel:
    """Fit an ARMA noise model to a residual sequence (orders by BIC).

    Each order of :data:`ORDERS` (up to ``max_order``) starts from the Hannan–Rissanen
    regression and is refined by minimising the sum of squared innovations (Levenberg–Marquardt,
    the roots kept inside the unit circle): a one-pass regression is not accurate enough when
    the residual has a root near 1 (a slow load through an integrator, quantisation
    differenced), and then the innovations stay visibly coloured.

    Parameters
    ----------
    e : ndarray
        The residual (any scale; its mean is removed). The first :data:`REGRESSION_SAMPLES`
        samples are used.
    max_order : int
        Largest order of ``A`` and ``C``.
    start : NoiseModel, optional
        A model of a similar residual (the same log at a nearby parameter vector): only its
        order is fitted, starting from its coefficients.

    Returns
    -------
    NoiseModel
        The identity (``A = C = 1``) if the residual is constant or too short.
    """
    e = np.asarray(e, dtype=float)
    e = e[:REGRESSION_SAMPLES] - np.mean(e[:REGRESSION_SAMPLES])
    n = e.size
    r0 = float(np.dot(e, e)) / max(n, 1)
    one = np.ones(1)
    long_p = min(LONG_AR_ORDER, n // 25)  # a short residual: a shorter long autoregression
    if long_p < 4 * max_order or r0 <= 0:
        return NoiseModel(ar=one, ma=one, variance=max(r0, 0.0), bic=0.0)
    begin = min(n // 4, _BEGIN)
    identity = NoiseModel(ar=one, ma=one, variance=r0, bic=n * math.log(r0))
    if start is not None and start.order != (0, 0):
        orders = (start.order,)
        theta0s = [np.concatenate([start.ar[1:], start.ma[1:]])]
    else:
        r = autocorrelation(e, long_p) / n
        poly, _ = levinson(r, long_p)
        innov = lfilter(poly, np.ones(1), e)
        orders = tuple(o for o in ORDERS if max(o) <= max_order)
        theta0s = [_hannan_rissanen(e, innov, p, q, begin) for p, q in orders]
    best = identity
    for (p, _q), theta0 in zip(orders, theta0s, strict=True):
        sol = least_squares(lambda th, p=p: _innovations(e, th, p, begin), theta0, method="lm",
                            max_nfev=50 * (theta0.size + 1))  # fmt: skip
        theta = sol.x if np.all(np.isfinite(sol.x)) else theta0
        w = _innovations(e, theta, p, begin)
        var = float(np.dot(w, w)) / w.size
        if not (0 < var < 1e6 * r0):
            continue
        bic = w.size * math.log(var) + theta.size * math.log(w.size)
        if bic < best.bic:
            best = NoiseModel(ar=np.concatenate([one, theta[:p]]),
                              ma=np.concatenate([one, theta[p:]]), variance=var,
                              bic=bic)  # fmt: skip
    return best
