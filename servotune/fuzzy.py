"""Fuzzy rule bases, Mamdani inference and query tables for the slave's fuzzy-PID (seed 000).

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

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from servotune.errors import SpecError
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

SETS = ("NB", "NM", "NS", "ZO", "PS", "PM", "PB")
"""The seven linguistic sets, from negative big to positive big."""

SHAPES = ("triangular", "gaussian")
"""Input membership shapes."""

DEFUZZ_METHODS = ("centroid", "weighted_average")
"""Defuzzification methods."""

GRID_STEPS = 100
"""Centroid grid points per output set spacing (1/3): grid step 1/300 on ``[−4/3, 4/3]``."""

MEMBERSHIP_BITS = 44
"""The sampled aggregate (centroid) is rounded to multiples of ``2^−44`` for exact int64 sums."""

_WEIGHT_BITS = 52  # firing strengths (weighted average) are rounded to multiples of 2^−52

RuleTable = tuple[tuple[str, ...], ...]
"""A 7×7 rule table: rows ``e`` NB…PB, columns ``ec`` NB…PB, entries set names."""

_N_SETS = len(SETS)
_INDEX = {name: k for k, name in enumerate(SETS)}
_J = np.arange(-4 * GRID_STEPS, 4 * GRID_STEPS + 1, dtype=np.int64)  # output grid indices
_CHUNK = 256  # points per vectorised block (bounds memory: 256 × 7 × 801 floats)


def _output_samples() -> np.ndarray:
    # t_k(j) = max(0, 1 − |j − (k − 3)M| / M): |·| an exact integer, one correctly rounded division
    peaks = (np.arange(_N_SETS, dtype=np.int64) - 3) * GRID_STEPS
    dist = np.abs(_J[None, :] - peaks[:, None])
    t = np.maximum(0.0, 1.0 - dist / GRID_STEPS)
    t.setflags(write=False)
    return t


_T = _output_samples()  # (7, 801) output set memberships on the grid

# --- validation -------------------------------------------------------------------------------


def _check_n(n: Any) -> int:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise SpecError(f"n must be an integer >= 1 [levels], got {n!r}")
    return int(n)


def _check_shape(shape: Any) -> str:
    if shape not in SHAPES:
        raise SpecError(f"shape must be one of {', '.join(SHAPES)}, got {shape!r}")
    return str(shape)


def _check_defuzz(defuzz: Any) -> str:
    if defuzz not in DEFUZZ_METHODS:
        raise SpecError(f"defuzz must be one of {', '.join(DEFUZZ_METHODS)}, got {defuzz!r}")
    return str(defuzz)


def _finite_array(name: str, x: ArrayLike, unit: str) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise SpecError(f"{name} must be real numbers [{unit}], got {x!r}") from exc
    bad = a[~np.isfinite(a)]
    if bad.size:
        raise SpecError(f"{name} must be finite [{unit}], got {bad.flat[0]!r}")
    return a


def _rule_table(x: Any, name: str) -> RuleTable:
    """Normalise a rule table (compact text or 7×7 names) to a tuple of tuples, validated."""
    if isinstance(x, str):
        rows: list[Any] = [r for r in x.replace("\n", "|").split("|") if r.strip()]
    elif isinstance(x, Sequence | np.ndarray):
        rows = list(x)
    else:
        raise SpecError(
            f"{name} must be a 7×7 rule table (text 'PB PB … | …' or rows of set names), "
            f"got {type(x).__name__}"
        )
    if len(rows) != _N_SETS:
        raise SpecError(f"{name} must have 7 rows (e NB…PB), got {len(rows)}")
    out = []
    for i, row in enumerate(rows):
        if not isinstance(row, str | Sequence | np.ndarray):
            raise SpecError(f"{name} row {i} (e = {SETS[i]}) must be set names, got {row!r}")
        cells = row.split() if isinstance(row, str) else list(row)
        if len(cells) != _N_SETS:
            raise SpecError(
                f"{name} row {i} (e = {SETS[i]}) must have 7 entries (ec NB…PB), got {len(cells)}"
            )
        for j, cell in enumerate(cells):
            if not isinstance(cell, str) or cell not in _INDEX:
                raise SpecError(
                    f"{name}[{i}][{j}] (e = {SETS[i]}, ec = {SETS[j]}) must be one of "
                    f"{' '.join(SETS)}, got {cell!r}"
                )
        out.append(tuple(str(c) for c in cells))
    return tuple(out)


# --- rule tables and rule bases ---------------------------------------------------------------


def parse_rules(text: str, *, name: str = "rules") -> RuleTable:
    """Parse a rule table from its compact text form.

    Parameters
    ----------
    text : str
        Seven rows (``e`` NB…PB) separated by ``|`` (or newlines), each seven set names
        (``ec`` NB…PB) separated by spaces, e.g. ``"PB PB PM PM PS ZO ZO | PB PB …"``.
    name : str
        Field name used in error messages.

    Returns
    -------
    RuleTable
        Tuple of 7 rows of 7 set names.

    Raises
    ------
    SpecError
        If the text is not a 7×7 table of names from :data:`SETS`.

    Examples
    --------
    >>> t = parse_rules(" | ".join(["ZO ZO ZO ZO ZO ZO ZO"] * 6 + ["PB PB PB PB PB PB PB"]))
    >>> t[6][0], t[0][6]
    ('PB', 'ZO')
    """
    if not isinstance(text, str):
        raise SpecError(f"{name} must be a text rule table, got {type(text).__name__}")
    return _rule_table(text, name)


def format_rules(table: RuleTable | str) -> str:
    """The compact text form of a rule table (rows joined by ``" | "``).

    Parameters
    ----------
    table : RuleTable or str
        A valid rule table.

    Returns
    -------
    str
        ``"r0c0 r0c1 … | r1c0 …"``; :func:`parse_rules` reads it back.
    """
    return " | ".join(" ".join(row) for row in _rule_table(table, "table"))


def _indices(table: RuleTable) -> np.ndarray:
    return np.array([[_INDEX[c] for c in row] for row in table], dtype=np.int64)


_ALL_ZO = tuple(("ZO",) * _N_SETS for _ in range(_N_SETS))


@dataclass(frozen=True, slots=True, kw_only=True)
class RuleBase:
    """The four rule tables of the fuzzy self-tuning PID + feedforward.

    Each table has rows ``e`` NB…PB and columns ``ec`` NB…PB; an entry is the output set of
    ``ΔK`` for that pair. A table may be given as compact text (:func:`parse_rules`) or as rows
    of set names; it is stored as a :data:`RuleTable` (tuple of tuples).

    Parameters
    ----------
    kp : RuleTable or str
        ΔKp rules (normalised units; the law scales them to [codes/count]).
    ki : RuleTable or str
        ΔKi rules.
    kd : RuleTable or str
        ΔKd rules.
    k1 : RuleTable or str
        ΔK1 rules (feedforward differential coefficient); default all ZO.
    name : str
        A label carried into the query tables and exports.

    Raises
    ------
    SpecError
        If a table is not 7×7 or holds a name not in :data:`SETS`.
    """

    kp: RuleTable | str
    ki: RuleTable | str
    kd: RuleTable | str
    k1: RuleTable | str = _ALL_ZO
    name: str = "custom"

    def __post_init__(self) -> None:
        for t in TABLE_NAMES:
            object.__setattr__(self, t, _rule_table(getattr(self, t), t))
        if not isinstance(self.name, str) or not self.name:
            raise SpecError(f"name must be a non-empty string, got {self.name!r}")

    def table(self, which: str) -> RuleTable:
        """The rule table ``which`` (one of :data:`TABLE_NAMES`)."""
        if which not in TABLE_NAMES:
            raise SpecError(f"table must be one of {', '.join(TABLE_NAMES)}, got {which!r}")
        return _rule_table(getattr(self, which), which)

    def indices(self, which: str) -> np.ndarray:
        """Rule table ``which`` as set indices 0 (NB) … 6 (PB), int array of shape (7, 7)."""
        return _indices(self.table(which))

    def to_dict(self) -> dict[str, str]:
        """Plain dict: the name and each table in compact text form (``RuleBase(**d)`` reads it)."""
        out = {t: format_rules(getattr(self, t)) for t in TABLE_NAMES}
        out["name"] = self.name
        return dict(sorted(out.items()))


CLASSIC_RULES = RuleBase(
    name="classic",
    kp=(
        "PB PB PM PM PS ZO ZO | PB PB PM PS PS ZO NS | PM PM PM PS ZO NS NS | "
        "PM PM PS ZO NS NM NM | PS PS ZO NS NS NM NM | PS ZO NS NM NM NM NB | "
        "ZO ZO NM NM NM NB NB"
    ),
    ki=(
        "NB NB NM NM NS ZO ZO | NB NB NM NS NS ZO ZO | NB NM NS NS ZO PS PS | "
        "NM NM NS ZO PS PM PM | NM NS ZO PS PS PM PB | ZO ZO PS PS PM PB PB | "
        "ZO ZO PS PM PM PB PB"
    ),
    kd=(
        "PS NS NB NB NB NM PS | PS NS NB NM NM NS ZO | ZO NS NM NM NS NS ZO | "
        "ZO NS NS NS NS NS ZO | ZO ZO ZO ZO ZO ZO ZO | PB NS PS PS PS PS PB | "
        "PB PM PM PM PS PS PB"
    ),
)
"""The classic textbook fuzzy self-tuning PID rules (ΔKp, ΔKi, ΔKd; ΔK1 all ZO).

These tables are not direction-independent: they assume a step that starts with a large
positive error, and give different gains to the mirrored state ``(−e, −ec)``.
"""

DEFAULT_RULES = RuleBase(
    name="default",
    # ΔKp: |e| large → more Kp (PB at ec = 0); e, ec same sign (error growing) → push harder;
    # opposite sign (converging) → back off, the faster the convergence the more.
    kp=(
        "PB PB PB PB PM PS ZO | PB PB PM PM PS ZO NS | PM PM PS PS ZO NS NS | "
        "PS PS ZO ZO ZO PS PS | NS NS ZO PS PS PM PM | NS ZO PS PM PM PB PB | "
        "ZO PS PM PB PB PB PB"
    ),
    # ΔKi: |e| large → least Ki (windup, overshoot); near zero → most Ki (the steady lag);
    # converging fast → less Ki (the integrator would carry the axis past the target).
    ki=(
        "NB NB NB NB NB NB NB | NM NM NS NS NM NM NB | PS PS PM PM PS ZO NS | "
        "ZO PS PM PB PM PS ZO | NS ZO PS PM PM PS PS | NB NM NM NS NS NM NM | "
        "NB NB NB NB NB NB NB"
    ),
    # ΔKd: converging (opposite signs) → more Kd to brake, more the faster; growing with a large
    # |e| → less Kd (the P term acts, no derivative kick); near zero → a little more Kd when ec is
    # large (damps the crossing), none when the axis is at rest (no noise amplification).
    kd=(
        "NS NS NM NM ZO PS PM | ZO ZO NS NS PS PM PB | PS PS ZO ZO PS PM PM | "
        "PM PS PS ZO PS PS PM | PM PM PS ZO ZO PS PS | PB PM PS NS NS ZO ZO | "
        "PM PS ZO NM NM NS NS"
    ),
)
"""servotune's rule base for position servos (ΔK1 all ZO).

**Direction-independent**: every table is invariant under 180° rotation,
``rule[6−i][6−j] == rule[i][j]``, so ``ΔK(−E, −EC) = ΔK(E, EC)``: a servo that tracks in both
directions sees the same gains either way. Each entry depends only on ``|e|``, ``|ec|`` and
whether the error is growing (``e``, ``ec`` of the same sign) or converging (opposite signs).

ΔKp
    Not decreasing with ``|E|`` at ``EC = 0`` (ZO, PS, PM, PB): a large error gets a stiff loop
    and a fast response. A growing error gets one step more (push harder); a converging error
    gets less, down to NS when it converges fast from a small or medium error, to brake before
    the target (no overshoot).
ΔKi
    Not increasing with ``|E|`` at ``EC = 0`` (PB, PM, NS, NB): a large error is the P term's
    job, and integrating it winds up and overshoots; near zero the integrator removes the steady
    lag (friction, drift, what the feedforward misses). It is cut further while the error
    converges fast, since the stored integral would carry the axis past the target.
ΔKd
    Raised when converging (opposite signs), the more the faster: the derivative brakes the
    approach. Lowered for a large growing error (the P term acts; no derivative kick at a
    reference step). At ``e ≈ 0`` a little more Kd when ``|ec|`` is large damps the crossing,
    none at rest so that encoder quantisation noise is not amplified.
ΔK1
    All ZO: ``K1`` stays at its base, the ideal velocity feedforward, over the whole table.
"""


# --- membership functions ---------------------------------------------------------------------


def input_peaks(n: int = 6) -> np.ndarray:
    """Peaks of the input sets NB…PB on the level universe: ``(k − 3)·n/3`` [levels].

    Parameters
    ----------
    n : int
        Largest level (>= 1).

    Returns
    -------
    ndarray, shape (7,)

    Examples
    --------
    >>> input_peaks(6)
    array([-6., -4., -2.,  0.,  2.,  4.,  6.])
    """
    n = _check_n(n)
    return np.array([(k - 3) * n / 3 for k in range(_N_SETS)])


def output_peaks() -> np.ndarray:
    """Peaks of the output sets NB…PB: ``(k − 3)/3`` (−1, −2/3, …, 1) [normalised]."""
    return np.array([(k - 3) / 3 for k in range(_N_SETS)])


def _input_mu(x: np.ndarray, n: int, shape: str) -> np.ndarray:
    # signed distance to each peak in set spacings; (k − 3)·n is exact, negation symmetric
    offsets = (np.arange(_N_SETS, dtype=np.int64) - 3) * n
    s = (3.0 * x[..., None] - offsets) / n
    d = np.abs(s)
    d[..., 0] = np.maximum(s[..., 0], 0.0)  # NB shoulder: 1 at and below −n
    d[..., -1] = np.maximum(-s[..., -1], 0.0)  # PB shoulder: 1 at and above n
    if shape == "triangular":
        return np.maximum(0.0, 1.0 - d)
    return np.exp2(-4.0 * d * d)


def input_membership(x: ArrayLike, *, n: int = 6, shape: str = "triangular") -> np.ndarray:
    """Memberships of input levels in the seven sets.

    Parameters
    ----------
    x : float or array_like
        Levels ``E`` or ``EC`` [levels]; any real value (beyond ``±n`` the shoulders hold 1).
    n : int
        Largest level (>= 1).
    shape : {"triangular", "gaussian"}
        Set shape (module docstring).

    Returns
    -------
    ndarray, shape ``x.shape + (7,)``
        ``μ_k(x)`` for k = NB…PB, in ``[0, 1]``.

    Raises
    ------
    SpecError
        If ``n``, ``shape`` or ``x`` is invalid.

    Examples
    --------
    >>> input_membership([-6, 1], n=6)
    array([[1. , 0. , 0. , 0. , 0. , 0. , 0. ],
           [0. , 0. , 0. , 0.5, 0.5, 0. , 0. ]])
    """
    n = _check_n(n)
    shape = _check_shape(shape)
    return _input_mu(_finite_array("x", x, "levels"), n, shape)


def output_grid() -> np.ndarray:
    """The centroid grid ``y_j = j/(3M)``, ``j = −4M…4M``, ``M =`` :data:`GRID_STEPS`.

    Returns
    -------
    ndarray, shape (8M + 1,)
        Grid points on the extended output universe ``[−4/3, 4/3]`` [normalised].
    """
    return _J / (3 * GRID_STEPS)


def output_membership(y: ArrayLike) -> np.ndarray:
    """Memberships of output values in the seven output sets.

    Every output set is a full triangle of half-width 1/3 around its peak ``(k − 3)/3``; NB and
    PB extend to ``∓4/3`` (no shoulders), so each is symmetric about its peak.

    Parameters
    ----------
    y : float or array_like
        Output values [normalised].

    Returns
    -------
    ndarray, shape ``y.shape + (7,)``
    """
    y = _finite_array("y", y, "normalised")
    return np.maximum(0.0, 1.0 - np.abs(3.0 * y[..., None] - (np.arange(_N_SETS) - 3)))


# --- inference --------------------------------------------------------------------------------


def _to_units(mu: np.ndarray, bits: int) -> np.ndarray:
    """Memberships in [0, 1] as int64 multiples of 2^−bits (rounded to nearest)."""
    return np.rint(np.ldexp(mu, bits)).astype(np.int64)


def _ratio(num: np.ndarray, den: np.ndarray, scale: int) -> np.ndarray:
    # exact integers; Python's int / int is correctly rounded (den > 0: the strongest rule fires
    # at >= 0.5 because each input has a set at >= 0.5 and every cell of a rule table has a rule)
    return np.array([int(a) / (scale * int(b)) for a, b in zip(num, den, strict=True)])


def _infer(idx: np.ndarray, mu_e: np.ndarray, mu_ec: np.ndarray, defuzz: str) -> np.ndarray:
    """Mamdani min–max inference for one rule table at P points (memberships (P, 7))."""
    out = np.empty(mu_e.shape[0])
    onehot = idx[None, :, :] == np.arange(_N_SETS)[:, None, None]  # (7 sets, 7, 7)
    for start in range(0, mu_e.shape[0], _CHUNK):
        sl = slice(start, start + _CHUNK)
        w = np.minimum(mu_e[sl, :, None], mu_ec[sl, None, :])  # rule firing, (P, 7 e, 7 ec)
        if defuzz == "weighted_average":
            q = _to_units(w.reshape(w.shape[0], -1), _WEIGHT_BITS)
            out[sl] = _ratio(q @ (idx.ravel() - 3), q.sum(axis=1), 3)
            continue
        clip = np.max(np.where(onehot[None], w[:, None], 0.0), axis=(2, 3))  # (P, 7 sets)
        agg = np.max(np.minimum(clip[:, :, None], _T[None]), axis=1)  # (P, grid)
        q = _to_units(agg, MEMBERSHIP_BITS)
        out[sl] = _ratio(q @ _J, q.sum(axis=1), 3 * GRID_STEPS)
    return out


def evaluate(
    rules: RuleBase | RuleTable | str,
    e_level: ArrayLike,
    ec_level: ArrayLike,
    *,
    n: int = 6,
    shape: str = "triangular",
    defuzz: str = "centroid",
) -> float | np.ndarray | dict[str, float | np.ndarray]:
    """Evaluate the fuzzy system directly at real levels ``(E, EC)``.

    Parameters
    ----------
    rules : RuleBase, RuleTable or str
        One rule table (rows ``e``, columns ``ec``), or a rule base for all four tables.
    e_level : float or array_like
        Error level ``E`` [levels]; beyond ``±n`` it counts as ``±n``.
    ec_level : float or array_like
        Error-change level ``EC`` [levels]; broadcast against ``e_level``.
    n : int
        Largest level (>= 1), the input universe ``[−n, n]``.
    shape : {"triangular", "gaussian"}
        Input set shape.
    defuzz : {"centroid", "weighted_average"}
        Defuzzification method.

    Returns
    -------
    float, ndarray or dict
        The output in normalised units ``[−1, 1]``: a float for scalar levels, else an array of
        the broadcast shape; for a :class:`RuleBase`, a dict ``{"kp", "ki", "kd", "k1"}`` of
        those.

    Raises
    ------
    SpecError
        If an argument is invalid.

    Examples
    --------
    >>> evaluate(DEFAULT_RULES, 0, 0)["ki"]  # ZO, ZO: the rule says PB
    1.0
    """
    n = _check_n(n)
    shape = _check_shape(shape)
    defuzz = _check_defuzz(defuzz)
    e, ec = np.broadcast_arrays(
        _finite_array("e_level", e_level, "levels"), _finite_array("ec_level", ec_level, "levels")
    )
    mu_e = _input_mu(e.ravel(), n, shape)
    mu_ec = _input_mu(ec.ravel(), n, shape)

    def one(idx: np.ndarray) -> float | np.ndarray:
        y = _infer(idx, mu_e, mu_ec, defuzz).reshape(e.shape)
        return float(y) if y.ndim == 0 else y

    if isinstance(rules, RuleBase):
        return {t: one(rules.indices(t)) for t in TABLE_NAMES}
    return one(_indices(_rule_table(rules, "rules")))


def query_table(
    rules: RuleTable | str,
    *,
    n: int = 6,
    shape: str = "triangular",
    defuzz: str = "centroid",
) -> np.ndarray:
    """Evaluate one rule table at every integer level pair.

    Parameters
    ----------
    rules : RuleTable or str
        Rows ``e`` NB…PB, columns ``ec`` NB…PB.
    n, shape, defuzz
        As in :func:`evaluate`.

    Returns
    -------
    ndarray, shape (2n+1, 2n+1)
        Entry ``[E + n, EC + n]`` is the output at ``(E, EC)`` [normalised].
    """
    n = _check_n(n)
    levels = np.arange(-n, n + 1, dtype=float)
    out = evaluate(rules, levels[:, None], levels[None, :], n=n, shape=shape, defuzz=defuzz)
    return np.asarray(out)


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class QueryTables:
    """The four query tables of a rule base, in normalised output units ``[−1, 1]``.

    Row ``E + n``, column ``EC + n`` (``E``, ``EC`` from ``−n`` to ``n``), the runtime's order.
    Arrays are stored read-only; equality is identity (compare the arrays explicitly).

    Parameters
    ----------
    n : int
        Largest level (>= 1).
    kp, ki, kd, k1 : ndarray, shape (2n+1, 2n+1)
        ΔKp, ΔKi, ΔKd, ΔK1 [normalised; the law multiplies by an output scale].
    shape : str
        Input set shape used.
    defuzz : str
        Defuzzification method used.
    rules : str
        Name of the rule base evaluated.
    """

    n: int
    kp: np.ndarray
    ki: np.ndarray
    kd: np.ndarray
    k1: np.ndarray
    shape: str = "triangular"
    defuzz: str = "centroid"
    rules: str = "custom"

    def __post_init__(self) -> None:
        n = _check_n(self.n)
        object.__setattr__(self, "n", n)
        _check_shape(self.shape)
        _check_defuzz(self.defuzz)
        size = 2 * n + 1
        for t in TABLE_NAMES:
            a = _finite_array(t, getattr(self, t), "normalised").copy()
            if a.shape != (size, size):
                raise SpecError(f"{t} must have shape ({size}, {size}) for n={n}, got {a.shape}")
            a.setflags(write=False)
            object.__setattr__(self, t, a)

    @property
    def levels(self) -> np.ndarray:
        """The levels ``−n…n`` indexing rows (``E``) and columns (``EC``)."""
        return np.arange(-self.n, self.n + 1)

    def table(self, which: str) -> np.ndarray:
        """The query table ``which`` (one of :data:`TABLE_NAMES`)."""
        if which not in TABLE_NAMES:
            raise SpecError(f"table must be one of {', '.join(TABLE_NAMES)}, got {which!r}")
        return getattr(self, which)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (sorted keys; tables as nested lists of floats, row = E)."""
        out: dict[str, Any] = {t: getattr(self, t).tolist() for t in TABLE_NAMES}
        out.update(n=self.n, shape=self.shape, defuzz=self.defuzz, rules=self.rules)
        return dict(sorted(out.items()))


def query_tables(
    rule_base: RuleBase,
    *,
    n: int = 6,
    shape: str = "triangular",
    defuzz: str = "centroid",
) -> QueryTables:
    """Evaluate a rule base into its four query tables.

    Parameters
    ----------
    rule_base : RuleBase
        E.g. :data:`DEFAULT_RULES` or :data:`CLASSIC_RULES`.
    n : int
        Largest level (>= 1); tables have shape ``(2n+1, 2n+1)``.
    shape : {"triangular", "gaussian"}
        Input set shape.
    defuzz : {"centroid", "weighted_average"}
        Defuzzification method.

    Returns
    -------
    QueryTables

    Raises
    ------
    SpecError
        If an argument is invalid.
    """
    if not isinstance(rule_base, RuleBase):
        raise SpecError(f"rule_base must be a RuleBase, got {type(rule_base).__name__}")
    n = _check_n(n)
    levels = np.arange(-n, n + 1, dtype=float)
    tabs = evaluate(rule_base, levels[:, None], levels[None, :], n=n, shape=shape, defuzz=defuzz)
    return QueryTables(n=n, shape=shape, defuzz=defuzz, rules=rule_base.name, **tabs)


# --- properties (reusable on float, int16 or rule tables) ---------------------------------------


def _square_odd(table: ArrayLike, name: str = "table") -> np.ndarray:
    a = np.asarray(table)
    if a.dtype.kind in "UO":  # a rule table: set names → −3…3
        try:
            a = np.vectorize(lambda c: _INDEX[c] - 3, otypes=[np.int64])(a)
        except KeyError as exc:
            raise SpecError(f"{name} holds a name not in {' '.join(SETS)}: {exc}") from exc
    if a.ndim != 2 or a.shape[0] != a.shape[1] or a.shape[0] % 2 == 0:
        raise SpecError(f"{name} must be a square table with an odd side, got shape {a.shape}")
    return a


def direction_independent(table: ArrayLike) -> bool:
    """True if ``table[−E, −EC] == table[E, EC]`` exactly, i.e. the table equals its 180° rotation.

    Parameters
    ----------
    table : array_like, shape (m, m), m odd
        A query table (float or integer, e.g. quantised int16) or a rule table of set names.

    Returns
    -------
    bool
    """
    a = _square_odd(table)
    return bool(np.array_equal(a, a[::-1, ::-1]))


def _centre_halves(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = a.shape[0] // 2
    col = a[:, c]
    return col[c:], col[c::-1]  # EC = 0 column from E = 0 outwards, positive and negative side


def nondecreasing_in_abs_e(table: ArrayLike) -> bool:
    """True if the ``EC = 0`` column does not decrease as ``|E|`` grows (on both sides).

    Parameters
    ----------
    table : array_like, shape (m, m), m odd
        A query table (float or integer) or a rule table of set names.

    Returns
    -------
    bool
    """
    halves = _centre_halves(_square_odd(table))
    return all(bool(np.all(h[1:] >= h[:-1])) for h in halves)


def nonincreasing_in_abs_e(table: ArrayLike) -> bool:
    """True if the ``EC = 0`` column does not increase as ``|E|`` grows (on both sides).

    Parameters
    ----------
    table : array_like, shape (m, m), m odd
        A query table (float or integer) or a rule table of set names.

    Returns
    -------
    bool
    """
    halves = _centre_halves(_square_odd(table))
    return all(bool(np.all(h[1:] <= h[:-1])) for h in halves)


def check_default_properties(tables: QueryTables | RuleBase | Mapping[str, ArrayLike]) -> list[str]:
    """The properties :data:`DEFAULT_RULES` promises that ``tables`` violate.

    Every table direction-independent; ΔKp not decreasing and ΔKi not increasing with ``|E|`` at
    ``EC = 0``; ΔK1 constant. All checks are exact comparisons, so they apply to float tables,
    to scaled and quantised int16 tables and to rule tables alike.

    Parameters
    ----------
    tables : QueryTables, RuleBase or mapping
        Something with the four tables ``kp``, ``ki``, ``kd``, ``k1`` (keys or attributes).

    Returns
    -------
    list of str
        One line per violated property; empty if all hold.
    """
    if isinstance(tables, QueryTables | RuleBase):
        get = {t: getattr(tables, t) for t in TABLE_NAMES}
    elif isinstance(tables, Mapping):
        missing = [t for t in TABLE_NAMES if t not in tables]
        if missing:
            raise SpecError(f"tables must hold {', '.join(TABLE_NAMES)}; missing {missing}")
        get = {t: tables[t] for t in TABLE_NAMES}
    else:
        raise SpecError(f"tables must be QueryTables, RuleBase or a mapping, got {tables!r}")
    bad = [
        f"{t} is not direction-independent"
        for t in TABLE_NAMES
        if not direction_independent(get[t])
    ]
    if not nondecreasing_in_abs_e(get["kp"]):
        bad.append("kp decreases with |E| at EC = 0")
    if not nonincreasing_in_abs_e(get["ki"]):
        bad.append("ki increases with |E| at EC = 0")
    k1 = _square_odd(get["k1"], "k1")
    if not np.all(k1 == k1.flat[0]):
        bad.append("k1 is not constant")
    return bad
