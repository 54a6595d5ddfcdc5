"""The structure and friction form of the axis model, chosen by BIC on the first samples of a log
(:mod:`servotune.identify.fitting`'s step 3), and the start of the estimate on the whole log.

Every candidate structure is estimated with the method of the final estimate (least squares
would prefer the wrong structure on a closed-loop log, its residual being the disturbance it
mistakes for dynamics), from the least-squares fit of the largest candidate, and scored in that
method's own terms (:class:`Scorer`): for ``iv`` the variance of the residual whitened by the
largest candidate's noise model (the same prefilter for all), for ``oe`` the raw residual's.
The smallest BIC wins unless the largest structure predicts held-out samples clearly better
(:func:`~servotune.identify.heldout.held_out_check`); with ``friction="auto"`` the winner is
refitted with the asymmetric form and the form with the smaller BIC kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune.identify import iv, model, oe
from servotune.identify.heldout import estimate, held_out_check, skip_samples
from servotune.identify.model import I_COULOMB, I_GAIN, PARAMS
from servotune.identify.noise import NoiseModel

__all__ = ["SELECTION_SAMPLES", "Scorer", "Selection", "select_structure"]

SELECTION_SAMPLES = 20_000
"""Samples (the first ones) the structure and friction-form selection fits on."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Selection:
    """What :func:`select_structure` chose.

    Attributes
    ----------
    free : ndarray of bool
        The estimated parameters (:data:`~servotune.identify.model.ALL_PARAMS` order).
    x : ndarray
        The start of the estimate on the whole log.
    selection : list of dict
        Every candidate structure's score, the smallest BIC first (empty when the structure
        was given).
    reason : str
        Why the structure was chosen.
    friction_selection : dict
        The friction forms' scores and the choice (empty unless ``friction="auto"``).
    noise : NoiseModel
        The largest candidate's noise model (the identity where there is none).
    variant : str
        The estimator the selection settled on: ``"iv-refined"``, ``"iv-basic"`` or
        ``"oe"``.
    """

    free: np.ndarray
    x: np.ndarray
    selection: list[dict[str, Any]]
    reason: str
    friction_selection: dict[str, Any]
    noise: NoiseModel
    variant: str


@dataclass(slots=True, kw_only=True)
class Scorer:
    """The candidates' estimates on the selection's samples, each scored by its BIC.

    ``variant`` (the estimator) and ``noise`` (the prefilter every candidate shares, the first
    noise model found) change as the selection goes on: refined IV falls back to basic IV where
    no candidate has a refined solution.
    """

    method: str
    variant: str
    u: np.ndarray
    dy: np.ndarray
    sigs: list[np.ndarray]
    projection: iv.Projection | None
    skip: int
    period_s: float
    compute_s: float
    noise: NoiseModel | None = None

    @property
    def samples(self) -> int:
        """Samples the scores are computed on (those skipped at the start not counted)."""
        return self.dy.size - self.skip

    def score(
        self, free: np.ndarray, x0: np.ndarray
    ) -> tuple[float, float, np.ndarray, NoiseModel]:
        """BIC, residual variance, estimate and noise model of one structure (``free``)."""
        try:
            est, _ = estimate(
                self.variant,
                self.u,
                self.dy,
                self.sigs,
                x0,
                free,
                period_s=self.period_s,
                compute_s=self.compute_s,
                skip=self.skip,
                projection=self.projection,
                noise0=self.noise,
                max_nfev=40,
                max_outer=4,
                refit_noise=self.noise is None,
            )
        except iv.NotConverged:  # this candidate has no IV solution: it cannot win
            return math.inf, math.inf, x0, self.noise or NoiseModel.identity()
        # each method's own criterion: iv solves its equations in the prefiltered domain (the
        # prefilter the same for every candidate), least squares minimises the raw residual
        r = est.whitened if self.method == "iv" else est.residual
        m = r.size
        var = max(float(np.mean(r * r)), 1e-300)
        k = int(free.sum())
        return m * math.log(var) + k * math.log(m), var, est.x, est.noise

    def score_all(
        self, candidates: list[tuple[str, ...]], form: str, x_start: np.ndarray
    ) -> list[dict[str, Any]]:
        """Every candidate structure scored, from ``x_start``, the largest first (its noise
        model is the prefilter of the others)."""
        out = []
        for t in sorted(candidates, key=len, reverse=True):
            free = model.free_mask(t, form)
            x0 = np.where(free, x_start, 0.0)
            x0[5], x0[6] = (
                (x_start[5], x_start[6]) if form == "asym" else (x0[I_GAIN], x0[I_COULOMB])
            )
            bic, var, x, nm = self.score(free, x0)
            if math.isfinite(bic):
                self.noise = self.noise or nm
            out.append(
                {
                    "bic": bic,
                    "params": list(model.names(free)),
                    "variance": var,
                    "_free": free,
                    "_x": x,
                }
            )
        return out


def _candidates(terms: tuple[str, ...] | None) -> list[tuple[str, ...]]:
    """The structures to choose from: ``terms`` alone, or every subset of the optional ones."""
    if terms is not None:
        return [terms]
    return [
        tuple(t for t, on in zip(model.OPTIONAL_PARAMS, bits, strict=True) if on)
        for bits in ((m & 1, m & 2, m & 4) for m in range(8))
    ]


def select_structure(
    method: str,
    u: np.ndarray,
    y: np.ndarray,
    dy: np.ndarray,
    sigs: list[np.ndarray],
    terms: tuple[str, ...] | None,
    friction: str,
    *,
    period_s: float,
    compute_s: float,
) -> Selection:
    """Structure and friction form by BIC on the first samples; the start of the estimate
    (module docstring).

    Raises
    ------
    NotConverged
        No candidate structure has a solution of ``method``.
    """
    n_s = min(dy.size, SELECTION_SAMPLES)
    form = "sym" if friction == "auto" else friction
    candidates = _candidates(terms)
    largest = model.free_mask(terms if terms is not None else model.OPTIONAL_PARAMS, form)
    x_ls = model.ls_start(u[: n_s + 1], y[: n_s + 1], period_s, compute_s, largest)
    skip_s = skip_samples(x_ls, period_s, n_s)
    x_oe = oe.oe_parameters(
        u[:n_s],
        dy[:n_s],
        x_ls,
        largest,
        period_s=period_s,
        compute_s=compute_s,
        skip=skip_s,
        max_nfev=40,
    )
    sigs_s = [sg[:n_s] for sg in sigs]
    proj = iv.project(u[:n_s], sigs_s, iv.projection_lags(period_s)) if method == "iv" else None
    # refined IV for every candidate (one without a solution cannot win); basic IV for all only
    # where no candidate has a refined solution
    scorer = Scorer(
        method=method,
        variant="iv-refined" if method == "iv" else method,
        u=u[:n_s],
        dy=dy[:n_s],
        sigs=sigs_s,
        projection=proj,
        skip=skip_s,
        period_s=period_s,
        compute_s=compute_s,
    )
    scored = scorer.score_all(candidates, form, x_oe)
    if scorer.variant == "iv-refined" and not any(math.isfinite(e["bic"]) for e in scored):
        scorer.variant, scorer.noise = "iv-basic", None
        scored = scorer.score_all(candidates, form, x_oe)
    best = min(scored, key=lambda e: e["bic"])
    if not math.isfinite(best["bic"]):
        raise iv.NotConverged(f"no candidate structure has an {method} solution")
    selection: list[dict[str, Any]] = []
    if terms is None:
        best, selection, reason = _by_bic(scorer, best, scored, (u, dy, sigs), x_oe)
    else:
        reason = "structure given by the user"
    free, x, friction_selection = _friction_form(scorer, friction, best)
    return Selection(
        free=free,
        x=x,
        selection=selection,
        reason=reason,
        friction_selection=friction_selection,
        noise=scorer.noise or NoiseModel.identity(),
        variant=scorer.variant,
    )


def _by_bic(
    scorer: Scorer,
    best: dict[str, Any],
    scored: list[dict[str, Any]],
    log: tuple[np.ndarray, np.ndarray, list[np.ndarray]],
    x_oe: np.ndarray,
) -> tuple[dict[str, Any], list[dict[str, Any]], str]:
    """The structure of smallest BIC among ``scored`` (``best``), unless the largest predicts
    held-out samples of the whole ``log`` (its ``u``, ``dy`` and signals) clearly better;
    the scores, smallest first, and the reason."""
    ordered = sorted(scored, key=lambda e: e["bic"])
    runner = ordered[1]
    reason = (
        f"smallest BIC ({ordered[0]['bic']:.1f}, {scorer.method} fits) of {len(scored)} "
        f"structures on {scorer.samples} samples; next: {'+'.join(runner['params'])} "
        f"at {runner['bic']:.1f}"
    )
    u, dy, sigs = log
    best, reason = held_out_check(
        best,
        scored,
        reason,
        scorer.variant,
        u,
        dy,
        sigs,
        scorer.dy.size,
        scorer.noise,
        x_oe,
        period_s=scorer.period_s,
        compute_s=scorer.compute_s,
    )
    selection = [{k: v for k, v in e.items() if not k.startswith("_")} for e in ordered]
    if not math.isfinite(best["bic"]):  # refined IV has no solution for it: basic IV
        scorer.variant = "iv-basic" if scorer.variant == "iv-refined" else scorer.variant
        bic_b, var_b, x_b, _ = scorer.score(best["_free"], best["_x"])
        best = {**best, "bic": bic_b, "variance": var_b, "_x": x_b}
    return best, selection, reason


def _friction_form(
    scorer: Scorer, friction: str, best: dict[str, Any]
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """The chosen structure's parameters and start: with ``friction="auto"`` refitted with the
    asymmetric form and that form kept where its BIC is smaller (both scores reported)."""
    free, x = best["_free"], best["_x"]
    if friction != "auto":
        return free, x, {}
    free_a = model.free_mask(
        tuple(p for p in model.OPTIONAL_PARAMS if free[PARAMS.index(p)]), "asym"
    )
    xa0 = x.copy()
    xa0[5], xa0[6] = x[I_GAIN], x[I_COULOMB]
    bic_a, _, xa, _ = scorer.score(free_a, xa0)
    scores = {"asym": bic_a, "sym": best["bic"]}
    chosen = "asym" if bic_a < best["bic"] else "sym"
    other = "sym" if chosen == "asym" else "asym"
    friction_selection = {
        "chosen": chosen,
        "criterion": f"BIC of {scorer.method} fits on {scorer.samples} samples",
        "runner_up": other,
        "scores": scores,
        "reason": f"BIC {scores[chosen]:.1f}; {other} at {scores[other]:.1f}",
    }
    if chosen == "asym":
        free, x = free_a, xa
    return free, x, friction_selection
