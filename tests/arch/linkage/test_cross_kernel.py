"""The linkage's kernel against the single-rig engine, bit for bit (one tick engine).

Both compose the axis tick of :mod:`servotune.sim.tick`. A linkage the engine can express —
every axis on one slave CPU, no resync, a queue that never runs dry — is a rig whose axes each
follow the commands the CPU pops, one per tick. The reference values here are the engine's
(:func:`servotune.sim.engine.simulate`) on a :class:`~servotune.sim.engine.Loop` built in this
file from the linkage config's fields, not by the linkage's own code: a rig ticking at the
CPU's period with the rig's compute time, the axes' plants, counter registers at power-up,
lock gains, PI gains and following-error limits, the rig's counts per revolution for the speed
limit, the interpolated commands as references (task mode from tick 0, as the slave runs), and
the same seed (one splitmix64 noise stream per run, each axis in column order each tick, no
draw for an axis without noise).

Where the engine cannot follow (a drifting CPU measured at the master's ticks, a tick a sync
moved), the reference is the plant's exact solution (:func:`servotune.plant.advance`) from the
traced state at each tick, recomputed in this file.

Tick 0 needed no alignment: the slave's first tick pops command 0 (in the prefill) and enters
the task law from its power-up state, as the engine's tick 0 does with ``ref_counts[0]`` in
task mode.
"""

from __future__ import annotations

import copy
import dataclasses
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from servotune.arch.linkage import (
    Clock,
    LinkageConfig,
    LinkageResult,
    interpolate,
    linkage_from_dict,
    run_linkage,
)
from servotune.laws.axis import MODE_TASK, AxisController
from servotune.laws.pi import PIGains
from servotune.plant import advance, lag_split, step_coefficients
from servotune.rig import Axis, Rig, Timer
from servotune.scenarios import Inputs
from servotune.sim.engine import Loop, Trace, simulate

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "plants" / "linkage-6axis.toml"
SEED = 11
N_TICKS = 100_000
AXES = ("x", "y", "z", "a")  # a slave CPU drives 2-4 axes


def _one_cpu(
    clock_ppm: float = 0.0, *, prefill_blocks: int = 2, repeats: int = 14
) -> LinkageConfig:
    """The example's x, y, z, a on one slave CPU, no resync, the path run ``repeats`` times.

    Changed from plants/linkage-6axis.toml, each for the comparison: axes b and c dropped (and
    from the moves), one CPU of the four axes at ``clock_ppm``, resync off; the example's path
    (it ends at home) repeated so the axes move over the whole run. To exercise the tick:
    x's counter starts 20,000 counts below the top of its 24-bit register (the first move
    wraps it), y's drive has 2.5 ms of dead time (lag 2.7 ms: more than a whole tick, the
    tick-slot ring), z's lag is exactly one tick (λ = 0) and a has no encoder noise (no draw).
    """
    d: dict[str, Any] = copy.deepcopy(tomllib.loads(EXAMPLE.read_text(encoding="utf-8")))
    for gone in ("b", "c"):
        del d["axis"][gone]
    moves = []
    for mv in d["path"]["move"]:
        mv = dict(mv)
        if "to" in mv:
            mv["to"] = {k: v for k, v in mv["to"].items() if k in AXES}
        moves.append(mv)
    d["path"]["move"] = moves * repeats
    d["cpu"] = [
        {
            "name": "s1",
            "clock_ppm": clock_ppm,
            "axes": list(AXES),
            "queue_depth": (prefill_blocks + 1) * d["bus"]["block_size"] + 5,
        }
    ]
    d["bus"]["prefill_blocks"] = prefill_blocks
    d["clock"] = {"resync_interval_s": 0.0}
    d["axis"]["x"]["counter_init"] = (1 << 24) - 20_000
    d["axis"]["y"]["plant"]["delay_s"] = 0.0025
    d["axis"]["z"]["plant"]["delay_s"] = 0.0018
    d["axis"]["a"]["plant"]["noise_counts"] = 0.0
    return linkage_from_dict(d, EXAMPLE.parent)


def _engine(cfg: LinkageConfig, tick_s: float, n_ticks: int) -> tuple[Trace, np.ndarray]:
    """The slave CPU as a single rig ticking every ``tick_s``, and the references it followed.

    The timer's clock is chosen so the achieved period is ``tick_s`` exactly (1000 timer counts
    per tick); the controllers are quantised at the linkage's nominal period, as the slave's
    are. References: the master's interpolated commands, the end held after the path.
    """
    clock_hz = 1000 / tick_s
    while 1000 / clock_hz != tick_s:  # the nearest clock whose 1000 counts are tick_s
        clock_hz = float(np.nextafter(clock_hz, np.inf if 1000 / clock_hz > tick_s else 0.0))
    timer = Timer(period_s=tick_s, clock_hz=clock_hz, compute_s=cfg.rig.timer.compute_s)
    axes = tuple(
        Axis(
            name=a.name,
            role="master" if i == 0 else "slave",
            plant=a.plant,
            lock_gain_codes_per_count=a.lock_gain_codes_per_count,
            following_error_limit_counts=a.following_error_limit_counts,
            counter_init=a.counter_init,
            counter_channel=i,
            dac_channel=i,
        )
        for i, a in enumerate(cfg.axes)
    )
    rig = Rig(
        name="one-slave-cpu",
        timer=timer,
        counter=cfg.rig.counter,
        dac=cfg.rig.dac,
        encoder=cfg.rig.encoder,
        axes=axes,
    )
    assert rig.period_s == tick_s
    assert rig.counts_per_rev == cfg.rig.counts_per_rev
    controllers = tuple(
        AxisController.from_gains(
            lock_gain_codes_per_count=a.lock_gain_codes_per_count,
            task_gains=PIGains(kp=a.kp, ki=a.ki),
            period_s=cfg.period_s,
            following_error_limit_counts=a.following_error_limit_counts,
        )
        for a in cfg.axes
    )
    loop = Loop(rig=rig, controllers=controllers, ref_source=(-1,) * len(axes))  # all external
    commands = interpolate(cfg).commands
    ref = commands[np.minimum(np.arange(n_ticks), commands.shape[0] - 1)]
    z = np.zeros((n_ticks, len(axes)), dtype=np.int64)
    inputs = Inputs(
        ref_counts=ref,
        mode=z + MODE_TASK,
        reset=z.astype(bool),
        dac_add_codes=z,
        load_v=np.zeros(z.shape),
    )
    return simulate(loop, inputs, seed=SEED), ref


def _assert_ticks_equal(res: LinkageResult, engine: Trace, n_ticks: int) -> None:
    """Every traced tick of every axis equals the engine's, bit for bit."""
    assert res.traces is not None
    for name, field, column in (
        ("D/A code", "code", engine.code),
        ("unwrapped position", "pos_counts", engine.pos_counts),
        ("true position", "true_pos_counts", engine.true_pos_counts),  # float equality
        ("speed", "speed_cps", engine.speed_cps),
    ):
        got = np.column_stack([getattr(t, field)[:n_ticks] for t in res.traces])
        assert got.shape == column.shape, name
        bad = np.argwhere(got != column)
        assert bad.size == 0, f"{name} differs first at tick, axis {bad[0].tolist()}"


@pytest.fixture(scope="module")
def exact() -> LinkageConfig:
    return _one_cpu()


def test_one_cpu_linkage_is_the_engines_bit_for_bit(exact: LinkageConfig) -> None:
    cfg = exact
    t = cfg.period_s
    # the lags the config sets up: y more than a whole tick, z exactly one
    lags = {a.name: lag_split(cfg.rig.timer.compute_s + a.plant.delay_s, t) for a in cfg.axes}
    assert lags["y"][0] == 1 and lags["y"][1] > 0 and lags["z"] == (1, 0.0)
    assert interpolate(cfg).n_ticks >= N_TICKS  # the path moves over the whole run
    res = run_linkage(cfg, seconds=N_TICKS * t, seed=SEED, trace=True)
    engine, ref = _engine(cfg, t, N_TICKS)
    (cpu,) = res.cpus
    # the CPU ticked on the master's grid, popped command k at tick k, never ran dry
    assert cpu.underruns == cpu.overruns == cpu.skipped == cpu.resyncs == 0
    assert np.array_equal(cpu.tick_index, np.arange(N_TICKS))
    assert np.array_equal(cpu.tick_time_s, np.arange(N_TICKS, dtype=np.int64) * t)
    assert all(np.array_equal(tr.ref_counts, ref[:, i]) for i, tr in enumerate(res.traces))
    # the run did something worth comparing: the circle, noise on the reads, x's counter wrapped
    assert np.ptp(engine.pos_counts[:, 0]) > 70_000 and np.ptp(engine.pos_counts[:, 1]) > 70_000
    assert np.any(engine.counter[:, 0] < 20_000) and np.any(engine.counter[:, 0] > 1 << 23)
    read_err = engine.pos_counts - np.floor(engine.true_pos_counts)  # noise (and the origin)
    assert all(np.unique(read_err[:, i]).size > 1 for i in range(3))  # x, y, z: noisy reads
    assert not np.any(read_err[:, 3])  # a: no noise, its reads are the floor of its position
    _assert_ticks_equal(res, engine, N_TICKS)
    # a master tick falls on the CPU's tick: the measurement is the position at the tick
    assert np.array_equal(res.actual_counts, engine.true_pos_counts)


def test_drifting_cpu_ticks_are_the_engines_at_its_own_period() -> None:
    """Without a resync every interval of a drifting CPU is one of its own ticks, so its axes
    are the engine's at the period ``T/(1 + ε)``; measuring at the master ticks, between the
    CPU's ticks, moves a copy and leaves the ticks alone (+1000 ppm over 20,000 ticks: 20 ticks
    ahead, within a prefill of 8 blocks: about 39 ticks of lead)."""
    n = 20_000
    cfg = _one_cpu(1000.0, prefill_blocks=8, repeats=3)
    tick_s = cfg.period_s / (1.0 + 1000.0 * 1e-6)
    res = run_linkage(cfg, seconds=n * cfg.period_s, seed=SEED, trace=True)
    (cpu,) = res.cpus
    assert cpu.underruns == cpu.skipped == 0 and cpu.tick_time_s.size > n
    engine, _ = _engine(cfg, tick_s, cpu.tick_time_s.size)
    _assert_ticks_equal(res, engine, cpu.tick_time_s.size)
    # the master's measurement at k·T, inside the CPU's tick i before it: the plant's exact
    # solution (servotune.plant.advance) from the engine's state at tick i, through the writes
    # acting over tick i (the write of tick i − m − 1 until λ, then that of tick i − m)
    tk = np.arange(n, dtype=np.int64) * cfg.period_s
    ticks = np.searchsorted(cpu.tick_time_s, tk, side="right") - 1
    cpr = cfg.rig.counts_per_rev
    for col, a in enumerate(cfg.axes):
        pl = a.plant
        m, lam = lag_split(cfg.rig.timer.compute_s + pl.delay_s, tick_s)
        volts = np.concatenate([np.zeros(m + 1), engine.volts[:, col]])  # 0 V before tick 0
        want = np.empty(n)
        for k in range(n):
            i = ticks[k]
            h = tk[k] - cpu.tick_time_s[i]
            p, v = engine.true_pos_counts[i, col], engine.speed_cps[i, col]
            for w, span in ((volts[i], min(h, lam)), (volts[i + 1], h - lam)):
                if span > 0.0:
                    c_a, c_b = step_coefficients(span, pl.tau_s)
                    p, v = advance(
                        p,
                        v,
                        w + pl.offset_v,
                        span,
                        c_a,
                        c_b,
                        pl.gain_cps_per_v,
                        pl.tau_s,
                        pl.coulomb_v,
                        pl.max_speed_cps(cpr),
                    )
            want[k] = p
        assert np.array_equal(res.actual_counts[:, col], want), a.name  # the same float ops
    assert not np.array_equal(res.actual_counts, engine.true_pos_counts[ticks])  # between ticks


def test_a_tick_moved_by_a_sync_moves_the_motor_over_the_actual_interval() -> None:
    """Two CPUs drifting ±3000 ppm, a sync every 0.25 s (0.75 ms of drift each time): the
    fast CPU's next tick after a sync comes later than one of its ticks, the slow one's
    earlier. Over an interval with no sync the motor moves one tick ``Tc = T/(1 + ε)``; over
    one with a sync, the actual interval; both times the writes held over the tick before,
    switching at ``λ`` (y: lag 2.7 ms, a write pending across the sync). Recomputed here with
    the plant's exact solution (servotune.plant.advance) from each traced tick to the next."""
    d_cfg = _one_cpu(repeats=1)
    cpus = (
        dataclasses.replace(d_cfg.cpus[0], name="fast", axes=("x", "y"), clock_ppm=3000.0),
        dataclasses.replace(d_cfg.cpus[0], name="slow", axes=("z", "a"), clock_ppm=-3000.0),
    )
    cfg = dataclasses.replace(d_cfg, cpus=cpus, clock=Clock(resync_interval_s=0.25))
    n = 5000
    res = run_linkage(cfg, seconds=n * cfg.period_s, seed=SEED, trace=True)
    assert res.traces is not None
    t_sync = np.arange(1, n // 125 + 1, dtype=np.int64) * 125 * cfg.period_s  # every 125 ticks
    rig = cfg.rig
    cpr = rig.counts_per_rev
    moved = 0
    for tr, a in zip(res.traces, cfg.axes, strict=True):
        cpu = next(c for c in res.cpus if c.name == tr.cpu)
        assert cpu.resyncs == t_sync.size - 1 and cpu.skipped == 0 and cpu.underruns == 0
        tick_s = cfg.period_s / (1.0 + cpu.clock_ppm * 1e-6)
        pl = a.plant
        m, lam = lag_split(rig.timer.compute_s + pl.delay_s, tick_s)
        volts = rig.dac.range_v[0] + tr.code * rig.dac.lsb_v
        volts = np.concatenate([np.zeros(m + 1), volts])  # 0 V before tick 0
        t = cpu.tick_time_s
        # a sync at t_r comes before a tick at the same instant: it is in (t[c-1], t[c]]
        synced = np.searchsorted(t_sync, t[1:], side="right") > np.searchsorted(
            t_sync, t[:-1], side="right"
        )
        for c in range(1, t.size):
            h = t[c] - t[c - 1] if synced[c - 1] else tick_s
            p, v = tr.true_pos_counts[c - 1], tr.speed_cps[c - 1]
            # over tick c − 1: the write of tick c − 2 − m until λ, then that of tick c − 1 − m
            for w, span in ((volts[c - 1], min(h, lam)), (volts[c], h - lam)):
                if span > 0.0:
                    c_a, c_b = step_coefficients(span, pl.tau_s)
                    p, v = advance(
                        p,
                        v,
                        w + pl.offset_v,
                        span,
                        c_a,
                        c_b,
                        pl.gain_cps_per_v,
                        pl.tau_s,
                        pl.coulomb_v,
                        pl.max_speed_cps(cpr),
                    )
            assert (p, v) == (tr.true_pos_counts[c], tr.speed_cps[c]), (a.name, c)
        moved += int(np.count_nonzero(synced))
        # the syncs moved the ticks: the fast CPU's interval grew, the slow one's shrank
        gaps = np.diff(t)[synced]
        assert np.all(gaps > tick_s * 1.1) if cpu.clock_ppm > 0 else np.all(gaps < tick_s * 0.9)
    assert moved == 4 * (t_sync.size - 1)  # every sync moved one tick of each axis
