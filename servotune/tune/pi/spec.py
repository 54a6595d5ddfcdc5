"""What a PI design is asked and what it returns: the targets, their checks, the result.

:data:`DEFAULT_TARGETS` are the default robustness targets, :class:`PITuning` is a design from
:func:`~servotune.tune.pi.design.tune_pi` with its margins; the private part holds the checked
targets (``Spec``) and the tolerances and limits of the synthesis.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from servotune.errors import SpecError
from servotune.io.files import json_float
from servotune.laws.pi import PIGains

__all__ = [
    "DEFAULT_TARGETS",
    "TOL_GM_DB",
    "TOL_MS_REL",
    "TOL_PM_DEG",
    "TOL_WC_REL",
    "PITuning",
]

DEFAULT_TARGETS: Mapping[str, float] = {
    "phase_margin_deg": 50.0,
    "gain_margin_db": 8.0,
    "max_sensitivity": 1.6,
}
"""Default robustness targets of a position-loop PI design (the master, the slave's start
point, the gantry drives, the linkage axes)."""

# how far a reported design may miss each target (deg, dB, relative, relative): the check's
# tolerances (check.acceptable) and the grid screen's slack (grid.start_point)
TOL_PM_DEG, TOL_GM_DB, TOL_MS_REL, TOL_WC_REL = 0.5, 0.1, 0.01, 0.01
REFINE_ROUNDS = 8  # NLP solves at most
MAX_BUILDS = 3  # NLP rebuilds for a changed crossing structure at most
GUARD_GAIN = 0.95  # |L| at a guard against a new gain crossover, at most
PEAK_STENCIL = np.array([0.995, 0.998, 1.0, 1.002, 1.005])  # added around a missed Ms peak


@dataclass(frozen=True, slots=True, kw_only=True)
class PITuning:
    """A PI design from :func:`tune_pi` and its margins as python-control computes them.

    The margins are computed results for the exact discrete loop
    ``L(z) = (Kp + Ki·T·z/(z−1)) · lsb_v · P(z)`` (``P`` with ZOH and the input lag).

    Parameters
    ----------
    kp : float
        Proportional gain [codes/count] (for a transfer-function plant: input units per output
        unit, divided by ``lsb_v``).
    ki : float
        Integral gain [codes/(count·s)].
    period_s : float
        Sample period the design is for [s].
    compute_s : float
        Tick start → output write [s] (part of the loop's lag).
    lsb_v : float
        Output step [V per code] (1.0 for a plain transfer function).
    crossover_rad_s : float
        Gain crossover frequency (where ``|L| = 1``; the one python-control reports with the
        phase margin) [rad/s]; NaN if ``|L|`` never crosses 1.
    phase_margin_deg : float
        Phase margin [deg]; ``inf`` if there is no gain crossover.
    gain_margin_db : float
        Gain margin [dB] (python-control's choice among the phase crossovers: the one closest
        to 0 dB); ``inf`` if the phase never crosses −180°.
    phase_crossover_rad_s : float
        Frequency of that phase crossover [rad/s]; NaN if none.
    max_sensitivity : float
        Peak of ``|1/(1 + L)|`` over ``(0, π/T]`` [-].
    sensitivity_peak_rad_s : float
        Where that peak is [rad/s].
    spectral_radius : float
        Largest closed-loop pole magnitude [-], < 1 (the loop is stable).
    target_phase_margin_deg, target_gain_margin_db, target_max_sensitivity : float or None
        The lower bounds (margins) and upper bound (sensitivity) asked; None if not asked.
    target_crossover_rad_s : float or None
        Upper bound asked on the gain crossover [rad/s].
    binding : tuple of str
        Targets met with (almost) no slack, by name (``"phase_margin_deg"``, ...): the ones
        that limit Ki.
    solver_status : str
        Ipopt's return status of the final solve (``"Solve_Succeeded"``, ...), or
        ``"start point"`` if the grid search's design was kept.
    solver_iterations : int
        Ipopt iterations over all solves (refinements included).
    """

    kp: float
    ki: float
    period_s: float
    compute_s: float
    lsb_v: float
    crossover_rad_s: float
    phase_margin_deg: float
    gain_margin_db: float
    phase_crossover_rad_s: float
    max_sensitivity: float
    sensitivity_peak_rad_s: float
    spectral_radius: float
    target_phase_margin_deg: float | None = None
    target_gain_margin_db: float | None = None
    target_max_sensitivity: float | None = None
    target_crossover_rad_s: float | None = None
    binding: tuple[str, ...] = ()
    solver_status: str = ""
    solver_iterations: int = 0

    def __post_init__(self) -> None:
        for name, unit in (("kp", "codes/count"), ("ki", "codes/(count·s)")):
            v = getattr(self, name)
            if not _is_real(v) or not math.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be a finite number >= 0 [{unit}], got {v!r}")
        for name, unit in (("period_s", "s"), ("lsb_v", "V")):
            v = getattr(self, name)
            if not _is_real(v) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a finite number > 0 [{unit}], got {v!r}")
        if not _is_real(self.compute_s) or not self.compute_s >= 0:
            raise ValueError(f"compute_s must be >= 0 [s], got {self.compute_s!r}")
        if not _is_real(self.spectral_radius) or not 0 <= self.spectral_radius < 1:
            raise ValueError(
                f"spectral_radius must be in [0, 1) (a stable loop), got {self.spectral_radius!r}"
            )
        object.__setattr__(self, "binding", tuple(self.binding))

    @property
    def gains(self) -> PIGains:
        """The gains as :class:`~servotune.laws.pi.PIGains` (what the runtime and engine use)."""
        return PIGains(kp=self.kp, ki=self.ki)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (sorted keys); non-finite numbers (``inf``, NaN) become None.

        ``gain_margin_db: None`` thus means "no phase crossover" (infinite gain margin), a
        ``target_*: None`` that the target was not asked.
        """
        out: dict[str, Any] = {}
        for name in sorted(self.__slots__):  # type: ignore[attr-defined]
            v = getattr(self, name)
            if isinstance(v, float):
                v = json_float(v)
            elif isinstance(v, tuple):
                v = list(v)
            out[name] = v
        return out


def _is_real(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


class Spec(NamedTuple):
    pm_deg: float | None
    gm_db: float | None
    ms: float | None
    wc_max: float | None

    def describe(self) -> str:
        parts = []
        if self.pm_deg is not None:
            parts.append(f"phase_margin_deg >= {self.pm_deg:g}")
        if self.gm_db is not None:
            parts.append(f"gain_margin_db >= {self.gm_db:g}")
        if self.ms is not None:
            parts.append(f"max_sensitivity <= {self.ms:g}")
        if self.wc_max is not None:
            parts.append(f"crossover_rad_s <= {self.wc_max:g}")
        return ", ".join(parts)


def check_spec(
    period_s: float,
    compute_s: float,
    lsb_v: float,
    pm: float | None,
    gm: float | None,
    ms: float | None,
    wc: float | None,
) -> Spec:
    def real(name: str, v: object, unit: str) -> float:
        if not _is_real(v) or not math.isfinite(v):  # type: ignore[arg-type]
            raise ValueError(f"{name} must be a finite number [{unit}], got {v!r}")
        return float(v)  # type: ignore[arg-type]

    if real("period_s", period_s, "s") <= 0:
        raise ValueError(f"period_s must be > 0 [s], got {period_s!r}")
    if real("compute_s", compute_s, "s") < 0:
        raise ValueError(f"compute_s must be >= 0 [s], got {compute_s!r}")
    if real("lsb_v", lsb_v, "V") <= 0:
        raise ValueError(f"lsb_v must be > 0 [V], got {lsb_v!r}")
    if pm is None and gm is None and ms is None:
        raise SpecError(
            "give at least one of phase_margin_deg, gain_margin_db, max_sensitivity "
            "(crossover_rad_s alone does not make the loop robust)"
        )
    if pm is not None and not 0 < real("phase_margin_deg", pm, "deg") < 90:
        raise SpecError(f"phase_margin_deg must be in (0, 90) [deg], got {pm!r}")
    if gm is not None and not real("gain_margin_db", gm, "dB") > 0:
        raise SpecError(f"gain_margin_db must be > 0 [dB], got {gm!r}")
    if ms is not None and not real("max_sensitivity", ms, "-") > 1:
        raise SpecError(f"max_sensitivity must be > 1 (no loop has a smaller peak), got {ms!r}")
    if wc is not None:
        nyq = math.pi / period_s
        if not 0 < real("crossover_rad_s", wc, "rad/s") < nyq:
            raise SpecError(
                f"crossover_rad_s must be in (0, π/period_s = {nyq:.6g}) [rad/s], got {wc!r}"
            )
    return Spec(
        None if pm is None else float(pm),
        None if gm is None else float(gm),
        None if ms is None else float(ms),
        None if wc is None else float(wc),
    )
