"""What ``servotune fit`` runs: method, structure, estimate, intervals, validation, diagnostics.

1. **Checks** — enough samples, a command that varies, a motor that moves, and a motor that
   moves *with* its command (:func:`~servotune.identify.model.check_direction`: a reversed
   encoder or D/A is an :class:`~servotune.errors.IdentificationError` naming the cause;
   ``invert_encoder`` negates the position first).
2. **Method** (``method="auto"``) — ``iv`` (:mod:`servotune.identify.iv`) when the log has an
   external signal that excites the axis (the excitation ``exc_code``, the reference where it
   moves in task mode) and it explains at least :data:`~servotune.identify.iv.MIN_R2` of the
   command's variance; otherwise ``oe`` (:mod:`servotune.identify.oe`) with a
   :class:`~servotune.identify.result.ClosedLoopBiasWarning` saying why (none for a log that is
   open loop throughout, where least squares is consistent).
3. **Structure and friction form** (:func:`~servotune.identify.selection.select_structure`) —
   with ``structure=None`` every structure (gain and tau plus any subset of delay, offset and
   Coulomb friction) is fitted on the first
   :data:`~servotune.identify.selection.SELECTION_SAMPLES` samples with the chosen method
   (least squares gives the start) and scored by BIC (``m·ln σ² + k·ln m``) on that method's
   residual: for ``iv`` whitened by one noise model (the largest candidate's), so that a
   coloured disturbance does not make every extra term look worth its price; for ``oe`` as it
   is. The smallest wins, unless the largest structure predicts held-out samples clearly better
   (:func:`~servotune.identify.heldout.held_out_check`). With ``friction="auto"`` the winner
   is refitted with the asymmetric form (its own gain, and Coulomb level where identifiable,
   for the negative direction) and the form with the smaller BIC is kept; both scores are
   reported. Where the refined IV finds no solution on the
   selection's samples, basic IV (:func:`~servotune.identify.iv.estimate_iv`) is used
   throughout; where neither does, least squares, with a warning. Where IV is chosen, least
   squares is fitted too and kept instead when it places gain and tau inside IV's own 95 %
   intervals (no closed-loop bias seen) and predicts held-out samples clearly better
   (:func:`_prefer_agreeing_oe`).
4. **Estimate** on the whole log with the chosen method, from the selection's fit.
5. **Intervals** — moving-block bootstrap of the estimating equations
   (:func:`~servotune.identify.quality.block_bootstrap`): they hold with correlated residuals.
6. **Validation** — split-half cross-validation: the model is estimated on each half (the
   one-step estimate of that half's own equations) and its simulation fit % (MATLAB
   ``compare``) measured on the other half, whose equations it has not used.
7. **Diagnostics** — whiteness of the noise model's innovations and their cross-correlation
   with the inputs (:mod:`servotune.identify.quality`); a failed test makes ``adequate`` false,
   with the reason, and an :class:`~servotune.identify.result.InadequateModelWarning`.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune.budget import check_memory
from servotune.errors import IdentificationError
from servotune.identify import iv, model, quality
from servotune.identify.heldout import (
    cross_validate,
    estimate,
    fit_pcts,
    simulate_dy,
    skip_samples,
    validation_split,
)
from servotune.identify.model import ALL_PARAMS, I_COULOMB, I_GAIN, PARAMS
from servotune.identify.result import (
    ClosedLoopBiasWarning,
    FitResult,
    InadequateModelWarning,
    PoorFitWarning,
)
from servotune.identify.selection import select_structure
from servotune.io.log import AxisLog, Log
from servotune.laws.axis import MODE_OPEN, MODE_TASK

__all__ = [
    "AGREEMENT_PARAMS",
    "FRICTION_FORMS",
    "METHODS",
    "MIN_ERROR_REDUCTION",
    "MIN_SAMPLES",
    "fit",
    "fit_arrays",
    "simulate_fit",
    "validation_split",
]

MIN_SAMPLES = 100
"""Fewest samples a log needs."""
METHODS = ("auto", "iv", "oe")
"""Values of ``method`` (``servotune fit --method``)."""
FRICTION_FORMS = ("auto", "sym", "asym")
"""Values of ``friction`` (``servotune fit --friction``)."""
_BYTES_PER_SAMPLE = 700  # the estimators' arrays: about 90 doubles per sample at the peak


def _params(x: np.ndarray, free: np.ndarray) -> dict[str, float]:
    """Every axis-model parameter (0 when left out), and the negative direction's when estimated."""
    out = {}
    for i, p in enumerate(ALL_PARAMS):
        if i < len(PARAMS):
            v = float(x[i]) if free[i] else 0.0
            out[p] = max(v, 0.0) if p in ("delay_s", "coulomb_v") else v
        elif free[i]:
            out[p] = max(float(x[i]), 0.0)
    return out


def _choose_method(
    method: str,
    u1: np.ndarray,
    sigs: list[np.ndarray],
    labels: list[str],
    period_s: float,
    open_loop: bool,
) -> tuple[str, str, iv.Projection | None]:
    if method not in METHODS:
        raise IdentificationError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if method == "oe":
        return "oe", "output-error least squares, as asked", None
    if not sigs:
        why = (
            "the log has no external signal (no exc_code column that varies, no reference "
            "that moves in task mode)"
        )
        if method == "iv":
            raise IdentificationError(f"method iv needs instruments, but {why}")
        if open_loop:
            return "oe", "open-loop log: output-error least squares is consistent", None
        warnings.warn(
            f"{why}: fitted by least squares (oe), which is biased if the loop was closed and a "
            "disturbance acted; log the excitation (exc_code) to get the consistent iv",
            ClosedLoopBiasWarning,
            stacklevel=3,
        )
        return "oe", f"output-error least squares: {why}", None
    proj = iv.project(u1, sigs, iv.projection_lags(period_s))
    share = f"{100 * proj.r2:.1f} %"
    names = " and ".join(labels)
    if proj.r2 < iv.MIN_R2 and method == "auto":
        warnings.warn(
            f"the external signals ({names}) explain only {share} of the command (need "
            f"{100 * iv.MIN_R2:g} %): too weak for instrumental variables, fitted by least "
            "squares (oe), which is biased if the loop was closed and a disturbance acted",
            ClosedLoopBiasWarning,
            stacklevel=3,
        )
        return (
            "oe",
            f"output-error least squares: {names} explain only {share} of the command",
            None,
        )
    return (
        "iv",
        f"instrumental variables, instruments from {names} (they explain {share} of the command)",
        proj,
    )


def fit_arrays(
    cmd_v: np.ndarray,
    pos_counts: np.ndarray,
    *,
    period_s: float,
    compute_s: float = 0.0,
    structure: str | tuple[str, ...] | list[str] | None = None,
    method: str = "auto",
    friction: str = "auto",
    exc_v: np.ndarray | None = None,
    ref_counts: np.ndarray | None = None,
    mode: np.ndarray | None = None,
    invert_encoder: bool = False,
) -> FitResult:
    """Identify the axis model from a command and a position sequence (module docstring).

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
        Terms to estimate besides gain and tau (``"delay,offset"``, short or full names);
        None or ``"auto"`` selects by BIC.
    method : str
        ``"auto"`` (default: ``iv`` when the log allows it, else ``oe`` with a warning),
        ``"iv"`` or ``"oe"``.
    friction : str
        ``"auto"`` (default: chosen by BIC), ``"sym"`` or ``"asym"`` (per-direction gain and
        Coulomb level).
    exc_v : ndarray, optional
        The excitation the law added [V] (the log's ``exc_code`` times the D/A step).
    ref_counts : ndarray of int, optional
        The reference [counts].
    mode : ndarray of int, optional
        The runtime's mode per row (``MODE_*``): the reference is an instrument only in task
        rows; a log open loop throughout needs no instruments.
    invert_encoder : bool
        Negate the position first (an encoder counting the other way).

    Returns
    -------
    FitResult

    Raises
    ------
    IdentificationError
        Too few samples, a constant command, a motor that never moved or moves against its
        command (a reversed encoder or D/A), ``method="iv"`` without an external signal, an
        unknown method, friction form or structure term.

    Warns
    -----
    ClosedLoopBiasWarning
        Least squares on a log that may be closed loop (no usable external signal).
    InadequateModelWarning
        A residual test failed (the reason is in ``FitResult.inadequacy``).
    PoorFitWarning
        The cross-validated velocity fit is below 50 %.
    """
    u = np.asarray(cmd_v, dtype=float)
    y = np.asarray(pos_counts)
    n = u.size
    _check(u, y)
    if invert_encoder:
        y = -y.astype(np.int64)
    if friction not in FRICTION_FORMS:
        raise IdentificationError(
            f"friction must be one of {', '.join(FRICTION_FORMS)}, got {friction!r}"
        )
    terms = model.parse_terms(structure)
    check_memory(
        n * _BYTES_PER_SAMPLE,
        f"identifying a log of {n:,} samples",
        f"{n:,} samples × {_BYTES_PER_SAMPLE} bytes",
    )
    model.check_direction(u, y, period_s, compute_s)
    task = None if mode is None else np.asarray(mode) == MODE_TASK
    open_loop = mode is not None and bool(np.all(np.asarray(mode) == MODE_OPEN))
    sigs, labels = iv.external_signals(exc_v, ref_counts, task)
    data = _Data(
        u=u,
        y=y,
        dy=np.diff(y).astype(float),
        sigs=[s[:-1] for s in sigs],
        labels=labels,
        terms=terms,
        friction=friction,
        period_s=float(period_s),
        compute_s=float(compute_s),
        inverted=bool(invert_encoder),
    )
    chosen, method_reason, proj = _choose_method(
        method, u[:-1], data.sigs, labels, period_s, open_loop
    )
    run = _estimate(data, method, chosen, method_reason, proj)
    result = _result(data, run)
    if method == "auto" and result.method == "iv":
        result = _prefer_agreeing_oe(data, result)
    if result.inadequacy:
        warnings.warn(
            "the model is not adequate: " + "; ".join(result.inadequacy),
            InadequateModelWarning,
            stacklevel=2,
        )
    val = result.fit_pct["velocity"]["validation"]
    if val is not None and val < 50:
        warnings.warn(
            f"cross-validated velocity fit is only {val:.1f} %", PoorFitWarning, stacklevel=2
        )
    return result


@dataclass(frozen=True, slots=True, kw_only=True)
class _Data:
    """A log's arrays and the options of one fit."""

    u: np.ndarray
    y: np.ndarray
    dy: np.ndarray
    sigs: list[np.ndarray]
    labels: list[str]
    terms: tuple[str, ...] | None
    friction: str
    period_s: float
    compute_s: float
    inverted: bool


@dataclass(frozen=True, slots=True, kw_only=True)
class _Run:
    """One method's selection and estimate on the whole log."""

    method: str
    method_reason: str
    free: np.ndarray
    selection: list[dict[str, Any]]
    reason: str
    friction_selection: dict[str, Any]
    est: model.Estimate
    info: dict[str, Any]
    skip: int


def _estimate(
    d: _Data, method: str, chosen: str, method_reason: str, proj: iv.Projection | None
) -> _Run:
    """Select the structure and estimate with the chosen method; least squares, with a
    warning, where instrumental variables find no solution (unless ``iv`` was asked)."""
    u1 = d.u[:-1]
    opts = {"period_s": d.period_s, "compute_s": d.compute_s}
    try:
        sel = select_structure(chosen, d.u, d.y, d.dy, d.sigs, d.terms, d.friction, **opts)
        skip = skip_samples(sel.x, d.period_s, d.u.size)
        final = "iv" if sel.variant == "iv-refined" else sel.variant  # refined may fall back
        est, info = estimate(
            final,
            u1,
            d.dy,
            d.sigs,
            sel.x,
            sel.free,
            skip=skip,
            projection=proj,
            noise0=sel.noise,
            **opts,
        )
    except iv.NotConverged as exc:
        if method == "iv":
            raise IdentificationError(f"method iv: {exc}; try --method oe") from None
        warnings.warn(
            f"instrumental variables found no solution on this log ({exc}): fitted by least "
            "squares (oe), which is biased if the loop was closed and a disturbance acted",
            ClosedLoopBiasWarning,
            stacklevel=3,
        )
        chosen, method_reason = "oe", f"output-error least squares: {exc}"
        sel = select_structure(chosen, d.u, d.y, d.dy, d.sigs, d.terms, d.friction, **opts)
        skip = skip_samples(sel.x, d.period_s, d.u.size)
        est, info = estimate(
            chosen, u1, d.dy, d.sigs, sel.x, sel.free, skip=skip, noise0=sel.noise, **opts
        )
    if chosen == "iv":
        method_reason += (
            "; refined: prefiltered by the noise model"
            if info["prefilter"]
            else "; basic: the noise-model prefilter found no solution on this log"
        )
    if est.x[I_GAIN] <= 10 * model.lower_bounds()[I_GAIN]:
        raise IdentificationError(
            f"the fitted gain {est.x[I_GAIN]:.3g} counts/s/V is implausibly small: the axis does "
            "not move with its command; the encoder or the D/A sign may be reversed (re-run with "
            "--invert-encoder), or the command does not reach the drive"
        )
    return _Run(
        method=chosen,
        method_reason=method_reason,
        free=sel.free,
        selection=sel.selection,
        reason=sel.reason,
        friction_selection=sel.friction_selection,
        est=est,
        info=info,
        skip=skip,
    )


def _result(d: _Data, run: _Run) -> FitResult:
    """Validation, diagnostics and intervals of an estimate, as the fit's result."""
    est, free, x = run.est, run.free, run.est.x
    u1 = d.u[:-1]
    opts = {"period_s": d.period_s, "compute_s": d.compute_s}
    # validation: split-half cross-validation, and the whole-log model on the whole log
    xs, folds = cross_validate(est, d.u, d.y, free, **opts)
    sim = (
        est.simulated
        if est.simulated is not None
        else simulate_dy(u1, d.dy, x, free, d.period_s, d.compute_s)
    )
    vel_est, pos_est = fit_pcts(d.y, d.dy, sim, d.period_s)
    del sim
    white, cross, reasons = quality.residual_tests(est, run.method, u1, d.sigs, d.labels, run.skip)
    # the intervals last: by then the estimate's per-sample arrays other than the equations'
    # terms are released (the bootstrap's own arrays take their memory)
    a_mat, scores, noise_model = est.a_mat, est.scores, est.noise
    del est
    params = _params(x, free)
    std, ci95, block = quality.bootstrap_intervals(
        a_mat, scores, params, model.names(free), model.lower_bounds()[free]
    )
    del a_mat, scores
    fit_pct: dict[str, dict[str, Any]] = {}
    for j, key in enumerate(("velocity", "position")):
        vals = None if folds is None else [f[j] for f in folds]
        fit_pct[key] = {
            "estimation": vel_est if j == 0 else pos_est,
            "folds": vals,
            "validation": None if vals is None else float(np.mean(vals)),
            "cross_validation": "split-half",
        }
    instruments: dict[str, Any] = {}
    if run.method == "iv":
        info = run.info
        instruments = {
            "signals": d.labels,
            "projection_lags": info["lags"],
            "r2": info["r2"],
            "converged": info["converged"],
            "iterations": info["iterations"],
            "prefilter": "noise model A/C" if info["prefilter"] else "none",
        }
    return FitResult(
        structure=model.names(free),
        params=params,
        std=std,
        ci95=ci95,
        method=run.method,
        method_reason=run.method_reason,
        interval_method=(
            f"moving-block bootstrap of the {run.method} estimating equations "
            f"({quality.BOOTSTRAP_REPLICATES} replicates, blocks of {block} samples), basic 95 % "
            "interval"
        ),
        friction="asym" if free[5] else "sym",
        friction_selection=run.friction_selection,
        fit_pct=fit_pct,
        whiteness=white,
        cross_correlation=cross,
        adequate=not reasons,
        inadequacy=tuple(reasons),
        instruments=instruments,
        noise_model=noise_model.to_dict(),
        period_s=d.period_s,
        compute_s=d.compute_s,
        selection=run.selection,
        reason=run.reason,
        n_samples=int(d.u.size),
        cv_params=tuple(_params(xi, free) for xi in xs),
        inverted_encoder=d.inverted,
    )


AGREEMENT_PARAMS = ("gain_cps_per_v", "tau_s")
"""The parameters least squares must place inside the instrumental-variable estimate's 95 %
intervals before the default prefers it (:func:`_prefer_agreeing_oe`)."""

MIN_ERROR_REDUCTION = 0.05
"""How much smaller least squares' held-out velocity error (100 − cross-validated fit %) must
be than IV's before the default prefers it: a difference at the noise level of the split is no
reason to leave the consistent estimator (on the real EMPS drive least squares' error is 9 %
smaller: 4.41 against 4.85 points)."""


def _prefer_agreeing_oe(d: _Data, ivr: FitResult) -> FitResult:
    """The default's choice between the consistent and the efficient estimator.

    Instrumental variables are consistent in closed loop; least squares (output error) is more
    efficient but biased when the loop feeds a disturbance back into the command. The test of
    the difference (in the spirit of Durbin-Wu-Hausman): where least squares places the
    dynamics (:data:`AGREEMENT_PARAMS`) inside the IV estimate's own 95 % intervals, no bias is
    seen at the precision the log allows, and the estimate that predicts held-out samples
    clearly better (split-half cross-validated velocity error at least
    :data:`MIN_ERROR_REDUCTION` smaller) is kept. On a closed-loop log with a
    disturbance the biased estimate lies many standard deviations away and IV stays.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            run = _estimate(d, "oe", "oe", "", None)
        except IdentificationError:
            return ivr
        oe_params = _params(run.est.x, run.free)
        for p in AGREEMENT_PARAMS:
            lo, hi = ivr.ci95[p]
            if not lo <= oe_params[p] <= hi:
                return ivr
        oer = _result(d, run)
    iv_val = ivr.fit_pct["velocity"]["validation"]
    oe_val = oer.fit_pct["velocity"]["validation"]
    if (
        iv_val is None
        or oe_val is None
        or 100 - oe_val > (1 - MIN_ERROR_REDUCTION) * (100 - iv_val)
    ):
        return ivr
    inside = ", ".join(
        f"{p} {oe_params[p]:.4g} in [{ivr.ci95[p][0]:.4g}, {ivr.ci95[p][1]:.4g}]"
        for p in AGREEMENT_PARAMS
    )
    reason = (
        "output-error least squares: it agrees with instrumental variables within their 95 % "
        f"intervals ({inside}), so no closed-loop bias is seen, and it predicts held-out "
        f"samples clearly better (cross-validated velocity fit {oe_val:.2f} % against "
        f"{iv_val:.2f} %)"
    )
    return dataclasses.replace(oer, method_reason=reason)


def _check(u: np.ndarray, y: np.ndarray) -> None:
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


def simulate_fit(result: FitResult, cmd_v: np.ndarray, pos_counts: np.ndarray) -> np.ndarray:
    """Held-out position simulation [counts], as the validation fit % measures it.

    Each half of the log is simulated from its own command and first position by the model
    fitted on the other half (split-half cross-validation; the whole-log model when the result
    has none). ``pos_counts`` is the position as fitted (negated already if the encoder was
    inverted).
    """
    u = np.asarray(cmd_v, dtype=float)
    y = np.asarray(pos_counts)
    n = y.size
    free = np.array([p in result.structure for p in ALL_PARAMS])

    def vec(params: dict[str, float]) -> np.ndarray:
        x = np.array([params.get(p, 0.0) for p in ALL_PARAMS])
        if "gain_neg_cps_per_v" not in params:
            x[5] = x[I_GAIN]
        if "coulomb_neg_v" not in params:
            x[6] = x[I_COULOMB]
        return x

    models = [vec(p) for p in result.cv_params] or [vec(result.params)] * 2
    h = validation_split(n)
    out = np.empty(n)
    for i, (a, b) in enumerate(((0, h), (h, n))):
        dya = np.diff(y[a:b]).astype(float)
        dp = simulate_dy(u[a : b - 1], dya, models[1 - i], free, result.period_s, result.compute_s)
        out[a:b] = y[a] + np.concatenate([[0.0], np.cumsum(dp)])
    return out


def fit(
    log: Log,
    *,
    axis: str | None = None,
    structure: str | tuple[str, ...] | list[str] | None = None,
    compute_s: float | None = None,
    method: str = "auto",
    friction: str = "auto",
    invert_encoder: bool = False,
) -> FitResult:
    """Identify one axis of a log (:func:`servotune.read_log`).

    Parameters
    ----------
    log : Log
    axis : str, optional
        Axis name (may be omitted for a single-axis log).
    structure, method, friction, invert_encoder : optional
        See :func:`fit_arrays`.
    compute_s : float, optional
        Known compute time [s]; default from the log's ``compute_s`` metadata, else 0 (then
        ``delay_s`` includes it).

    Returns
    -------
    FitResult
        The axis's model, its intervals and its diagnostics.

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
    exc_v = None if ax.exc_code is None else ax.exc_code * log.dac_lsb_v
    return fit_arrays(
        ax.cmd_v,
        ax.pos_counts,
        period_s=log.period_s,
        compute_s=compute_s,
        structure=structure,
        method=method,
        friction=friction,
        exc_v=exc_v,
        ref_counts=ax.ref_counts,
        mode=ax.mode,
        invert_encoder=invert_encoder,
    )
