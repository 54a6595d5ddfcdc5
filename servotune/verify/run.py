"""Verification: does a tuning meet its spec on the bit-true closed loop?

:func:`verify` runs the tuning's controllers, exactly as the runtime
runs them (the engine: :func:`~servotune.sim.engine.prepare_batch`,
:func:`~servotune.sim.engine.run_batch`), on every scenario for the nominal plants and every
Monte Carlo variant, and reports per limit the worst value, the variant it came from and the
margin. It also checks what no scenario can show by a number alone: the fastest simulated
motion against the counter's speed limits, the timer's period error, and that no runtime sum
can overflow with the tuning's constants.

The spec file is described in :mod:`servotune.verify.spec`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from servotune.errors import SpecError
from servotune.laws.axis import FAULT_MASK, FLAG_SATURATED, MODE_TASK
from servotune.metrics import step_info
from servotune.rig import Rig
from servotune.scenarios import Inputs, _sync_move_for, build_scenario
from servotune.sim.engine import Loop, prepare_batch, run_batch
from servotune.tuning import Tuning
from servotune.validate import show_value
from servotune.verify.checks import (
    _FAULT_QUANTITY,
    _Fastest,
    check_overflow,
    check_speed,
    check_timer,
)
from servotune.verify.margins import plant_cases, tuning_margins
from servotune.verify.result import Check, Row, Verification
from servotune.verify.spec import LIMITS, ScenarioSpec, Spec
from servotune.verify.variants import Variant, _seed_seqs, plant_variants

__all__ = [
    "verify",
]

_CHUNK = 64  # candidates per engine batch (bounds the memory of the traces)


# --- running the scenarios -----------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class _MoveWindows:
    start: int  # last tick before the master's reference moves
    target: float  # the reference's final value [counts]
    steady: tuple[int, int]  # [lo, hi) ticks of the steady-lag window


def _inputs(rig: Rig, sc: ScenarioSpec) -> Inputs:
    assert sc.seconds is not None  # resolved by ScenarioSpec
    if sc.kind == "sync":
        return _sync_move_for(rig, sc).inputs
    if sc.kind == "track":
        return build_scenario(rig, "track", axis=_master(rig)[1], seconds=sc.seconds).inputs
    n = math.floor(sc.seconds / rig.period_s + 0.5)
    if n < 3:
        raise SpecError(f"scenario.{sc.name}.seconds gives only {n} ticks")
    return Inputs.hold(n, len(rig.axes))


def _master(rig: Rig) -> tuple[int, str]:
    for i, a in enumerate(rig.axes):
        if a.role == "master":
            return i, a.name
    raise SpecError(f"rig {show_value(rig.name)} has no master axis")


def _move_windows(rig: Rig, sc: ScenarioSpec, inputs: Inputs) -> _MoveWindows:
    i_m, _ = _master(rig)
    ref = inputs.ref_counts[:, i_m]
    moving = np.flatnonzero(ref != ref[0])
    if moving.size == 0:
        raise SpecError(f"scenario {show_value(sc.name)}: the master's reference does not move")
    start = max(int(moving[0]) - 1, 0)
    direction = 1 if ref[-1] >= ref[0] else -1
    dr = direction * np.diff(ref)
    cruise = np.flatnonzero(dr >= dr.max() - 2)  # within 2 counts/tick of the top speed
    c0, c1 = int(cruise[0]) + 1, int(cruise[-1]) + 1
    hi = c1
    for j, a in enumerate(rig.axes):
        if a.role == "slave":
            changed = np.flatnonzero(inputs.load_v[:, j] != inputs.load_v[0, j])
            if changed.size:
                hi = min(hi, int(changed[0]))
    lo = (c0 + hi) // 2
    if hi - lo < 3:
        raise SpecError(
            f"scenario {show_value(sc.name)} has no constant-speed part before the load step "
            f"to measure "
            "the steady lag; lengthen seconds or shorten accel_s"
        )
    return _MoveWindows(start=start, target=float(ref[-1]), steady=(lo, hi))


def _step_values(
    t: np.ndarray, y: np.ndarray, y_init: float, target: float, band_pct: float
) -> tuple[float, float]:
    info = step_info(t, y, y_init=y_init, y_final=target, settling_threshold=band_pct / 100.0)
    settle = info.settling_time_s
    return info.overshoot_pct, (math.inf if math.isnan(settle) else settle)


def _worst(values: np.ndarray, labels: Sequence[str]) -> tuple[float, str]:
    """Largest value (NaN counts as the largest) and the label of its variant."""
    v = np.where(np.isnan(values), np.inf, values)
    i = int(np.argmax(v))
    return float(v[i]), labels[i]


def _run(
    loop: Loop, variants: Sequence[Variant], seeds: Sequence[int], inputs: Inputs
) -> dict[str, np.ndarray]:
    """Traces of a chunk of variants (one engine batch)."""
    batch = prepare_batch(loop, plants=[v.plants for v in variants], seeds=list(seeds))
    res = run_batch(batch, inputs, metrics_only=False)
    assert res.traces is not None
    keys = ("counter", "pos_counts", "err_counts", "flags", "true_pos_counts", "speed_cps")
    return {key: getattr(res.traces, key) for key in keys}


def _evaluate(
    rig: Rig, sc: ScenarioSpec, inputs: Inputs, tr: dict[str, np.ndarray]
) -> tuple[dict[tuple[str, str], np.ndarray], dict[str, np.ndarray]]:
    """Every limited quantity per variant of a chunk (``(quantity, axis)`` → values), and per
    axis whether each variant latched a fault."""
    names = rig.axis_names
    n_v, n_t = tr["flags"].shape[:2]
    values: dict[tuple[str, str], np.ndarray] = {}
    pos = tr["true_pos_counts"]
    flags = tr["flags"]
    if sc.kind in ("sync", "track"):
        win = _move_windows(rig, sc, inputs)
        i_m, _ = _master(rig)
        t = (np.arange(n_t - win.start, dtype=np.int64)) * rig.period_s
        for a, name in enumerate(names):
            task = inputs.mode[:, a] == MODE_TASK
            if not task.any():
                continue
            over = np.empty(n_v)
            settle = np.empty(n_v)
            for b in range(n_v):
                y = pos[b, win.start :, a]
                over[b], settle[b] = _step_values(
                    t, y, float(y[0]), win.target, sc.settling_band_pct
                )
            values[("overshoot_pct", name)] = over
            values[("settling_time_s", name)] = settle
            sat = (flags[:, :, a] & FLAG_SATURATED) != 0
            values[("saturation_pct", name)] = 100.0 * sat[:, task].mean(axis=1)
            if rig.axes[a].role == "slave":
                e = pos[:, :, i_m] - pos[:, :, a]
                et = e[:, task]
                values[("max_sync_error_counts", name)] = np.abs(et).max(axis=1)
                values[("rms_sync_error_counts", name)] = np.sqrt(np.mean(et * et, axis=1))
                lo, hi = win.steady
                values[("steady_lag_counts", name)] = np.abs(e[:, lo:hi]).mean(axis=1)
    else:
        k0 = math.ceil(sc.settle_s / rig.period_s)
        bits = rig.counter.bits
        for a, name in enumerate(names):
            # the plant's whole count in the runtime's frame (relative to its first read)
            first = (tr["counter"][:, 0, a] - rig.axes[a].counter_init) % (1 << bits)
            first = np.where(first >= 1 << (bits - 1), first - (1 << bits), first)
            y = np.floor(pos[:, :, a]).astype(np.int64) - first[:, None]
            target = tr["pos_counts"][:, :, a] + tr["err_counts"][:, :, a]
            values[("holding_band_counts", name)] = (
                np.abs(target[:, k0:] - y[:, k0:]).max(axis=1).astype(float)
            )
            sat = (flags[:, :, a] & FLAG_SATURATED) != 0
            values[("saturation_pct", name)] = 100.0 * sat.mean(axis=1)
    faults = {name: ((flags[:, :, a] & FAULT_MASK) != 0).any(axis=1)
              for a, name in enumerate(names)}  # fmt: skip
    return values, faults


def _rows(
    sc: ScenarioSpec,
    names: Sequence[str],
    values: dict[tuple[str, str], np.ndarray],
    faults: dict[str, np.ndarray],
    labels: Sequence[str],
) -> tuple[list[Row], np.ndarray]:
    """The rows of a scenario (worst over the variants) and which variants keep every limit
    of it (a NaN or a fault fails)."""
    rows = []
    ok = np.ones(len(labels), dtype=bool)
    for key, lim in sc.limits.items():
        quantity, unit = LIMITS[key]
        for name in names:
            if (quantity, name) in values:
                v = values[(quantity, name)]
                worst, label = _worst(v, labels)
                ok &= v <= lim
                rows.append(Row(scenario=sc.name, quantity=quantity, axis=name, unit=unit,
                                limit=lim, worst=worst, variant=label))  # fmt: skip
    for name in names:
        faulted = faults[name]
        ok &= ~faulted
        first = labels[int(np.argmax(faulted))] if faulted.any() else labels[0]
        rows.append(Row(scenario=sc.name, quantity=_FAULT_QUANTITY, axis=name, unit="runs",
                        limit=0.0, worst=float(faulted.sum()), variant=first))  # fmt: skip
    return rows, ok


def check_margins(tuning: Tuning, rig: Rig, spec: Spec) -> list[Check]:
    """One check per axis and loop kind (``margins:<axis>:<lock|task>``): every loop of that
    kind (every query-table cell of a scheduled law) keeps the spec's margin limits on the
    nominal plants and over the plant set (:func:`~servotune.verify.margins.plant_cases`: the
    corners of the identified intervals and of the spec's Monte-Carlo gain and tau spreads,
    each also ``margins.extra_ticks`` ticks late, at the period ± the timer's error limit;
    and ``margins.samples`` plant sets drawn inside that box).

    The check's value is the worst Ms [1]; its detail names the worst loop (the cell), the
    plant case and the limits it breaks. Every loop on every case is screened on a grid; the
    worst ones (by Ms, phase and gain margin) are judged by python-control.
    """
    mc = spec.montecarlo
    cases = plant_cases(rig, gain_spread=mc.gain_spread, tau_spread=mc.tau_spread,
                        extra_ticks=spec.margin_extra_ticks,
                        period_error_ppm=spec.max_period_error_ppm or 0.0,
                        samples=spec.margin_samples, seed=mc.seed)  # fmt: skip
    m = tuning_margins(tuning, rig, limits=spec.margins, cases=cases, every_loop=False)
    lim = spec.margins
    out = []
    for name in tuning.axis_names:
        for kind in ("lock", "task"):
            loops = list(m.select(name, kind))
            if not loops:
                continue
            bad = [(x, lim.broken(x)) for x in loops if lim.broken(x)]
            worst, broken = bad[0] if bad else (m.worst(name, kind), ())
            if bad:
                worst, broken = min(bad, key=lambda xb: (xb[0].stable, -xb[0].max_sensitivity))
            figures = (f"PM {worst.phase_margin_deg:.1f}°, GM {worst.gain_margin_db:.1f} dB, "
                       f"Ms {worst.max_sensitivity:.2f}")  # fmt: skip
            if broken:
                detail = (f"{worst.name} on plant {worst.plant}: {'; '.join(broken)} "
                          f"({len(bad)} of {len(loops)} loop cases break a limit)")  # fmt: skip
            else:
                detail = f"worst {worst.name} on plant {worst.plant}: {figures}"
            out.append(Check(name=f"margins:{name}:{kind}", passed=not broken,
                             value=worst.max_sensitivity, limit=lim.max_sensitivity, unit="1",
                             detail=detail, facts=worst.to_dict()))  # fmt: skip
    return out


def verify(
    tuning: Tuning,
    rig: Rig,
    spec: Spec,
    *,
    seed: int | None = None,
    progress: Callable[[str], None] | None = None,
) -> Verification:
    """Verify a tuning against a spec on the bit-true closed loop.

    Every scenario runs for the nominal plants and every Monte Carlo variant
    (:func:`plant_variants`), each with its own noise stream, through the engine with the
    tuning's quantised constants (nothing is re-quantised). Then the checks: the fastest motion
    against the counter's limits (:func:`check_speed`), the timer period (:func:`check_timer`)
    and the overflow bound (:func:`check_overflow`; if it fails the runs are skipped, since the
    runtime arithmetic is not defined for such constants), and the margins of every loop the
    runtime can run over the plant set (:func:`check_margins`).

    Parameters
    ----------
    tuning : Tuning
    rig : Rig
        The rig to verify on (its axes and period must match the tuning's).
    spec : Spec
    seed : int, optional
        Seeds the variants and the noise; default ``spec.montecarlo.seed``. Same inputs and
        seed give the same result.
    progress : callable, optional
        Receives one line per step (the CLI prints them on stderr).

    Returns
    -------
    Verification

    Raises
    ------
    TuningError
        If the tuning does not belong to the rig (axes, period).
    SpecError
        If the spec names another rig, an axis the rig lacks, or a scenario cannot be built.
    """
    say = progress or (lambda _msg: None)
    if spec.rig is not None and spec.rig != rig.name:
        raise SpecError(
            f"spec {show_value(spec.name)} is written for rig {show_value(spec.rig)}, not "
            f"{show_value(rig.name)}"
        )
    loop = tuning.loop(rig)
    sync_limits = ("max_sync_error_counts", "max_rms_sync_error_counts", "max_steady_lag_counts")
    if not any(a.role == "slave" for a in rig.axes):
        for sc in spec.scenarios:
            for k in sc.limits:
                if k in sync_limits:
                    raise SpecError(
                        f"scenario.{sc.name}.{k} needs a slave axis; rig "
                        f"{show_value(rig.name)} has none"
                    )
    used_seed = spec.montecarlo.seed if seed is None else int(seed)
    variants = plant_variants(rig, spec.montecarlo, used_seed)
    labels = [v.label for v in variants]
    noise = [int(s) for s in _seed_seqs(used_seed)[1].generate_state(len(variants), np.uint64)]
    overflow = check_overflow(tuning, rig)
    checks: list[Check] = [overflow, check_timer(rig, spec.max_period_error_ppm)]
    rows: list[Row] = []
    if not overflow.passed:
        say("verify: constants break the overflow bound; closed-loop runs skipped")
        return Verification(spec=spec, rig_name=rig.name, axis_names=rig.axis_names,
                            seed=used_seed, variants=variants, rows=(),
                            checks=tuple(checks))  # fmt: skip
    fastest = _Fastest()
    passed = np.ones(len(variants), dtype=bool)
    for sc in spec.scenarios:
        say(f"verify: scenario {sc.name} ({sc.kind}, {sc.seconds:g} s), {len(variants)} plant sets")
        try:
            inputs = _inputs(rig, sc)
        except SpecError as exc:
            raise SpecError(f"scenario.{sc.name}: {exc}") from None
        if sc.kind != "lock":
            _move_windows(rig, sc, inputs)  # a bad scenario fails before the runs
        parts = []
        for k in range(0, len(variants), _CHUNK):  # chunks bound the traces' memory
            tr = _run(loop, variants[k : k + _CHUNK], noise[k : k + _CHUNK], inputs)
            parts.append(_evaluate(rig, sc, inputs, tr))
            step = np.abs(np.diff(tr["true_pos_counts"], axis=1))
            if step.size and step.max() > fastest.counts_per_tick:
                b, _, a = np.unravel_index(int(np.argmax(step)), step.shape)
                fastest.counts_per_tick = float(step.max())
                fastest.where_tick = f"{sc.name}, {rig.axes[a].name}, {labels[k + b]}"
            spd = np.abs(tr["speed_cps"])
            if spd.max() > fastest.speed_cps:
                b, _, a = np.unravel_index(int(np.argmax(spd)), spd.shape)
                fastest.speed_cps = float(spd.max())
                fastest.where_speed = f"{sc.name}, {rig.axes[a].name}, {labels[k + b]}"
        values = {key: np.concatenate([v[key] for v, _ in parts]) for key in parts[0][0]}
        faults = {n: np.concatenate([f[n] for _, f in parts]) for n in parts[0][1]}
        sc_rows, sc_ok = _rows(sc, rig.axis_names, values, faults, labels)
        rows += sc_rows
        passed &= sc_ok
    checks[:0] = check_speed(
        rig,
        fastest.counts_per_tick,
        fastest.speed_cps,
        where_tick=fastest.where_tick,
        where_speed=fastest.where_speed,
    )
    say("verify: margins of every loop over the plant set")
    checks += check_margins(tuning, rig, spec)
    result = Verification(spec=spec, rig_name=rig.name, axis_names=rig.axis_names,
                          seed=used_seed, variants=variants, rows=tuple(rows),
                          checks=tuple(checks),
                          variant_passed=tuple(bool(x) for x in passed))  # fmt: skip
    say(f"verify: {'PASSED' if result.passed else 'FAILED'}")
    return result
