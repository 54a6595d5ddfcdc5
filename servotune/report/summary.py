"""What a report says first: the verdict, the tightest margin and what to do next.

Every sentence here is derived from the numbers it is given (a verification, the loop margins);
none is fixed text. :func:`summarise` reads a :class:`~servotune.verify.result.Verification`
into a :class:`ReportSummary`; :func:`next_step` turns the verdict (or the failure that weighs
most) into one or two sentences naming the command or the knob; :func:`margin_comment` says why
the master's and the slave's phase margins differ (:mod:`servotune.analysis.margins`: the slave
runs one loop per query-table cell).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

from servotune.validate import show_share

if TYPE_CHECKING:
    from servotune.verify.result import Verification

__all__ = [
    "Limit",
    "ReportSummary",
    "limits_of",
    "margin_comment",
    "next_step",
    "pass_fraction_text",
    "search_notes",
    "summarise",
]

_FAULT = "fault_runs"  # servotune.verify.checks._FAULT_QUANTITY (a count, limit 0)


@dataclass(frozen=True, slots=True, kw_only=True)
class Limit:
    """One judged limit: a scenario row or a check with a numeric bound.

    Attributes
    ----------
    name : str
        ``"sync: max_sync_error_counts of slave"`` or ``"check margins:slave:task"``.
    worst : float
        The worst value [unit].
    limit : float
        The bound [unit] (an upper bound).
    unit : str
    passed : bool
    relative_margin : float
        ``(limit − worst) / limit`` [1]; negative when broken.
    where : str
        The variant (plant set) or detail that gave ``worst``.
    """

    name: str
    worst: float
    limit: float
    unit: str
    passed: bool
    relative_margin: float
    where: str = ""

    def describe(self) -> str:
        """``"sync: max_sync_error_counts of slave is 954.8 counts against a limit of 1843
        counts (48 % left)"``."""
        u = f" {self.unit}" if self.unit and self.unit != "1" else ""
        left = self.relative_margin * 100.0
        state = f"{left:.0f} % left" if left >= 0 else f"{-left:.0f} % over"
        return (
            f"{self.name} is {_num(self.worst)}{u} against a limit of "
            f"{_num(self.limit)}{u} ({state})"
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class ReportSummary:
    """The head of a report.

    Attributes
    ----------
    verified : bool
        A verification was given.
    passed : bool
        It passed (False when not verified).
    failed : int
        Limits and checks that failed.
    total : int
        Limits and checks judged.
    failures : tuple of str
        One line per failure (:attr:`Verification.failures`).
    tightest : Limit or None
        The limit with the least relative margin (the most broken one when some fail).
    montecarlo : tuple or None
        ``(passed, count, fraction, low, high)`` over the Monte-Carlo plant sets, the
        Clopper–Pearson 95 % interval (None without variants).
    next_step : str
        What to do next (:func:`next_step`).
    """

    verified: bool
    passed: bool
    failed: int
    total: int
    failures: tuple[str, ...] = ()
    tightest: Limit | None = None
    montecarlo: tuple[int, int, float, float, float] | None = None
    next_step: str = ""

    @property
    def verdict(self) -> str:
        """``"PASSED"``, ``"FAILED"`` or ``"NOT VERIFIED"``."""
        if not self.verified:
            return "NOT VERIFIED"
        return "PASSED" if self.passed else "FAILED"

    def headline(self) -> str:
        """``"PASSED: 0 of 41 limits and checks failed"``."""
        if not self.verified:
            return "NOT VERIFIED: no verification was run for this report"
        return f"{self.verdict}: {self.failed} of {self.total} limits and checks failed"

    def montecarlo_text(self) -> str:
        """The Monte-Carlo pass fraction with its interval, or "" without variants."""
        if self.montecarlo is None:
            return ""
        return pass_fraction_text(self.montecarlo)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (non-finite numbers as None)."""
        out: dict[str, Any] = {f.name: getattr(self, f.name) for f in fields(self)}
        out["failures"] = list(self.failures)
        out["tightest"] = (
            None
            if self.tightest is None
            else {f.name: _finite(getattr(self.tightest, f.name)) for f in fields(self.tightest)}
        )
        if self.montecarlo is not None:
            k, n, frac, lo, hi = self.montecarlo
            out["montecarlo"] = {
                "passed": k,
                "count": n,
                "fraction": _finite(frac),
                "ci95": [lo, hi],
                "interval": "Clopper-Pearson",
            }
        out["verdict"] = self.verdict
        return out


def pass_fraction_text(
    pass_fraction: tuple[int, int, float, float, float],
    what: str = "plant variants keep every limit",
) -> str:
    """``Monte Carlo: k of n <what> (p %; 95 % interval lo–hi %, Clopper–Pearson)`` from a
    ``(k, n, fraction, low, high)`` pass fraction (shares by
    :func:`~servotune.validate.show_share`: never 100.0 % while one run failed)."""
    k, n, frac, lo, hi = pass_fraction
    return (
        f"Monte Carlo: {k} of {n} {what} ({show_share(frac)} %; 95 % interval "
        f"{show_share(lo)}–{show_share(hi)} %, Clopper–Pearson)"
    )


def _finite(x: Any) -> Any:
    return None if isinstance(x, float) and not math.isfinite(x) else x


def _num(x: float) -> str:
    if not math.isfinite(x):
        return "never" if x > 0 else "n/a"
    return f"{x:.4g}"


def limits_of(v: Verification) -> list[Limit]:
    """Every row with a positive limit and every check with a bound, as :class:`Limit`."""
    out = []
    for r in v.rows:
        if r.quantity == _FAULT or not r.limit > 0:
            continue
        rel = r.relative_margin
        out.append(
            Limit(
                name=f"{r.scenario}: {r.quantity} of {r.axis}",
                worst=float(r.worst),
                limit=float(r.limit),
                unit=r.unit,
                passed=r.passed,
                relative_margin=-math.inf if rel is None or math.isnan(rel) else rel,
                where=f"variant {r.variant}",
            )
        )
    for c in v.checks:
        if c.limit is None or not c.limit > 0 or not math.isfinite(c.value):
            continue
        # a check's bound is an upper bound on |value| (Ms, ppm, counts per tick)
        worst = abs(float(c.value))
        out.append(
            Limit(
                name=f"check {c.name}",
                worst=worst,
                limit=float(c.limit),
                unit=c.unit,
                passed=c.passed,
                relative_margin=(c.limit - worst) / c.limit,
                where=c.detail,
            )
        )
    return out


def summarise(
    verification: Verification | None,
    *,
    tuning_path: str = "TUNING",
    rig_path: str = "RIG",
    spec_path: str | None = None,
) -> ReportSummary:
    """The head of a report from a verification (or its absence).

    Parameters
    ----------
    verification : Verification or None
    tuning_path, rig_path : str
        The files as the user named them (written into the commands of the next step).
    spec_path : str, optional
        The spec file verified against (default: a placeholder naming the spec).
    """
    if verification is None:
        step = next_step(None, tuning_path=tuning_path, rig_path=rig_path, spec_path=spec_path)
        return ReportSummary(verified=False, passed=False, failed=0, total=0, next_step=step)
    v = verification
    failed = sum(not r.passed for r in v.rows) + sum(not c.passed for c in v.checks)
    limits = limits_of(v)
    tightest = min(limits, key=lambda x: x.relative_margin) if limits else None
    k, n, frac, lo, hi = v.pass_fraction
    return ReportSummary(
        verified=True,
        passed=v.passed,
        failed=failed,
        total=len(v.rows) + len(v.checks),
        failures=tuple(v.failures),
        tightest=tightest,
        montecarlo=(k, n, frac, lo, hi) if n else None,
        next_step=next_step(v, tuning_path=tuning_path, rig_path=rig_path, spec_path=spec_path),
    )


# The knob for each quantity a scenario limits: what to change, in the user's terms. ``{rig}``,
# ``{tuning}``, ``{spec}``, ``{scenario}`` and ``{axis}`` are filled in.
_RETUNE = "servotune tune {rig} --spec {spec} -o {tuning}"
_KNOBS: Mapping[str, str] = {
    "overshoot_pct": (
        "the {axis} runs past its stop: ask the tuner for more phase margin "
        "(`{retune} --pm 55`), or give the move a gentler ramp (accel_s in the spec's "
        "[scenario.{scenario}])"
    ),
    "settling_time_s": (
        "the {axis} settles late: more phase margin damps the stop (`{retune} --pm 55`); or, if "
        "the machine allows it, more time (max_settling_time_s in [scenario.{scenario}])"
    ),
    "max_sync_error_counts": (
        "the slave falls too far behind: tune it for this spec's sync run with a larger budget "
        "(`{retune} --generations 80 --population 48`)"
    ),
    "rms_sync_error_counts": (
        "the slave stays too far behind on average: tune it for this spec's sync run with a "
        "larger budget (`{retune} --generations 80 --population 48`)"
    ),
    "steady_lag_counts": (
        "the slave lags at constant speed: its feedforward (K1) is too weak for this move; "
        "re-tune for this spec (`{retune}`)"
    ),
    "saturation_pct": (
        "the {axis}'s D/A sits on a rail: re-tune with a tighter `--max-saturation-pct`, or "
        "slow the move (speed_fraction in [scenario.{scenario}])"
    ),
    "holding_band_counts": (
        "the position lock lets the {axis} drift out of its band: null the drive's zero "
        "offset, or raise its lock gain (lock_gain_codes_per_count in {rig}) and re-tune"
    ),
    _FAULT: (
        "a run of the {axis} latched a fault (following-error trip or counter fault): slow the "
        "move (speed_fraction in [scenario.{scenario}]) or, if the error is expected, raise "
        "following_error_limit_counts in {rig}"
    ),
}
_CHECK_KNOBS: Mapping[str, str] = {
    "margins": (
        "a loop breaks the margin limits over the plant set (`servotune margins {tuning}` lists "
        "every loop): re-tune with this spec so the tuner holds every cell to its [margins] "
        "(`{retune}`)"
    ),
    "counter_unwrap": (
        "the fastest motion is beyond what the counter can unwrap: lower the moves' "
        "speed_fraction in the spec or the axis's speed_limit_rpm in {rig}"
    ),
    "counter_input_frequency": (
        "the fastest motion exceeds the counter card's input frequency: lower the moves' "
        "speed_fraction in the spec or the axis's speed_limit_rpm in {rig}"
    ),
    "timer_period": (
        "the achieved tick period is too far from the requested one: choose a period the "
        "8253 divisor reaches more closely (timer.period_s in {rig})"
    ),
    "overflow": (
        "the gains overflow the runtime's fixed-point arithmetic: re-tune (`{retune}`) with "
        "smaller bounds"
    ),
}


def _knob(text: str, **names: str) -> str:
    return text.format(**names, retune=_RETUNE.format(**names))


def next_step(
    verification: Verification | None,
    *,
    tuning_path: str = "TUNING",
    rig_path: str = "RIG",
    spec_path: str | None = None,
) -> str:
    """What to do next, in one or two sentences that follow from the verdict.

    Passed: export the verified tables (and, when the tightest limit is within 10 %, name
    it). Failed: the failure that weighs most (the largest relative excess, a failed check
    before a fault count) with its numbers and the knob that moves it. Not verified: verify.

    Examples
    --------
    >>> next_step(None, tuning_path="tuning.json")[:40]
    'Not verified: judge the tuning against y'
    """
    spec = spec_path or "SPEC"
    if verification is not None and verification.spec.name and spec_path is None:
        spec = f"SPEC (the spec {verification.spec.name!r})"
    names = {"rig": rig_path, "tuning": tuning_path, "spec": spec}
    if verification is None:
        return (
            f"Not verified: judge the tuning against your limits with `servotune verify "
            f"{tuning_path} --spec {spec} --report DIR`; export-table refuses an unverified "
            "tuning."
        )
    v = verification
    if v.passed:
        text = (
            f"Passed: export the verified tables with `servotune export-table {tuning_path} "
            f"-o fuzzy.json` (or `--format c -o c/` for the C runtime)."
        )
        limits = limits_of(v)
        if limits:
            t = min(limits, key=lambda x: x.relative_margin)
            if t.relative_margin < 0.10:
                text += (
                    f" Keep an eye on the tightest limit: {t.describe()}; it will fail "
                    "first if the machine differs from its model."
                )
        return text
    if not v.rows:
        return (
            "Failed before the closed-loop runs: "
            + "; ".join(v.failures)
            + ". "
            + _knob(_CHECK_KNOBS["overflow"], **names).capitalize()
            + "."
        )
    # the failure that weighs most: a failed check, else the row most over its limit
    bad_checks = [c for c in v.checks if not c.passed]
    bad_rows = [r for r in v.rows if not r.passed]
    n_more = len(bad_checks) + len(bad_rows) - 1
    more = f" ({n_more} more failure{'s' if n_more != 1 else ''} listed below.)" if n_more else ""
    if bad_checks:
        c = bad_checks[0]
        key = c.name.split(":", 1)[0]
        knob = _CHECK_KNOBS.get(key, "see the check's detail")
        return (
            f"Failed: check {c.name}: {c.detail}. Next: "
            f"{_knob(knob, **names, axis='', scenario='')}.{more}"
        )

    def excess(r: Any) -> float:
        rel = r.relative_margin
        return -math.inf if rel is None or math.isnan(rel) else rel

    finite = [r for r in bad_rows if r.quantity != _FAULT]
    r = min(finite, key=excess) if finite else bad_rows[0]
    u = f" {r.unit}"
    what = (
        f"{r.scenario}: {r.quantity} of {r.axis} is {_num(float(r.worst))}{u} against a "
        f"limit of {_num(float(r.limit))}{u} (variant {r.variant})"
    )
    knob = _KNOBS.get(r.quantity, "see the failing row")
    return f"Failed: {what}. Next: {_knob(knob, **names, axis=r.axis, scenario=r.scenario)}.{more}"


def margin_comment(
    centre: Mapping[str, Any],
    cells: Mapping[str, Sequence[Any]],
    *,
    min_phase_margin_deg: float,
) -> str:
    """Why the phase margins in the Bode table differ between the axes, from the numbers.

    Parameters
    ----------
    centre : mapping
        Per axis, the phase margin [deg] of the loop the Bode plot shows (a PI axis's only
        task loop, a scheduled axis's table centre).
    cells : mapping
        Per scheduled axis, its task loops on the nominal plant, one per query-table cell
        (objects with ``phase_margin_deg`` and ``cell``, :class:`LoopMargins`).
    min_phase_margin_deg : float
        The limit every loop is held to [deg].

    Returns
    -------
    str
        One paragraph ("" with fewer than two axes).
    """
    names = list(centre)
    if len(names) < 2:
        return ""
    parts = []
    fixed = [a for a in names if a not in cells]
    sched = [a for a in names if a in cells]
    shown = ", ".join(f"{a} {centre[a]:.0f}°" for a in names)
    parts.append(f"Phase margins in the table above: {shown}.")
    for a in sched:
        loops = [m for m in cells[a] if math.isfinite(m.phase_margin_deg)]
        if not loops:
            continue
        lo = min(loops, key=lambda m: m.phase_margin_deg)
        hi = max(loops, key=lambda m: m.phase_margin_deg)
        c = centre[a]
        rel = (
            "lower than"
            if any(c < centre[f] - 5 for f in fixed)
            else ("higher than" if any(c > centre[f] + 5 for f in fixed) else "close to")
        )
        versus = f", {rel} the {' and '.join(fixed)}'s," if fixed else ""
        parts.append(
            f"They are different loops: the {a} runs one loop per query-table cell (its gains "
            f"scheduled by the fuzzy levels of the error E and its change EC; the feedforward "
            f"K1 acts on the reference and changes no margin), and the Bode plot shows only the "
            f"centre cell (E = EC = 0, where it sits in steady following) with {c:.0f}°{versus} "
            f"while over its {len(cells[a])} cells the phase margin runs from "
            f"{lo.phase_margin_deg:.0f}° (cell E={lo.cell[0]:+d} EC={lo.cell[1]:+d}) to "
            f"{hi.phase_margin_deg:.0f}° (E={hi.cell[0]:+d} EC={hi.cell[1]:+d}) on the nominal "
            "plant (heat map below)."
        )
        below = [m for m in loops if m.phase_margin_deg < min_phase_margin_deg]
        if below:
            parts.append(
                f"{len(below)} of its cells are below the {min_phase_margin_deg:g}° limit on the "
                "nominal plant: those loops are under-damped where the fuzzy table sends the "
                "slave, and the verification's margins check fails for them."
            )
        else:
            parts.append(
                f"Every cell keeps the {min_phase_margin_deg:g}° limit on the nominal plant; "
                "the verification's margins checks judge them over the whole plant set."
            )
    if fixed:
        parts.append(
            f"The {' and '.join(fixed)} runs one fixed-gain loop: its phase margin is "
            "the one shown."
        )
    return " ".join(parts)


def search_notes(slave: Mapping[str, Any]) -> list[str]:
    """What a slave tuning's search says of its optimum (the ``slave`` entry of
    :func:`~servotune.tune.workflow.tuning_summary`): the constraints it sits on and the search
    bounds it reached, each a lower-case clause without a full stop (none: ``[]``)."""
    notes = []
    if slave.get("binding"):
        notes.append(f"constraints the optimum sits on: {', '.join(slave['binding'])}")
    if slave.get("at_bounds"):
        notes.append(f"search bounds reached (widen them): {', '.join(slave['at_bounds'])}")
    return notes
