"""Identify the axis model (SPEC §5) from a logged experiment.

Method (what runs when):

1. **Start** — inverse-dynamics least squares on filtered derivatives of the position
   (moving average, then central differences):
   ``v = K·u(t − lag) − tau·a + K·offset − K·coulomb·sign(v)`` is linear in
   ``(K, tau, K·offset, K·coulomb)`` for a given lag, so it is solved on a grid of delays
   (quarter ticks up to :data:`MAX_DELAY_TICKS`) and the best grid point is kept. Samples at
   near-zero speed are left out of this step (the sign of the speed is unknown there).
2. **Refinement** — output-error least squares: the model is *simulated* from the logged
   command with the same exact tick step the engine uses (ZOH, fractional lag, Coulomb
   stick/slip, :func:`servotune.plant.advance_tick`) and its position increment per tick is fitted
   to the logged one (``scipy.optimize.least_squares``, trust-region reflective, bounds). The
   increment form keeps the simulation stable for an integrating plant and is consistent in
   closed loop (the logged command is used, the noise is on the measurement). At most
   :data:`MAX_FIT_SAMPLES` samples of the estimation part are used.
3. **Structure** — with ``structure=None`` every structure (gain and tau, plus any subset of
   delay, offset and Coulomb) is fitted on the first :data:`SELECTION_SAMPLES` samples and the
   one with the smallest BIC (``n·ln(RSS/n) + k·ln(n)``) is kept; the reason is reported.
4. **Uncertainty** — ``cov = s²·(JᵀJ)⁻¹`` from the Jacobian at the optimum, scaled by the
   long-run variance factor ``1 + 2·Σρ_j`` of the residuals (the increments of a quantised
   position are MA(1)-correlated); 95 % intervals are ±1.96 std.
5. **Quality** — fit % (MATLAB ``compare``: ``100·(1 − ‖y − ŷ‖/‖y − mean(y)‖)``) for
   velocity and position on the estimation (first 70 %) and validation (last 30 %) parts, and a
   Ljung–Box whiteness test on the position residual.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.optimize import least_squares
from scipy.special import gammaincc

from servotune._numba_cache import jit
from servotune.errors import IdentificationError
from servotune.logs import AxisLog, Log
from servotune.plant import Plant, advance_tick, discretize, plant_row

if TYPE_CHECKING:
    import control

__all__ = [
    "MAX_FIT_SAMPLES",
    "OPTIONAL_PARAMS",
    "PARAMS",
    "FitResult",
    "PoorFitWarning",
    "fit",
    "fit_arrays",
    "simulate_fit",
]

PARAMS = ("gain_cps_per_v", "tau_s", "delay_s", "offset_v", "coulomb_v")
"""Parameter names (SPEC §5), in the order of the internal vector."""
OPTIONAL_PARAMS = ("delay_s", "offset_v", "coulomb_v")
MAX_DELAY_TICKS = 4.0
MAX_FIT_SAMPLES = 100_000
SELECTION_SAMPLES = 20_000
MIN_SAMPLES = 100
ESTIMATION_FRACTION = 0.7


class PoorFitWarning(UserWarning):
    """The identified model explains the data poorly (low validation fit)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class FitResult:
    """An identified axis model. Estimated quantities are marked as fitted results.

    Attributes
    ----------
    structure : tuple of str
        Parameters estimated (always ``gain_cps_per_v`` and ``tau_s``).
    params : dict
        Fitted value of every SPEC parameter (0 for those left out) [units in the names].
    std, ci95 : dict
        Standard deviation and 95 % interval of the estimated parameters.
    fit_pct : dict
        ``{"position"|"velocity": {"estimation": %, "validation": %}}``.
    whiteness : dict
        Ljung–Box test of the position residual: statistic, lags, p-value, white (p > 0.01).
    period_s, compute_s : float
        Sample period and the known compute time the delay is counted beyond [s].
    selection : list of dict
        Per candidate structure: parameters, RSS, BIC (empty when the structure was given).
    reason : str
        Why this structure.
    n_samples : int
    """

    structure: tuple[str, ...]
    params: dict[str, float]
    std: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    fit_pct: dict[str, dict[str, float]]
    whiteness: dict[str, Any]
    period_s: float
    compute_s: float
    selection: list[dict[str, Any]] = field(default_factory=list)
    reason: str = ""
    n_samples: int = 0

    @property
    def plant(self) -> Plant:
        """The fitted axis model as a :class:`~servotune.plant.Plant`."""
        return Plant(**{k: float(self.params[k]) for k in PARAMS})

    @property
    def model(self) -> control.TransferFunction:
        """Continuous ``K / (s (tau s + 1))`` [counts/V] (the delay is in :attr:`params`)."""
        return self.plant.to_tf()

    @property
    def discrete_model(self) -> control.StateSpace:
        """Exact ZOH model at the log's period with the total lag (compute + delay)."""
        return discretize(self.plant, self.period_s, self.compute_s + self.params["delay_s"])

    def summary(self) -> str:
        """A readable multi-line summary (what ``servotune fit`` prints on stderr)."""
        units = {"gain_cps_per_v": "counts/s/V", "tau_s": "s", "delay_s": "s",
                 "offset_v": "V", "coulomb_v": "V"}  # fmt: skip
        lines = [f"structure: {' + '.join(self.structure)} ({self.reason})"]
        for p in PARAMS:
            if p in self.structure:
                lo, hi = self.ci95[p]
                lines.append(
                    f"  {p:15s} {self.params[p]:12.6g} ± {self.std[p]:.2g} {units[p]} "
                    f"(95 %: {lo:.6g} … {hi:.6g})"
                )
            else:
                lines.append(f"  {p:15s} {'left out':>12s}")
        f = self.fit_pct
        lines.append(
            f"fit (MATLAB compare) velocity {f['velocity']['estimation']:.1f} % estimation, "
            f"{f['velocity']['validation']:.1f} % validation; position "
            f"{f['position']['estimation']:.1f} % / {f['position']['validation']:.1f} %"
        )
        w = self.whiteness
        lines.append(
            f"position residual whiteness (Ljung-Box, {w['lags']} lags): p = {w['p_value']:.3g}"
            f" ({'white' if w['white'] else 'not white'})"
        )
        lines.append(f"period {self.period_s * 1e3:.6g} ms, {self.n_samples} samples, "
                     f"delay counted beyond compute_s = {self.compute_s * 1e3:g} ms")  # fmt: skip
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON (sorted keys when dumped with ``sort_keys``)."""
        return {
            "ci95": {k: [float(a), float(b)] for k, (a, b) in self.ci95.items()},
            "compute_s": self.compute_s,
            "fit_pct": self.fit_pct,
            "n_samples": self.n_samples,
            "params": {k: float(v) for k, v in self.params.items()},
            "period_s": self.period_s,
            "reason": self.reason,
            "selection": self.selection,
            "std": {k: float(v) for k, v in self.std.items()},
            "structure": list(self.structure),
            "whiteness": self.whiteness,
        }


# --- simulation of the model from the logged command ---------------------------------------


@jit
def _increments(u: np.ndarray, row: np.ndarray, m: int, v0: float, out: np.ndarray) -> None:
    """Position increment of the model over each tick, driven by the logged command [counts]."""
    v = v0
    off = row[2]  # R_OFFSET
    for k in range(out.shape[0]):
        j_new = k - m
        j_old = j_new - 1
        w_new = (u[j_new] if j_new >= 0 else u[0]) + off
        w_old = (u[j_old] if j_old >= 0 else u[0]) + off
        dp, v = advance_tick(0.0, v, w_old, w_new, row)
        out[k] = dp


def _plant_from(x: np.ndarray) -> Plant:
    return Plant(
        gain_cps_per_v=float(x[0]),
        tau_s=float(x[1]),
        delay_s=float(max(x[2], 0.0)),
        offset_v=float(x[3]),
        coulomb_v=float(max(x[4], 0.0)),
    )


class _Problem:
    """Output-error problem on a block of the log."""

    def __init__(self, u: np.ndarray, dy: np.ndarray, period_s: float, compute_s: float,
                 skip: int) -> None:  # fmt: skip
        self.u = np.ascontiguousarray(u, dtype=float)
        self.dy = np.ascontiguousarray(dy, dtype=float)
        self.period_s = period_s
        self.compute_s = compute_s
        self.skip = skip
        self.v0 = float(np.mean(dy[: max(1, min(5, dy.size))]) / period_s)
        self._buf = np.empty(dy.size)

    def simulate(self, x: np.ndarray) -> np.ndarray:
        row, m = plant_row(_plant_from(x), self.period_s, self.compute_s)
        _increments(self.u, row, m, self.v0, self._buf)
        return self._buf

    def residual(self, x: np.ndarray) -> np.ndarray:
        return (self.dy - self.simulate(x))[self.skip :].copy()


def _steps(x: np.ndarray, period_s: float) -> np.ndarray:
    return np.array(
        [max(abs(x[0]) * 1e-5, 1e-6), max(abs(x[1]) * 1e-4, 1e-7), period_s * 1e-3, 2e-6, 2e-6]
    )


def _jacobian(prob: _Problem, x: np.ndarray, free: np.ndarray) -> np.ndarray:
    r0 = prob.residual(x)
    h = _steps(x, prob.period_s)
    cols = []
    for i in np.flatnonzero(free):
        xi = x.copy()
        xi[i] += h[i]
        cols.append((prob.residual(xi) - r0) / h[i])
    return np.column_stack(cols)


_LOWER = np.array([1e-9, 1e-5, 0.0, -1.0, 0.0])


def _upper(period_s: float) -> np.ndarray:
    return np.array([1e12, 10.0, MAX_DELAY_TICKS * period_s, 1.0, 5.0])


def _oe_fit(prob: _Problem, x0: np.ndarray, free: np.ndarray, max_nfev: int) -> np.ndarray:
    lo, hi = _LOWER[free], _upper(prob.period_s)[free]
    z0 = np.clip(x0[free], lo + 1e-12 * np.abs(lo), hi)
    scale = np.array([max(abs(x0[0]), 1.0), max(x0[1], 1e-3), prob.period_s, 1e-3, 1e-3])[free]

    def full(z: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[free] = z
        return x

    sol = least_squares(
        lambda z: prob.residual(full(z)),
        z0,
        jac=lambda z: _jacobian(prob, full(z), free),
        bounds=(lo, hi),
        x_scale=scale,
        method="trf",
        max_nfev=max_nfev,
        xtol=1e-10,
        ftol=1e-12,
        gtol=1e-10,
    )
    return full(sol.x)


# --- the least-squares start -------------------------------------------------------------


def _derivatives(y: np.ndarray, period_s: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Speed and acceleration from a moving-average-smoothed position (central differences).

    Only the least-squares start uses them; the output-error step does not differentiate.
    Returns the speed [counts/s], the acceleration [counts/s²] and the edge to leave out.
    """
    h = max(2, math.floor(0.01 / period_s + 0.5))  # about 10 ms each side
    box = np.ones(2 * h + 1) / (2 * h + 1)
    ys = np.convolve(y.astype(float), box, mode="same")
    v = np.zeros_like(ys)
    a = np.zeros_like(ys)
    v[h:-h] = (ys[2 * h :] - ys[: -2 * h]) / (2 * h * period_s)
    a[h:-h] = (ys[2 * h :] - 2 * ys[h:-h] + ys[: -2 * h]) / (h * period_s) ** 2
    return v, a, 3 * h


def _ls_start(
    u: np.ndarray, y: np.ndarray, period_s: float, compute_s: float, free: np.ndarray
) -> np.ndarray:
    """Inverse-dynamics least squares on filtered derivatives, best delay on a grid."""
    n = y.size
    v, a, w = _derivatives(y, period_s)
    keep = np.abs(v) > 2.0 / period_s  # moving: more than 2 counts per tick
    keep[:w] = keep[-w:] = False
    if keep.sum() < 20:
        keep = np.abs(v) > 0.2 / period_s
        keep[:w] = keep[-w:] = False
    if keep.sum() < 20:
        raise IdentificationError("the motor hardly moved: fewer than 20 moving samples")
    grid = np.arange(0, 4 * int(MAX_DELAY_TICKS) + 1) * 0.25 * period_s if free[2] else [0.0]
    idx = np.arange(n)
    best = None
    for d in grid:
        lag = compute_s + d
        j = idx - math.ceil(lag / period_s - 1e-12)
        ud = u[np.clip(j, 0, n - 1)]
        cols = [ud[keep], -a[keep]]
        if free[3]:
            cols.append(np.ones(keep.sum()))
        if free[4]:
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
    x = np.array([k_gain, tau, d, 0.0, 0.0])
    i = 2
    if free[3]:
        x[3] = float(theta[i]) / k_gain
        i += 1
    if free[4]:
        x[4] = max(float(theta[i]) / k_gain, 0.0)
    return x


# --- quality ------------------------------------------------------------------------------


def _fit_pct(meas: np.ndarray, sim: np.ndarray) -> float:
    den = np.linalg.norm(meas - np.mean(meas))
    if den == 0:
        return float("nan")
    return float(100.0 * (1.0 - np.linalg.norm(meas - sim) / den))


def _ljung_box(r: np.ndarray, lags: int = 20) -> dict[str, Any]:
    r = r - np.mean(r)
    n = r.size
    den = float(np.dot(r, r))
    if den == 0 or n <= lags + 1:
        return {"lags": lags, "p_value": float("nan"), "statistic": float("nan"), "white": False}
    rho = np.array([np.dot(r[:-j], r[j:]) / den for j in range(1, lags + 1)])
    q = float(n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, lags + 1))))
    p = float(gammaincc(lags / 2.0, q / 2.0))  # chi-square survival function, `lags` dof
    return {
        "lag1_autocorrelation": float(rho[0]),
        "lags": lags,
        "p_value": p,
        "statistic": q,
        "white": bool(p > 0.01),
    }


def _long_run_factor(r: np.ndarray, lags: int = 10) -> float:
    r = r - np.mean(r)
    den = float(np.dot(r, r))
    if den == 0:
        return 1.0
    rho = [np.dot(r[:-j], r[j:]) / den for j in range(1, lags + 1)]
    return float(max(0.1, 1.0 + 2.0 * sum((1 - j / (lags + 1)) * p for j, p in
                                          enumerate(rho, start=1))))  # fmt: skip


# --- the public API -----------------------------------------------------------------------


def _simulate_positions(
    u: np.ndarray, y: np.ndarray, x: np.ndarray, period_s: float, compute_s: float, k0: int
) -> tuple[np.ndarray, np.ndarray]:
    """Model increments, and positions simulated from the log's start, restarted at ``k0 − 1``."""
    dy = np.diff(y).astype(float)
    dp = _Problem(u[:-1], dy, period_s, compute_s, 0).simulate(x).copy()
    pos = np.empty(y.size)
    pos[:k0] = y[0] + np.concatenate([[0.0], np.cumsum(dp[: k0 - 1])])
    pos[k0 - 1 :] = y[k0 - 1] + np.concatenate([[0.0], np.cumsum(dp[k0 - 1 :])])
    return dp, pos


def simulate_fit(result: FitResult, cmd_v: np.ndarray, pos_counts: np.ndarray) -> np.ndarray:
    """Position the fitted model gives for a logged command [counts], as ``fit_pct`` uses it.

    The simulation starts at the first measured position and restarts at the first validation
    sample (the estimation/validation split of the fit).
    """
    y = np.asarray(pos_counts)
    x = np.array([result.params[p] for p in PARAMS])
    k0 = validation_split(y.size)
    return _simulate_positions(np.asarray(cmd_v, float), y, x, result.period_s,
                               result.compute_s, k0)[1]  # fmt: skip


def validation_split(n_samples: int) -> int:
    """First sample of the validation part for a log of ``n_samples``."""
    return max(MIN_SAMPLES, int(ESTIMATION_FRACTION * (n_samples - 1)))


def _parse_structure(structure: str | tuple[str, ...] | list[str] | None) -> np.ndarray | None:
    if structure is None or structure == "auto":
        return None
    names = structure.split(",") if isinstance(structure, str) else list(structure)
    names = [s.strip() for s in names if s.strip()]
    aliases = {"gain": "gain_cps_per_v", "tau": "tau_s", "delay": "delay_s",
               "offset": "offset_v", "coulomb": "coulomb_v"}  # fmt: skip
    names = [aliases.get(s, s) for s in names]
    bad = [s for s in names if s not in PARAMS]
    if bad:
        raise IdentificationError(
            f"unknown structure parameter {bad[0]!r}; choose from gain, tau, delay, offset, "
            "coulomb (gain and tau are always estimated)"
        )
    free = np.array([True, True, False, False, False])
    for s in names:
        free[PARAMS.index(s)] = True
    return free


def _all_structures() -> list[np.ndarray]:
    out = []
    for mask in range(8):
        out.append(np.array([True, True, bool(mask & 1), bool(mask & 2), bool(mask & 4)]))
    return out


def _names(free: np.ndarray) -> tuple[str, ...]:
    return tuple(p for p, f in zip(PARAMS, free, strict=True) if f)


def fit_arrays(
    cmd_v: np.ndarray,
    pos_counts: np.ndarray,
    *,
    period_s: float,
    compute_s: float = 0.0,
    structure: str | tuple[str, ...] | list[str] | None = None,
) -> FitResult:
    """Identify the axis model from a command and a position sequence.

    Parameters
    ----------
    cmd_v : ndarray
        D/A output written each tick [V] (row k written at ``t_k + compute_s``).
    pos_counts : ndarray of int
        Unwrapped encoder position latched at ``t_k`` [counts].
    period_s : float
        Sample period [s].
    compute_s : float
        Known tick-start → write time [s]; ``delay_s`` is identified beyond it.
    structure : str or sequence of str, optional
        Parameters to estimate besides gain and tau (``"delay,offset"``, names or SPEC names);
        None or ``"auto"`` selects by BIC.

    Returns
    -------
    FitResult

    Raises
    ------
    IdentificationError
        Too few samples, a constant command, a motor that never moved, or no fit.
    """
    u = np.asarray(cmd_v, dtype=float)
    y = np.asarray(pos_counts)
    n = u.size
    if y.size != n:
        raise IdentificationError(f"command and position lengths differ ({n} vs {y.size})")
    if n < MIN_SAMPLES:
        raise IdentificationError(f"the log is too short: {n} samples, need at least {MIN_SAMPLES}")
    if not np.all(np.isfinite(u)):
        raise IdentificationError("the command has non-finite values")
    if np.ptp(u) == 0:
        raise IdentificationError(
            f"the command is constant ({u[0]:g} V): nothing excites the axis, not identifiable"
        )
    if np.ptp(y) < 10:
        raise IdentificationError(
            f"the motor never moved (position range {int(np.ptp(y))} counts): not identifiable"
        )
    dy = np.diff(y).astype(float)
    n_est = validation_split(n)
    skip = min(50, n_est // 10)
    given = _parse_structure(structure)
    selection: list[dict[str, Any]] = []
    x_sel: dict[tuple[str, ...], np.ndarray] = {}
    if given is None:
        n_s = min(n_est, SELECTION_SAMPLES)
        prob_s = _Problem(u[:n_s], dy[:n_s], period_s, compute_s, skip)
        best = None
        for free in _all_structures():
            x0 = _ls_start(u[: n_s + 1], y[: n_s + 1], period_s, compute_s, free)
            x = _oe_fit(prob_s, x0, free, max_nfev=40)
            rss = float(np.sum(prob_s.residual(x) ** 2))
            m = n_s - skip
            k = int(free.sum())
            bic = m * math.log(max(rss, 1e-300) / m) + k * math.log(m)
            entry = {"bic": bic, "params": list(_names(free)), "rss": rss}
            selection.append(entry)
            x_sel[_names(free)] = x
            if best is None or bic < best[0]:
                best = (bic, free)
        assert best is not None
        free = best[1]
        ordered = sorted(selection, key=lambda e: e["bic"])
        runner = ordered[1] if len(ordered) > 1 else None
        reason = (
            f"smallest BIC ({ordered[0]['bic']:.1f}) of {len(selection)} structures on "
            f"{n_s - skip} samples"
            + (f"; next: {'+'.join(runner['params'])} at {runner['bic']:.1f}" if runner else "")
        )
    else:
        free = given
        reason = "structure given by the user"
    n_f = min(n_est, MAX_FIT_SAMPLES)
    prob = _Problem(u[:n_f], dy[:n_f], period_s, compute_s, skip)
    x0 = x_sel.get(_names(free))
    if x0 is None:
        x0 = _ls_start(u[: n_f + 1], y[: n_f + 1], period_s, compute_s, free)
    x = _oe_fit(prob, x0, free, max_nfev=60)
    # uncertainty
    r = prob.residual(x)
    jac = _jacobian(prob, x, free)
    dof = max(1, r.size - int(free.sum()))
    s2 = float(np.dot(r, r)) / dof
    try:
        cov = np.linalg.inv(jac.T @ jac) * s2 * _long_run_factor(r)
        sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        sd = np.full(int(free.sum()), np.inf)
    names = _names(free)
    params = {p: (float(x[i]) if free[i] else 0.0) for i, p in enumerate(PARAMS)}
    params["delay_s"] = max(params["delay_s"], 0.0)
    params["coulomb_v"] = max(params["coulomb_v"], 0.0)
    std = {p: float(s) for p, s in zip(names, sd, strict=True)}
    ci95 = {p: (params[p] - 1.96 * std[p], params[p] + 1.96 * std[p]) for p in names}
    # quality on the whole log with the final model
    k0 = n_est
    dp, pos_sim = _simulate_positions(u, y, x, period_s, compute_s, k0)
    vel_m, vel_s = dy / period_s, dp / period_s
    pos_est, pos_val = pos_sim[:k0], pos_sim[k0 - 1 :].copy()
    pos_val[0] = y[k0 - 1]
    fit_pct = {
        "position": {
            "estimation": _fit_pct(y[:k0].astype(float), pos_est),
            "validation": _fit_pct(y[k0 - 1 :].astype(float), pos_val),
        },
        "velocity": {
            "estimation": _fit_pct(vel_m[: k0 - 1], vel_s[: k0 - 1]),
            "validation": _fit_pct(vel_m[k0 - 1 :], vel_s[k0 - 1 :]),
        },
    }
    white = _ljung_box(y[k0 - 1 :].astype(float) - pos_val)
    if fit_pct["velocity"]["validation"] < 50:
        warnings.warn(
            f"validation velocity fit is only {fit_pct['velocity']['validation']:.1f} %",
            PoorFitWarning,
            stacklevel=2,
        )
    return FitResult(
        structure=names,
        params=params,
        std=std,
        ci95=ci95,
        fit_pct=fit_pct,
        whiteness=white,
        period_s=float(period_s),
        compute_s=float(compute_s),
        selection=selection,
        reason=reason,
        n_samples=int(n),
    )


def fit(
    log: Log,
    *,
    axis: str | None = None,
    structure: str | tuple[str, ...] | list[str] | None = None,
    compute_s: float | None = None,
) -> FitResult:
    """Identify one axis of a log (:func:`servotune.read_log`).

    Parameters
    ----------
    log : Log
    axis : str, optional
        Axis name (may be omitted for a single-axis log).
    structure : optional
        See :func:`fit_arrays`.
    compute_s : float, optional
        Known compute time [s]; default from the log's ``compute_s`` metadata, else 0 (then
        ``delay_s`` includes it).

    Returns
    -------
    FitResult

    Raises
    ------
    IdentificationError
        If the log cannot identify the model (see :func:`fit_arrays`) or has counter faults.
    """
    ax: AxisLog = log.axis(axis)
    if ax.counter_faults.size:
        raise IdentificationError(
            f"the counter column breaks the high-byte rule at {ax.counter_faults.size} rows "
            f"(first at sample {int(ax.counter_faults[0])}): the unwrapped position is unreliable"
        )
    if compute_s is None:
        compute_s = log.compute_s if log.compute_s is not None else 0.0
    return fit_arrays(
        ax.cmd_v, ax.pos_counts, period_s=log.period_s, compute_s=compute_s, structure=structure
    )
