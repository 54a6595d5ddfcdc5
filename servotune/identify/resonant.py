"""The plant ``servotune fit --modes`` writes when the log's frequency response has modes
(docs/frf.md#into-the-rig-file-fit---modes).

The time-domain fit (:mod:`servotune.identify.fitting`) models a rigid axis: on a resonant one
its gain and time constant absorb what the modes do, and its fit is poor. The frequency-domain
fit (:func:`servotune.identify.modes.fit_modes`) models the modes, and its rigid part is the
right one. So the written plant takes from each what it measures:

- **gain, tau, delay** from the frequency-domain fit, with its 95 % intervals. For the
  asymmetric friction form the two directions' gains keep the time-domain fit's ratio, scaled
  so that their mean (:attr:`servotune.plant.Plant.mean_gain_cps_per_v`, the gain a linear
  response measures) is the frequency-domain gain;
- **the modes** from the frequency-domain fit;
- **offset and Coulomb friction** re-estimated in the time domain with the linear part and the
  modes fixed: output-error least squares of the log's position increments (started from the
  time-domain fit's values), the resonant plant simulated from the logged command by the
  engine's exact step (:func:`servotune.plant.advance_tick_modal`), the first samples left
  out as the fit does (:func:`servotune.identify.heldout.skip_samples`, and five decay times
  of the slowest mode). Which of them are estimated is chosen again, by BIC (``m ln σ² +
  k ln m``) over the subsets of offset and Coulomb friction (the friction form the time-domain
  fit chose): its own choice was made by a model that lacked the modes, whose misfit hides
  them. Their 95 % intervals come from the moving-block bootstrap of the estimating equations,
  as the time-domain fit's do (:func:`servotune.identify.quality.block_bootstrap`).

The written model is then judged as the time-domain fit is: its simulated speed and position
on the whole log (fit %, MATLAB ``compare``) and the residual tests (whiteness of the
innovations of a noise model fitted to its output error; their correlation with the external
signals, else the command).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import optimize

from servotune.identify import noise, quality
from servotune.identify.heldout import fit_pcts, skip_samples
from servotune.identify.model import (
    ALL_PARAMS,
    PARAMS,
    lower_bounds,
    simulate_plant,
    upper_bounds,
)
from servotune.plant import Plant

if TYPE_CHECKING:
    from servotune.identify.modes import ModeFit

__all__ = ["FRICTION_TERMS", "LINEAR_TERMS", "WrittenPlant", "written_plant"]

LINEAR_TERMS = ("gain_cps_per_v", "tau_s", "delay_s", "gain_neg_cps_per_v")
"""The parameters the frequency-domain fit gives the written plant."""
FRICTION_TERMS = ("offset_v", "coulomb_v", "coulomb_neg_v")
"""The parameters re-estimated with the linear part and the modes fixed."""
FROM_FREQUENCY = "frequency-domain fit (with the modes)"
REFINED = "time domain, re-estimated with the linear part and the modes fixed"
FD_STEP_V = 2e-6
"""Forward-difference step of the friction terms [V] (the identifier's,
:func:`servotune.identify.model.fd_steps`)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class WrittenPlant:
    """What ``fit --modes -o`` writes when modes were found (module docstring).

    Attributes
    ----------
    params : dict
        Every parameter written, as :attr:`FitResult.params` holds them (0 for a term left
        out) [units: :data:`servotune.identify.model.UNITS`].
    structure : tuple of str
        The parameters estimated (by either fit): the frequency-domain fit's gain, tau and delay
        (and the negative direction's gain), and the friction terms of the time-domain fit's
        structure.
    ci95 : dict
        95 % interval of each estimated parameter.
    source : dict
        Per estimated parameter, which fit it comes from.
    fit_pct : dict
        ``{"velocity": %, "position": %}``: the written plant, modes included, simulated from
        the logged command over the whole log (MATLAB ``compare``).
    whiteness, cross_correlation : dict, list of dict
        The residual tests of its output error (as :class:`FitResult`'s).
    adequate : bool
    inadequacy : tuple of str
    selection : str
        How the friction terms were chosen.
    iterations : int
        Simulations the friction terms' least squares made.
    """

    params: dict[str, float]
    structure: tuple[str, ...]
    ci95: dict[str, tuple[float, float]]
    source: dict[str, str]
    fit_pct: dict[str, float]
    whiteness: dict[str, Any] = field(default_factory=dict)
    cross_correlation: list[dict[str, Any]] = field(default_factory=list)
    adequate: bool = False
    inadequacy: tuple[str, ...] = ()
    selection: str = ""
    iterations: int = 0

    def summary(self, rigid_velocity_pct: float) -> list[str]:
        """Lines for :meth:`FitResult.summary`: where each parameter comes from, the fit %."""
        by_source: dict[str, list[str]] = {}
        for p in self.structure:
            by_source.setdefault(self.source[p], []).append(p)
        out = ["written plant (fit -o), modes included:"]
        for src, names in by_source.items():
            values = ", ".join(f"{p} {self.params[p]:.6g}" for p in names)
            out.append(f"  {values}: from the {src}")
        left = [p for p in PARAMS if p not in self.structure]
        if left:
            out.append(f"  {', '.join(left)}: left out (0)")
        out.append(f"  friction terms: {self.selection}")
        out.append(
            f"  fit (MATLAB compare) velocity {self.fit_pct['velocity']:.1f} %, position "
            f"{self.fit_pct['position']:.1f} % on the whole log (the time-domain rigid fit: "
            f"velocity {rigid_velocity_pct:.1f} %)"
        )
        out.append(
            "  adequate: yes" if self.adequate else "  adequate: NO: " + "; ".join(self.inadequacy)
        )
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain data for ``fit --json`` (``written_plant``)."""
        return {
            "params": dict(self.params),
            "structure": list(self.structure),
            "ci95": {k: [float(a), float(b)] for k, (a, b) in self.ci95.items()},
            "source": dict(self.source),
            "fit_pct": dict(self.fit_pct),
            "whiteness": self.whiteness,
            "cross_correlation": self.cross_correlation,
            "adequate": self.adequate,
            "inadequacy": list(self.inadequacy),
            "selection": self.selection,
            "iterations": self.iterations,
        }


def _scaled_gains(result_params: dict[str, float], mode_fit: ModeFit) -> dict[str, float]:
    """Gain(s), tau and delay from the frequency-domain fit (module docstring)."""
    out = {"tau_s": mode_fit.tau_s, "delay_s": mode_fit.delay_s}
    g_pos = result_params["gain_cps_per_v"]
    g_neg = result_params.get("gain_neg_cps_per_v", g_pos)
    scale = mode_fit.gain_cps_per_v / (0.5 * (g_pos + g_neg))
    out["gain_cps_per_v"] = g_pos * scale
    if "gain_neg_cps_per_v" in result_params:
        out["gain_neg_cps_per_v"] = g_neg * scale
    return out


def _plant(params: dict[str, float], modes: tuple) -> Plant:
    kw: dict[str, Any] = {k: float(params[k]) for k in PARAMS}
    for k in ALL_PARAMS[len(PARAMS) :]:
        if k in params:
            kw[k] = float(params[k])
    return Plant(**kw, modes=modes)


def written_plant(
    result: Any,
    mode_fit: ModeFit,
    cmd_v: np.ndarray,
    pos_counts: np.ndarray,
    *,
    signals: list[tuple[str, np.ndarray]] | tuple = (),
) -> WrittenPlant:
    """The plant to write for ``result`` (a :class:`~servotune.identify.FitResult`, the
    time-domain fit of ``cmd_v`` [V] and ``pos_counts`` [counts], negated already if the
    encoder was inverted) and ``mode_fit`` (its modes, at least one): module docstring.

    ``signals``: the external signals (label, values per sample) the residual is tested
    against (the excitation [V]); none: the command.
    """
    period_s, compute_s = result.period_s, result.compute_s
    u1 = np.asarray(cmd_v, dtype=float)[:-1]
    y = np.asarray(pos_counts)
    dy = np.diff(y).astype(float)
    params = dict(result.params)
    params.update(_scaled_gains(result.params, mode_fit))
    slowest = max(1.0 / (2.0 * np.pi * m.freq_hz * m.damping) for m in mode_fit.modes)
    skip = max(
        skip_samples(np.array([0.0, params["tau_s"]]), period_s, dy.size),
        min(math.ceil(5.0 * slowest / period_s), dy.size // 10),
    )
    v0 = float(np.mean(dy[: max(1, min(5, dy.size))]) / period_s)

    def sim(trial: dict[str, float]) -> np.ndarray:
        plant = _plant(dict(params, **trial), mode_fit.modes)
        return simulate_plant(plant, u1, period_s=period_s, compute_s=compute_s, v0=v0)

    fits = sorted(
        (_refine(terms, params, sim, dy, skip, period_s) for terms in _candidates(result)),
        key=lambda f: f.bic,
    )
    best = fits[0]
    params.update({p: float(v) for p, v in zip(best.terms, best.z, strict=True)})
    for p in FRICTION_TERMS:  # a term left out is 0 (the negative direction's: the positive's)
        if p in params and p not in best.terms:
            params[p] = params["coulomb_v"] if p == "coulomb_neg_v" else 0.0
    ci95 = _frequency_intervals(result.params, params, mode_fit)
    if best.terms:
        _, lo_dev, hi_dev, _ = quality.block_bootstrap(best.jac.T @ best.jac, best.scores)
        for i, p in enumerate(best.terms):
            low = params[p] - float(hi_dev[i])
            ci95[p] = (low if p == "offset_v" else max(low, 0.0), params[p] - float(lo_dev[i]))
    vel, pos = fit_pcts(y, dy, best.dp, period_s)
    linear = [p for p in LINEAR_TERMS if p in params]
    structure = tuple(p for p in ALL_PARAMS if p in linear or p in best.terms)
    white, cross, reasons = _tests((dy - best.dp)[skip:], u1[skip:], signals, skip)
    runner = f"; next: {'+'.join(fits[1].terms) or 'none'} at {fits[1].bic:.1f}"
    return WrittenPlant(
        params={k: float(v) for k, v in params.items()},
        structure=structure,
        ci95={p: ci95[p] for p in structure},
        source={p: FROM_FREQUENCY if p in linear else REFINED for p in structure},
        selection=f"{'+'.join(best.terms) or 'none'} by BIC ({best.bic:.1f}, output-error fits "
        f"with the linear part and the modes fixed, {dy.size - skip} samples)"
        + (runner if len(fits) > 1 else ""),
        fit_pct={"velocity": vel, "position": pos},
        whiteness=white,
        cross_correlation=cross,
        adequate=not reasons,
        inadequacy=tuple(reasons),
        iterations=sum(f.nfev for f in fits),
    )


@dataclass(frozen=True, slots=True)
class _Refined:
    terms: tuple[str, ...]
    z: np.ndarray
    dp: np.ndarray  # the simulated increments at z
    jac: np.ndarray  # (samples after skip, terms): their sensitivities
    scores: np.ndarray
    bic: float
    nfev: int


def _candidates(result: Any) -> list[tuple[str, ...]]:
    """The friction structures tried: every subset of offset and Coulomb friction, with the
    negative direction's Coulomb level where the asymmetric form identifies it (Coulomb
    friction and no offset, :func:`servotune.identify.model.free_mask`)."""
    asym = result.friction == "asym"
    out = []
    for offset in (False, True):
        for coulomb in (False, True):
            terms = ("offset_v",) * offset + ("coulomb_v",) * coulomb
            out.append(terms + ("coulomb_neg_v",) * (asym and coulomb and not offset))
    return out


def _refine(
    terms: tuple[str, ...],
    params: dict[str, float],
    sim: Any,
    dy: np.ndarray,
    skip: int,
    period_s: float,
) -> _Refined:
    """Output-error least squares of the friction ``terms`` (the others 0), started from the
    time-domain fit's values; scored by BIC, ``m ln σ² + k ln m``."""
    idx = [ALL_PARAMS.index(p) for p in terms]
    lo, hi = lower_bounds()[idx], upper_bounds(period_s)[idx]
    steps = np.full(len(terms), FD_STEP_V)
    left = {p: 0.0 for p in FRICTION_TERMS if p not in terms}

    def trial(z: np.ndarray) -> dict[str, float]:
        return dict(left, **{p: float(v) for p, v in zip(terms, z, strict=True)})

    def jac(z: np.ndarray) -> np.ndarray:
        base = sim(trial(z))[skip:]
        cols = [(sim(trial(z + steps * e))[skip:] - base) / FD_STEP_V for e in np.eye(len(z))]
        return np.column_stack(cols)

    nfev = 0
    z = np.zeros(0)
    if terms:
        z0 = np.clip([params.get(p, 0.0) for p in terms], lo + FD_STEP_V, hi - FD_STEP_V)
        sol = optimize.least_squares(
            lambda z: sim(trial(z))[skip:] - dy[skip:],
            z0,
            jac=jac,
            bounds=(lo, hi),
            method="trf",
            x_scale=np.full(len(terms), 1e-3),
            max_nfev=30,
        )
        z, nfev = sol.x, int(sol.nfev) * (1 + len(terms))
    dp = sim(trial(z))
    r = (dy - dp)[skip:]
    m = r.size
    bic = m * math.log(max(float(np.mean(r * r)), 1e-300)) + len(terms) * math.log(m)
    j = jac(z) if terms else np.zeros((m, 0))
    return _Refined(terms, z, dp, j, j * r[:, None], bic, nfev)


def _frequency_intervals(
    rigid: dict[str, float], params: dict[str, float], mode_fit: ModeFit
) -> dict[str, tuple[float, float]]:
    """The frequency-domain fit's 95 % intervals for the written gain(s), tau and delay (a
    direction's gain: the fit's gain interval scaled as the gain is; the ratio's own
    uncertainty is not in it)."""
    k = mode_fit.gain_cps_per_v
    out = {"tau_s": mode_fit.tau_s_95, "delay_s": mode_fit.delay_s_95}
    for p in ("gain_cps_per_v", "gain_neg_cps_per_v"):
        if p in params and (p == "gain_cps_per_v" or p in rigid):
            f = params[p] / k
            out[p] = (mode_fit.gain_cps_per_v_95[0] * f, mode_fit.gain_cps_per_v_95[1] * f)
    lo, hi = out["delay_s"]
    out["delay_s"] = (max(lo, 0.0), max(hi, 0.0))
    return {p: (float(a), float(b)) for p, (a, b) in out.items()}


def _tests(
    residual: np.ndarray,
    cmd: np.ndarray,
    signals: list[tuple[str, np.ndarray]],
    skip: int,
) -> tuple[dict[str, Any], list[dict[str, Any]], list[str]]:
    """The residual tests of the written plant's output error (module docstring)."""
    if noise.long_enough(min(residual.size, noise.REGRESSION_SAMPLES)):
        nm = noise.fit_noise_model(residual)
        innov, fitted = nm.whiten(residual)[nm.settle_samples :], sum(nm.order)
    else:
        innov, fitted = residual, 0
    white = quality.ljung_box(innov, fitted=fitted)
    inputs = [(lab, s[skip : skip + residual.size]) for lab, s in signals] or [("command", cmd)]
    n = innov.size
    cross = [quality.cross_correlation_test(innov, s[-n:], name=lab) for lab, s in inputs]
    reasons = []
    if not white["white"]:
        reasons.append(
            f"the innovations are not white (Ljung-Box p = {white['p_value']:.2g}, largest "
            f"|autocorrelation| {white['max_abs_autocorrelation']:.3f})"
        )
    reasons += [
        f"the residual is correlated with the {c['input']} (p = {c['p_value']:.2g}, largest "
        f"|corr| {c['max_abs_correlation']:.3f})"
        for c in cross
        if not c["uncorrelated"]
    ]
    return white, cross, reasons
