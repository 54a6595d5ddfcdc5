"""The axis model (docs/formats.md#axis-model): D/A volts → encoder counts, with its exact
integration.

A speed-command drive and motor, position ``p`` [counts], speed ``v = dp/dt`` [counts/s]::

    tau_s · dv/dt + v = gain_d · (u(t − delay_s) + offset_v + load_v(t) − coulomb_d · d)

with ``d = sign(v)`` the direction of motion, and at rest the direction the net input pushes
(``d = +1`` if it exceeds ``coulomb_v``, ``d = −1`` if it is below ``−coulomb_neg``). The
asymmetric model (docs/formats.md#asymmetric-friction) gives each direction its own viscous gain and
Coulomb level: ``gain_d, coulomb_d`` are ``gain_cps_per_v, coulomb_v`` for ``d = +1`` and
``gain_neg_cps_per_v, coulomb_neg_v`` for ``d = −1`` (each ``None``: the positive direction's
value, the symmetric model). The speed the drive aims at is limited to
``±max_speed`` (the drive's speed limit, the same both ways), and at rest the motor stays at
rest while ``−coulomb_neg_v <= u + offset_v + load_v <= coulomb_v`` (no chattering through
zero). Between input changes the input is constant, so position and speed have a closed form;
the only events are zero crossings of the speed (where the direction and its parameters
switch), which are solved exactly. The same formulas give the exact ZOH discretisation of the
linear part (:func:`discretize`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from servotune._numba_cache import jit
from servotune.resonance import (
    MAX_MODES,
    MODE_WIDTH,
    MODES_HEADER,
    Mode,
    mode_rows,
    modes_segment,
    set_modes,
)
from servotune.validate import show_value

if TYPE_CHECKING:  # python-control is imported where it is used (it is slow to import)
    import control

__all__ = [
    "NPARAM",
    "NROW",
    "Plant",
    "advance",
    "advance_inlined",
    "advance_span",
    "advance_tick",
    "advance_tick_inlined",
    "advance_tick_modal",
    "fill_plant_rows",
    "lag_split",
    "parameter_row",
    "plant_row",
    "put_modes",
    "step_coefficients",
    "tick_coefficients",
]


def _check_finite_ge(name: str, value: float, lo: float, unit: str, strict: bool = False) -> None:
    if not isinstance(value, int | float) or isinstance(value, bool) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number [{unit}], got {show_value(value)}")
    if (value <= lo) if strict else (value < lo):
        op = ">" if strict else ">="
        raise ValueError(f"{name} must be {op} {lo:g} [{unit}], got {show_value(value)}")


@dataclass(frozen=True, slots=True, kw_only=True)
class Plant:
    """Dynamics of one axis (docs/formats.md#axis-model), volts at the D/A output → encoder counts.

    Parameters
    ----------
    gain_cps_per_v : float
        Steady-state speed per volt [counts/s/V] (counts after the counter's multiplication).
    tau_s : float
        Drive + mechanical time constant [s], > 0.
    delay_s : float
        Pure input delay (drive dead time) [s], may be a fraction of a tick.
    offset_v : float
        Analog zero drift [V]: the motor responds to ``u + offset_v``.
    coulomb_v : float
        Coulomb friction as equivalent drive input [V], >= 0 (moving in the positive direction,
        and the breakaway level at rest upwards).
    max_speed_rpm : float or None
        Drive speed limit [r/min]; None for no limit. Converting it to counts/s needs the rig's
        counts per revolution (:meth:`max_speed_cps`). The same in both directions.
    noise_counts : float
        Standard deviation of encoder measurement noise [counts], added before the floor.
    gain_neg_cps_per_v : float or None
        Steady-state speed per volt moving in the negative direction [counts/s/V], > 0; None:
        ``gain_cps_per_v`` (symmetric).
    coulomb_neg_v : float or None
        Coulomb friction moving in the negative direction, and the breakaway level at rest
        downwards [V], >= 0; None: ``coulomb_v`` (symmetric).
    modes : tuple of Mode
        Lightly damped modes measured with the position (:mod:`servotune.resonance`), at most
        :data:`~servotune.resonance.MAX_MODES`; empty: the rigid plant.

    Notes
    -----
    With both ``*_neg`` fields None (or equal to the positive direction's values) the model is
    the symmetric one, and every simulation gives the same bytes as before they existed.
    The linear model (:meth:`to_tf`, :func:`discretize`) uses the mean gain
    (:attr:`mean_gain_cps_per_v`) and, as always, leaves the friction out.
    """

    gain_cps_per_v: float
    tau_s: float
    delay_s: float = 0.0
    offset_v: float = 0.0
    coulomb_v: float = 0.0
    max_speed_rpm: float | None = None
    noise_counts: float = 0.0
    gain_neg_cps_per_v: float | None = None
    coulomb_neg_v: float | None = None
    modes: tuple[Mode, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.modes, tuple):
            object.__setattr__(self, "modes", tuple(self.modes))
        if len(self.modes) > MAX_MODES or not all(isinstance(m, Mode) for m in self.modes):
            raise ValueError(f"modes must be at most {MAX_MODES} Mode records, got {self.modes!r}")
        _check_finite_ge("gain_cps_per_v", self.gain_cps_per_v, 0.0, "counts/s/V", strict=True)
        _check_finite_ge("tau_s", self.tau_s, 0.0, "s", strict=True)
        _check_finite_ge("delay_s", self.delay_s, 0.0, "s")
        _check_finite_ge("offset_v", self.offset_v, -math.inf, "V")
        _check_finite_ge("coulomb_v", self.coulomb_v, 0.0, "V")
        _check_finite_ge("noise_counts", self.noise_counts, 0.0, "counts")
        if self.max_speed_rpm is not None:
            _check_finite_ge("max_speed_rpm", self.max_speed_rpm, 0.0, "r/min", strict=True)
        if self.gain_neg_cps_per_v is not None:
            _check_finite_ge(
                "gain_neg_cps_per_v", self.gain_neg_cps_per_v, 0.0, "counts/s/V", strict=True
            )
        if self.coulomb_neg_v is not None:
            _check_finite_ge("coulomb_neg_v", self.coulomb_neg_v, 0.0, "V")

    @property
    def gains_cps_per_v(self) -> tuple[float, float]:
        """Viscous gain moving positive and moving negative [counts/s/V]."""
        neg = self.gain_neg_cps_per_v
        return self.gain_cps_per_v, self.gain_cps_per_v if neg is None else neg

    @property
    def coulombs_v(self) -> tuple[float, float]:
        """Coulomb level moving positive and moving negative [V]."""
        neg = self.coulomb_neg_v
        return self.coulomb_v, self.coulomb_v if neg is None else neg

    @property
    def symmetric(self) -> bool:
        """True if both directions have the same gain and Coulomb level (the symmetric model)."""
        (g_p, g_n), (c_p, c_n) = self.gains_cps_per_v, self.coulombs_v
        return g_p == g_n and c_p == c_n

    @property
    def mean_gain_cps_per_v(self) -> float:
        """The linear model's gain [counts/s/V]: the mean of the two directions' gains.

        For a speed swinging through zero, ``v = V sin(ωt)``, the first harmonic of
        ``gain_d · v`` is ``(gain + gain_neg) / 2 · v`` (the describing function of the
        direction-dependent gain); for a symmetric plant it is ``gain_cps_per_v`` exactly.
        """
        g_p, g_n = self.gains_cps_per_v
        return g_p if g_p == g_n else 0.5 * (g_p + g_n)

    def max_speed_cps(self, counts_per_rev: float) -> float:
        """Drive speed limit in counts/s (``inf`` if none) [counts/s]."""
        if self.max_speed_rpm is None:
            return math.inf
        return self.max_speed_rpm / 60.0 * counts_per_rev

    def to_tf(self) -> control.TransferFunction:
        """Linear part without the delay: ``gain / (s (tau s + 1))`` [counts/V], times
        ``1 + Σ g s² / (s² + 2 ζ ω s + ω²)`` for a resonant plant's modes.

        The delay ``exp(-delay_s s)`` is not rational; :func:`discretize` includes it exactly.
        Offset and friction are left out; the gain of an asymmetric plant is the mean of its
        two directions' gains (:attr:`mean_gain_cps_per_v`).
        """
        import control

        rigid = control.tf([self.mean_gain_cps_per_v], [self.tau_s, 1.0, 0.0])
        if not self.modes:
            return rigid
        factor = control.tf([1.0], [1.0])
        for m in self.modes:  # 1 + Σ g s² / (s² + 2 ζ ω s + ω²) (docs/frf.md)
            w = 2.0 * math.pi * m.freq_hz
            factor = factor + control.tf([m.gain, 0.0, 0.0], [1.0, 2.0 * m.damping * w, w * w])
        return rigid * factor

    @classmethod
    def from_tf(cls, tf: control.TransferFunction, **extra: float) -> Plant:
        """Build from a continuous ``K / (s (tau s + 1))`` transfer function.

        The plant is symmetric (``gain_cps_per_v = K``) unless ``extra`` says otherwise.

        Raises
        ------
        ValueError
            If ``tf`` is discrete or not of that form.
        """
        if not tf.isctime():
            raise ValueError("from_tf needs a continuous-time transfer function (dt=0)")
        num = np.atleast_1d(np.squeeze(tf.num[0][0])).astype(float)
        den = np.atleast_1d(np.squeeze(tf.den[0][0])).astype(float)
        num = np.trim_zeros(num, "f")
        den = np.trim_zeros(den, "f")
        if num.size != 1 or den.size != 3 or den[2] != 0.0 or den[0] <= 0 or den[1] <= 0:
            raise ValueError(
                "from_tf expects gain / (s (tau s + 1)): numerator K, denominator [a, b, 0]"
            )
        return cls(gain_cps_per_v=float(num[0] / den[1]), tau_s=float(den[0] / den[1]), **extra)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict with the axis model's parameter names (docs/formats.md#axis-model); a
        resonant plant's ``modes`` as a list of ``{freq_hz, damping, gain}``."""
        modes = [{"freq_hz": m.freq_hz, "damping": m.damping, "gain": m.gain} for m in self.modes]
        return ({"modes": modes} if modes else {}) | {
            "coulomb_neg_v": self.coulomb_neg_v,
            "coulomb_v": self.coulomb_v,
            "delay_s": self.delay_s,
            "gain_cps_per_v": self.gain_cps_per_v,
            "gain_neg_cps_per_v": self.gain_neg_cps_per_v,
            "max_speed_rpm": self.max_speed_rpm,
            "noise_counts": self.noise_counts,
            "offset_v": self.offset_v,
            "tau_s": self.tau_s,
        }


@jit
def step_coefficients(h_s: float, tau_s: float) -> tuple[float, float]:
    """``a = exp(-h/tau)`` and ``b = tau (1 - a)`` for a constant-input interval of ``h_s``."""
    a = math.exp(-h_s / tau_s)
    return a, -tau_s * math.expm1(-h_s / tau_s)


@jit(inline="always")
def _target_speed(
    s: float,
    w: float,
    gain: float,
    coulomb: float,
    gain_neg: float,
    coulomb_neg: float,
    vmax: float,
) -> float:
    """The speed [counts/s] the motor tends to moving in direction ``s`` (±1) under the net
    input ``w`` [V]: that direction's ``gain · (w − coulomb · s)``, within ``±vmax``."""
    if s > 0.0:
        vinf = gain * (w - coulomb * s)
    else:
        vinf = gain_neg * (w - coulomb_neg * s)
    if vinf > vmax:
        return vmax
    if vinf < -vmax:
        return -vmax
    return vinf


@jit
def advance(
    p: float,
    v: float,
    w: float,
    h: float,
    a: float,
    b: float,
    gain: float,
    tau: float,
    coulomb: float,
    vmax: float,
    gain_neg: float | None = None,
    coulomb_neg: float | None = None,
    q: np.ndarray | None = None,
    row: np.ndarray | None = None,
    piece: int = -1,
) -> tuple[float, float]:
    """Advance position and speed exactly over ``h`` seconds of constant drive input ``w``.

    The direction ``d`` is the sign of the speed, or at rest the way ``w`` pushes past the
    Coulomb level of that way; ``gain, coulomb`` act moving positive, ``gain_neg,
    coulomb_neg`` moving negative. A speed reaching zero inside the interval stops there
    (sticks while ``-coulomb_neg <= w <= coulomb``) or goes on the other way with the other
    direction's parameters from the crossing instant.

    Parameters
    ----------
    p, v : float
        Position [counts] and speed [counts/s] at the start.
    w : float
        Net drive input ``u + offset + load`` [V], constant over the interval.
    h : float
        Interval [s]; ``a = exp(-h/tau)`` and ``b = tau (1 - a)`` precomputed for it.
    gain, tau, coulomb, vmax : float
        Plant parameters [counts/s/V], [s], [V], [counts/s]; ``gain`` and ``coulomb`` of the
        positive direction, ``vmax`` both ways.
    gain_neg, coulomb_neg : float or None
        The negative direction's gain [counts/s/V] and Coulomb level [V]; None (default): the
        positive direction's (symmetric). A plant row carries both (:func:`plant_row`).
    q, row, piece : optional
        A resonant plant's modes: their state ``q`` (moved in place over every piece of
        constant target speed, :func:`servotune.resonance.modes_segment`), the plant row that
        holds them, and which of the row's two pieces of a tick ``h`` is (``-1``: neither, the
        coefficients are computed for ``h``).

    Returns
    -------
    p, v : float
        Position and speed at the end.
    """
    if gain_neg is None:
        gain_neg = gain
    if coulomb_neg is None:
        coulomb_neg = coulomb
    if h <= 0.0:
        return p, v
    if v == 0.0:
        if w <= coulomb and w >= -coulomb_neg:
            if q is not None:  # at rest the whole piece: the modes ring out freely
                modes_segment(q, row, R_MODES, piece, h, 0.0, 0.0)
            return p, 0.0
        s = 1.0 if w > 0.0 else -1.0
    else:
        s = 1.0 if v > 0.0 else -1.0
    vinf = _target_speed(s, w, gain, coulomb, gain_neg, coulomb_neg, vmax)
    vend = vinf + (v - vinf) * a
    kinks = coulomb > 0.0 or coulomb_neg > 0.0 or gain_neg != gain  # the model bends at v = 0
    if kinks and v != 0.0 and vinf * s < 0.0 and vend * s <= 0.0:
        # speed reaches zero inside the interval: solve the crossing time exactly
        t0 = tau * math.log((v - vinf) / (-vinf))
        if t0 > h:
            t0 = h
        p += vinf * t0 - (v - vinf) * tau * math.expm1(-t0 / tau)
        hr = h - t0
        if q is not None:
            modes_segment(q, row, R_MODES, -1, t0, vinf, v - vinf)
        if (w <= coulomb and w >= -coulomb_neg) or hr <= 0.0:
            if q is not None and hr > 0.0:
                modes_segment(q, row, R_MODES, -1, hr, 0.0, 0.0)
            return p, 0.0
        # from rest the other way, with that direction's gain and Coulomb level
        s = 1.0 if w > 0.0 else -1.0
        vinf = _target_speed(s, w, gain, coulomb, gain_neg, coulomb_neg, vmax)
        ar = math.exp(-hr / tau)
        p += vinf * hr + vinf * tau * math.expm1(-hr / tau)
        if q is not None:
            modes_segment(q, row, R_MODES, -1, hr, vinf, -vinf)
        return p, vinf * (1.0 - ar)
    if q is not None:
        modes_segment(q, row, R_MODES, piece, h, vinf, v - vinf)
    return p + vinf * h + (v - vinf) * b, vend


@jit
def tick_coefficients(
    period_s: float, lam_s: float, gain: float, tau_s: float
) -> tuple[float, float, float, float, float, float]:
    """Exact one-tick map of the linear part with the input switching at ``lam_s``.

    ``p' = p + phi_b·v + go_p·w_old + gn_p·w_new`` and ``v' = phi_a·v + go_v·w_old + gn_v·w_new``,
    ``w_old`` acting on [0, λ) and ``w_new`` on [λ, T) (ZOH with a fractional lag).

    Returns
    -------
    phi_b, phi_a, go_p, go_v, gn_p, gn_v : float
    """
    a_t, b_t = step_coefficients(period_s, tau_s)
    a1, b1 = step_coefficients(lam_s, tau_s)
    a2, b2 = step_coefficients(period_s - lam_s, tau_s)
    g1_p, g1_v = gain * (lam_s - b1), gain * (1.0 - a1)
    gn_p, gn_v = gain * (period_s - lam_s - b2), gain * (1.0 - a2)
    return b_t, a_t, g1_p + b2 * g1_v, a2 * g1_v, gn_p, gn_v


@jit
def lag_split(lag_s: float, period_s: float) -> tuple[int, float]:
    """Split a lag into whole ticks and a remainder: ``lag_s = m·period_s + λ``, 0 <= λ < T.

    Uses a relative tolerance of 1e-12 so that a lag of exactly m ticks gives λ = 0.
    """
    ratio = lag_s / period_s
    m = math.floor(ratio + 1e-12)
    lam = lag_s - m * period_s
    if lam < period_s * 1e-12:
        lam = 0.0
    return int(m), float(lam)


# --- the discretised plant of one tick (shared by the engine and the identifier) -----------

R_GAIN, R_TAU, R_OFFSET, R_COULOMB, R_VMAX, R_NOISE = 0, 1, 2, 3, 4, 5
R_A1, R_B1, R_A2, R_B2, R_H1, R_H2 = 6, 7, 8, 9, 10, 11
R_PHI_B, R_PHI_A, R_GO_P, R_GO_V, R_GN_P, R_GN_V, R_LINEAR = 12, 13, 14, 15, 16, 17, 18
R_GAIN_NEG, R_COULOMB_NEG = 19, 20
R_MODES = 21
"""Where the modes start in a row (their layout: :mod:`servotune.resonance`)."""
NROW = R_MODES + MODES_HEADER + MAX_MODES * MODE_WIDTH
"""Length of a plant row (:func:`plant_row`)."""


def plant_row(
    plant: Plant, period_s: float, compute_s: float = 0.0, counts_per_rev: float = math.inf
) -> tuple[np.ndarray, int]:
    """Everything :func:`advance_tick` needs for one plant, and the whole ticks of lag.

    Parameters
    ----------
    plant : Plant
    period_s : float
        Tick period [s].
    compute_s : float
        Tick start → D/A write [s]; the motor input lags ``compute_s + delay_s``.
    counts_per_rev : float
        For the drive speed limit [counts/rev] (``inf``: no limit applies).

    Returns
    -------
    row : ndarray, shape (NROW,)
        ``R_GAIN``, ``R_COULOMB`` the positive direction's gain and Coulomb level,
        ``R_GAIN_NEG``, ``R_COULOMB_NEG`` the negative direction's (resolved: equal to the
        positive ones for a symmetric plant); ``R_LINEAR`` is 1 only for a linear model
        (symmetric gain, no friction), where the one-tick map ``R_PHI_B`` … ``R_GN_V`` holds.
    lag_ticks : int
        ``m`` in ``lag = m·T + λ``: the write of tick ``k − m`` acts from ``λ`` into tick ``k``.
    """
    params = parameter_row(plant, counts_per_rev)[None]
    rows = np.zeros((1, NROW))
    lags = np.empty(1, dtype=np.int64)
    fill_plant_rows(params, period_s, compute_s, rows, lags)
    if plant.modes:
        put_modes(rows[0], plant.modes)
    return rows[0], int(lags[0])


def put_modes(row: np.ndarray, modes: tuple[Mode, ...] | np.ndarray) -> None:
    """Write ``modes`` (records, or rows ``freq_hz, damping, gain``) into a filled plant row,
    their coefficients for the row's two pieces of a tick and its time constant."""
    set_modes(row, R_MODES, mode_rows(modes), row[R_H1], row[R_H2], row[R_TAU])


P_GAIN, P_TAU, P_OFFSET, P_COULOMB, P_GAIN_NEG, P_COULOMB_NEG, P_VMAX, P_NOISE, P_DELAY = range(9)
NPARAM = 9
"""Columns of a plant parameter row (:func:`fill_plant_rows`): the positive direction's gain
[counts/s/V], ``tau_s`` [s], ``offset_v`` [V], the positive direction's Coulomb level [V], the
negative direction's gain and Coulomb level (resolved: equal to the positive ones for a
symmetric plant), the speed limit [counts/s] (``inf``: none), ``noise_counts`` [counts],
``delay_s`` [s]."""


def parameter_row(plant: Plant, counts_per_rev: float = math.inf) -> np.ndarray:
    """A plant's parameter row (columns ``P_*``, :data:`NPARAM`) for :func:`fill_plant_rows`:
    the directions' values resolved, the speed limit in counts/s (``inf``: none, or no
    ``counts_per_rev``)."""
    vmax = plant.max_speed_cps(counts_per_rev) if math.isfinite(counts_per_rev) else math.inf
    (_, gain_neg), (_, coulomb_neg) = plant.gains_cps_per_v, plant.coulombs_v
    return np.array(
        [
            plant.gain_cps_per_v,
            plant.tau_s,
            plant.offset_v,
            plant.coulomb_v,
            gain_neg,
            coulomb_neg,
            vmax,
            plant.noise_counts,
            plant.delay_s,
        ]
    )


@jit
def fill_plant_rows(
    params: np.ndarray, period_s: float, compute_s: float, rows: np.ndarray, lags: np.ndarray
) -> None:
    """:func:`plant_row` of many plants at once, compiled: ``rows[i], lags[i]`` of the plant
    whose parameters are ``params[i]`` (columns ``P_*``, :data:`NPARAM`).

    The one place a plant row is computed (:func:`plant_row` calls it for one plant); a
    Monte-Carlo chunk fills its plant sets' rows here without building a :class:`Plant` each.
    """
    for i in range(params.shape[0]):
        gain = params[i, P_GAIN]
        tau = params[i, P_TAU]
        coulomb = params[i, P_COULOMB]
        gain_neg = params[i, P_GAIN_NEG]
        coulomb_neg = params[i, P_COULOMB_NEG]
        m, lam = lag_split(compute_s + params[i, P_DELAY], period_s)
        a1, b1 = step_coefficients(lam, tau)
        a2, b2 = step_coefficients(period_s - lam, tau)
        phi_b, phi_a, go_p, go_v, gn_p, gn_v = tick_coefficients(period_s, lam, gain, tau)
        linear = coulomb == 0.0 and coulomb_neg == 0.0 and gain_neg == gain
        row = rows[i]
        row[R_GAIN] = gain
        row[R_TAU] = tau
        row[R_OFFSET] = params[i, P_OFFSET]
        row[R_COULOMB] = coulomb
        row[R_VMAX] = params[i, P_VMAX]
        row[R_NOISE] = params[i, P_NOISE]
        row[R_A1] = a1
        row[R_B1] = b1
        row[R_A2] = a2
        row[R_B2] = b2
        row[R_H1] = lam
        row[R_H2] = period_s - lam
        row[R_PHI_B] = phi_b
        row[R_PHI_A] = phi_a
        row[R_GO_P] = go_p
        row[R_GO_V] = go_v
        row[R_GN_P] = gn_p
        row[R_GN_V] = gn_v
        row[R_LINEAR] = 1.0 if linear else 0.0
        row[R_GAIN_NEG] = gain_neg
        row[R_COULOMB_NEG] = coulomb_neg
        row[R_MODES] = 0.0  # no modes (:func:`put_modes` adds them)
        row[R_MODES + 1] = 1.0 / tau
        for j in range(R_MODES + MODES_HEADER, NROW):
            row[j] = 0.0
        lags[i] = m


advance_inlined = jit(inline="always")(advance.py_func)
""":func:`advance` compiled into each caller instead of called: the same operations (the same
bits), faster in a kernel where it is the hot path (the lean Monte-Carlo kernel,
:func:`advance_tick_inlined`), at the price of compiling it into that kernel."""


@jit(inline="always")
def _advance_tick_with(step, p, v, w_old, w_new, row, q=None):
    """:func:`advance_tick`'s body, with ``step`` (:func:`advance` or :data:`advance_inlined`)
    for the sub-intervals, and a resonant plant's modes' state ``q`` (None: rigid)."""
    vmax = row[R_VMAX]
    gain = row[R_GAIN]
    if row[R_LINEAR] > 0.0 and abs(w_new) * gain <= vmax and abs(w_old) * gain <= vmax:
        if q is not None:  # the modes over the tick's two pieces of constant target speed
            v_lam = v
            if row[R_H1] > 0.0:
                vinf = gain * w_old
                modes_segment(q, row, R_MODES, 0, row[R_H1], vinf, v - vinf)
                v_lam = vinf + (v - vinf) * row[R_A1]
            vinf = gain * w_new
            modes_segment(q, row, R_MODES, 1, row[R_H2], vinf, v_lam - vinf)
        p_n = p + row[R_PHI_B] * v + row[R_GO_P] * w_old + row[R_GN_P] * w_new
        v_n = row[R_PHI_A] * v + row[R_GO_V] * w_old + row[R_GN_V] * w_new
        return p_n, v_n
    if row[R_H1] > 0.0:
        p, v = step(
            p,
            v,
            w_old,
            row[R_H1],
            row[R_A1],
            row[R_B1],
            gain,
            row[R_TAU],
            row[R_COULOMB],
            vmax,
            row[R_GAIN_NEG],
            row[R_COULOMB_NEG],
            q,
            row,
            0,
        )
    return step(
        p,
        v,
        w_new,
        row[R_H2],
        row[R_A2],
        row[R_B2],
        gain,
        row[R_TAU],
        row[R_COULOMB],
        vmax,
        row[R_GAIN_NEG],
        row[R_COULOMB_NEG],
        q,
        row,
        1,
    )


@jit(inline="always")
def advance_tick(
    p: float, v: float, w_old: float, w_new: float, row: np.ndarray
) -> tuple[float, float]:
    """Move a plant over one tick: input ``w_old`` for ``λ``, then ``w_new`` [V, net of offset].

    Uses the exact linear one-tick map while no nonlinearity can act (a linear model: no
    friction and the same gain both ways; and the speed limit cannot bind for either input),
    else :func:`advance` on both sub-intervals.
    """
    return _advance_tick_with(advance, p, v, w_old, w_new, row)


@jit(inline="always")
def advance_tick_inlined(
    p: float, v: float, w_old: float, w_new: float, row: np.ndarray
) -> tuple[float, float]:
    """:func:`advance_tick` with :func:`advance` compiled in (:data:`advance_inlined`): the
    same bits; for the lean Monte-Carlo kernel, where the two sub-interval steps are a third of
    the time (the other kernels call it, which compiles faster)."""
    return _advance_tick_with(advance_inlined, p, v, w_old, w_new, row)


@jit(inline="always")
def advance_tick_modal(
    p: float, v: float, q: np.ndarray, w_old: float, w_new: float, row: np.ndarray
) -> tuple[float, float]:
    """:func:`advance_tick` of a plant that may have modes: their state ``q`` (shape
    ``2·MAX_MODES``, :mod:`servotune.resonance`) moves exactly with the rigid part over each
    piece of the tick. Without modes it is :func:`advance_tick` (the same bits; ``q`` is not
    touched)."""
    if row[R_MODES] == 0.0:
        return _advance_tick_with(advance, p, v, w_old, w_new, row)
    return _advance_tick_with(advance, p, v, w_old, w_new, row, q)


@jit(inline="always")
def _advance_for(p: float, v: float, w: float, h: float, row: np.ndarray) -> tuple[float, float]:
    """:func:`advance` over ``h`` seconds, its coefficients computed for ``h``."""
    tau = row[R_TAU]
    return advance(
        p,
        v,
        w,
        h,
        math.exp(-h / tau),
        -tau * math.expm1(-h / tau),
        row[R_GAIN],
        tau,
        row[R_COULOMB],
        row[R_VMAX],
        row[R_GAIN_NEG],
        row[R_COULOMB_NEG],
    )


@jit(inline="always")
def advance_span(
    p: float, v: float, w_old: float, w_new: float, lam: float, h: float, row: np.ndarray
) -> tuple[float, float]:
    """Move a plant over ``h`` seconds from a tick start: ``w_old`` until ``lam``, then ``w_new``.

    :func:`advance_tick` for a span whose length is not the row's tick (a slave CPU's tick
    stretched by a clock sync, the state inside a tick): the same exact solution, coefficients
    computed for these lengths.

    Parameters
    ----------
    p, v : float
        Position [counts] and speed [counts/s] at the tick start.
    w_old, w_new : float
        Net inputs before and from ``lam`` [V].
    lam : float
        When the input switches, from the tick start [s], >= 0.
    h : float
        Length of the span [s], >= 0.
    row : ndarray
        The plant's row (:func:`plant_row`).
    """
    if h <= lam:
        return _advance_for(p, v, w_old, h, row)
    if lam > 0.0:
        p, v = _advance_for(p, v, w_old, lam, row)
    return _advance_for(p, v, w_new, h - lam, row)
