"""servotune.sim.lean_sync: the lean two-axis kernel against the traced path, bit for bit.

- every figure of :func:`servotune.verify.run._run_lean_sync` (the lean kernel) equals the traced
  path's (:func:`servotune.verify.scenario_values.evaluate` on the general kernel's traces) for the
  nominal plants and 64 noisy plant sets of the example spec's spread, ``sync``, ``track`` and
  ``lock`` (the holding band); and ``verify`` gives the same JSON with ``kernel="auto"`` (the
  lean kernel) and ``kernel="general"``;
- with noise on both axes, one or none (the draws' places in the stream);
- the approximated draws stay far inside the margin that makes them safe;
- :func:`pairwise_sum` has ``numpy.add.reduce``'s bits;
- :func:`servotune.plant.fill_plant_rows` (through :func:`plant_row` and in bulk) equals a
  plain-python reference written from the definitions in ``servotune/plant.py``;
- a plant set whose response is not finite is refused as the traced path refuses it.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numba
import numpy as np
import pytest

from servotune.plant import NPARAM, NROW, Plant, fill_plant_rows, plant_row
from servotune.rig import EXAMPLE_RIG_PATH, load_rig
from servotune.sim.engine import prepare_batch, run_batch
from servotune.sim.lean_sync import _NZ_MARGIN, N_FAST, _approx_draws, _noisy_floor, pairwise_sum
from servotune.sim.tick import normal
from servotune.verify import load_spec, verify
from servotune.verify import run as vrun
from servotune.verify.montecarlo import SpecSpread
from servotune.verify.scenario_values import evaluate, scenario_inputs
from servotune.verify.variants import seed_seqs

SPEC_PATH = EXAMPLE_RIG_PATH.with_name("pc-dual-servo.spec.toml")
N_DRAWS = 64


@pytest.fixture(scope="module")
def rig():
    return load_rig(EXAMPLE_RIG_PATH)


@pytest.fixture(scope="module")
def spec():
    return load_spec(SPEC_PATH)


def _shared(tuning, rig, spec, scenarios=("sync", "track")) -> vrun._Shared:
    runs = tuple((spec.scenario(s), scenario_inputs(rig, spec.scenario(s))) for s in scenarios)
    return vrun._Shared(
        rig=rig,
        loop=tuning.loop(rig),
        runs=runs,
        distribution=SpecSpread(rig=rig, montecarlo=spec.montecarlo),
        seed=spec.montecarlo.seed,
        threads=1,
    )


def _chunk(seed: int, n_draws: int) -> vrun._Chunk:
    """The nominal plants and draws mc1 … mc<n_draws>, with verify's noise seeds."""
    noise = seed_seqs(seed)[1].generate_state(n_draws + 1, np.uint64)
    return vrun._Chunk(start=0, stop=n_draws + 1, noise=noise)


def _traced(shared, sc, inputs, chunk_plants, chunk):
    """The traced path of :func:`servotune.verify.run._run_chunk`: values, faults and the
    traces' true position and speed."""
    batch = prepare_batch(
        shared.loop, plants=chunk_plants.plants(), seeds=[int(x) for x in chunk.noise]
    )
    res = run_batch(batch, inputs, metrics_only=False, threads=1)
    tr = res.traces
    assert tr is not None
    values, faults = evaluate(
        shared.rig,
        sc,
        inputs,
        {
            "counter": tr.counter,
            "pos_counts": tr.pos_counts,
            "err_counts": tr.err_counts,
            "flags": tr.flags,
            "true_pos_counts": tr.true_pos_counts,
        },
    )
    return values, faults, tr.true_pos_counts, tr.speed_cps


def _assert_bits_equal(lean: np.ndarray, traced: np.ndarray, what: str) -> None:
    """Equal as floats (``==``, NaN nowhere) and in sign (so also the same JSON)."""
    lean, traced = np.asarray(lean), np.asarray(traced)
    assert lean.shape == traced.shape, what
    assert not np.isnan(lean).any() and not np.isnan(traced).any(), what
    bad = np.flatnonzero((lean != traced) | (np.signbit(lean) != np.signbit(traced)))
    assert bad.size == 0, f"{what}: plant sets {bad.tolist()[:10]} differ: " + ", ".join(
        f"{lean[i]!r} != {traced[i]!r}" for i in bad[:5]
    )


TUNINGS = ["quick_tuning", "default_tuning"]  # one failing the spec's limits, one passing them


def _noisy_only(rig, noisy: str):
    """The rig with encoder noise on the axes ``noisy`` names (``both``, ``master``, ``slave``,
    ``none``): the lean kernel draws each tick's noise by its place in the stream, which
    depends on which axes draw."""
    if noisy == "both":
        return rig
    keep = {"master": {"master"}, "slave": {"slave"}, "none": set()}[noisy]
    return dataclasses.replace(
        rig,
        axes=tuple(
            a
            if a.name in keep
            else dataclasses.replace(a, plant=dataclasses.replace(a.plant, noise_counts=0.0))
            for a in rig.axes
        ),
    )


CASES = [(sc, t, "both") for sc in ("sync", "track", "lock") for t in TUNINGS] + [
    (sc, "default_tuning", noisy)
    for sc in ("sync", "lock")
    for noisy in ("master", "slave", "none")
]
QUANTITIES = {
    "move": {"overshoot_pct", "settling_time_s", "saturation_pct", "max_sync_error_counts",
             "rms_sync_error_counts", "steady_lag_counts"},
    "lock": {"holding_band_counts", "saturation_pct"},
}  # fmt: skip


@pytest.mark.parametrize(("scenario", "tuning", "noisy"), CASES)
def test_lean_figures_equal_traced(request, rig, spec, scenario, tuning, noisy) -> None:
    rig = _noisy_only(rig, noisy)
    assert sum(a.plant.noise_counts > 0 for a in rig.axes) == {"both": 2, "none": 0}.get(noisy, 1)
    shared = _shared(request.getfixturevalue(tuning), rig, spec, (scenario,))
    chunk = _chunk(shared.seed, N_DRAWS)
    sc, inputs = shared.runs[0]
    chunk_plants, _ = vrun._chunk_plants(chunk, shared)
    assert chunk_plants.params is not None  # the parameter-row path of a chunk
    pf, pi = chunk_plants.rows()
    assert vrun._lean_sync_ok(shared, sc, pi)
    seeds = np.asarray(chunk.noise, dtype=np.uint64)
    values, faults, fast = vrun._run_lean_sync(shared, sc, inputs, pf, pi, seeds)
    t_values, t_faults, true_pos, speed = _traced(shared, sc, inputs, chunk_plants, chunk)

    # the same quantities, every one of them bit for bit
    assert sorted(values) == sorted(t_values)
    assert {q for q, _ in values} == QUANTITIES["lock" if sc.kind == "lock" else "move"]
    for key in values:
        _assert_bits_equal(values[key], t_values[key], f"{scenario} {key}")
    assert sorted(faults) == sorted(t_faults)
    for name in faults:
        np.testing.assert_array_equal(faults[name], t_faults[name])

    # the fastest motion per plant set: largest |step| over one tick and |speed|, the first in
    # (tick, axis) order
    assert fast.shape == (N_DRAWS + 1, N_FAST)
    step = np.abs(np.diff(true_pos, axis=1)).reshape(N_DRAWS + 1, -1)
    spd = np.abs(speed).reshape(N_DRAWS + 1, -1)
    n_ax = true_pos.shape[2]
    for col, arr in ((0, step), (3, spd)):
        best = arr.argmax(axis=1)
        _assert_bits_equal(fast[:, col], arr.max(axis=1), f"{scenario} fast[{col}]")
        np.testing.assert_array_equal(fast[:, col + 1], best // n_ax)
        np.testing.assert_array_equal(fast[:, col + 2], best % n_ax)

    # the plant sets differ (the comparison is not one plant set 65 times), and the scenario
    # has a transient to measure (a hold: the drift pushes each axis off its target)
    assert np.unique(fast[:, 3]).size > N_DRAWS // 2
    if sc.kind == "lock":
        for name in ("master", "slave"):
            band = values[("holding_band_counts", name)]
            assert band.max() >= 2 and np.unique(band).size >= 2, (name, band)
    else:
        assert np.unique(values[("overshoot_pct", "slave")]).size > N_DRAWS // 2
        assert (values[("max_sync_error_counts", "slave")] > 0).all()


@pytest.mark.parametrize("tuning", TUNINGS)
def test_verify_same_json_lean_and_traced(request, rig, spec, tuning) -> None:
    """The shipped spec (sync, track, lock and the held-out sync scenario; 64 draws)."""
    tuning = request.getfixturevalue(tuning)
    assert spec.montecarlo.count == N_DRAWS
    assert {"sync", "track"} <= {sc.kind for sc in spec.scenarios}
    lean = verify(tuning, rig, spec)  # kernel="auto": the lean two-axis kernel
    traced = verify(tuning, rig, spec, kernel="general")
    assert lean.rows  # the runs were not skipped (overflow check passed)
    a = json.dumps(lean.to_dict(), sort_keys=True)
    b = json.dumps(traced.to_dict(), sort_keys=True)
    assert a == b


def test_verify_runs_the_lean_kernel(quick_tuning, rig, spec, monkeypatch) -> None:
    """The comparison above compares two paths: with ``kernel="auto"`` no scenario of the
    example spec (moves, the hold, the held-out move) reaches the traced engine; with
    ``kernel="general"`` every one does."""
    calls = []
    real = vrun.run_batch
    monkeypatch.setattr(vrun, "run_batch", lambda *a, **k: calls.append(1) or real(*a, **k))
    assert {s.kind for s in spec.scenarios} == {"sync", "track", "lock"}
    small = dataclasses.replace(spec, montecarlo=dataclasses.replace(spec.montecarlo, count=2))
    verify(quick_tuning, rig, small)
    assert calls == []
    verify(quick_tuning, rig, small, kernel="general")
    assert len(calls) >= len(spec.scenarios)  # at least a batch per scenario
    with pytest.raises(ValueError, match="kernel must be 'auto' or 'general'"):
        verify(quick_tuning, rig, small, kernel="lean")  # type: ignore[arg-type]


# --- pairwise_sum ----------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["normal", "wide", "squares", "cancelling"])
def test_pairwise_sum_is_numpys(kind) -> None:
    rng = np.random.default_rng(["normal", "wide", "squares", "cancelling"].index(kind))
    for n in [*range(301), 599, 600, 1000, 4097]:
        if kind == "normal":
            a = rng.standard_normal(n)
        elif kind == "wide":  # every magnitude from 1e-300 to 1e300, both signs
            a = rng.standard_normal(n) * 10.0 ** rng.integers(-300, 300, n)
        elif kind == "squares":  # the kernel's use: squared sync errors
            e = rng.standard_normal(n) * 1e3
            a = e * e
        else:  # large terms cancelling, small ones left over: the order shows
            a = np.repeat(rng.standard_normal((n + 1) // 2) * 1e16, 2)[:n]
            a[1::2] *= -1.0
            a += rng.standard_normal(n) * 1e-3
        want = np.add.reduce(a)
        got = pairwise_sum(a, 0, n)
        assert got == want and math.copysign(1, got) == math.copysign(1, want), (kind, n)
        # a row inside a longer buffer (the kernel sums a window of its buffer)
        buf = np.concatenate([rng.standard_normal(5), a, rng.standard_normal(3)])
        got = pairwise_sum(buf, 5, n)
        assert got == want, (kind, n, "offset")


# --- fill_plant_rows -------------------------------------------------------------------------


def _reference_row(
    plant: Plant, period_s: float, compute_s: float, counts_per_rev: float
) -> tuple[list[float], int]:
    """A plant row in plain python, from the definitions in ``servotune/plant.py``:

    - ``lag_split``'s docstring: ``lag = m·T + λ``, ``0 <= λ < T``, ``m = floor(lag/T + 1e-12)``,
      ``λ`` set to 0 below ``T·1e-12`` (the relative tolerance it states);
    - ``step_coefficients``' docstring: ``a = exp(-h/tau)``, ``b = tau (1 - a)``, ``1 - a``
      taken as ``-expm1(-h/tau)``;
    - ``tick_coefficients``' docstring: the exact one-tick map with ``w_old`` on ``[0, λ)`` and
      ``w_new`` on ``[λ, T)``: over ``h`` from rest a unit input gives ``p = gain (h − b)``,
      ``v = gain (1 − a)``, and a speed ``v`` moves on by ``p += b·v``, ``v ← a·v``;
    - ``plant_row``'s docstring and ``NPARAM``'s: the negative direction resolved to the positive
      one for a symmetric plant, ``R_LINEAR`` 1 only without friction and with one gain; the
      speed limit in counts/s (``max_speed_rpm / 60 · counts_per_rev``, ``inf`` without one).
    """

    def ab(h: float, tau: float) -> tuple[float, float]:
        return math.exp(-h / tau), -tau * math.expm1(-h / tau)

    gain, tau = plant.gain_cps_per_v, plant.tau_s
    gain_neg = gain if plant.gain_neg_cps_per_v is None else plant.gain_neg_cps_per_v
    coulomb_neg = plant.coulomb_v if plant.coulomb_neg_v is None else plant.coulomb_neg_v
    if plant.max_speed_rpm is None or not math.isfinite(counts_per_rev):
        vmax = math.inf
    else:
        vmax = plant.max_speed_rpm / 60.0 * counts_per_rev
    lag = compute_s + plant.delay_s
    m = math.floor(lag / period_s + 1e-12)
    lam = lag - m * period_s
    if lam < period_s * 1e-12:
        lam = 0.0
    a1, b1 = ab(lam, tau)
    a2, b2 = ab(period_s - lam, tau)
    a_t, b_t = ab(period_s, tau)
    g1_p, g1_v = gain * (lam - b1), gain * (1.0 - a1)
    gn_p, gn_v = gain * (period_s - lam - b2), gain * (1.0 - a2)
    linear = plant.coulomb_v == 0.0 and coulomb_neg == 0.0 and gain_neg == gain
    row = [
        gain,
        tau,
        plant.offset_v,
        plant.coulomb_v,
        vmax,
        plant.noise_counts,
        a1,
        b1,
        a2,
        b2,
        lam,
        period_s - lam,
        b_t,
        a_t,
        g1_p + b2 * g1_v,
        a2 * g1_v,
        gn_p,
        gn_v,
        1.0 if linear else 0.0,
        gain_neg,
        coulomb_neg,
        0.0,  # no modes (servotune.resonance's layout: the count, 1/τ, then the modes)
        1.0 / tau,
    ]
    row += [0.0] * (NROW - len(row))
    return row, m


def _random_plant(rng: np.random.Generator, period_s: float, compute_s: float) -> Plant:
    kind = rng.integers(4)
    if kind == 0:  # a lag of exactly whole ticks (λ = 0 through the tolerance)
        delay = max(0.0, int(rng.integers(0, 3)) * period_s - compute_s)
    elif kind == 1:
        delay = 0.0
    else:
        delay = float(rng.uniform(0.0, 3.0 * period_s))
    asym = rng.random() < 0.5
    coulomb = 0.0 if rng.random() < 0.3 else float(rng.uniform(0.0, 0.5))
    return Plant(
        gain_cps_per_v=float(10.0 ** rng.uniform(1.0, 6.0)),
        tau_s=float(10.0 ** rng.uniform(-4.0, 0.5)),
        delay_s=delay,
        offset_v=float(rng.uniform(-0.05, 0.05)),
        coulomb_v=coulomb,
        max_speed_rpm=None if rng.random() < 0.4 else float(rng.uniform(10.0, 6000.0)),
        noise_counts=float(rng.uniform(0.0, 2.0)),
        gain_neg_cps_per_v=float(10.0 ** rng.uniform(1.0, 6.0)) if asym else None,
        coulomb_neg_v=(float(rng.uniform(0.0, 0.5)) if rng.random() < 0.7 else None)
        if asym
        else None,
    )


def test_fill_plant_rows_equals_reference() -> None:
    rng = np.random.default_rng(7)
    n = 0
    for period_s, compute_s in ((0.004000235, 0.0002), (0.001, 0.0), (0.0005, 0.0004)):
        for cpr in (12288.0, math.inf, 4000.0):
            plants = [_random_plant(rng, period_s, compute_s) for _ in range(300)]
            want = [_reference_row(p, period_s, compute_s, cpr) for p in plants]
            # one at a time (plant_row) …
            for p, (row, m) in zip(plants, want, strict=True):
                got, lag = plant_row(p, period_s, compute_s, cpr)
                assert lag == m
                np.testing.assert_array_equal(got, np.array(row), err_msg=repr(p))
            # … and all at once from parameter rows (what a Monte-Carlo chunk does)
            params = np.empty((len(plants), NPARAM))
            for i, p in enumerate(plants):
                row, _ = want[i]
                params[i] = (
                    p.gain_cps_per_v,
                    p.tau_s,
                    p.offset_v,
                    p.coulomb_v,
                    row[19],
                    row[20],
                    row[4],
                    p.noise_counts,
                    p.delay_s,
                )
            rows = np.empty((len(plants), NROW))
            lags = np.empty(len(plants), dtype=np.int64)
            fill_plant_rows(params, period_s, compute_s, rows, lags)
            np.testing.assert_array_equal(rows, np.array([r for r, _ in want]))
            np.testing.assert_array_equal(lags, [m for _, m in want])
            n += len(plants)
    # the draws cover every branch
    assert n == 2700


# --- a response the traced path refuses -----------------------------------------------------


def _huge_gain(rig, axis: str):
    """The rig with ``axis``'s drive gain at 1.7e308 counts/s/V and no speed limit: a valid
    plant whose speed overflows to inf at full D/A (positions go NaN)."""
    plant = dataclasses.replace(
        rig.axis(axis).plant, gain_cps_per_v=1.7e308, max_speed_rpm=None, gain_neg_cps_per_v=None
    )
    return dataclasses.replace(
        rig,
        axes=tuple(dataclasses.replace(a, plant=plant) if a.name == axis else a for a in rig.axes),
    )


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.parametrize("axis", ["master", "slave"])
@pytest.mark.parametrize(
    ("gain_spread", "message"),
    [
        # the nominal gain kept: the response goes NaN, the traced path's step_info refuses it
        (0.0, "y must be finite"),
        # spread: a drawn gain overflows to inf; the traced path refuses the plant
        (0.2, "gain_cps_per_v must be a finite number"),
    ],
)
def test_refused_like_traced(
    quick_tuning, rig, spec, monkeypatch, axis, gain_spread, message
) -> None:
    """The lean path raises the traced path's ValueError: it runs the kernel, sees a response
    ``step_info`` refuses and falls back to the traced path; a parameter row no Plant accepts
    is refused before any run."""
    bad_rig = _huge_gain(rig, axis)
    mc = dataclasses.replace(spec.montecarlo, count=2, gain_spread=gain_spread)
    small = dataclasses.replace(
        spec,
        montecarlo=mc,
        scenarios=tuple(s for s in spec.scenarios if s.kind in ("sync", "track")),
    )
    lean_results = []
    real = vrun._run_lean_sync
    monkeypatch.setattr(
        vrun,
        "_run_lean_sync",
        lambda *a, **k: lean_results.append(real(*a, **k)) or lean_results[-1],
    )
    errors = {}
    for lean in (False, True):
        with pytest.raises(ValueError, match=message) as exc:
            verify(quick_tuning, bad_rig, small, kernel="auto" if lean else "general")
        errors[lean] = str(exc.value)
    assert errors[True] == errors[False]
    # the lean kernel ran (and declined) only where the plants were valid
    assert lean_results == ([None] if gain_spread == 0.0 else [])


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.parametrize("axis", ["master", "slave"])
def test_hold_not_finite_is_left_to_the_traced_path(quick_tuning, rig, spec, axis) -> None:
    """A hold whose position runs beyond int64 (a drive gain of 1.7e308 counts/s/V): the traced
    path casts its ``floor`` to int64 as numpy casts it (no error, a RuntimeWarning); the lean
    kernel does not imitate that cast, it declines (None) and
    :func:`~servotune.verify.run._run_chunk` runs the traced path."""
    spec = dataclasses.replace(
        spec, montecarlo=dataclasses.replace(spec.montecarlo, gain_spread=0.0)
    )
    shared = _shared(quick_tuning, _huge_gain(rig, axis), spec, ("lock",))
    chunk = _chunk(shared.seed, 2)
    sc, inputs = shared.runs[0]
    chunk_plants, _ = vrun._chunk_plants(chunk, shared)
    pf, pi = chunk_plants.rows()
    assert vrun._lean_sync_ok(shared, sc, pi)
    seeds = np.asarray(chunk.noise, dtype=np.uint64)
    assert vrun._run_lean_sync(shared, sc, inputs, pf, pi, seeds) is None
    with pytest.warns(RuntimeWarning, match="invalid value encountered in cast"):
        _, _, true_pos, _ = _traced(shared, sc, inputs, chunk_plants, chunk)
    # where it ends, no position has an int64 floor (beyond ±2**63 counts, or NaN)
    assert not (np.abs(true_pos[:, -1, rig.axis_names.index(axis)]) < 2.0**63).any()
    # the same hold on the rig as shipped runs lean
    shared = _shared(quick_tuning, rig, spec, ("lock",))
    chunk_plants, _ = vrun._chunk_plants(chunk, shared)
    pf, pi = chunk_plants.rows()
    assert vrun._run_lean_sync(shared, sc, inputs, pf, pi, seeds) is not None


@numba.njit
def _exact_stream(seed, n, out):
    """The stream's draws one after the other, as the general kernel makes them (the state a
    uint64 throughout: from Python it would come back as an int and lose its type)."""
    state = seed
    for d in range(n):
        state, out[d] = normal(state)


def test_approximate_draws_within_the_margin() -> None:
    """The lean kernel takes ``floor(q + noise)`` on approximated draws only where the exact
    draw cannot be on the other side of an integer (``_NZ_MARGIN`` per unit of sigma): the
    approximation must stay far inside that margin. Measured against the exact draws
    (:func:`servotune.sim.tick.normal`, libm's log and cos) of a stream, draw by draw."""
    n = 200_000
    approx = np.empty(n)
    _approx_draws(np.uint64(0x5EED), n, approx)
    exact = np.empty(n)
    _exact_stream(np.uint64(0x5EED), n, exact)
    err = np.abs(approx - exact)
    assert err.max() < 1e-7 < _NZ_MARGIN / 50, err.max()
    # the draws are the stream's, in its order (not merely normal-looking numbers)
    assert np.corrcoef(approx, exact)[0, 1] > 0.999_999
    assert abs(exact.mean()) < 0.01 and abs(exact.std() - 1.0) < 0.01


def test_noisy_floor_is_the_floor_or_declines() -> None:
    """Where the lean kernel's shortcut floor answers, it is ``math.floor`` of the sum; it
    declines (the caller reads exactly) within the margin of an integer, for a value not
    finite, and from 2**53 on (where every double is an integer)."""
    rng = np.random.default_rng(8)
    q = np.concatenate([rng.uniform(-1e6, 1e6, 20_000), rng.uniform(-3.0, 3.0, 20_000)])
    nz = rng.normal(scale=0.3, size=q.size)
    margin = _NZ_MARGIN * 1.3
    answered = 0
    for qi, ni in zip(q, nz, strict=True):
        ok, c = _noisy_floor(float(qi), float(ni), margin)
        x = float(qi) + float(ni)
        near = min(x - math.floor(x), math.floor(x) + 1.0 - x) <= margin + 1e-15 * abs(qi)
        assert ok is (not near), (qi, ni)
        if ok:
            assert c == math.floor(x)
            answered += 1
    assert answered > 0.99 * q.size
    for qi in (5.0 + 0.5 * margin, -7.0 - 0.5 * margin, 3.0):  # within the margin: declined
        assert _noisy_floor(qi, 0.0, margin)[0] is False
    assert _noisy_floor(-0.5, 0.0, margin) == (True, -1)
    for qi in (math.nan, math.inf, -math.inf, 2.0**53, -(2.0**60), 2.0**70):
        assert _noisy_floor(qi, 0.25, margin)[0] is False, qi
