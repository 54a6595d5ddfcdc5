"""Identification on virtual-rig logs with known truth (quantisation, noise, drift, friction,
closed loop, counter wraps) — the acceptance tests of `servotune fit`."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest

import servotune as st
from servotune.identify import fit, fit_arrays
from servotune.logs import read_log, write_log
from servotune.pipeline import log_metadata, run_scenario, trace_log_columns

SEEDS = range(10)


def _rig_near_wrap(rig: st.Rig, **plant: float) -> st.Rig:
    """Example rig with the master's counter 16 counts below the wrap and plant changes."""
    m = rig.axis("master")
    m = dataclasses.replace(m, counter_init=2**24 - 16, plant=dataclasses.replace(m.plant, **plant))
    return dataclasses.replace(rig, axes=(m, rig.axis("slave")))


def _log(tmp_path: Path, rig: st.Rig, scenario: str, closed: bool, seed: int) -> Path:
    scen = st.build_scenario(rig, scenario, axis="master", seconds=40.0, closed_loop=closed)
    tr = run_scenario(rig, scen, seed=seed)
    path = tmp_path / f"{scenario}-{closed}-{seed}.csv"
    # as servotune simulate writes it: with the excitation (exc_code), so the default is iv
    write_log(
        path,
        period_s=rig.period_s,
        columns=trace_log_columns(tr, scen.inputs.dac_add_codes),
        metadata=log_metadata(rig, seed=seed),
    )
    return path


@pytest.mark.parametrize(("scenario", "closed"), [("steps", False), ("prbs", True)])
def test_fit_recovers_truth_over_ten_seeds(
    tmp_path: Path, rig: st.Rig, scenario: str, closed: bool
) -> None:
    # acceptance: gain and tau within 2 %, offset within 5 mV, Coulomb within 10 %,
    # delay within a quarter tick; open loop and closed loop (lock module active), the 24-bit
    # counter wrapping during the log, noise 0.3 counts, quantised encoder and D/A
    r = _rig_near_wrap(rig)
    truth = r.axis("master").plant
    for seed in SEEDS:
        path = _log(tmp_path, r, scenario, closed, seed)
        log = read_log(path)
        raw = log.axis("master").counter
        assert np.any(np.abs(np.diff(raw)) > 2**23), "the counter must wrap during the log"
        res = fit(log, axis="master")
        assert res.method == "iv", res.method_reason
        p = res.params
        assert p["gain_cps_per_v"] == pytest.approx(truth.gain_cps_per_v, rel=0.02), seed
        assert p["tau_s"] == pytest.approx(truth.tau_s, rel=0.02), seed
        assert abs(p["offset_v"] - truth.offset_v) < 0.005, seed
        assert p["coulomb_v"] == pytest.approx(truth.coulomb_v, rel=0.10), seed
        assert abs(p["delay_s"] - truth.delay_s) < r.period_s / 4, seed
        assert res.fit_pct["velocity"]["validation"] > 90


@pytest.mark.parametrize(
    ("delay_s", "offset_v", "coulomb_v"),
    list(itertools.product([0.0, 0.0008], [0.0, 0.005], [0.0, 0.002])),
)
def test_structure_selection_finds_the_true_structure(
    rig: st.Rig, delay_s: float, offset_v: float, coulomb_v: float
) -> None:
    # acceptance: on logs made with and without friction, offset and delay
    r = _rig_near_wrap(rig, delay_s=delay_s, offset_v=offset_v, coulomb_v=coulomb_v)
    scen = st.build_scenario(r, "prbs", axis="master", seconds=40.0, closed_loop=True)
    tr = run_scenario(r, scen, seed=11)
    res = fit_arrays(
        tr.volts[:, 0], tr.pos_counts[:, 0], period_s=r.period_s, compute_s=r.timer.compute_s
    )
    truth = {"delay_s": delay_s > 0, "offset_v": offset_v != 0, "coulomb_v": coulomb_v > 0}
    got = {k: k in res.structure for k in truth}
    assert got == truth, res.reason
    assert "BIC" in res.reason
    assert len(res.selection) == 8


def test_uncertainty_covers_truth_and_result_is_complete(rig: st.Rig) -> None:
    r = _rig_near_wrap(rig)
    truth = r.axis("master").plant
    scen = st.build_scenario(r, "steps", axis="master", seconds=40.0, closed_loop=True)
    tr = run_scenario(r, scen, seed=5)
    res = fit_arrays(
        tr.volts[:, 0], tr.pos_counts[:, 0], period_s=r.period_s, compute_s=r.timer.compute_s
    )
    d = res.to_dict()
    assert set(d) >= {"structure", "params", "std", "ci95", "fit_pct", "whiteness", "period_s"}
    for name in res.structure:
        lo, hi = res.ci95[name]
        assert lo < hi and res.std[name] > 0
    # the intervals are honest: the truth lies within 4 standard deviations
    for name in ("gain_cps_per_v", "tau_s"):
        assert abs(res.params[name] - getattr(truth, name)) < 4 * res.std[name] + 1e-12, name
    assert res.model.dt == 0 and res.discrete_model.dt == pytest.approx(r.period_s)
    assert res.plant.gain_cps_per_v == res.params["gain_cps_per_v"]


@pytest.mark.parametrize("period_s", [0.001, 0.02])
def test_other_sample_periods(rig: st.Rig, period_s: float) -> None:
    # 1 ms and 20 ms logs must work too
    timer = dataclasses.replace(rig.timer, period_s=period_s, compute_s=period_s / 20)
    r = dataclasses.replace(_rig_near_wrap(rig), timer=timer)
    truth = r.axis("master").plant
    scen = st.build_scenario(r, "steps", axis="master", seconds=60.0, closed_loop=True)
    tr = run_scenario(r, scen, seed=2)
    res = fit_arrays(
        tr.volts[:, 0], tr.pos_counts[:, 0], period_s=r.period_s, compute_s=r.timer.compute_s
    )
    assert res.params["gain_cps_per_v"] == pytest.approx(truth.gain_cps_per_v, rel=0.02)
    assert res.params["tau_s"] == pytest.approx(truth.tau_s, rel=0.05)


@pytest.mark.parametrize(
    ("cmd", "pos", "message"),
    [
        (np.zeros(500), np.arange(500), "constant"),
        (np.sin(np.arange(500)), np.zeros(500, dtype=np.int64), "never moved"),
        (np.sin(np.arange(50)), np.arange(50), "too short"),
    ],
)
def test_not_identifiable(cmd: np.ndarray, pos: np.ndarray, message: str) -> None:
    with pytest.raises(st.IdentificationError, match=message):
        fit_arrays(cmd, pos, period_s=0.004)


def test_structure_given_and_bad_structure(rig: st.Rig) -> None:
    r = _rig_near_wrap(rig)
    scen = st.build_scenario(r, "steps", axis="master", seconds=20.0, closed_loop=True)
    tr = run_scenario(r, scen, seed=1)
    res = fit_arrays(
        tr.volts[:, 0],
        tr.pos_counts[:, 0],
        period_s=r.period_s,
        structure="offset",
        compute_s=r.timer.compute_s,
    )
    assert res.structure == ("gain_cps_per_v", "tau_s", "offset_v")
    assert res.params["coulomb_v"] == 0.0 and res.selection == []
    with pytest.raises(st.IdentificationError, match="unknown structure parameter 'friction'"):
        fit_arrays(tr.volts[:, 0], tr.pos_counts[:, 0], period_s=r.period_s, structure="friction")
