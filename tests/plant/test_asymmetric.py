"""The asymmetric axis model (docs/formats.md#asymmetric-friction): gain and Coulomb friction per
direction.

Oracles, each independent of :func:`servotune.plant.advance`'s closed form:

- scipy ``solve_ivp`` (DOP853) of the continuous model, direction by direction, with a
  terminal event at zero speed; at the event the direction is chosen again from the net input
  (stick inside ``[-coulomb_neg, coulomb]``, else the way the input pushes);
- the steady speeds of an open-loop run, from the model equation itself:
  ``v = gain_d · (w − coulomb_d · d)``;
- the symmetric model's old bytes: :data:`OLD_SYMMETRIC_SHA256` is the SHA-256 of
  :func:`_symmetric_grid`'s outputs computed with ``advance`` as it was before the asymmetric
  model (commit d44257b), the demo digests of ``tests/test_pipeline.py`` pin the rest;
- engine paths against each other (general and lean kernel, ``simulate`` and ``run_batch``,
  the gantry's and the linkage's kernels against ``simulate``), and the C copy of the plant in
  ``bench/c_loop.c`` against the engine, D/A code for D/A code.
"""

from __future__ import annotations

import ctypes
import dataclasses
import importlib.util
import math
import shutil
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import control
import numpy as np
import pytest
from arch.gantry.test_cross_kernel import _engine_run, expressible  # noqa: F401  (fixture)
from arch.linkage.test_cross_kernel import _assert_ticks_equal, _engine, _one_cpu
from conftest import one_axis
from scipy.integrate import solve_ivp

import servotune as st
from servotune.arch.gantry import GantryAxis, GantryConfig, GantryTrace, simulate_gantry
from servotune.arch.gantry.load import load_gantry
from servotune.arch.gantry.synthesis import resolve_gains
from servotune.arch.linkage import run_linkage
from servotune.laws.axis import MODE_LOCK, MODE_OPEN, MODE_TASK
from servotune.modal import discretize
from servotune.plant import (
    R_COULOMB,
    R_COULOMB_NEG,
    R_GAIN,
    R_GAIN_NEG,
    R_LINEAR,
    Plant,
    advance,
    advance_span,
    advance_tick,
    plant_row,
    step_coefficients,
)
from servotune.scenarios import trapezoid_ref
from servotune.verify.spec import MonteCarlo
from servotune.verify.variants import plant_variants

ROOT = Path(__file__).resolve().parents[2]
GAIN, GAIN_NEG, TAU = 12288.0, 9000.0, 0.025
C_POS, C_NEG = 0.03, 0.08


def _asym(p: Plant, gain_ratio: float = 0.75, coulomb_ratio: float = 2.5) -> Plant:
    """``p`` with the negative direction's gain and Coulomb level scaled from the positive."""
    return dataclasses.replace(
        p,
        gain_neg_cps_per_v=p.gain_cps_per_v * gain_ratio,
        coulomb_neg_v=p.coulomb_v * coulomb_ratio,
    )


# --- advance against the continuous model ------------------------------------------------


def _reference(
    p: float, v: float, w: float, h: float, gains: tuple, coulombs: tuple, vmax: float
) -> tuple[float, float]:
    """The model integrated by scipy: one direction at a time, a terminal event at v = 0."""
    t = 0.0
    while t < h:
        if v == 0.0:
            if -coulombs[1] <= w <= coulombs[0]:
                return p, 0.0  # the input is constant: it stays stuck to the end
            d = 1.0 if w > 0.0 else -1.0
        else:
            d = math.copysign(1.0, v)
        g, c = (gains[0], coulombs[0]) if d > 0 else (gains[1], coulombs[1])
        vinf = min(max(g * (w - c * d), -vmax), vmax)

        def rhs(_t: float, x: np.ndarray, vinf: float = vinf) -> list[float]:
            return [x[1], (vinf - x[1]) / TAU]

        def stop(_t: float, x: np.ndarray) -> float:
            return x[1]

        stop.terminal = True  # type: ignore[attr-defined]
        stop.direction = -d  # type: ignore[attr-defined]  # only the speed falling to zero
        sol = solve_ivp(rhs, (t, h), [p, v], method="DOP853", rtol=1e-13, atol=1e-12, events=stop)
        if sol.status == 1:
            t, p, v = float(sol.t_events[0][0]), float(sol.y_events[0][0][0]), 0.0
        else:
            t, p, v = h, float(sol.y[0, -1]), float(sol.y[1, -1])
    return p, v


@pytest.mark.parametrize(
    ("v0", "w", "coulombs", "vmax", "h"),
    [
        (0.0, 0.5, (C_POS, C_NEG), math.inf, 0.1),  # breakaway forward: the positive gain
        (0.0, -0.5, (C_POS, C_NEG), math.inf, 0.1),  # breakaway backward: the negative one
        (900.0, 0.0, (C_POS, C_NEG), math.inf, 0.1),  # forward, brakes to a stop, sticks
        (-900.0, 0.0, (C_POS, C_NEG), math.inf, 0.1),  # backward, brakes to a stop, sticks
        (-900.0, 0.05, (C_POS, C_NEG), math.inf, 0.1),  # stops; 0.05 > C_POS: goes forward
        (2000.0, -0.5, (C_POS, C_NEG), math.inf, 0.1),  # forward, crosses, backward
        (-2000.0, 0.5, (C_POS, C_NEG), math.inf, 0.1),  # backward, crosses, forward
        (1500.0, -0.2, (0.0, 0.0), math.inf, 0.1),  # no friction: the gain switches at 0
        (1500.0, -0.2, (0.0, C_NEG), math.inf, 0.1),  # friction one way only
        (-1500.0, 0.01, (0.0, C_NEG), math.inf, 0.1),  # stops, then forward (no friction)
        (0.0, 2.0, (C_POS, C_NEG), 5000.0, 0.1),  # speed limit forward
        (0.0, -2.0, (C_POS, C_NEG), 5000.0, 0.1),  # speed limit backward (the same)
        (3000.0, -2.0, (C_POS, C_NEG), 5000.0, 0.1),  # crosses into the speed limit
        (2000.0, -0.5, (C_POS, C_NEG), math.inf, 0.004),  # decelerates, no crossing yet
        (-300.0, 0.4, (C_POS, C_NEG), math.inf, 0.004),  # crosses inside one tick
    ],
)
def test_advance_matches_the_continuous_model(
    v0: float, w: float, coulombs: tuple, vmax: float, h: float
) -> None:
    a, b = step_coefficients(h, TAU)
    got = advance(10.0, v0, w, h, a, b, GAIN, TAU, coulombs[0], vmax, GAIN_NEG, coulombs[1])
    want = _reference(10.0, v0, w, h, (GAIN, GAIN_NEG), coulombs, vmax)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-7)
    if want[1] == 0.0:
        assert got[1] == 0.0  # a stop is exact, not a small speed


def test_the_direction_decides_gain_and_friction() -> None:
    # the steady speed of each direction is its own: gain_d · (w − coulomb_d · d)
    h = 2.0  # 80 time constants: at the final speed to the last bit that matters
    a, b = step_coefficients(h, TAU)
    _, v_pos = advance(0.0, 0.0, 0.5, h, a, b, GAIN, TAU, C_POS, math.inf, GAIN_NEG, C_NEG)
    _, v_neg = advance(0.0, 0.0, -0.5, h, a, b, GAIN, TAU, C_POS, math.inf, GAIN_NEG, C_NEG)
    assert v_pos == pytest.approx(GAIN * (0.5 - C_POS), rel=1e-12)
    assert v_neg == pytest.approx(-GAIN_NEG * (0.5 - C_NEG), rel=1e-12)


def test_stiction_band_is_asymmetric() -> None:
    # at rest the motor stays at rest while -coulomb_neg <= w <= coulomb (the axis model, per way)
    a, b = step_coefficients(0.004, TAU)
    for w in (0.0, C_POS, -C_NEG, 0.02, -0.05, -0.079):
        got = advance(5.0, 0.0, w, 0.004, a, b, GAIN, TAU, C_POS, math.inf, GAIN_NEG, C_NEG)
        assert got == (5.0, 0.0), w
    for w in (C_POS + 1e-4, -C_NEG - 1e-4):
        p, v = advance(5.0, 0.0, w, 0.004, a, b, GAIN, TAU, C_POS, math.inf, GAIN_NEG, C_NEG)
        assert math.copysign(1.0, v) == math.copysign(1.0, w) and (p - 5.0) * w > 0


# --- symmetric: the old model, bit for bit --------------------------------------------------


def _symmetric_grid() -> tuple[np.ndarray, ...]:
    """Inputs of symmetric plants over every branch of ``advance``: at rest and moving, in and
    out of the stiction band, crossings, the speed limit, zero-length intervals."""
    rng = np.random.default_rng(20240917)
    n = 4000
    v0 = np.where(rng.uniform(size=n) < 0.3, 0.0, rng.uniform(-3000.0, 3000.0, n))
    w = np.where(rng.uniform(size=n) < 0.2, rng.uniform(-0.03, 0.03, n), rng.uniform(-1, 1, n))
    h = rng.choice(np.array([0.0, 0.0013, 0.004, 0.1]), n)
    coulomb = rng.choice(np.array([0.0, 0.02, 0.1]), n)
    vmax = rng.choice(np.array([math.inf, 4000.0]), n)
    return v0, w, h, coulomb, vmax


OLD_SYMMETRIC = Path(__file__).resolve().parent / "golden" / "symmetric_grid_d44257b.npy"
"""The float64 outputs (p, v per input) of :func:`_symmetric_grid` through
``advance(10, v0, w, h, a, b, 12288, 0.025, coulomb, vmax)`` as of commit d44257b (before the
asymmetric model), computed with that commit's ``servotune/plant.py`` (their SHA-256 was
75d2e2de…; ``np.save``, no pickle)."""

OLD_RTOL = 1e-12
"""The closed-form advance composes a handful of exp/expm1/log calls; two libms (or one libm's
code paths for two processors) differ by at most an ulp in each, so about 1e-15 relative in the
outputs: 1e-12 leaves a factor of 1000, while any change of the model moves them by far more."""


def _grid_outputs(step: Callable[..., tuple[float, float]]) -> np.ndarray:
    out = []
    for v0, w, h, c, vm in zip(*_symmetric_grid(), strict=True):
        a, b = step_coefficients(float(h), TAU)
        out.extend(step(float(v0), float(w), float(h), a, b, float(c), float(vm)))
    return np.array(out, dtype=np.float64)


def test_symmetric_by_none_is_the_old_model_bit_for_bit() -> None:
    by_none = _grid_outputs(
        lambda v0, w, h, a, b, c, vm: advance(10.0, v0, w, h, a, b, GAIN, TAU, c, vm)
    )
    explicit = _grid_outputs(
        lambda v0, w, h, a, b, c, vm: advance(10.0, v0, w, h, a, b, GAIN, TAU, c, vm, GAIN, c)
    )
    assert by_none.tobytes() == explicit.tobytes()  # one machine: the same bits
    # across machines: the old model's outputs within the libm's last bits
    np.testing.assert_allclose(by_none, np.load(OLD_SYMMETRIC), rtol=OLD_RTOL, atol=1e-12)


def test_symmetric_rows_are_the_old_rows(rig: st.Rig) -> None:
    for ax in rig.axes:
        p = ax.plant
        row, m = plant_row(p, rig.period_s, rig.timer.compute_s, rig.counts_per_rev)
        equal = dataclasses.replace(
            p, gain_neg_cps_per_v=p.gain_cps_per_v, coulomb_neg_v=p.coulomb_v
        )
        row_eq, m_eq = plant_row(equal, rig.period_s, rig.timer.compute_s, rig.counts_per_rev)
        assert m == m_eq and row.tobytes() == row_eq.tobytes()
        assert (row[R_GAIN_NEG], row[R_COULOMB_NEG]) == (row[R_GAIN], row[R_COULOMB])
    linear = Plant(gain_cps_per_v=GAIN, tau_s=TAU)
    assert plant_row(linear, 0.004)[0][R_LINEAR] == 1.0
    # any asymmetry, even without friction, leaves the linear one-tick map
    for asym in (
        dataclasses.replace(linear, gain_neg_cps_per_v=GAIN_NEG),
        dataclasses.replace(linear, coulomb_neg_v=C_NEG),
    ):
        assert plant_row(asym, 0.004)[0][R_LINEAR] == 0.0


# --- the row and the tick -----------------------------------------------------------------


def test_tick_and_span_use_the_row_directions() -> None:
    # advance_tick and advance_span on an asymmetric row are advance on the sub-intervals
    pl = Plant(
        gain_cps_per_v=GAIN,
        tau_s=TAU,
        delay_s=0.0013,
        coulomb_v=C_POS,
        gain_neg_cps_per_v=GAIN_NEG,
        coulomb_neg_v=C_NEG,
    )
    row, _ = plant_row(pl, 0.004)
    lam = 0.0013
    for v0, w_old, w_new in ((1500.0, 0.4, -0.6), (-1500.0, -0.3, 0.6), (0.0, -0.5, 0.5)):
        a1, b1 = step_coefficients(lam, TAU)
        a2, b2 = step_coefficients(0.004 - lam, TAU)
        p, v = advance(0.0, v0, w_old, lam, a1, b1, GAIN, TAU, C_POS, math.inf, GAIN_NEG, C_NEG)
        want = advance(
            p, v, w_new, 0.004 - lam, a2, b2, GAIN, TAU, C_POS, math.inf, GAIN_NEG, C_NEG
        )
        assert advance_tick(0.0, v0, w_old, w_new, row) == want
        np.testing.assert_allclose(
            advance_span(0.0, v0, w_old, w_new, lam, 0.004, row), want, rtol=1e-12, atol=1e-9
        )
        ref = _reference(0.0, v0, w_old, lam, (GAIN, GAIN_NEG), (C_POS, C_NEG), math.inf)
        t_new = _reference(*ref, w_new, 0.004 - lam, (GAIN, GAIN_NEG), (C_POS, C_NEG), math.inf)
        np.testing.assert_allclose(want, t_new, rtol=1e-9, atol=1e-7)


# --- the linear model and validation -------------------------------------------------------


def test_linear_model_uses_the_mean_gain() -> None:
    pl = Plant(gain_cps_per_v=GAIN, tau_s=TAU, gain_neg_cps_per_v=GAIN_NEG)
    assert pl.mean_gain_cps_per_v == 0.5 * (GAIN + GAIN_NEG)
    tf = pl.to_tf()
    assert float(np.squeeze(tf.num[0][0])) == 0.5 * (GAIN + GAIN_NEG)
    mean = Plant(gain_cps_per_v=0.5 * (GAIN + GAIN_NEG), tau_s=TAU)
    d_pl, d_mean = discretize(pl, 0.004, 0.001), discretize(mean, 0.004, 0.001)
    np.testing.assert_array_equal(d_pl.A, d_mean.A)
    np.testing.assert_array_equal(d_pl.B, d_mean.B)
    # symmetric: exactly the positive gain (no rounding through a mean)
    odd = Plant(gain_cps_per_v=12288.049999999999, tau_s=TAU)
    assert odd.mean_gain_cps_per_v == odd.gain_cps_per_v and odd.symmetric
    assert not pl.symmetric and pl.gains_cps_per_v == (GAIN, GAIN_NEG)
    assert Plant.from_tf(control.tf([GAIN], [TAU, 1.0, 0.0])).symmetric


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        (
            "gain_neg_cps_per_v",
            -9000.0,
            r"gain_neg_cps_per_v must be > 0 \[counts/s/V\], got -9000.0",
        ),
        ("gain_neg_cps_per_v", 0.0, r"gain_neg_cps_per_v must be > 0 \[counts/s/V\], got 0.0"),
        (
            "gain_neg_cps_per_v",
            math.nan,
            r"gain_neg_cps_per_v must be a finite number \[counts/s/V\], got nan",
        ),
        (
            "gain_neg_cps_per_v",
            math.inf,
            r"gain_neg_cps_per_v must be a finite number \[counts/s/V\], got inf",
        ),
        ("coulomb_neg_v", -0.01, r"coulomb_neg_v must be >= 0 \[V\], got -0.01"),
        ("coulomb_neg_v", math.inf, r"coulomb_neg_v must be a finite number \[V\], got inf"),
        ("coulomb_neg_v", "0.01", r"coulomb_neg_v must be a finite number \[V\], got '0.01'"),
    ],
)
def test_bad_direction_values_name_field_value_unit(
    field: str, value: object, message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        Plant(gain_cps_per_v=GAIN, tau_s=TAU, **{field: value})


def test_monte_carlo_variants_keep_the_asymmetry(rig: st.Rig) -> None:
    asym_rig = dataclasses.replace(
        rig, axes=(dataclasses.replace(rig.axes[0], plant=_asym(rig.axes[0].plant)), *rig.axes[1:])
    )
    mc = MonteCarlo(
        count=20, seed=3, gain_spread=0.2, tau_spread=0.1, offset_spread_v=0.002, coulomb_spread=0.5
    )
    sym = plant_variants(rig, mc)
    asym = plant_variants(asym_rig, mc)
    for vs, va in zip(sym, asym, strict=True):
        ps, pa = vs.plants[0], va.plants[0]
        # the same draws: the positive direction is the symmetric rig's variant, bit for bit
        assert (pa.gain_cps_per_v, pa.tau_s, pa.offset_v, pa.coulomb_v) == (
            ps.gain_cps_per_v,
            ps.tau_s,
            ps.offset_v,
            ps.coulomb_v,
        )
        # each direction spread by the same draw: the drive's ratio between them is kept
        assert pa.gain_neg_cps_per_v == pytest.approx(0.75 * pa.gain_cps_per_v, rel=1e-12)
        assert pa.coulomb_neg_v == pytest.approx(2.5 * pa.coulomb_v, rel=1e-12)
        # a symmetric plant stays symmetric, with nothing new in its record
        assert ps.gain_neg_cps_per_v is None and ps.coulomb_neg_v is None
        assert vs.plants[1] == va.plants[1]
        names = rig.axis_names
        d_s, d_a = vs.to_dict(names), va.to_dict(names)
        assert "gain_neg_cps_per_v" not in d_s["plants"][names[0]]
        assert d_a["plants"][names[0]]["coulomb_neg_v"] == pa.coulomb_neg_v
    assert len({v.plants[0].gain_neg_cps_per_v for v in asym}) == 21  # they vary


# --- the engine: every path, bit for bit -------------------------------------------------


@pytest.fixture(scope="module")
def asym_loop(rig: st.Rig) -> tuple[st.Loop, st.Inputs]:
    """One axis with an asymmetric plant (friction, noise, speed limit) and inputs that move
    it both ways: lock, a trapezoid out and back, a load, open-loop pushes each way."""
    r1 = one_axis(rig, coulomb_v=0.02)
    r1 = dataclasses.replace(
        r1, axes=(dataclasses.replace(r1.axes[0], plant=_asym(r1.axes[0].plant)),)
    )
    n = 4000
    ref = trapezoid_ref(n, r1.period_s, 30_000, 60_000.0, 400_000.0, start_tick=200)
    ref[2000:] -= trapezoid_ref(n - 2000, r1.period_s, 30_000, 60_000.0, 400_000.0)
    mode = np.full(n, MODE_TASK, dtype=np.int64)
    mode[:150] = MODE_LOCK
    mode[3300:3400] = MODE_OPEN  # a push each way
    u_add = np.zeros(n, dtype=np.int64)
    u_add[3300:3350] = 200
    u_add[3350:3400] = -200
    load = np.zeros(n)
    load[1200:1500] = -0.05
    inputs = st.Inputs.hold(n, 1).replace_axis(
        0, mode=mode, ref_counts=ref, dac_add_codes=u_add, load_v=load
    )
    return st.Loop.from_rig(r1, [st.PIGains(kp=0.5, ki=5.0)]), inputs


def test_engine_paths_agree_bit_for_bit_on_an_asymmetric_plant(
    asym_loop: tuple[st.Loop, st.Inputs], monkeypatch: pytest.MonkeyPatch
) -> None:
    import servotune.sim.engine as engine

    loop, inputs = asym_loop
    p = loop.rig.axes[0].plant
    sym = dataclasses.replace(p, gain_neg_cps_per_v=None, coulomb_neg_v=None)
    plants = [(p,), (sym,), (_asym(p, 1.3, 0.2),)]
    batch = st.prepare_batch(loop, plants=plants, seeds=[5, 5, 6])
    traced = st.run_batch(batch, inputs, metrics_only=False)
    for i, (pl, seed) in enumerate(zip(plants, [5, 5, 6], strict=True)):
        alone = st.simulate(loop, inputs, seed=seed, plants=pl)
        for key in ("code", "counter", "true_pos_counts", "speed_cps"):
            np.testing.assert_array_equal(getattr(alone, key), getattr(traced.traces, key)[i])

    def no_general_kernel(*args: object) -> None:
        raise AssertionError("a one-axis metrics-only batch must run in the lean kernel")

    monkeypatch.setattr(engine, "batch_kernel", no_general_kernel)
    lean = st.run_batch(batch, inputs, metrics_only=True, threads=2)
    np.testing.assert_array_equal(lean.metrics.array, traced.metrics.array)
    # the run crosses zero speed both ways, and the asymmetry changes it
    spd = traced.traces.speed_cps[0, :, 0]
    assert (spd > 1000).sum() > 100 and (spd < -1000).sum() > 100
    assert not np.array_equal(traced.traces.code[0], traced.traces.code[1])
    assert not np.array_equal(traced.traces.true_pos_counts[0], traced.traces.true_pos_counts[1])


def test_open_loop_steady_speeds_are_each_directions(rig: st.Rig) -> None:
    # open loop, ±1000 D/A codes held: the final speeds are gain_d · (w − coulomb_d · d)
    r1 = one_axis(rig, noise_counts=0.0, max_speed_rpm=None, coulomb_v=0.02, offset_v=0.0)
    r1 = dataclasses.replace(
        r1,
        axes=(
            dataclasses.replace(
                r1.axes[0], plant=_asym(r1.axes[0].plant), following_error_limit_counts=0
            ),
        ),
    )
    p = r1.axes[0].plant
    n = 200  # 0.8 s: 32 time constants
    for codes in (1000, -1000):
        inputs = st.Inputs.hold(n, 1).replace_axis(0, mode=MODE_OPEN, dac_add_codes=codes)
        tr = st.simulate(st.Loop.from_rig(r1), inputs)
        w = float(tr.volts[-1, 0]) + p.offset_v
        d = 1.0 if codes > 0 else -1.0
        g, c = (p.gain_cps_per_v, p.coulomb_v) if d > 0 else (p.gain_neg_cps_per_v, p.coulomb_neg_v)
        assert tr.speed_cps[-1, 0] == pytest.approx(g * (w - c * d), rel=1e-9)


# --- the gantry and the linkage -----------------------------------------------------------


@pytest.fixture(scope="module")
def asym_gantry(expressible: GantryConfig) -> GantryConfig:  # noqa: F811
    """The cross-kernel test's engine-expressible gantry, 20 s, both drives asymmetric."""
    g = expressible
    return dataclasses.replace(
        g,
        seconds=20_000 * g.bus.cycle_s,
        master=dataclasses.replace(g.master, plant=_asym(g.master.plant)),
        slave=dataclasses.replace(g.slave, plant=_asym(g.slave.plant, 1.2, 0.5)),
    )


@pytest.mark.parametrize("case", ["mismatch", "load"])
def test_gantry_with_asymmetric_drives_is_the_engines_bit_for_bit(
    asym_gantry: GantryConfig, case: str
) -> None:
    tr = simulate_gantry(asym_gantry, "parallel", case=case, seed=7)
    ref, _ = _engine_run(asym_gantry, case)
    for name, got, want in (
        ("code", tr.code, ref.code),
        ("position", tr.position, ref.true_pos_counts),
    ):
        bad = np.argwhere(got != want)
        assert bad.size == 0, f"{case}: {name} differs first at cycle, axis {bad[0].tolist()}"


def test_coupled_gantry_runs_the_asymmetric_model() -> None:
    g = resolve_gains(load_gantry(ROOT / "plants" / "gantry.toml"))
    g = dataclasses.replace(
        g,
        seconds=1.0,
        beam=dataclasses.replace(g.beam, stiffness_v_per_count=2e-3, damping_v_s_per_count=2e-5),
        move=dataclasses.replace(g.move, distance_counts=-g.move.distance_counts),  # backward
    )

    def drives(gain_ratio: float | None, coulomb_ratio: float | None) -> GantryTrace:
        def one(side: GantryAxis) -> GantryAxis:
            p = side.plant
            gn = None if gain_ratio is None else p.gain_cps_per_v * gain_ratio
            cn = None if coulomb_ratio is None else p.coulomb_v * coulomb_ratio
            plant = dataclasses.replace(p, gain_neg_cps_per_v=gn, coulomb_neg_v=cn)
            return dataclasses.replace(side, plant=plant)

        cfg = dataclasses.replace(g, master=one(g.master), slave=one(g.slave))
        return simulate_gantry(cfg, "listening", case="mismatch", seed=3)

    sym = drives(None, None)
    equal = drives(1.0, 1.0)
    asym = drives(0.7, 3.0)
    assert sym.code.tobytes() == equal.code.tobytes()
    assert sym.position.tobytes() == equal.position.tobytes()
    assert np.ptp(asym.position[:, 0]) > 10_000  # it moved
    assert not np.array_equal(asym.position, sym.position)
    assert not np.array_equal(asym.sync_error, sym.sync_error)


def test_linkage_with_asymmetric_axes_is_the_engines_bit_for_bit() -> None:
    n = 20_000
    base = _one_cpu(repeats=3)
    axes = tuple(
        dataclasses.replace(a, plant=_asym(a.plant, 0.8 + 0.1 * i, 2.0))
        for i, a in enumerate(base.axes)
    )
    cfg = dataclasses.replace(base, axes=axes)
    res = run_linkage(cfg, seconds=n * cfg.period_s, seed=11, trace=True)
    engine, _ = _engine(cfg, cfg.period_s, n)
    _assert_ticks_equal(res, engine, n)
    sym = run_linkage(base, seconds=n * cfg.period_s, seed=11, trace=True)
    assert res.traces is not None and sym.traces is not None
    assert not np.array_equal(res.traces[0].true_pos_counts, sym.traces[0].true_pos_counts)


# --- the C copy of the plant (bench/c_loop.c) ---------------------------------------------


def _bench_module() -> ModuleType:
    spec = importlib.util.spec_from_file_location("servotune_bench", ROOT / "bench" / "bench.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("servotune_bench", mod)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler (cc) on PATH")
@pytest.mark.parametrize(
    ("coulomb_v", "coulomb_neg_v"),
    [(0.0, 0.0), (0.0, 0.01), (0.02, 0.04)],  # the gains alone; friction one way; both ways
)
def test_c_plant_copy_is_the_engines_on_an_asymmetric_plant(
    coulomb_v: float, coulomb_neg_v: float
) -> None:
    # the bench's own loop runs a linear plant (the one-tick map): here the C advance itself
    bench = _bench_module()
    rig = bench.one_axis_rig()
    ax = rig.axes[0]
    plant = dataclasses.replace(
        ax.plant,
        gain_neg_cps_per_v=0.7 * ax.plant.gain_cps_per_v,
        coulomb_v=coulomb_v,
        coulomb_neg_v=coulomb_neg_v,
    )
    rig = dataclasses.replace(rig, axes=(dataclasses.replace(ax, plant=plant),))
    loop = st.Loop.from_rig(rig, [bench.PI_GAINS])
    n = 8000
    ref = np.ascontiguousarray(bench.reference_counts(n, rig.period_s), dtype=np.int64)
    inputs = st.Inputs.hold(n, 1).replace_axis(0, mode=MODE_TASK, ref_counts=ref)
    row, lag = plant_row(plant, rig.period_s, rig.timer.compute_s, rig.counts_per_rev)
    row = np.ascontiguousarray(row)
    assert row[R_LINEAR] == 0.0
    codes = np.zeros(n, dtype=np.int32)
    with tempfile.TemporaryDirectory(prefix="servotune-asym-") as tmp:
        lib = bench.build_c_loop(loop, Path(tmp))
        rc = lib.c_loop(
            n,
            row.ctypes.data_as(ctypes.POINTER(ctypes.c_double)),
            lag,
            ax.counter_init,
            rig.counter.bits,
            rig.dac.range_v[0],
            rig.dac.lsb_v,
            ref.ctypes.data,
            codes.ctypes.data,
        )
    assert rc == 0
    trace = st.simulate(loop, inputs, seed=0)
    bad = np.flatnonzero(codes != trace.code[:, 0])
    assert bad.size == 0, f"the C loop's code differs first at tick {bad[0]}"
    spd = trace.speed_cps[:, 0]
    assert (spd > 1000).any() and (spd < -1000).any()  # both directions
