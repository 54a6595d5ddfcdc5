"""Membership functions, Mamdani min–max inference and query tables (see :mod:`servotune.fuzzy`).

The input sets live on the level universe ``[−n, n]``, the output sets on ``[−1, 1]``; a rule
table is evaluated at real levels (:func:`evaluate`) or at every integer level pair into a
query table (:func:`query_table`, :func:`query_tables`), exactly sign-symmetric as the package
docstring explains.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from servotune.errors import SpecError
from servotune.fuzzy.rules import N_SETS, RuleBase, RuleTable, rule_table, table_indices
from servotune.laws.fuzzy_pid import TABLE_NAMES

__all__ = [
    "DEFUZZ_METHODS",
    "GRID_STEPS",
    "MEMBERSHIP_BITS",
    "SHAPES",
    "QueryTables",
    "evaluate",
    "input_membership",
    "input_peaks",
    "output_grid",
    "output_membership",
    "output_peaks",
    "query_table",
    "query_tables",
]

SHAPES = ("triangular", "gaussian")
"""Input membership shapes."""

DEFUZZ_METHODS = ("centroid", "weighted_average")
"""Defuzzification methods."""

GRID_STEPS = 100
"""Centroid grid points per output set spacing (1/3): grid step 1/300 on ``[−4/3, 4/3]``."""

MEMBERSHIP_BITS = 44
"""The sampled aggregate (centroid) is rounded to multiples of ``2^−44`` for exact int64 sums."""

_WEIGHT_BITS = 52  # firing strengths (weighted average) are rounded to multiples of 2^−52

_J = np.arange(-4 * GRID_STEPS, 4 * GRID_STEPS + 1, dtype=np.int64)  # output grid indices
_CHUNK = 256  # points per vectorised block (bounds memory: 256 × 7 × 801 floats)


def _output_samples() -> np.ndarray:
    # t_k(j) = max(0, 1 − |j − (k − 3)M| / M): |·| an exact integer, one correctly rounded division
    peaks = (np.arange(N_SETS, dtype=np.int64) - 3) * GRID_STEPS
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
    return np.array([(k - 3) * n / 3 for k in range(N_SETS)])


def output_peaks() -> np.ndarray:
    """Peaks of the output sets NB…PB: ``(k − 3)/3`` (−1, −2/3, …, 1) [normalised]."""
    return np.array([(k - 3) / 3 for k in range(N_SETS)])


def _input_mu(x: np.ndarray, n: int, shape: str) -> np.ndarray:
    # signed distance to each peak in set spacings; (k − 3)·n is exact, negation symmetric
    offsets = (np.arange(N_SETS, dtype=np.int64) - 3) * n
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
    return np.maximum(0.0, 1.0 - np.abs(3.0 * y[..., None] - (np.arange(N_SETS) - 3)))


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
    onehot = idx[None, :, :] == np.arange(N_SETS)[:, None, None]  # (7 sets, 7, 7)
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
    >>> from servotune.fuzzy.rules import DEFAULT_RULES
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
    return one(table_indices(rule_table(rules, "rules")))


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
    n, shape, defuzz
        As in :func:`evaluate`; the tables have shape ``(2n+1, 2n+1)``.

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
