"""Fleet fits (``servotune fit LOGS --fleet``): generated fleets with planted
drifts, the table's two forms, bad logs, determinism, the baseline table, the CLI.

The logs are made the way the README's "Your own machine" makes one (``servotune excite
--kind multisine`` played by ``servotune simulate --input … --closed-loop``, the lock module
holding the axis), each machine with its own plant drawn around the example rig's master plant.
Each machine's spread is drawn from a counter-based generator keyed by (seed, machine index)
(docs/decisions.md#11-random-numbers), clipped at ±2.5 standard deviations (a production tolerance:
no machine is a true outlier unless planted). Drifts are planted in a machine's second log only:
friction up (``coulomb_v`` × 2.5), gain down (``gain_cps_per_v`` × 0.85), or both.

The 300-log fleet (150 machines × commissioning and now) is marked ``slow``
(docs/decisions.md#8-test-time: ``make test-slow``); a 24-machine fleet checks the rest in ``make
test``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest
from report.figures_check import axis_unit_problems

from servotune.cli import main
from servotune.errors import FleetTableError
from servotune.excite import design_excitation, excitation_inputs
from servotune.fleet import (
    DRIFT_K,
    OUTLIER_Z,
    FleetResult,
    FleetRow,
    chance_outlier_rate,
    fit_fleet,
    machine_and_date,
    read_fleet_table,
    robust_spread,
    robust_z,
    summarise_fleet,
    write_fleet_table,
)
from servotune.fleet.table import COLUMNS, parse_fleet_table
from servotune.identify.model import ALL_PARAMS
from servotune.logs import write_log
from servotune.pipeline import log_metadata, run_scenario, trace_log_columns
from servotune.plant import Plant
from servotune.rig import Rig, load_rig
from servotune.scenarios import Scenario

RIG = Path(__file__).resolve().parents[2] / "plants" / "pc-dual-servo.toml"
DATES = ("2024-03-01", "2025-03-01")  # commissioning, now
SECONDS = 8.0  # 2,000 ticks: every fit adequate, about 0.1 s each (6 s logs fail residual tests)
SPREAD_REL = {"gain_cps_per_v": 0.03, "tau_s": 0.06, "delay_s": 0.10, "coulomb_v": 0.12}
"""Machine-to-machine standard deviation, relative to the master plant [-]."""
OFFSET_SD_V = 0.002  # analog zero drift differs absolutely [V]
FRICTION_UP = {"coulomb_v": 2.5}
GAIN_DOWN = {"gain_cps_per_v": 0.85}
BOTH = {**FRICTION_UP, **GAIN_DOWN}


def master_rig() -> Rig:
    """The example rig with its master axis only (the slave would sit locked in every log)."""
    rig = load_rig(RIG)
    return dataclasses.replace(rig, axes=(rig.axis("master"),))


def machine_plant(base: Plant, seed: int, index: int) -> Plant:
    """Machine ``index``'s plant: ``base`` with each parameter drawn from its spread."""
    rng = np.random.Generator(np.random.Philox(key=np.array([seed, index], dtype=np.uint64)))
    t = np.clip(rng.standard_normal(5), -2.5, 2.5)
    kw = {
        p: getattr(base, p) * (1.0 + SPREAD_REL[p] * t[i])
        for i, p in enumerate(("gain_cps_per_v", "tau_s", "delay_s", "coulomb_v"))
    }
    return dataclasses.replace(base, offset_v=base.offset_v + OFFSET_SD_V * t[4], **kw)


def write_fleet_logs(
    out: Path,
    n_machines: int,
    *,
    seed: int = 22,
    drifts: Mapping[int, Mapping[str, float]] = (),  # type: ignore[assignment]
    dates: tuple[str, ...] = DATES,
    seconds: float = SECONDS,
) -> tuple[list[Path], dict[str, dict[str, float]]]:
    """Write ``n_machines × len(dates)`` closed-loop logs ``m<index>_<date>.csv`` into ``out``.

    ``drifts``: machine index → parameter → factor applied in its logs after the first date.
    Returns the paths and, per machine id, its true plant at the first date.
    """
    rig = master_rig()
    master = rig.axes[0]
    exc = design_excitation(rig, "master", "multisine", seconds, seed=1)  # one exc.csv for all
    inputs = excitation_inputs(rig, "master", exc.absolute_codes, closed_loop=True)
    scen = Scenario(name="input", axis="master", inputs=inputs)
    paths, truth = [], {}
    for i in range(n_machines):
        machine = f"m{i:03d}"
        plant = machine_plant(master.plant, seed, i)
        truth[machine] = {
            p: getattr(plant, p)
            for p in ("gain_cps_per_v", "tau_s", "delay_s", "offset_v", "coulomb_v")
        }
        for d, date in enumerate(dates):
            p = plant
            if d > 0 and i in drifts:
                p = dataclasses.replace(
                    plant, **{k: getattr(plant, k) * f for k, f in drifts[i].items()}
                )
            r = dataclasses.replace(rig, axes=(dataclasses.replace(master, plant=p),))
            noise_seed = i * len(dates) + d
            trace = run_scenario(r, scen, seed=noise_seed)
            meta = log_metadata(
                r,
                scenario="input",
                axis="master",
                closed_loop="true",
                seed=noise_seed,
                machine_id=machine,
                date=date,
            )
            path = out / f"{machine}_{date}.csv"
            write_log(
                path,
                period_s=r.period_s,
                metadata=meta,
                columns=trace_log_columns(trace, scen.inputs.dac_add_codes),
            )
            paths.append(path)
    return paths, truth


def flagged(result: FleetResult) -> dict[str, tuple[str, ...]]:
    return result.summary.drifted


# --- the big fleet: 300 logs, three planted drifts ------------------------------------------

BIG_MACHINES = 150
BIG_DRIFTS = {17: FRICTION_UP, 58: GAIN_DOWN, 121: BOTH}


@pytest.fixture(scope="module")
def big_fleet(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[Path], FleetResult, float]:
    d = tmp_path_factory.mktemp("fleet300")
    paths, _ = write_fleet_logs(d, BIG_MACHINES, drifts=BIG_DRIFTS)
    t0 = time.perf_counter()
    result = fit_fleet(paths)
    return paths, result, time.perf_counter() - t0


@pytest.mark.slow
def test_300_log_fleet_flags_exactly_the_planted_drifts(
    big_fleet: tuple[list[Path], FleetResult, float],
) -> None:
    paths, result, seconds = big_fleet
    s = result.summary
    assert len(paths) == 300 and s.n_rows == 300 and s.n_failed == 0
    assert s.n_machines == BIG_MACHINES
    # the question, answered: these machines drifted, in these parameters, no others
    assert s.drifted == {
        "m017": ("coulomb_v",),
        "m058": ("gain_cps_per_v",),
        "m121": ("coulomb_v", "gain_cps_per_v"),
    }
    for d in s.drifts:
        assert d.before_date == DATES[0] and d.after_date == DATES[1]
        assert d.before_source == "run" and d.k > DRIFT_K
        # the fitted ratio: friction × 2.5 (+150 %), gain × 0.85 (−15 %); friction is the
        # less precise (its interval ±1.5 % on each fit of an 8 s log)
        np.testing.assert_allclose(d.after / d.before, BOTH[d.parameter], rtol=0.04)
    # the clipped spread plants no outlier: only the drifted machines' latest values stand out
    assert set(s.outlying) <= {"m017", "m058", "m121"}
    text = s.text()
    assert "machine m058 axis master: gain_cps_per_v fell 15." in text
    assert "machine m017 axis master: coulomb_v rose 1" in text
    # the rows carry the flags; the earlier logs of the drifted machines are not flagged
    by_file = {r.file: r for r in result.rows}
    assert by_file[f"m121_{DATES[1]}.csv"].drift == ("gain_cps_per_v", "coulomb_v")
    assert by_file[f"m121_{DATES[0]}.csv"].drift == ()
    # the time is reported, not asserted (benchmarks live in make bench: docs/scale.md)
    print(f"\n300 fits in-process: {seconds:.1f} s, {300 / seconds:.1f} fits/s")


@pytest.mark.slow
def test_300_log_fleet_spread_matches_the_drawn_one(
    big_fleet: tuple[list[Path], FleetResult, float],
) -> None:
    _, result, _ = big_fleet
    base = master_rig().axes[0].plant
    spread = {sp.parameter: sp for sp in result.summary.spreads}
    assert set(spread) == {"gain_cps_per_v", "tau_s", "delay_s", "offset_v", "coulomb_v"}
    for p, rel in SPREAD_REL.items():  # a clipped normal: the robust spread is near its sd
        np.testing.assert_allclose(spread[p].median, getattr(base, p), rtol=rel / 3)
        np.testing.assert_allclose(spread[p].spread, rel * getattr(base, p), rtol=0.25)
    np.testing.assert_allclose(spread["offset_v"].spread, OFFSET_SD_V, rtol=0.25)


# --- a small fleet for the rest (make test) --------------------------------------------------

SMALL_MACHINES = 24
SMALL_DRIFTS = {5: BOTH}


@pytest.fixture(scope="module")
def small_logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Path]]:
    d = tmp_path_factory.mktemp("fleet")
    paths, _ = write_fleet_logs(d, SMALL_MACHINES, drifts=SMALL_DRIFTS)
    bad = d / "m900_2025-03-01.csv"  # a malformed log: a row with too few fields
    text = [
        line.replace("m000", "m900").replace(DATES[0], DATES[1])
        for line in paths[0].read_text().splitlines()
    ]
    bad.write_text("\n".join([*text[:40], "12,0.048", *text[41:60]]) + "\n")
    empty = d / "m901_2025-03-01.csv"
    empty.write_text("")
    return d, [*paths, bad, empty]


@pytest.fixture(scope="module")
def small_fleet(small_logs: tuple[Path, list[Path]]) -> FleetResult:
    return fit_fleet(small_logs[1])


def test_small_fleet_flags_its_drift(small_fleet: FleetResult) -> None:
    s = small_fleet.summary
    assert s.drifted == {"m005": ("coulomb_v", "gain_cps_per_v")}
    assert s.n_machines == SMALL_MACHINES and s.n_rows == 2 * SMALL_MACHINES + 2


def test_bad_logs_are_rows_with_their_error(small_fleet: FleetResult) -> None:
    rows = {r.file: r for r in small_fleet.rows}
    bad, empty = rows["m900_2025-03-01.csv"], rows["m901_2025-03-01.csv"]
    for r in (bad, empty):
        assert not r.ok and r.params == {} and r.adequate is None
        assert "\n" not in r.error and r.error
        assert "/" not in r.error  # named by its file name, not the run's directory
    assert bad.machine_id == "m900" and bad.date == "2025-03-01"  # from its metadata
    assert "m900_2025-03-01.csv" in bad.error and "row 41 has 2 fields" in bad.error
    assert empty.machine_id == "m901"  # from the file name
    assert small_fleet.summary.n_failed == 2
    assert "failed (2; the table's error column)" in small_fleet.summary.text()
    ok = [r for r in small_fleet.rows if r.ok]
    assert len(ok) == 2 * SMALL_MACHINES and all(r.adequate for r in ok)


def test_rows_sorted_with_digest_and_metadata(
    small_fleet: FleetResult, small_logs: tuple[Path, list[Path]]
) -> None:
    import hashlib

    rows = small_fleet.rows
    assert [r.key for r in rows] == sorted(r.key for r in rows)
    by_file = {r.file: r for r in rows}
    for p in small_logs[1]:
        assert by_file[p.name].sha256 == hashlib.sha256(p.read_bytes()).hexdigest()
    r = by_file[f"m003_{DATES[0]}.csv"]
    assert (r.machine_id, r.date, r.axis, r.method) == ("m003", DATES[0], "master", "iv")
    assert set(r.ci95) == set(r.structure.split("+"))
    for p, (lo, hi) in r.ci95.items():
        assert lo < r.params[p] < hi


def test_csv_and_parquet_hold_the_same_table(small_fleet: FleetResult, tmp_path: Path) -> None:
    write_fleet_table(small_fleet, tmp_path / "f.csv")
    write_fleet_table(small_fleet, tmp_path / "f.parquet")
    a = read_fleet_table(tmp_path / "f.csv")
    b = read_fleet_table(tmp_path / "f.parquet")
    assert a == b == small_fleet.rows
    import pyarrow.parquet as pq

    t = pq.read_table(tmp_path / "f.parquet")
    assert t.column_names == [n for n, _ in COLUMNS] and t.num_rows == len(small_fleet.rows)
    assert t.schema.metadata[b"servotune.schema"] == b"servotune.fleet/1"


def test_same_input_same_bytes(
    small_logs: tuple[Path, list[Path]], small_fleet: FleetResult
) -> None:
    again = fit_fleet(list(reversed(small_logs[1])))  # another order, the same table
    for fmt in ("csv", "parquet"):
        assert again.table_bytes(fmt) == small_fleet.table_bytes(fmt)
    assert json.dumps(again.to_dict(), sort_keys=True) == json.dumps(
        small_fleet.to_dict(), sort_keys=True
    )


def test_baseline_table_gives_the_drift(
    small_logs: tuple[Path, list[Path]], small_fleet: FleetResult, tmp_path: Path
) -> None:
    _, paths = small_logs
    then = [p for p in paths if p.name.endswith(f"_{DATES[0]}.csv")]
    now = [p for p in paths if p.name.endswith(f"_{DATES[1]}.csv")]
    first = fit_fleet(then)
    assert first.summary.drifts == ()
    write_fleet_table(first, tmp_path / "commissioning.parquet")
    later = fit_fleet(now, baseline=tmp_path / "commissioning.parquet")
    assert later.summary.drifted == {"m005": ("coulomb_v", "gain_cps_per_v")}
    assert {dr.before_source for dr in later.summary.drifts} == {"baseline"}
    assert "(baseline table)" in later.summary.text()
    # without the baseline, one fit per machine: nothing to compare with
    assert summarise_fleet(later.rows).drifts == ()
    # a baseline holding the same files as the run adds nothing (same SHA-256: the same fit)
    write_fleet_table(small_fleet, tmp_path / "all.csv")
    again = summarise_fleet(small_fleet.rows, baseline=read_fleet_table(tmp_path / "all.csv"))
    assert again == dataclasses.replace(small_fleet.summary, n_baseline=len(small_fleet.rows))


def test_report_page(small_fleet: FleetResult, tmp_path: Path) -> None:
    from servotune.report.fleet import write_fleet_report

    page = write_fleet_report(small_fleet, tmp_path / "fleet.html").read_text()
    assert "data:image/png;base64," in page and "m005" in page and "Failed logs" in page
    from servotune.plot import plot_fleet

    fig = plot_fleet(small_fleet)
    try:  # every panel's axes labelled with a unit, as every figure of the reports
        assert len(fig.axes) == len(small_fleet.summary.spreads) == 5
        assert not axis_unit_problems(fig)
        assert {a.get_xlabel() for a in fig.axes} >= {"gain_cps_per_v [counts/s/V]"}
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


# --- the pieces ------------------------------------------------------------------------------


def test_robust_z_reference_values() -> None:
    # Iglewicz & Hoaglin (1993): M = 0.6745 (x − x̃) / MAD; here x̃ = 3, MAD = 1
    z = robust_z([1.0, 2.0, 3.0, 4.0, 100.0])
    np.testing.assert_allclose(z, 0.6745 * np.array([-2.0, -1.0, 0.0, 1.0, 97.0]), rtol=1e-12)
    med, mad, spread = robust_spread([5.0, 5.0, 5.0, 6.0, 9.0])  # MAD 0: mean |dev| · √(π/2)
    assert (med, mad) == (5.0, 0.0)
    np.testing.assert_allclose(spread, np.sqrt(np.pi / 2) * 1.0, rtol=1e-12)
    assert np.isnan(robust_z([2.0, 2.0, 2.0])).all()


def test_robust_z_of_rows_is_each_row_alone() -> None:
    rows = np.array([[1.0, 2.0, 3.0, 4.0, 100.0], [5.0, 5.0, 5.0, 6.0, 9.0], [2.0] * 5])
    got = robust_z(rows)
    for r, z in zip(rows, got, strict=True):
        np.testing.assert_array_equal(z, robust_z(r))


def test_chance_outlier_rate_against_independent_references() -> None:
    """The outlier rule's false-flag rate: for a large fleet, the normal tail beyond 3.5 on
    both sides (scipy's ``norm.sf``); for 5 machines, a loop of :func:`robust_spread` (the
    scalar path) over fleets drawn from another generator; smaller fleets flag more."""
    from scipy.stats import norm

    big = chance_outlier_rate(20_000)
    assert abs(big / (2.0 * norm.sf(OUTLIER_Z)) - 1.0) < 0.12, big  # 4.65e-4; ±3.3 % noise
    rng = np.random.Generator(np.random.MT19937(42))
    hits = total = 0
    for _ in range(40_000):
        x = rng.standard_normal(5)
        med, _, spread = robust_spread(x)
        hits += int((np.abs(x - med) / spread > OUTLIER_Z).sum())
        total += 5
    five = chance_outlier_rate(5)
    assert abs(five / (hits / total) - 1.0) < 0.08, (five, hits / total)  # ±2 % and ±1 % noise
    rates = [chance_outlier_rate(n) for n in (5, 10, 30, 150, 20_000)]
    assert rates == sorted(rates, reverse=True) and rates[0] > 50 * rates[-1]
    assert chance_outlier_rate(10) == chance_outlier_rate(10)  # seeded: the same every run
    with pytest.raises(ValueError, match="n_machines must be >= 3"):
        chance_outlier_rate(2)


def test_summary_states_the_outliers_chance_would_show(small_fleet: FleetResult) -> None:
    """The outlier line sets the count found beside the count a fleet of this size would show
    by chance: the sum over the judged parameters of machines × the rule's false-flag rate."""
    s = small_fleet.summary
    judged = [sp for sp in s.spreads if sp.spread > 0]
    assert s.judged_values == sum(sp.n_machines for sp in judged) > 0
    want = sum(sp.n_machines * chance_outlier_rate(sp.n_machines) for sp in judged)
    assert s.chance_outliers == pytest.approx(want, rel=1e-12)
    assert 0.1 < s.chance_outliers < 5.0  # a small fleet: far above 4.65e-4 per value
    line = next(ln for ln in s.text().splitlines() if ln.startswith("outliers against"))
    assert line.endswith(
        f"of {s.judged_values} values; a fleet of this size would show about "
        f"{s.chance_outliers:.2g} by chance alone (every parameter spread "
        "normally)"
    )
    # the figure follows the fleet's size: the same fits with fewer machines expect more per value
    fewer = summarise_fleet([r for r in small_fleet.rows if r.machine_id < "m010"])
    assert fewer.judged_values < s.judged_values
    assert (fewer.chance_outliers / fewer.judged_values) > (s.chance_outliers / s.judged_values)


def test_machine_and_date_rules() -> None:
    assert machine_and_date("a/m017_2025-03-01.csv", {}) == ("m017", "2025-03-01")
    assert machine_and_date("line-2_press_7_2025-03-01T08:00.csv", {}) == (
        "line-2_press_7",
        "2025-03-01T08:00",
    )
    assert machine_and_date("m017_after-repair.csv", {}) == ("m017", "")
    assert machine_and_date("gantry-7.csv", {}) == ("gantry-7", "")
    assert machine_and_date("x_2025-01-01.csv", {"machine_id": "G7", "date": "2024-12-31"}) == (
        "G7",
        "2024-12-31",
    )


def _row(machine: str, date: str, gain: float, half_width: float = 1.0) -> FleetRow:
    params = {
        "gain_cps_per_v": gain,
        "tau_s": 0.025,
        "delay_s": 0.0,
        "offset_v": 0.0,
        "coulomb_v": 0.0,
    }
    ci = {"gain_cps_per_v": (gain - half_width, gain + half_width), "tau_s": (0.0249, 0.0251)}
    return FleetRow(
        machine_id=machine,
        date=date,
        file=f"{machine}_{date}.csv",
        axis="master",
        sha256=f"{machine}{date}",
        params=params,
        ci95=ci,
        structure="gain_cps_per_v+tau_s",
        adequate=True,
    )


def test_drift_rule_needs_both_conditions() -> None:
    # a fleet of 40: gains 1000 + 10·i, MAD 100, spread = 100/0.6745 = 148 counts/s/V
    then = [_row(f"m{i}", "2024-01-01", 1000.0 + 10 * i) for i in range(40)]
    now = [_row(f"m{i}", "2025-01-01", 1000.0 + 10 * i) for i in range(40)]
    spread = 100.0 / 0.6745
    # m1: a change of 1.5 spreads with non-overlapping intervals: not enough
    now[1] = _row("m1", "2025-01-01", 1010.0 - 1.5 * spread)
    # m2: 3 spreads but wide intervals that overlap: estimation noise, not drift
    then[2] = _row("m2", "2024-01-01", 1020.0, half_width=2 * spread)
    now[2] = _row("m2", "2025-01-01", 1020.0 - 3 * spread, half_width=2 * spread)
    # m3: 3 spreads, intervals apart: drift
    now[3] = _row("m3", "2025-01-01", 1030.0 - 3 * spread)
    s = summarise_fleet(then + now)
    assert s.drifted == {"m3": ("gain_cps_per_v",)}
    (d,) = s.drifts
    (sp,) = [x for x in s.spreads if x.parameter == "gain_cps_per_v"]
    np.testing.assert_allclose(d.k, 3.0 * spread / sp.spread, rtol=1e-12)
    np.testing.assert_allclose(sp.spread, spread, rtol=0.1)  # three changed: a robust spread
    # the previous fit may come from a baseline table instead
    s2 = summarise_fleet(now, baseline=then)
    assert s2.drifted == {"m3": ("gain_cps_per_v",)} and s2.drifts[0].before_source == "baseline"
    # fewer than MIN_MACHINES machines: nothing flagged
    assert summarise_fleet(then[:4] + now[:4]).drifts == ()


def test_undated_logs_are_not_compared() -> None:
    rows = [_row(f"m{i}", "", 1000.0 + 10 * i) for i in range(6)]
    rows += [dataclasses.replace(_row("m0", "", 2000.0), file="m0_b.csv")]
    s = summarise_fleet(rows)
    assert s.drifts == () and s.n_undated == 7
    assert "not compared for drift" in s.text()


def test_table_refuses_other_files(tmp_path: Path) -> None:
    p = tmp_path / "x.csv"
    p.write_text("a,b\n1,2\n")
    with pytest.raises(FleetTableError, match="not a servotune fleet table"):
        read_fleet_table(p)
    p.write_text("# schema: servotune.fleet/0\nmachine_id\n")
    with pytest.raises(FleetTableError, match="re-run"):
        read_fleet_table(p)
    with pytest.raises(FleetTableError, match="not a Parquet file"):
        parse_fleet_table(b"PAR1 nonsense", "parquet", "y.parquet")
    with pytest.raises(FleetTableError, match=r"\.parquet or \.csv"):
        write_fleet_table([], tmp_path / "f.xlsx")


def test_error_row_for_a_missing_file(tmp_path: Path) -> None:
    r = fit_fleet([tmp_path / "m7_2025-01-01.csv"])
    (row,) = r.rows
    assert row.error == "cannot read 'm7_2025-01-01.csv': No such file or directory"
    assert row.to_record()["status"] == "error"
    assert all(row.to_record()[p] is None for p in ALL_PARAMS)


# --- the command line ------------------------------------------------------------------------


def _cli_logs(small_logs: tuple[Path, list[Path]]) -> list[str]:
    """Ten machines of the small fleet (m005 drifted) and its two bad logs."""
    return [str(p) for p in small_logs[1] if p.name[:4] < "m010" or p.name[:2] == "m9"]


def test_cli_fleet(
    small_logs: tuple[Path, list[Path]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    logs = _cli_logs(small_logs)
    out = tmp_path / "fleet.parquet"
    code = main(
        [
            "fit",
            *logs,
            "--fleet",
            str(out),
            "--axis",
            "master",
            "--json",
            "--fleet-report",
            str(tmp_path / "fleet.html"),
            "--workers",
            "1",
        ]
    )
    cap = capsys.readouterr()
    assert code == 0
    doc = json.loads(cap.out)  # --json: the summary on stdout (docs/decisions.md#10-output-streams)
    assert doc["schema"] == "servotune.fleet/1" and doc["summary"]["drifted"] == {
        "m005": ["coulomb_v", "gain_cps_per_v"]
    }
    assert len(doc["rows"]) == len(logs) == 22
    assert "drift since" not in cap.err and "fit fleet: 22/22 logs" in cap.err
    assert f"wrote the fleet table (22 rows) to {out}" in cap.err
    assert len(read_fleet_table(out)) == 22
    assert (tmp_path / "fleet.html").is_file()


def test_cli_fleet_baseline(
    small_logs: tuple[Path, list[Path]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    logs = _cli_logs(small_logs)
    then = [p for p in logs if p.endswith(f"_{DATES[0]}.csv")]
    now = [p for p in logs if p.endswith(f"_{DATES[1]}.csv")]
    assert main(["fit", *then, "--fleet", str(tmp_path / "then.csv")]) == 0
    assert (
        main(
            [
                "fit",
                *now,
                "--fleet",
                str(tmp_path / "now.csv"),
                "--baseline",
                str(tmp_path / "then.csv"),
            ]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert "machine m005 axis master: gain_cps_per_v fell 15." in err
    assert "machine m005 axis master: coulomb_v rose 1" in err
    assert "failed (2; the table's error column)" in err
    assert (
        main(
            [
                "fit",
                *now,
                "--fleet",
                str(tmp_path / "now2.csv"),
                "--previous",
                str(tmp_path / "then.csv"),
            ]
        )
        == 0
    )
    assert (tmp_path / "now.csv").read_bytes() == (tmp_path / "now2.csv").read_bytes()


def test_cli_usage_errors(
    small_logs: tuple[Path, list[Path]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, paths = small_logs
    assert main(["fit", str(paths[0]), str(paths[1])]) == 2
    assert "several logs need --fleet" in capsys.readouterr().err
    assert main(["fit", str(paths[0]), "--fleet", str(tmp_path / "f.xlsx")]) == 3
    assert ".parquet or .csv" in capsys.readouterr().err
    for extra in (["-o", str(tmp_path / "r.toml")], ["--plot", str(tmp_path / "f.png")]):
        assert main(["fit", str(paths[0]), "--fleet", str(tmp_path / "f.csv"), *extra]) == 2
        assert "not with --fleet" in capsys.readouterr().err
    assert main(["fit", str(paths[0]), "--baseline", str(tmp_path / "f.csv")]) == 2
    assert "--baseline needs --fleet" in capsys.readouterr().err
    assert not (tmp_path / "f.csv").exists()


@pytest.mark.slow
def test_local_cluster_gives_the_same_bytes(
    small_logs: tuple[Path, list[Path]], small_fleet: FleetResult
) -> None:
    from servotune.executor import open_executor

    with open_executor(len(small_logs[1]), workers=2) as ex:
        assert ex.name == "dask LocalCluster (2 workers)"
        on_cluster = fit_fleet(small_logs[1], executor=ex)
    assert on_cluster.executor != small_fleet.executor
    for fmt in ("csv", "parquet"):
        assert on_cluster.table_bytes(fmt) == small_fleet.table_bytes(fmt)


def _halsampler_capture(path: Path, seed: int, gain_cps_per_v: float, tau_s: float) -> None:
    """A halsampler capture (``pid.0.output encoder.0.position``, each value followed by a
    space) of ``tau·dv/dt + v = K·u`` driven by a random multilevel command [V] held for 5–40
    samples at 4 ms; the position exact at each sample (ZOH), floored to whole counts after
    0.3 count of noise, written in mm (2000 counts/mm)."""
    rng = np.random.Generator(np.random.Philox(key=np.array([seed, 0], dtype=np.uint64)))
    n, period = 3000, 0.004
    holds = np.repeat(rng.uniform(-4.0, 4.0, n), rng.integers(5, 40, n))[:n]
    a = np.exp(-period / tau_s)
    v = p = 0.0
    pos = np.empty(n)
    for k, u in enumerate(holds):
        pos[k] = p
        ku = gain_cps_per_v * u
        p += ku * period + (v - ku) * tau_s * (1.0 - a)
        v = ku + (v - ku) * a
    counts = np.floor(pos + rng.normal(0.0, 0.3, n))
    path.write_text("".join(f"{u:f} {c / 2000.0:f} \n" for u, c in zip(holds, counts, strict=True)))


def test_cli_fleet_of_hal_captures_with_one_map(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    gains = {"mill-a": 3000.0, "mill-b": 3300.0}
    for i, (name, gain) in enumerate(gains.items()):
        _halsampler_capture(tmp_path / f"{name}_2025-03-01.txt", i, gain, 0.05)
    logs = sorted(str(p) for p in tmp_path.glob("*.txt"))
    code = main(
        [
            "fit",
            *logs,
            "--fleet",
            str(tmp_path / "f.csv"),
            "--axis",
            "x",
            "--map",
            "cmd=pid.0.output,pos=encoder.0.position",
            "--hal-columns",
            "pid.0.output,encoder.0.position",
            "--period-s",
            "0.004",
            "--position-scale",
            "2000",
        ]
    )
    assert code == 0, capsys.readouterr().err
    rows = read_fleet_table(tmp_path / "f.csv")
    assert [(r.machine_id, r.date, r.axis) for r in rows] == [
        ("mill-a", "2025-03-01", "x"),
        ("mill-b", "2025-03-01", "x"),
    ]
    for r in rows:
        np.testing.assert_allclose(r.params["gain_cps_per_v"], gains[r.machine_id], rtol=0.02)
