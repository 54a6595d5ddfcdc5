"""The fleet's measured spread as a Monte-Carlo plant distribution.

Small fleets built from :class:`FleetRow` objects directly (no fitting): the draws are keyed by
(seed, draw index) whatever the chunking (docs/decisions.md#11-random-numbers), each draw is one
machine's fitted plant exactly, a machine counts by its latest adequate fit, errors are one line,
and ``servotune verify --plants-from`` runs on it, its record binding the table's bytes; the loop
margins are judged on every machine (checked against a loop built here with python-control).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import pickle
from pathlib import Path

import numpy as np
import pytest

from servotune.cli import main
from servotune.errors import SpecError
from servotune.fleet import (
    MIN_MACHINES,
    FleetRow,
    FleetSpread,
    fleet_spread,
    latest_fits,
    write_fleet_table,
)
from servotune.rig import Rig, load_rig

ROOT = Path(__file__).resolve().parents[2]
RIG = ROOT / "plants" / "pc-dual-servo.toml"


def _row(
    machine: str,
    date: str,
    gain: float,
    tau: float,
    *,
    axis: str = "slave",
    adequate: bool | None = True,
    error: str = "",
    **extra: float,
) -> FleetRow:
    params = {
        "gain_cps_per_v": gain,
        "tau_s": tau,
        "delay_s": 0.0012,
        "offset_v": -0.004,
        "coulomb_v": 0.0,
    } | extra
    return FleetRow(
        machine_id=machine,
        date=date,
        file=f"{machine}_{date}.csv",
        axis=axis,
        sha256=f"{machine}{date}",
        adequate=adequate,
        error=error,
        params={} if error else params,
    )


def _fleet(n: int = 6, axis: str = "slave") -> list[FleetRow]:
    """``n`` machines around the example rig's slave plant, one fit each."""
    return [
        _row(
            f"m{k:02d}",
            "2025-03-01",
            11700.0 * (0.95 + 0.02 * k),
            0.030 + 0.001 * k,
            axis=axis,
            coulomb_v=0.002 + 0.0001 * k,
        )
        for k in range(n)
    ]


@pytest.fixture(scope="module")
def rig() -> Rig:
    return load_rig(RIG)


def test_draws_are_the_same_for_any_chunking(rig) -> None:
    d = fleet_spread(_fleet(), rig, axis="slave")
    plants, values = d.draw(7, 0, 64)
    p1, v1 = d.draw(7, 0, 20)
    p2, v2 = d.draw(7, 20, 64)
    assert plants == p1 + p2
    np.testing.assert_array_equal(values, np.concatenate([v1, v2]))
    (p33,), v33 = d.draw(7, 33, 34)  # one draw alone, by its index
    assert p33 == plants[33] and np.array_equal(v33[0], values[33])
    assert len({p[1] for p in plants}) == 6  # 64 draws from 6 machines reach every one
    assert not np.array_equal(values, d.draw(8, 0, 64)[1])  # another seed, other draws
    empty, v0 = d.draw(7, 0, 0)  # what verify asks first
    assert empty == [] and v0.shape == (0, len(d.parameters))


def test_each_draw_is_one_machines_fit_exactly(rig) -> None:
    rows = _fleet()
    d = fleet_spread(rows, rig, axis="slave")
    assert d.parameters == (
        "slave.gain_cps_per_v",
        "slave.tau_s",
        "slave.delay_s",
        "slave.offset_v",
        "slave.coulomb_v",
    )
    assert d.machines == tuple(r.machine_id for r in rows)
    by_machine = {r.machine_id: r for r in rows}
    plants, values = d.draw(3, 0, 40)
    master = rig.axis("master").plant
    for (m_plant, s_plant), v in zip(plants, values, strict=True):
        assert m_plant == master  # the other axis keeps the rig's plant
        k = d.plants.index(s_plant)
        fit = by_machine[d.machines[k]].params
        assert v.tolist() == [fit[p.split(".")[1]] for p in d.parameters]  # bit for bit
        assert (
            s_plant.gain_cps_per_v,
            s_plant.tau_s,
            s_plant.delay_s,
            s_plant.offset_v,
            s_plant.coulomb_v,
        ) == tuple(v.tolist())
        assert s_plant.gain_neg_cps_per_v is None and s_plant.coulomb_neg_v is None
        slave = rig.axis("slave").plant  # the rig's speed limit and noise are kept
        assert (s_plant.max_speed_rpm, s_plant.noise_counts) == (
            slave.max_speed_rpm,
            slave.noise_counts,
        )


def test_a_left_out_term_is_zero_and_an_asymmetric_fit_draws_its_negative_side(rig) -> None:
    rows = _fleet()
    del rows[0].params["coulomb_v"]  # a term the fit left out (a table's empty cell)
    rows[1] = dataclasses.replace(
        rows[1], params=rows[1].params | {"gain_neg_cps_per_v": 11000.0, "coulomb_neg_v": 0.003}
    )
    d = fleet_spread(rows, rig, axis="slave")
    assert d.parameters[-2:] == ("slave.gain_neg_cps_per_v", "slave.coulomb_neg_v")
    assert d.plants[0].coulomb_v == 0.0 and d.values[0][4] == 0.0
    assert (d.plants[1].gain_neg_cps_per_v, d.plants[1].coulomb_neg_v) == (11000.0, 0.003)
    # a symmetric machine's negative side is its positive one (resolved, as the engine runs it)
    assert d.values[2][-2:] == (rows[2].params["gain_cps_per_v"], rows[2].params["coulomb_v"])
    assert d.plants[2].gain_neg_cps_per_v is None


def test_the_latest_adequate_fit_of_each_machine_is_used(rig) -> None:
    rows = _fleet()
    rows += [
        _row("m00", "2024-01-01", 9000.0, 0.05),  # older adequate fit: superseded
        _row("m00", "2025-06-01", 12500.0, 0.031),  # the latest adequate one: used
        _row("m00", "2025-09-01", 20000.0, 0.09, adequate=False),  # latest, inadequate
        _row("m00", "2025-10-01", 0.0, 0.0, error="cannot read"),  # latest, failed
        _row("m01", "", 30000.0, 0.2),  # undated: earlier than any dated fit
    ]
    latest = latest_fits(rows, adequate_only=True)
    assert latest[("slave", "m00")].date == "2025-06-01"
    assert latest[("slave", "m01")].date == "2025-03-01"
    assert latest_fits(rows)[("slave", "m00")].date == "2025-09-01"  # adequate or not
    d = fleet_spread(rows, rig, axis="slave")
    assert d.files[0] == "m00_2025-06-01.csv" and d.plants[0].gain_cps_per_v == 12500.0
    gains = set(d.draw(1, 0, 200)[1][:, 0].tolist())
    assert 12500.0 in gains and not gains & {9000.0, 20000.0, 30000.0}


def test_it_pickles_and_reads_a_fleet_table(rig, tmp_path) -> None:
    rows = _fleet()
    path = tmp_path / "fleet.parquet"
    write_fleet_table(rows, path)
    d = fleet_spread(path, rig, axis="slave")
    assert d.source.startswith("fleet.parquet sha256 ") and "fleet.parquet" in d.name
    assert d.name.startswith("fleet spread (6 machines") and d.name.endswith("axis slave)")
    again = pickle.loads(pickle.dumps(d))
    assert isinstance(again, FleetSpread) and again == d
    np.testing.assert_array_equal(again.draw(5, 10, 30)[1], d.draw(5, 10, 30)[1])
    assert d.values == fleet_spread(rows, rig, axis="slave").values


def test_a_fleet_of_unprefixed_logs_serves_the_named_axis(rig) -> None:
    d = fleet_spread(_fleet(axis=""), rig, axis="master")
    assert d.parameters[0] == "master.gain_cps_per_v" and len(d.machines) == 6
    assert d.draw(0, 0, 5)[0][0][1] == rig.axis("slave").plant


@pytest.mark.parametrize(
    ("rows", "axis", "words"),
    [
        (_fleet(), "spindle", "axis 'spindle' is not an axis of rig 'pc-dual-servo'"),
        (_fleet(MIN_MACHINES - 1), "slave", f"has {MIN_MACHINES - 1} machines with an adequate"),
        (_fleet(axis="master"), "slave", "has 0 machines with an adequate fit of axis 'slave'"),
        ([dataclasses.replace(r, adequate=False) for r in _fleet()], "slave", "has 0 machines"),
        ([*_fleet()[:-1], _row("m99", "2025-03-01", 11700.0, -0.01)], "slave", "machine 'm99'"),
    ],
    ids=["axis-not-in-rig", "too-few", "no-fit-of-axis", "none-adequate", "invalid-plant"],
)
def test_errors_are_one_line(rig, rows, axis, words) -> None:
    with pytest.raises(SpecError) as info:
        fleet_spread(rows, rig, axis=axis)
    msg = str(info.value)
    assert words in msg and "\n" not in msg


# --- servotune verify --plants-from ----------------------------------------------------------


@pytest.fixture(scope="module")
def bench(quick_workbench, default_tuning) -> dict[str, Path]:
    """The example rig's default tuning, a quick spec and a small fleet table of its slave."""
    bench = quick_workbench("fleet_spread", default_tuning)
    bench["fleet"] = bench["dir"] / "fleet.parquet"
    write_fleet_table(_fleet(), bench["fleet"])
    return bench


def test_verify_plants_from_a_fleet(bench, capsys) -> None:
    argv = [
        "verify",
        str(bench["tuning"]),
        "--spec",
        str(bench["spec"]),
        "--montecarlo",
        "6",
        "--plants-from",
        str(bench["fleet"]),
        "--plants-axis",
        "slave",
    ]
    code = main(argv)
    err = capsys.readouterr().err
    assert code in (0, 1) and "Traceback" not in err
    assert "fleet spread (6 machines of fleet.parquet" in err
    record = json.loads(Path(f"{bench['tuning']}.verify.json").read_text())
    mc = record["verification"]["montecarlo"]  # the record names the distribution
    assert mc["count"] == 6 and mc["distribution"].startswith("fleet spread (6 machines")
    # and binds the fleet table's exact bytes beside the tuning, rig and spec
    sha = hashlib.sha256(bench["fleet"].read_bytes()).hexdigest()
    assert record["files"]["fleet"] == {"name": "fleet.parquet", "sha256": sha}
    assert mc["distribution"].endswith(f"of fleet.parquet sha256 {sha[:12]}, axis slave)")
    assert set(record["files"]) == {"fleet", "rig", "spec", "tuning"}
    assert {s["parameter"] for s in mc["sensitivity"]} <= {
        f"slave.{p}" for p in ("gain_cps_per_v", "tau_s", "delay_s", "offset_v", "coulomb_v")
    }


def test_verify_plants_from_usage_and_bad_input(bench, capsys) -> None:
    base = ["verify", str(bench["tuning"]), "--spec", str(bench["spec"]), "--montecarlo", "2"]
    assert main([*base, "--plants-from", str(bench["fleet"])]) == 2
    assert "--plants-from FLEET and --plants-axis AXIS go together" in capsys.readouterr().err
    assert main([*base, "--plants-from", str(bench["fleet"]), "--plants-axis", "spindle"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'spindle' is not an axis of rig" in err[0]


def _lock_phase_margin(
    rig: Rig, kl: float, gain: float, tau: float, lag_s: float, period_s: float
) -> float:
    """The lock loop's phase margin [deg] built here from the textbook pieces, not from
    servotune's margins code: ``Kl·lsb·gain / (s (tau s + 1))`` behind a ``lag_s`` dead time
    (Padé, order 8), zero-order-hold discretised by python-control."""
    import control

    num, den = control.pade(lag_s, 8)
    p = control.tf([kl * rig.dac.lsb_v * gain], [tau, 1.0, 0.0]) * control.tf(num, den)
    loop = control.c2d(p, period_s, method="zoh")
    _, pm, _, _ = control.margin(loop)
    return float(pm)


@pytest.mark.filterwarnings("ignore:stability_margins:UserWarning")  # python-control's own
def test_margins_are_judged_on_every_machine_of_the_fleet(rig, default_tuning) -> None:
    """A machine whose measured slave gain is 3x the rig's breaks the slave's lock margins:
    the spec's corners (±20 % gain) do not reach it, the fleet's machines do."""
    from servotune.verify import load_spec
    from servotune.verify.run import check_margins

    spec = load_spec(RIG.with_name("pc-dual-servo.spec.toml"))
    rows = _fleet()
    rows[5] = _row("m05", "2025-03-01", 3.0 * 11700.0, 0.030, coulomb_v=0.002)

    def lock_check(distribution):
        checks = check_margins(default_tuning, rig, spec, distribution)
        return next(c for c in checks if c.name == "margins:slave:lock")

    assert lock_check(None).passed  # the spec's own plant cases
    assert lock_check(fleet_spread(_fleet(), rig, axis="slave")).passed  # a tight fleet
    bad = lock_check(fleet_spread(rows, rig, axis="slave"))
    assert not bad.passed and "on plant fleet m05" in bad.detail, bad.detail

    # the reported phase margin, against a loop built here for m05 at the case it names
    # (one tick late, the period at the timer's error limit)
    case = bad.facts["plant"]
    assert case == f"fleet m05+{spec.margin_extra_ticks}tick@+{spec.max_period_error_ppm:g}ppm"
    period = rig.period_s * (1.0 + spec.max_period_error_ppm * 1e-6)
    lag = rig.timer.compute_s + 0.0012 + spec.margin_extra_ticks * rig.period_s  # _row's delay
    kl = default_tuning.controller("slave").lock_gain.value  # the quantised gain it runs
    pm = _lock_phase_margin(rig, kl, 3.0 * 11700.0, 0.030, lag, period)
    assert pm < spec.margins.min_phase_margin_deg
    assert bad.facts["phase_margin_deg"] == pytest.approx(pm, abs=0.5), (bad.facts, pm)
