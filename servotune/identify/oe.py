"""Output-error least squares (``--method oe``): the model simulated from the logged command.

The model (:mod:`servotune.identify.model`) is simulated from the logged command with the
engine's exact tick step and its position increment per tick is fitted to the logged one by
``scipy.optimize.least_squares`` (trust-region reflective, bounds), the Jacobian by forward
differences computed in parallel.

Assumes: the residual — the measured increment minus the model's — is independent of the
command. That holds in open loop (the command is played, whatever the noise), and in closed loop
only when nothing but white measurement noise disturbs the axis. Biased when: the loop is closed
and a disturbance that the controller reacts to acts on the axis (a load, a coloured drift): the
command then carries the controller's reaction to it, correlated with the residual, and the gain
comes out low by roughly the share of the command's variance that reaction makes up (6–12 % on
the example rig with an AR(1) load) — more data does not help. Use ``iv``
(:mod:`servotune.identify.iv`) when the log has an external signal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NotRequired, TypedDict, Unpack

import numpy as np
from scipy.optimize import least_squares

from servotune.identify import model
from servotune.identify.noise import NoiseModel, fit_noise_model

__all__ = ["OEFit", "OEOptions", "estimate_oe", "oe_parameters"]


@dataclass(frozen=True, slots=True, kw_only=True)
class OEFit(model.Estimate):
    """What least squares found (:class:`~servotune.identify.model.Estimate`).

    ``a_mat`` is ``JᵀJ`` (the estimating equations ``Jᵀε = 0``, differentiated) and the
    scores ``j_k·ε_k``; the noise model describes the residual after the fit (least squares
    does not use it).

    Attributes
    ----------
    nfev : int
        Residual evaluations.
    """

    nfev: int


class _Problem:
    """Residual and Jacobian of the output error, the last simulation cached."""

    def __init__(
        self,
        u: np.ndarray,
        dy: np.ndarray,
        x0: np.ndarray,
        free: np.ndarray,
        period_s: float,
        compute_s: float,
        skip: int,
    ) -> None:
        self.inputs = np.ascontiguousarray(u, dtype=float)[None, :]
        self.dy = np.ascontiguousarray(dy, dtype=float)
        self.x0, self.free = x0, free
        self.period_s, self.compute_s, self.skip = period_s, compute_s, skip
        self.v0 = float(np.mean(dy[: max(1, min(5, dy.size))]) / period_s)
        self._key: bytes | None = None
        self._jac: np.ndarray | None = None

    def full(self, z: np.ndarray) -> np.ndarray:
        x = self.x0.copy()
        x[self.free] = z
        return x

    def simulate(self, z: np.ndarray) -> np.ndarray:
        return model.simulate_increments(
            self.inputs,
            [self.full(z)],
            self.free,
            [0],
            period_s=self.period_s,
            compute_s=self.compute_s,
            v0=self.v0,
        )[0]

    def residual(self, z: np.ndarray) -> np.ndarray:
        return (self.dy - self.simulate(z))[self.skip :]

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        key = z.tobytes()
        if key != self._key:
            ((_, jac),) = model.sensitivities(
                self.inputs,
                self.full(z),
                self.free,
                (0,),
                period_s=self.period_s,
                compute_s=self.compute_s,
                v0=self.v0,
            )
            used = jac[:, self.skip :].T
            minus = np.empty(used.shape)  # one copy, in C order
            np.negative(used, out=minus)
            self._key, self._jac = key, minus
        assert self._jac is not None
        return self._jac

    def solve(self, max_nfev: int) -> Any:
        """``least_squares`` from ``x0`` within the model's bounds (its result object)."""
        x0, free, period_s = self.x0, self.free, self.period_s
        lo, hi = model.lower_bounds()[free], model.upper_bounds(period_s)[free]
        z0 = np.clip(x0[free], lo + 1e-12 * np.abs(lo), hi)
        scale = np.array(
            [
                max(abs(x0[0]), 1.0),
                max(x0[1], 1e-3),
                period_s,
                1e-3,
                1e-3,
                max(abs(x0[5]), 1.0),
                1e-3,
            ]
        )[free]
        return least_squares(
            self.residual,
            z0,
            jac=self.jacobian,
            bounds=(lo, hi),
            x_scale=scale,
            method="trf",
            max_nfev=max_nfev,
            xtol=1e-10,
            ftol=1e-12,
            gtol=1e-10,
        )


def estimate_oe(
    u: np.ndarray,
    dy: np.ndarray,
    x0: np.ndarray,
    free: np.ndarray,
    *,
    period_s: float,
    compute_s: float,
    skip: int,
    max_nfev: int = 60,
    noise0: NoiseModel | None = None,
    refit_noise: bool = True,
) -> OEFit:
    """Output-error least-squares estimate of the free parameters (module docstring).

    Parameters
    ----------
    u, dy, x0, free, period_s, compute_s, skip
        The log, the start and the structure, as for
        :func:`servotune.identify.iv.estimate_iv` (no external signals: the residual's own
        sensitivities are the instruments).
    max_nfev : int
        Most residual evaluations.
    noise0 : NoiseModel, optional
        A noise model of a similar residual: its order is refitted (``refit_noise``), or it is
        kept as it is.
    refit_noise : bool
        Refit the residual's noise model (starting from ``noise0``).

    Returns
    -------
    OEFit
    """
    prob = _Problem(u, dy, x0, free, period_s, compute_s, skip)
    sol = prob.solve(max_nfev)
    x = prob.full(sol.x)
    jac = prob.jacobian(sol.x)
    np.negative(jac, out=jac)  # the problem is done with: its Jacobian negated in place
    sim = prob.simulate(sol.x)
    r = (prob.dy - sim)[skip:]
    nm = fit_noise_model(r, start=noise0) if refit_noise or noise0 is None else noise0
    return OEFit(
        x=x,
        a_mat=jac.T @ jac,
        scores=jac * r[:, None],
        residual=r,
        whitened=nm.whiten(r)[nm.settle_samples :],
        noise=nm,
        instruments=jac.T,
        sensitivities=jac.T,
        simulated=sim,
        nfev=int(sol.nfev),
    )


class OEOptions(TypedDict):
    """The keywords of :func:`estimate_oe` that :func:`oe_parameters` passes on to it:
    ``period_s``, ``compute_s``, ``skip`` and optionally ``max_nfev``."""

    period_s: float
    compute_s: float
    skip: int
    max_nfev: NotRequired[int]


def oe_parameters(
    u: np.ndarray, dy: np.ndarray, x0: np.ndarray, free: np.ndarray, **options: Unpack[OEOptions]
) -> np.ndarray:
    """The parameter vector of :func:`estimate_oe` alone (:data:`~model.ALL_PARAMS` order).

    The same least-squares solution, without the noise model of its residual (not fitted):
    where the fit is only a start, as for the structure selection.
    """
    return estimate_oe(
        u, dy, x0, free, noise0=NoiseModel.identity(), refit_noise=False, **options
    ).x
