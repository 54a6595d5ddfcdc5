"""The closed-loop engine: equivalence with python-control, bit-truth, lock, modes, wraps."""

from __future__ import annotations

import dataclasses
import warnings
from functools import partial

import control
import numpy as np
import pytest
from conftest import ROOT, linear_one_axis, one_axis

import servotune as st
from servotune.fixed import F_U, round_half_away, shift_round
from servotune.laws.axis import (
    FLAG_COUNTER_FAULT,
    FLAG_FOLLOWING_ERROR,
    MODE_LOCK,
    MODE_TASK,
)
from servotune.laws.pi import pi_ideal_step, pi_step
from servotune.pipeline import default_pi_gains, lock_hold
from servotune.scenarios import trapezoid_ref


def _python_control_closed_loop(loop: st.Loop, lag_s: float, ref: np.ndarray) -> np.ndarray:
    """Closed loop built and simulated by python-control: ZOH plant, discrete PI, feedback."""
    rig = loop.rig
    period = rig.period_s
    pi = loop.controllers[0].task
    kp, kit = pi.kp.value, pi.ki_t.value
    # backward-Euler PI, as servotune.laws.pi: Kp + Ki·T·z/(z − 1)
    controller = control.ss(control.tf([kp + kit, -kp], [1.0, -1.0], dt=period))
    plant = st.discretize(rig.axes[0].plant, period, lag_s)
    closed = control.feedback(controller * rig.dac.lsb_v * plant, 1)
    t = np.arange(ref.size, dtype=np.int64) * period
    return control.forced_response(closed, T=t, U=ref.astype(float)).outputs


@pytest.mark.parametrize(
    ("compute_s", "delay_s"),
    [(0.0, 0.0), (0.0002, 0.0013), (0.0002, 0.0041)],  # none; fraction of a tick; > one tick
)
def test_ideal_loop_equals_python_control(rig: st.Rig, compute_s: float, delay_s: float) -> None:
    # acceptance: ideal PI, no quantisation/friction/noise: engine == python-control within
    # 1e-9 of max|y|. The acceptance case is compute_s = 0 and no delay; the lagged cases check the
    # fractional-delay discretisation the same way.
    r1 = linear_one_axis(rig, compute_s=compute_s, delay_s=delay_s)
    loop = st.Loop.from_rig(r1, [st.PIGains(kp=0.25, ki=0.8)])
    n = 1500
    ref = np.zeros(n, dtype=np.int64)
    ref[10:] = 1000
    ref[700:] = -2500
    inputs = st.Inputs.hold(n, 1).replace_axis(0, mode=MODE_TASK, ref_counts=ref)
    trace = st.simulate(loop, inputs, ideal=True)
    y_engine = trace.true_pos_counts[:, 0]
    y_pc = _python_control_closed_loop(loop, compute_s + delay_s, ref)
    scale = np.max(np.abs(y_engine))
    assert scale > 1000  # the loop really moved
    np.testing.assert_allclose(y_engine, y_pc, rtol=0, atol=1e-9 * scale)


def test_integer_pi_within_one_lsb_of_ideal() -> None:
    # acceptance: fed the same error sequence, the integer PI's codes stay within 1 LSB of the
    # ideal PI's rounded output (away from the rails, where only the integer PI has anti-windup)
    gains = st.PIGains(kp=0.731, ki=3.3)
    c = gains.quantize(0.004000235)
    rng = np.random.default_rng(7)
    e = rng.integers(-300, 301, size=20_000).astype(np.int64)
    integ_q, integ_f = 0, 0.0
    worst = 0
    for ek in e.tolist():
        u_q, integ_q = pi_step(c.kp.q, c.kp.f, c.ki_t.q, c.ki_t.f, integ_q, ek, 0, 2048, 4095)
        u_f, integ_f = pi_ideal_step(c.kp.value, c.ki_t.value, integ_f, float(ek))
        assert abs(u_f) < 2000, "sequence must stay off the rails for this comparison"
        code_int = shift_round(u_q, F_U) + 2048
        code_ideal = int(round_half_away(u_f)) + 2048
        worst = max(worst, abs(code_int - code_ideal))
    assert worst <= 1


def test_lock_holds_example_rig_within_one_pulse(rig: st.Rig) -> None:
    # acceptance (the PC rig's lock): the lock module (Kp = 0.4 codes/count) holds both axes within
    # ±1 pulse = ±4 counts for 60 s against the rig's drift, judged after the start transient
    # on the noiseless position
    res = lock_hold(rig, seconds=60.0, settle_s=2.0, seed=3)
    for name, (lo, hi) in res.observed.items():
        assert -4 <= lo <= hi <= 4, (name, lo, hi)
        plo, phi = res.predicted[name]
        assert abs(lo - plo) <= 1 and abs(hi - phi) <= 1, (name, (lo, hi), (plo, phi))
    # the drift really acts: without the lock output the axis would move by
    # 12288 counts/s/V * 5 mV * 60 s ≈ 3700 counts (example rig, master)
    assert rig.axis("master").plant.offset_v == pytest.approx(0.005)


@pytest.mark.parametrize("offset_mv", [-8.0, -3.0, 1.5, 4.0, 5.0, 6.5, 9.0])
def test_predicted_lock_band_matches_simulation(rig: st.Rig, offset_mv: float) -> None:
    # acceptance: the band `servotune rig` predicts (the quantised fixed point of
    # docs/runtime.md#position-lock-and-its-holding-band)
    # matches simulation within 1 count, for several drifts (friction-free, noiseless plant)
    r1 = one_axis(rig, offset_v=offset_mv * 1e-3, coulomb_v=0.0, noise_counts=0.0)
    res = lock_hold(r1, seconds=20.0, settle_s=3.0)
    lo, hi = res.observed["master"]
    plo, phi = res.predicted["master"]
    assert abs(lo - plo) <= 1 and abs(hi - phi) <= 1, ((lo, hi), (plo, phi))
    # below 4.88 mV within 2 counts, 4.88–9.77 mV within 4 counts
    bound = 2 if abs(offset_mv) < 4.8828125 else 4
    assert max(abs(plo), abs(phi)) <= bound


def test_mode_switches_are_bumpless(rig: st.Rig) -> None:
    # acceptance: lock → task → lock produce no step in the code sequence beyond the law's own
    r1 = one_axis(rig, noise_counts=0.0)
    gains = default_pi_gains(r1)
    loop = st.Loop.from_rig(r1, gains)
    n = 1500
    mode = np.full(n, MODE_LOCK, dtype=np.int64)
    k_in, k_out = 400, 1100
    mode[k_in:k_out] = MODE_TASK
    ref = np.zeros(n, dtype=np.int64)
    ref[k_in:] = 37  # the task reference differs from the lock target: a real error at entry
    inputs = st.Inputs.hold(n, 1).replace_axis(0, mode=mode, ref_counts=ref)
    tr = st.simulate(loop, inputs)
    code = tr.code[:, 0].astype(np.int64)
    # entering: the first task output equals the lock's last (I := u_lock − Kp·e)
    assert code[k_in] == code[k_in - 1]
    assert tr.err_counts[k_in, 0] != 0
    # leaving: the lock target latches at the position of the switch tick: zero lock error, so
    # the lock's own output 0 V; afterwards the lock holds near the task's end position
    assert tr.err_counts[k_out, 0] == 0
    assert code[k_out] == 2048
    hold = tr.pos_counts[k_out:, 0] - tr.pos_counts[k_out, 0]
    assert np.max(np.abs(hold)) <= 4
    # control: without the bumpless entry the first task code would differ by Kp·e
    kp = loop.controllers[0].task.kp.value
    assert abs(kp * tr.err_counts[k_in, 0]) >= 1.0


def test_ramp_wrapping_the_counter_many_times_is_tracked(rig: st.Rig) -> None:
    # acceptance: a rotary axis (travel limits off) ramping through many 24-bit wraps
    r1 = one_axis(rig, max_speed_rpm=None)
    ax = dataclasses.replace(r1.axes[0], travel_counts=None, speed_limit_rpm=600.0)
    r1 = dataclasses.replace(r1, axes=(ax,))
    loop = st.Loop.from_rig(r1, default_pi_gains(r1))
    speed_cps = 550 / 60 * r1.counts_per_rev
    n = int(5.5 * 2**24 / speed_cps / r1.period_s)  # about 5.5 wraps
    ref = trapezoid_ref(n + 10, r1.period_s, speed_cps * n * r1.period_s, speed_cps, 2e5)[:n]
    inputs = st.Inputs.hold(n, 1).replace_axis(0, mode=MODE_TASK, ref_counts=ref)
    tr = st.simulate(loop, inputs, seed=5)
    raw = tr.counter[:, 0]
    wraps = int(np.sum(np.diff(raw) < -(1 << 23)))
    assert wraps >= 5
    assert not np.any(tr.flags[:, 0] & (FLAG_COUNTER_FAULT | FLAG_FOLLOWING_ERROR))
    step = np.diff(tr.pos_counts[:, 0])
    assert np.max(np.abs(step)) <= 1.1 * speed_cps * r1.period_s + 2  # no jump at any wrap
    # unwrapped position agrees with the true plant position everywhere
    assert np.max(np.abs(tr.pos_counts[:, 0] - tr.true_pos_counts[:, 0])) < 3
    k_cruise = slice(n // 2, n)
    assert np.max(np.abs(tr.err_counts[k_cruise, 0])) < 50


def test_batch_equals_alone_bit_for_bit(rig: st.Rig) -> None:
    # acceptance: the same inputs give the same codes, run alone or in a batch
    loop = st.Loop.from_rig(rig, default_pi_gains(rig))
    scen = st.build_scenario(rig, "track", axis="master", seconds=2.0)
    base = [a.plant for a in rig.axes]
    variants = [
        tuple(
            dataclasses.replace(p, gain_cps_per_v=p.gain_cps_per_v * g, tau_s=p.tau_s * t)
            for p in base
        )
        for g, t in [(1.0, 1.0), (0.8, 1.3), (1.2, 0.7), (1.1, 1.1)]
    ]
    seeds = [11, 12, 13, 14]
    batch = st.prepare_batch(loop, plants=variants, seeds=seeds)
    res2 = st.run_batch(batch, scen.inputs, metrics_only=False, threads=2)
    res1 = st.run_batch(batch, scen.inputs, metrics_only=False, threads=1)
    np.testing.assert_array_equal(res2.traces.code, res1.traces.code)
    np.testing.assert_array_equal(res2.metrics.array, res1.metrics.array)
    for i, (plants, seed) in enumerate(zip(variants, seeds, strict=True)):
        alone = st.simulate(loop, scen.inputs, seed=seed, plants=plants)
        np.testing.assert_array_equal(alone.code, res2.traces.code[i])
        np.testing.assert_array_equal(alone.counter, res2.traces.counter[i])
    # the variants really differ
    assert not np.array_equal(res2.traces.code[0], res2.traces.code[1])


def test_metrics_only_agree_with_traces(rig: st.Rig) -> None:
    loop = st.Loop.from_rig(rig, default_pi_gains(rig))
    scen = st.build_scenario(rig, "track", axis="master", seconds=2.0)
    batch = st.prepare_batch(loop, n_candidates=2, seeds=3)
    res = st.run_batch(batch, scen.inputs, metrics_only=False)
    only = st.run_batch(batch, scen.inputs, metrics_only=True)
    np.testing.assert_array_equal(res.metrics.array, only.metrics.array)
    e = res.traces.err_counts[0, :, 0]
    task = res.traces.mode[0, :, 0] == MODE_TASK
    assert res.metric("max_abs_err_counts")[0, 0] == np.max(np.abs(e[task]))
    np.testing.assert_allclose(
        res.metric("rms_err_counts")[0, 0],
        np.sqrt(np.mean(e[task].astype(float) ** 2)),
        rtol=1e-12,
    )


def test_same_seed_same_bytes_other_seed_differs(rig: st.Rig) -> None:
    loop = st.Loop.from_rig(rig)
    inputs = st.Inputs.hold(2000, 2)
    a = st.simulate(loop, inputs, seed=1)
    b = st.simulate(loop, inputs, seed=1)
    c = st.simulate(loop, inputs, seed=2)
    assert a.code.tobytes() == b.code.tobytes()
    assert a.counter.tobytes() == b.counter.tobytes()
    assert a.counter.tobytes() != c.counter.tobytes()


def test_a_seed_outside_64_bits_is_refused_at_every_entry(rig: st.Rig, tmp_path) -> None:
    """A library caller's seed: an integer in 0..2**64 - 1 (a numpy integer too) or one
    ValueError naming the seed; numpy's own refusals named nothing ('expected non-negative
    integer') and a float was silently truncated (seed=1.5 ran as 1)."""
    from servotune.arch.gantry import compare_topologies
    from servotune.arch.gantry.load import load_gantry
    from servotune.arch.gantry.run import gantry_montecarlo
    from servotune.arch.gantry.synthesis import resolve_gains
    from servotune.pipeline import run_demo
    from servotune.tune.workflow import tune_rig
    from servotune.tuning import read_tuning
    from servotune.verify import load_spec, verify

    loop = st.Loop.from_rig(rig)
    inputs = st.Inputs.hold(50, 2)
    want = st.simulate(loop, inputs, seed=3).counter.tobytes()
    assert st.simulate(loop, inputs, seed=np.uint64(3)).counter.tobytes() == want
    gantry = resolve_gains(load_gantry(ROOT / "plants" / "gantry.toml"))
    tuning = read_tuning(ROOT / "tests" / "corpus" / "base" / "tuning.json")
    spec = load_spec(ROOT / "plants" / "pc-dual-servo.spec.toml")
    entries = [
        partial(st.simulate, loop, inputs),
        partial(verify, tuning, rig, spec),
        partial(tune_rig, ROOT / "plants" / "pc-dual-servo.toml"),
        partial(compare_topologies, gantry),
        partial(gantry_montecarlo, gantry, 2),
        partial(run_demo, ROOT / "plants" / "pc-dual-servo.toml", tmp_path),
    ]
    plants = [tuple(a.plant for a in rig.axes)] * 2
    refusal = r"seed must be an integer in 0\.\.18446744073709551615 \[-\], got "
    for bad in (-1, 2**64, 1.5, True, "3"):
        for entry in entries:
            with pytest.raises(ValueError, match=refusal):
                entry(seed=bad)
        with pytest.raises(ValueError, match=refusal):
            st.prepare_batch(loop, plants=plants, seeds=[0, bad])
    assert list(tmp_path.iterdir()) == []


def test_following_error_trip_latches_until_reset(rig: st.Rig) -> None:
    r1 = one_axis(rig, noise_counts=0.0)
    ax = dataclasses.replace(r1.axes[0], following_error_limit_counts=50)
    r1 = dataclasses.replace(r1, axes=(ax,))
    loop = st.Loop.from_rig(r1, default_pi_gains(r1))
    n = 600
    ref = np.zeros(n, dtype=np.int64)
    ref[100:] = 200  # a step bigger than the limit
    mode = np.full(n, MODE_TASK, dtype=np.int64)
    mode[400:] = MODE_LOCK  # the operator resets and leaves the task
    reset = np.zeros(n, dtype=bool)
    reset[400] = True
    inputs = st.Inputs.hold(n, 1).replace_axis(0, mode=mode, ref_counts=ref, reset=reset)
    tr = st.simulate(loop, inputs)
    f = tr.flags[:, 0]
    trip = int(np.argmax(f & FLAG_FOLLOWING_ERROR))
    assert trip == 100  # the first tick the error exceeds 50 counts
    assert np.all(tr.code[trip:400, 0] == 2048)  # latched at mid-scale (0 V)
    assert np.all(f[trip:400] & FLAG_FOLLOWING_ERROR)
    assert not np.any(f[400:] & FLAG_FOLLOWING_ERROR)  # cleared by the reset
    # after the reset the lock holds the axis where it stands
    assert np.all(tr.mode[400:, 0] == MODE_LOCK)
    assert np.max(np.abs(tr.pos_counts[400:, 0] - tr.pos_counts[400, 0])) <= 4


def test_non_latched_reads_tear_and_latched_do_not(rig: st.Rig) -> None:
    # a non-latched read lets the count move between byte reads: a carry into the middle byte
    # between the low and the middle read reads 256 counts off for that tick
    r1 = one_axis(rig, noise_counts=0.0, max_speed_rpm=None)
    ax = dataclasses.replace(r1.axes[0], following_error_limit_counts=0)
    torn_rig = dataclasses.replace(
        r1, axes=(ax,), counter=dataclasses.replace(r1.counter, latched=False, read_skew_s=2e-4)
    )
    inputs = st.Inputs.hold(3000, 1).replace_axis(0, mode=2, dac_add_codes=800)
    latched = st.simulate(
        st.Loop.from_rig(dataclasses.replace(torn_rig, counter=r1.counter)), inputs
    )
    torn = st.simulate(st.Loop.from_rig(torn_rig), inputs)
    d_latched = np.abs(latched.pos_counts[:, 0] - np.floor(latched.true_pos_counts[:, 0]))
    d_torn = np.abs(torn.pos_counts[:, 0] - np.floor(torn.true_pos_counts[:, 0]))
    assert d_latched.max() == 0
    assert d_torn.max() >= 200  # a byte carry missed


@pytest.mark.parametrize("lanes", [1, 3])
def test_lane_grouping_changes_no_result(
    rig: st.Rig, lanes: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # candidates are interleaved per thread (engine.LANES); 5 candidates leave a partial group
    import servotune.sim.engine as engine

    loop = st.Loop.from_rig(rig, default_pi_gains(rig))
    scen = st.build_scenario(rig, "track", axis="master", seconds=1.0)
    p = rig.axes[0].plant
    variants = [
        (dataclasses.replace(p, tau_s=p.tau_s * (1 + 0.1 * i)), rig.axes[1].plant) for i in range(5)
    ]
    batch = st.prepare_batch(loop, plants=variants, seeds=[3, 1, 4, 1, 5])
    ref = st.run_batch(batch, scen.inputs, metrics_only=False)
    monkeypatch.setattr(engine, "LANES", lanes)
    got = st.run_batch(batch, scen.inputs, metrics_only=False)
    for key in ("code", "counter", "flags"):
        np.testing.assert_array_equal(getattr(got.traces, key), getattr(ref.traces, key))
    np.testing.assert_array_equal(got.metrics.array, ref.metrics.array)


@pytest.mark.parametrize("latched", [True, False])
def test_one_axis_metrics_only_equal_traced_run(
    rig: st.Rig, latched: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    # one-axis metrics-only batches run in the lean kernel (engine._run_lean); its metrics must
    # equal those of the traced kernel (engine._run_group) bit for bit, over noise, friction,
    # the speed limit, lags of 0 and 1 whole ticks, every mode, a reset, a following-error
    # trip, excitation, load and the three task laws
    import servotune.sim.engine as engine
    from servotune.laws.axis import AxisController
    from servotune.laws.fuzzy_pid import FuzzyPIDGains
    from servotune.laws.pi import PIGains

    r1 = one_axis(rig)
    r1 = dataclasses.replace(
        r1, counter=dataclasses.replace(r1.counter, latched=latched, read_skew_s=2e-4)
    )
    p = r1.axes[0].plant
    lag1 = 1.3 * r1.period_s - r1.timer.compute_s  # compute + delay in [T, 2T): m = 1
    plants = [
        (p,),
        (dataclasses.replace(p, delay_s=lag1, gain_cps_per_v=0.8 * p.gain_cps_per_v),),
        (dataclasses.replace(p, noise_counts=0.0, coulomb_v=0.0, max_speed_rpm=None),),
        (dataclasses.replace(p, delay_s=lag1, tau_s=1.3 * p.tau_s),),
        (p,),
        (p,),
    ]
    size = 7
    gen = np.random.default_rng(5)
    fuzzy = FuzzyPIDGains(
        kp0=0.5,
        ki0=3.0,
        kd0=0.002,
        k10=0.0,
        ke=0.04,
        kec=0.4,
        n=3,
        dkp=gen.uniform(-0.2, 0.2, (size, size)),
        dki=gen.uniform(-1, 1, (size, size)),
    )

    def ctl(gains: object, fe_limit: int = 0) -> tuple[AxisController]:
        return (
            AxisController.from_gains(
                lock_gain_codes_per_count=r1.axes[0].lock_gain_codes_per_count,
                task_gains=gains,
                period_s=r1.period_s,
                following_error_limit_counts=fe_limit,
            ),
        )

    ctls = [
        ctl(PIGains(kp=0.5, ki=5.0)),
        ctl(PIGains(kp=0.3, ki=2.0)),
        ctl(PIGains(kp=0.5, ki=5.0)),
        ctl(fuzzy),
        ctl(None),  # lock only: task ticks run the lock
        ctl(PIGains(kp=0.5, ki=5.0), fe_limit=300),  # trips on the step, reset at tick 2200
    ]
    loop = st.Loop.from_rig(r1, [PIGains(kp=0.5, ki=5.0)])
    n = 3000
    ref = trapezoid_ref(n, r1.period_s, 40_000, 60_000.0, 400_000.0)
    ref[2500:] += 2_000  # a step
    mode = np.full(n, MODE_TASK, dtype=np.int64)
    mode[:200] = MODE_LOCK
    mode[1500:1700] = 2  # open loop
    mode[2200:2400] = MODE_LOCK  # after the reset
    reset = np.zeros(n, dtype=bool)
    reset[2200] = True
    u_add = np.zeros(n, dtype=np.int64)
    u_add[1500:1800] = 300
    load = np.zeros(n)
    load[1000:1300] = -0.05
    inputs = st.Inputs.hold(n, 1).replace_axis(
        0, mode=mode, ref_counts=ref, reset=reset, dac_add_codes=u_add, load_v=load
    )
    batch = st.prepare_batch(loop, plants=plants, controllers=ctls, seeds=[1, 2, 3, 4, 5, 6])
    assert batch.ring == 3  # lags of 0 and 1 whole ticks
    traced = st.run_batch(batch, inputs, metrics_only=False, metric_from_tick=150)

    def no_general_kernel(*args: object) -> None:
        raise AssertionError("a one-axis metrics-only batch must run in the lean kernel")

    monkeypatch.setattr(engine, "batch_kernel", no_general_kernel)
    for threads in (1, 2):
        lean = st.run_batch(batch, inputs, metrics_only=True, metric_from_tick=150, threads=threads)
        np.testing.assert_array_equal(lean.metrics.array, traced.metrics.array)
    # the scenario reaches what it is meant to: a trip, saturation, and a reset that clears it
    assert traced.metric("first_fault_tick")[5, 0] > 0
    assert traced.metric("saturated_ticks").max() > 0
    assert not np.any(traced.traces.flags[5, 2200:2400, 0] & FLAG_FOLLOWING_ERROR)


def test_a_kernel_that_cannot_compile_is_an_error_with_its_cause(
    rig: st.Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    # numba is used through its public API only, and a compile failure is not hidden behind a
    # slower fallback: run_batch raises CompileError naming the kernel, numba and the cause
    import numba

    import servotune.sim.engine as engine
    from servotune.errors import CompileError

    r1 = one_axis(rig)
    loop = st.Loop.from_rig(r1, [st.PIGains(kp=0.5, ki=5.0)])
    n = 200
    inputs = st.Inputs.hold(n, 1).replace_axis(0, mode=MODE_TASK, ref_counts=np.full(n, 100))
    batch = st.prepare_batch(loop, n_candidates=3, seeds=7)
    calls = []

    def refused(*args: object) -> None:
        calls.append(1)
        raise numba.core.errors.TypingError("no such internal")

    monkeypatch.setattr(engine, "kernel_lean", refused)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(CompileError, match=r"kernel refused .*numba .*no such internal"):
            st.run_batch(batch, inputs)
    assert calls == [1]
    # the general kernel is untouched
    assert np.all(np.isfinite(st.run_batch(batch, inputs, metrics_only=False).metrics.array))


def test_batch_metrics_are_named_and_round_trip_the_kernel_array() -> None:
    # BatchResult.metrics is a named object: each field is the kernel's column of that name
    from servotune.sim.result import BatchMetrics
    from servotune.sim.tick import METRIC_NAMES

    arr = np.arange(2 * 3 * len(METRIC_NAMES), dtype=float).reshape(2, 3, len(METRIC_NAMES))
    m = BatchMetrics.from_array(arr)
    np.testing.assert_array_equal(m.array, arr)
    np.testing.assert_array_equal(m.itae_counts_s2, arr[:, :, METRIC_NAMES.index("itae_counts_s2")])
    assert set(m.to_dict()) == set(METRIC_NAMES)
    res = st.BatchResult(metrics=m)
    np.testing.assert_array_equal(res.metric("task_ticks"), m.task_ticks)
    with pytest.raises(st.SimulationError, match="no metric 'nope'"):
        res.metric("nope")


def test_constants_wider_than_the_lean_frame_run_in_the_general_kernel(
    rig: st.Rig, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the lean kernel copies a candidate's constants into its frame (CONSTS_CAPACITY words);
    # wider ones (large fuzzy tables) take the general kernel, with the same metrics
    import servotune.sim.engine as engine

    r1 = one_axis(rig)
    loop = st.Loop.from_rig(r1, [st.PIGains(kp=0.5, ki=5.0)])
    n = 1500
    ref = trapezoid_ref(n, r1.period_s, 20_000, 40_000.0, 300_000.0)
    inputs = st.Inputs.hold(n, 1).replace_axis(0, mode=MODE_TASK, ref_counts=ref)
    batch = st.prepare_batch(loop, n_candidates=3, seeds=7)
    lean = st.run_batch(batch, inputs)
    calls = []
    monkeypatch.setattr(engine, "_run_lean_batch", lambda *a: calls.append(1))
    monkeypatch.setattr(engine, "CONSTS_CAPACITY", batch.consts.shape[2] - 1)
    general = st.run_batch(batch, inputs)
    assert calls == []
    np.testing.assert_array_equal(general.metrics.array, lean.metrics.array)
