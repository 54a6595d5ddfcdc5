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
from servotune.errors import IdentificationError

__all__ = [
    "NoiseModel",
    "autocorrelation",
    "convolve",
    "crosscorrelation",
    "fit_noise_model",
    "levinson",
    "lfilter",
    "long_enough",
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


_SHORT = 4  # most coefficients of each polynomial of a short filter (the noise models' ARMA)


@jit
def _lfilter_rows(b: np.ndarray, a: np.ndarray, x: np.ndarray, y: np.ndarray) -> None:
    """Direct-form filter ``a(q)·y = b(q)·x`` along each row, from rest (``a[0] = 1``).

    Each output is ``Σ_i b_i x_{k−i} − Σ_i a_i y_{k−i}``, summed in that order (i rising) over
    the samples there are. :func:`_short_rows` gives the same outputs, bit for bit, faster.
    """
    nb, na = b.size, a.size
    for r in range(x.shape[0]):
        for k in range(x.shape[1]):
            acc = 0.0
            for i in range(min(nb, k + 1)):
                acc += b[i] * x[r, k - i]
            for i in range(1, min(na, k + 1)):
                acc -= a[i] * y[r, k - i]
            y[r, k] = acc


@jit
def _short_head(
    b: np.ndarray,
    a: np.ndarray,
    xr: np.ndarray,
    shift: float,
    add: float,
    fused: bool,
    yr: np.ndarray,
    xh: np.ndarray,
    raw: np.ndarray,
) -> None:
    """The first ``raw.size`` outputs of one row as :func:`_lfilter_rows` makes them.

    Leaves their inputs (shifted) in ``xh`` and the outputs before ``add`` in ``raw``; the
    inputs are all read before any output is written (``yr`` may be ``xr``).
    """
    nb, na = b.size, a.size
    for k in range(raw.size):
        xh[k] = (xr[k] - shift) if fused else xr[k]
    for k in range(raw.size):
        acc = 0.0
        for i in range(min(nb, k + 1)):
            acc += b[i] * xh[k - i]
        for i in range(1, min(na, k + 1)):
            acc -= a[i] * raw[k - i]
        raw[k] = acc
        yr[k] = (acc + add) if fused else acc


@jit
def _short_output(
    coef: tuple[float, ...],
    nb: int,
    na: int,
    u0: float,
    u1: float,
    u2: float,
    u3: float,
    p1: float,
    p2: float,
    p3: float,
) -> float:
    """One output of a short filter from its registers, summed as :func:`_lfilter_rows` sums it.

    ``coef`` is ``(b0, b1, b2, b3, a1, a2, a3)``; ``u0 … u3`` the input now and the three
    before, ``p1 … p3`` the three outputs before. Only the terms of the ``nb`` and ``na``
    coefficients there are enter the sum, in the plain loop's order. Left to LLVM to inline
    (``inline="always"`` makes the two-row loop slower).
    """
    acc = 0.0
    acc += coef[0] * u0
    if nb > 1:
        acc += coef[1] * u1
    if nb > 2:
        acc += coef[2] * u2
    if nb > 3:
        acc += coef[3] * u3
    if na > 1:
        acc -= coef[4] * p1
    if na > 2:
        acc -= coef[5] * p2
    if na > 3:
        acc -= coef[6] * p3
    return acc


@jit
def _short_rows(
    b: np.ndarray,
    a: np.ndarray,
    x: np.ndarray,
    shift: np.ndarray,
    add: np.ndarray,
    fused: bool,
    y: np.ndarray,
) -> None:
    """:func:`_lfilter_rows` for short filters (at most :data:`_SHORT` coefficients each).

    The sums unrolled, in the same order, the past inputs and outputs kept in registers, and two
    rows filtered side by side (their recursions overlap): bit for bit the plain loop's
    outputs. Each input is read once, before the output of its sample is written, so ``y`` may
    be ``x`` (filtered in place). ``fused``: row ``r`` filtered as ``x[r] − shift[r]`` and its
    output returned plus ``add[r]`` (the recursion on the output before it), bit for bit what
    the three array operations give, without their temporaries (:meth:`NoiseModel.whiten`).
    """
    nb, na = b.size, a.size
    rows, n = x.shape
    head = min(_SHORT, n)
    xh = np.zeros(_SHORT)
    raw = np.zeros(_SHORT)
    coef = (
        b[0],
        b[1] if nb > 1 else 0.0,
        b[2] if nb > 2 else 0.0,
        b[3] if nb > 3 else 0.0,
        a[1] if na > 1 else 0.0,
        a[2] if na > 2 else 0.0,
        a[3] if na > 3 else 0.0,
    )
    last = _SHORT - 1  # the registers' start: the head's last samples (used only when n > head)
    for r in range(0, rows - 1, 2):
        xp, yp, xq, yq = x[r], y[r], x[r + 1], y[r + 1]
        sp, sq, dp, dq = shift[r], shift[r + 1], add[r], add[r + 1]
        _short_head(b, a, xp, sp, dp, fused, yp, xh[:head], raw[:head])
        u1, u2, u3 = xh[last], xh[last - 1], xh[last - 2]
        p1, p2, p3 = raw[last], raw[last - 1], raw[last - 2]
        _short_head(b, a, xq, sq, dq, fused, yq, xh[:head], raw[:head])
        v1, v2, v3 = xh[last], xh[last - 1], xh[last - 2]
        q1, q2, q3 = raw[last], raw[last - 1], raw[last - 2]
        for k in range(head, n):
            u0 = (xp[k] - sp) if fused else xp[k]
            v0 = (xq[k] - sq) if fused else xq[k]
            acc = _short_output(coef, nb, na, u0, u1, u2, u3, p1, p2, p3)
            bcc = _short_output(coef, nb, na, v0, v1, v2, v3, q1, q2, q3)
            yp[k] = (acc + dp) if fused else acc
            yq[k] = (bcc + dq) if fused else bcc
            u3, u2, u1 = u2, u1, u0
            v3, v2, v1 = v2, v1, v0
            p3, p2, p1 = p2, p1, acc
            q3, q2, q1 = q2, q1, bcc
    if rows % 2:  # the last row alone
        r = rows - 1
        xp, yp, sp, dp = x[r], y[r], shift[r], add[r]
        _short_head(b, a, xp, sp, dp, fused, yp, xh[:head], raw[:head])
        u1, u2, u3 = xh[last], xh[last - 1], xh[last - 2]
        p1, p2, p3 = raw[last], raw[last - 1], raw[last - 2]
        for k in range(head, n):
            u0 = (xp[k] - sp) if fused else xp[k]
            acc = _short_output(coef, nb, na, u0, u1, u2, u3, p1, p2, p3)
            yp[k] = (acc + dp) if fused else acc
            u3, u2, u1 = u2, u1, u0
            p3, p2, p1 = p2, p1, acc


def _filter(
    b: np.ndarray,
    a: np.ndarray,
    x: np.ndarray,
    shift: np.ndarray | None,
    add: np.ndarray | None,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """``b(q)/a(q)`` along the last axis from rest; with ``shift``/``add`` (one per row):
    ``lfilter(b, a, x − shift) + add``; into ``out`` (which may be ``x``) when given."""
    x = np.asarray(x, dtype=float)
    rows = np.ascontiguousarray(x.reshape(-1, x.shape[-1]) if x.ndim != 1 else x[None, :])
    b = np.asarray(b, dtype=float)
    a = np.asarray(a, dtype=float)
    fused = shift is not None and add is not None
    short = b.size <= _SHORT and a.size <= _SHORT and rows.shape[0] > 0
    if out is not None and not (
        short and out.shape == x.shape and out.dtype == np.float64 and out.flags.c_contiguous
    ):
        out[...] = _filter(b, a, x, shift, add)
        return out
    y = np.empty_like(rows) if out is None else out.reshape(rows.shape)
    if short:
        none = np.zeros(rows.shape[0])
        sh = none if shift is None else np.ascontiguousarray(shift, dtype=float).reshape(-1)
        ad = none if add is None else np.ascontiguousarray(add, dtype=float).reshape(-1)
        call_compiled(_short_rows, b, a, rows, sh, ad, fused, y)
    else:
        if fused:
            assert shift is not None and add is not None
            rows = rows - np.asarray(shift, dtype=float).reshape(-1, 1)
        call_compiled(_lfilter_rows, b, a, rows, y)
        if fused:
            y += np.asarray(add, dtype=float).reshape(-1, 1)
    return y.reshape(x.shape)


def lfilter(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``b(q)/a(q)`` applied along the last axis from rest (the short ARMA filters here).

    ``a`` is monic. The same as ``scipy.signal.lfilter(b, a, x, axis=-1)``, compiled, so that
    ``servotune fit`` need not import :mod:`scipy.signal` (half a second).
    """
    return _filter(b, a, x, None, None)


def convolve(
    x: np.ndarray, h: np.ndarray, spectra: dict[int, np.ndarray] | None = None
) -> np.ndarray:
    """The first ``len(x)`` samples of the full convolution ``x * h`` (FFT).

    ``spectra``: :func:`spectrum` of ``x`` already made, by FFT length (used when the length
    matches).
    """
    n = x.size + h.size - 1
    nf = sp_fft.next_fast_len(n, real=True)
    fx = spectra[nf] if spectra is not None and nf in spectra else sp_fft.rfft(x, nf, workers=-1)
    # x's spectrum times h's, in that order: numpy's complex product is not bitwise commutative
    # (``fx * <temporary>`` may be evaluated in place in the temporary, operands swapped)
    prod = np.multiply(fx, sp_fft.rfft(h, nf, workers=-1))
    return sp_fft.irfft(prod, nf, workers=-1)[: x.size]


def correlation_length(n: int, max_lag: int) -> int:
    """FFT length of the correlations of ``n`` samples up to ``max_lag`` (no wrap-around)."""
    return sp_fft.next_fast_len(n + max_lag + 1, real=True)


def spectrum(a: np.ndarray, nf: int) -> np.ndarray:
    """The real FFT of ``a`` zero-padded to ``nf`` (what :func:`crosscorrelation` transforms)."""
    return sp_fft.rfft(a, nf, workers=-1)


def correlation_of_spectra(fa: np.ndarray, fb: np.ndarray, nf: int, max_lag: int) -> np.ndarray:
    """:func:`crosscorrelation` from the two sequences' :func:`spectrum` (each made once)."""
    return sp_fft.irfft(np.conj(fa) * fb, nf, workers=-1)[: max_lag + 1].copy()


def crosscorrelation(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """``R[j] = Σ_k a_k · b_{k+j}`` for ``j = 0 … max_lag`` (sums over the overlap; FFT)."""
    nf = correlation_length(a.size, max_lag)
    fa = spectrum(a, nf)
    fb = fa if b is a else spectrum(b, nf)  # an autocorrelation: one transform
    return correlation_of_spectra(fa, fb, nf, max_lag)


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

    def whiten(self, x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``A(q)/C(q)`` applied along the last axis, started in steady state at the mean.

        ``out``: where to put it (``x`` itself, to filter in place; a float64 array of the
        shape of ``x``); the same values either way.

        The mean of ``x`` passes with the filter's static gain ``A(1)/C(1)`` from the first
        sample on, the deviations from it are filtered from rest: started from rest with the
        mean included, a slowly decaying start-up transient would dominate the output wherever
        ``A(1)/C(1)`` is small (a noise model with a root near 1), and started in steady state
        at the first sample it would where that gain is large.
        """
        x = np.asarray(x, dtype=float)
        gain = float(np.sum(self.ar) / np.sum(self.ma))
        if self.ar.size == 1 and self.ma.size == 1:
            return x * gain if out is None else np.multiply(x, gain, out=out)
        m = np.mean(x, axis=-1, keepdims=True)
        # lfilter(ar, ma, x - m) + m * gain, without the temporaries
        return _filter(self.ar, self.ma, x, m, m * gain, out)

    def to_dict(self) -> dict[str, object]:
        """Plain dict for JSON."""
        return {
            "ar": [float(v) for v in self.ar],
            "ma": [float(v) for v in self.ma],
            "innovation_variance": self.variance,
        }


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


def long_enough(n: int, max_order: int = MAX_ARMA_ORDER) -> bool:
    """Whether a residual of ``n`` samples is long enough for :func:`fit_noise_model` to fit
    an ARMA model (shorter ones get the identity)."""
    return min(LONG_AR_ORDER, n // 25) >= 4 * max_order


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

    Raises
    ------
    IdentificationError
        The best model's whitening filter needs as many samples to settle as the residual has
        (:attr:`NoiseModel.settle_samples`: ~920 for a root at :data:`MAX_ROOT`): the filtered
        sequences start after it, so on such a short log nothing would be left to estimate or
        test with, and a lesser model would give intervals that are too narrow.
    """
    e = np.asarray(e, dtype=float)
    e = e[:REGRESSION_SAMPLES] - np.mean(e[:REGRESSION_SAMPLES])
    n = e.size
    r0 = float(np.dot(e, e)) / max(n, 1)
    one = np.ones(1)
    long_p = min(LONG_AR_ORDER, n // 25)  # a short residual: a shorter long autoregression
    if not long_enough(n, max_order) or r0 <= 0:
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
        sol = least_squares(
            lambda th, p=p: _innovations(e, th, p, begin),
            theta0,
            method="lm",
            max_nfev=50 * (theta0.size + 1),
        )
        theta = sol.x if np.all(np.isfinite(sol.x)) else theta0
        w = _innovations(e, theta, p, begin)
        var = float(np.dot(w, w)) / w.size
        if not (0 < var < 1e6 * r0):
            continue
        bic = w.size * math.log(var) + theta.size * math.log(w.size)
        if bic < best.bic:
            best = NoiseModel(
                ar=np.concatenate([one, theta[:p]]),
                ma=np.concatenate([one, theta[p:]]),
                variance=var,
                bic=bic,
            )
    if best.settle_samples >= n:  # its start-up outlasts the residual it was fitted on
        raise IdentificationError(
            f"the disturbance in this log needs a noise model whose start-up lasts "
            f"{best.settle_samples} samples, and the residual has {n}: the log is too short to "
            "identify it (record a longer one)"
        )
    return best
