"""The Monte Carlo draws each mode of a resonant plant
(servotune.verify.variants.spread_parameters): its frequency in the wider of its 95 % interval and
±10 %, its damping in its 95 % interval, from a stream of its own, keyed by the draw's index; the
engine runs the drawn modes; a rigid rig and the other parameters draw as before
(docs/frf.md#the-resonant-plant-in-the-simulation)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from servotune.examples import example_path
from servotune.plant import (
    NPARAM,
    P_COULOMB,
    P_COULOMB_NEG,
    P_GAIN,
    P_GAIN_NEG,
    P_OFFSET,
    P_TAU,
    Plant,
)
from servotune.resonance import Mode
from servotune.rig import Rig, load_rig
from servotune.sim.engine import prepare_batch, run_batch, simulate
from servotune.tuning import read_tuning
from servotune.verify import load_spec, plant_variants, verify
from servotune.verify.montecarlo import SpecSpread
from servotune.verify.plant_sets import M_DAMPING, M_FREQ, ChunkPlants, mode_column
from servotune.verify.scenario_values import scenario_inputs
from servotune.verify.spec import MonteCarlo
from servotune.verify.variants import SPREAD_PARAMETERS, spread_parameters, spread_plants

ROOT = Path(__file__).resolve().parents[2]
TUNING = ROOT / "tests" / "corpus" / "base" / "tuning.json"  # a tuning of the example rig
F_COL, Z_COL = mode_column(0, M_FREQ), mode_column(0, M_DAMPING)
DRAWN = (P_GAIN, P_TAU, P_OFFSET, P_COULOMB, P_GAIN_NEG, P_COULOMB_NEG)


@pytest.fixture(scope="module")
def rigid() -> tuple[Rig, MonteCarlo]:
    rig = load_rig(example_path("pc-dual-servo.toml"))
    return rig, load_spec(example_path("pc-dual-servo.spec.toml")).montecarlo


@pytest.fixture(scope="module")
def belt() -> tuple[Rig, MonteCarlo]:
    """The belt rig (a 35 Hz mode on the master, damping 0.04, no intervals), 64 draws."""
    rig = load_rig(example_path("belt-axis.toml"))
    mc = load_spec(example_path("belt-axis.spec.toml")).montecarlo
    assert mc.count == 64
    return rig, mc


def with_master_modes(rig: Rig, *modes: Mode) -> Rig:
    """``rig`` with the master's plant carrying ``modes`` (none: rigid)."""
    axes = tuple(
        dataclasses.replace(a, plant=dataclasses.replace(a.plant, modes=modes))
        if a.name == "master"
        else a
        for a in rig.axes
    )
    return dataclasses.replace(rig, axes=axes)


def spans(x: np.ndarray, lo: float, hi: float) -> bool:
    """Whether every ``x`` is in [lo, hi], the least in its lowest 5 %, the largest in its top."""
    edge = 0.05 * (hi - lo)
    return bool(((x >= lo) & (x <= hi)).all() and x.min() < lo + edge and x.max() > hi - edge)


def test_a_rigid_rig_draws_as_before(rigid) -> None:
    rig, mc = rigid
    params = spread_parameters(rig, mc, mc.seed, 0, mc.count)
    assert np.isnan(params[..., NPARAM:]).all()  # no mode slots used
    variants = plant_variants(rig, mc)[1:]
    for v, row in zip(variants, params, strict=True):
        for p, x in zip(v.plants, row, strict=True):
            assert p.modes == ()
            got = (p.gain_cps_per_v, p.tau_s, p.offset_v, p.coulomb_v)
            assert got == tuple(x[[P_GAIN, P_TAU, P_OFFSET, P_COULOMB]])
    docs = [v.to_dict(rig.axis_names) for v in plant_variants(rig, mc)]
    assert all("modes" not in ax for d in docs for ax in d["plants"].values())
    spread = SpecSpread(rig=rig, montecarlo=mc)
    assert spread.parameters == tuple(f"{a}.{k}" for a in rig.axis_names for k in SPREAD_PARAMETERS)
    _, values = spread.draw_parameters(mc.seed, 0, mc.count)
    assert np.array_equal(values, params[:, :, :4].reshape(mc.count, 8))


def test_a_mode_without_intervals_draws_its_frequency_within_ten_percent(belt) -> None:
    rig, mc = belt
    variants = plant_variants(rig, mc)
    assert variants[0].plants[0].modes == rig.axis("master").plant.modes  # the nominal's own
    freqs = np.array([v.plants[0].modes[0].freq_hz for v in variants[1:]])
    assert ((freqs >= 31.5) & (freqs <= 38.5)).all()
    assert freqs.min() < 33.0 and freqs.max() > 37.0  # spread over the range
    assert {v.plants[0].modes[0].damping for v in variants} == {0.04}  # no interval: kept
    assert {v.plants[0].modes[0].gain for v in variants} == {0.5}  # the gain is not drawn
    assert all(v.plants[1].modes == () for v in variants)  # the slave stays rigid
    d = variants[1].to_dict(rig.axis_names)
    assert d["plants"]["master"]["modes"] == [{"freq_hz": freqs[0], "damping": 0.04}]
    assert "modes" not in d["plants"]["slave"]
    spread = SpecSpread(rig=rig, montecarlo=mc)
    assert "master.mode1_freq_hz" in spread.parameters
    assert "master.mode1_damping" not in spread.parameters  # not drawn: no interval
    _, values = spread.draw_parameters(mc.seed, 0, mc.count)
    assert np.array_equal(values[:, spread.parameters.index("master.mode1_freq_hz")], freqs)


@pytest.mark.parametrize(
    ("freq_95", "damping_95", "f_range", "z_range"),
    [
        ((30.0, 36.0), (0.02, 0.09), (30.0, 38.5), (0.02, 0.09)),  # wider below, ±10 % above
        ((28.0, 45.0), (-0.5, 1.5), (28.0, 45.0), (1e-4, 0.99)),  # damping kept inside (0, 1)
    ],
)
def test_a_mode_with_intervals_draws_in_the_wider_range(
    belt, freq_95, damping_95, f_range, z_range
) -> None:
    rig, mc = belt
    mode = Mode(freq_hz=35.0, damping=0.04, gain=0.5, freq_hz_95=freq_95, damping_95=damping_95)
    fitted = with_master_modes(rig, mode)
    params = spread_parameters(fitted, mc, mc.seed, 0, 256)
    f, z = params[:, 0, F_COL], params[:, 0, Z_COL]
    assert spans(f, *f_range) and spans(z, *z_range)
    assert ((z > 0) & (z < 1)).all()
    assert "master.mode1_damping" in SpecSpread(rig=fitted, montecarlo=mc).parameters
    # the drawn plants carry them
    plants = spread_plants(fitted, mc, mc.seed, 0, 4)
    assert [p[0].modes[0].freq_hz for p in plants] == list(f[:4])
    assert [p[0].modes[0].damping for p in plants] == list(z[:4])


def test_a_chunk_draws_the_modes_the_whole_run_draws(belt) -> None:
    rig, mc = belt
    whole = spread_parameters(rig, mc, 3, 0, 64)
    part = spread_parameters(rig, mc, 3, 10, 20)
    assert np.array_equal(part, whole[10:20], equal_nan=True)
    assert spread_plants(rig, mc, 3, 10, 20) == spread_plants(rig, mc, 3, 0, 64)[10:20]
    spread = SpecSpread(rig=rig, montecarlo=mc)
    assert np.array_equal(
        spread.draw_parameters(3, 10, 20)[1], spread.draw_parameters(3, 0, 64)[1][10:20]
    )
    # another seed draws other modes
    assert not np.array_equal(spread_parameters(rig, mc, 4, 0, 64)[:, 0, F_COL], whole[:, 0, F_COL])


def test_the_other_draws_do_not_change_with_the_modes(belt) -> None:
    rig, mc = belt
    with_modes = spread_parameters(rig, mc, mc.seed, 0, 200)
    without = spread_parameters(with_master_modes(rig), mc, mc.seed, 0, 200)
    assert np.array_equal(with_modes[..., :NPARAM], without[..., :NPARAM])
    assert np.isnan(without[..., NPARAM:]).all()
    # an axis the spec does not spread keeps its nominal mode
    slave_only = dataclasses.replace(mc, axes=("slave",))
    kept = spread_parameters(rig, slave_only, mc.seed, 0, 20)
    assert (kept[:, 0, F_COL] == 35.0).all() and (kept[:, 0, Z_COL] == 0.04).all()
    assert "master.mode1_freq_hz" not in SpecSpread(rig=rig, montecarlo=slave_only).parameters


def test_the_engine_runs_the_drawn_modes(belt) -> None:
    """One variant through the verify path (the chunk's parameter rows, and its plants in the
    general kernel) against ``simulate`` of a rig whose plants are written out with that
    variant's values and its mode: the same traces, and not the nominal mode's."""
    rig, mc = belt
    tuning = read_tuning(TUNING)
    spec = load_spec(example_path("belt-axis.spec.toml"))
    inputs = scenario_inputs(rig, spec.scenario("track"))
    i, seed, noise = 5, 11, 1234
    params, _ = SpecSpread(rig=rig, montecarlo=mc).draw_parameters(seed, i, i + 1)
    chunk = ChunkPlants(rig=rig, params=params)
    batch = prepare_batch(tuning.loop(rig), plants=chunk.plants(), seeds=[noise])
    pf, pi = chunk.rows()
    assert np.array_equal(pf, batch.pf) and np.array_equal(pi, batch.pi)  # rows = plants' rows
    traced = run_batch(batch, inputs, metrics_only=False, threads=1).traces
    assert traced is not None
    x = params[0]
    f, z = float(x[0, F_COL]), float(x[0, Z_COL])
    assert f != 35.0

    def written(p: Plant, row: np.ndarray, modes: tuple[Mode, ...]) -> Plant:
        return Plant(
            gain_cps_per_v=float(row[P_GAIN]),
            tau_s=float(row[P_TAU]),
            delay_s=p.delay_s,
            offset_v=float(row[P_OFFSET]),
            coulomb_v=float(row[P_COULOMB]),
            max_speed_rpm=p.max_speed_rpm,
            noise_counts=p.noise_counts,
            modes=modes,
        )

    def run(modes: tuple[Mode, ...]):
        plants = [written(a.plant, x[j], modes if j == 0 else ()) for j, a in enumerate(rig.axes)]
        axes = tuple(dataclasses.replace(a, plant=p) for a, p in zip(rig.axes, plants, strict=True))
        return simulate(tuning.loop(dataclasses.replace(rig, axes=axes)), inputs, seed=noise)

    tr = run((Mode(freq_hz=f, damping=z, gain=0.5),))
    for name in ("code", "counter", "pos_counts", "err_counts", "true_pos_counts", "speed_cps"):
        assert np.array_equal(getattr(tr, name), getattr(traced, name)[0]), name
    nominal = run(rig.axis("master").plant.modes)
    assert not np.array_equal(nominal.pos_counts, tr.pos_counts)  # the mode's draw shows


def test_a_verification_lists_and_ranks_the_drawn_modes(belt) -> None:
    """verify() on the belt rig: each variant's record lists its drawn mode, the worst list and
    the sensitivity table carry ``master.mode1_freq_hz``, whatever the chunking."""
    rig, mc = belt
    tuning = read_tuning(TUNING)
    spec = load_spec(example_path("belt-axis.spec.toml"))
    small = dataclasses.replace(
        spec, scenarios=(spec.scenario("sync"),), montecarlo=dataclasses.replace(mc, count=6)
    )
    one = verify(tuning, rig, small)
    doc = one.to_dict()
    params = spread_parameters(rig, small.montecarlo, small.montecarlo.seed, 0, 6)
    listed = [v["plants"]["master"]["modes"] for v in doc["variants"]]
    assert listed[0] == [{"freq_hz": 35.0, "damping": 0.04}]
    assert listed[1:] == [[{"freq_hz": float(r[0, F_COL]), "damping": 0.04}] for r in params]
    assert all("modes" not in v["plants"]["slave"] for v in doc["variants"])
    summary = one.montecarlo
    assert summary is not None
    assert all("master.mode1_freq_hz" in w.parameters for w in summary.worst)
    assert "master.mode1_freq_hz" in {s.parameter for s in summary.sensitivity}
    chunked = verify(tuning, rig, small, chunk_size=2)
    assert json.dumps(chunked.to_dict(), sort_keys=True) == json.dumps(doc, sort_keys=True)
