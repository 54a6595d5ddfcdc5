"""Monte-Carlo verification at scale (servotune.verify.montecarlo, the chunked verify): draws keyed
by index, results independent of the chunking, the worst plant sets and the sensitivity table.
The cluster runs of the same are in tests/test_executor.py."""

from __future__ import annotations

import dataclasses
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import servotune as st
from servotune.executor import InProcessExecutor
from servotune.report.text import format_montecarlo, format_table
from servotune.tuning import read_tuning
from servotune.verify import load_spec, plant_variants, verify
from servotune.verify import run as run_module
from servotune.verify.montecarlo import SpecSpread, average_ranks, least, sensitivity_table
from servotune.verify.run import LISTED_VARIANTS
from servotune.verify.variants import spread_plants

ROOT = Path(__file__).resolve().parents[2]
RIG = ROOT / "plants" / "pc-dual-servo.toml"
SPEC = ROOT / "plants" / "pc-dual-servo.spec.toml"
TUNING = ROOT / "tests" / "corpus" / "base" / "tuning.json"  # a tuning of the example rig


@pytest.fixture(scope="module")
def rig() -> st.Rig:
    return st.load_rig(RIG)


@pytest.fixture(scope="module")
def sync_spec():
    """The shipped spec, its sync scenario only, 30 plant sets."""
    spec = load_spec(SPEC)
    sync = next(sc for sc in spec.scenarios if sc.name == "sync")
    mc = dataclasses.replace(spec.montecarlo, count=30)
    return dataclasses.replace(spec, scenarios=(sync,), montecarlo=mc)


def test_a_chunk_draws_what_the_whole_run_draws(rig) -> None:
    mc = dataclasses.replace(load_spec(SPEC).montecarlo, count=40)
    whole = plant_variants(rig, mc, 7)
    assert spread_plants(rig, mc, 7, 17, 29) == [v.plants for v in whole[18:30]]
    plants, values = SpecSpread(rig=rig, montecarlo=mc).draw(7, 3, 5)
    assert plants == [v.plants for v in whole[4:6]]
    assert values.shape == (2, 8)
    assert values[1, 1] == whole[5].plants[0].tau_s  # master.tau_s of mc5


class _Recording(InProcessExecutor):
    """In-process, noting the plant sets of each task."""

    def __init__(self) -> None:
        self.sizes: list[int] = []

    def _map(self, fn, items, shared, done):
        self.sizes += [c.stop - c.start for c in items]
        return super()._map(fn, items, shared, done)


def test_result_is_the_same_for_any_chunk_size(rig, sync_spec, monkeypatch) -> None:
    tuning = read_tuning(TUNING)
    one = verify(tuning, rig, sync_spec)
    for chunk_size in (1, 4, 13):
        other = verify(tuning, rig, sync_spec, chunk_size=chunk_size)
        assert json.dumps(other.to_dict(), sort_keys=True) == json.dumps(
            one.to_dict(), sort_keys=True
        )
    # the default plan (large chunks first, shrinking: executor.guided_chunk_bounds), made to
    # give chunks of 8 down to 2 plant sets here
    monkeypatch.setattr(run_module, "_CHUNK_RANGE", (2, 8))
    ex = _Recording()
    guided = verify(tuning, rig, sync_spec, executor=ex)
    assert json.dumps(guided.to_dict(), sort_keys=True) == json.dumps(one.to_dict(), sort_keys=True)
    assert ex.sizes[0] == 8 and ex.sizes[-1] <= 2 and sum(ex.sizes) == 31
    # ... and a task holds at most _CHUNK_WORK plant·ticks: the sync scenario is 2 × 600 per
    # plant set, so a budget of 3 plant sets' ticks gives chunks of 3 at most (never below 2)
    monkeypatch.setattr(run_module, "_CHUNK_WORK", 3 * 1200 + 5)
    ex = _Recording()
    bounded = verify(tuning, rig, sync_spec, executor=ex)
    assert max(ex.sizes) == 3 and sum(ex.sizes) == 31
    assert json.dumps(bounded.to_dict(), sort_keys=True) == json.dumps(
        one.to_dict(), sort_keys=True
    )
    mc = one.montecarlo
    assert mc is not None and mc.count == 30 and mc.passed == sum(one.variant_passed[1:])
    assert one.pass_fraction[3:] == mc.ci95
    # least margin first, each names the figure and the drawn parameters
    margins = [w.relative_margin for w in mc.worst]
    assert margins == sorted(margins) and len(mc.worst) == 5
    w = mc.worst[0]
    assert w.label.startswith("mc") and w.scenario == "sync"
    assert set(w.parameters) == set(SpecSpread(rig=rig, montecarlo=sync_spec.montecarlo).parameters)
    assert "worst plant sets of 30" in format_table(one)


def test_big_run_lists_only_the_plant_sets_it_names(rig, sync_spec, monkeypatch) -> None:
    """Above LISTED_VARIANTS, the result (and its record) lists the nominal plants and the
    plant sets its rows and worst list name, each as drawn."""
    import servotune.verify.run as run

    monkeypatch.setattr(run, "LISTED_VARIANTS", 10)
    tuning = read_tuning(TUNING)
    v = verify(tuning, rig, sync_spec)
    assert LISTED_VARIANTS == 10_000 and v.plant_sets == 31
    labels = {x.label for x in v.variants}
    named = {r.variant for r in v.rows} | {w.label for w in v.montecarlo.worst} | {"nominal"}
    assert labels == named
    whole = {x.label: x for x in plant_variants(rig, sync_spec.montecarlo)}
    assert all(x == whole[x.label] for x in v.variants)


def test_sensitivity_finds_the_parameter_that_drives_failures() -> None:
    rng = np.random.default_rng(3)
    n = 4000
    values = rng.uniform(0.0, 1.0, size=(n, 3))
    values[:, 2] = 0.5  # does not vary: no row
    margin = 0.5 - values[:, 1] + 0.01 * values[:, 0]  # tau-like: large values fail
    passed = margin >= 0
    table = sensitivity_table(("a.gain", "a.tau_s", "a.const"), values, passed, margin)
    assert [s.parameter for s in table] == ["a.tau_s", "a.gain"]
    tau = table[0]
    assert tau.low_fail_pct == 0.0 and tau.high_fail_pct == 100.0
    assert tau.rank_correlation < -0.99
    np.testing.assert_allclose(tau.fail_pct, 100.0 * (~passed).mean(), rtol=0, atol=1e-12)
    np.testing.assert_allclose([tau.low_edge, tau.high_edge], [0.25, 0.75], atol=0.02)


def _few_failures(seed: int, n: int = 100_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The shape of the example spec's 100,000-plant-set run (2026-11-26: 3 failures, all with
    the slave's drift in the last percent of its spread, and by chance all three in the master
    gain's lowest quarter, whose Spearman ρ with the least margin was +0.86): column 0 a
    "master gain" that sets every passing plant set's margin and has nothing to do with the
    failures; column 1 a "slave drift" whose last 0.05 % fails; column 2 noise. Failures are
    then moved, among the tail's plant sets, to the lowest quarter of column 0."""
    rng = np.random.default_rng(seed)
    values = rng.uniform(0.0, 1.0, size=(n, 3))
    fail = values[:, 1] < 5e-4
    # the coincidence: the failing plant sets' column 0 drawn again from its lowest quarter
    values[fail, 0] = rng.uniform(0.0, 0.24, size=int(fail.sum()))
    margin = np.where(fail, -0.25, 0.1 + values[:, 0])
    return values, ~fail, margin


def test_sensitivity_tests_few_failures_instead_of_trusting_quarters() -> None:
    """A handful of failures that all fall in one parameter's lowest quarter by chance must not
    rank that parameter first because its ρ over the passing plant sets is large: the rank-sum
    test puts the parameter whose failing values sit in its last percent first, and says which
    ones set the failures apart beyond chance."""
    values, passed, margin = _few_failures(1)
    k = int((~passed).sum())
    assert 20 <= k <= 80  # about 0.05 % of 100,000
    table = sensitivity_table(("m.gain", "s.offset", "s.noise"), values, passed, margin)
    by = {s.parameter: s for s in table}
    # the quarters alone cannot tell the two apart: every failure in both lowest quarters …
    assert by["m.gain"].low_fail_pct == by["s.offset"].low_fail_pct > 0.0
    assert by["m.gain"].high_fail_pct == by["s.offset"].high_fail_pct == 0.0
    # … and ρ favours the gain (it sets every passing margin); the old order put it first
    assert abs(by["m.gain"].rank_correlation) > abs(by["s.offset"].rank_correlation)
    assert table[0].parameter == "s.offset"
    assert by["s.offset"].fail_p_value < 1e-12 and by["s.offset"].beyond_chance
    # the gain's failing values are low as well (drawn so), so its test finds that too: the
    # table states what the data show, the order says which is stronger
    assert by["s.offset"].fail_p_value < by["m.gain"].fail_p_value
    assert not by["s.noise"].beyond_chance
    # reference: scipy's test on the same split (the table passes failing, then passing values)
    from scipy.stats import mannwhitneyu

    x = values[:, 1]
    assert by["s.offset"].fail_p_value == mannwhitneyu(x[~passed], x[passed]).pvalue


def test_beyond_chance_holds_its_error_rate_when_nothing_drives_failures() -> None:
    """Under the null (failures drawn independently of every parameter), ``beyond_chance`` names
    a parameter in at most about 5 % of verifications (Bonferroni over the parameters keeps the
    family-wise rate at or below 0.05). 400 simulated verifications of 2,000 plant sets, 5
    parameters, 1 % failing: expected at most 20 with a flag; 33 is beyond the binomial
    (400, 0.05) 99.9 % quantile. Each p-value also lies in [0, 1] and they spread out (a test
    that always returned 1 would pass the count alone)."""
    rng = np.random.default_rng(11)
    flagged = 0
    ps = []
    for _ in range(400):
        values = rng.standard_normal((2000, 5))
        passed = rng.random(2000) >= 0.01
        passed[0], passed[1] = False, True  # at least one of each
        margin = np.where(passed, 1.0, -1.0)
        table = sensitivity_table(tuple("abcde"), values, passed, margin)
        flagged += any(s.beyond_chance for s in table)
        ps += [s.fail_p_value for s in table]
    assert flagged <= 33
    ps = np.array(ps)
    assert ((ps >= 0) & (ps <= 1)).all()
    # uniform under the null: each decile holds about a tenth of the 2,000 p-values
    counts = np.histogram(ps, bins=10, range=(0, 1))[0]
    assert counts.min() > 140 and counts.max() < 260, counts


def test_sensitivity_figures_are_scipy_s_own() -> None:
    """The table ranks the margin once and the parameters on threads; each ρ and p must still
    be what scipy.stats.spearmanr and mannwhitneyu give for that column, to the bit (ties in
    the margin, faults' -inf and NaN margins included), and a constant margin has no ρ."""
    from scipy.stats import mannwhitneyu, spearmanr

    rng = np.random.default_rng(11)
    n = 3000
    values = rng.normal(size=(n, 4))
    margin = np.round(0.3 - 0.2 * values[:, 2] + 0.1 * rng.normal(size=n), 2)  # ties
    margin[:40] = -np.inf
    margin[40:45] = np.nan
    passed = np.isfinite(margin) & (margin >= 0)
    names = ("a", "b", "c", "d")
    table = {s.parameter: s for s in sensitivity_table(names, values, passed, margin)}
    m = np.where(np.isnan(margin), -np.inf, margin)
    for j, name in enumerate(names):
        x = values[:, j]
        assert table[name].rank_correlation == float(spearmanr(x, m).statistic)
        assert table[name].fail_p_value == float(mannwhitneyu(x[~passed], x[passed]).pvalue)
    assert table["c"].rank_correlation < -0.8
    flat = sensitivity_table(names, values, passed, np.full(n, 0.5))
    assert all(np.isnan(s.rank_correlation) for s in flat)
    with warnings.catch_warnings():  # every plant set faulted: no rho, and no numpy warning
        warnings.simplefilter("error")
        faulted = sensitivity_table(names, values, np.zeros(n, bool), np.full(n, -np.inf))
    assert all(np.isnan(s.rank_correlation) for s in faulted)


def test_average_ranks_are_scipy_s_rankdata() -> None:
    """The table's ranks (numpy's unstable sort, ties averaged) are scipy.stats.rankdata's
    values, to the bit: runs of ties, -0.0 beside 0.0, infinities, one value, a NaN (scipy's
    own policy), and a column taken out of a 2-D array (strided)."""
    from scipy.stats import rankdata

    rng = np.random.default_rng(3)
    cases = [
        np.round(rng.normal(size=20_000), 1),  # long runs of ties
        rng.normal(size=5_000),
        np.array([0.0, -0.0, 1.0, -np.inf, np.inf, 0.0, -np.inf]),
        np.array([2.5]),
        np.array([1.0, np.nan, 0.5]),
        np.round(rng.normal(size=(4_000, 3)), 2)[:, 1],
        np.zeros(0),
    ]
    for x in cases:
        want = rankdata(x)
        got = average_ranks(x)
        assert got.dtype == np.float64 and got.shape == x.shape
        np.testing.assert_array_equal(got, want)


def test_least_is_the_head_of_a_stable_sort() -> None:
    rng = np.random.default_rng(2)
    for n, k in ((1, 5), (10, 5), (1000, 5), (1000, 0), (5000, 40)):
        x = np.round(rng.normal(size=n), 1)  # many ties
        x[: n // 7] = -np.inf
        want = np.argsort(x, kind="stable")[:k]
        np.testing.assert_array_equal(least(x, k), want)


def test_nothing_failing_or_everything_failing_has_no_test() -> None:
    rng = np.random.default_rng(5)
    values = rng.uniform(size=(500, 2))
    for passed in (np.ones(500, dtype=bool), np.zeros(500, dtype=bool)):
        table = sensitivity_table(("a", "b"), values, passed, values[:, 0] - 0.5)
        assert all(np.isnan(s.fail_p_value) and not s.beyond_chance for s in table)
        # ordered as before the test existed: by |ρ| (a drives the margin)
        assert [s.parameter for s in table] == ["a", "b"]


def test_the_text_says_which_parameters_set_failures_apart() -> None:
    """The closing line follows the table: the same draws with the failures tied to a parameter
    name it; with the failures drawn independently of every parameter it says none does; with
    nothing failing there is no test, no p column and no line."""
    values, passed, margin = _few_failures(2, n=20_000)
    names = ("m.gain", "s.offset", "s.noise")

    def text(passed: np.ndarray) -> str:
        table = sensitivity_table(names, values, passed, margin)
        summary = st.verify.MonteCarloSummary(
            count=passed.size,
            passed=int(passed.sum()),
            ci95=(0.0, 1.0),
            distribution="spec spread",
            sensitivity=table,
        )
        return format_montecarlo(summary)

    k = int((~passed).sum())
    tied = text(passed)
    last = tied.splitlines()[-1]
    assert last.startswith(f"the {k} failing plant sets differ beyond chance (p < 0.05/3, ")
    assert last.split(" in: ")[1].split(", ")[0] == "s.offset"
    head = next(ln for ln in tied.splitlines() if ln.strip().startswith("parameter"))
    assert head.split()[-2:] == ["p", "ρ"]
    chance = np.ones(passed.size, dtype=bool)
    chance[np.random.default_rng(0).choice(passed.size, k, replace=False)] = False
    untied = text(chance)
    assert untied.splitlines()[-1] == (
        f"no parameter sets the {k} failing plant sets apart beyond chance (p < 0.05/3, "
        "Bonferroni): the table's failure rates may be chance"
    )
    none = text(np.ones(passed.size, dtype=bool))
    assert "rank-sum" not in none and "beyond chance" not in none


def test_montecarlo_text_names_the_figure_and_the_table(rig, sync_spec) -> None:
    tuning = read_tuning(TUNING)
    v = verify(tuning, rig, sync_spec)
    text = format_montecarlo(v.montecarlo)
    assert text.splitlines()[0].startswith("worst plant sets of 30 from the spec spread")
    assert "sensitivity:" in text and "slave.tau_s" in text
