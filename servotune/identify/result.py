"""The identified model as a named result (:class:`FitResult`), and the identifier's warnings."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

from servotune._version import __version__
from servotune.identify.model import ALL_PARAMS, PARAMS, UNITS
from servotune.identify.quality import BOOTSTRAP_REPLICATES
from servotune.modal import discretize
from servotune.plant import Plant
from servotune.rig import PlantFit

if TYPE_CHECKING:
    import control

    from servotune.identify.modes import ModeFit
    from servotune.identify.resonant import WrittenPlant

__all__ = ["ClosedLoopBiasWarning", "FitResult", "InadequateModelWarning", "PoorFitWarning"]

FIT_SCHEMA = "servotune.fit/2"
"""Schema of ``servotune fit --json`` (``/2``: method, intervals, diagnostics, friction form)."""


class PoorFitWarning(UserWarning):
    """The identified model explains the data poorly (low cross-validated fit)."""


class ClosedLoopBiasWarning(UserWarning):
    """Least squares was used on a log where it may be biased (no usable external signal)."""


class InadequateModelWarning(UserWarning):
    """A residual test failed: the model or its noise model misses something in the data."""


@dataclass(frozen=True, slots=True, kw_only=True)
class FitResult:
    """An identified axis model. Every quantity here is a fitted result.

    Attributes
    ----------
    structure : tuple of str
        Parameters estimated (always ``gain_cps_per_v`` and ``tau_s``; with the asymmetric
        friction form also ``gain_neg_cps_per_v`` and, with Coulomb friction,
        ``coulomb_neg_v``).
    params : dict
        Fitted value of every axis-model parameter (0 for terms left out), and of the negative
        direction's ones for the asymmetric form [units in the names, :attr:`units`].
    std : dict
        Standard deviation of each estimated parameter (:attr:`interval_method`).
    ci95 : dict
        95 % interval of each estimated parameter.
    method : str
        ``"iv"`` (refined instrumental variables, :mod:`servotune.identify.iv`) or ``"oe"``
        (output-error least squares, :mod:`servotune.identify.oe`).
    method_reason : str
        Why this method.
    interval_method : str
        How the intervals were made.
    friction : str
        ``"sym"`` or ``"asym"``.
    friction_selection : dict
        The choice between the friction forms and both scores (empty when it was given).
    fit_pct : dict
        ``{"position"|"velocity": {"estimation": %, "validation": %, "folds": [%, %]}}``:
        the whole-log model on the whole log, and split-half cross-validation (each half's
        model on the other half; ``validation`` their mean, None if a half could not be fitted).
    whiteness : dict
        Ljung–Box test of the noise model's innovations.
    cross_correlation : list of dict
        Innovations against each input's past (the external signals for ``iv``, the command
        for ``oe``).
    adequate : bool
        Every residual test passed.
    inadequacy : tuple of str
        Why not, one reason per failed test.
    instruments : dict
        For ``iv``: the external signals, the projection's FIR length and R².
    noise_model : dict
        The residual's ARMA model.
    period_s, compute_s : float
        Sample period and the known compute time the delay is counted beyond [s].
    selection : list of dict
        Per candidate structure: parameters, innovation variance, BIC (empty when given).
    reason : str
        Why this structure.
    n_samples : int
    cv_params : tuple of dict
        Parameters fitted on the first and on the second half (empty without CV).
    inverted_encoder : bool
        The position was negated before fitting (``--invert-encoder``).
    mode_fit : ModeFit or None
        The lightly damped modes fitted to the log's frequency response (``fit --modes``,
        :func:`servotune.identify.logfit.fit_log_modes`), with the rigid part that frequency-domain
        fit found beside them; None: not asked for (the rigid model alone).
    written : WrittenPlant or None
        When :attr:`mode_fit` has modes: the plant ``fit -o`` writes, its gain, tau and delay
        from the frequency-domain fit and its offset and friction re-estimated with them and
        the modes fixed (:mod:`servotune.identify.resonant`); None: the time-domain fit's
        parameters are written.
    """

    structure: tuple[str, ...]
    params: dict[str, float]
    std: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    method: str
    method_reason: str
    interval_method: str
    friction: str
    fit_pct: dict[str, dict[str, Any]]
    whiteness: dict[str, Any]
    cross_correlation: list[dict[str, Any]]
    adequate: bool
    period_s: float
    compute_s: float
    inadequacy: tuple[str, ...] = ()
    friction_selection: dict[str, Any] = field(default_factory=dict)
    instruments: dict[str, Any] = field(default_factory=dict)
    noise_model: dict[str, Any] = field(default_factory=dict)
    selection: list[dict[str, Any]] = field(default_factory=list)
    reason: str = ""
    n_samples: int = 0
    cv_params: tuple[dict[str, float], ...] = ()
    inverted_encoder: bool = False
    mode_fit: ModeFit | None = None
    written: WrittenPlant | None = None

    @property
    def units(self) -> dict[str, str]:
        """Unit of every parameter in :attr:`params`."""
        return {p: UNITS[p] for p in self.params}

    @property
    def plant(self) -> Plant:
        """The fitted axis model as a :class:`~servotune.plant.Plant`: the parameters fitted
        to the log (:attr:`written`'s when there is one), and the modes of :attr:`mode_fit`
        (with their 95 % intervals) if any."""
        params = self.params if self.written is None else self.written.params
        kw: dict[str, Any] = {k: float(params[k]) for k in PARAMS}
        for k in ALL_PARAMS[len(PARAMS) :]:
            if k in params:
                kw[k] = float(params[k])
        if self.mode_fit is not None:
            kw["modes"] = self.mode_fit.modes
        return Plant(**kw)

    @property
    def plant_fit(self) -> PlantFit:
        """What ``fit -o`` records beside the plant (:class:`servotune.rig.PlantFit`): with
        :attr:`written`, its estimated parameters, intervals, residual tests and whole-log
        fit % (no split-half figures: the linear part is the whole log's frequency response's)."""
        w = self.written
        if w is not None:
            return PlantFit(
                method=self.method,
                structure=w.structure,
                friction=self.friction,
                adequate=w.adequate,
                reason="; ".join(w.inadequacy),
                interval=f"gain, tau, delay: {self.mode_fit_interval}; offset and friction: "
                f"moving-block bootstrap of the output-error equations with the linear part and "
                f"the modes fixed ({BOOTSTRAP_REPLICATES} replicates), basic 95 % interval",
                velocity_fit_pct=_finite(w.fit_pct["velocity"]),
                position_fit_pct=_finite(w.fit_pct["position"]),
                ci95={k: (float(lo), float(hi)) for k, (lo, hi) in w.ci95.items()},
            )
        return PlantFit(
            method=self.method,
            structure=self.structure,
            friction=self.friction,
            adequate=self.adequate,
            reason="; ".join(self.inadequacy),
            interval=self.interval_method,
            velocity_fit_pct=_finite(self.fit_pct["velocity"]["estimation"]),
            velocity_fit_cv_pct=_finite(self.fit_pct["velocity"]["validation"]),
            position_fit_pct=_finite(self.fit_pct["position"]["estimation"]),
            position_fit_cv_pct=_finite(self.fit_pct["position"]["validation"]),
            ci95={k: (float(lo), float(hi)) for k, (lo, hi) in self.ci95.items()},
        )

    @property
    def mode_fit_interval(self) -> str:
        """How the frequency-domain fit's intervals are made (:mod:`servotune.identify.modes`)."""
        return (
            "the frequency-domain fit's Jacobian, widened by its reduced chi-square "
            f"({self.mode_fit.reduced_chi_square:.3g})"
            if self.mode_fit is not None
            else ""
        )

    @property
    def model(self) -> control.TransferFunction:
        """Continuous ``K / (s (tau s + 1))`` [counts/V] (the delay is in :attr:`params`)."""
        return self.plant.to_tf()

    @property
    def discrete_model(self) -> control.StateSpace:
        """Exact ZOH model at the log's period with the total lag (compute + delay)."""
        return discretize(self.plant, self.period_s, self.compute_s + self.params["delay_s"])

    def provenance(self, log_name: str, log_sha256: str, log_date: str = "") -> str:
        """One line saying where the model comes from, for the rig file's plant table: the
        tool, the log (its name, the start of its SHA-256, its ``date`` metadata if any), the
        method and structure, the cross-validated velocity fit and the adequacy."""
        vel = self.fit_pct["velocity"]["validation"]
        when = f", logged {log_date}" if log_date else ""
        return (
            f"fitted by servotune {__version__} from {log_name} (sha256 {log_sha256[:12]}…"
            f"{when}): {self.method}, {'+'.join(self.structure)}, cross-validated velocity fit "
            + ("n/a" if vel is None else f"{vel:.1f} %")
            + f", adequate: {'yes' if self.adequate else 'no (' + self.reason + ')'}"
            + ("" if self.mode_fit is None else f"; {_modes_said(self.mode_fit)}")
            + ("" if self.written is None else f"; {_written_said(self.written)}")
        )

    def summary(self) -> str:
        """A readable multi-line summary (what ``servotune fit`` prints on stderr)."""
        lines = [
            f"method: {self.method} ({self.method_reason})",
            f"structure: {' + '.join(self.structure)} ({self.reason})",
        ]
        fs = self.friction_selection
        lines.append(f"friction: {self.friction}" + (f" ({fs['reason']})" if fs else ""))
        for p in self.params:
            if p in self.structure:
                lo, hi = self.ci95[p]
                lines.append(
                    f"  {p:18s} {self.params[p]:12.6g} {UNITS[p]:10s} 95 %: "
                    f"{lo:.6g} … {hi:.6g} (± {self.std[p]:.2g})"
                )
            else:
                lines.append(f"  {p:18s} {'left out':>12s}")
        lines.append(f"intervals: {self.interval_method}")
        f = self.fit_pct
        lines.append(
            f"fit (MATLAB compare) velocity {f['velocity']['estimation']:.1f} % on the whole "
            f"log, {_pct(f['velocity']['validation'])} cross-validated; position "
            f"{f['position']['estimation']:.1f} % / {_pct(f['position']['validation'])}"
        )
        w = self.whiteness
        tests = [f"innovations whiteness (Ljung-Box, {w['lags']} lags) p = {w['p_value']:.3g}"]
        tests += [
            f"cross-correlation with {c['input']} p = {c['p_value']:.3g}"
            for c in self.cross_correlation
        ]
        lines.append("residual tests: " + "; ".join(tests))
        lines.append(
            "adequate: yes" if self.adequate else "adequate: NO: " + "; ".join(self.inadequacy)
        )
        lines.append(
            f"period {self.period_s * 1e3:.6g} ms, {self.n_samples} samples, "
            f"delay counted beyond compute_s = {self.compute_s * 1e3:g} ms"
            + (", encoder inverted" if self.inverted_encoder else "")
        )
        if self.mode_fit is not None:
            lines.append(
                f"modes, fitted to the log's frequency response ({self.mode_fit.lines} lines); "
                "its rigid part beside the time-domain one above:"
            )
            lines += ["  " + line for line in self.mode_fit.summary().splitlines()]
        if self.written is not None:
            lines += self.written.summary(self.fit_pct["velocity"]["estimation"])
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict for JSON (every field; ``parameters`` gathers value, interval and unit)."""
        d: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in ("mode_fit", "written"):  # only with fit --modes (and modes found for
                if v is not None:  # the written plant): the same JSON without
                    d["written_plant" if f.name == "written" else f.name] = v.to_dict()
                continue
            if f.name == "ci95":
                v = {k: [float(a), float(b)] for k, (a, b) in v.items()}
            elif isinstance(v, tuple):
                v = list(v)
            d[f.name] = v
        d["units"] = self.units
        d["parameters"] = {
            p: {
                "value": float(self.params[p]),
                "unit": UNITS[p],
                "estimated": p in self.ci95,
                "ci95": [float(x) for x in self.ci95[p]] if p in self.ci95 else None,
                "std": float(self.std[p]) if p in self.std else None,
            }
            for p in self.params
        }
        return _finite(d)


def _modes_said(mode_fit: ModeFit) -> str:
    n = len(mode_fit.modes)
    return f"{n} mode{'' if n == 1 else 's'} ({mode_fit.order_rule}) from its frequency response"


def _written_said(written: WrittenPlant) -> str:
    refined = [p for p in written.structure if p in ("offset_v", "coulomb_v", "coulomb_neg_v")]
    return (
        "written: gain, tau, delay from the frequency-domain fit"
        + (f", {', '.join(refined)} re-estimated with the modes" if refined else "")
        + f", velocity fit {written.fit_pct['velocity']:.1f} % on the whole log, adequate: "
        + ("yes" if written.adequate else "no")
    )


def _pct(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.1f} %"


def _finite(x: Any) -> Any:
    """``x`` with every non-finite float replaced by None (strict JSON)."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_finite(v) for v in x]
    return x
