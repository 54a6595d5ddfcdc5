"""The report's summary follows from the numbers: the verdict, the count of
failures, the tightest margin, the Monte-Carlo fraction and what to do next; swapping the
verdict swaps the sentences."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from report.conftest import EXAMPLE_SPEC, ReportBuild
from servotune.report.html import summary_section
from servotune.report.summary import margin_comment, next_step, pass_fraction_text, summarise
from servotune.verify.result import Check, Row, Verification
from servotune.verify.spec import load_spec


@pytest.fixture(scope="module")
def passed() -> Verification:
    rows = (
        Row(
            scenario="sync",
            quantity="max_sync_error_counts",
            axis="slave",
            unit="counts",
            limit=1843.0,
            worst=954.8,
            variant="mc12",
        ),
        Row(
            scenario="sync",
            quantity="overshoot_pct",
            axis="master",
            unit="%",
            limit=8.0,
            worst=7.6,
            variant="nominal",
        ),
        Row(
            scenario="sync",
            quantity="fault_runs",
            axis="slave",
            unit="runs",
            limit=0.0,
            worst=0.0,
            variant="nominal",
        ),
    )
    checks = (
        Check(
            name="margins:slave:task",
            passed=True,
            value=1.5,
            limit=2.0,
            unit="1",
            detail="worst slave task cell E=-4 EC=-6: Ms 1.50",
        ),
    )
    return Verification(
        spec=load_spec(EXAMPLE_SPEC),
        rig_name="pc-dual-servo",
        axis_names=("master", "slave"),
        seed=0,
        variants=(),
        rows=rows,
        checks=checks,
        variant_passed=(True,) * 9 + (False,),
    )


def _swap(v: Verification, **row_changes: float) -> Verification:
    """The same verification with the slave's sync-error row changed."""
    rows = tuple(
        dataclasses.replace(r, **row_changes) if r.quantity == "max_sync_error_counts" else r
        for r in v.rows
    )
    return dataclasses.replace(v, rows=rows)


def test_a_pass_says_export_and_names_the_tightest_limit(passed: Verification) -> None:
    s = summarise(passed, tuning_path="reports/tuning.json", rig_path="rig.toml")
    assert s.verdict == "PASSED" and (s.failed, s.total) == (0, 4)
    # the tightest: overshoot 7.6 of 8 % (5 % left), not the sync error (48 % left)
    assert s.tightest is not None and s.tightest.name == "sync: overshoot_pct of master"
    assert "7.6 % against a limit of 8 % (5 % left)" in s.tightest.describe()
    assert s.next_step.startswith(
        "Passed: export the verified tables with `servotune export-table reports/tuning.json "
        "-o fuzzy.json`"
    )
    assert "tightest limit: sync: overshoot_pct of master" in s.next_step  # within 10 %
    # Monte Carlo over the variants after the nominal one: 8 of 9
    assert s.montecarlo is not None and s.montecarlo[:2] == (8, 9)
    assert "8 of 9 plant variants keep every limit (88.9 %" in s.montecarlo_text()


@pytest.mark.parametrize(
    ("k", "n", "text"),
    [
        # the 100,000-plant-set verification of the example spec (2026-11-26): 3 failures
        (
            99_996,
            99_999,
            "99996 of 99999 plant variants keep every limit (99.997 %; 95 % "
            "interval 99.99–99.999 %",
        ),
        (
            99_999,
            99_999,
            "99999 of 99999 plant variants keep every limit (100.0 %; 95 % interval 99.996–100.0 %",
        ),
        (
            1,
            99_999,
            "1 of 99999 plant variants keep every limit (0.001 %; 95 % interval 0.00003–0.01 %",
        ),
        (63, 64, "63 of 64 plant variants keep every limit (98.4 %; 95 % interval 91.6–99.96 %"),
    ],
)
def test_a_share_below_one_never_reads_100_percent(k: int, n: int, text: str) -> None:
    """The sentence's shares: one decimal, more where one would print a share strictly between
    0 and 1 as 0.0 or 100.0 ("99996 of 99999 … (100.0 %)" was printed). Intervals from scipy's
    beta distribution (the Clopper–Pearson bounds are its 2.5 % and 97.5 % quantiles), not from
    the code under test."""
    from scipy.stats import beta

    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    assert pass_fraction_text((k, n, k / n, lo, hi)) == f"Monte Carlo: {text}, Clopper–Pearson)"


def test_swapping_the_verdict_swaps_the_sentence(passed: Verification) -> None:
    failed = _swap(passed, worst=2100.0)
    s = summarise(failed, tuning_path="tuning.json", rig_path="rig.toml", spec_path="my.spec.toml")
    assert s.verdict == "FAILED" and s.failed == 1
    # the failure that weighs most, with its numbers, and the knob that moves it
    assert s.next_step.startswith(
        "Failed: sync: max_sync_error_counts of slave is 2100 counts against a limit of 1843 "
        "counts (variant mc12). Next: the slave falls too far behind"
    )
    assert "`servotune tune rig.toml --spec my.spec.toml -o tuning.json --generations 80" in (
        s.next_step
    )
    assert s.tightest is not None and s.tightest.relative_margin < 0
    assert "(14 % over)" in s.tightest.describe()
    good = summarise(passed, tuning_path="tuning.json").next_step
    assert good != s.next_step and "export-table" not in s.next_step
    # the page's summary box turns with it
    page_pass = summary_section(summarise(passed))
    page_fail = summary_section(s)
    assert "Summary: PASSED" in page_pass and 'class="summary pass"' in page_pass
    assert "Summary: FAILED" in page_fail and 'class="summary fail"' in page_fail
    assert "<code>servotune tune rig.toml --spec my.spec.toml" in page_fail


def test_each_failing_quantity_names_its_own_knob(passed: Verification) -> None:
    base = passed.rows[0]
    knobs = {
        "overshoot_pct": "--pm 55",
        "settling_time_s": "--pm 55",
        "steady_lag_counts": "feedforward (K1)",
        "saturation_pct": "--max-saturation-pct",
        "holding_band_counts": "lock_gain_codes_per_count",
        "fault_runs": "following_error_limit_counts",
    }
    said = set()
    for quantity, knob in knobs.items():
        bad = dataclasses.replace(base, quantity=quantity, worst=base.limit * 2 + 1)
        v = dataclasses.replace(passed, rows=(bad,))
        text = next_step(v, tuning_path="t.json", rig_path="r.toml")
        assert knob in text, (quantity, text)
        said.add(text)
    assert len(said) == len(knobs)
    # a failed check comes before the rows
    check = dataclasses.replace(passed.checks[0], passed=False, value=2.4)
    v = dataclasses.replace(_swap(passed, worst=2100.0), checks=(check,))
    text = next_step(v, tuning_path="t.json", rig_path="r.toml")
    assert (
        text.startswith("Failed: check margins:slave:task") and "servotune margins t.json" in text
    )
    assert "(1 more failure listed below.)" in text


def test_without_a_verification_the_report_says_verify() -> None:
    s = summarise(None, tuning_path="t.json")
    assert s.verdict == "NOT VERIFIED" and "`servotune verify t.json --spec" in s.next_step


def test_the_margin_comment_follows_the_numbers() -> None:
    def cells(pms: list[float]) -> list[SimpleNamespace]:
        return [SimpleNamespace(phase_margin_deg=pm, cell=(i - 1, 0)) for i, pm in enumerate(pms)]

    # a slave at 25° beside a master at 50°
    low = margin_comment(
        {"master": 50.0, "slave": 25.0},
        {"slave": cells([22.0, 25.0, 61.0])},
        min_phase_margin_deg=45.0,
    )
    assert "master 50°, slave 25°" in low and "centre cell" in low
    assert "lower than the master's" in low
    assert "from 22° (cell E=-1 EC=+0) to 61° (E=+1 EC=+0)" in low
    assert "2 of its cells are below the 45° limit" in low
    high = margin_comment(
        {"master": 55.0, "slave": 75.0},
        {"slave": cells([65.0, 75.0, 90.0])},
        min_phase_margin_deg=45.0,
    )
    assert "higher than the master's" in high and "Every cell keeps the 45° limit" in high
    assert margin_comment({"master": 55.0}, {}, min_phase_margin_deg=45.0) == ""


def test_the_page_leads_with_the_summary_and_embeds_everything(report_build: ReportBuild) -> None:
    page = report_build.path.read_text(encoding="utf-8")
    v = report_build.verification
    verdict = "PASSED" if v.passed else "FAILED"
    first = page.index("<section")
    box = "pass" if v.passed else "fail"
    assert page[first:].startswith(f'<section id="summary" class="summary {box}">')
    assert f"Summary: {verdict}" in page and "What to do next:" in page
    k, n = v.pass_fraction[:2]
    assert f"Monte Carlo: {k} of {n} plant variants keep every limit" in page
    # the numbers a user came for, with units
    for text in (
        "95 % interval",
        "Fit (MATLAB compare",
        "99.0 % on the whole log",
        "Kp [codes/count]",
        "PM [deg]",
        "Ms [1]",
        "Winner on the tuning objective: composite (fuzzy-PID + feedforward)",
        "The composite law wins on the objective",
        "ITAE (the tuning objective) [counts·s²]",
        "sync error master − slave (black)",
        "Phase margins in the table above",
        "queue level [setpoints]",
        "Over the plant set",
    ):
        assert text in page, text
    # one self-contained file: every image a data URI, nothing fetched
    srcs = re.findall(r'<img [^>]*src="([^"]*)"', page)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert not re.search(r'(src|href)="(?!data:|#)', page)
    # the numbers as data: the JSON block holds the summary the page shows
    block = re.search(
        r'<script type="application/json" id="servotune-data">(.*?)</script>', page, re.S
    )
    assert block is not None
    data = json.loads(block.group(1))
    assert data["summary"]["verdict"] == verdict and data["summary"]["total"] == (
        len(v.rows) + len(v.checks)
    )
    assert Path(report_build.out / "report.html") == report_build.path
