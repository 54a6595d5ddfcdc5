"""Monte-Carlo verification at scale: where the plant sets come from, and what they show.

:func:`servotune.verify.verify` runs the nominal plants and ``count`` plant sets drawn from a
:class:`PlantDistribution` through every scenario of a spec, in chunks on an executor
(:mod:`servotune.executor`: in-process, or a Dask cluster for a million plant sets). This
module holds the two ends of that run:

- the **distribution**: :class:`SpecSpread`, the spec's ``[montecarlo]`` spreads around the
  rig's plants (:func:`~servotune.verify.variants.plant_variants`' draw, bit for bit), behind
  the :class:`PlantDistribution` interface, which another source of plants (a fleet's
  measured spread) implements the same way;
- the **summary** (:func:`summarise`): the pass fraction with its exact interval, the plant
  sets with the least margin and the parameter each failure tracks (:func:`sensitivity_table`).

Every draw is keyed by the seed and the draw's index (docs/decisions.md#11-random-numbers): a chunk
``[start, stop)`` draws what one pass over all draws would draw there, so the verification is the
same bytes whatever the chunking, the number of workers or the executor.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from servotune.plant import Plant
from servotune.rig import Rig
from servotune.verify.result import MonteCarloSummary, Sensitivity, WorstVariant, clopper_pearson
from servotune.verify.spec import MonteCarlo
from servotune.verify.variants import drawn_columns, spread_parameters, spread_plants

__all__ = [
    "PlantDistribution",
    "SpecSpread",
    "average_ranks",
    "least",
    "sensitivity_table",
    "summarise",
]

N_WORST = 5
"""Plant sets listed in :attr:`MonteCarloSummary.worst` by default."""
BEYOND_CHANCE = 0.05
"""Family-wise error rate of the sensitivity table's ``beyond_chance`` (Bonferroni)."""


class PlantDistribution(Protocol):
    """A source of random plant sets for a Monte-Carlo verification.

    Draw ``i`` must depend only on the seed and ``i`` (not on the chunk it is drawn in), so
    that a verification is the same whatever the chunking and the executor; the object is sent
    to the workers, so it must pickle.

    Attributes
    ----------
    name : str
        What the summary calls it (``"spec spread"``).
    parameters : tuple of str
        Names of the drawn values that :meth:`draw` returns, ``"<axis>.<parameter>"`` with the
        unit in the parameter's name (the sensitivity table's rows).
    source_files : tuple of tuple of str
        Files the distribution was read from, as ``(kind, name, sha256)`` (e.g. a fleet table:
        ``("fleet", "fleet.parquet", "<SHA-256 of its bytes>")``): the verification record
        binds each beside the tuning, rig and spec. Empty for the spec's spread (the spec is
        bound already).
    margin_plant_sets : tuple of (str, tuple of Plant)
        Labelled plant sets (one plant per rig axis) on which the loop margins are judged too,
        beside the spec's corners (:func:`servotune.analysis.plant_cases.plant_cases`): e.g. every
        measured machine of a fleet. Empty for the spec's spread (its corners are the cases).
    """

    name: str
    parameters: tuple[str, ...]
    source_files: tuple[tuple[str, str, str], ...]
    margin_plant_sets: tuple[tuple[str, tuple[Plant, ...]], ...]

    def draw(self, seed: int, start: int, stop: int) -> tuple[list[tuple[Plant, ...]], np.ndarray]:
        """Draws ``start … stop − 1``: per draw one plant per rig axis (rig order), and the
        drawn values, shape ``(stop − start, len(parameters))``."""
        ...


@dataclass(frozen=True, slots=True, kw_only=True)
class SpecSpread:
    """:class:`PlantDistribution` of a spec's ``[montecarlo]`` table: each varied axis's gain,
    time constant, offset and Coulomb level drawn uniformly inside the spreads (widened to the
    identified 95 % intervals of a fitted rig), and each of its modes' frequency and damping
    (:func:`~servotune.verify.variants.spread_parameters`), exactly as
    :func:`~servotune.verify.variants.plant_variants` draws them.

    Parameters
    ----------
    rig : Rig
    montecarlo : MonteCarlo
        The spreads and the axes they apply to (its ``count`` and ``seed`` are not used here).
    """

    rig: Rig
    montecarlo: MonteCarlo
    name: str = "spec spread"
    source_files: tuple[tuple[str, str, str], ...] = ()
    margin_plant_sets: tuple[tuple[str, tuple[Plant, ...]], ...] = ()

    @property
    def axes(self) -> tuple[str, ...]:
        """The axes whose plants vary (rig order)."""
        names = self.rig.axis_names
        return tuple(n for n in names if not self.montecarlo.axes or n in self.montecarlo.axes)

    @property
    def parameters(self) -> tuple[str, ...]:
        """``"<axis>.<parameter>"`` per varied axis: each spread parameter, then each mode's
        drawn values (``master.mode1_freq_hz``; ``master.mode1_damping`` where its damping has
        an interval): :func:`~servotune.verify.variants.drawn_columns`."""
        return tuple(name for name, _, _ in drawn_columns(self.rig, self.montecarlo))

    def draw(self, seed: int, start: int, stop: int) -> tuple[list[tuple[Plant, ...]], np.ndarray]:
        """See :meth:`PlantDistribution.draw`."""
        plants = spread_plants(self.rig, self.montecarlo, seed, start, stop)
        return plants, self.draw_parameters(seed, start, stop)[1]

    def draw_parameters(self, seed: int, start: int, stop: int) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`draw` without a :class:`Plant` each: the plant sets' parameter rows
        (:func:`~servotune.verify.variants.spread_parameters`, shape ``(stop − start, rig axes,
        NCOLUMNS)``, :mod:`servotune.verify.plant_sets`, the modes' draws included) and the
        drawn values. A distribution may offer this method: a Monte-Carlo chunk then builds its
        plant rows from the parameters directly (much faster)."""
        params = spread_parameters(self.rig, self.montecarlo, seed, start, stop)
        cols = drawn_columns(self.rig, self.montecarlo)
        axes = [j for _, j, _ in cols]
        values = params[:, axes, [c for _, _, c in cols]].reshape(len(params), len(cols))
        return params, np.ascontiguousarray(values)


def average_ranks(x: np.ndarray) -> np.ndarray:
    """``scipy.stats.rankdata(x)`` (average ranks of ties, 1 … n) of a 1-D float array, the
    same values, about twice as fast on a million draws.

    scipy sorts with a stable merge sort; any sort leaves equal values side by side, and their
    average rank does not depend on their order among themselves, so numpy's faster unstable
    sort gives the same ranks. An array with a NaN goes to scipy (its NaN policy).
    """
    from scipy.stats import rankdata

    x = np.asarray(x, dtype=np.float64)
    n = x.size
    if x.ndim != 1 or n == 0 or bool(np.isnan(x).any()):
        return np.asarray(rankdata(x), dtype=np.float64)
    order = np.argsort(x)
    xs = x[order]
    new = np.empty(n, dtype=bool)
    new[0] = True
    np.not_equal(xs[1:], xs[:-1], out=new[1:])
    starts = np.flatnonzero(new)  # first sorted place of each run of equal values
    ends = np.append(starts[1:], n)
    ranks = np.empty(n)
    ranks[order] = np.repeat(0.5 * (starts + ends + 1), ends - starts)  # (first + last) / 2
    return ranks


def _sensitivity_row(
    name: str,
    x: np.ndarray,
    fail: np.ndarray,
    fail_pct: float,
    m_ranks: np.ndarray | None,
    tested: bool,
    n_tested: int,
) -> Sensitivity:
    """One parameter's row of :func:`sensitivity_table` (``m_ranks``: the least margins'
    average ranks, None where Spearman's rho is not defined: a constant margin, n <= 2)."""
    from scipy.stats import mannwhitneyu

    q1, q3 = (float(q) for q in np.quantile(x, [0.25, 0.75]))
    rho = math.nan
    if m_ranks is not None:
        rho = float(np.corrcoef(np.column_stack((average_ranks(x), m_ranks)), rowvar=False)[1, 0])
    p = float(mannwhitneyu(x[fail], x[~fail]).pvalue) if tested else math.nan
    return Sensitivity(
        parameter=name,
        low_edge=q1,
        high_edge=q3,
        low_fail_pct=100.0 * float(fail[x <= q1].mean()),
        high_fail_pct=100.0 * float(fail[x >= q3].mean()),
        fail_pct=fail_pct,
        rank_correlation=rho,
        fail_p_value=p,
        beyond_chance=p < BEYOND_CHANCE / n_tested,
    )


def sensitivity_table(
    names: Sequence[str], values: np.ndarray, passed: np.ndarray, margin: np.ndarray
) -> tuple[Sensitivity, ...]:
    """Which drawn parameter drives failures (:class:`~servotune.verify.result.Sensitivity`).

    For each parameter that varies: the failure rate of the plant sets in its lowest and in
    its highest quarter (by the draws' own quartiles, so a skewed or measured distribution
    reads the same way), and Spearman's rank correlation with each plant set's least relative
    margin. A servo engineer reads the first as "a slow slave drive (``slave.tau_s`` in its
    top quarter) fails 4 % of the time, a fast one never", and the second as the direction and
    strength of the trend when nothing fails at all. Where some plant sets fail and others
    pass, each parameter's failing values are tested against its passing ones (scipy's
    Wilcoxon–Mann–Whitney rank-sum test, two-sided; Bonferroni over the parameters tested for
    ``beyond_chance``). Rows are ordered by that p-value (where there is one), then by the
    difference of the two failure rates, then by ``|ρ|``, then by name.

    Parameters
    ----------
    names : sequence of str
        Parameter names (columns of ``values``).
    values : ndarray, shape (n, len(names))
        The drawn values.
    passed : ndarray of bool, shape (n,)
        Whether each plant set kept every limit.
    margin : ndarray, shape (n,)
        Each plant set's least relative margin [1] (``-inf`` for a fault).

    Returns
    -------
    tuple of Sensitivity
    """
    fail = ~np.asarray(passed, dtype=bool)
    n = fail.size
    if n == 0:
        return ()
    fail_pct = 100.0 * float(fail.mean())
    m = np.where(np.isnan(margin), -np.inf, margin)  # ranks: a fault's -inf ranks lowest
    varied = [j for j in range(len(names)) if np.ptp(values[:, j]) > 0.0]
    tested = 0 < int(fail.sum()) < n
    # Spearman's rho as scipy.stats.spearmanr computes it (the Pearson correlation of the
    # average ranks, numpy.corrcoef), with the margin ranked once rather than once per
    # parameter (average_ranks: scipy's ranks from a faster sort); the parameters' ranks and
    # tests run on threads (numpy's sorts release the GIL): a million plant sets' table took
    # 2.5 s on one core, most of it in the sorts
    m_ranks = average_ranks(m) if n > 2 and bool((m != m[0]).any()) else None  # not constant

    def row(j: int) -> Sensitivity:
        return _sensitivity_row(
            names[j], values[:, j], fail, fail_pct, m_ranks, tested, len(varied)
        )

    with ThreadPoolExecutor(max_workers=max(1, min(len(varied), os.cpu_count() or 1))) as pool:
        out = list(pool.map(row, varied))

    def key(s: Sensitivity) -> tuple[float, float, float, str]:
        r = abs(s.rank_correlation) if np.isfinite(s.rank_correlation) else -1.0
        p = s.fail_p_value if np.isfinite(s.fail_p_value) else 2.0
        return (p, -abs(s.high_fail_pct - s.low_fail_pct), -r, s.parameter)

    return tuple(sorted(out, key=key))


def least(x: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` smallest values of ``x`` (no NaN), smallest first, the lower index
    first among equals: ``numpy.argsort(x, kind="stable")[:k]``, without sorting all of ``x``
    (a partition finds the k-th value; only the values up to it are sorted)."""
    k = max(0, min(int(k), x.size))
    if k == 0:
        return np.zeros(0, dtype=np.intp)
    kth = np.partition(x, k - 1)[k - 1]
    cand = np.flatnonzero(x <= kth)  # ascending indices: the stable sort keeps them in order
    return cand[np.argsort(x[cand], kind="stable")][:k]


def worst_draws(margin: np.ndarray, n_worst: int = N_WORST) -> np.ndarray:
    """The draws (0-based; plant set ``mc<i + 1>``) with the least margin, least first: the
    ones :func:`summarise` lists (NaN counts as ``-inf``)."""
    return least(np.where(np.isnan(margin), -np.inf, margin), int(n_worst))


def summarise(
    *,
    distribution: PlantDistribution,
    values: np.ndarray,
    passed: np.ndarray,
    margin: np.ndarray,
    figures: Sequence[tuple[str, str, str, str, float]],
    which: np.ndarray,
    figure_values: np.ndarray,
    n_worst: int = N_WORST,
) -> MonteCarloSummary:
    """The :class:`~servotune.verify.result.MonteCarloSummary` of the Monte-Carlo plant sets.

    Parameters
    ----------
    distribution : PlantDistribution
        Where the draws came from (its name and parameter names).
    values : ndarray, shape (n, len(distribution.parameters))
        The drawn values of draws ``0 … n − 1`` (labels ``mc1 … mc<n>``).
    passed : ndarray of bool, shape (n,)
    margin : ndarray, shape (n,)
        Least relative margin of each draw over every limit [1].
    figures : sequence of (scenario, quantity, axis, unit, limit)
        The limits, in row order.
    which : ndarray of int, shape (n,)
        Per draw, the index in ``figures`` of the limit giving its margin.
    figure_values : ndarray, shape (n,)
        Per draw, that limit's value [unit].
    n_worst : int
        Plant sets to list.
    """
    n = int(passed.size)
    k = int(passed.sum())
    ci = clopper_pearson(k, n) if n else (0.0, 1.0)
    worst: list[WorstVariant] = []
    if n:
        for i in worst_draws(margin, n_worst):
            scenario, quantity, axis, unit, limit = figures[int(which[i])]
            worst.append(
                WorstVariant(
                    label=f"mc{int(i) + 1}",
                    relative_margin=float(margin[i]),
                    scenario=scenario,
                    quantity=quantity,
                    axis=axis,
                    unit=unit,
                    value=float(figure_values[i]),
                    limit=float(limit),
                    parameters=dict(
                        zip(distribution.parameters, (float(v) for v in values[i]), strict=True)
                    ),
                )
            )
    return MonteCarloSummary(
        count=n,
        passed=k,
        ci95=(float(ci[0]), float(ci[1])),
        distribution=distribution.name,
        worst=tuple(worst),
        sensitivity=sensitivity_table(distribution.parameters, values, passed, margin),
    )
