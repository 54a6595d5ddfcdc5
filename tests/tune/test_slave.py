"""Slave tuning (servotune.tune.slave): improves on its start, reproducible, tunes what runs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import servotune as st
from servotune.errors import SpecError
from servotune.pipeline import default_pi_gains
from servotune.scenarios import sync_move
from servotune.sim.engine import Loop, simulate
from servotune.tune.slave import (
    SlaveTuneSpec,
    corner_plants,
    ideal_feedforward,
    tune_slave,
)
from servotune.tune.workflow import rule_tables

# small budget: the properties, not the optimum, are under test
# (the margin limits relaxed too, so that the loop-shaping start, designed for the nominal plant
# only, is feasible; the robust limits are tested in tests/tune/test_robust.py)
SMALL = SlaveTuneSpec(population=8, generations=4, max_overshoot_pct=200.0, seconds=1.6,
                      min_phase_margin_deg=20.0, min_gain_margin_db=3.0,
                      max_sensitivity=4.0)  # fmt: skip


@pytest.fixture(scope="module")
def tables() -> dict[str, np.ndarray]:
    return rule_tables("default")


@pytest.fixture(scope="module")
def composite(rig: st.Rig, tables: dict[str, np.ndarray]):
    g = default_pi_gains(rig)
    return tune_slave(rig, g[0], structure="composite", tables=tables, start=g[1], spec=SMALL)


def test_improves_on_its_start(composite) -> None:
    # the relaxed spec makes the start feasible, so the comparison is between two real ITAEs
    assert composite.feasible
    assert composite.start_feasible and np.isfinite(composite.start_objective)
    assert composite.objective < composite.start_objective
    # the best-so-far never gets worse from one generation to the next
    assert all(b <= a for a, b in zip(composite.history, composite.history[1:], strict=False))


def test_reproducible_by_seed(rig: st.Rig, tables, composite) -> None:
    g = default_pi_gains(rig)
    again = tune_slave(rig, g[0], structure="composite", tables=tables, start=g[1], spec=SMALL)
    assert again.to_dict() == composite.to_dict()
    other = tune_slave(
        rig, g[0], structure="composite", tables=tables, start=g[1], spec=SMALL, seed=5
    )
    assert other.to_dict()["gains"] != composite.to_dict()["gains"]


def test_objective_is_the_integer_loop_on_every_variant(rig: st.Rig, composite) -> None:
    # what is tuned is what runs: re-simulate the tuned law alone on each variant (same noise
    # seeds as the tuner) and recompute the ITAE of the sync error from the trace
    g = default_pi_gains(rig)
    loop = Loop.from_rig(rig, [g[0], composite.gains])
    scen = sync_move(rig, seconds=SMALL.seconds, load_step_v=SMALL.load_step_v)
    seeds = np.random.SeedSequence(0).generate_state(5, np.uint64)
    itaes = []
    for v, seed in zip(corner_plants(rig.axes[1].plant, 0.2, 0.3), seeds, strict=True):
        tr = simulate(loop, scen.inputs, seed=int(seed), plants=[rig.axes[0].plant, v])
        task = tr.mode[:, 1] == 1
        k = np.nonzero(task)[0]
        e = np.abs(tr.err_counts[task, 1].astype(float))
        itaes.append(float(np.sum(k * rig.period_s * e * rig.period_s)))
        assert not np.any(tr.flags[:, 1] & 3)
    np.testing.assert_allclose(np.mean(itaes), composite.objective, rtol=1e-9)


def test_pid_has_no_tables_and_no_feedforward(rig: st.Rig) -> None:
    g = default_pi_gains(rig)
    res = tune_slave(rig, g[0], structure="pid", start=g[1], spec=SMALL)
    assert res.gains.k10 == 0.0
    for t in ("dkp", "dki", "dkd", "dk1"):
        assert not np.any(getattr(res.gains, t))
    ff = tune_slave(rig, g[0], structure="pid_ff", start=g[1], spec=SMALL)
    assert ff.gains.k10 > 0.0 and not np.any(ff.gains.dkp)


def test_ideal_feedforward_units(rig: st.Rig) -> None:
    # 1 / (gain · LSB): codes per count/s; for 12,288 counts/s/V and 20/4096 V it is 1/60
    p = dataclasses.replace(rig.axes[0].plant, gain_cps_per_v=12288.0)
    assert ideal_feedforward(p, 20 / 4096) == pytest.approx(1 / 60, rel=1e-12)


def test_impossible_constraints_are_reported_infeasible(rig: st.Rig, tables) -> None:
    # Ms <= 1.001 is out of reach: by Bode's sensitivity integral (a stable loop with a delay,
    # as every loop here has, integrates ln|S| to >= 0 over frequency) |S| exceeds 1 somewhere
    # unless L = 0, and the search space's smallest gains (Kp0 >= start/5) keep it well above
    # 1.001. (Zero overshoot and saturation, the constraints this test used before, turned out
    # reachable by a sluggish slave once the search space was widened.)
    g = default_pi_gains(rig)
    spec = dataclasses.replace(SMALL, max_sensitivity=1.001)
    res = tune_slave(rig, g[0], structure="composite", tables=tables, start=g[1], spec=spec)
    assert not res.feasible and res.objective == float("inf")
    assert res.worst["max_sensitivity"] > 1.001


def test_bad_requests(rig: st.Rig) -> None:
    g = default_pi_gains(rig)
    with pytest.raises(SpecError, match="structure must be one of"):
        tune_slave(rig, g[0], structure="fuzzy", start=g[1])
    with pytest.raises(SpecError, match="needs query tables"):
        tune_slave(rig, g[0], structure="composite", start=g[1])
    with pytest.raises(SpecError, match="population must be"):
        SlaveTuneSpec(population=2)
    with pytest.raises(SpecError, match=r"max_saturation_pct must be a number in \[0, 100\]"):
        SlaveTuneSpec(max_saturation_pct=-1.0)
    with pytest.raises(SpecError, match="seconds must be a number > 0"):
        SlaveTuneSpec(seconds=float("nan"))
