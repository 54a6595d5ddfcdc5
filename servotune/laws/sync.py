"""The synchronisation compensator and the sync-error monitor
(docs/systems.md#fieldbus-gantry-with-a-listening-slave), in the runtime arithmetic
(docs/runtime.md).

The listening slave (or, cross-coupled, the CNC) feeds the **sync error** ``e = y_master −
y_slave`` [counts] through a SISO controller whose output is a **compensation added to the
slave's position command** [counts]. The law is PI or PD with a dead zone:

- dead zone: ``e_d = e − dz`` above ``dz``, ``e + dz`` below ``−dz``, else 0 (``e`` clamped to
  ±(2^31 − 1) first);
- the PI core is the runtime's own :func:`~servotune.laws.pi.pi_step` with its rails at
  ±``limit_counts`` (conditional integration, the integrator clamped to the rails), and the
  derivative term ``(Kd/T)·(e_d − e_d,prev)`` is the composite law's
  :func:`~servotune.laws.fuzzy_pid.feed_terms` with no feedforward;
- the compensation is ``clamp(shift_round(u_q, F_U), −limit, limit)`` [counts].

Entering (enable, or after a reset) is bumpless: the integrator starts at ``−Kp·e_d`` so the
first compensation is 0, and ``e_d,prev := e_d`` (no derivative kick).

The monitor compares ``|e|`` with a warning and a trip threshold, as industrial CNCs do; the
caller latches a trip (both axes stop, :data:`~servotune.laws.axis.FLAG_SYNC_TRIP`).

Gains are in counts of compensation per count of sync error: ``Kp`` [-], ``Ki·T`` [-/tick],
``Kd/T`` [-·tick] (the period folded in, no division at run time). The bound that keeps the
arithmetic exact: ``limit_counts < 2^31`` so the rails ``±limit·2^F_U`` fit in int64.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune._numba_cache import jit
from servotune.fixed import F_U, Fixed, align, clamp_e, quantize, shift_round
from servotune.laws.fuzzy_pid import feed_terms
from servotune.laws.pi import pi_step
from servotune.validate import show_value

__all__ = [
    "SYNC_LAWS",
    "SYNC_OK",
    "SYNC_TRIP",
    "SYNC_WARN",
    "SyncConstants",
    "SyncGains",
    "dead_zone",
    "sync_enter",
    "sync_monitor",
    "sync_step",
]

SYNC_LAWS = ("pi", "pd")
"""Structures of the sync compensator."""

SYNC_OK, SYNC_WARN, SYNC_TRIP = 0, 1, 2
"""Monitor levels (:func:`sync_monitor`)."""

LIMIT_MAX_COUNTS = 2**31 - 1


@dataclass(frozen=True, slots=True, kw_only=True)
class SyncGains:
    """Sync compensator in design units.

    Parameters
    ----------
    law : str
        ``"pi"`` or ``"pd"``.
    kp : float
        Proportional gain [counts of compensation per count of sync error].
    ki : float
        Integral gain [1/s] (PI only; 0 for PD).
    kd : float
        Derivative gain [s] (PD only; 0 for PI).
    dead_zone_counts : int
        Sync errors within ±dead_zone_counts give no correction [counts].
    limit_counts : int
        Largest compensation either way [counts]; also the integrator's clamp.
    """

    law: str = "pi"
    kp: float
    ki: float = 0.0
    kd: float = 0.0
    dead_zone_counts: int = 0
    limit_counts: int = 4096

    def __post_init__(self) -> None:
        if self.law not in SYNC_LAWS:
            raise ValueError(
                f"law must be one of {', '.join(SYNC_LAWS)}, got {show_value(self.law)}"
            )
        for name, unit in (("kp", "-"), ("ki", "1/s"), ("kd", "s")):
            v = getattr(self, name)
            if (
                not isinstance(v, int | float)
                or isinstance(v, bool)
                or not math.isfinite(v)
                or v < 0
            ):
                raise ValueError(
                    f"{name} must be a finite number >= 0 [{unit}], got {show_value(v)}"
                )
        if self.law == "pi" and self.kd != 0:
            raise ValueError(f"kd must be 0 for a PI sync law [s], got {show_value(self.kd)}")
        if self.law == "pd" and self.ki != 0:
            raise ValueError(f"ki must be 0 for a PD sync law [1/s], got {show_value(self.ki)}")
        dz, lim = self.dead_zone_counts, self.limit_counts
        if type(dz) is not int or dz < 0:
            raise ValueError(
                f"dead_zone_counts must be an integer >= 0 [counts], got {show_value(dz)}"
            )
        if type(lim) is not int or not 1 <= lim <= LIMIT_MAX_COUNTS:
            raise ValueError(
                f"limit_counts must be an integer in 1..{LIMIT_MAX_COUNTS} [counts], got "
                f"{show_value(lim)}"
            )

    def quantize(self, period_s: float) -> SyncConstants:
        """Fold the period in and quantise: ``Kp``, ``Ki·T`` and ``Kd/T`` as (q, f) pairs."""
        if not (isinstance(period_s, int | float) and math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"period_s must be > 0 [s], got {show_value(period_s)}")
        return SyncConstants(
            kp=quantize(self.kp),
            ki_t=quantize(self.ki * period_s),
            kd_t=quantize(self.kd / period_s),
            dead_zone_counts=self.dead_zone_counts,
            limit_counts=self.limit_counts,
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return {
            "dead_zone_counts": self.dead_zone_counts,
            "kd": self.kd,
            "ki": self.ki,
            "kp": self.kp,
            "law": self.law,
            "limit_counts": self.limit_counts,
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class SyncConstants:
    """Sync compensator constants as the runtime holds them (see the module docstring)."""

    kp: Fixed
    ki_t: Fixed
    kd_t: Fixed
    dead_zone_counts: int
    limit_counts: int

    def to_dict(self) -> dict[str, Any]:
        """Plain dict: every gain as its (q, f) pair."""
        return {
            "dead_zone_counts": self.dead_zone_counts,
            "kd_t": self.kd_t.to_dict(),
            "ki_t": self.ki_t.to_dict(),
            "kp": self.kp.to_dict(),
            "limit_counts": self.limit_counts,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SyncConstants:
        """Inverse of :meth:`to_dict` (no re-quantising)."""
        return cls(
            kp=Fixed.from_dict(d["kp"]),
            ki_t=Fixed.from_dict(d["ki_t"]),
            kd_t=Fixed.from_dict(d["kd_t"]),
            dead_zone_counts=int(d["dead_zone_counts"]),
            limit_counts=int(d["limit_counts"]),
        )


@jit(inline="always")
def dead_zone(e: int, dz: int) -> int:
    """``e`` clamped to ±(2^31 − 1), then moved towards 0 by ``dz`` (0 inside ±dz) [counts]."""
    e = clamp_e(e)
    if e > dz:
        return e - dz
    if e < -dz:
        return e + dz
    return 0


@jit(inline="always")
def sync_enter(kp_q: int, kp_f: int, dz: int, limit: int, e: int) -> tuple[int, int]:
    """Bumpless enable: returns ``(integ, e_d)`` with ``integ = −Kp·e_d`` (clamped to the rails).

    The first compensation after entering is 0; ``e_d`` is the derivative's previous value.
    """
    e_d = dead_zone(e, dz)
    integ = -align(kp_q * e_d, F_U - kp_f)
    i_max = limit * (np.int64(1) << F_U)
    if integ > i_max:
        integ = i_max
    elif integ < -i_max:
        integ = -i_max
    return integ, e_d


@jit(inline="always")
def sync_step(
    kp_q: int,
    kp_f: int,
    kit_q: int,
    kit_f: int,
    kdt_q: int,
    kdt_f: int,
    dz: int,
    limit: int,
    integ: int,
    e_prev: int,
    e: int,
) -> tuple[int, int, int]:
    """One tick of the sync compensator in the runtime arithmetic.

    Parameters
    ----------
    kp_q, kp_f, kit_q, kit_f, kdt_q, kdt_f : int
        ``Kp``, ``Ki·T`` and ``Kd/T`` as (q, f).
    dz, limit : int
        Dead zone and compensation limit [counts].
    integ : int
        Integrator [counts, F_U fraction bits].
    e_prev : int
        The dead-zoned sync error of the previous tick [counts].
    e : int
        Sync error ``y_master − y_slave`` [counts].

    Returns
    -------
    comp : int
        Compensation added to the slave's position command [counts], within ±limit.
    integ : int
        The integrator after this tick.
    e_d : int
        This tick's dead-zoned error (the next tick's ``e_prev``).
    """
    e_d = dead_zone(e, dz)
    d_term = feed_terms(kdt_q, kdt_f, 0, 0, e_d - e_prev, 0)
    # the PI core with its rails at ±limit: pi_step's "zero code" is limit, its top 2·limit
    u_q, integ = pi_step(kp_q, kp_f, kit_q, kit_f, integ, e_d, d_term, limit, 2 * limit)
    comp = shift_round(u_q, F_U)
    if comp > limit:
        comp = limit
    elif comp < -limit:
        comp = -limit
    return comp, integ, e_d


@jit(inline="always")
def sync_monitor(e: int, warn: int, trip: int) -> int:
    """Monitor level of a sync error: ``SYNC_TRIP`` if ``|e| >= trip`` (trip > 0),
    ``SYNC_WARN`` if ``|e| >= warn`` (warn > 0), else ``SYNC_OK``; ``|e|`` saturates at
    2^31 − 1 (the clamp of docs/runtime.md#saturation-and-clamps), so thresholds are meaningful up
    to that."""
    a = clamp_e(e)  # |e| of any int64 (INT64_MIN included), saturated at 2^31 − 1
    if a < 0:
        a = -a
    if trip > 0 and a >= trip:
        return SYNC_TRIP
    if warn > 0 and a >= warn:
        return SYNC_WARN
    return SYNC_OK
