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
from typing import TYPE_CHECKING

import numpy as np

from servotune._control import scipy_paths
from servotune._numba_cache import jit
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
    "discretize",
    "discretize_lti",
    "fill_plant_rows",
    "lag_split",
    "plant_row",
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

    def __post_init__(self) -> None:
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
        """Linear part without the delay: ``gain / (s (tau s + 1))`` [counts/V].

        The delay ``exp(-delay_s s)`` is not rational; :func:`discretize` includes it exactly.
        Offset and friction are left out; the gain of an asymmetric plant is the mean of its
        two directions' gains (:attr:`mean_gain_cps_per_v`).
        """
        import control

        return control.tf([self.mean_gain_cps_per_v], [self.tau_s, 1.0, 0.0])

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

    def to_dict(self) -> dict[str, float | None]:
        """Plain dict with the axis model's parameter names (docs/formats.md#axis-model)."""
        return {
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
        if (w <= coulomb and w >= -coulomb_neg) or hr <= 0.0:
            return p, 0.0
        # from rest the other way, with that direction's gain and Coulomb level
        s = 1.0 if w > 0.0 else -1.0
        vinf = _target_speed(s, w, gain, coulomb, gain_neg, coulomb_neg, vmax)
        ar = math.exp(-hr / tau)
        p += vinf * hr + vinf * tau * math.expm1(-hr / tau)
        return p, vinf * (1.0 - ar)
    return p + vinf * h + (v - vinf) * b, vend


def discretize(plant: Plant, period_s: float, lag_s: float = 0.0) -> control.StateSpace:
    """Exact ZOH discretisation of the linear part, with a total input lag.

    The input (volts) is written every ``period_s`` and reaches the motor ``lag_s`` later
    (compute time + ``delay_s``); with ``lag_s = m·T + λ`` the input changes inside each tick at
    ``λ`` (modified z-transform). Offset, friction and speed limit are left out; an asymmetric
    plant enters with the mean of its two directions' gains (:attr:`Plant.mean_gain_cps_per_v`),
    a symmetric one with ``gain_cps_per_v`` exactly.

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
        position, speed and the ``m + 1`` (or ``m``, if λ = 0) held past inputs.
    """
    import control

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
NROW = 21
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
    vmax = plant.max_speed_cps(counts_per_rev) if math.isfinite(counts_per_rev) else math.inf
    (_, gain_neg), (_, coulomb_neg) = plant.gains_cps_per_v, plant.coulombs_v
    params = np.array(
        [
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
        ]
    )
    rows = np.empty((1, NROW))
    lags = np.empty(1, dtype=np.int64)
    fill_plant_rows(params, period_s, compute_s, rows, lags)
    return rows[0], int(lags[0])


P_GAIN, P_TAU, P_OFFSET, P_COULOMB, P_GAIN_NEG, P_COULOMB_NEG, P_VMAX, P_NOISE, P_DELAY = range(9)
NPARAM = 9
"""Columns of a plant parameter row (:func:`fill_plant_rows`): the positive direction's gain
[counts/s/V], ``tau_s`` [s], ``offset_v`` [V], the positive direction's Coulomb level [V], the
negative direction's gain and Coulomb level (resolved: equal to the positive ones for a
symmetric plant), the speed limit [counts/s] (``inf``: none), ``noise_counts`` [counts],
``delay_s`` [s]."""


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
        lags[i] = m


advance_inlined = jit(inline="always")(advance.py_func)
""":func:`advance` compiled into each caller instead of called: the same operations (the same
bits), faster in a kernel where it is the hot path (the lean Monte-Carlo kernel,
:func:`advance_tick_inlined`), at the price of compiling it into that kernel."""


@jit(inline="always")
def _advance_tick_with(step, p, v, w_old, w_new, row):
    """:func:`advance_tick`'s body, with ``step`` (:func:`advance` or :data:`advance_inlined`)
    for the sub-intervals."""
    vmax = row[R_VMAX]
    gain = row[R_GAIN]
    if row[R_LINEAR] > 0.0 and abs(w_new) * gain <= vmax and abs(w_old) * gain <= vmax:
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
    from scipy.linalg import expm

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
