"""A plant's lightly damped modes: the :class:`Mode` record and their exact step (docs/frf.md).

The resonant plant (:mod:`servotune.modal` for its responses) measures, instead of the rigid
position ``p``, ``y = p + Σ_i g_i q_i``, each ``q_i`` a second-order filter of the rigid
acceleration ``a = v̇``::

    q̈_i = a − 2 ζ_i ω_i q̇_i − ω_i² q_i.

**Driven by the rigid speed.** With ``w_i = q̇_i − v`` the acceleration drops out::

    q̇_i = w_i + v,    ẇ_i = −ω_i² q_i − 2 ζ_i ω_i w_i − 2 ζ_i ω_i v,

a linear system ``ẋ = M x + β v`` with input the rigid speed ``v``. Over every piece of a
tick where the drive input is constant the rigid speed is
``v(t) = v∞ + (v_0 − v∞) e^{−t/τ}`` (:func:`servotune.plant.advance`: friction and the speed
limit change only ``v∞`` and where the pieces end), so the mode moves **exactly** over a piece
of length ``h`` by::

    x(h) = E x(0) + c v∞ + e (v_0 − v∞),
    E = e^{M h},  c = M⁻¹ (E − I) β,  e = (M + I/τ)⁻¹ (E − e^{−h/τ} I) β,

with ``E`` in closed form from the pair of poles ``−σ ± j ω_d`` (``σ = ζ ω``,
``ω_d = ω √(1 − ζ²)``): ``E = e^{−σ h} (cos(ω_d h) I + sin(ω_d h)/ω_d (M + σ I))``
(:func:`mode_coefficients`). A plant row keeps these for the tick's two pieces (before and
after the delay's fraction ``λ``); a piece cut by a zero crossing of the speed computes its
own.

**Row layout** (inside the plant row, from the offset ``off`` the plant gives): ``row[off]``
the number of modes, ``row[off + 1]`` ``1/τ``, then per mode :data:`MODE_WIDTH` numbers:
``ω²``, ``2σ``, ``g``, ``σ``, ``ω_d`` and the two pieces' ``E11 E12 E21 E22 c1 c2 e1 e2``.
The state of an axis's modes is an array ``(q_1, w_1, q_2, w_2, …)`` of ``2 ·``
:data:`MAX_MODES`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune._numba_cache import jit
from servotune.errors import SpecError

__all__ = [
    "MAX_MODES",
    "MODES_HEADER",
    "MODE_WIDTH",
    "Mode",
    "mode_coefficients",
    "mode_rows",
    "modes_output",
    "modes_segment",
    "modes_speed",
    "set_modes",
    "with_intervals",
]

MAX_MODES = 4
"""Modes a plant can carry."""
MODES_HEADER = 2
"""Numbers before the first mode's block: the count and ``1/τ``."""
_OMEGA2, _TWO_SIGMA, _GAIN, _SIGMA, _OMEGA_D, _PIECES = 0, 1, 2, 3, 4, 5
MODE_WIDTH = _PIECES + 16
"""Numbers per mode in a row (module docstring)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Mode:
    """A lightly damped mode: ``g s² / (s² + 2 ζ ω s + ω²)``, ``ω = 2π f`` (module docstring).

    Attributes
    ----------
    freq_hz : float
        Resonance frequency ``f`` [Hz], > 0.
    damping : float
        Damping ratio ``ζ`` [-], 0 < ζ < 1.
    gain : float
        Modal gain ``g`` [-], > −1 (a two-mass system's load-to-motor inertia ratio).
    freq_hz_95, damping_95, gain_95 : (float, float) or None
        95 % intervals (a fit's), or None.
    """

    freq_hz: float
    damping: float
    gain: float
    freq_hz_95: tuple[float, float] | None = None
    damping_95: tuple[float, float] | None = None
    gain_95: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        checks = (
            ("freq_hz", self.freq_hz, lambda x: x > 0, "> 0 [Hz]"),
            ("damping", self.damping, lambda x: 0 < x < 1, "in (0, 1)"),
            ("gain", self.gain, lambda x: x > -1, "> -1"),
        )
        for name, value, ok, want in checks:
            good = isinstance(value, int | float) and not isinstance(value, bool)
            if not (good and math.isfinite(value) and ok(value)):
                raise SpecError(f"Mode {name} must be {want}, got {value!r}")

    @property
    def antiresonance_hz(self) -> float:
        """The anti-resonance of the mode alone, ``f / √(1 + g)`` [Hz]."""
        return self.freq_hz / math.sqrt(1.0 + self.gain)

    def to_dict(self) -> dict[str, Any]:
        """Plain data, units in the keys."""
        out = with_intervals(self, ("freq_hz", "damping", "gain"))
        return out | {"antiresonance_hz": self.antiresonance_hz}


def with_intervals(obj: object, names: tuple[str, ...] | list[str]) -> dict[str, Any]:
    """``{name: value, name_95: [lo, hi] or None}`` for each name."""
    out: dict[str, Any] = {}
    for name in names:
        pair = getattr(obj, f"{name}_95")
        out[name] = float(getattr(obj, name))
        out[f"{name}_95"] = None if pair is None else [float(pair[0]), float(pair[1])]
    return out


def mode_rows(modes: tuple[Mode, ...] | list[Mode] | np.ndarray) -> np.ndarray:
    """The modes as rows ``freq_hz, damping, gain``, shape (n, 3) (an array: itself, reshaped)."""
    if isinstance(modes, np.ndarray):
        return modes.reshape(-1, 3)
    return np.array([(m.freq_hz, m.damping, m.gain) for m in modes], dtype=float).reshape(-1, 3)


@jit
def mode_coefficients(
    h: float, sigma: float, omega_d: float, omega2: float, two_sigma: float, inv_tau: float
) -> tuple[float, float, float, float, float, float, float, float]:
    """``E11 E12 E21 E22 c1 c2 e1 e2`` of one mode over a piece of ``h`` seconds (module
    docstring): ``x(h) = E x(0) + c v∞ + e (v_0 − v∞)``."""
    ex = math.exp(-sigma * h)
    cs = math.cos(omega_d * h)
    sn = math.sin(omega_d * h) / omega_d
    e11 = ex * (cs + sn * sigma)
    e12 = ex * sn
    e21 = -ex * sn * omega2
    e22 = ex * (cs - sn * sigma)
    # c = M⁻¹ (E − I) β, β = (1, −2σ), M⁻¹ = [[−2σ, −1], [ω², 0]] / ω²
    d1 = (e11 - 1.0) - e12 * two_sigma
    d2 = e21 - (e22 - 1.0) * two_sigma
    c1 = (-two_sigma * d1 - d2) / omega2
    c2 = d1
    # e = (M + I/τ)⁻¹ (E − e^{−h/τ} I) β
    et = math.exp(-h * inv_tau)
    f1 = (e11 - et) - e12 * two_sigma
    f2 = e21 - (e22 - et) * two_sigma
    det = inv_tau * (inv_tau - two_sigma) + omega2
    g1 = ((inv_tau - two_sigma) * f1 - f2) / det
    g2 = (omega2 * f1 + inv_tau * f2) / det
    return e11, e12, e21, e22, c1, c2, g1, g2


@jit
def set_modes(
    row: np.ndarray, off: int, modes: np.ndarray, h1: float, h2: float, tau: float
) -> None:
    """Write the modes ``modes`` (rows ``freq_hz, damping, gain``) into ``row`` from ``off``,
    with the coefficients of the two pieces ``h1``, ``h2`` [s] of a plant of time constant
    ``tau`` [s] (module docstring). No modes: the count 0, and nothing else read."""
    n = modes.shape[0]
    inv_tau = 1.0 / tau
    row[off] = n
    row[off + 1] = inv_tau
    for i in range(n):
        o = off + MODES_HEADER + i * MODE_WIDTH
        w = 2.0 * math.pi * modes[i, 0]
        zeta = modes[i, 1]
        sigma = zeta * w
        omega_d = w * math.sqrt(1.0 - zeta * zeta)
        row[o + _OMEGA2] = w * w
        row[o + _TWO_SIGMA] = 2.0 * sigma
        row[o + _GAIN] = modes[i, 2]
        row[o + _SIGMA] = sigma
        row[o + _OMEGA_D] = omega_d
        for piece in range(2):
            h = h1 if piece == 0 else h2
            cf = mode_coefficients(h, sigma, omega_d, w * w, 2.0 * sigma, inv_tau)
            for j in range(8):
                row[o + _PIECES + 8 * piece + j] = cf[j]


@jit(inline="always")
def modes_segment(
    q: np.ndarray, row: np.ndarray, off: int, piece: int, h: float, vinf: float, dv: float
) -> None:
    """Move the modes' state ``q`` over a piece of ``h`` seconds in which the rigid speed is
    ``vinf + dv e^{−t/τ}`` (module docstring): with the row's coefficients of piece
    ``piece`` (0 or 1), or computed for ``h`` if ``piece < 0``."""
    n = int(row[off])
    for i in range(n):
        o = off + MODES_HEADER + i * MODE_WIDTH
        if piece >= 0:
            c = o + _PIECES + 8 * piece
            e11, e12, e21, e22 = row[c], row[c + 1], row[c + 2], row[c + 3]
            c1, c2, g1, g2 = row[c + 4], row[c + 5], row[c + 6], row[c + 7]
        else:
            e11, e12, e21, e22, c1, c2, g1, g2 = mode_coefficients(
                h,
                row[o + _SIGMA],
                row[o + _OMEGA_D],
                row[o + _OMEGA2],
                row[o + _TWO_SIGMA],
                row[off + 1],
            )
        qi = q[2 * i]
        wi = q[2 * i + 1]
        q[2 * i] = e11 * qi + e12 * wi + c1 * vinf + g1 * dv
        q[2 * i + 1] = e21 * qi + e22 * wi + c2 * vinf + g2 * dv


@jit(inline="always")
def modes_output(p: float, q: np.ndarray, row: np.ndarray, off: int) -> float:
    """The measured position ``p + Σ g_i q_i`` [counts]; ``p`` itself without modes."""
    n = int(row[off])
    if n == 0:
        return p
    y = p
    for i in range(n):
        y += row[off + MODES_HEADER + i * MODE_WIDTH + _GAIN] * q[2 * i]
    return y


@jit(inline="always")
def modes_speed(v: float, q: np.ndarray, row: np.ndarray, off: int) -> float:
    """The measured speed ``v + Σ g_i (w_i + v)`` [counts/s]; ``v`` itself without modes."""
    n = int(row[off])
    if n == 0:
        return v
    s = v
    for i in range(n):
        s += row[off + MODES_HEADER + i * MODE_WIDTH + _GAIN] * (q[2 * i + 1] + v)
    return s
