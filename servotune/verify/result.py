"""What verification found: a row per limit, the checks, the :class:`Verification`, and its
pass/fail table for the terminal (:func:`format_table`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from scipy.stats import beta

from servotune.io.files import json_float
from servotune.validate import show_number, show_value
from servotune.verify.spec import Spec
from servotune.verify.variants import Variant

__all__ = [
    "Check",
    "MonteCarloSummary",
    "Row",
    "Sensitivity",
    "Verification",
    "WorstVariant",
    "clopper_pearson",
]


# --- results -------------------------------------------------------------------------------


def clopper_pearson(k: int, n: int, alpha: float = 0.05) -> tuple[float, float]:
    """The exact (Clopper–Pearson) ``1 − alpha`` interval of a probability from ``k`` successes
    in ``n`` trials, ``n >= 1``: it holds the true probability at least ``1 − alpha`` of the
    time.

    >>> [round(x, 4) for x in clopper_pearson(64, 64)]
    [0.944, 1.0]
    """
    a = alpha / 2.0
    lo = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1.0 - a, k + 1, n - k))
    return lo, hi


@dataclass(frozen=True, slots=True, kw_only=True)
class Row:
    """One limit of one scenario on one axis, judged over every variant.

    Attributes
    ----------
    scenario : str
    quantity : str
        What is measured (``overshoot_pct``, ``max_sync_error_counts``, …, ``fault_runs``).
    axis : str
    unit : str
    limit : float
        Upper bound [unit].
    worst : float
        Largest value over the variants [unit] (``inf``: never settled).
    variant : str
        Label of the variant giving ``worst``.
    """

    scenario: str
    quantity: str
    axis: str
    unit: str
    limit: float
    worst: float
    variant: str

    @property
    def passed(self) -> bool:
        """``worst <= limit`` (a NaN fails)."""
        return bool(self.worst <= self.limit)

    @property
    def margin(self) -> float:
        """``limit − worst`` [unit]; negative when violated."""
        return self.limit - self.worst

    @property
    def relative_margin(self) -> float | None:
        """``margin / limit`` [1]; None for a zero limit."""
        return self.margin / self.limit if self.limit > 0 else None

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (non-finite numbers as None)."""
        rel = self.relative_margin
        return {
            "axis": self.axis,
            "limit": float(self.limit),
            "margin": json_float(self.margin),
            "passed": self.passed,
            "quantity": self.quantity,
            "relative_margin": None if rel is None else json_float(rel),
            "scenario": self.scenario,
            "unit": self.unit,
            "variant": self.variant,
            "worst": json_float(self.worst),
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class Check:
    """A verification check that is not a scenario limit.

    Attributes
    ----------
    name : str
        ``counter_unwrap``, ``counter_input_frequency``, ``timer_period`` or ``overflow``.
    passed : bool
    value : float
        The checked quantity [unit].
    limit : float or None
        Its bound [unit]; None if only reported.
    unit : str
    detail : str
        One line for people.
    facts : mapping
        The numbers behind it.
    """

    name: str
    passed: bool
    value: float
    limit: float | None
    unit: str
    detail: str
    facts: Mapping[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict."""
        return {
            "detail": self.detail,
            "facts": dict(self.facts),
            "limit": None if self.limit is None else json_float(self.limit),
            "name": self.name,
            "passed": self.passed,
            "unit": self.unit,
            "value": json_float(self.value),
        }


def _plain(x: Any) -> Any:
    """JSON-ready copy of a result field: floats through :func:`json_float`, mappings with
    sorted keys, tuples as lists."""
    if isinstance(x, float):
        return json_float(x)
    if isinstance(x, Mapping):
        return {str(k): _plain(x[k]) for k in sorted(x)}
    if isinstance(x, tuple | list):
        return [_plain(v) for v in x]
    return x


@dataclass(frozen=True, slots=True, kw_only=True)
class WorstVariant:
    """One of the Monte-Carlo plant sets with the least margin.

    Attributes
    ----------
    label : str
        ``"mc<i>"`` (1-based draw index; :func:`~servotune.verify.plant_variants`).
    relative_margin : float
        Its least ``(limit − value) / limit`` over every limit of every scenario [1]; negative:
        the figure below fails; ``-inf``: a fault latched, a value was NaN or a zero limit was
        exceeded.
    scenario, quantity, axis, unit : str
        The figure giving that margin (``fault_runs`` for a latched fault).
    value : float
        Its value [unit] (1 for a fault).
    limit : float
        Its limit [unit].
    parameters : mapping of str to float
        The drawn plant parameters (``"<axis>.<parameter>"``, units in the names).
    """

    label: str
    relative_margin: float
    scenario: str
    quantity: str
    axis: str
    unit: str
    value: float
    limit: float
    parameters: Mapping[str, float] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        """Whether this plant set keeps every limit (its least margin is not negative)."""
        return bool(self.relative_margin >= 0.0)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (non-finite numbers as None)."""
        return {f: _plain(getattr(self, f)) for f in self.__slots__} | {"passed": self.passed}


@dataclass(frozen=True, slots=True, kw_only=True)
class Sensitivity:
    """How one drawn plant parameter relates to failures (a row of the sensitivity table).

    Read it as: plant sets whose ``parameter`` lies in its lowest quarter of the draws
    (``<= low_edge``) fail ``low_fail_pct`` % of the time, those in its highest quarter
    (``>= high_edge``) ``high_fail_pct`` %, against ``fail_pct`` % over all draws; a parameter
    that drives failures shows a large difference between the two. Quarters are coarse (a
    failure window in a parameter's last percent, or three failures that all fall in one quarter
    by chance, look alike there), so ``fail_p_value`` tests what they suggest: the two-sided
    p-value of the Wilcoxon–Mann–Whitney rank-sum test between the failing and the passing plant
    sets' values of the parameter, and ``beyond_chance`` says whether it stays below 5 % after
    Bonferroni's correction for the number of parameters tested. ``rank_correlation`` is
    Spearman's ρ between the parameter and each plant set's least relative margin: negative
    when a larger value leaves less margin; it ranks the parameters even when nothing fails.

    Attributes
    ----------
    parameter : str
        ``"<axis>.<parameter>"`` (unit in the name).
    low_edge, high_edge : float
        The parameter's lower and upper quartile over the draws [its unit].
    low_fail_pct, high_fail_pct, fail_pct : float
        Failure rates [%]: in the lowest quarter, in the highest quarter, overall.
    rank_correlation : float
        Spearman's ρ with the least relative margin [1]; NaN when either does not vary.
    fail_p_value : float
        The rank-sum test's p-value, failing against passing plant sets [1]; NaN when none or
        every plant set fails.
    beyond_chance : bool
        ``fail_p_value < 0.05 / (parameters tested)``.
    """

    parameter: str
    low_edge: float
    high_edge: float
    low_fail_pct: float
    high_fail_pct: float
    fail_pct: float
    rank_correlation: float
    fail_p_value: float = math.nan
    beyond_chance: bool = False

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (non-finite numbers as None)."""
        return {f: _plain(getattr(self, f)) for f in self.__slots__}


@dataclass(frozen=True, slots=True, kw_only=True)
class MonteCarloSummary:
    """What the Monte-Carlo plant sets of a verification show, beyond each limit's worst value.

    Attributes
    ----------
    count : int
        Monte-Carlo plant sets run (the nominal plants not counted).
    passed : int
        Of them, those that keep every limit of every scenario (no fault).
    ci95 : tuple of float
        Exact (Clopper–Pearson) 95 % interval of the pass probability [1].
    distribution : str
        Where the plants were drawn from (``"spec spread"``; a fleet's measured spread names
        itself).
    worst : tuple of WorstVariant
        The plant sets with the least margin, least first (ties: lower draw index first).
    sensitivity : tuple of Sensitivity
        One row per drawn parameter that varies, the one most tied to failures first
        (:func:`~servotune.verify.montecarlo.sensitivity_table`: smallest rank-sum p-value,
        then largest difference of the quartiles' failure rates, then largest ``|ρ|``).
    """

    count: int
    passed: int
    ci95: tuple[float, float]
    distribution: str
    worst: tuple[WorstVariant, ...] = ()
    sensitivity: tuple[Sensitivity, ...] = ()

    @property
    def pass_fraction(self) -> float:
        """``passed / count`` [1] (NaN without plant sets)."""
        return self.passed / self.count if self.count else math.nan

    def to_dict(self) -> dict[str, Any]:
        """Plain dict, JSON-ready."""
        return {
            "ci95": [json_float(x) for x in self.ci95],
            "count": self.count,
            "distribution": self.distribution,
            "interval": "Clopper-Pearson",
            "pass_fraction": json_float(self.pass_fraction),
            "passed": self.passed,
            "sensitivity": [x.to_dict() for x in self.sensitivity],
            "worst": [x.to_dict() for x in self.worst],
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class Verification:
    """What :func:`verify` found.

    Attributes
    ----------
    spec : Spec
    rig_name : str
    axis_names : tuple of str
    seed : int
        The seed used (variants and noise).
    variants : tuple of Variant
        The nominal plants first, then every Monte-Carlo plant set up to
        :data:`~servotune.verify.run.LISTED_VARIANTS` of them; beyond that only those named by
        a row or by ``montecarlo.worst`` (each is redrawn from the seed by its label).
    rows : tuple of Row
        Every limit of every scenario (empty if the runs were skipped, see ``checks``).
    checks : tuple of Check
    variant_passed : tuple of bool
        Per plant set (index 0 the nominal plants, ``i`` the draw ``mc<i>``), whether it kept
        every limit of every scenario.
    montecarlo : MonteCarloSummary or None
        The worst plant sets and the sensitivity table (None without Monte-Carlo plant sets or
        runs).
    """

    spec: Spec
    rig_name: str
    axis_names: tuple[str, ...]
    seed: int
    variants: tuple[Variant, ...]
    rows: tuple[Row, ...]
    checks: tuple[Check, ...]
    variant_passed: tuple[bool, ...] = ()
    montecarlo: MonteCarloSummary | None = None

    @property
    def plant_sets(self) -> int:
        """Plant sets run: the nominal plants and every Monte-Carlo draw."""
        return max(len(self.variant_passed), len(self.variants))

    @property
    def pass_fraction(self) -> tuple[int, int, float, float, float]:
        """Over the Monte-Carlo variants (the nominal plants excluded): ``(passed, count,
        fraction, low, high)``, ``low``–``high`` the exact (Clopper–Pearson) 95 % interval of
        the probability that a plant drawn from the spec's spread keeps every limit; NaN
        fraction and (0, 1) without variants."""
        mc = list(self.variant_passed[1:])
        n, k = len(mc), int(sum(mc))
        if n == 0:
            return 0, 0, math.nan, 0.0, 1.0
        return k, n, k / n, *clopper_pearson(k, n)

    @property
    def passed(self) -> bool:
        """Every limit and every check holds (and the runs were made)."""
        return (
            bool(self.rows)
            and all(r.passed for r in self.rows)
            and all(c.passed for c in self.checks)
        )

    @property
    def failures(self) -> list[str]:
        """One line per violated limit or failed check."""
        out = [
            f"{r.scenario}: {r.quantity} of {r.axis} = {show_number(r.worst)} {r.unit} > limit "
            f"{show_number(r.limit)} {r.unit} (variant {r.variant})"
            for r in self.rows
            if not r.passed
        ]
        out += [f"check {c.name}: {c.detail}" for c in self.checks if not c.passed]
        if not self.rows:
            out.append("closed-loop runs skipped (see the overflow check)")
        return out

    def row(self, scenario: str, quantity: str, axis: str) -> Row:
        """The row of one scenario, quantity and axis."""
        for r in self.rows:
            if (r.scenario, r.quantity, r.axis) == (scenario, quantity, axis):
                return r
        raise KeyError(f"no row {scenario}/{quantity}/{axis}")

    def check(self, name: str) -> Check:
        """The check called ``name``."""
        for c in self.checks:
            if c.name == name:
                return c
        raise KeyError(f"no check {show_value(name)}")

    def _montecarlo_dict(self) -> dict[str, Any]:
        if self.montecarlo is not None:
            return self.montecarlo.to_dict()
        k, n, frac, lo, hi = self.pass_fraction
        return {
            "ci95": [json_float(lo), json_float(hi)],
            "count": n,
            "interval": "Clopper-Pearson",
            "pass_fraction": json_float(frac),
            "passed": k,
        }

    def to_dict(self) -> dict[str, Any]:
        """Plain dict, JSON-ready (``json.dumps(..., sort_keys=True)``)."""
        return {
            "checks": [c.to_dict() for c in self.checks],
            "failures": self.failures,
            "montecarlo": self._montecarlo_dict(),
            "passed": self.passed,
            "rig": self.rig_name,
            "rows": [r.to_dict() for r in self.rows],
            "seed": self.seed,
            "spec": self.spec.to_dict(),
            "variants": [v.to_dict(self.axis_names) for v in self.variants],
        }


# --- presenting ----------------------------------------------------------------------------
