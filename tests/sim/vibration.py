"""The free vibration a trace is left with, measured independently of servotune's design code:
a matrix-pencil fit (Hua and Sarkar's method: SVD of a Hankel matrix, then the amplitudes by
least squares) of a sum of damped exponentials (used by the shaped-move tests)."""

from __future__ import annotations

import math

import numpy as np


def pencil(x: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Poles ``z`` and amplitudes ``c`` of ``x[k] ≈ Σ c z^k`` (matrix pencil)."""
    n = x.size
    rows = n // 2
    hankel = np.array([x[k : k + rows + 1] for k in range(n - rows)])
    v = np.linalg.svd(hankel, full_matrices=False)[2][:order].T
    z = np.linalg.eigvals(np.linalg.pinv(v[:-1]) @ v[1:])
    c = np.linalg.lstsq(z[None, :] ** np.arange(n)[:, None], x.astype(complex), rcond=None)[0]
    return z, c


def vibration_near(x: np.ndarray, period_s: float, near_hz: float, order: int = 10) -> float:
    """Amplitude of the free oscillation of ``x`` (samples ``period_s`` apart) whose frequency
    is nearest ``near_hz``: twice the magnitude of its complex amplitude at the first sample."""
    z, c = pencil(x, order)
    s = np.log(z) / period_s
    up = s.imag > 0
    k = np.flatnonzero(up)[np.argmin(np.abs(s[up].imag / (2 * math.pi) - near_hz))]
    return float(2 * abs(c[k]))
