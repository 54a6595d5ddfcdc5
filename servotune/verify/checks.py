"""The checks no scenario limit shows: that no runtime sum can overflow with the tuning's
constants, the timer's period error, and the fastest motion against the counter's speed
limits."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from servotune.analysis.plant_cases import mode_factors
from servotune.fixed import E_MAX, F_U, INT64_MAX
from servotune.hw import counter as hw_counter
from servotune.laws.axis import AxisController
from servotune.laws.filters import chain_response
from servotune.laws.fuzzy_pid import TABLE_NAMES, FuzzyPIDConstants
from servotune.rig import Rig
from servotune.tuning import Tuning
from servotune.verify.result import Check
from servotune.verify.spec import Spec

__all__ = [
    "check_filter_attenuation",
    "check_overflow",
    "check_speed",
    "check_timer",
    "max_safe_gain_q",
]

FAULT_QUANTITY = "fault_runs"


# --- checks --------------------------------------------------------------------------------


def max_safe_gain_q() -> int:
    """Largest gain magnitude ``|q|`` whose product with a clamped error fits int64.

    Errors are clamped to ``±(2^31 − 1)`` before any product
    (docs/runtime.md#saturation-and-clamps), so ``|q · e| <= |q| ·
    (2^31 − 1)``; that is at most ``2^63 − 1`` for ``|q| <= 2^32 + 2``.

    Examples
    --------
    >>> max_safe_gain_q() == 2**32 + 2
    True
    """
    return int(INT64_MAX) // int(E_MAX)


def _gain_terms(c: AxisController) -> list[tuple[str, int, int]]:
    """(name, largest |q| the runtime multiplies by a clamped value, f) of every gain."""
    terms = [("lock_gain", abs(c.lock_gain.q), c.lock_gain.f)]
    t = c.task
    if t is None:
        return terms
    if isinstance(t, FuzzyPIDConstants):
        for name, base, (tq, f_t) in zip(TABLE_NAMES, t.bases, t.tables, strict=True):
            shift = base.f - int(f_t)
            if shift < 0:
                terms.append((f"{name} table (f_t {f_t} > f {base.f})", 0, -1))
                continue
            sched = [int(base.q) + int(x) * (1 << shift) for x in np.asarray(tq).reshape(-1)]
            q_max = max(abs(int(base.q)), *(abs(s) for s in sched))
            label = {"kp": "kp", "ki": "ki_t", "kd": "kd_t", "k1": "k1_t"}[name]
            terms.append((f"scheduled {label}", q_max, base.f))
        terms.append(("ke", abs(t.ke.q), t.ke.f))
        terms.append(("kec", abs(t.kec.q), t.kec.f))
    else:
        terms.append(("kp", abs(t.kp.q), t.kp.f))
        terms.append(("ki_t", abs(t.ki_t.q), t.ki_t.f))
    return terms


def check_overflow(tuning: Tuning, rig: Rig) -> Check:
    """Prove, on the tuning's own constants, that no runtime sum or product can overflow.

    The bound (docs/runtime.md#saturation-and-clamps):

    - errors, error changes and reference changes are clamped to ``|e| <= 2^31 − 1`` before
      any product, so a product ``q · e`` fits int64 if ``|q| <= 2^32 + 2``
      (:func:`max_safe_gain_q`); for the fuzzy-PID law ``q`` is the scheduled gain
      ``Kx0 + ΔKx`` (the table entry aligned exactly by ``2^(f − f_t)``), checked over every
      table cell;
    - every gain has ``0 <= f <= F_U`` (products align to the output's ``F_U`` fraction bits by
      a multiplication by ``2^(F_U − f)``, saturating, never a shift of a negative value), and
      every table ``f_t <= f``;
    - the integrator is clamped to the D/A span, ``|I| <= 2^(dac_bits − 1) · 2^F_U``; every
      other sum is a saturating add, so ``|u_q| <= 2^63 − 1`` and the code
      ``shift_round(u_q, F_U) + zero`` fits easily;
    - positions are int64 counts: at the fastest axis speed limit they overflow only after the
      time in ``facts["position_overflow_years"]``.

    Returns
    -------
    Check
        ``value`` is ``log2`` of the largest product bound [bits], ``limit`` 63.
    """
    limit = max_safe_gain_q()
    per_axis: dict[str, Any] = {}
    bad: list[str] = []
    worst_bound = 1
    for name, c in zip(tuning.axis_names, tuning.controllers, strict=True):
        entries = {}
        for term, q_max, f in _gain_terms(c):
            bound = q_max * int(E_MAX)
            worst_bound = max(worst_bound, bound)
            ok_f = 0 <= f <= F_U
            ok_q = q_max <= limit
            entries[term] = {"f": f, "product_bound": bound, "q_max": q_max, "ok": ok_f and ok_q}
            if not ok_f:
                bad.append(f"{name} {term}: f = {f} outside 0..{F_U} (needs a right shift)")
            elif not ok_q:
                bad.append(
                    f"{name} {term}: |q| up to {q_max} > {limit}, |q·e| up to 2^"
                    f"{math.log2(bound):.2f} > 2^63 − 1"
                )
        per_axis[name] = entries
    i_bound = (1 << (rig.dac.bits - 1)) << F_U
    v_max = max(a.speed_limit_rpm for a in rig.axes) / 60.0 * rig.counts_per_rev
    years = float(INT64_MAX) / v_max / (365.25 * 86400.0)
    log2_worst = math.log2(worst_bound)
    if bad:
        detail = "; ".join(bad)
    else:
        detail = (
            f"largest |gain·e| <= 2^{log2_worst:.2f} < 2^63 (|e| <= 2^31 − 1, gains <= "
            f"{limit}); integrator <= 2^{math.log2(i_bound):.0f}; other sums saturate"
        )
    return Check(
        name="overflow",
        passed=not bad,
        value=log2_worst,
        limit=63.0,
        unit="bits",
        detail=detail,
        facts={
            "axes": per_axis,
            "error_clamp": int(E_MAX),
            "integrator_bound": i_bound,
            "max_safe_gain_q": limit,
            "position_overflow_years": years,
        },
    )


def check_timer(rig: Rig, max_period_error_ppm: float | None = None) -> Check:
    """The timer's achieved period against the requested one [ppm] (judged only with a limit)."""
    t = rig.timer
    err = t.period_error_ppm
    ok = max_period_error_ppm is None or abs(err) <= max_period_error_ppm
    return Check(
        name="timer_period",
        passed=bool(ok),
        value=err,
        limit=max_period_error_ppm,
        unit="ppm",
        detail=(
            f"divisor {t.divisor}: {t.achieved_period_s * 1e3:.6f} ms for {t.period_s * 1e3:g} "
            f"ms requested ({err:+.1f} ppm"
            + (")" if max_period_error_ppm is None else f", limit ±{max_period_error_ppm:g})")
        ),
        facts={
            "achieved_period_s": t.achieved_period_s,
            "divisor": t.divisor,
            "requested_period_s": t.period_s,
        },
    )


@dataclass(slots=True)
class Fastest:
    """Largest motion per tick and speed seen in the runs, and where."""

    counts_per_tick: float = 0.0
    speed_cps: float = 0.0
    where_tick: str = "no run"
    where_speed: str = "no run"


def check_speed(
    rig: Rig,
    max_counts_per_tick: float,
    max_speed_cps: float,
    *,
    where_tick: str = "",
    where_speed: str = "",
) -> tuple[Check, Check]:
    """The fastest simulated motion against the counter's two speed limits.

    Parameters
    ----------
    rig : Rig
    max_counts_per_tick : float
        Largest |motion| between two ticks in any run [counts/tick].
    max_speed_cps : float
        Largest |speed| in any run [counts/s].
    where_tick, where_speed : str
        Which run each came from (for the detail lines).

    Returns
    -------
    (Check, Check)
        ``counter_unwrap``: motion per tick against ``2^(bits − 8)`` (the high-byte rule);
        ``counter_input_frequency``: speed [r/min] against the card's input-frequency limit.
    """
    c, T, cpr = rig.counter, rig.period_s, rig.counts_per_rev
    lim_tick = hw_counter.max_counts_per_tick(c.bits)
    lim_unwrap_rpm = hw_counter.unwrap_speed_limit_rpm(c.bits, cpr, T)
    lim_input_rpm = hw_counter.input_speed_limit_rpm(c.max_input_hz, rig.encoder.pulses_per_rev)
    rpm_tick = max_counts_per_tick / T / cpr * 60.0
    rpm = max_speed_cps / cpr * 60.0
    unwrap = Check(
        name="counter_unwrap",
        passed=bool(max_counts_per_tick <= lim_tick),
        value=float(max_counts_per_tick),
        limit=float(lim_tick),
        unit="counts/tick",
        detail=(
            f"fastest motion {max_counts_per_tick:.1f} counts/tick ({rpm_tick:.0f} r/min)"
            f"{f' ({where_tick})' if where_tick else ''}; "
            f"the high-byte rule holds up to {lim_tick} counts/tick ({lim_unwrap_rpm:.0f} r/min)"
        ),
        facts={"limit_rpm": lim_unwrap_rpm, "value_rpm": rpm_tick},
    )
    freq = Check(
        name="counter_input_frequency",
        passed=bool(rpm <= lim_input_rpm),
        value=rpm,
        limit=lim_input_rpm,
        unit="r/min",
        detail=(
            f"fastest speed {rpm:.0f} r/min ({max_speed_cps * T:.1f} counts/tick)"
            f"{f' ({where_speed})' if where_speed else ''}; the card "
            f"counts up to {c.max_input_hz:g} Hz = {lim_input_rpm:.0f} r/min with "
            f"{rig.encoder.pulses_per_rev:g} pulses/rev"
        ),
        facts={
            "limit_counts_per_tick": lim_input_rpm / 60.0 * cpr * T,
            "value_counts_per_tick": max_speed_cps * T,
        },
    )
    return unwrap, freq


def check_filter_attenuation(tuning: Tuning, rig: Rig, spec: Spec) -> list[Check]:
    """With ``[margins] min_filter_attenuation_db``: one check per axis whose plant has modes
    (``filters:<axis>``), the filters' gain (their quantised coefficients at the achieved
    period) at each mode's frequency, at the ends of its range and at its nominal value
    (:func:`~servotune.analysis.plant_cases.mode_factors`: what the Monte Carlo draws), at
    most ``−min_filter_attenuation_db``. Its value is the least attenuation [dB]."""
    need = spec.min_filter_attenuation_db
    if need is None:
        return []
    out = []
    for a, (name, ctl) in enumerate(zip(tuning.axis_names, tuning.controllers, strict=True)):
        modes = rig.axes[a].plant.modes
        if not modes:
            continue
        least, at = math.inf, modes[0].freq_hz
        for m in modes:
            lo, hi = mode_factors(m)
            f = m.freq_hz * np.array([lo, 1.0, hi])
            gain = np.abs(chain_response(ctl.filters, 2 * math.pi * f, rig.period_s))
            db = -20.0 * np.log10(np.maximum(gain, 1e-300))
            if db.min() < least:
                least, at = float(db.min()), float(f[int(np.argmin(db))])
        what = "no output filter" if not ctl.filters else f"{len(ctl.filters)} filter section(s)"
        out.append(
            Check(
                name=f"filters:{name}",
                passed=least >= need,
                value=least,
                limit=need,
                unit="dB",
                detail=f"{what}: least attenuation {least:.1f} dB at {at:.4g} Hz over the modes' "
                f"ranges (at least {need:g} dB required)",
            )
        )
    return out
