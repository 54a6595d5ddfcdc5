"""Monte-Carlo over the gantry's drives: deterministic by seed, its interval
the exact binomial one (checked against scipy's ``binomtest``), a trip in a drawn pair fails the
check naming the pair, and the named pair trips when run on its own."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest
from scipy.stats import binomtest

from servotune.arch.gantry import CASES, compare_topologies, gantry_montecarlo, simulate_gantry
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.synthesis import resolve_gains
from servotune.cli import main
from servotune.cli.help_examples import EXAMPLES

ROOT = Path(__file__).resolve().parents[3]
GANTRY = ROOT / "plants" / "gantry.toml"


@pytest.fixture(scope="module")
def cfg():
    return resolve_gains(load_gantry(GANTRY))


def _tight(cfg):
    """A trip threshold between the nominal gantry's worst sync error (552 counts, mismatch,
    listening) and what drawn plants reach: the nominal passes, some drawn pairs trip."""
    return dataclasses.replace(cfg, sync=dataclasses.replace(cfg.sync, trip_counts=900))


def test_same_seed_same_result_and_draws_inside_the_spreads(cfg) -> None:
    a = gantry_montecarlo(cfg, 12, seed=3)
    assert a == gantry_montecarlo(cfg, 12, seed=3)
    assert a.variants != gantry_montecarlo(cfg, 12, seed=4).variants
    for v in a.variants:
        assert 0.8 <= v.factors["master_gain"] <= 1.2 and 0.7 <= v.factors["slave_tau"] <= 1.3
    with pytest.raises(ValueError, match="count must be an integer"):
        gantry_montecarlo(cfg, 0)


def test_pass_fraction_interval_is_the_exact_binomial_one(cfg) -> None:
    mc = gantry_montecarlo(_tight(cfg), 30, seed=0)
    k, n, frac, lo, hi = mc.pass_fraction
    assert n == 30 and 0 < k < n  # some pairs trip at the tight threshold, not all
    ref = binomtest(k, n).proportion_ci(confidence_level=0.95, method="exact")
    assert (lo, hi) == pytest.approx((ref.low, ref.high), abs=1e-9)
    assert frac == k / n and not mc.passed


def test_a_tripping_pair_fails_the_check_and_trips_on_its_own(cfg) -> None:
    tight = _tight(cfg)
    cmp = compare_topologies(tight, montecarlo=30)
    assert cmp.row("listening", "mismatch").tripped is False  # the nominal gantry passes
    assert not cmp.passed
    line = [f for f in cmp.failed if f.startswith("Monte Carlo:")]
    w = cmp.montecarlo.worst
    assert len(line) == 1 and f"first by size: {w.label}: master gain x" in line[0]
    # rebuild the named pair from its factors and run it: it trips
    f = w.factors
    plants = {}
    for name in ("master", "slave"):
        p = getattr(tight, name).plant
        plants[name] = dataclasses.replace(
            getattr(tight, name),
            plant=dataclasses.replace(
                p,
                gain_cps_per_v=p.gain_cps_per_v * f[f"{name}_gain"],
                tau_s=p.tau_s * f[f"{name}_tau"],
            ),
        )
    pair = dataclasses.replace(tight, **plants)
    assert any(simulate_gantry(pair, case=c, seed=1 + w.index).metrics().tripped for c in CASES)
    doc = cmp.to_dict()["montecarlo"]
    assert doc["count"] == 30 and doc["worst"]["label"] == w.label


def test_cli_sync_montecarlo(capsys) -> None:
    assert main(["sync", str(GANTRY), "--montecarlo", "8"]) == 0
    out = capsys.readouterr().out
    assert "Monte Carlo: 8 of 8 plant pairs never trip (100.0 %; 95 % interval 63.1–100.0 %" in out


def test_each_drive_draws_by_its_own_spread(cfg) -> None:
    wide = dataclasses.replace(cfg, slave=dataclasses.replace(cfg.slave, gain_spread=0.5))
    mc = gantry_montecarlo(wide, 40, seed=1)
    slave = [v.factors["slave_gain"] for v in mc.variants]
    master = [v.factors["master_gain"] for v in mc.variants]
    assert all(0.5 <= f <= 1.5 for f in slave) and max(abs(f - 1) for f in slave) > 0.3
    assert all(0.8 <= f <= 1.2 for f in master)


README = ROOT / "README.md"


def _number(text: str) -> float:
    """A README number: ``1,525`` → 1525, ``−15`` → -15."""
    return float(text.replace(",", "").replace("−", "-"))


def _readme_sync_command() -> list[str]:
    """The README's ``servotune sync … --montecarlo N`` reference line, as arguments."""
    m = re.search(
        r"^servotune (sync plants/gantry\.toml --montecarlo \d+)\s", README.read_text(), re.M
    )
    assert m is not None, "the README has no `servotune sync plants/gantry.toml --montecarlo N`"
    return m.group(1).split()


def test_the_readme_montecarlo_size_passes_as_the_readme_says(capsys) -> None:
    # the command as the README and `sync --help` write it, run on the example gantry
    words = _readme_sync_command()
    n = int(words[-1])
    help_line = next(e for e in EXAMPLES["sync"] if "--montecarlo" in e)
    assert f"--montecarlo {n} " in help_line + " "  # the help's example: the same size
    args = [str(GANTRY) if w == "plants/gantry.toml" else w for w in words]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert f"Monte Carlo: {n} of {n} plant pairs never trip" in out
    # the README's statement of that run: its count and its largest sync error
    said = re.search(
        r"On the example, ([\d,]+) pairs of ([\d,]+) pass \(95 % interval "
        r"([\d.]+)–100 %\); the largest sync error of\s+any pair is ([\d,]+) "
        r"counts against the ([\d,]+)-count trip",
        README.read_text(),
    )
    assert said is not None
    k, total, lo, largest, trip = (_number(g) for g in said.groups())
    assert k == total == n
    assert f"95 % interval {lo:.1f}–100.0 %" in out
    assert f"largest sync error {largest:.0f} counts" in out
    assert trip == resolve_gains(load_gantry(GANTRY)).sync.trip_counts


def test_the_readme_account_of_a_thousand_pairs(cfg) -> None:
    """At 1,000 pairs the README says which pair trips, by how much and where in the set."""
    text = " ".join(README.read_text().split())
    said = re.search(
        r"At ([\d,]+) pairs one pair trips \(([\d,]+) of ([\d,]+) pass, 95 % "
        r"interval ([\d.]+)–([\d.]+) %; `mc(\d+)`, ([\d,]+) counts\), near the "
        r"set's corner where the strong, fast master \(gain ([+−\d]+) %, tau "
        r"([+−\d]+) %\) meets the weakest, slowest slave \(gain ([+−\d]+) %, "
        r"tau ([+−\d]+) %\)",
        text,
    )
    assert said is not None
    n, k, n2, lo, hi, index, largest, mg, mt, sg, st = (_number(g) for g in said.groups())
    mc = gantry_montecarlo(cfg, int(n), seed=0)
    kk, nn, _, ci_lo, ci_hi = mc.pass_fraction
    assert (kk, nn) == (k, n2) == (n - 1, n)
    assert (round(100 * ci_lo, 1), round(100 * ci_hi, 3)) == (lo, hi)
    tripped = [v for v in mc.variants if v.tripped]
    assert [v.index for v in tripped] == [index] and mc.worst.label == f"mc{index:.0f}"
    assert round(mc.worst.max_sync_error_counts) == largest
    f = mc.worst.factors
    for key, pct in (
        ("master_gain", mg),
        ("master_tau", mt),
        ("slave_gain", sg),
        ("slave_tau", st),
    ):
        assert round(100 * (f[key] - 1)) == pct, key
