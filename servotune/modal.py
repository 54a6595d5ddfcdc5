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
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg import expm

from servotune._control import scipy_paths
from servotune.errors import SpecError
from servotune.plant import Plant, lag_split, tick_coefficients
from servotune.resonance import Mode, mode_rows, with_intervals
from servotune.validate import show_value

if TYPE_CHECKING:  # python-control is imported where it is used (it is slow to import)
    import control

__all__ = [
    "OUTPUTS",
    "Mode",
    "check_number",
    "discretize",
    "discretize_lti",
    "modal_response",
    "modal_state_space",
    "mode_rows",
    "sampled_response",
    "with_intervals",
]

OUTPUTS = ("velocity", "position")
"""What a response is of: the velocity [counts/s per V] or the position [counts per V]."""


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


def discretize(plant: Plant, period_s: float, lag_s: float = 0.0) -> control.StateSpace:
    """Exact ZOH discretisation of the linear part, with a total input lag.

    The input (volts) is written every ``period_s`` and reaches the motor ``lag_s`` later
    (compute time + ``delay_s``); with ``lag_s = m·T + λ`` the input changes inside each tick at
    ``λ`` (modified z-transform). Offset, friction and speed limit are left out; an asymmetric
    plant enters with the mean of its two directions' gains (:attr:`Plant.mean_gain_cps_per_v`),
    a symmetric one with ``gain_cps_per_v`` exactly. A resonant plant (with ``modes``) is its
    transfer function (:meth:`Plant.to_tf`, modes included) sampled by :func:`discretize_lti`.

    Parameters
    ----------
    plant : Plant
    period_s : float
        Sample period [s] (the achieved timer period).
    lag_s : float
        Total lag from the tick start to the motor input [s], >= 0.

    Returns
    -------
    control.StateSpace
        Discrete system (``dt=period_s``), input volts, output position [counts]; states are
        position, speed and the ``m + 1`` (or ``m``, if λ = 0) held past inputs (a resonant
        plant's: :func:`discretize_lti`'s).
    """
    import control

    if plant.modes:  # the resonant plant: its transfer function sampled the same way
        return discretize_lti(plant.to_tf(), period_s, lag_s)
    if period_s <= 0:
        raise ValueError(f"period_s must be > 0 [s], got {show_value(period_s)}")
    if lag_s < 0:
        raise ValueError(f"lag_s must be >= 0 [s], got {show_value(lag_s)}")
    m, lam = lag_split(lag_s, period_s)
    phi_b, phi_a, go_p, go_v, gn_p, gn_v = tick_coefficients(
        period_s, lam, plant.mean_gain_cps_per_v, plant.tau_s
    )
    phi_t = np.array([[1.0, phi_b], [0.0, phi_a]])
    g_old = np.array([go_p, go_v])  # input from write k-m-1, acting for λ at the tick start
    g_new = np.array([gn_p, gn_v])  # input from write k-m, acting for T-λ
    n_hist = m + 1 if lam > 0.0 else m  # past inputs held in the state
    n = 2 + n_hist
    a_mat = np.zeros((n, n))
    b_mat = np.zeros((n, 1))
    a_mat[:2, :2] = phi_t
    # history states: h_1 = u(k-1), ..., h_j = u(k-j)
    if n_hist == 0:
        b_mat[:2, 0] = g_new
    else:
        if m == 0:
            b_mat[:2, 0] = g_new
        else:
            a_mat[:2, 2 + m - 1] += g_new
        if lam > 0.0:
            a_mat[:2, 2 + m] += g_old
        b_mat[2, 0] = 1.0
        for j in range(1, n_hist):
            a_mat[2 + j, 2 + j - 1] = 1.0
    c_mat = np.zeros((1, n))
    c_mat[0, 0] = 1.0
    return control.ss(a_mat, b_mat, c_mat, np.zeros((1, 1)), dt=period_s)


@scipy_paths
def discretize_lti(
    sys: control.TransferFunction | control.StateSpace, period_s: float, lag_s: float = 0.0
) -> control.StateSpace:
    """Exact ZOH discretisation of any continuous SISO system, with a total input lag.

    The generic form of :func:`discretize`: the input is written every ``period_s`` and reaches
    the system ``lag_s`` later; with ``lag_s = m·T + λ`` (:func:`lag_split`) the held input
    changes inside each tick at ``λ`` (modified z-transform). Over one tick
    ``x' = Φ(T)·x + Φ(T−λ)·Γ(λ)·u_old + Γ(T−λ)·u_new`` with ``Φ(h) = exp(A h)`` and
    ``Γ(h) = ∫₀ʰ exp(A s) ds · B`` (one matrix exponential each), ``u_old`` the write of tick
    ``k−m−1`` and ``u_new`` that of tick ``k−m``.

    Parameters
    ----------
    sys : control.TransferFunction or control.StateSpace
        Continuous-time (``dt=0``) SISO system [output units per input unit].
    period_s : float
        Sample period [s].
    lag_s : float
        Total lag from the sample instant to the system input [s], >= 0.

    Returns
    -------
    control.StateSpace
        Discrete system (``dt=period_s``); states are those of ``control.ss(sys)`` followed by
        the ``m + 1`` (or ``m``, if λ = 0) held past inputs. A direct feedthrough ``D`` acts on
        the input held at the sample instant (``u_old`` if λ > 0).

    Raises
    ------
    ValueError
        If ``sys`` is not continuous-time SISO, or ``period_s``/``lag_s`` are out of range.

    Examples
    --------
    >>> import control
    >>> d = discretize_lti(control.tf([1.0], [1.0, 1.0]), 0.1, 0.05)
    >>> d.dt, d.nstates
    (0.1, 2)
    """
    import control

    if not isinstance(sys, control.TransferFunction | control.StateSpace):
        raise ValueError(
            f"sys must be a control.TransferFunction or StateSpace, got {type(sys).__name__}"
        )
    if not sys.isctime(strict=True):
        raise ValueError(f"sys must be continuous-time (dt=0), got dt={show_value(sys.dt)}")
    if sys.ninputs != 1 or sys.noutputs != 1:
        raise ValueError(f"sys must be SISO, got {sys.noutputs} outputs x {sys.ninputs} inputs")
    if not (isinstance(period_s, int | float) and math.isfinite(period_s) and period_s > 0):
        raise ValueError(f"period_s must be > 0 [s], got {show_value(period_s)}")
    if not (isinstance(lag_s, int | float) and math.isfinite(lag_s) and lag_s >= 0):
        raise ValueError(f"lag_s must be >= 0 [s], got {show_value(lag_s)}")
    ss = control.ss(sys)
    a_c, b_c = np.asarray(ss.A, dtype=float), np.asarray(ss.B, dtype=float)
    c_c, d_c = np.asarray(ss.C, dtype=float), float(np.asarray(ss.D, dtype=float)[0, 0])
    nx = a_c.shape[0]
    m, lam = lag_split(lag_s, period_s)

    def phi_gamma(h: float) -> tuple[np.ndarray, np.ndarray]:
        aug = np.zeros((nx + 1, nx + 1))
        aug[:nx, :nx] = a_c * h
        aug[:nx, nx:] = b_c * h
        e = expm(aug)
        return e[:nx, :nx], e[:nx, nx]

    phi_t, _ = phi_gamma(period_s)
    phi_2, g_new = phi_gamma(period_s - lam)  # u_new acts for T - λ
    _, g_1 = phi_gamma(lam)
    g_old = phi_2 @ g_1  # u_old acts for λ, then the state moves on for T - λ
    n_hist = m + 1 if lam > 0.0 else m
    n = nx + n_hist
    a_mat = np.zeros((n, n))
    b_mat = np.zeros((n, 1))
    c_mat = np.zeros((1, n))
    d_mat = np.zeros((1, 1))
    a_mat[:nx, :nx] = phi_t
    c_mat[0, :nx] = c_c[0]
    # history states: h_1 = u(k-1), ..., h_j = u(k-j), at columns nx + j - 1
    if m == 0:
        b_mat[:nx, 0] = g_new
    else:
        a_mat[:nx, nx + m - 1] += g_new
    if lam > 0.0:
        a_mat[:nx, nx + m] += g_old
        c_mat[0, nx + m] += d_c  # at the sample instant the old input still acts
    elif m == 0:
        d_mat[0, 0] = d_c
    else:
        c_mat[0, nx + m - 1] += d_c
    if n_hist > 0:
        b_mat[nx, 0] = 1.0
        for j in range(1, n_hist):
            a_mat[nx + j, nx + j - 1] = 1.0
    return control.ss(a_mat, b_mat, c_mat, d_mat, dt=period_s)
