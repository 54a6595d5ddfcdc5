"""The resonant plant: lightly damped modes on the rigid plant, and its exact sampled response
(docs/frf.md).

**Model.** The rigid plant (:class:`servotune.plant.Plant`: gain ``K`` [counts/s per V], time
constant ``τ`` [s], total input delay ``d`` [s]) times one modal term per lightly damped mode
(frequency ``f_i`` [Hz], damping ``ζ_i``, dimensionless gain ``g_i``), ``ω_i = 2π f_i``:

    P(s) = K e^{-s d} / (s (τ s + 1)) · (1 + Σ_i g_i s² / (s² + 2 ζ_i ω_i s + ω_i²)).

With one mode the factor is the two-mass system's measured at the motor (motor and load
coupled by a spring and damper): ``g`` the load's inertia over the motor's, the resonance at
``f``, the anti-resonance at ``f / √(1 + g)`` (G. Ellis, "Control System Design Guide", 4th
ed., Butterworth-Heinemann 2012, on mechanical resonance); exact where the rigid part is the
motion of both inertias together, close where friction to ground is light. ``−1 < g < 0``
puts the anti-resonance above the resonance.

**State space** (:func:`modal_state_space`). ``x = (p, v, q_1, q̇_1, q_2, q̇_2, …)``: the rigid
position [counts] and velocity [counts/s], and per mode a second-order filter of the rigid
acceleration ``a``, so that ``Q_i = s² P_rigid U / (s² + 2 ζ_i ω_i s + ω_i²)``:

    ṗ = v,   v̇ = a = (K u(t − d) − v) / τ,   q̈_i = a − 2 ζ_i ω_i q̇_i − ω_i² q_i,
    y = p + Σ_i g_i q_i.

**Sampling.** The input is held from each write (zero-order hold) and reaches the plant ``d``
later, ``d = m T + δ``, ``0 <= δ < T`` (:func:`servotune.plant.lag_split`). Over one tick
``x_{k+1} = Φ x_k + Γ_0 u_{k−m} + Γ_1 u_{k−m−1}``, ``Φ = e^{A T}``,
``Γ_0 = ∫_0^{T−δ} e^{A σ} dσ B``, ``Γ_1 = e^{A (T−δ)} ∫_0^{δ} e^{A σ} dσ B`` (matrix
exponentials of the block matrix ``[[A, B], [0, 0]]``), and the position response at
``z = e^{j ω T}`` is exact (K. J. Åström, B. Wittenmark, "Computer-Controlled Systems", 3rd
ed., Prentice Hall 1997, ch. 2, sampling a system with a time delay):

    G(z) = C (z I − Φ)^{-1} (Γ_0 + Γ_1 z^{-1}) z^{-m};

the velocity response is ``G(z) (1 − z^{-1}) / T``, the FRF estimator's backward difference.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import expm

from servotune.errors import SpecError
from servotune.plant import lag_split

__all__ = [
    "OUTPUTS",
    "Mode",
    "check_number",
    "modal_response",
    "modal_state_space",
    "mode_rows",
    "sampled_response",
    "with_intervals",
]

OUTPUTS = ("velocity", "position")
"""What a response is of: the velocity [counts/s per V] or the position [counts per V]."""


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
            if not (isinstance(value, int | float) and math.isfinite(value) and ok(value)):
                raise SpecError(f"Mode {name} must be {want}, got {value!r}")

    @property
    def antiresonance_hz(self) -> float:
        """The anti-resonance of the mode alone, ``f / √(1 + g)`` [Hz]."""
        return self.freq_hz / math.sqrt(1.0 + self.gain)

    def to_dict(self) -> dict[str, Any]:
        """Plain data, units in the keys."""
        out = with_intervals(self, ("freq_hz", "damping", "gain"))
        return out | {"antiresonance_hz": self.antiresonance_hz}


def with_intervals(obj: object, names: Sequence[str]) -> dict[str, Any]:
    """``{name: value, name_95: [lo, hi] or None}`` for each name."""
    out: dict[str, Any] = {}
    for name in names:
        pair = getattr(obj, f"{name}_95")
        out[name] = float(getattr(obj, name))
        out[f"{name}_95"] = None if pair is None else [float(pair[0]), float(pair[1])]
    return out


def modal_state_space(
    gain_cps_per_v: float, tau_s: float, modes: Sequence[Mode] | np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The continuous state space ``(A, B, C)`` of the modal model, without its delay.

    States ``(p, v, q_1, q̇_1, …)`` (module docstring); input [V], output the position [counts].

    Parameters
    ----------
    gain_cps_per_v : float
        ``K`` [counts/s per V].
    tau_s : float
        ``τ`` [s].
    modes : sequence of Mode, or array of shape (n, 3)
        The modes, or rows ``(freq_hz, damping, gain)``.
    """
    mp = mode_rows(modes)
    n = 2 + 2 * mp.shape[0]
    a = np.zeros((n, n))
    b = np.zeros(n)
    c = np.zeros(n)
    a[0, 1] = 1.0
    a[1, 1] = -1.0 / tau_s
    b[1] = gain_cps_per_v / tau_s
    c[0] = 1.0
    for i, (f_hz, zeta, g) in enumerate(mp):
        j = 2 + 2 * i
        w = 2.0 * math.pi * f_hz
        a[j, j + 1] = 1.0
        a[j + 1, j] = -w * w
        a[j + 1, j + 1] = -2.0 * zeta * w
        a[j + 1, 1] = -1.0 / tau_s  # the rigid acceleration's state part
        b[j + 1] = gain_cps_per_v / tau_s
        c[j] = g
    return a, b, c


def mode_rows(modes: Sequence[Mode] | np.ndarray) -> np.ndarray:
    if isinstance(modes, np.ndarray):
        return modes.reshape(-1, 3)
    return np.array([(m.freq_hz, m.damping, m.gain) for m in modes], dtype=float).reshape(-1, 3)


def _phi_gamma(
    a: np.ndarray, b: np.ndarray, spans: Sequence[float]
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``e^{A h}`` and ``∫_0^h e^{A σ} dσ B`` for each ``h`` of ``spans``, from one matrix
    exponential of the block-diagonal matrix of their ``[[A h, B h], [0, 0]]``."""
    n = a.shape[0]
    blocks = [slice(i * (n + 1), i * (n + 1) + n) for i in range(len(spans))]
    aug = np.zeros(((n + 1) * len(spans),) * 2)
    for rows, h in zip(blocks, spans, strict=True):
        aug[rows, rows] = a * h
        aug[rows, rows.stop] = b * h
    e = expm(aug)
    return [(e[rows, rows], e[rows, rows.stop]) for rows in blocks]


@functools.lru_cache(maxsize=64)
def _sampled(
    tau: float, freq_damping: tuple[tuple[float, float], ...], lam: float, period_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One tick of the model with ``K = 1`` in scaled states (``ω_i q_i`` for ``q_i``: the
    exponentials' matrices stay small): the scale, ``Φ``'s eigenvalues ``λ`` and eigenvectors
    ``V``, and ``V⁻¹ [Γ_0, Γ_1]``. Neither ``K`` nor the modal gains enter: a fit's steps in
    them reuse it."""
    rows = np.array([(f, z, 0.0) for f, z in freq_damping]).reshape(-1, 3)
    a, b, _ = modal_state_space(1.0, tau, rows)
    scale = np.ones(a.shape[0])
    scale[2::2] = 2.0 * math.pi * rows[:, 0]
    a, b = a * scale[:, None] / scale[None, :], b * scale
    if lam > 0.0:
        (phi, g0), (phi_lam, g_lam) = _phi_gamma(a, b, (period_s - lam, lam))
        phi, g1 = phi @ phi_lam, phi @ g_lam
    else:
        ((phi, g0),) = _phi_gamma(a, b, (period_s,))
        g1 = np.zeros_like(g0)
    poles, vec = np.linalg.eig(phi)  # distinct: 1, e^{−T/τ} and each mode's complex pair
    return scale, poles, vec, np.linalg.solve(vec, np.stack([g0, g1], axis=1))


def sampled_response(
    freq_hz: np.ndarray,
    k: float,
    tau: float,
    delay: float,
    period_s: float,
    mp: np.ndarray,
    output: str,
) -> np.ndarray:
    """The exact sampled response (module docstring), no checks."""
    m, lam = lag_split(delay, period_s)
    fz = tuple((float(f), float(z)) for f, z, _ in mp)
    scale, poles, vec, right = _sampled(float(tau), fz, lam, float(period_s))
    c = np.zeros(scale.size)
    c[0] = 1.0
    c[2::2] = mp[:, 2]
    c = c / scale
    z = np.exp(2j * math.pi * np.asarray(freq_hz, dtype=float) * period_s)
    # Φ = V Λ V⁻¹: C (zI − Φ)⁻¹ Γ = Σ_i (C V)_i (V⁻¹ Γ)_i / (z − λ_i)
    both = (1.0 / (z[:, None] - poles[None, :])) @ ((c @ vec)[:, None] * right)
    resp = (both[:, 0] + both[:, 1] / z) * (k * z ** (-m))
    if output == "velocity":
        resp = resp * (1.0 - 1.0 / z) / period_s
    return resp


def modal_response(
    freq_hz: np.ndarray | Sequence[float],
    *,
    gain_cps_per_v: float,
    tau_s: float,
    delay_s: float,
    period_s: float,
    modes: Sequence[Mode] = (),
    output: str = "velocity",
    compute_s: float = 0.0,
) -> np.ndarray:
    """The exact response of the sampled modal model at ``e^{j 2π f T}`` (module docstring).

    Parameters
    ----------
    freq_hz : array
        Frequencies [Hz], each 0 < f < Nyquist.
    gain_cps_per_v : float
        ``K`` [counts/s per V], > 0.
    tau_s : float
        ``τ`` [s], > 0.
    delay_s : float
        The plant's input delay [s], >= 0.
    period_s : float
        Tick period ``T`` [s], > 0.
    modes : sequence of Mode
        The modes, each below the Nyquist frequency.
    output : str
        ``"velocity"`` [counts/s per V] or ``"position"`` [counts per V].
    compute_s : float
        The rig's compute time [s], >= 0: the total delay is ``d = delay_s + compute_s``.

    Returns
    -------
    ndarray of complex

    Raises
    ------
    SpecError
        A value out of range, a frequency or a mode at or above the Nyquist frequency.
    """
    for name, v in (("gain_cps_per_v", gain_cps_per_v), ("tau_s", tau_s), ("period_s", period_s)):
        check_number(name, v, 0.0, strict=True)
    check_number("delay_s", delay_s, 0.0)
    check_number("compute_s", compute_s, 0.0)
    if output not in OUTPUTS:
        raise SpecError(f"output must be one of {', '.join(OUTPUTS)}, got {output!r}")
    f = np.asarray(freq_hz, dtype=float).reshape(-1)
    nyq = 0.5 / period_s
    if not np.all(np.isfinite(f) & (f > 0) & (f < nyq)):
        raise SpecError(f"freq_hz must be finite and within (0, {nyq:g}) Hz, the Nyquist frequency")
    for i, m in enumerate(modes):
        if not isinstance(m, Mode) or m.freq_hz >= nyq:
            raise SpecError(
                f"modes[{i}] must be a Mode below the Nyquist frequency {nyq:g} Hz (period "
                f"{period_s * 1e3:g} ms; a mode above it folds onto lower lines), got {m!r}"
            )
    d = delay_s + compute_s
    return sampled_response(f, gain_cps_per_v, tau_s, d, period_s, mode_rows(modes), output)


def check_number(name: str, v: object, lo: float, *, strict: bool = False) -> None:
    ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
    if not (ok and (v > lo if strict else v >= lo)):  # type: ignore[operator]
        raise SpecError(
            f"{name} must be a finite number {'>' if strict else '>='} {lo:g}, got {v!r}"
        )


# --- the fit ------------------------------------------------------------------------------
