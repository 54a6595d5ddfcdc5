"""Fuzzy rule bases, Mamdani inference and query tables for the slave's fuzzy-PID
(docs/systems.md#pc-dual-servo-synchronisation).

Each tick the runtime quantises the error ``e`` [counts] and its change ``ec`` [counts/tick] to
integer levels ``E, EC`` in ``−n…n`` (the scaling factors ``Ke``, ``Kec`` belong to the law,
:mod:`servotune.laws.fuzzy_pid`) and reads ΔKp, ΔKi, ΔKd and ΔK1 from four **query tables**
(row ``E`` from ``−n`` to ``n``, column ``EC`` from ``−n`` to ``n``, shape ``(2n+1, 2n+1)``).
This module evaluates a fuzzy system offline into those tables, in normalised output units
(universe ``[−1, 1]``); scaling to gain units and quantising to int16 happen in the law.

The fuzzy system
----------------
- Seven linguistic sets :data:`SETS` ``NB NM NS ZO PS PM PB`` on every universe.
- **Inputs** ``E`` and ``EC`` live on the level universe ``[−n, n]``; the set peaks are evenly
  spaced, ``c_k = (k − 3)·n/3`` (``−n, −2n/3, …, n``), one *spacing* being ``n/3`` levels.
  Triangular sets (default) reach 0 at the neighbouring peaks, so they form a partition of unity;
  gaussian sets ``μ = 2^(−4 s²)``, ``s`` the distance to the peak in spacings (σ = spacing /
  (2√(2 ln 2)): neighbours cross at 0.5, a set is 1/16 at its neighbours' peaks). NB and PB are
  shoulders: 1 at and beyond ``∓n``, so ``|E| = n`` is fully NB/PB.
- **Outputs** live on ``[−1, 1]`` with peaks ``p_k = (k − 3)/3`` (``−1, −2/3, …, 1``). Every
  output set is a full symmetric triangle of half-width 1/3, including NB and PB, which extend to
  ``∓4/3`` on the extended output universe ``[−4/3, 4/3]``. A single fired set (at any firing
  level) is a symmetric clipped triangle, so its centroid is exactly its peak and an all-PB rule
  table gives exactly 1.0. PB's part beyond 1 is never larger than its mirror image below 1, so
  every centroid lies within ``[−1, 1]``.
- **Inference**: Mamdani min–max. A rule fires at ``min(μ_E, μ_EC)``; implication clips its
  output set at that level (min); aggregation takes the max over rules.
- **Defuzzification** (``defuzz``):

  ``"centroid"`` (default)
      Centroid of the aggregated set sampled on the output grid ``y_j = j/(3M)``,
      ``j = −4M…4M`` with ``M =`` :data:`GRID_STEPS` ``= 100`` points per set spacing
      (step 1/300 ≈ 0.0033, 801 points). Every set boundary and peak is a grid point, and the
      grid sum of a piecewise-linear membership that vanishes at both ends equals its trapezoid
      integral; the centroid agrees with the continuous one within 1e-4 (tested; the
      residue comes from kinks of the aggregate between grid points).
  ``"weighted_average"``
      ``Σ w_r·p_r / Σ w_r`` over the 49 rules, ``w_r`` a rule's firing strength and ``p_r`` the
      peak of its output set (no max aggregation).

Exactness (why the tables are exactly symmetric)
------------------------------------------------
The default rule base must keep ``ΔK(−E, −EC) = ΔK(E, EC)`` *bit for bit*, also after scaling
and quantisation. Every step here is either exact or a sign-symmetric, correctly rounded
operation on bit-identical operands:

- input memberships are computed from ``s = (3x − (k − 3)·n)/n`` (``(k − 3)·n`` is an exact
  integer, negation commutes with IEEE subtraction and division), so
  ``μ_k(−x) == μ_{6−k}(x)`` bit for bit; min and max are exact;
- the clip level of each output set is a max over the rules that conclude it (order-free);
- the sampled aggregate is rounded to multiples of ``2^−``:data:`MEMBERSHIP_BITS` (``2^−44``,
  below 1e-13) and summed in int64: every sum is exact (``Σ|j|·q_j ≤ 400·401·2^44 < 2^62``), so
  the result is independent of summation order; for the weighted average the firing strengths
  are rounded to multiples of ``2^−52`` (``Σ|k − 3|·q_r ≤ 49·3·2^52 < 2^60``);
- the centroid index ratio ``Σ j·q_j / (3M · Σ q_j)`` is rounded once (Python's integer true
  division is correctly rounded), so mirrored aggregates give exactly negated results and a
  single fired set gives exactly ``fl((k − 3)/3)``; the weighted average is computed the same way.

Hence a rule table invariant under 180° rotation gives a bit-exactly direction-independent query
table, one whose rotation is its negation (NB↔PB) gives an exactly odd table, and both survive
``round_half_away(scale · table · 2^f)`` because that rounding is sign-symmetric and monotone.

Examples
--------
>>> qt = query_tables(DEFAULT_RULES)
>>> qt.kp.shape
(13, 13)
>>> direction_independent(qt.kp), float(qt.kp[6, 6])
(True, 0.0)
>>> evaluate(CLASSIC_RULES.kp, 6, -2)  # E = 6 is PB, EC = −2 the NS peak: the rule says NM
-0.6666666666666666
"""

from servotune.fuzzy.inference import (
    DEFUZZ_METHODS,
    GRID_STEPS,
    MEMBERSHIP_BITS,
    SHAPES,
    QueryTables,
    evaluate,
    input_membership,
    input_peaks,
    output_grid,
    output_membership,
    output_peaks,
    query_table,
    query_tables,
)
from servotune.fuzzy.properties import (
    check_default_properties,
    direction_independent,
    nondecreasing_in_abs_e,
    nonincreasing_in_abs_e,
)
from servotune.fuzzy.rules import (
    CLASSIC_RULES,
    DEFAULT_RULES,
    SETS,
    RuleBase,
    RuleTable,
    format_rules,
    parse_rules,
)
from servotune.laws.fuzzy_pid import TABLE_NAMES

__all__ = [
    "CLASSIC_RULES",
    "DEFAULT_RULES",
    "DEFUZZ_METHODS",
    "GRID_STEPS",
    "MEMBERSHIP_BITS",
    "SETS",
    "SHAPES",
    "TABLE_NAMES",
    "QueryTables",
    "RuleBase",
    "RuleTable",
    "check_default_properties",
    "direction_independent",
    "evaluate",
    "format_rules",
    "input_membership",
    "input_peaks",
    "nondecreasing_in_abs_e",
    "nonincreasing_in_abs_e",
    "output_grid",
    "output_membership",
    "output_peaks",
    "parse_rules",
    "query_table",
    "query_tables",
]
