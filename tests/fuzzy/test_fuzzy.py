"""Tests for servotune.fuzzy: rule bases, Mamdani inference and query tables."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from servotune.errors import SpecError
from servotune.fixed import quantize_table
from servotune.fuzzy import (
    CLASSIC_RULES,
    DEFAULT_RULES,
    DEFUZZ_METHODS,
    SETS,
    SHAPES,
    TABLE_NAMES,
    QueryTables,
    RuleBase,
    check_default_properties,
    direction_independent,
    evaluate,
    format_rules,
    input_membership,
    input_peaks,
    nondecreasing_in_abs_e,
    nonincreasing_in_abs_e,
    output_grid,
    output_membership,
    output_peaks,
    parse_rules,
    query_table,
    query_tables,
)

# The classic textbook tables, as given in the task brief (rows e NB…PB, columns ec NB…PB).
CLASSIC_TEXT = {
    "kp": "PB PB PM PM PS ZO ZO | PB PB PM PS PS ZO NS | PM PM PM PS ZO NS NS | "
    "PM PM PS ZO NS NM NM | PS PS ZO NS NS NM NM | PS ZO NS NM NM NM NB | ZO ZO NM NM NM NB NB",
    "ki": "NB NB NM NM NS ZO ZO | NB NB NM NS NS ZO ZO | NB NM NS NS ZO PS PS | "
    "NM NM NS ZO PS PM PM | NM NS ZO PS PS PM PB | ZO ZO PS PS PM PB PB | ZO ZO PS PM PM PB PB",
    "kd": "PS NS NB NB NB NM PS | PS NS NB NM NM NS ZO | ZO NS NM NM NS NS ZO | "
    "ZO NS NS NS NS NS ZO | ZO ZO ZO ZO ZO ZO ZO | PB NS PS PS PS PS PB | PB PM PM PM PS PS PB",
}
MIRROR = dict(zip(SETS, reversed(SETS), strict=True))
RNG_SEED = 20240611


def uniform(name: str) -> tuple[tuple[str, ...], ...]:
    return tuple((name,) * 7 for _ in range(7))


def rows_only() -> tuple[tuple[str, ...], ...]:
    """Rule table that depends on e only: row i is all SETS[i]."""
    return tuple((s,) * 7 for s in SETS)


def levels(n: int) -> np.ndarray:
    return np.arange(-n, n + 1)


def random_points(n: int, count: int = 40) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(RNG_SEED)
    # include points beyond ±n (the shoulders)
    return rng.uniform(-1.2 * n, 1.2 * n, count), rng.uniform(-1.2 * n, 1.2 * n, count)


# --- rule tables ------------------------------------------------------------------------------


def test_classic_rules_equal_the_textbook_tables():
    for t, text in CLASSIC_TEXT.items():
        expected = [row.split() for row in text.split("|")]  # independent parse
        assert len(expected) == 7
        assert all(len(row) == 7 for row in expected)
        assert [list(row) for row in getattr(CLASSIC_RULES, t)] == expected
    assert CLASSIC_RULES.k1 == uniform("ZO")


def test_parse_and_format_round_trip():
    table = parse_rules(CLASSIC_TEXT["kp"])
    assert table[0] == ("PB", "PB", "PM", "PM", "PS", "ZO", "ZO")
    assert table[6][6] == "NB"
    assert parse_rules(format_rules(table)) == table
    # newlines separate rows too
    assert parse_rules(CLASSIC_TEXT["kp"].replace("|", "\n")) == table
    rb = RuleBase(**DEFAULT_RULES.to_dict())
    assert rb == DEFAULT_RULES
    assert list(DEFAULT_RULES.to_dict()) == sorted(DEFAULT_RULES.to_dict())


def test_rule_base_accepts_rows_of_names_and_indices():
    rb = RuleBase(kp=rows_only(), ki=[list(r) for r in rows_only()], kd=uniform("PS"))
    assert rb.kp == rb.ki == rows_only()
    assert_array_equal(rb.indices("kp")[:, 0], np.arange(7))
    assert_array_equal(rb.indices("kd"), np.full((7, 7), 4))


def test_default_rule_base_properties_at_rule_level():
    for t in TABLE_NAMES:
        r = getattr(DEFAULT_RULES, t)
        assert all(r[6 - i][6 - j] == r[i][j] for i in range(7) for j in range(7)), t
    assert DEFAULT_RULES.k1 == uniform("ZO")
    # EC = ZO column from e = ZO outwards: ΔKp not decreasing, ΔKi not increasing
    kp_col = [SETS.index(DEFAULT_RULES.kp[i][3]) for i in range(3, 7)]
    ki_col = [SETS.index(DEFAULT_RULES.ki[i][3]) for i in range(3, 7)]
    assert kp_col == sorted(kp_col)
    assert ki_col == sorted(ki_col, reverse=True)
    # the helpers read rule tables (set names) as well
    assert check_default_properties(DEFAULT_RULES) == []


# --- membership functions ---------------------------------------------------------------------


@pytest.mark.parametrize("n", [3, 6])
def test_triangular_input_sets_peaks_and_partition_of_unity(n):
    peaks = input_peaks(n)
    assert_array_equal(peaks, np.linspace(-n, n, 7))
    # at each peak the set is 1 and every other set (its neighbours included) is 0
    assert_array_equal(input_membership(peaks, n=n), np.eye(7))
    x = np.linspace(-2 * n, 2 * n, 4001)
    mu = input_membership(x, n=n)
    assert_allclose(mu.sum(axis=-1), 1.0, rtol=0, atol=1e-15)
    assert np.all(mu >= 0)
    # shoulders: fully NB at and below −n, fully PB at and above n
    assert np.all(mu[x <= -n, 0] == 1.0)
    assert np.all(mu[x >= n, 6] == 1.0)
    # exact mirror symmetry μ_k(−x) == μ_{6−k}(x)
    assert_array_equal(input_membership(-x, n=n), mu[:, ::-1])


def test_triangular_input_sets_hand_values():
    # n = 6: peaks every 2 levels, so odd levels are halfway between two sets
    assert_array_equal(input_membership(5, n=6), [0, 0, 0, 0, 0, 0.5, 0.5])
    assert_array_equal(input_membership(-1, n=6), [0, 0, 0.5, 0.5, 0, 0, 0])
    # n = 3: E = 0.25 is a quarter of the way from ZO (0) to PS (1)
    assert_array_equal(input_membership(0.25, n=3), [0, 0, 0, 0.75, 0.25, 0, 0])


def test_gaussian_input_sets():
    n = 6
    peaks = input_peaks(n)
    mu = input_membership(peaks, n=n, shape="gaussian")
    assert_array_equal(np.diag(mu), np.ones(7))
    # FWHM = one spacing: 1/16 at the neighbours' peaks, 0.5 halfway between
    assert_allclose(np.diag(mu, 1), 1 / 16, rtol=1e-15)
    assert_allclose(input_membership(1.0, n=n, shape="gaussian")[3:5], [0.5, 0.5], rtol=1e-15)
    x = np.linspace(-9, 9, 721)
    g = input_membership(x, n=n, shape="gaussian")
    assert_array_equal(input_membership(-x, n=n, shape="gaussian"), g[:, ::-1])
    assert np.all(g[x <= -n, 0] == 1.0)
    assert np.all(g[x >= n, 6] == 1.0)


def test_output_sets_are_full_symmetric_triangles():
    peaks = output_peaks()
    assert_array_equal(peaks, [-1, -2 / 3, -1 / 3, 0, 1 / 3, 2 / 3, 1])
    assert_array_equal(output_membership(peaks), np.eye(7))
    # the end sets extend past ±1 to ±4/3, symmetric about their peaks
    t = np.linspace(0, 1 / 3, 11)
    pb = output_membership(1 + t)[:, 6]
    assert_allclose(pb, output_membership(1 - t)[:, 6], atol=1e-15)
    assert output_membership(4 / 3)[6] == pytest.approx(0, abs=1e-15)
    grid = output_grid()
    assert grid[0] == -4 / 3 and grid[-1] == 4 / 3 and grid.size == 801
    assert_array_equal(grid, -grid[::-1])


# --- inference: exact reference values --------------------------------------------------------


@pytest.mark.parametrize("defuzz", DEFUZZ_METHODS)
@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("n", [3, 6])
def test_single_set_tables_give_exactly_its_peak(n, shape, defuzz):
    e, ec = random_points(n)
    grid_e, grid_ec = np.meshgrid(levels(n), levels(n), indexing="ij")
    for k, name in enumerate(SETS):
        expected = (k - 3) / 3  # PB → exactly 1.0, ZO → exactly 0.0
        qt = query_table(uniform(name), n=n, shape=shape, defuzz=defuzz)
        assert qt.shape == (2 * n + 1, 2 * n + 1)
        assert np.all(qt == expected), name
        assert np.all(evaluate(uniform(name), e, ec, n=n, shape=shape, defuzz=defuzz) == expected)
        assert np.all(qt == evaluate(uniform(name), grid_e, grid_ec, n=n, shape=shape))
    assert np.all(query_table(uniform("PB"), n=n, shape=shape, defuzz=defuzz) == 1.0)
    assert np.all(query_table(uniform("ZO"), n=n, shape=shape, defuzz=defuzz) == 0.0)


@pytest.mark.parametrize("defuzz", DEFUZZ_METHODS)
@pytest.mark.parametrize("n", [3, 6])
def test_rows_are_e_and_columns_are_ec(n, defuzz):
    # A table that depends on e only gives a query table constant along each row (E fixed)
    # and rising down the rows: entry [E + n, ·] = E/n (a peak, or halfway between two
    # adjacent peaks with equal weights, whose centroid is the midpoint). A transposed table
    # would vary along the columns instead.
    qt = query_table(rows_only(), n=n, defuzz=defuzz)
    expected = np.repeat((levels(n) / n)[:, None], 2 * n + 1, axis=1)
    assert_array_equal(qt, expected)
    cols_only = tuple(zip(*rows_only(), strict=True))  # depends on ec only
    assert_array_equal(query_table(cols_only, n=n, defuzz=defuzz), expected.T)


def test_classic_kp_off_diagonal_hand_values():
    # n = 6, triangular: input peaks at −6, −4, −2, 0, 2, 4, 6.
    # (E, EC) = (6, −2): μ_E(PB) = 1 (shoulder), μ_EC(NS) = 1, all others 0, so only the rule
    # (e PB, ec NS) fires, at min(1, 1) = 1. Classic ΔKp row PB = "ZO ZO NM NM NM NB NB",
    # column NS (3rd) = NM, whose centroid is its peak −2/3.
    # (E, EC) = (−2, 6): only (e NS, ec PB) fires; row NS = "PM PM PM PS ZO NS NS",
    # column PB (7th) = NS → −1/3.
    assert evaluate(CLASSIC_RULES.kp, 6, -2) == -2 / 3
    assert evaluate(CLASSIC_RULES.kp, -2, 6) == -1 / 3
    qt = query_tables(CLASSIC_RULES)
    n = qt.n
    assert qt.kp[n + 6, n - 2] == -2 / 3  # row E = 6, column EC = −2
    assert qt.kp[n - 2, n + 6] == -1 / 3
    # (E, EC) = (5, −3): μ_E(PM) = μ_E(PB) = 0.5, μ_EC(NM) = μ_EC(NS) = 0.5; all four rules
    # fire at 0.5: (PM, NM) → ZO, (PM, NS) → NS, (PB, NM) → ZO, (PB, NS) → NM.
    # Centroid: NM, NS, ZO clipped at 0.5 merge into a plateau on [−5/6, 1/6] with ramps to
    # −1 and 1/3, symmetric about −1/3. Weighted average: (0 − 1/3 + 0 − 2/3) / 4 = −1/4.
    assert evaluate(CLASSIC_RULES.kp, 5, -3) == -1 / 3
    assert evaluate(CLASSIC_RULES.kp, 5, -3, defuzz="weighted_average") == -1 / 4
    # (E, EC) = (−3, 5): (NM, PM) → ZO, (NM, PB) → NS, (NS, PM) → NS, (NS, PB) → NS, all at
    # 0.5. Centroid: NS and ZO clipped at 0.5, plateau [−1/2, 1/6], ramps to −2/3 and 1/3,
    # symmetric about −1/6. Weighted average: (0 − 1/3 − 1/3 − 1/3) / 4 = −1/4.
    assert evaluate(CLASSIC_RULES.kp, -3, 5) == -1 / 6
    assert evaluate(CLASSIC_RULES.kp, -3, 5, defuzz="weighted_average") == -1 / 4
    assert qt.kp[n + 5, n - 3] == -1 / 3
    assert qt.kp[n - 3, n + 5] == -1 / 6


def _reference_mamdani(rules, e, ec, n, shape):
    """Independent min–max + centroid on a fine grid (step 1/60000), for one point."""
    y = np.linspace(-4 / 3, 4 / 3, 160_001)
    out = output_membership(y)  # (G, 7)
    mu_e = input_membership(e, n=n, shape=shape)
    mu_ec = input_membership(ec, n=n, shape=shape)
    clip = np.zeros(7)  # max over the rules concluding each set of min(μ_e, μ_ec)
    for i in range(7):
        for j in range(7):
            k = SETS.index(rules[i][j])
            clip[k] = max(clip[k], min(mu_e[i], mu_ec[j]))
    agg = np.max(np.minimum(clip, out), axis=1)
    return float(np.sum(agg * y) / np.sum(agg))


def _reference_weighted(rules, e, ec, n, shape):
    mu_e = input_membership(e, n=n, shape=shape)
    mu_ec = input_membership(ec, n=n, shape=shape)
    num = den = 0.0
    for i in range(7):
        for j in range(7):
            w = min(mu_e[i], mu_ec[j])
            num += w * (SETS.index(rules[i][j]) - 3) / 3
            den += w
    return num / den


@pytest.mark.parametrize("shape", SHAPES)
def test_inference_matches_an_independent_implementation(shape):
    n = 6
    e, ec = random_points(n, count=8)
    for t in ("kp", "kd"):
        rules = getattr(DEFAULT_RULES, t)
        got_c = evaluate(rules, e, ec, n=n, shape=shape)
        got_w = evaluate(rules, e, ec, n=n, shape=shape, defuzz="weighted_average")
        for a, b, yc, yw in zip(e, ec, got_c, got_w, strict=True):
            # centroid grid step 1/300: documented agreement within 1e-4
            assert yc == pytest.approx(_reference_mamdani(rules, a, b, n, shape), abs=1e-4)
            assert yw == pytest.approx(_reference_weighted(rules, a, b, n, shape), abs=1e-12)


# --- query tables -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("n", "shape", "defuzz"),
    [
        (6, "triangular", "centroid"),
        (6, "triangular", "weighted_average"),
        (3, "triangular", "centroid"),
        (6, "gaussian", "centroid"),
    ],
)
@pytest.mark.parametrize("rule_base", [DEFAULT_RULES, CLASSIC_RULES], ids=lambda r: r.name)
def test_query_tables_equal_direct_evaluation(rule_base, n, shape, defuzz):
    qt = query_tables(rule_base, n=n, shape=shape, defuzz=defuzz)
    assert (qt.n, qt.shape, qt.defuzz, qt.rules) == (n, shape, defuzz, rule_base.name)
    assert_array_equal(qt.levels, levels(n))
    for i, e in enumerate(levels(n)):
        for j, ec in enumerate(levels(n)):
            direct = evaluate(rule_base, int(e), int(ec), n=n, shape=shape, defuzz=defuzz)
            for t in TABLE_NAMES:
                assert qt.table(t)[i, j] == direct[t], (t, e, ec)
    for t in TABLE_NAMES:
        assert_array_equal(
            qt.table(t), query_table(rule_base.table(t), n=n, shape=shape, defuzz=defuzz)
        )
        assert np.all(np.abs(qt.table(t)) <= 1.0)


def test_query_tables_object():
    qt = query_tables(DEFAULT_RULES, n=3)
    with pytest.raises(ValueError, match="read-only"):
        qt.kp[0, 0] = 1.0
    d = qt.to_dict()
    assert list(d) == sorted(d)
    assert d["n"] == 3 and len(d["kp"]) == 7 and d["rules"] == "default"
    with pytest.raises(dataclasses.FrozenInstanceError):
        qt.n = 4  # type: ignore[misc]
    with pytest.raises(SpecError, match="ki must have shape"):
        QueryTables(n=3, kp=qt.kp, ki=np.zeros((5, 5)), kd=qt.kd, k1=qt.k1)


# --- the default's properties, exactly, on float and on quantised tables ------------------------


@pytest.mark.parametrize("defuzz", DEFUZZ_METHODS)
@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("n", [3, 6])
def test_default_properties_hold_exactly(n, shape, defuzz):
    qt = query_tables(DEFAULT_RULES, n=n, shape=shape, defuzz=defuzz)
    assert check_default_properties(qt) == []
    for t in TABLE_NAMES:
        a = qt.table(t)
        assert np.array_equal(a, a[::-1, ::-1]), t  # bit-exact, not allclose
    assert nondecreasing_in_abs_e(qt.kp)
    assert nonincreasing_in_abs_e(qt.ki)
    assert np.all(qt.k1 == 0.0)
    for scale in (0.3, 1.7, 12.5):
        quantised = {}
        for t in TABLE_NAMES:
            q, f = quantize_table(scale * qt.table(t), f_max=20)
            assert q.dtype == np.int16 and f <= 20
            quantised[t] = q
            assert direction_independent(q), (t, scale)
        assert nondecreasing_in_abs_e(quantised["kp"])
        assert nonincreasing_in_abs_e(quantised["ki"])
        assert check_default_properties(quantised) == []
        assert np.any(quantised["kp"] != 0)


def test_direction_independence_at_real_points():
    # the symmetry is exact off the grid too (any real E, EC), not only at integer levels
    for shape in SHAPES:
        for defuzz in DEFUZZ_METHODS:
            e, ec = random_points(6)
            a = evaluate(DEFAULT_RULES, e, ec, shape=shape, defuzz=defuzz)
            b = evaluate(DEFAULT_RULES, -e, -ec, shape=shape, defuzz=defuzz)
            for t in TABLE_NAMES:
                assert_array_equal(a[t], b[t])


@pytest.mark.parametrize("defuzz", DEFUZZ_METHODS)
@pytest.mark.parametrize("shape", SHAPES)
def test_mirrored_rule_table_gives_exactly_negated_output(shape, defuzz):
    # R'[i][j] = mirror(R[6−i][6−j]) (NB↔PB …): R'(−E, −EC) must be exactly −R(E, EC)
    rules = CLASSIC_RULES.kp
    mirrored = tuple(tuple(MIRROR[rules[6 - i][6 - j]] for j in range(7)) for i in range(7))
    e, ec = random_points(6)
    a = evaluate(rules, e, ec, shape=shape, defuzz=defuzz)
    b = evaluate(mirrored, -e, -ec, shape=shape, defuzz=defuzz)
    assert_array_equal(b, -a)
    assert np.any(a != 0)


def test_property_helpers_detect_violations():
    qt = query_tables(CLASSIC_RULES)
    # classic is built for one direction: (NB, NB) → PB but (PB, PB) → NB for ΔKp
    assert not direction_independent(qt.kp)
    assert not direction_independent(CLASSIC_RULES.kp)
    # classic ΔKi at EC = 0 rises with E > 0 (ZO, PS, PS, PM)
    assert not nonincreasing_in_abs_e(qt.ki)
    q, _ = quantize_table(1.7 * qt.ki, f_max=20)
    assert not nonincreasing_in_abs_e(q)
    bad = check_default_properties(qt)
    assert "kp is not direction-independent" in bad
    assert "ki increases with |E| at EC = 0" in bad
    # int16 differences must not wrap: 32767 then −32767 is a decrease
    t = np.zeros((3, 3), dtype=np.int16)
    t[1, 1], t[2, 1], t[0, 1] = 32767, -32767, -32767
    assert not nondecreasing_in_abs_e(t)
    assert nonincreasing_in_abs_e(t)
    k1 = np.zeros((13, 13))
    k1[0, 0] = k1[12, 12] = 1.0
    assert "k1 is not constant" in check_default_properties({**qt.to_dict(), "k1": k1})


# --- validation ---------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [0, -1, 1.5, True, "6", None])
def test_invalid_n(n):
    with pytest.raises(SpecError, match="n must be an integer >= 1"):
        query_tables(DEFAULT_RULES, n=n)
    with pytest.raises(ValueError, match="n must"):
        evaluate(DEFAULT_RULES.kp, 0, 0, n=n)
    with pytest.raises(ValueError, match="n must"):
        input_peaks(n)


def test_n_one_works():
    qt = query_tables(DEFAULT_RULES, n=1)
    assert qt.kp.shape == (3, 3)
    assert check_default_properties(qt) == []


def test_invalid_options_and_inputs():
    with pytest.raises(SpecError, match="shape must be one of"):
        query_tables(DEFAULT_RULES, shape="trapezoid")
    with pytest.raises(SpecError, match="defuzz must be one of"):
        evaluate(DEFAULT_RULES, 0, 0, defuzz="mom")
    with pytest.raises(SpecError, match="e_level must be finite"):
        evaluate(DEFAULT_RULES.kp, np.nan, 0)
    with pytest.raises(SpecError, match="ec_level must be finite"):
        evaluate(DEFAULT_RULES.kp, 0, [0, np.inf])
    with pytest.raises(SpecError, match="rule_base must be a RuleBase"):
        query_tables(DEFAULT_RULES.kp)  # type: ignore[arg-type]


def test_invalid_rule_tables():
    six_rows = " | ".join(["ZO ZO ZO ZO ZO ZO ZO"] * 6)
    with pytest.raises(SpecError, match="kp must have 7 rows"):
        RuleBase(kp=six_rows, ki=uniform("ZO"), kd=uniform("ZO"))
    short = [list(r) for r in uniform("ZO")]
    short[4] = short[4][:6]
    with pytest.raises(SpecError, match=r"kd row 4 \(e = PS\) must have 7 entries"):
        RuleBase(kp=uniform("ZO"), ki=uniform("ZO"), kd=short)
    bad = [list(r) for r in uniform("ZO")]
    bad[2][3] = "XX"
    with pytest.raises(SpecError, match=r"ki\[2\]\[3\] \(e = NS, ec = ZO\) must be one of"):
        RuleBase(kp=uniform("ZO"), ki=bad, kd=uniform("ZO"))
    with pytest.raises(SpecError, match="k1"):
        RuleBase(kp=uniform("ZO"), ki=uniform("ZO"), kd=uniform("ZO"), k1=42)
    with pytest.raises(SpecError, match="rules"):
        evaluate("PB PB", 0, 0)
    with pytest.raises(SpecError, match="name must be"):
        RuleBase(kp=uniform("ZO"), ki=uniform("ZO"), kd=uniform("ZO"), name="")
    with pytest.raises(SpecError, match="table must be one of"):
        DEFAULT_RULES.table("kx")
