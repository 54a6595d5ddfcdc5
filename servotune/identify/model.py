"""The model the identifier fits, simulated from a command: parameters, bounds, sensitivities.

The axis model (docs/formats.md#axis-model, :class:`servotune.plant.Plant`) is simulated tick by
tick with the engine's exact step (:func:`servotune.plant.advance_tick`: ZOH, fractional lag,
Coulomb stick/slip, a per-direction gain and Coulomb level for the asymmetric form), driven by a
command sequence; what is compared with a log is the position increment per tick (the increment form
keeps the simulation of an integrating plant stable, and needs no initial position).

The parameter vector has a fixed order (:data:`ALL_PARAMS`); a boolean mask says which entries
a structure estimates (the others stay 0, or for the negative direction equal the positive one).
Several parameter vectors — and several commands (the logged one and its projection on the
external signals, :mod:`servotune.identify.iv`) — are simulated at once, each by a compiled
kernel that runs without the GIL, in threads for long logs: the forward-difference
sensitivities the estimators need cost one pass over the log per column, spread over the
cores.

Also here: the inverse-dynamics least-squares start and its direction check (a reversed encoder
or D/A is recognised before any fit).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from servotune._numba_cache import call_compiled, jit
from servotune.errors import IdentificationError
from servotune.identify.noise import NoiseModel
from servotune.plant import (
    NROW,
    R_MODES,
    R_OFFSET,
    Plant,
    advance_tick,
    advance_tick_modal,
    plant_row,
)
from servotune.resonance import MAX_MODES, modes_output

__all__ = [
    "ALL_PARAMS",
    "ASYM_PARAMS",
    "MAX_DELAY_TICKS",
    "OPTIONAL_PARAMS",
    "PARAMS",
    "UNITS",
    "Estimate",
    "check_direction",
    "free_mask",
    "lower_bounds",
    "ls_start",
    "names",
    "plant_from",
    "simulate_increments",
    "simulate_plant",
    "upper_bounds",
]

PARAMS = ("gain_cps_per_v", "tau_s", "delay_s", "offset_v", "coulomb_v")
"""The axis model's parameters, in the order of the internal vector."""
ASYM_PARAMS = ("gain_neg_cps_per_v", "coulomb_neg_v")
"""The negative direction's gain and Coulomb level (asymmetric friction form,
docs/formats.md#asymmetric-friction)."""
ALL_PARAMS = PARAMS + ASYM_PARAMS
"""The internal parameter vector."""
OPTIONAL_PARAMS = ("delay_s", "offset_v", "coulomb_v")
"""Terms a structure may leave out (gain and tau are always estimated)."""
UNITS = {
    "gain_cps_per_v": "counts/s/V",
    "tau_s": "s",
    "delay_s": "s",
    "offset_v": "V",
    "coulomb_v": "V",
    "gain_neg_cps_per_v": "counts/s/V",
    "coulomb_neg_v": "V",
}
"""Unit of each parameter."""
MAX_DELAY_TICKS = 4.0
"""Largest delay the fit considers [ticks] (beyond the known compute time)."""

I_GAIN, I_TAU, I_DELAY, I_OFFSET, I_COULOMB, I_GAIN_NEG, I_COULOMB_NEG = range(7)
_ALIASES = {"gain": "gain_cps_per_v", "tau": "tau_s", "delay": "delay_s", "offset": "offset_v",
            "coulomb": "coulomb_v"}  # fmt: skip


@dataclass(frozen=True, slots=True, kw_only=True)
class Estimate:
    """What an estimator found, with what its uncertainty and its diagnostics need.

    The estimate solves estimating equations ``Σ_k s_k(θ) = 0``; linearised,
    ``θ̂ − θ = A⁻¹ Σ_k s_k`` (:func:`servotune.identify.quality.block_bootstrap`).

    Attributes
    ----------
    x : ndarray
        Parameter vector (:data:`ALL_PARAMS` order).
    a_mat : ndarray, shape (p, p)
        ``A``: the estimating equations differentiated at ``x``.
    scores : ndarray, shape (n, p)
        ``s_k``: the equations' terms at ``x``.
    residual : ndarray
        Output error at ``x`` [counts per tick], from the first sample used.
    whitened : ndarray
        The residual whitened by :attr:`noise` (its innovations) [counts per tick].
    noise : NoiseModel
        The residual's ARMA model.
    instruments, sensitivities : ndarray, shape (p, n)
        Per sample, what ``a_mat`` sums: ``a_mat = instruments @ sensitivities.T`` (and the
        scores are the instruments times the residual as the equations weigh it), so the
        equations of any stretch of the log can be formed again (the one-step estimates of
        the cross-validation).
    simulated : ndarray or None
        The model at ``x`` simulated from the logged command over the whole log, from its
        first sample (:func:`simulate_increments`, the initial speed from the first five
        increments) [counts per tick], when the estimator has it: the whole-log fit % needs
        no simulation of its own.
    """

    x: np.ndarray
    a_mat: np.ndarray
    scores: np.ndarray
    residual: np.ndarray
    whitened: np.ndarray
    noise: NoiseModel
    instruments: np.ndarray
    sensitivities: np.ndarray
    simulated: np.ndarray | None = None


def names(free: np.ndarray) -> tuple[str, ...]:
    """Names of the estimated parameters of a mask."""
    return tuple(p for p, f in zip(ALL_PARAMS, free, strict=True) if f)


def free_mask(terms: tuple[str, ...] | list[str], friction: str) -> np.ndarray:
    """The mask of a structure: gain, tau, the given optional terms, and the friction form.

    ``friction="asym"`` adds the negative direction's gain, and its Coulomb level when the
    structure has Coulomb friction and no offset: while the axis moves, an offset ``o`` and
    Coulomb levels ``c⁺, c⁻`` act only as ``o − c⁺`` (moving up) and ``o + c⁻`` (moving down),
    so with an offset in the structure the two levels are not separately identifiable (only the
    breakaway band at rest would tell them apart) and the asymmetric form keeps one level.
    """
    free = np.zeros(len(ALL_PARAMS), dtype=bool)
    free[I_GAIN] = free[I_TAU] = True
    for t in terms:
        free[ALL_PARAMS.index(_ALIASES.get(t, t))] = True
    if friction == "asym":
        free[I_GAIN_NEG] = True
        free[I_COULOMB_NEG] = free[I_COULOMB] and not free[I_OFFSET]
    return free


def parse_terms(structure: str | tuple[str, ...] | list[str] | None) -> tuple[str, ...] | None:
    """The optional terms of a ``--structure`` value; None for ``None`` or ``"auto"``.

    Raises
    ------
    IdentificationError
        For a name that is not one of delay, offset, coulomb (or their full names).
    """
    if structure is None or structure == "auto":
        return None
    given = structure.split(",") if isinstance(structure, str) else list(structure)
    terms = [_ALIASES.get(s.strip(), s.strip()) for s in given if s.strip()]
    bad = [s for s in terms if s not in PARAMS]
    if bad:
        raise IdentificationError(
            f"unknown structure parameter {bad[0]!r}; choose from gain, tau, delay, offset, "
            "coulomb (gain and tau are always estimated; the friction form is --friction)"
        )
    return tuple(dict.fromkeys(t for t in terms if t in OPTIONAL_PARAMS))


def lower_bounds() -> np.ndarray:
    """Lower bound of every parameter (gains and tau positive, delay and friction >= 0)."""
    return np.array([1e-9, 1e-5, 0.0, -1.0, 0.0, 1e-9, 0.0])


def upper_bounds(period_s: float) -> np.ndarray:
    """Upper bound of every parameter (delay within :data:`MAX_DELAY_TICKS`)."""
    return np.array([1e12, 10.0, MAX_DELAY_TICKS * period_s, 1.0, 5.0, 1e12, 5.0])


def fd_steps(x: np.ndarray, period_s: float) -> np.ndarray:
    """Forward-difference steps of the sensitivities, per parameter [parameter units]."""
    return np.array(
        [
            max(abs(x[0]) * 1e-5, 1e-6),
            max(abs(x[1]) * 1e-4, 1e-7),
            period_s * 1e-3,
            2e-6,
            2e-6,
            max(abs(x[5]) * 1e-5, 1e-6),
            2e-6,
        ]
    )


def typical_scale(x: np.ndarray, period_s: float) -> np.ndarray:
    """A typical size of each parameter, for scaled steps and tolerances [parameter units]."""
    return np.array(
        [max(abs(x[0]), 1.0), max(abs(x[1]), 1e-3), period_s, 1e-3, 1e-3, max(abs(x[5]), 1.0), 1e-3]
    )


def plant_from(x: np.ndarray, free: np.ndarray) -> Plant:
    """The :class:`~servotune.plant.Plant` of a parameter vector (left-out terms 0 / symmetric)."""
    asym = bool(free[I_GAIN_NEG])
    return Plant(
        gain_cps_per_v=float(x[I_GAIN]),
        tau_s=float(x[I_TAU]),
        delay_s=float(max(x[I_DELAY], 0.0)) if free[I_DELAY] else 0.0,
        offset_v=float(x[I_OFFSET]) if free[I_OFFSET] else 0.0,
        coulomb_v=float(max(x[I_COULOMB], 0.0)) if free[I_COULOMB] else 0.0,
        gain_neg_cps_per_v=float(x[I_GAIN_NEG]) if asym else None,
        coulomb_neg_v=float(max(x[I_COULOMB_NEG], 0.0)) if free[I_COULOMB_NEG] else None,
    )


# --- simulation -----------------------------------------------------------------------------


@jit(nogil=True)
def _increments(u: np.ndarray, row: np.ndarray, m: int, v0: float, out: np.ndarray) -> None:
    """Position increment over each tick [counts] of one plant row driven by the command ``u``;
    of a resonant row (:mod:`servotune.resonance`), the measured position's, its modes at rest
    at the start (moving steadily at ``v0``: ``q̇ = 0``, so ``w = −v0``).

    Compiled without the GIL: the rows of :func:`simulate_increments` run in threads.
    """
    v = v0
    off = row[R_OFFSET]
    n_modes = int(row[R_MODES])
    q = np.zeros(2 * MAX_MODES)
    for i in range(n_modes):
        q[2 * i + 1] = -v0
    y_modes = 0.0
    for k in range(out.shape[0]):
        j_new = k - m
        j_old = j_new - 1
        w_new = (u[j_new] if j_new >= 0 else u[0]) + off
        w_old = (u[j_old] if j_old >= 0 else u[0]) + off
        if n_modes == 0:
            dp, v = advance_tick(0.0, v, w_old, w_new, row)
            out[k] = dp
        else:
            dp, v = advance_tick_modal(0.0, v, q, w_old, w_new, row)
            y_new = modes_output(0.0, q, row, R_MODES)
            out[k] = dp + (y_new - y_modes)
            y_modes = y_new


def simulate_plant(
    plant: Plant, cmd_v: np.ndarray, *, period_s: float, compute_s: float, v0: float
) -> np.ndarray:
    """The measured position's increment over each tick [counts] of ``plant`` (its modes
    included) driven by ``cmd_v`` [V] (row k written at ``t_k + compute_s``), from the speed
    ``v0`` [counts/s] with its modes at rest."""
    row, lag = plant_row(plant, period_s, compute_s)
    u = np.ascontiguousarray(cmd_v, dtype=float)
    out = np.empty(u.size)
    call_compiled(_increments, u, row, int(lag), float(v0), out)
    return out


PARALLEL_STEPS = 4_000_000
"""Simulated ticks (rows × samples) from which the rows run in threads, one per core."""


def simulate_increments(
    inputs: np.ndarray | Sequence[np.ndarray],
    xs: list[np.ndarray],
    free: np.ndarray,
    which: list[int],
    *,
    period_s: float,
    compute_s: float,
    v0: float,
) -> np.ndarray:
    """Simulate several parameter vectors, each on one of several commands, in parallel.

    Parameters
    ----------
    inputs : ndarray, shape (n_inputs, n), or sequence of ndarray, shape (n,)
        Commands [V], one per row (row k written at ``t_k + compute_s``); a sequence of rows
        spares stacking long ones into one array.
    xs : list of ndarray
        Parameter vectors (:data:`ALL_PARAMS` order).
    free : ndarray of bool
        The structure (:func:`free_mask`).
    which : list of int
        For each vector, the row of ``inputs`` that drives it.
    period_s, compute_s : float
        Tick and known compute time [s].
    v0 : float
        Initial speed [counts/s].

    Returns
    -------
    ndarray, shape (len(xs), n)
        Position increment over each tick [counts].
    """
    rows = np.empty((len(xs), NROW))
    lags = np.empty(len(xs), dtype=np.int64)
    for r, x in enumerate(xs):
        rows[r], lags[r] = plant_row(plant_from(x, free), period_s, compute_s)
    if isinstance(inputs, np.ndarray):
        commands = np.ascontiguousarray(inputs, dtype=float)
        n = commands.shape[1]
    else:
        commands = [np.ascontiguousarray(c, dtype=float) for c in inputs]
        n = commands[0].shape[0]
        if any(c.shape != (n,) for c in commands):
            raise ValueError("every command of simulate_increments needs the same length")
    out = np.empty((len(xs), n))

    def run(r: int) -> None:
        call_compiled(_increments, commands[which[r]], rows[r], int(lags[r]), float(v0), out[r])

    workers = min(len(xs), os.cpu_count() or 1)
    if out.size < PARALLEL_STEPS or workers < 2:
        for r in range(len(xs)):
            run(r)
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(run, range(len(xs))))
    return out


def sensitivities(
    inputs: np.ndarray | Sequence[np.ndarray],
    x: np.ndarray,
    free: np.ndarray,
    which_inputs: tuple[int, ...],
    *,
    period_s: float,
    compute_s: float,
    v0: float,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The simulated increments and their forward-difference sensitivities, per command.

    Returns
    -------
    list of (base, jac)
        For each row of ``inputs`` named in ``which_inputs``: ``base`` (n,) the increments at
        ``x`` [counts] and ``jac`` (n_free, n) their derivatives by the free parameters (one
        row per parameter: the layout the filters and products run along).
    """
    steps = fd_steps(x, period_s)
    idx = np.flatnonzero(free)
    xs: list[np.ndarray] = []
    which: list[int] = []
    for w in which_inputs:
        xs.append(x)
        which.append(w)
        for i in idx:
            xi = x.copy()
            xi[i] += steps[i]
            xs.append(xi)
            which.append(w)
    sim = simulate_increments(
        inputs, xs, free, which, period_s=period_s, compute_s=compute_s, v0=v0
    )
    out = []
    per = idx.size + 1
    for j in range(len(which_inputs)):
        base = sim[j * per]
        jac = sim[j * per + 1 : (j + 1) * per]  # the differences made in place: no temporaries
        np.subtract(jac, base, out=jac)
        np.divide(jac, steps[idx][:, None], out=jac)
        out.append((base, jac))
    return out


def clip_to_bounds(x: np.ndarray, free: np.ndarray, period_s: float) -> np.ndarray:
    """``x`` with its free entries inside the bounds (the others unchanged)."""
    y = x.copy()
    lo, hi = lower_bounds(), upper_bounds(period_s)
    y[free] = np.clip(y[free], lo[free], hi[free])
    return y


# --- the least-squares start and the direction check -----------------------------------------


def derivatives(y: np.ndarray, period_s: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Speed and acceleration from a moving-average-smoothed position (central differences).

    Only the start uses them; the estimators do not differentiate. Returns the speed
    [counts/s], the acceleration [counts/s²] and the edge to leave out [samples].
    """
    h = max(2, math.floor(0.01 / period_s + 0.5))  # about 10 ms each side
    box = np.ones(2 * h + 1) / (2 * h + 1)
    ys = np.convolve(y.astype(float), box, mode="same")
    v = np.zeros_like(ys)
    a = np.zeros_like(ys)
    v[h:-h] = (ys[2 * h :] - ys[: -2 * h]) / (2 * h * period_s)
    a[h:-h] = (ys[2 * h :] - 2 * ys[h:-h] + ys[: -2 * h]) / (h * period_s) ** 2
    return v, a, 3 * h


def _moving(v: np.ndarray, w: int, period_s: float) -> np.ndarray:
    keep = np.abs(v) > 2.0 / period_s  # moving: more than 2 counts per tick
    keep[:w] = keep[-w:] = False
    if keep.sum() < 20:
        keep = np.abs(v) > 0.2 / period_s
        keep[:w] = keep[-w:] = False
    if keep.sum() < 20:
        raise IdentificationError("the motor hardly moved: fewer than 20 moving samples")
    return keep


DIRECTION_SAMPLES = 200_000
"""Samples (the first ones) the direction check looks at."""


def check_direction(u: np.ndarray, y: np.ndarray, period_s: float, compute_s: float) -> None:
    """Refuse a log whose axis moves against, or not with, its command.

    The steady-speed gain of a least-squares fit of the (smoothed) speed on the command and a
    constant, at the delay of best fit, must be positive and explain a visible part of the
    motion; otherwise the encoder or the D/A sign is reversed (or the command does not reach
    the drive), and no fit can be trusted.

    Only the first :data:`DIRECTION_SAMPLES` samples are looked at (the wiring does not
    change within a log).

    Raises
    ------
    IdentificationError
        Naming the likely cause and ``--invert-encoder``.
    """
    u, y = u[:DIRECTION_SAMPLES], y[:DIRECTION_SAMPLES]
    v, _, w = derivatives(y, period_s)
    keep = _moving(v, w, period_s)
    n = y.size
    idx = np.flatnonzero(keep)
    vk = v[keep] - np.mean(v[keep])
    best = None
    svv = float(np.dot(vk, vk))
    for lag in sorted(
        {
            math.ceil((compute_s + d) / period_s - 1e-12)
            for d in np.arange(0, 4 * int(MAX_DELAY_TICKS) + 1) * 0.25 * period_s
        }
    ):
        ud = u[np.clip(idx - lag, 0, n - 1)]
        ud = ud - np.mean(ud)
        suu = float(np.dot(ud, ud))
        suv = float(np.dot(ud, vk))
        gain = suv / suu if suu > 0 else 0.0
        rss = svv - gain * suv
        if best is None or rss < best[0]:
            best = (rss, gain, math.sqrt(suu / ud.size))
    assert best is not None
    _, gain, su = best
    sv = float(np.std(v[keep]))
    if gain <= 0.0:
        raise IdentificationError(
            f"the axis moves against its command (steady-speed gain {gain:.4g} counts/s/V "
            f"< 0): the encoder or the D/A sign is reversed; fix the wiring or the counter "
            f"direction, or re-run with --invert-encoder to negate the position"
        )
    if gain * su < 0.05 * sv:
        raise IdentificationError(
            f"the axis does not move with its command (steady-speed gain {gain:.3g} "
            f"counts/s/V explains {100 * gain * su / max(sv, 1e-300):.2g} % of the speed): "
            f"the encoder or the D/A sign may be reversed, or the command does not reach the "
            f"drive; check the wiring, or re-run with --invert-encoder to negate the position"
        )


def ls_start(
    u: np.ndarray, y: np.ndarray, period_s: float, compute_s: float, free: np.ndarray
) -> np.ndarray:
    """Inverse-dynamics least squares on filtered derivatives, best delay on a grid.

    ``v = K·u(t − lag) − tau·a + K·offset − K·coulomb·sign(v)`` is linear in
    ``(K, tau, K·offset, K·coulomb)`` for a given lag; samples at near-zero speed are left out.
    An asymmetric structure starts symmetric (the negative direction's values equal).
    """
    n = y.size
    v, a, w = derivatives(y, period_s)
    keep = _moving(v, w, period_s)
    grid = np.arange(0, 4 * int(MAX_DELAY_TICKS) + 1) * 0.25 * period_s if free[2] else [0.0]
    idx = np.arange(n)
    best = None
    for d in grid:
        j = idx - math.ceil((compute_s + d) / period_s - 1e-12)
        ud = u[np.clip(j, 0, n - 1)]
        cols = [ud[keep], -a[keep]]
        if free[I_OFFSET]:
            cols.append(np.ones(keep.sum()))
        if free[I_COULOMB]:
            cols.append(-np.sign(v[keep]))
        phi = np.column_stack(cols)
        theta, *_ = np.linalg.lstsq(phi, v[keep], rcond=None)
        rss = float(np.sum((v[keep] - phi @ theta) ** 2))
        if best is None or rss < best[0]:
            best = (rss, d, theta)
    assert best is not None
    _, d, theta = best
    k_gain = float(theta[0]) if theta[0] > 0 else float(np.std(v) / max(np.std(u), 1e-9))
    tau = float(np.clip(theta[1], 1e-4, 5.0))
    x = np.zeros(len(ALL_PARAMS))
    x[I_GAIN], x[I_TAU], x[I_DELAY] = k_gain, tau, d
    i = 2
    if free[I_OFFSET]:
        x[I_OFFSET] = float(np.clip(theta[i] / k_gain, -0.5, 0.5))
        i += 1
    if free[I_COULOMB]:
        x[I_COULOMB] = float(np.clip(theta[i] / k_gain, 0.0, 1.0))
    x[I_GAIN_NEG] = x[I_GAIN]
    x[I_COULOMB_NEG] = x[I_COULOMB]
    return x
